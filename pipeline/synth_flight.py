"""Synthetic flights: a camera moving along a corridor wall carrying signs, with exact ground truth.

The world is the wall's frame: x along the corridor, y down, z into the wall, metres; the wall is
z = 0, the floor y = FLOOR_Y, the ceiling y = CEILING_Y. Each sign hangs on the wall centred at
its `centre`, its sign frame the world's axes moved there (x right, y down, z into the wall, as
`pipeline.pose` has it), so a camera pose (R, t_w) of the world, X_cam = R·X_world + t_w, sees
the sign at X_cam = R·X_sign + (R·centre + t_w).

Each of the three planes is warped on by its homography (a procedural texture, repeating), on the
pixels whose rays meet it first; the signs and a white look-alike plaque warped on with their exact
homographies from a mip level near their size on screen; then lit by a band of ceiling lights,
exposed with a drifting gain, blurred along the frame's motion, noised with per-row bands.
The camera follows a smooth path through keyframes (position and the point it looks at,
Catmull-Rom), with a slow hovering roll.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .camera import Camera, save_camera
from .library import Library, LibrarySign

FLOOR_Y = 1.4
CEILING_Y = -1.3
TEXTURE_PX_PER_M = 200.0
TEXTURE_SIZE = 512  # px: a texture repeats every TEXTURE_SIZE / TEXTURE_PX_PER_M = 2.56 m
# Shutter open for this fraction of the frame interval: the length of the motion blur.
SHUTTER = 0.5
FOURCC = "mp4v"
# The renderer's version, raised whenever a change moves what its frames show: a flight rendered
# once and kept (bench/track.py's) is named by it, so that an older rendering is not measured again.
RENDERING = 3
# Frames are encoded as an sRGB camera encodes them, linear light to the power 1 / GAMMA; a surface's gray
# level (a texture's, a plaque's) is what a frame shows of it unblurred, and it is drawn as the light that is.
GAMMA = 2.2


@dataclass(frozen=True)
class Keyframe:
    """The camera at `time_s`: its centre and the point it looks at, world metres."""

    time_s: float
    position: tuple[float, float, float]
    target: tuple[float, float, float]


@dataclass(frozen=True)
class Plaque:
    """A sign (`label`: a library id) or a look-alike (`label` None) on the wall, its centre in
    world metres, its size in metres."""

    label: str | None
    centre: tuple[float, float]
    size_m: tuple[float, float]


# From 7 m off the wall (both signs 45-50 px wide), in to the first until it fills the frame, along past
# the look-alike, to the second and away obliquely.
CORRIDOR_PATH = (
    Keyframe(0.0, (-0.4, 0.1, -7.0), (0.9, -0.15, 0.0)),
    Keyframe(2.5, (-0.3, 0.05, -4.0), (0.4, -0.2, 0.0)),
    Keyframe(4.5, (0.0, -0.1, -1.2), (0.0, -0.2, 0.0)),
    Keyframe(5.8, (0.02, -0.18, -0.58), (0.0, -0.2, 0.0)),
    Keyframe(7.2, (0.6, -0.05, -1.6), (1.1, -0.15, 0.0)),
    Keyframe(9.2, (2.1, 0.0, -1.3), (2.6, -0.1, 0.0)),
    Keyframe(12.0, (4.2, 0.1, -2.2), (2.6, -0.1, 0.0)),
)
CORRIDOR_PLAQUES = (
    Plaque("security_compound", (0.0, -0.2), (0.6, 0.24)),
    Plaque(None, (1.3, -0.15), (0.6, 0.24)),
    Plaque("chief_of_security", (2.6, -0.1), (0.6, 0.24)),
)


def _catmull_rom(times: np.ndarray, values: np.ndarray, t: float) -> np.ndarray:
    """(D,) Catmull-Rom interpolation at `t` of (N, D) `values` at increasing (N,) `times`."""
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    p = [values[max(i - 1, 0)], values[i], values[i + 1], values[min(i + 2, len(values) - 1)]]
    s = (t - times[i]) / (times[i + 1] - times[i])
    s = min(max(s, 0.0), 1.0)
    return 0.5 * ((2 * p[1]) + (-p[0] + p[2]) * s + (2 * p[0] - 5 * p[1] + 4 * p[2] - p[3]) * s**2
                  + (-p[0] + 3 * p[1] - 3 * p[2] + p[3]) * s**3)


def camera_pose(path: Sequence[Keyframe], time_s: float, roll_deg: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) of the world in the camera, X_cam = R·X_world + t, at `time_s` on `path`:
    looking at the interpolated target, image y along world y (down), with a slow hovering roll."""
    times = np.array([k.time_s for k in path])
    centre = _catmull_rom(times, np.array([k.position for k in path]), time_s)
    target = _catmull_rom(times, np.array([k.target for k in path]), time_s)
    R = look_at(centre, target, math.radians(roll_deg) * math.sin(2 * math.pi * time_s / 4.0))
    return R, -R @ centre


def look_at(centre: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """(3, 3) R (world to camera) of a camera at `centre` looking at `target` (world metres), image y
    along world y (down), then rolled by `roll_rad` about its optical axis."""
    z = np.asarray(target, dtype=np.float64) - centre
    z /= np.linalg.norm(z)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return cv2.Rodrigues(np.array([0.0, 0.0, roll_rad]))[0] @ np.stack([x, y, z])


def _texture(rng: np.random.Generator, base: float, lines_m: float | None, size: int = TEXTURE_SIZE) -> np.ndarray:
    """(size, size) float32 repeating texture of linear light, its gray level around `base` in [0, 1],
    with grid lines every `lines_m` metres (tiles, planks) when given."""
    # Blurred as a 3 x 3 tiling and cut from the middle, so that the texture repeats seamlessly.
    tiled = np.tile(rng.normal(0.0, 1.0, (size, size)).astype(np.float32), (3, 3))
    middle = slice(size, 2 * size)
    fine = cv2.GaussianBlur(tiled, (0, 0), 1.0)[middle, middle]
    coarse = cv2.GaussianBlur(tiled, (0, 0), 12.0)[middle, middle]
    tex = base + 0.15 * fine + 2.0 * coarse
    if lines_m is not None:
        step = max(2, int(round(lines_m * TEXTURE_PX_PER_M)))
        tex[::step, :] *= 0.6
        tex[:, ::step] *= 0.6
    return (np.clip(tex, 0.0, 1.0) ** GAMMA).astype(np.float32)


def _look_alike(size_m: tuple[float, float], px_per_m: float = 1333.0) -> np.ndarray:
    """(h, w) uint8 white plaque of other words, the signs' size: what the detector must not track."""
    w, h = int(size_m[0] * px_per_m), int(size_m[1] * px_per_m)
    img = np.full((h, w), 235, np.uint8)
    cv2.rectangle(img, (8, 8), (w - 9, h - 9), 40, 6)
    cv2.putText(img, "MEETING ROOM", (int(0.1 * w), int(0.62 * h)), cv2.FONT_HERSHEY_DUPLEX, w / 420, 30,
                max(2, w // 160), cv2.LINE_AA)
    return img


def level_pixels(level: int) -> np.ndarray:
    """(3, 3) map from the pixels of mip `level` of a decal's `_pyramid` to its full-size
    coordinates, whose edges are at 0 and w (a full-size pixel u spans [u, u + 1], as
    `pixel_to_world` and the truth's corners have it): warpPerspective samples pixel centres at
    whole coordinates, and a pixel i of the level spans [2^level i, 2^level (i + 1)], its centre
    at 2^level (i + 1/2). Mapped without the half pixel, a plaque was drawn 0.25-0.5 px up and
    left of its true corners."""
    step = 2.0**level
    return np.array([[step, 0.0, step / 2], [0.0, step, step / 2], [0.0, 0.0, 1.0]])


def _pyramid(image: np.ndarray) -> list[np.ndarray]:
    """The uint8 gray `image` as linear light in [0, 1], then halved until under 16 px: its mip levels."""
    levels = [(image.astype(np.float32) / 255) ** GAMMA]
    while min(levels[-1].shape) > 16:
        levels.append(cv2.pyrDown(levels[-1]))
    return levels


@dataclass(frozen=True)
class _Decal:
    plaque: Plaque
    levels: list[np.ndarray]  # gray [0, 1], full size first

    def pixel_to_world(self) -> np.ndarray:
        """(3, 3) full-size decal px -> world (x, y, 1) on the wall."""
        h, w = self.levels[0].shape
        sx, sy = self.plaque.size_m[0] / w, self.plaque.size_m[1] / h
        cx, cy = self.plaque.centre
        return np.array([[sx, 0, cx - w / 2 * sx], [0, sy, cy - h / 2 * sy], [0, 0, 1]])


@dataclass(frozen=True)
class FlightFrame:
    """One rendered frame: the (H, W, 3) BGR uint8 image and its truth (`truth_json`)."""

    image: np.ndarray
    truth: dict


class FlightRenderer:
    """Renders frames of a camera moving past `plaques` on a corridor wall, seen by `camera`
    (distortion-free, with width and height)."""

    def __init__(self, library: Library, camera: Camera, plaques: Sequence[Plaque] = CORRIDOR_PLAQUES,
                 seed: int = 0) -> None:
        if camera.width is None or camera.height is None or camera.has_distortion:
            raise ValueError("flights are rendered with a distortion-free camera of known image size")
        self.library, self.camera = library, camera
        self.size = (camera.width, camera.height)
        self.rng = np.random.default_rng(seed)
        # A row of ceiling lights along the corridor, one a texture repeat apart: the surfaces are
        # brighter under each and dimmer between; the plaques are lit evenly.
        along = np.arange(TEXTURE_SIZE, dtype=np.float32)[None, :]
        light = 0.75 + 0.25 * np.cos(2 * np.pi * along / TEXTURE_SIZE)
        self.textures = {name: _texture(self.rng, base, lines) * light
                         for name, base, lines in (("wall", 0.5, None), ("floor", 0.3, 0.5), ("ceiling", 0.6, 0.6))}
        self.decals = [_Decal(p, _pyramid(library[p.label].image if p.label is not None else _look_alike(p.size_m)))
                       for p in plaques]
        u, v = np.meshgrid(np.arange(self.size[0], dtype=np.float64), np.arange(self.size[1], dtype=np.float64))
        rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(camera.K).T
        self.rays = rays.astype(np.float32)  # (H, W, 3) camera frame

    def signs(self) -> list[LibrarySign]:
        return [self.library[d.plaque.label] for d in self.decals if d.plaque.label is not None]

    def radiance(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(H, W) float32 linear light of the scene seen with world pose (R, t), before exposure."""
        centre = -R.T @ t
        K = self.camera.K
        # Each plane's texture goes on through its homography (texture px -> image px); which plane
        # a pixel sees follows from its ray, whose y and z components are linear in (u, v).
        A = R.T @ np.linalg.inv(K)
        u = np.arange(self.size[0], dtype=np.float32)[None, :]
        v = np.arange(self.size[1], dtype=np.float32)[:, None]
        dy = np.float32(A[1, 0]) * u + np.float32(A[1, 1]) * v + np.float32(A[1, 2])
        dz = np.float32(A[2, 0]) * u + np.float32(A[2, 1]) * v + np.float32(A[2, 2])
        reach = np.float32(-centre[2]) * dy  # the wall point's y below the camera, times dz
        wall = ((dz > 0) & (reach > np.float32(CEILING_Y - centre[1]) * dz)
                & (reach < np.float32(FLOOR_Y - centre[1]) * dz))
        scale = np.diag([1 / TEXTURE_PX_PER_M, 1 / TEXTURE_PX_PER_M, 1.0])
        planes = {"wall": np.column_stack([R[:, 0], R[:, 1], t]),
                  "floor": np.column_stack([R[:, 0], R[:, 2], R[:, 1] * FLOOR_Y + t]),
                  "ceiling": np.column_stack([R[:, 0], R[:, 2], R[:, 1] * CEILING_Y + t])}
        seen = {"wall": wall, "floor": ~wall & (dy > 0), "ceiling": ~wall & (dy <= 0)}
        out = np.zeros((self.size[1], self.size[0]), np.float32)
        for name, P in planes.items():
            if not seen[name].any():
                continue
            warped = cv2.warpPerspective(self.textures[name], K @ P @ scale, self.size, flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_WRAP)
            np.copyto(out, warped, where=seen[name])
        for decal in self.decals:
            H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ decal.pixel_to_world()
            h, w = decal.levels[0].shape
            corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], dtype=np.float64) @ H.T
            if np.any(corners[:, 2] <= 1e-6):
                continue
            px = corners[:, :2] / corners[:, 2:]
            width_px = max(np.linalg.norm(px[1] - px[0]), np.linalg.norm(px[2] - px[3]), 1.0)
            level = int(np.clip(math.floor(math.log2(w / width_px)), 0, len(decal.levels) - 1))
            H_level = H @ level_pixels(level)
            src = decal.levels[level]
            warped = cv2.warpPerspective(src, H_level, self.size, flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            cover = cv2.warpPerspective(np.ones_like(src), H_level, self.size, flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            out = out * (1 - cover) + warped * 0.97
        return out

    def render(self, path: Sequence[Keyframe], time_s: float, fps: float) -> FlightFrame:
        """The frame at `time_s` on `path`, with motion blur over SHUTTER of a frame at `fps`."""
        R, t = camera_pose(path, time_s)
        image = self.radiance(R, t)
        blur = self._motion(path, R, t, time_s, SHUTTER / fps)
        if np.hypot(*blur) >= 1.0:
            image = _motion_blur(image, blur)
        gain = 1.0 + 0.18 * math.sin(2 * math.pi * time_s / 5.0) + 0.05 * math.sin(2 * math.pi * time_s / 1.3)
        image = encoded(image * np.float32(gain))
        noise = (2.0 * self.rng.standard_normal(image.shape, dtype=np.float32)
                 + self.rng.standard_normal((image.shape[0], 1), dtype=np.float32))
        gray = np.clip(image + noise, 0, 255).astype(np.uint8)
        return FlightFrame(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), self._truth(R, t))

    def _motion(self, path: Sequence[Keyframe], R: np.ndarray, t: np.ndarray, time_s: float,
                shutter_s: float) -> tuple[float, float]:
        """Image px the frame's centre point on the wall moves while the shutter is open."""
        R2, t2 = camera_pose(path, time_s + shutter_s)
        centre = -R.T @ t
        ray = R.T @ np.array([0.0, 0.0, 1.0])
        point = centre + ray * (-centre[2] / max(ray[2], 1e-6))
        p = self.camera.K @ (R2 @ point + t2)
        cx, cy = self.camera.K[0, 2], self.camera.K[1, 2]
        return float(p[0] / p[2] - cx), float(p[1] / p[2] - cy)

    def _truth(self, R: np.ndarray, t: np.ndarray) -> dict:
        """Each sign's pose and corners for world pose (R, t)."""
        K = self.camera.K
        width, height = self.size
        signs = []
        for decal in self.decals:
            label = decal.plaque.label
            if label is None:
                continue
            sign = self.library[label]
            cx, cy = decal.plaque.centre
            t_sign = R @ np.array([cx, cy, 0.0]) + t
            H = K @ np.column_stack([R[:, 0], R[:, 1], t_sign]) @ sign.pixel_to_metric
            hom = np.column_stack([sign.corners_px, np.ones(4)]) @ H.T
            in_front = bool(np.all(hom[:, 2] > 1e-6))
            corners = hom[:, :2] / np.where(in_front, hom[:, 2:], 1.0)
            inside = in_front and bool(np.all((corners >= 0) & (corners <= [width - 1, height - 1])))
            width_px = float(max(np.linalg.norm(corners[1] - corners[0]), np.linalg.norm(corners[2] - corners[3])))
            if not in_front:
                continue
            signs.append({"label": label, "corners": corners.tolist(), "R": R.tolist(), "t": t_sign.tolist(),
                          "in_view": inside, "width_px": width_px})
        return {"camera_position": (-R.T @ t).tolist(), "signs": signs}


def encoded(light: np.ndarray) -> np.ndarray:
    """(H, W) float32 linear light, 1 the brightest a frame records -> its gray levels 0-255 (float32)."""
    return cv2.pow(np.clip(light, 0.0, 1.0), 1 / GAMMA) * np.float32(255)


def _motion_blur(image: np.ndarray, motion: tuple[float, float]) -> np.ndarray:
    """`image` blurred along the (dx, dy) px of motion with a line kernel."""
    length = int(math.ceil(math.hypot(*motion)))
    size = 2 * (length // 2) + 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    ux, uy = motion[0] / math.hypot(*motion), motion[1] / math.hypot(*motion)
    for s in np.linspace(-length / 2, length / 2, 2 * length + 1):
        kernel[int(round(c + s * uy)), int(round(c + s * ux))] += 1
    return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REPLICATE)


def write_flight(out_dir: str | Path, library: Library, camera: Camera, *, duration_s: float, fps: float = 30.0,
                 path: Sequence[Keyframe] = CORRIDOR_PATH, seed: int = 0, quality: int = 90,
                 progress: Callable[[int, int], None] | None = None) -> Path:
    """Render a flight into `out_dir`: flight.mp4, truth.json and camera.yaml. `path` is played
    over `duration_s` seconds (its keyframe times shifted to start at 0 and scaled to fit) at `fps`.
    Returns the video's path.

    truth.json: {"fps", "width", "height", "video", "frames": [{"frame", "time_s",
    "camera_position" (world m), "signs": [{"label", "corners" (4x2 px TL, TR, BR, BL), "R", "t"
    (X_cam = R·X_sign + t), "in_view" (every corner inside the frame), "width_px"}]}]}.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    span = path[-1].time_s - path[0].time_s
    scaled = [Keyframe((k.time_s - path[0].time_s) * duration_s / span, k.position, k.target) for k in path]
    renderer = FlightRenderer(library, camera, seed=seed)
    video = out / "flight.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*FOURCC), fps, renderer.size)
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {video} with the {FOURCC} codec")
    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, quality)
    n = int(round(duration_s * fps))
    frames = []
    try:
        for i in range(n):
            frame = renderer.render(scaled, i / fps, fps)
            writer.write(frame.image)
            frames.append({"frame": i, "time_s": i / fps, **frame.truth})
            if progress is not None:
                progress(i + 1, n)
    finally:
        writer.release()
    width, height = renderer.size
    truth = {"fps": fps, "width": width, "height": height, "video": video.name, "frames": frames}
    (out / "truth.json").write_text(json.dumps(truth), encoding="utf-8")
    save_camera(camera, out / "camera.yaml")
    return video
