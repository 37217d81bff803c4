"""Sign libraries: a folder of sign images plus `library.json` with their physical sizes.

`library.json`::

    {"signs": [{"id": "security_compound", "name": "Security Compound", "text": "مجمع أمني",
                "image": "security_compound.png", "width_m": 0.6, "height_m": 0.24, "kind": "plaque"}]}

`kind` says how a winner is verified (pipeline/verify.py): "plaque", a plaque of text on plain
paper, checked strip by strip against look-alikes sharing some of its words; "picture", a textured
landmark (a poster, a box, a photo of a facade), checked for its likeness alone. Without it, an
image with a plain margin all round is a plaque, any other a picture (`infer_kind`).
`min_text_correlation` (optional, 0-1) replaces the setting of that name (or, for a picture,
`min_picture_correlation`) for this landmark alone.

Library pixel (u, v) (OpenCV convention, the image's top-left corner at (0, 0) and its
bottom-right corner at (w, h)) maps to the sign frame (x right, y down, z into the wall,
metres, origin at the sign centre) by X = (u - w/2)·width_m/w, Y = (v - h/2)·height_m/h.
"""

from __future__ import annotations

import json
import re
import reprlib
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np

from . import shipped_folder
from .image import ImageError, read_image, to_gray
from .jsonfile import read_json

SAMPLE_LIBRARY = shipped_folder(Path(__file__).resolve().parent, "sample_images") / "library"
T = TypeVar("T")
ID_PATTERN = re.compile(r"^[a-z0-9][a-z0-9_-]{0,63}$")
# The label of an image without a sign (datasets' none/ folder, evaluate's confusion matrix, the
# server's expected labels): no sign may take it.
NO_SIGN = "none"
# Aspect ratios of image and physical size may differ by this much before it is an error:
# a sign printed with a slightly different aspect would give a skewed pose.
ASPECT_TOLERANCE = 0.02
# Standard deviation of gray levels below which a sign image is blank: no features, and a
# plaque correlation of zero with anything. The sample signs have 61-68.
MIN_GRAY_SPREAD = 4.0
# Physical sign sizes (metres) outside this range are refused as a slip of units: indoor signs
# run from a door label a few cm wide to a banner across a hall, and a size typed in
# centimetres (an A4 sign's width as 30) or millimetres (as 300) lands above it, as one
# divided by 1000 once too often lands below. A sign 2 cm wide spans the ~60 px the plaque
# fallback needs only from 20 cm away (f = 600 px); no wall is wider than 10 m indoors.
SIGN_SIZE_RANGE_M = (0.02, 10.0)
# Two sign images alike beyond MAX_LIKENESS (see `likeness`) cannot be told apart: features score
# both alike, the margin over the runner-up fails and neither is recognised, or the wrong one
# wins. Measured on security_compound against altered copies, 10 synthetic photos each: copies
# re-encoded, halved, dimmed, blurred or turned 180° (likeness 1.0), lit unevenly (0.98),
# padded by 2.5-5 % (0.99), cropped by 1.5-3 % (0.90-0.95) or warped by 2-4 % (1.0) were
# recognised 0-2 times in 10 and up to 7 answered as the copy; warped by 6-12 % (0.98-0.99),
# 3-9 times, up to 4 as the copy; stretched by 3-40 % (1.0), 0-10 times. A crop of 6 % (0.80),
# the mirror image (-0.01) and signs of a letter more or less (0.71, 0.76; 6 in 6) were told
# apart. Other words sharing one with a sample sign (tests' DECOYS) reach 0.47, the sample signs
# -0.29 to 0.11. Refused though told apart: padding of 10-20 % (0.92-0.97, 10 in 10: the plaque's
# outline differs) and EXIT 7 against EXIT 8 (0.87, 18 in 20).
MAX_LIKENESS = 0.85
LIKENESS_SIZE = 60  # px, each side of the square both images are squeezed to
# The keys library.json may hold, of a sign and at its top (beside "signs", what the server's state records of where
# its library came from: app/state.py library_meta). Others are refused: a typo such as "heigth_m" was dropped
# without a word, the height then taken from the image's aspect.
SIGN_KEYS = ("id", "name", "text", "image", "width_m", "height_m", "kind", "min_text_correlation")
LIBRARY_KEYS = ("signs", "copied_from", "fingerprint", "added")
KINDS = ("plaque", "picture")
# An image is a plaque when this fraction of its edge pixels (at 128 px wide) lie within PLAIN_SPREAD
# of its gray range from their median: paper all round its text. The sample signs have 1.00; of
# the homogr photos (A side), OpenCV's box.png and graf1.png, none more than 0.85 but LePoint2A, a
# magazine on a plain table, at 1.00; a crop inside the box 0.13.
PLAIN_BORDER = 0.95
PLAIN_SPREAD = 0.1
# ... and when its paper shows between its marks: at least this fraction of the box that holds its
# marks (their 1st to 99th percentile of rows and columns, at 128 px wide) is plain. Text leaves
# paper between its strokes: the sample signs 0.68-0.75, a plaque of bold 4.5 x Hershey text 0.44;
# a picture on a plain ground does not: LePoint2A, a magazine lying on a gray table, 0.06 (its
# photos' other A sides 0.06-0.54, their borders not plain). Taken for a plaque, LePoint2's text
# check failed through its true homography (weakest strip 0.62) and passed only through a dense
# alignment 7.3 px off it.
PAPER_AMONG_MARKS = 0.25
KIND_SIZE = 128  # px, the width an image is looked at to infer its kind
LIKENESS_CELLS = (6, 2)  # columns and rows of the cells compared, each LIKENESS_SIZE / 6 x LIKENESS_SIZE / 2 px
LIKENESS_SHADING_SIGMA = 8.0  # px at LIKENESS_SIZE: wider than strokes, narrower than the light across a sign
# A cell with less than this fraction of the mean cell's detail in both images is blank in both:
# its correlation would be that of noise.
LIKENESS_BLANK = 0.05
LIKENESS_ECC_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)


class LibraryError(ValueError):
    """A library folder or entry that cannot be used; the message says which and why."""


@dataclass(eq=False)
class LibrarySign:
    """One known planar sign.

    `image` is the grayscale sign, (h, w) uint8. `width_m`, `height_m`: physical size in metres.
    """

    id: str
    name: str
    text: str
    image_file: str
    width_m: float
    height_m: float
    image: np.ndarray = field(repr=False)
    kind: str = "plaque"
    # this landmark's own bar for the check of its look (None: the settings'), see `verify.text_threshold`
    min_text_correlation: float | None = None

    @property
    def size_px(self) -> tuple[int, int]:
        """(w, h) of the library image in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    @property
    def corners_px(self) -> np.ndarray:
        """(4, 2) library-pixel corners TL, TR, BR, BL."""
        w, h = self.size_px
        return np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=np.float64)

    @property
    def pixel_to_metric(self) -> np.ndarray:
        """(3, 3) map from homogeneous library pixels to sign-plane metres (X, Y, 1)."""
        w, h = self.size_px
        sx, sy = self.width_m / w, self.height_m / h
        return np.array([[sx, 0, -w / 2 * sx], [0, sy, -h / 2 * sy], [0, 0, 1]], dtype=np.float64)

    def to_metric(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) library pixels -> (N, 3) sign-frame points in metres with z = 0."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        A = self.pixel_to_metric
        xy = uv * np.diag(A)[:2] + A[:2, 2]
        return np.column_stack([xy, np.zeros(len(xy))])

    def to_json(self) -> dict:
        out = {"id": self.id, "name": self.name, "text": self.text, "image": self.image_file,
               "width_m": self.width_m, "height_m": self.height_m, "kind": self.kind}
        if self.min_text_correlation is not None:
            out["min_text_correlation"] = self.min_text_correlation
        return out


@dataclass(eq=False)
class Library:
    """Signs in a folder. `cache` holds data derived from the signs (`per_sign`), keyed by the caller."""

    root: Path
    signs: list[LibrarySign]
    cache: dict = field(default_factory=dict, repr=False)

    def __getitem__(self, sign_id: str) -> LibrarySign:
        for sign in self.signs:
            if sign.id == sign_id:
                return sign
        raise KeyError(sign_id)

    @property
    def ids(self) -> list[str]:
        return [s.id for s in self.signs]

    @property
    def pictures_only(self) -> bool:
        """Whether every sign is a picture: none is a bright plaque that segmentation could find."""
        return all(s.kind == "picture" for s in self.signs)

    def per_sign(self, key: Hashable, compute: Callable[[LibrarySign], T]) -> dict[str, T]:
        """{sign id: compute(sign)} for every sign, computed once per `key` and kept in `cache`;
        computed again when the signs have changed since."""
        cached = self.cache.get(key)
        if cached is None or cached.keys() != set(self.ids):
            cached = self.cache[key] = {sign.id: compute(sign) for sign in self.signs}
        return cached


def validate_sign_entry(entry: dict, where: str) -> dict:
    """Check one `library.json` entry; returns it with sizes as floats."""
    if not isinstance(entry, dict):
        raise LibraryError(f"{where}: each sign must be an object")
    _refuse_unknown_keys(entry, SIGN_KEYS, where)
    missing = [k for k in ("id", "image", "width_m") if k not in entry]
    if missing:
        raise LibraryError(f"{where}: missing {', '.join(missing)}")
    sign_id = entry["id"]
    if not isinstance(sign_id, str) or not ID_PATTERN.match(sign_id):
        raise LibraryError(
            f"{where}: id {reprlib.repr(sign_id)} must be 1-64 characters of a-z, 0-9, _ or -, starting with a letter "
            "or digit"
        )
    if sign_id == NO_SIGN:
        raise LibraryError(f"{where}: id {NO_SIGN!r} is reserved for images without a sign; choose another id")
    image = entry["image"]
    # No file system has names of more than 255 characters (NAME_MAX); reading one, the error would quote it whole.
    if not isinstance(image, str) or Path(image).name != image or image.startswith(".") or len(image) > 255:
        raise LibraryError(f"{where}: image {reprlib.repr(image)} must be a plain file name (at most 255 characters) "
                           "inside the library folder")
    for key in ("width_m", "height_m"):
        value = entry.get(key)
        if value is None and key == "height_m":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise LibraryError(f"{where}: {key} must be a positive number of metres; got {reprlib.repr(value)}")
        check_size_m(key, float(value), where)
    kind = entry.get("kind")
    if kind is not None and kind not in KINDS:
        raise LibraryError(f"{where}: kind {reprlib.repr(kind)} must be \"plaque\" (a plaque of text on plain paper, "
                           "checked against plaques of other words) or \"picture\" (a textured landmark: a poster, a "
                           "box, a photo), or left out to be told from the image")
    bar = entry.get("min_text_correlation")
    if bar is not None and (isinstance(bar, bool) or not isinstance(bar, (int, float)) or not 0 <= bar <= 1):
        raise LibraryError(f"{where}: min_text_correlation must be a number from 0 (no check) to 1, or left out for "
                           f"the settings'; got {reprlib.repr(bar)}")
    return entry


def _refuse_unknown_keys(data: dict, known: tuple[str, ...], where: str) -> None:
    """LibraryError naming the keys of `data` (a library.json object, at `where`) that are not `known`."""
    unknown = [key for key in data if key not in known]
    if unknown:
        raise LibraryError(f"{where}: unknown key(s) {reprlib.repr(unknown)[1:-1]}: correct or remove them; the keys "
                           f"read are {', '.join(known)}")


def check_size_m(key: str, value: float, where: str) -> None:
    """LibraryError when `value` metres (positive) is outside SIGN_SIZE_RANGE_M, naming the slip of
    units that would explain it and what the value would then be."""
    lo, hi = SIGN_SIZE_RANGE_M
    if lo <= value <= hi:
        return
    bounds = f"signs are {lo:g}-{hi:g} m"
    if value > hi:
        readings = [(unit, f"{value:g} {symbol} is {value / per_m:g} m")
                    for unit, symbol, per_m in (("centimetres", "cm", 100), ("millimetres", "mm", 1000))
                    if lo <= value / per_m <= hi]
        slip = (f" typed in {' or '.join(u for u, _ in readings)}? {'; '.join(r for _, r in readings)};"
                if readings else "")
        raise LibraryError(f"{where}: {key} = {value:g} m is larger than any indoor sign ({bounds}):{slip} "
                           "give it in metres")
    raise LibraryError(f"{where}: {key} = {value:g} m is {value * 1000:g} mm, smaller than any sign ({bounds}): "
                       "converted to metres twice? give it in metres, e.g. 0.3 for a sign 30 cm wide")


def infer_kind(image: np.ndarray) -> str:
    """"plaque" when the (h, w) uint8 image has a plain margin all round (see PLAIN_BORDER) and its
    paper shows between its marks (PAPER_AMONG_MARKS), else "picture"."""
    h, w = image.shape[:2]
    small = cv2.resize(image, (KIND_SIZE, max(8, round(KIND_SIZE * h / w))), interpolation=cv2.INTER_AREA)
    small = small.astype(np.float32)
    border = np.concatenate([small[0], small[-1], small[:, 0], small[:, -1]])
    paper, spread = float(np.median(border)), PLAIN_SPREAD * max(float(np.ptp(small)), 1e-6)
    if np.mean(np.abs(border - paper) <= spread) < PLAIN_BORDER:
        return "picture"
    plain = np.abs(small - paper) <= spread
    rows, cols = np.nonzero(~plain)
    if rows.size == 0:
        return "plaque"
    (top, bottom), (left, right) = (np.percentile(rows, [1, 99]).astype(int), np.percentile(cols, [1, 99]).astype(int))
    return "plaque" if plain[top:bottom + 1, left:right + 1].mean() >= PAPER_AMONG_MARKS else "picture"


def make_sign(entry: dict, image: np.ndarray, where: str) -> LibrarySign:
    """A `LibrarySign` from a validated entry and its grayscale image; fills a missing height from the aspect."""
    h, w = image.shape[:2]
    if min(w, h) < 32:
        raise LibraryError(f"{where}: image is {w}x{h} px; a sign image needs at least 32 px on each side")
    spread = float(image.std())
    if spread < MIN_GRAY_SPREAD:
        raise LibraryError(f"{where}: image is blank (gray level spread {spread:.1f}); a sign image needs its "
                           "text or marks to be recognised by")
    width_m = float(entry["width_m"])
    height_m = float(entry["height_m"]) if entry.get("height_m") is not None else width_m * h / w
    aspect_px, aspect_m = w / h, width_m / height_m
    if abs(aspect_px / aspect_m - 1) > ASPECT_TOLERANCE:
        raise LibraryError(
            f"{where}: image aspect {aspect_px:.3f} ({w}x{h} px) does not match physical aspect "
            f"{aspect_m:.3f} ({width_m}x{height_m} m)"
        )
    return LibrarySign(
        id=entry["id"], name=str(entry.get("name") or entry["id"]), text=str(entry.get("text") or ""),
        image_file=entry["image"], width_m=width_m, height_m=height_m, image=image,
        kind=entry.get("kind") or infer_kind(image),
        min_text_correlation=None if entry.get("min_text_correlation") is None else float(entry["min_text_correlation"]),
    )


def _likeness_view(image: np.ndarray) -> np.ndarray:
    """The (h, w) uint8 sign squeezed to LIKENESS_SIZE px square, blurred by 1 px and less its shading:
    (LIKENESS_SIZE, LIKENESS_SIZE) float32."""
    square = cv2.resize(image, (LIKENESS_SIZE, LIKENESS_SIZE), interpolation=cv2.INTER_AREA).astype(np.float32)
    square = cv2.GaussianBlur(square, (0, 0), 1.0)
    return square - cv2.GaussianBlur(square, (0, 0), LIKENESS_SHADING_SIGMA)


def _cell_likeness(a: np.ndarray, b: np.ndarray) -> float:
    """The lowest zero-mean normalised cross-correlation of two `_likeness_view`s over their
    LIKENESS_CELLS, blank cells aside: two signs are alike only where every part is."""
    cols, rows = LIKENESS_CELLS
    size = LIKENESS_SIZE
    a, b = (v.reshape(rows, size // rows, cols, size // cols).transpose(0, 2, 1, 3).reshape(rows * cols, -1)
            for v in (a, b))
    a, b = a - a.mean(axis=1, keepdims=True), b - b.mean(axis=1, keepdims=True)
    detail_a, detail_b = (a * a).sum(axis=1), (b * b).sum(axis=1)
    correlation = (a * b).sum(axis=1) / np.sqrt(np.maximum(detail_a * detail_b, 1e-12))
    compared = np.maximum(detail_a, detail_b) > LIKENESS_BLANK * max(detail_a.mean(), detail_b.mean())
    return float(correlation[compared].min())


def _aligned(view: np.ndarray, onto: np.ndarray) -> np.ndarray:
    """`view` warped onto `onto` (both `_likeness_view`s) by the homography ECC finds from none, or as
    it is when ECC finds none."""
    try:
        _, warp = cv2.findTransformECC(onto, view, np.eye(3, dtype=np.float32), cv2.MOTION_HOMOGRAPHY,
                                       LIKENESS_ECC_CRITERIA, None, 3)
    except cv2.error:  # did not converge: nothing alike to align
        return view
    return cv2.warpPerspective(view, warp, view.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def likeness(a: np.ndarray, b: np.ndarray) -> float:
    """How alike two (h, w) uint8 sign images are to features, from -1 to 1: `_cell_likeness` of
    their `_likeness_view`s, as they are and with `b`'s aligned onto `a`'s by a homography (any
    homography of a sign is the same sign to features, a photo of it at a slant too), the best
    over `b`'s four quarter turns. Squeezed square, a copy at another size or aspect is as alike
    as the sign itself."""
    view_a, view_b = _likeness_view(a), _likeness_view(b)
    turns = [np.ascontiguousarray(np.rot90(view_b, k)) for k in range(4)]
    return max(max(_cell_likeness(view_a, turn), _cell_likeness(view_a, _aligned(turn, view_a))) for turn in turns)


def alike_sign(image: np.ndarray, signs: Iterable[LibrarySign]) -> tuple[LibrarySign, float] | None:
    """The sign among `signs` whose image the (h, w) uint8 `image` cannot be told apart from (`likeness`
    at least MAX_LIKENESS), the likest, with its likeness; None when every one is distinct."""
    scored = [(sign, likeness(sign.image, image)) for sign in signs]
    alike = [(sign, value) for sign, value in scored if value >= MAX_LIKENESS]
    return max(alike, key=lambda pair: pair[1]) if alike else None


def load_library(root: str | Path = SAMPLE_LIBRARY) -> Library:
    """Load every sign listed in `root/library.json`."""
    root = Path(root)
    meta_path = root / "library.json"
    if root.is_file():
        raise LibraryError(f"{root} is a file: give the sign library's folder, the one holding library.json and "
                           "the signs' images")
    if not root.is_dir():
        raise LibraryError(f"{root}: no such folder (a sign library is a folder holding library.json)")
    if not meta_path.is_file():
        raise LibraryError(f"{root} is not a sign library: {meta_path} not found")
    meta = read_json(meta_path, LibraryError)
    if isinstance(meta, dict):
        _refuse_unknown_keys(meta, LIBRARY_KEYS, str(meta_path))
    entries = meta.get("signs") if isinstance(meta, dict) else None
    if not isinstance(meta, dict) or not isinstance(entries, list) or not entries:
        raise LibraryError(f'{meta_path} must hold {{"signs": [...]}} with at least one sign')

    signs: list[LibrarySign] = []
    for i, entry in enumerate(entries):
        where = f"{meta_path} sign #{i}"
        validate_sign_entry(entry, where)
        if entry["id"] in {s.id for s in signs}:
            raise LibraryError(f"{where}: duplicate id {entry['id']!r}")
        try:  # as any image is read: artwork on a transparent ground is a sign on white
            image = to_gray(read_image(root / entry["image"]))
        except ImageError as exc:
            raise LibraryError(f"{where}: cannot read its image: {exc}") from None
        signs.append(make_sign(entry, image, where))
        # as the page refuses to add such a copy, and for the same reason
        if alike := alike_sign(image, signs[:-1]):
            raise LibraryError(f"{where} ({entry['id']!r}) cannot be told apart from {alike[0].id!r} (likeness "
                               f"{alike[1]:.2f}; from {MAX_LIKENESS} on features score both alike and neither is "
                               "recognised, or the wrong one is): keep one of them in library.json")
    return Library(root=root, signs=signs)


def save_library_json(library: Library) -> None:
    """Write `library.json` for the signs currently in `library`."""
    path = library.root / "library.json"
    path.write_text(json.dumps({"signs": [s.to_json() for s in library.signs]}, ensure_ascii=False, indent=2) + "\n",
                    encoding="utf-8")
