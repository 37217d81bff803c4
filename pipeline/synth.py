"""Synthetic indoor scenes of library signs, with exact ground truth.

A scene is a box-shaped room, ray-cast per pixel. The back wall is the sign plane z = 0 of the
sign frame (x right, y down, z into the wall, metres, origin at the sign centre); floor, ceiling,
side walls and a front wall close the box around the camera, so every ray hits a surface.
Surfaces carry procedural textures (paint, plaster, concrete, tiles, wood), skirting and flat
decals - doors, paper sheets, whiteboards, posters, light switches, white plaques with Latin
text, ceiling light panels and the sign itself - each warped by its exact plane homography.

Like a small camera: the scene is rendered at twice the output size in linear radiance, lit by
point lights, downsampled with INTER_AREA (anti-aliasing), then exposed, vignetted, blurred,
gamma-encoded, noised and JPEG-compressed.

Ground truth is for the output camera: X_cam = R·X_sign + t, H = K·[r1 r2 t]·sign.pixel_to_metric
(library pixels -> image pixels, H[2,2] = 1) and `corners` = H·sign.corners_px (TL, TR, BR, BL).
"""

from __future__ import annotations

import colorsys
import functools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from signpose.pipeline.camera import Camera, assumed_camera, save_camera
from signpose.pipeline.image import resize_map
from signpose.pipeline.library import Library, LibrarySign

# The default mix of a dataset; "steep" (a sign 60-75 degrees off its normal, ALL_CATEGORIES) is rendered
# only when asked for, so the mix, and the figures measured on it, stay as they were.
CATEGORIES = ("easy", "hard", "negative")
ALL_CATEGORIES = (*CATEGORIES, "steep")
DEFAULT_WEIGHTS = {"easy": 0.5, "hard": 0.3, "negative": 0.2, "steep": 0.3}
# The renderer's version, raised whenever a change moves what its scenes show: scenes rendered once
# and kept by the benches are named by it, so that an older rendering is not measured again.
RENDERING = 3
# Sign-width ranges below are in px for a 640 px wide image and scale with the image width.
REFERENCE_WIDTH = 640
SUPERSAMPLE = 2
TEX_SIZE = 1024
TEX_PX_PER_M = 256.0  # a texture tile repeats every TEX_SIZE / TEX_PX_PER_M = 4 m
MIP_LEVELS = 6
INSIDE_MARGIN_PX = 3  # positives keep every sign corner this far inside the image

LATIN_WORDS = (
    "office meeting room staff only exit archive laboratory storage printer kitchen toilets "
    "please keep door closed fire assembly point notice schedule monday tuesday friday report "
    "project budget minutes agenda safety first wash hands visitors sign in reception floor "
    "level north south block wing lecture hall server no entry authorised personnel"
).split()
PLAQUE_TEXTS = ("EXIT", "OFFICE", "ROOM 204", "MEETING ROOM", "STAFF ONLY", "ARCHIVE", "LAB 3",
                "STORAGE", "KITCHEN", "NO ENTRY", "RECEPTION", "WC", "SERVER ROOM", "B-112")


class SynthError(ValueError):
    """Scene parameters that cannot be rendered; the message says which and why."""


@dataclass
class Scene:
    """One rendered scene and its ground truth for the output camera.

    `image`: (h, w, 3) BGR uint8, exactly what decoding `jpeg` gives. For positives `R` (3, 3),
    `t` (3,) metres, `H` (3, 3) library px -> image px and `corners` (4, 2) image px TL, TR, BR, BL;
    all four are None for negatives. `params` holds the drawn parameters (JSON-ready).
    """

    image: np.ndarray = field(repr=False)
    jpeg: bytes = field(repr=False)
    label: str | None
    category: str
    R: np.ndarray | None
    t: np.ndarray | None
    H: np.ndarray | None
    corners: np.ndarray | None
    params: dict

    def truth(self) -> dict:
        """This scene's `truth.json` entry."""
        def lst(a):
            return None if a is None else np.asarray(a).tolist()
        return {"label": self.label, "category": self.category, "R": lst(self.R), "t": lst(self.t),
                "H": lst(self.H), "corners": lst(self.corners), "params": self.params}


@dataclass(frozen=True)
class _Look:
    """Pose and imaging ranges of one look: easy, or one way of being hard (widths in px at REFERENCE_WIDTH)."""

    mode: str
    off_axis_deg: tuple[float, float]
    width_px: tuple[float, float]
    roll_deg: float
    blur_sigma: tuple[float, float]
    motion_px: tuple[float, float]
    noise: tuple[float, float]  # sensor noise std in 8-bit levels at mid-grey
    brightness: tuple[float, float]  # auto-exposure target: mean display level in [0, 1]
    jpeg_quality: tuple[int, int]
    side_lamp: bool = False  # a lamp close to the sign: a strong gradient across it
    wall_max: float = 0.85  # brightest wall paint (sRGB value); light walls make white plaques hard to segment


LOOKS = {
    "easy": _Look("easy", (0, 35), (150, 400), 8, (0, 0.7), (0, 0), (1, 3), (0.35, 0.55), (75, 95), wall_max=0.72),
    "oblique": _Look("oblique", (45, 70), (110, 300), 15, (0, 0.9), (0, 0), (2, 5), (0.3, 0.5), (60, 90)),
    "small": _Look("small", (0, 45), (60, 110), 15, (0, 0.8), (0, 0), (2, 5), (0.3, 0.5), (60, 90)),
    "blurred": _Look("blurred", (0, 45), (110, 300), 20, (1.2, 2.5), (6, 16), (3, 8), (0.3, 0.5), (60, 85)),
    "dim": _Look("dim", (0, 45), (110, 300), 20, (0, 1.0), (0, 0), (6, 14), (0.1, 0.2), (60, 85)),
    "gradient": _Look("gradient", (0, 45), (110, 300), 20, (0, 1.0), (0, 0), (3, 8), (0.25, 0.45), (60, 85),
                      side_lamp=True),
    # A UAV flying along a corridor sees door signs this way: SIFT on the view alone finds few matches.
    "steep": _Look("steep", (60, 75), (90, 200), 10, (0, 0.8), (0, 0), (2, 5), (0.3, 0.5), (60, 90)),
}
HARD_MODES = ("oblique", "small", "blurred", "dim", "gradient")


@dataclass(frozen=True)
class _Plane:
    """A rectangle of the room: points origin + u·a1 + v·a2 (sign frame, metres), u, v in `bounds`.

    a1 × a2 points into the surface, so decals drawn with image x along a1 and y along a2 read
    correctly from inside the room.
    """

    origin: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    bounds: tuple[float, float, float, float]  # u_min, v_min, u_max, v_max
    texture: str  # "wall", "floor" or "ceiling"

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.a1, self.a2)

    def homography(self, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(3, 3) map from plane (u, v, 1) to image pixels."""
        return K @ np.column_stack([R @ self.a1, R @ self.a2, R @ self.origin + t])


@dataclass
class _Decal:
    """A flat picture on plane `plane` covering `rect` = (u0, v0, u1, v1) metres.

    `albedo` is (h, w, 3) float32 linear reflectance; image pixel (x, y) sits at
    u = u0 + x·(u1 - u0)/w, the library's pixel convention. `emission` adds radiance (lamps).
    """

    plane: int
    rect: tuple[float, float, float, float]
    albedo: np.ndarray
    emission: float = 0.0
    kind: str = ""


@dataclass
class _Room:
    """Room dimensions around the sign; Y grows downwards, the floor is at Y = sign_height."""

    sign_height: float  # sign centre above the floor, m
    ceiling_height: float
    above_door: bool


@dataclass
class _Surface:
    """The pixels whose nearest surface is one plane: flat pixel indices and, per pixel (n,),
    plane coordinates u, v (m), sign-frame hit points (n, 3), camera depth (m), cos of incidence."""

    pixels: np.ndarray
    u: np.ndarray
    v: np.ndarray
    points: np.ndarray
    depth: np.ndarray
    cos_incidence: np.ndarray


@dataclass
class _Hits:
    """Ray-cast result: (h, w) index of the visible plane, and one `_Surface` per plane."""

    plane: np.ndarray
    surfaces: list[_Surface]


# ---------------------------------------------------------------------------------------------
# Colours and procedural textures (linear reflectance, float32)


def _srgb(rng: np.random.Generator, value: tuple[float, float], sat: tuple[float, float],
          hue: tuple[float, float] = (0.0, 1.0)) -> tuple[int, int, int]:
    """A random BGR colour, 0-255 sRGB, for drawing."""
    r, g, b = colorsys.hsv_to_rgb(rng.uniform(*hue) % 1.0, rng.uniform(*sat), rng.uniform(*value))
    return int(b * 255), int(g * 255), int(r * 255)


def _linear(bgr) -> np.ndarray:
    """sRGB 0-255 (a colour or an image) -> linear reflectance float32."""
    return ((np.asarray(bgr, dtype=np.float32) / 255.0) ** 2.2).astype(np.float32)


def _noise(rng: np.random.Generator, beta: float, stretch: float = 1.0) -> np.ndarray:
    """(TEX_SIZE, TEX_SIZE) periodic 1/f^beta noise, zero mean, unit std.

    Filtering white noise in the Fourier domain makes it tile seamlessly; `stretch` > 1 damps
    vertical frequencies, so features run long down the texture (wood grain along v).
    """
    n = TEX_SIZE
    out = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((n, n))) * _noise_filter(beta, stretch), s=(n, n))
    return ((out - out.mean()) / out.std()).astype(np.float32)


@functools.lru_cache(maxsize=16)
def _noise_filter(beta: float, stretch: float) -> np.ndarray:
    fy = np.fft.fftfreq(TEX_SIZE)[:, None] * stretch
    fx = np.fft.rfftfreq(TEX_SIZE)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = np.inf
    return f**-beta


def _cells(rng: np.random.Generator, period_m: float, spread: float, planks: bool = False) -> np.ndarray:
    """(TEX_SIZE, TEX_SIZE) multiplier 1 ± spread, constant per square tile (or per vertical plank).

    `period_m` must divide the 4 m tile so cells repeat seamlessly.
    """
    count = round(TEX_SIZE / TEX_PX_PER_M / period_m)
    idx = np.arange(TEX_SIZE) * count // TEX_SIZE
    values = 1 + spread * rng.standard_normal((1 if planks else count, count))
    return values[np.ix_(idx * (not planks), idx)].astype(np.float32)


def _grid_lines(period_m: float, width_m: float, planks: bool = False) -> np.ndarray:
    """(TEX_SIZE, TEX_SIZE) coverage in [0, 1] of joints every `period_m`: a grout grid, or plank seams."""
    x = np.arange(TEX_SIZE) / TEX_PX_PER_M
    d = np.abs((x + period_m / 2) % period_m - period_m / 2)
    line = np.clip(width_m / 2 - d + 0.5 / TEX_PX_PER_M, 0, 1 / TEX_PX_PER_M) * TEX_PX_PER_M
    return np.maximum.outer(line * (not planks), line).astype(np.float32)


def _shade(base: np.ndarray, variation: np.ndarray) -> np.ndarray:
    return np.clip(base[None, None, :] * variation[..., None], 0, 1).astype(np.float32)


def _mix(a: np.ndarray, b: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return a * (1 - alpha[..., None]) + b * alpha[..., None]


def _wood(rng: np.random.Generator, plank_m: float, value: tuple[float, float]) -> np.ndarray:
    """Planks running along v, `plank_m` wide, with grain and dark seams."""
    base = _linear(_srgb(rng, value, (0.35, 0.65), (0.05, 0.1)))
    grain = 1 + 0.12 * _noise(rng, 1.6, stretch=14) + 0.05 * _noise(rng, 0.8, stretch=4)
    planks = _cells(rng, plank_m, 0.12, planks=True)
    seams = _grid_lines(plank_m, 0.003, planks=True)
    return _mix(_shade(base, grain * planks), base * 0.35, seams)


def _tiles(rng: np.random.Generator, period_m: float, value: tuple[float, float], sat=(0.0, 0.4)) -> np.ndarray:
    base = _linear(_srgb(rng, value, sat))
    grout = _linear(_srgb(rng, (0.3, 0.85), (0.0, 0.1)))
    variation = _cells(rng, period_m, 0.04) * (1 + 0.03 * _noise(rng, 1.5))
    joints = _grid_lines(period_m, rng.uniform(0.003, 0.008))
    return _mix(_shade(base, variation), np.broadcast_to(grout, base.shape), joints)


def _wall_texture(rng: np.random.Generator, top: float) -> tuple[str, np.ndarray]:
    """A wall texture whose base colour has sRGB value at most `top`."""
    kind = str(rng.choice(["paint", "plaster", "concrete", "tiles", "wood"], p=[0.35, 0.2, 0.15, 0.15, 0.15]))
    if kind == "wood":
        return kind, _wood(rng, float(rng.choice([0.1, 0.125, 0.2, 0.25])), (0.35, min(top, 0.7)))
    if kind == "tiles":
        return kind, _tiles(rng, float(rng.choice([0.2, 0.25, 0.4])), (0.45, top))
    if kind == "concrete":
        base = _linear(_srgb(rng, (0.45, min(top, 0.7)), (0.0, 0.06)))
        pores = (_noise(rng, 0.2) > 2.6).astype(np.float32)
        return kind, _shade(base, (1 + 0.15 * _noise(rng, 1.8) + 0.05 * _noise(rng, 0.9)) * (1 - 0.4 * pores))
    base = _linear(_srgb(rng, (0.45, top), (0.0, 0.35)))
    if kind == "plaster":
        return kind, _shade(base, 1 + 0.08 * _noise(rng, 2.4) + 0.04 * _noise(rng, 1.2))
    return kind, _shade(base, 1 + 0.03 * _noise(rng, 2.0) + 0.015 * _noise(rng, 0.7))


def _floor_texture(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    kind = str(rng.choice(["tiles", "wood", "linoleum"]))
    if kind == "tiles":
        return kind, _tiles(rng, float(rng.choice([0.4, 0.5])), (0.3, 0.65), (0.0, 0.3))
    if kind == "wood":
        return kind, _wood(rng, float(rng.choice([0.125, 0.2])), (0.3, 0.55))
    base = _linear(_srgb(rng, (0.25, 0.55), (0.05, 0.4)))
    return kind, _shade(base, 1 + 0.08 * _noise(rng, 1.5) + 0.05 * _noise(rng, 0.5))


def _ceiling_texture(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    base = _linear(_srgb(rng, (0.75, 0.92), (0.0, 0.05)))
    if rng.random() < 0.5:
        return "paint", _shade(base, 1 + 0.02 * _noise(rng, 2.0))
    speckle = _shade(base, 1 + 0.06 * _noise(rng, 0.4) + 0.03 * _noise(rng, 1.8))
    rails = _grid_lines(0.5, 0.024)
    return "drop", _mix(speckle, np.broadcast_to(base * 0.8, speckle.shape), rails)


def _mipmap(texture: np.ndarray) -> list[np.ndarray]:
    # INTER_AREA halving averages 2x2 blocks without crossing the tile edge, so levels stay periodic.
    levels = [texture]
    for _ in range(MIP_LEVELS - 1):
        levels.append(cv2.resize(levels[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    return levels


def _sample_texture(levels: list[np.ndarray], u: np.ndarray, v: np.ndarray, texels_per_px: np.ndarray) -> np.ndarray:
    """Trilinear lookup of (N,) plane coordinates (m) -> (N, 3) reflectance.

    Blending mip levels by each pixel's footprint keeps distant grout and seams from aliasing
    into moire, which no real camera shows.
    """
    n = len(u)
    rows = -(-n // 1024)
    pad = rows * 1024 - n  # cv2.remap maps must be under 32767 px per side

    def grid(a):
        return np.pad(a.astype(np.float32), (0, pad)).reshape(rows, 1024)

    lam = np.clip(np.log2(np.maximum(texels_per_px, 1.0)), 0, MIP_LEVELS - 1)
    lo = np.floor(lam).astype(int)
    frac = (lam - lo)[:, None].astype(np.float32)
    out = np.zeros((n, 3), np.float32)
    for level in range(lo.min(), min(lo.max() + 2, MIP_LEVELS)):
        weight = np.where(lo == level, 1 - frac[:, 0], 0) + np.where(lo + 1 == level, frac[:, 0], 0)
        if not weight.any():
            continue
        tex = levels[level]
        scale = TEX_PX_PER_M / 2**level
        x = np.mod(u * scale - 0.5, tex.shape[1])
        y = np.mod(v * scale - 0.5, tex.shape[0])
        sampled = cv2.remap(tex, grid(x), grid(y), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        out += sampled.reshape(-1, 3)[:n] * weight[:, None].astype(np.float32)
    return out


# ---------------------------------------------------------------------------------------------
# Decal pictures: drawn in sRGB with OpenCV, returned as linear reflectance


def _fit_text(text: str, font: int, box_w: int, box_h: int, thickness_frac: float = 0.12) -> tuple[float, int]:
    """Font scale and thickness for `text` to fill a box_w x box_h px box."""
    (w, h), _ = cv2.getTextSize(text, font, 1.0, 2)
    scale = min(box_w / w, box_h / h)
    return scale, max(1, round(scale * 22 * thickness_frac))


def _centred_text(img: np.ndarray, text: str, font: int, scale: float, thickness: int, color, cy: float) -> None:
    (w, h), _ = cv2.getTextSize(text, font, scale, thickness)
    org = (round((img.shape[1] - w) / 2), round(cy + h / 2))
    cv2.putText(img, text, org, font, scale, color, thickness, cv2.LINE_AA)


def _text_lines(rng: np.random.Generator, img: np.ndarray, box: tuple[int, int, int, int], line_h: int,
                color) -> None:
    """Fill `box` (x0, y0, x1, y1) with lines of random Latin words, like printed text."""
    x0, y0, x1, y1 = box
    scale = line_h / 30
    y = y0 + line_h
    while y < y1:
        words: list[str] = []
        x = x0
        while True:
            word = str(rng.choice(LATIN_WORDS))
            (w, _), _ = cv2.getTextSize(word + " ", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
            if x + w > x1 or (words and rng.random() < 0.08):
                break
            words.append(word)
            x += w
        cv2.putText(img, " ".join(words), (x0, y), cv2.FONT_HERSHEY_SIMPLEX, scale, color, 1, cv2.LINE_AA)
        y += round(line_h * rng.uniform(1.4, 1.9))


def _paper(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    """A printed sheet (A5-A3, either orientation) with text, a table or shapes. Returns (image, size m)."""
    w_m, h_m = [(0.148, 0.21), (0.21, 0.297), (0.297, 0.42)][rng.choice(3, p=[0.2, 0.6, 0.2])]
    if rng.random() < 0.35:
        w_m, h_m = h_m, w_m
    ppm = 1000
    w, h = round(w_m * ppm), round(h_m * ppm)
    shade = int(rng.uniform(228, 252))
    img = np.full((h, w, 3), (shade, shade, shade - rng.integers(0, 10)), np.uint8)
    ink = _srgb(rng, (0.0, 0.35), (0.0, 0.8))
    m = round(0.02 * ppm)
    content = rng.choice(["text", "table", "shapes", "notice"])
    if content == "notice":
        title = str(rng.choice(PLAQUE_TEXTS))
        scale, thick = _fit_text(title, cv2.FONT_HERSHEY_DUPLEX, w - 2 * m, h // 6)
        _centred_text(img, title, cv2.FONT_HERSHEY_DUPLEX, scale, thick, ink, h * 0.18)
        _text_lines(rng, img, (m, round(h * 0.35), w - m, h - m), 10, (40, 40, 40))
    elif content == "table":
        _text_lines(rng, img, (m, m, w - m, m + 40), 12, ink)
        cols, rows = rng.integers(2, 5), rng.integers(4, 12)
        xs = np.linspace(m, w - m, cols + 1).astype(int)
        ys = np.linspace(m + 50, h - m, rows + 1).astype(int)
        for x in xs:
            cv2.line(img, (x, ys[0]), (x, ys[-1]), (60, 60, 60), 1, cv2.LINE_AA)
        for y in ys:
            cv2.line(img, (xs[0], y), (xs[-1], y), (60, 60, 60), 1, cv2.LINE_AA)
        for r in range(rows):
            for c in range(cols):
                cv2.putText(img, str(rng.choice(LATIN_WORDS)), (xs[c] + 4, ys[r + 1] - 5),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.3, (30, 30, 30), 1, cv2.LINE_AA)
    elif content == "shapes":
        for _ in range(rng.integers(3, 9)):
            color = _srgb(rng, (0.1, 0.8), (0.2, 1.0))
            centre = (int(rng.integers(m, w - m)), int(rng.integers(m, h - m)))
            r = int(rng.integers(8, max(9, min(w, h) // 4)))
            if rng.random() < 0.5:
                cv2.circle(img, centre, r, color, -1 if rng.random() < 0.6 else 3, cv2.LINE_AA)
            else:
                cv2.rectangle(img, (centre[0] - r, centre[1] - r // 2), (centre[0] + r, centre[1] + r // 2), color, -1,
                              cv2.LINE_AA)

    else:
        _text_lines(rng, img, (m, m, w - m, h - m), int(rng.integers(8, 14)), ink)
    return _linear(img), (w_m, h_m)


def _latin_plaque(rng: np.random.Generator,
                  size_m: tuple[float, float] | None = None) -> tuple[np.ndarray, tuple[float, float]]:
    """A white sign with Latin text - a distractor that segments exactly like a library sign."""
    if size_m is None:
        w_m = rng.uniform(0.3, 0.8)
        size_m = (w_m, w_m / rng.uniform(2.0, 3.5))
    ppm = 800
    w, h = round(size_m[0] * ppm), round(size_m[1] * ppm)
    shade = int(rng.uniform(232, 252))
    img = np.full((h, w, 3), shade, np.uint8)
    ink = _srgb(rng, (0.0, 0.3), (0.0, 0.9))
    font = int(rng.choice([cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_TRIPLEX]))
    title = str(rng.choice(PLAQUE_TEXTS))
    two_lines = rng.random() < 0.4
    scale, thick = _fit_text(title, font, int(w * 0.8), int(h * (0.35 if two_lines else 0.5)), 0.15)
    _centred_text(img, title, font, scale, thick, ink, h * (0.38 if two_lines else 0.5))
    if two_lines:
        sub = " ".join(rng.choice(LATIN_WORDS, 2)).title()
        scale, thick = _fit_text(sub, font, int(w * 0.7), int(h * 0.18))
        _centred_text(img, sub, font, scale, thick, ink, h * 0.72)
    if rng.random() < 0.3:
        border = max(2, h // 25)
        cv2.rectangle(img, (border, border), (w - border, h - border), ink, max(2, border // 2), cv2.LINE_AA)
    return _linear(img), size_m


def _whiteboard(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    w_m, h_m = rng.uniform(0.9, 1.8), rng.uniform(0.6, 1.2)
    ppm = 250
    w, h = round(w_m * ppm), round(h_m * ppm)
    img = np.full((h, w, 3), int(rng.uniform(235, 252)), np.uint8)
    frame = max(3, round(0.02 * ppm))
    for _ in range(rng.integers(0, 12)):
        color = [(30, 30, 30), (160, 60, 20), (30, 30, 170), (40, 120, 40)][rng.integers(4)]
        if rng.random() < 0.5:
            steps = rng.normal(0, 6, (rng.integers(10, 60), 2))
            pts = np.cumsum(steps, axis=0) + [rng.uniform(0, w), rng.uniform(0, h)]
            cv2.polylines(img, [pts.astype(np.int32)], False, color, 2, cv2.LINE_AA)
        else:
            words = " ".join(rng.choice(LATIN_WORDS, rng.integers(1, 4)))
            org = (int(rng.uniform(frame, w * 0.6)), int(rng.uniform(frame + 20, h - frame)))
            cv2.putText(img, words, org, cv2.FONT_HERSHEY_SCRIPT_SIMPLEX, rng.uniform(0.6, 1.1), color, 2, cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (150, 150, 150), frame)
    return _linear(img), (w_m, h_m)


def _poster(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    w_m = rng.uniform(0.4, 0.7)
    h_m = w_m * rng.uniform(1.2, 1.5)
    ppm = 300
    w, h = round(w_m * ppm), round(h_m * ppm)
    img = np.full((h, w, 3), _srgb(rng, (0.3, 0.95), (0.1, 0.9)), np.uint8)
    for _ in range(rng.integers(2, 8)):
        color = _srgb(rng, (0.1, 1.0), (0.2, 1.0))
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        r = int(rng.uniform(10, w / 2.5))
        if rng.random() < 0.5:
            cv2.circle(img, c, r, color, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, (c[0] - r, c[1] - r), (c[0] + r, c[1] + r // 2), color, -1)
    title = " ".join(rng.choice(LATIN_WORDS, 2)).upper()
    scale, thick = _fit_text(title, cv2.FONT_HERSHEY_DUPLEX, int(w * 0.85), int(h * 0.08))
    _centred_text(img, title, cv2.FONT_HERSHEY_DUPLEX, scale, thick, _srgb(rng, (0, 1), (0, 1)), h * 0.1)
    return _linear(img), (w_m, h_m)


def _switch(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    img = np.full((80, 80, 3), int(rng.uniform(215, 245)), np.uint8)
    cv2.rectangle(img, (0, 0), (79, 79), (170, 170, 170), 2)
    cv2.rectangle(img, (28, 18), (52, 62), (190, 190, 190), 2, cv2.LINE_AA)
    return _linear(img), (0.08, 0.08)


def _door(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    """Door leaf with frame, panels and handle; its bottom edge is the floor. Returns (image, size m)."""
    leaf_w, leaf_h, frame_m = rng.uniform(0.8, 0.95), rng.uniform(2.0, 2.1), rng.uniform(0.05, 0.1)
    w_m, h_m = leaf_w + 2 * frame_m, leaf_h + frame_m
    ppm = 200
    w, h, f = round(w_m * ppm), round(h_m * ppm), round(frame_m * ppm)
    if rng.random() < 0.6:
        frame_color = _srgb(rng, (0.3, 0.9), (0.0, 0.3))  # painted
    else:
        frame_color = _srgb(rng, (0.3, 0.6), (0.4, 0.7), (0.05, 0.1))  # wood
    img = np.full((h, w, 3), frame_color, np.uint8)
    if rng.random() < 0.5:  # wood veneer
        leaf = _srgb(rng, (0.3, 0.7), (0.35, 0.7), (0.04, 0.1))
        grain = cv2.resize(rng.standard_normal((max(2, h // 60), w)).astype(np.float32), (w - 2 * f, h - f),
                           interpolation=cv2.INTER_CUBIC)
        img[f:, f:w - f] = np.clip(np.asarray(leaf, np.float32) * (1 + 0.08 * grain[..., None]), 0, 255)
    else:
        img[f:, f:w - f] = _srgb(rng, (0.2, 0.9), (0.0, 0.6))
    cv2.rectangle(img, (f, f), (w - f - 1, h), (30, 30, 30), 2)
    if rng.random() < 0.5:
        edge_dark = tuple(int(c * 0.7) for c in img[h // 2, w // 2])
        mx, my = round(0.12 * ppm), round(0.12 * ppm)
        mid = f + (h - f) // 2
        for y0, y1 in ((f + my, mid - my // 2), (mid + my // 2, h - my)):
            cv2.rectangle(img, (f + mx, y0), (w - f - mx, y1), edge_dark, 3, cv2.LINE_AA)
    elif rng.random() < 0.4:  # wired-glass window
        cv2.rectangle(img, (w // 2 - round(0.12 * ppm), f + round(0.25 * ppm)),
                      (w // 2 + round(0.12 * ppm), f + round(0.9 * ppm)), (70, 60, 50), -1)
    hx = f + round(0.07 * ppm) if rng.random() < 0.5 else w - f - round(0.07 * ppm)
    hy = h - round(1.0 * ppm)
    metal = (175, 175, 180)
    cv2.rectangle(img, (hx - 5, hy - 18), (hx + 5, hy + 18), metal, -1)
    cv2.line(img, (hx, hy), (hx + (20 if hx < w / 2 else -20), hy), metal, 5, cv2.LINE_AA)
    return _linear(img), (w_m, h_m)


def _light_panel(rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    w_m, h_m = (0.6, 0.6) if rng.random() < 0.6 else (1.2, 0.3)
    w, h = round(w_m * 200), round(h_m * 200)
    img = np.full((h, w, 3), 250, np.uint8)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (170, 170, 170), 4)
    return _linear(img), (w_m, h_m)


# ---------------------------------------------------------------------------------------------
# Geometry: room, camera pose, decal layout


def _room_planes(room: _Room, camera_pos: np.ndarray, rng: np.random.Generator,
                 sign_size: tuple[float, float]) -> list[_Plane]:
    """Back wall (the sign plane), left, right, front walls, floor, ceiling - a box around the camera."""
    cx, _, cz = camera_pos
    half_w = sign_size[0] / 2 + 0.3
    x_left = max(half_w, -cx + 0.5) + rng.uniform(0.1, 3.0)
    x_right = max(half_w, cx + 0.5) + rng.uniform(0.1, 3.0)
    z_front = cz - rng.uniform(0.5, 3.0)
    y_floor, y_ceil = room.sign_height, room.sign_height - room.ceiling_height
    ex, ey, ez = np.eye(3)
    return [
        _Plane(np.zeros(3), ex, ey, (-x_left, y_ceil, x_right, y_floor), "wall"),
        _Plane(-x_left * ex, ez, ey, (z_front, y_ceil, 0.0, y_floor), "wall"),
        _Plane(x_right * ex, -ez, ey, (0.0, y_ceil, -z_front, y_floor), "wall"),
        _Plane(z_front * ez, -ex, ey, (-x_right, y_ceil, x_left, y_floor), "wall"),
        _Plane(y_floor * ey, ex, -ez, (-x_left, 0.0, x_right, -z_front), "floor"),
        _Plane(y_ceil * ey, ex, ez, (-x_left, z_front, x_right, 0.0), "ceiling"),
    ]


def _look_at(camera_pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation (sign -> camera) of an upright camera at `camera_pos` looking at `target`."""
    z = target - camera_pos
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)  # camera x = down × forward, so the image stays upright
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _rotation_to(direction: np.ndarray) -> np.ndarray:
    """Smallest rotation taking the optical axis (0, 0, 1) onto unit `direction`."""
    axis = np.cross([0.0, 0.0, 1.0], direction)
    angle = math.atan2(np.linalg.norm(axis), direction[2])
    if angle < 1e-12:
        return np.eye(3)
    return cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0]


def _project(K: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) sign-frame points -> (N, 2) pixels and (N,) camera depths."""
    cam = points @ R.T + t
    return cam[:, :2] / cam[:, 2:] @ K[:2, :2].T + K[:2, 2], cam[:, 2]


def _sign_corners_m(size: tuple[float, float]) -> np.ndarray:
    w, h = size
    return np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])


def _draw_pose(rng: np.random.Generator, camera: Camera, look: _Look, room: _Room,
               sign_size: tuple[float, float], tries: int = 500) -> tuple[np.ndarray, np.ndarray, dict]:
    """Camera (R, t) in front of the sign, looking roughly at it, with the whole sign in the image.

    The off-axis angle is between the wall normal and the ray from the sign centre to the camera;
    the distance is solved so the sign's mean top/bottom edge length hits a drawn target width.
    """
    K, w, h = camera.K, camera.width, camera.height
    corners = _sign_corners_m(sign_size)
    scale = w / REFERENCE_WIDTH
    for attempt in range(tries):
        theta = math.radians(rng.uniform(*look.off_axis_deg))
        # Mostly sideways: a UAV flies at roughly the height of a door sign.
        psi = rng.normal(0, 0.35) + (0 if rng.random() < 0.5 else math.pi)
        direction = np.array([math.sin(theta) * math.cos(psi), math.sin(theta) * math.sin(psi), -math.cos(theta)])
        target_w = rng.uniform(*look.width_px) * scale
        spread = 0.7 * (1 - attempt / tries)  # how far off-centre the sign may sit, shrinking on retries
        aim = np.array([(rng.uniform(-1, 1) * spread + 1) * w / 2, (rng.uniform(-1, 1) * spread + 1) * h / 2, 1])
        ray = np.linalg.solve(K, aim)
        roll = math.radians(rng.uniform(-look.roll_deg, look.roll_deg))
        turn = cv2.Rodrigues(np.array([0, 0, roll]))[0] @ _rotation_to(ray / np.linalg.norm(ray)).T
        R = turn @ _look_at(direction, np.zeros(3))
        distance = K[0, 0] * sign_size[0] / target_w
        for _ in range(6):  # projected width ~ 1/distance; a few fixed-point steps converge
            t = -R @ (distance * direction)
            px, depth = _project(K, R, t, corners)
            if np.any(depth <= 0.05):
                break
            width_px = (np.linalg.norm(px[1] - px[0]) + np.linalg.norm(px[2] - px[3])) / 2
            distance *= width_px / target_w
        else:
            pos = distance * direction
            height = room.sign_height - pos[1]
            inside = np.all(px >= INSIDE_MARGIN_PX) and np.all(px <= [w - INSIDE_MARGIN_PX, h - INSIDE_MARGIN_PX])
            if inside and 0.4 <= height <= room.ceiling_height - 0.25:
                params = {"off_axis_deg": math.degrees(theta), "distance_m": distance,
                          "sign_width_px": float(width_px), "roll_deg": math.degrees(roll),
                          "camera_height_m": height}
                return R, t, params
    raise SynthError(f"no camera pose for look {look.mode!r} keeps the sign inside a {w}x{h} image")


def _raycast(planes: list[_Plane], K: np.ndarray, size: tuple[int, int], R: np.ndarray,
             camera_pos: np.ndarray) -> _Hits:
    """Nearest surface hit by each pixel's ray.

    `planes` are the faces of an axis-aligned box around the camera, so along each axis a ray can
    only reach the face its direction points to, and every ray hits something.
    """
    w, h = size
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    pix = np.stack([xs.ravel(), ys.ravel(), np.ones(w * h, np.float32)], -1)
    rays = pix @ (R.T @ np.linalg.inv(K)).T.astype(np.float32)  # sign-frame directions, camera depth 1
    dists, faces = [], []
    for axis in range(3):
        pos, neg = (next(i for i, p in enumerate(planes) if p.normal[axis] == s) for s in (1, -1))
        ahead = rays[:, axis] > 0
        wall = np.where(ahead, planes[pos].origin[axis], planes[neg].origin[axis]).astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            dists.append(np.abs((wall - np.float32(camera_pos[axis])) / rays[:, axis]))
        faces.append(np.where(ahead, pos, neg))
    nearest = np.argmin(np.stack(dists), axis=0)
    index = np.choose(nearest, faces).astype(np.int8)
    depth_all = np.choose(nearest, dists)
    surfaces = []
    for i, p in enumerate(planes):
        pixels = np.flatnonzero(index == i)
        ray, depth = rays[pixels], depth_all[pixels]
        points = camera_pos.astype(np.float32) + depth[:, None] * ray
        rel = points - p.origin.astype(np.float32)
        cos_inc = ray @ p.normal.astype(np.float32) / np.linalg.norm(ray, axis=1)
        surfaces.append(_Surface(pixels, rel @ p.a1.astype(np.float32), rel @ p.a2.astype(np.float32),
                                 points, depth, cos_inc))
    return _Hits(index.reshape(h, w), surfaces)


class _Layout:
    """Non-overlapping decal placement on the visible parts of the room's surfaces."""

    def __init__(self, planes: list[_Plane], coarse: _Hits, R: np.ndarray, t: np.ndarray,
                 rng: np.random.Generator):
        self.planes, self.R, self.t, self.rng = planes, R, t, rng
        self.taken: dict[int, list[tuple[float, float, float, float]]] = {i: [] for i in range(len(planes))}
        self.decals: list[_Decal] = []
        self.visible: dict[int, tuple[float, float, float, float, float]] = {}
        total = coarse.plane.size
        for i, (plane, seen) in enumerate(zip(planes, coarse.surfaces)):
            if len(seen.pixels) > 0.01 * total:
                u, v, b = seen.u, seen.v, plane.bounds
                # A little beyond the visible part, so decals can be cut by the image edge.
                self.visible[i] = (max(b[0], u.min() - 0.3), max(b[1], v.min() - 0.3),
                                   min(b[2], u.max() + 0.3), min(b[3], v.max() + 0.3), len(seen.pixels) / total)

    def walls(self) -> list[int]:
        return [i for i in self.visible if self.planes[i].texture == "wall"]

    def random_wall(self) -> int | None:
        walls = self.walls()
        if not walls:
            return None
        weights = np.array([self.visible[i][4] for i in walls])
        return int(self.rng.choice(walls, p=weights / weights.sum()))

    def free(self, plane: int, rect: tuple[float, float, float, float], margin: float) -> bool:
        u0, v0, u1, v1 = rect
        b = self.planes[plane].bounds
        if u0 < b[0] or v0 < b[1] - 1e-9 or u1 > b[2] or v1 > b[3] + 1e-9:
            return False
        for a0, b0, a1, b1 in self.taken[plane]:
            if u0 < a1 + margin and a0 < u1 + margin and v0 < b1 + margin and b0 < v1 + margin:
                return False
        p = self.planes[plane]
        pts = np.array([p.origin + u * p.a1 + v * p.a2 for u in (u0, u1) for v in (v0, v1)])
        # Decals straddling the camera plane would fold through infinity under a homography.
        return bool(np.all(pts @ self.R[2] + self.t[2] > 0.05))

    def add(self, plane: int, rect, albedo: np.ndarray, kind: str, emission: float = 0.0, margin: float = 0.05) -> bool:
        if not self.free(plane, rect, margin):
            return False
        self.taken[plane].append(tuple(rect))
        self.decals.append(_Decal(plane, tuple(rect), albedo, emission, kind))
        return True

    def scatter(self, plane: int | None, picture: tuple[np.ndarray, tuple[float, float]], kind: str,
                height: tuple[float, float], tries: int = 20) -> bool:
        """Place `picture` on `plane` (visible part) with its centre `height` m above the floor."""
        if plane is None or plane not in self.visible:
            return False
        albedo, (w, h) = picture
        u_lo, _, u_hi, _, _ = self.visible[plane]
        floor = self.planes[plane].bounds[3]
        for _ in range(tries):
            if u_hi - u_lo < w:
                return False
            u0 = self.rng.uniform(u_lo, u_hi - w)
            v0 = floor - self.rng.uniform(*height) - h / 2
            if self.add(plane, (u0, v0, u0 + w, v0 + h), albedo, kind):
                return True
        return False


def _draw_room(rng: np.random.Generator, sign_size: tuple[float, float]) -> tuple[_Room, tuple | None]:
    """Room heights, and the door of the room the sign marks (None: the sign hangs on bare wall)."""
    door = _door(rng) if rng.random() < 0.65 else None
    above_door = door is not None and rng.random() < 0.35
    if above_door:
        sign_height = door[1][1] + rng.uniform(0.05, 0.2) + sign_size[1] / 2
    else:
        sign_height = rng.uniform(1.3, 1.9)
    ceiling = max(sign_height + sign_size[1] / 2 + 0.3, rng.uniform(2.6, 3.3))
    return _Room(sign_height, ceiling, above_door), door


def _layout_clutter(layout: _Layout, rng: np.random.Generator, room: _Room, door: tuple | None,
                    sign_size: tuple[float, float], sign_shown: bool) -> None:
    """The sign's door, then doors, paper, boards, posters, plaques and switches, alike for positives and negatives."""
    sw, sh = sign_size
    floor = room.sign_height
    if door is not None:  # the sign marks a room: beside or above that room's door
        img, (dw, dh) = door
        if room.above_door:
            u0 = rng.uniform(-0.1, 0.1) - dw / 2
        else:
            gap = rng.uniform(0.1, 0.4)
            u0 = sw / 2 + gap if rng.random() < 0.5 else -sw / 2 - gap - dw
        layout.add(0, (u0, floor - dh, u0 + dw, floor), img, "door", margin=0.0)
    if sign_shown:
        # Clutter keeps a varying gap to the sign, sometimes tight enough to merge white blobs.
        gap = rng.uniform(0.0, 0.25)
        layout.taken[0].append((-sw / 2 - gap, -sh / 2 - gap, sw / 2 + gap, sh / 2 + gap))
    else:  # where a sign would hang: bare wall, another white plaque, or a sheet of paper
        spot = rng.choice(["bare", "plaque", "paper"], p=[0.35, 0.45, 0.2])
        picture = _latin_plaque(rng, sign_size) if spot == "plaque" else _paper(rng) if spot == "paper" else None
        if picture is not None:
            w, h = picture[1]
            layout.add(0, (-w / 2, -h / 2, w / 2, h / 2), picture[0], str(spot), margin=0.0)
    for plane in layout.walls():
        for _ in range(rng.integers(0, 3)):
            img, (dw, dh) = _door(rng)
            u_lo, _, u_hi, _, _ = layout.visible[plane]
            if u_hi - u_lo > dw:
                u0 = rng.uniform(u_lo, u_hi - dw)
                layout.add(plane, (u0, floor - dh, u0 + dw, floor), img, "door", margin=0.3)
    for _ in range(rng.integers(1, 5)):
        layout.scatter(layout.random_wall(), _paper(rng), "paper", (1.0, 1.8))
    for _ in range(rng.integers(0, 3)):
        layout.scatter(layout.random_wall(), _latin_plaque(rng), "plaque", (1.4, 2.2))
    if rng.random() < 0.35:
        board = _whiteboard(rng)
        layout.scatter(layout.random_wall(), board, "whiteboard", (1.3, 1.6))
    for _ in range(rng.integers(0, 3)):
        layout.scatter(layout.random_wall(), _poster(rng), "poster", (1.3, 1.8))
    for _ in range(rng.integers(0, 3)):
        layout.scatter(layout.random_wall(), _switch(rng), "switch", (1.05, 1.25))


def _lights(rng: np.random.Generator, planes: list[_Plane], layout: _Layout, look: _Look,
            sign_size: tuple[float, float]) -> tuple[list[tuple[np.ndarray, float]], float]:
    """Point lights under ceiling light panels (panels drawn as emissive decals), plus ambient level."""
    ceiling = planes[5]
    x_lo, z_lo, x_hi, z_hi = ceiling.bounds
    lights = []
    for _ in range(rng.integers(1, 4)):
        picture, (w, h) = _light_panel(rng)
        # In a narrow room the panel may not fit (layout.add then skips it); its light still shines.
        x = rng.uniform(x_lo + w / 2, max(x_lo, x_hi - w / 2))
        z = rng.uniform(z_lo + h / 2, max(z_lo, min(z_hi - h / 2, -0.3)))
        pos = ceiling.origin + np.array([x, 0.15, z])
        r2 = float(pos @ pos)  # squared distance to the sign centre: each light gives it similar light
        lights.append((pos, rng.uniform(0.5, 1.5) * r2))
        layout.add(5, (x - w / 2, z - h / 2, x + w / 2, z + h / 2), picture, "light", emission=rng.uniform(4, 8))
    if look.side_lamp:
        side = 1 if rng.random() < 0.5 else -1
        pos = np.array([side * rng.uniform(0.4, 0.9) * sign_size[0] * 2, rng.uniform(-0.4, 0.4),
                        -rng.uniform(0.15, 0.4)])
        lights.append((pos, rng.uniform(2, 4) * float(pos @ pos)))
    return lights, rng.uniform(0.15, 0.6)


# ---------------------------------------------------------------------------------------------
# Rendering


def _composite(albedo: np.ndarray, emission: np.ndarray, hits: _Hits, decal: _Decal, planes: list[_Plane],
               K: np.ndarray, R: np.ndarray, t: np.ndarray) -> None:
    """Warp `decal` into `albedo`/`emission` (in place) where its plane is the visible surface."""
    img = decal.albedo
    h_img, w_img = img.shape[:2]
    u0, v0, u1, v1 = decal.rect
    to_plane = np.array([[(u1 - u0) / w_img, 0, u0], [0, (v1 - v0) / h_img, v0], [0, 0, 1]])
    H = planes[decal.plane].homography(K, R, t) @ to_plane
    corners = np.array([[0, 0, 1], [w_img, 0, 1], [w_img, h_img, 1], [0, h_img, 1]], float) @ H.T
    if np.any(corners[:, 2] <= 0):
        return
    px = corners[:, :2] / corners[:, 2:]
    height, width = albedo.shape[:2]
    x0, y0 = np.floor(np.clip(px.min(0) - 1, 0, [width, height])).astype(int)
    x1, y1 = np.ceil(np.clip(px.max(0) + 2, 0, [width, height])).astype(int)
    if x1 <= x0 or y1 <= y0:
        return
    # The picture's pixel i spans [i, i + 1], as its corners above say; warpPerspective samples pixel
    # centres at whole coordinates, so its pixel i goes where H takes i + 0.5. Without the half pixel
    # every picture was drawn half a pixel of it up and left of its true corners.
    H = H @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    # Shrink big pictures with INTER_AREA first: warpPerspective's bilinear lookup would alias.
    edge_x = max(np.linalg.norm(px[1] - px[0]), np.linalg.norm(px[2] - px[3]))
    edge_y = max(np.linalg.norm(px[3] - px[0]), np.linalg.norm(px[2] - px[1]))
    sx, sy = min(1.0, edge_x / w_img), min(1.0, edge_y / h_img)
    if sx < 0.8 or sy < 0.8:
        w_s, h_s = max(2, round(w_img * sx)), max(2, round(h_img * sy))
        img = cv2.resize(img, (w_s, h_s), interpolation=cv2.INTER_AREA)
        H = H @ resize_map(w_img / w_s, h_img / h_s)  # the resized picture's px -> the original's
    H_roi = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]]) @ H
    size = (int(x1 - x0), int(y1 - y0))
    # Zero borders make the warped picture premultiplied by its coverage: anti-aliased edges. Weighed by
    # its coverage once more, each rim pixel held the square of its share and every picture was drawn
    # shrunk by a few tenths of a pixel.
    warped = cv2.warpPerspective(img, H_roi, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    cover = cv2.warpPerspective(np.ones(img.shape[:2], np.float32), H_roi, size, flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT)
    seen = (hits.plane[y0:y1, x0:x1] == decal.plane).astype(np.float32)
    cover *= seen
    roi = albedo[y0:y1, x0:x1]
    roi *= 1 - cover[..., None]
    roi += warped * seen[..., None]
    emission[y0:y1, x0:x1] = emission[y0:y1, x0:x1] * (1 - cover) + decal.emission * cover


def _render_radiance(planes: list[_Plane], textures: dict[str, list[np.ndarray]], decals: list[_Decal],
                     lights: list[tuple[np.ndarray, float]], ambient: float, skirting: tuple[float, np.ndarray],
                     K: np.ndarray, size: tuple[int, int], R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(h, w, 3) float32 linear radiance seen by camera K of `size` (w, h)."""
    camera_pos = -R.T @ t
    hits = _raycast(planes, K, size, R, camera_pos)
    h, w = hits.plane.shape
    albedo = np.zeros((h * w, 3), np.float32)
    irradiance = np.zeros(h * w, np.float32)
    skirting_h, skirting_color = skirting
    for plane, hit in zip(planes, hits.surfaces):
        if not len(hit.pixels):
            continue
        texels = hit.depth / K[0, 0] / np.sqrt(np.maximum(hit.cos_incidence, 0.05)) * TEX_PX_PER_M
        surface = _sample_texture(textures[plane.texture], hit.u, hit.v, texels)
        if plane.texture == "wall":
            surface[hit.v > plane.bounds[3] - skirting_h] = skirting_color
        albedo[hit.pixels] = surface
        facing = -plane.normal.astype(np.float32)  # normal into the room
        light = np.zeros(len(hit.pixels), np.float32)
        for pos, power in lights:
            to_light = pos.astype(np.float32) - hit.points
            r2 = np.maximum(np.einsum("nk,nk->n", to_light, to_light), 0.05)
            light += power * np.maximum(to_light @ facing, 0) / (r2 * np.sqrt(r2))
        # Corners and edges of a room get less indirect light; a cheap stand-in for ambient occlusion.
        u0, v0, u1, v1 = plane.bounds
        edge = np.maximum(np.minimum(np.minimum(hit.u - u0, u1 - hit.u), np.minimum(hit.v - v0, v1 - hit.v)), 0)
        irradiance[hit.pixels] = light + ambient * (1 - 0.4 * np.exp(-edge / 0.25))
    albedo = albedo.reshape(h, w, 3)
    emission = np.zeros((h, w), np.float32)
    for decal in decals:
        _composite(albedo, emission, hits, decal, planes, K, R, t)
    irradiance = irradiance.reshape(h, w)
    return (albedo * (irradiance + emission)[..., None]).astype(np.float32)


def _develop(radiance: np.ndarray, look: _Look, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Linear radiance (h, w, 3) -> BGR uint8 as a small camera records it, and the drawn parameters."""
    h, w = radiance.shape[:2]
    img = radiance * (1 + rng.normal(0, 0.04, 3)).astype(np.float32)  # white balance error
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xs - w / 2) ** 2 + (ys - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    vignette = rng.uniform(0.1, 0.45)
    img *= (1 - vignette * r2)[..., None]
    brightness = rng.uniform(*look.brightness)
    img *= brightness**2.2 / max(float(img.mean()), 1e-6)  # auto exposure on the mean level
    blur = rng.uniform(*look.blur_sigma)
    motion = 0.0
    if look.motion_px[1] > 0 and rng.random() < 0.5:  # blurred look: camera shake or defocus
        motion, blur = rng.uniform(*look.motion_px), rng.uniform(0, 0.6)
        length = int(math.ceil(motion)) | 1
        kernel = np.zeros((length, length), np.float32)
        angle = rng.uniform(0, math.pi)
        d = (motion - 1) / 2 * np.array([math.cos(angle), math.sin(angle)])
        c = length // 2
        cv2.line(kernel, (round(c - d[0]), round(c - d[1])), (round(c + d[0]), round(c + d[1])), 1.0, 1, cv2.LINE_AA)
        img = cv2.filter2D(img, -1, kernel / kernel.sum())
    if blur > 0.2:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    display = np.clip(img, 0, 1) ** (1 / 2.2)
    noise = rng.uniform(*look.noise) / 255
    # Shot noise grows with the signal; a shared luminance part plus weaker colour noise.
    sigma = noise * np.sqrt((display + 0.05) / 0.55)
    display = display + sigma * (rng.standard_normal((h, w, 1)) + 0.5 * rng.standard_normal((h, w, 3)))
    image = np.clip(display * 255 + 0.5, 0, 255).astype(np.uint8)
    return image, {"brightness": brightness, "vignette": vignette, "blur_sigma_px": blur, "motion_blur_px": motion,
                   "noise_levels": noise * 255}


def synthetic_camera(size: tuple[int, int] = (640, 480)) -> Camera:
    """The default synthetic camera: distortion-free, 60° horizontal field of view."""
    assumed = assumed_camera(*size)
    return Camera(assumed.K, assumed.dist, assumed.width, assumed.height, "synthetic")


def render_scene(library: Library, sign_id: str | None, camera: Camera, rng: np.random.Generator,
                 category: str) -> Scene:
    """One scene of `category` (of ALL_CATEGORIES); `sign_id` is the sign shown (positives) or None (negatives)."""
    if category not in ALL_CATEGORIES:
        raise SynthError(f"category must be one of {', '.join(ALL_CATEGORIES)}; got {category!r}")
    if (category == "negative") != (sign_id is None):
        raise SynthError("negatives show no sign (sign_id None); easy, hard and steep scenes need a sign_id")
    if camera.width is None or camera.height is None:
        raise SynthError("the camera needs an image width and height to render")
    if camera.has_distortion:
        raise SynthError("synthetic scenes are rendered with a distortion-free camera")
    sign: LibrarySign = library[sign_id] if sign_id else library.signs[rng.integers(len(library.signs))]
    sign_size = (sign.width_m, sign.height_m)
    if category == "hard" or (category == "negative" and rng.random() < 0.4):
        look = LOOKS[str(rng.choice(HARD_MODES))]
    elif category == "steep":
        look = LOOKS["steep"]
    else:
        look = LOOKS["easy"]

    room, door = _draw_room(rng, sign_size)
    R, t, pose_params = _draw_pose(rng, camera, look, room, sign_size)
    planes = _room_planes(room, -R.T @ t, rng, sign_size)

    K = camera.K
    coarse_K = np.diag([1 / 8, 1 / 8, 1]) @ K
    coarse = _raycast(planes, coarse_K, (camera.width // 8, camera.height // 8), R, -R.T @ t)
    layout = _Layout(planes, coarse, R, t, rng)
    _layout_clutter(layout, rng, room, door, sign_size, sign_shown=sign_id is not None)
    lights, ambient = _lights(rng, planes, layout, look, sign_size)
    decals = layout.decals
    if sign_id is not None:
        plaque = _linear(_srgb(rng, (0.88, 0.97), (0.0, 0.06)))
        ink = _linear(_srgb(rng, (0.05, 0.2), (0.0, 0.3)))
        coverage = (sign.image.astype(np.float32) / 255)[..., None]
        w, h = sign_size
        decals = decals + [_Decal(0, (-w / 2, -h / 2, w / 2, h / 2), ink + (plaque - ink) * coverage, 0.0, "sign")]

    surfaces = {"wall": _wall_texture(rng, look.wall_max), "floor": _floor_texture(rng),
                "ceiling": _ceiling_texture(rng)}
    textures = {name: _mipmap(texture) for name, (_, texture) in surfaces.items()}
    skirting = (rng.uniform(0.06, 0.15), _linear(_srgb(rng, (0.1, 0.9), (0.0, 0.4))))
    # Output pixel i averages supersampled pixels SUPERSAMPLE·i ... SUPERSAMPLE·i + SUPERSAMPLE - 1 (INTER_AREA).
    offset = (SUPERSAMPLE - 1) / 2
    supersample = np.array([[SUPERSAMPLE, 0, offset], [0, SUPERSAMPLE, offset], [0, 0, 1]])
    big = (camera.width * SUPERSAMPLE, camera.height * SUPERSAMPLE)
    radiance = _render_radiance(planes, textures, decals, lights, ambient, skirting, supersample @ K, big, R, t)
    radiance = cv2.resize(radiance, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    image, develop_params = _develop(radiance, look, rng)
    quality = int(rng.integers(look.jpeg_quality[0], look.jpeg_quality[1] + 1))
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)

    params = {"look": look.mode, **pose_params, **develop_params, "jpeg_quality": quality,
              **{name: kind for name, (kind, _) in surfaces.items()},
              "sign_above_door": room.above_door, "clutter": sorted(d.kind for d in layout.decals)}
    params = {k: round(float(v), 4) if isinstance(v, float) else v for k, v in params.items()}
    if sign_id is None:
        for key in ("off_axis_deg", "distance_m", "sign_width_px", "roll_deg"):
            params.pop(key)
        return Scene(image, jpeg, None, category, None, None, None, None, params)
    H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ sign.pixel_to_metric
    H /= H[2, 2]
    corners = cv2.perspectiveTransform(sign.corners_px.reshape(-1, 1, 2), H).reshape(4, 2)
    return Scene(image, jpeg, sign_id, category, R, t, H, corners, params)


def _plan(library: Library, n: int, categories: Sequence[str], weights: Sequence[float],
          rng: np.random.Generator) -> list[tuple[str, str | None]]:
    """(category, sign id) per scene: category counts by largest remainder, signs in turn, shuffled.

    Exact proportions rather than independent draws keep small sets (and benchmarks) balanced.
    """
    w = np.asarray(weights, float) / np.sum(weights)
    counts = np.floor(w * n).astype(int)
    for i in np.argsort(-(w * n - counts), kind="stable")[: n - counts.sum()]:
        counts[i] += 1
    plan: list[tuple[str, str | None]] = []
    turn = int(rng.integers(len(library.ids)))
    for category, count in zip(categories, counts):
        for _ in range(count):
            sign_id = None
            if category != "negative":
                sign_id = library.ids[turn % len(library.ids)]
                turn += 1
            plan.append((category, sign_id))
    return [plan[i] for i in rng.permutation(len(plan))]


def generate_dataset(out_dir: str | Path, library: Library, n: int, seed: int, camera: Camera | None = None,
                     categories: Sequence[str] = CATEGORIES, weights: Sequence[float] | None = None,
                     size: tuple[int, int] = (640, 480),
                     progress: Callable[[int, int], None] | None = None) -> dict[str, dict]:
    """Render `n` scenes into `out_dir` as scene_000.jpg..., plus `camera.yaml` and `truth.json`.

    `weights` (default DEFAULT_WEIGHTS) align with `categories`; the camera defaults to the
    synthetic camera of `size` (w, h) px. `progress(done, n)` is called after each scene.
    Returns truth.json's "images" mapping, file name -> truth entry. The same seed gives the
    same files.
    """
    unknown = set(categories) - set(ALL_CATEGORIES)
    if unknown or not categories:
        raise SynthError(f"categories must be among {', '.join(ALL_CATEGORIES)}; got {list(categories)}")
    weights = [DEFAULT_WEIGHTS[c] for c in categories] if weights is None else list(weights)
    if len(weights) != len(categories) or min(weights) < 0 or sum(weights) <= 0:
        raise SynthError("weights must be one non-negative number per category, not all zero")
    if n < 1:
        raise SynthError(f"n must be at least 1; got {n}")
    camera = camera or synthetic_camera(size)
    out = Path(out_dir)
    digits = max(3, len(str(n - 1)))
    names = [f"scene_{i:0{digits}d}.jpg" for i in range(n)]
    # Scenes of an earlier run that this one would not overwrite would sit beside truth.json unlisted,
    # and they may be someone's data: refuse rather than delete them.
    stale = sorted({p.name for p in out.glob("scene_*.jpg")} - set(names))
    if stale:
        listed = ", ".join(stale[:3]) + (", ..." if len(stale) > 3 else "")
        raise SynthError(f"{out} already holds {len(stale)} scene file(s) that truth.json would not list ({listed}); "
                         "pick an empty folder or remove them")
    out.mkdir(parents=True, exist_ok=True)
    seeds = np.random.SeedSequence(seed)
    plan = _plan(library, n, categories, weights, np.random.default_rng(seeds.spawn(1)[0]))
    images: dict[str, dict] = {}
    # One child seed per scene, so a scene can be re-rendered alone from (seed, index).
    for i, ((category, sign_id), scene_seed, name) in enumerate(zip(plan, seeds.spawn(n), names)):
        scene = render_scene(library, sign_id, camera, np.random.default_rng(scene_seed), category)
        (out / name).write_bytes(scene.jpeg)
        images[name] = scene.truth()
        if progress:
            progress(i + 1, n)
    save_camera(camera, out / "camera.yaml", name="synthetic")
    truth = {"camera": "camera.yaml", "seed": seed, "images": images}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    return images
