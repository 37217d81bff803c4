"""A second synthetic test world: library signs printed on paper and pasted into real photographs.

It shares nothing with `pipeline.synth`'s rooms but the library and the camera types, so that
defaults tuned on either world alone show it on the other. A scene is a real photograph (from
folders the caller names; the project holds none) cropped and scaled at random, white cards of
Latin print and, for dim views, lamps and windows pasted on it, and one printed plaque: a library
sign, a look-alike plaque of other words (`decoys`) or none. The plaque is a plane turned by yaw
and pitch in front of the camera, anywhere in the frame, from about 40 to 250 px wide.

Print: paper tint, ink colour and ink spread; glossy paper reflects a lamp on one side.
Light: a brightness of its own for the plaque (dim ones in clutter), a gradient across it, a
cast shadow with a soft edge across sign and wall, vignetting and a colour cast.
Camera (`photo_world_camera`): a 70 degree lens with barrel distortion and an off-centre
principal point (its camera.yaml says so), defocus, motion or Gaussian blur, Poisson-Gaussian
sensor noise, a gamma of 1.8-2.6 and JPEG at quality 45-95.

Scenes are `pipeline.synth.Scene` records, the truth `pipeline.evaluate.load_dataset` reads; nothing
of synth's rendering is used. Ground truth, for the distorted image the camera records: X_cam = R·X_sign + t (sign frame,
metres); `corners` (4, 2) image px TL, TR, BR, BL, the sign's corners through the lens; `H`
(3, 3) library px -> image px through those corners (under distortion no homography is exact).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from signpose.pipeline.camera import Camera, save_camera
from signpose.pipeline.library import Library, LibrarySign
from signpose.pipeline.synth import Scene

CATEGORIES = ("easy", "hard", "steep", "negative")
HARD_LOOKS = ("small", "dim", "shadow", "glare", "blurred", "oblique")
NEGATIVE_LOOKS = ("look-alike", "no sign")
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg")
SUPERSAMPLE = 2  # the scene is composed at twice the output size and shrunk (anti-aliasing)
EDGE_MARGIN_PX = 4  # a positive's corners stay this far inside the image
HFOV_DEG = 70.0
# k1, k2, p1, p2: a mild barrel lens, moving the frame's corners about 5 % inwards at 640 x 480
DISTORTION = (-0.12, 0.03, 0.0, 0.0)


class PhotoWorldError(ValueError):
    """Scene parameters or backgrounds that cannot be used; the message says which and why."""


@dataclass(frozen=True)
class View:
    """How a plaque is seen in one look: the angle between its normal and the ray to it
    (degrees), its projected width (px at 640 px across, the wider of its top and bottom
    edges) and the roll (degrees either way)."""

    off_axis_deg: tuple[float, float]
    width_px: tuple[float, float]
    roll_deg: float


VIEWS = {
    "easy": View((0, 30), (110, 250), 8),
    "small": View((0, 35), (40, 80), 12),
    "dim": View((0, 40), (70, 220), 15),
    "shadow": View((0, 40), (80, 250), 15),
    "glare": View((0, 40), (90, 250), 15),
    "blurred": View((0, 40), (90, 250), 15),
    "oblique": View((40, 60), (90, 250), 15),
    "steep": View((60, 75), (70, 200), 10),
}


def photo_world_camera(size: tuple[int, int] = (640, 480)) -> Camera:
    """The world's camera for (w, h) px images: HFOV_DEG across, the principal point 1 % off
    centre, DISTORTION."""
    w, h = size
    f = w / 2 / math.tan(math.radians(HFOV_DEG) / 2)
    K = np.array([[f, 0, w / 2 + 0.01 * w], [0, f, h / 2 - 0.01 * h], [0, 0, 1]])
    return Camera(K, np.array(DISTORTION, float), w, h, "photo world")


def background_photos(folders: Sequence[str | Path]) -> list[Path]:
    """The photos (PHOTO_SUFFIXES) directly in `folders`, sorted; PhotoWorldError without any."""
    photos = sorted(p for folder in folders if Path(folder).is_dir() for p in Path(folder).iterdir()
                    if p.suffix.lower() in PHOTO_SUFFIXES)
    if not photos:
        raise PhotoWorldError(f"no photos ({', '.join(PHOTO_SUFFIXES)}) in {', '.join(map(str, folders))}: "
                              "name folders of real photographs to paste the signs into")
    return photos


@functools.lru_cache(maxsize=32)
def _photo(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise PhotoWorldError(f"cannot read the background photo {path}")
    return image


def _linear(srgb: np.ndarray) -> np.ndarray:
    """uint8 sRGB-ish values -> float32 linear reflectance in [0, 1]."""
    return (np.asarray(srgb, np.float32) / 255.0) ** 2.2


def _background(rng: np.random.Generator, photos: Sequence[Path], size: tuple[int, int]) -> tuple[np.ndarray, str]:
    """(h, w, 3) float32 linear: a random crop of one of `photos`, at least 40 % of its side,
    maybe mirrored, scaled to `size` (w, h); and the photo's name."""
    path = photos[int(rng.integers(len(photos)))]
    photo = _photo(path)
    ph, pw = photo.shape[:2]
    w, h = size
    side = min(pw / w, ph / h) * rng.uniform(0.4, 1.0)  # photo px per output px
    cw, ch = int(w * side), int(h * side)
    x0, y0 = int(rng.integers(0, pw - cw + 1)), int(rng.integers(0, ph - ch + 1))
    crop = cv2.resize(photo[y0:y0 + ch, x0:x0 + cw], size, interpolation=cv2.INTER_AREA if side > 1
                      else cv2.INTER_LINEAR)
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    return _linear(crop), path.name


def _pose(rng: np.random.Generator, K: np.ndarray, size: tuple[int, int], sign: LibrarySign,
          view: View) -> tuple[np.ndarray, np.ndarray, dict]:
    """(R, t, params) of a plaque turned `view`-wise somewhere in the (w, h) frame, its ideal
    (undistorted) corners at least EDGE_MARGIN_PX inside it."""
    w, h = size
    half = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [sign.width_m / 2, sign.height_m / 2, 0]
    for attempt in range(400):
        off_axis = math.radians(rng.uniform(*view.off_axis_deg))
        # mostly turned about the vertical: a camera at about the sign's height
        azimuth = rng.normal(0, 0.3) + (0 if rng.random() < 0.5 else math.pi)
        normal_turn = off_axis * np.array([math.cos(azimuth), math.sin(azimuth)])
        roll = math.radians(rng.uniform(-view.roll_deg, view.roll_deg))
        spread = 0.8 * (1 - attempt / 400)
        pixel = np.array([w / 2 * (1 + spread * rng.uniform(-1, 1)), h / 2 * (1 + spread * rng.uniform(-1, 1)), 1])
        ray = np.linalg.solve(K, pixel)
        ray /= np.linalg.norm(ray)
        # the plaque faces the ray to it, then turns off it by `off_axis`
        facing = _aligning(np.array([0.0, 0.0, 1.0]), ray)
        R = facing @ cv2.Rodrigues(np.array([normal_turn[1], -normal_turn[0], roll]))[0]
        target = rng.uniform(*view.width_px) * w / 640
        depth = K[0, 0] * sign.width_m / target
        for _ in range(5):  # the projected width goes nearly as 1 / depth
            t = ray * depth
            cam = half @ R.T + t
            if np.any(cam[:, 2] <= 0.05):
                break
            px = cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
            width = max(np.linalg.norm(px[1] - px[0]), np.linalg.norm(px[2] - px[3]))
            depth *= width / target
        else:
            if np.all(px >= EDGE_MARGIN_PX) and np.all(px <= [w - EDGE_MARGIN_PX, h - EDGE_MARGIN_PX]):
                seen = math.degrees(math.acos(abs(float(R[:, 2] @ ray))))
                return R, t, {"off_axis_deg": seen, "distance_m": float(np.linalg.norm(t)), "roll_deg": math.degrees(roll)}
    raise PhotoWorldError(f"no pose keeps a {view.width_px} px plaque inside a {w}x{h} image")


def _aligning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector `a` to unit vector `b`."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    return np.eye(3) if s < 1e-12 else cv2.Rodrigues(axis / s * math.atan2(s, c))[0]


def _print(rng: np.random.Generator, image: np.ndarray) -> np.ndarray:
    """(h, w, 3) float32 linear reflectance of the gray plaque `image` printed: paper tint, ink
    colour and ink spread (dilated or thinned by up to 2 library px)."""
    spread = int(rng.integers(-2, 3))
    if spread:
        kernel = np.ones((abs(spread) * 2 + 1,) * 2, np.uint8)
        image = cv2.erode(image, kernel) if spread > 0 else cv2.dilate(image, kernel)
    paper = rng.uniform(0.72, 0.9) * (1 + rng.normal(0, 0.03, 3))
    ink = rng.uniform(0.01, 0.08) * (1 + rng.normal(0, 0.3, 3)).clip(0.3)
    coverage = (image.astype(np.float32) / 255)[..., None]
    return (ink + (paper - ink) * coverage).astype(np.float32)


def _latin_card(rng: np.random.Generator) -> np.ndarray:
    """(h, w) uint8: a white card or sheet of Latin print, a plaque-like object of no sign."""
    w = int(rng.integers(300, 700))
    h = int(w * rng.uniform(0.3, 1.4))
    card = np.full((h, w), int(rng.integers(225, 255)), np.uint8)
    words = ("EXIT", "ROOM 12", "PRIVATE", "NOTICE", "OPEN", "PUSH", "LAB", "B-204", "WAY OUT", "STAFF")
    lines = int(rng.integers(0, 5))
    for i in range(lines):
        text = str(rng.choice(words))
        scale = rng.uniform(0.8, 2.5) * w / 600
        y = int(h * (i + 1) / (lines + 1))
        cv2.putText(card, text, (int(w * rng.uniform(0.05, 0.3)), y), int(rng.choice([0, 2, 3])), scale,
                    int(rng.integers(0, 90)), max(1, int(scale * 2)), cv2.LINE_AA)
    return card


def _paste(canvas: np.ndarray, albedo: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Warp `albedo` (h, w, C) through H (its px -> canvas px) onto `canvas` (in place),
    anti-aliased; returns the (H, W) float32 coverage."""
    hc, wc = canvas.shape[:2]
    corners = cv2.perspectiveTransform(np.array([[[0, 0], [albedo.shape[1], 0], [albedo.shape[1], albedo.shape[0]],
                                                  [0, albedo.shape[0]]]], np.float64), H)[0]
    across = max(np.linalg.norm(corners[1] - corners[0]), np.linalg.norm(corners[2] - corners[3]))
    shrink = min(1.0, 1.5 * across / albedo.shape[1])
    if shrink < 1.0:  # warpPerspective's bilinear lookup would alias a far larger picture
        small = cv2.resize(albedo, None, fx=shrink, fy=shrink, interpolation=cv2.INTER_AREA)
        sx, sy = albedo.shape[1] / small.shape[1], albedo.shape[0] / small.shape[0]
        H = H @ np.diag([sx, sy, 1.0])  # the shrunk picture's edges are the picture's
        albedo = small
    # library pixel i spans [i, i + 1]: its centre, where warpPerspective samples it, is i + 0.5
    H = H @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    warped = cv2.warpPerspective(albedo, H, (wc, hc), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    cover = cv2.warpPerspective(np.ones(albedo.shape[:2], np.float32), H, (wc, hc), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT)
    if warped.ndim == 2:
        warped = warped[..., None]
    canvas *= 1 - cover[..., None]
    canvas += warped
    return cover


def _clutter(rng: np.random.Generator, canvas: np.ndarray, lamps: bool, keep_out: np.ndarray | None) -> list[str]:
    """Paste 0-3 cards of Latin print and, with `lamps`, 1-3 lamps or windows brighter than any
    paper (they set the image's maximum) onto the linear `canvas` (in place), none over the
    `keep_out` quad ((4, 2) canvas px, the plaque's, or None); returns their kinds."""
    hc, wc = canvas.shape[:2]
    kinds = []
    for _ in range(int(rng.integers(0, 4))):
        card = _latin_card(rng)
        width = rng.uniform(0.08, 0.3) * wc
        quad = _random_quad(rng, wc, hc, width, width * card.shape[0] / card.shape[1])
        if keep_out is not None and _overlap(quad, keep_out):
            continue
        ch, cw = card.shape
        H = cv2.getPerspectiveTransform(np.array([[0, 0], [cw, 0], [cw, ch], [0, ch]], np.float32), quad)
        _paste(canvas, np.repeat(_linear(card)[..., None] * rng.uniform(0.6, 1.0), 3, axis=2), H)
        kinds.append("card")
    for _ in range(int(rng.integers(1, 4)) if lamps else 0):
        centre = (int(rng.uniform(0, wc)), int(rng.uniform(0, hc)))
        axes = (int(rng.uniform(0.03, 0.12) * wc), int(rng.uniform(0.02, 0.1) * wc))
        extent = np.array([[centre[0] - axes[0], centre[1] - axes[1]], [centre[0] + axes[0], centre[1] + axes[1]]])
        if keep_out is not None and _overlap(extent, keep_out):
            continue
        glow = np.zeros((hc, wc), np.float32)
        if rng.random() < 0.5:
            cv2.ellipse(glow, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1, cv2.LINE_AA)
            kinds.append("lamp")
        else:
            cv2.rectangle(glow, (centre[0] - axes[0], centre[1] - axes[1]), (centre[0] + axes[0], centre[1] + axes[1]),
                          1.0, -1, cv2.LINE_AA)
            kinds.append("window")
        canvas += (cv2.GaussianBlur(glow, (0, 0), 3) * rng.uniform(2.0, 5.0))[..., None]
    return kinds


def _overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.1) -> bool:
    """Whether the bounding boxes of quads `a` and `b` (4, 2), `b`'s grown by `margin` of its size, overlap."""
    grow = margin * np.ptp(b, axis=0)
    return bool(np.all(a.min(axis=0) < b.max(axis=0) + grow) and np.all(b.min(axis=0) - grow < a.max(axis=0)))


def _random_quad(rng: np.random.Generator, w: int, h: int, qw: float, qh: float) -> np.ndarray:
    """(4, 2) float32 corners TL, TR, BR, BL of a qw x qh px rectangle anywhere in a w x h frame,
    its corners jittered by up to 10 % (a little perspective)."""
    x, y = rng.uniform(-0.1 * qw, w - 0.9 * qw), rng.uniform(-0.1 * qh, h - 0.9 * qh)
    rect = np.array([[x, y], [x + qw, y], [x + qw, y + qh], [x, y + qh]])
    return (rect + rng.uniform(-0.1, 0.1, (4, 2)) * [qw, qh]).astype(np.float32)


def _light(rng: np.random.Generator, look: str, size: tuple[int, int], quad: np.ndarray | None) -> tuple[np.ndarray, dict]:
    """(h, w) float32 light multiplying the whole scene, given the plaque's `quad` (4, 2) px (or
    None): a gradient across the plaque, a cast shadow with a soft edge, vignetting."""
    w, h = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    light = np.ones((h, w), np.float32)
    centre = quad.mean(axis=0) if quad is not None else np.array([rng.uniform(0, w), rng.uniform(0, h)])
    extent = float(np.ptp(quad[:, 0])) if quad is not None else w / 4
    angle = rng.uniform(0, 2 * math.pi)
    along = ((xs - centre[0]) * math.cos(angle) + (ys - centre[1]) * math.sin(angle)) / max(extent, 1.0)
    ramp = rng.uniform(1.5, 3.0) if look in ("shadow", "glare") else rng.uniform(1.0, 1.4)
    light *= np.clip(1 + (ramp - 1) * (along + 0.5), 1 / ramp, ramp) / math.sqrt(ramp)  # ratio `ramp` across it
    shadow = 1.0
    if look == "shadow" or rng.random() < 0.15:
        # a straight shadow edge through the plaque, softened by 0.5-4 px of penumbra
        cut = rng.uniform(-0.3, 0.3)
        side = ((xs - centre[0]) * math.cos(angle + 1.2) + (ys - centre[1]) * math.sin(angle + 1.2)) / max(extent, 1.0)
        shadow = rng.uniform(0.25, 0.6)
        soft = rng.uniform(0.5, 4.0) / max(extent, 1.0)
        light *= shadow + (1 - shadow) / (1 + np.exp(-(side - cut) / soft))
    r2 = ((xs - w / 2) ** 2 + (ys - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    vignette = rng.uniform(0.1, 0.5)
    light *= 1 - vignette * r2
    return light, {"light_ratio": ramp, "shadow": shadow, "vignette": vignette}


def _blur(rng: np.random.Generator, image: np.ndarray, look: str) -> tuple[np.ndarray, dict]:
    """`image` through the lens's and the hand's blur: for the blurred look a defocus disc of
    radius 1.5-3.5 px or a motion streak of 4-12 px, else a Gaussian of at most 0.8 px."""
    if look == "blurred":
        if rng.random() < 0.5:
            radius = rng.uniform(1.5, 3.5)
            n = int(math.ceil(radius)) * 2 + 1
            disc = np.zeros((n, n), np.float32)
            cv2.circle(disc, (n // 2 * 16, n // 2 * 16), int(radius * 16), 1.0, -1, cv2.LINE_AA, 4)
            return cv2.filter2D(image, -1, disc / disc.sum()), {"defocus_px": radius}
        length = rng.uniform(4, 12)
        n = int(math.ceil(length)) | 1
        streak = np.zeros((n, n), np.float32)
        angle = rng.uniform(0, math.pi)
        d = (length - 1) / 2 * np.array([math.cos(angle), math.sin(angle)]) * 16
        c = n // 2 * 16
        cv2.line(streak, (int(c - d[0]), int(c - d[1])), (int(c + d[0]), int(c + d[1])), 1.0, 1, cv2.LINE_AA, 4)
        return cv2.filter2D(image, -1, streak / streak.sum()), {"motion_px": length}
    sigma = rng.uniform(0, 0.8)
    return (cv2.GaussianBlur(image, (0, 0), sigma) if sigma > 0.2 else image), {"blur_sigma_px": sigma}


@functools.lru_cache(maxsize=4)
def _lens_maps(K_bytes: bytes, dist_bytes: bytes, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel of the distorted image, where its ray meets the ideal pinhole image."""
    K, dist = np.frombuffer(K_bytes).reshape(3, 3), np.frombuffer(dist_bytes)
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    ideal = cv2.undistortPoints(grid, K, dist, P=K).reshape(h, w, 2).astype(np.float32)
    return ideal[..., 0], ideal[..., 1]


def _record(rng: np.random.Generator, linear: np.ndarray, look: str) -> tuple[np.ndarray, dict]:
    """Linear radiance (h, w, 3) -> BGR uint8 as the camera records it: auto exposure,
    Poisson-Gaussian noise, gamma, saturation."""
    exposure = rng.uniform(0.3, 0.5) ** 2.2 / max(float(linear.mean()), 1e-6)
    image = linear * exposure
    shot = rng.uniform(0.0005, 0.004) * (2 if look in ("dim", "blurred") else 1)
    read = rng.uniform(0.0005, 0.003)
    image = image + np.sqrt(np.maximum(image, 0) * shot + read**2) * rng.standard_normal(image.shape).astype(np.float32)
    gamma = rng.uniform(1.8, 2.6)
    display = np.clip(image, 0, 1) ** (1 / gamma)
    return (display * 255 + 0.5).astype(np.uint8), {"exposure": exposure, "shot_noise": shot, "read_noise": read,
                                                    "gamma": gamma}


def render_photo_scene(library: Library, *, sign_id: str | None, decoy: np.ndarray | None, category: str, look: str,
                       photos: Sequence[Path], camera: Camera, rng: np.random.Generator) -> Scene:
    """One scene: library sign `sign_id`, the look-alike plaque `decoy` ((h, w) uint8, seen as a
    library sign would be) or neither, pasted on one of `photos` in `look` (VIEWS, HARD_LOOKS or
    NEGATIVE_LOOKS) and recorded by `camera` (with its size and distortion)."""
    if camera.width is None or camera.height is None:
        raise PhotoWorldError("the camera needs an image width and height to render")
    if sign_id is not None and decoy is not None:
        raise PhotoWorldError("a scene shows a library sign or a look-alike, not both")
    size = (camera.width, camera.height)
    K = camera.K
    background, photo_name = _background(rng, photos, (size[0] * SUPERSAMPLE, size[1] * SUPERSAMPLE))
    view_look = look if look in VIEWS else str(rng.choice(["easy", *HARD_LOOKS]))
    lamps = look == "dim" or (look in NEGATIVE_LOOKS and rng.random() < 0.4)
    shown = library[sign_id] if sign_id is not None else None
    plaque = shown.image if shown is not None else decoy
    params: dict = {"look": look, "background": photo_name}
    R = t = None
    quad = None
    # output px -> composed px, pixel centres aligned as INTER_AREA's shrink aligns them
    up = np.array([[SUPERSAMPLE, 0, (SUPERSAMPLE - 1) / 2], [0, SUPERSAMPLE, (SUPERSAMPLE - 1) / 2], [0, 0, 1]])
    if plaque is None:
        params["clutter"] = _clutter(rng, background, lamps, None)
        scene = background
    else:
        # a look-alike is printed and sized as the library's signs are
        model = shown or LibrarySign("look-alike", "", "", "", library.signs[0].width_m, library.signs[0].height_m,
                                     plaque)
        R, t, pose_params = _pose(rng, K, size, model, VIEWS[view_look])
        params |= pose_params
        H_ideal = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ model.pixel_to_metric
        quad = cv2.perspectiveTransform(model.corners_px[None], H_ideal)[0]
        params["clutter"] = _clutter(rng, background, lamps, quad * SUPERSAMPLE)
        albedo = _print(rng, plaque)
        sign_layer = np.zeros_like(background)
        cover = _paste(sign_layer, albedo, up @ H_ideal)
        gain = rng.uniform(0.15, 0.35) if look == "dim" else rng.uniform(0.6, 1.3)
        if look == "glare" or rng.random() < 0.1:
            # glossy paper mirrors a lamp on one side of the plaque
            ends = cv2.perspectiveTransform(model.corners_px[None], up @ H_ideal)[0]
            spot = 0.7 * ends[int(rng.integers(4))] + 0.3 * ends.mean(axis=0)
            ys, xs = np.mgrid[0:background.shape[0], 0:background.shape[1]].astype(np.float32)
            radius = np.ptp(ends[:, 0]) * rng.uniform(0.15, 0.35)
            strength = rng.uniform(0.6, 2.0)
            sign_layer += (strength * np.exp(-((xs - spot[0]) ** 2 + (ys - spot[1]) ** 2) / (2 * radius**2))
                           * cover)[..., None]
            params["glare"] = strength
        scene = background * (1 - cover[..., None]) + sign_layer * gain
        params["plaque_light"] = gain
    scene = cv2.resize(scene, size, interpolation=cv2.INTER_AREA)
    light, light_params = _light(rng, look, size, quad)
    cast = np.array([1.0, 1.0, 1.0]) + rng.normal(0, 0.12, 3)
    scene = scene * light[..., None] * cast.clip(0.6, 1.4).astype(np.float32)
    params |= light_params | {"colour_cast_bgr": cast.round(3).tolist()}
    if camera.has_distortion:
        scene = cv2.remap(scene, *_lens_maps(K.tobytes(), camera.dist.astype(np.float64).tobytes(), *size),
                          cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    scene, blur_params = _blur(rng, scene, look)
    image, record_params = _record(rng, scene, look)
    quality = int(rng.integers(45, 96))
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    params |= blur_params | record_params | {"jpeg_quality": quality}
    params = {k: round(v, 4) if isinstance(v, float) else v for k, v in params.items()}
    if shown is None or R is None or t is None:
        if R is not None and t is not None:
            params["look_alike_corners"] = _seen_corners(model, R, t, camera).round(2).tolist()
        # synth.py is type-checked without strict optional, so mypy reads Scene's optional fields as required
        nothing: Any = None
        return Scene(image, jpeg, nothing, category, nothing, nothing, nothing, nothing, params)
    corners = _seen_corners(shown, R, t, camera)
    params["sign_width_px"] = round(float(max(np.linalg.norm(corners[1] - corners[0]),
                                              np.linalg.norm(corners[2] - corners[3]))), 2)
    H = cv2.getPerspectiveTransform(shown.corners_px.astype(np.float32), corners.astype(np.float32))
    return Scene(image, jpeg, shown.id, category, R, t, H / H[2, 2], corners, params)


def _seen_corners(sign: LibrarySign, R: np.ndarray, t: np.ndarray, camera: Camera) -> np.ndarray:
    """(4, 2) image px of the sign's corners TL, TR, BR, BL as `camera`, distortion and all, records them."""
    points = sign.to_metric(sign.corners_px)
    return cv2.projectPoints(points, cv2.Rodrigues(R)[0], t, camera.K, camera.dist)[0].reshape(4, 2)


def scene_plan(library: Library, counts: dict[str, int], rng: np.random.Generator) -> list[tuple[str, str, str | None]]:
    """(category, look, sign id or None) per scene for `counts` scenes of each category, in a
    random order: looks in turn, and each category's signs in turn and shuffled, so that no look
    goes with one sign."""
    unknown = set(counts) - set(CATEGORIES)
    if unknown or any(n < 0 for n in counts.values()) or not sum(counts.values()):
        raise PhotoWorldError(f"counts must give a non-negative number of scenes for some of {', '.join(CATEGORIES)}; "
                              f"got {counts}")
    plan: list[tuple[str, str, str | None]] = []
    for category, n in counts.items():
        looks = {"easy": ("easy",), "hard": HARD_LOOKS, "steep": ("steep",), "negative": NEGATIVE_LOOKS}[category]
        signs = [None if category == "negative" else library.ids[i % len(library.ids)] for i in range(n)]
        plan += [(category, looks[i % len(looks)], signs[j]) for i, j in enumerate(rng.permutation(n))]
    return [plan[i] for i in rng.permutation(len(plan))]


def generate_photo_world(out_dir: str | Path, library: Library, *, backgrounds: Sequence[str | Path],
                         decoys: Sequence[np.ndarray], counts: dict[str, int], seed: int,
                         size: tuple[int, int] = (640, 480),
                         progress: Callable[[int, int], None] | None = None) -> dict[str, dict]:
    """Render scenes (`scene_plan` of `counts`) into `out_dir` as scene_000.jpg..., with
    `camera.yaml` (`photo_world_camera`) and `truth.json` (`pipeline.evaluate.load_dataset`
    reads them); returns truth.json's "images". `backgrounds`: folders of real photographs,
    read where they lie; `decoys`: (h, w) uint8 plaques of other words for the look-alike
    negatives. The same seed and inputs give the same files."""
    photos = background_photos(backgrounds)
    if counts.get("negative") and not decoys:
        raise PhotoWorldError("negatives need look-alike plaques (decoys) of other words")
    out = Path(out_dir)
    if any(out.glob("scene_*.jpg")):
        raise PhotoWorldError(f"{out} already holds scenes; pick an empty folder")
    out.mkdir(parents=True, exist_ok=True)
    camera = photo_world_camera(size)
    seeds = np.random.SeedSequence(seed)
    plan = scene_plan(library, counts, np.random.default_rng(seeds.spawn(1)[0]))
    images: dict[str, dict] = {}
    decoy_turn = 0
    for i, ((category, look, sign_id), scene_seed) in enumerate(zip(plan, seeds.spawn(len(plan)))):
        decoy = None
        if look == "look-alike":
            decoy, decoy_turn = decoys[decoy_turn % len(decoys)], decoy_turn + 1
        scene = render_photo_scene(library, sign_id=sign_id, decoy=decoy, category=category, look=look,
                                   photos=photos, camera=camera, rng=np.random.default_rng(scene_seed))
        name = f"scene_{i:03d}.jpg"
        (out / name).write_bytes(scene.jpeg)
        images[name] = scene.truth()
        if progress:
            progress(i + 1, len(plan))
    save_camera(camera, out / "camera.yaml", name="photo_world")
    truth = {"camera": "camera.yaml", "seed": seed, "images": images}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    return images
