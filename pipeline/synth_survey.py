"""Synthetic surveys: photos of a room whose walls carry signs, with every sign's and camera's true pose.

The world is the room's frame, that of the first sign on the back wall: x along the back wall, y
down, z into it, metres. The back wall is z = 0, the front wall z = -depth, the side walls
x = x_min and x = x_max, the floor y = FLOOR_Y and the ceiling y = CEILING_Y (as the flights'
corridor). A sign's frame (x right, y down, z into its wall, `pipeline.pose`) sits at its centre on
its wall, so the survey's truth map (X_map = R·X_sign + position) is in this frame, the first
sign's at the identity.

Signs go round the walls (back, right, front, left) at random spacings along the walls, away from
the corners; photos are taken from random places in the room looking at one sign or between two
neighbours, kept when the signs meant are in full view, large enough and not too oblique, so that
neighbouring signs are seen together and link the survey into one group. Each plane is ray-cast
(the nearest along each pixel's ray) and warped on by its homography as the flights' walls are,
the signs from a mip level near their size on screen; each photo is exposed with its own gain and
noised.
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
from .library import Library
from .pose import camera_position
from .sign_map import MappedSign, SignMap, save_sign_map
from .synth_flight import CEILING_Y, FLOOR_Y, TEXTURE_PX_PER_M, _pyramid, _texture, encoded, level_pixels, look_at

# A sign seen with fewer px across than this, or more oblique than this, is not a view a survey relies on.
MIN_SIGN_PX = 70.0
MAX_OBLIQUITY_DEG = 60.0
# How far photos stand from the walls, and signs from the room's corners (metres).
WALL_MARGIN_M = 0.6
CORNER_MARGIN_M = 1.0
SIGN_Y_RANGE = (-0.4, 0.3)  # sign centres' heights (y down), metres


@dataclass(frozen=True)
class Plane:
    """A wall, the floor or the ceiling: the points origin + a·u + b·v (a, b metres along unit u, v);
    its texture's px run along u and v."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    texture: np.ndarray  # (n, n) float32 gray [0, 1], repeating

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.u, self.v)


@dataclass(frozen=True)
class PlacedSign:
    """Library sign `label` in the room: X_world = R·X_sign + centre; on plane `wall` (an index)."""

    label: str
    R: np.ndarray
    centre: np.ndarray
    wall: int


@dataclass(frozen=True)
class Room:
    """The room's extent (metres) and its signs."""

    x_min: float
    x_max: float
    depth: float
    signs: list[PlacedSign]

    def sign_map(self) -> SignMap:
        """The true map: every sign's pose in the room's frame."""
        return SignMap({s.label: MappedSign(s.label, s.R, s.centre) for s in self.signs})


# Each wall by its signs' x and z axes: x along the wall to the right of a reader facing it (y down
# crossed with z), z into the wall; in this order the walls go round the room.
_WALL_AXES = {
    "back": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
    "right": (np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])),
    "front": (np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])),
    "left": (np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])),
}
_WALLS = tuple(_WALL_AXES)


def room_layout(labels: Sequence[str], rng: np.random.Generator, *, spacing_m: tuple[float, float] = (2.0, 4.0),
                depth_m: float | None = None) -> Room:
    """A room 6 to 8 m wide with `labels` round its walls, neighbours `spacing_m` apart (min, max)
    along the walls (round a corner: along both), the first sign at the world's origin. `depth_m`:
    the room's depth (default: random, 5 to 7 m). ValueError when the signs do not fit."""
    depth = depth_m if depth_m is not None else float(rng.uniform(5.0, 7.0))
    width = float(rng.uniform(6.0, 8.0))
    steps = np.concatenate([[0.0], rng.uniform(*spacing_m, size=len(labels) - 1)])
    x_min = -CORNER_MARGIN_M
    lengths = {"back": width, "right": depth, "front": width, "left": depth}
    starts = {"back": np.array([x_min, 0.0, 0.0]), "right": np.array([x_min + width, 0.0, 0.0]),
              "front": np.array([x_min + width, 0.0, -depth]), "left": np.array([x_min, 0.0, -depth])}
    signs: list[PlacedSign] = []
    along = CORNER_MARGIN_M
    wall_index = 0
    for label, step in zip(labels, steps):
        along += step
        while along > lengths[_WALLS[wall_index]] - CORNER_MARGIN_M:
            # Round the corner: the rest of the step goes along the next wall, kept off its corner.
            along = max(along - lengths[_WALLS[wall_index]], CORNER_MARGIN_M)
            wall_index += 1
            if wall_index == len(_WALLS):
                raise ValueError("the signs do not fit round the room: fewer signs or closer spacing")
        wall = _WALLS[wall_index]
        x_axis, z_axis = _WALL_AXES[wall]
        y = 0.0 if not signs else float(rng.uniform(*SIGN_Y_RANGE))
        centre = starts[wall] + x_axis * along + np.array([0.0, y, 0.0])
        R = np.column_stack([x_axis, [0.0, 1.0, 0.0], z_axis])
        signs.append(PlacedSign(label, R, centre, wall_index))
    return Room(x_min, x_min + width, depth, signs)


class SurveyRenderer:
    """Renders photos of `room` with `camera` (distortion-free, with width and height)."""

    def __init__(self, library: Library, camera: Camera, room: Room, seed: int = 0) -> None:
        if camera.width is None or camera.height is None or camera.has_distortion:
            raise ValueError("surveys are rendered with a distortion-free camera of known image size")
        self.library, self.camera, self.room = library, camera, room
        self.size = (camera.width, camera.height)
        self.rng = np.random.default_rng(seed)
        down = np.array([0.0, 1.0, 0.0])
        corners = {"back": np.array([room.x_min, 0.0, 0.0]), "right": np.array([room.x_max, 0.0, 0.0]),
                   "front": np.array([room.x_max, 0.0, -room.depth]), "left": np.array([room.x_min, 0.0, -room.depth])}
        wall = _texture(self.rng, 0.55, None)
        # Walls (index as PlacedSign.wall), then the floor and the ceiling.
        self.planes = [Plane(corners[w], _WALL_AXES[w][0], down, wall) for w in _WALLS]
        self.planes += [Plane(np.array([0.0, FLOOR_Y, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                              _texture(self.rng, 0.3, 0.5)),
                        Plane(np.array([0.0, CEILING_Y, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]),
                              _texture(self.rng, 0.65, 0.6))]
        self.levels = {s.label: _pyramid(library[s.label].image) for s in room.signs}

    def radiance(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(H, W) float32 linear light of the room seen with world pose (R, t), X_cam = R·X_world + t."""
        K = self.camera.K
        width, height = self.size
        centre = camera_position(R, t)
        A = R.T @ np.linalg.inv(K)  # image px (u, v, 1) -> world ray direction
        u = np.arange(width, dtype=np.float32)[None, :]
        v = np.arange(height, dtype=np.float32)[:, None]
        depths = []
        for plane in self.planes:
            n = plane.normal
            a = (n @ A).astype(np.float32)
            facing = a[0] * u + a[1] * v + a[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = np.float32(n @ (plane.origin - centre)) / facing
            depths.append(np.where(depth > 0, depth, np.inf).astype(np.float32))
        nearest = np.argmin(np.stack(depths), axis=0)
        out = np.zeros((height, width), np.float32)
        scale = np.diag([1 / TEXTURE_PX_PER_M, 1 / TEXTURE_PX_PER_M, 1.0])
        for i, plane in enumerate(self.planes):
            seen = nearest == i
            if not seen.any():
                continue
            H = K @ np.column_stack([R @ plane.u, R @ plane.v, R @ plane.origin + t]) @ scale
            warped = cv2.warpPerspective(plane.texture, H, self.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            np.copyto(out, warped, where=seen)
        for sign in self.room.signs:
            library_sign = self.library[sign.label]
            H = K @ np.column_stack([R @ sign.R[:, 0], R @ sign.R[:, 1], R @ sign.centre + t]) \
                @ library_sign.pixel_to_metric
            levels = self.levels[sign.label]
            h, w = levels[0].shape
            hom = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], dtype=np.float64) @ H.T
            if np.any(hom[:, 2] <= 1e-6):
                continue
            px = hom[:, :2] / hom[:, 2:]
            width_px = max(np.linalg.norm(px[1] - px[0]), np.linalg.norm(px[2] - px[3]), 1.0)
            level = int(np.clip(math.floor(math.log2(w / width_px)), 0, len(levels) - 1))
            H_level = H @ level_pixels(level)
            src = levels[level]
            warped = cv2.warpPerspective(src, H_level, self.size, flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            cover = cv2.warpPerspective(np.ones_like(src), H_level, self.size, flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            # `warped` fades to black across the plaque's rim as `cover` falls; a sign behind another wall is hidden.
            on_wall = (nearest == sign.wall).astype(np.float32)
            out = out * (1 - cover * on_wall) + warped * np.float32(0.97) * on_wall
        return out

    def photo(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(H, W, 3) BGR uint8 photo with world pose (R, t): its own exposure, sensor noise."""
        gain = np.float32(self.rng.uniform(0.85, 1.15))
        image = encoded(self.radiance(R, t) * gain)
        gray = np.clip(image + 2.0 * self.rng.standard_normal(image.shape, dtype=np.float32), 0, 255).astype(np.uint8)
        return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)

    def in_view(self, R: np.ndarray, t: np.ndarray) -> list[str]:
        """The signs a photo with world pose (R, t) shows whole, MIN_SIGN_PX wide or more and at most
        MAX_OBLIQUITY_DEG off facing the camera."""
        K = self.camera.K
        width, height = self.size
        centre = camera_position(R, t)
        shown = []
        for sign in self.room.signs:
            library_sign = self.library[sign.label]
            corners = library_sign.corners_px
            X = np.column_stack([corners, np.ones(4)]) @ library_sign.pixel_to_metric.T  # sign (x, y, 1)
            world = X[:, :1] * sign.R[:, 0] + X[:, 1:2] * sign.R[:, 1] + sign.centre
            cam = world @ R.T + t
            if np.any(cam[:, 2] <= 0.1):
                continue
            px = (cam @ K.T)[:, :2] / cam[:, 2:]
            if not np.all((px >= 2) & (px <= [width - 3, height - 3])):
                continue
            if min(np.linalg.norm(px[1] - px[0]), np.linalg.norm(px[2] - px[3])) < MIN_SIGN_PX:
                continue
            to_camera = centre - sign.centre
            facing = -sign.R[:, 2] @ to_camera / np.linalg.norm(to_camera)
            if math.degrees(math.acos(min(1.0, facing))) > MAX_OBLIQUITY_DEG:
                continue
            # No wall hides a sign facing the camera: the room is convex.
            shown.append(sign.label)
        return shown


@dataclass(frozen=True)
class SurveyPhoto:
    """One photo's truth: world to camera (R, t), X_cam = R·X_world + t, and the signs in view."""

    name: str
    R: np.ndarray
    t: np.ndarray
    signs: list[str]


def plan_photos(renderer: SurveyRenderer, n: int, rng: np.random.Generator, *, pair_share: float = 2 / 3,
                max_tries: int = 2000) -> list[SurveyPhoto]:
    """`n` camera poses: the first sees the first sign alone from close by (the default anchor), then they go
    round the neighbouring pairs (`pair_share` of the photos) and single signs, each from a random place
    at least WALL_MARGIN_M from the walls. ValueError when a pair cannot be seen together."""
    room = renderer.room
    signs = room.signs
    pairs = [(a, b) for a, b in zip(signs, signs[1:])]
    wanted: list[tuple[PlacedSign, ...]] = [(signs[0],)]
    for k in range(1, n):
        if math.floor(k * pair_share + 1e-9) > math.floor((k - 1) * pair_share + 1e-9):
            wanted.append(pairs[sum(len(w) == 2 for w in wanted) % len(pairs)])
        else:
            wanted.append((signs[(sum(len(w) == 1 for w in wanted) - 1) % len(signs)],))
    photos = []
    for i, want in enumerate(wanted):
        for _ in range(max_tries):
            if i == 0:  # close in front of the first sign, which alone is in view
                centre = want[0].centre - want[0].R[:, 2] * rng.uniform(1.5, 2.5) + rng.normal(0.0, 0.2, 3)
            else:
                centre = np.array([rng.uniform(room.x_min + WALL_MARGIN_M, room.x_max - WALL_MARGIN_M),
                                   rng.uniform(-0.5, 0.4),
                                   rng.uniform(-room.depth + WALL_MARGIN_M, -WALL_MARGIN_M)])
            target = np.mean([s.centre for s in want], axis=0) + rng.normal(0.0, 0.15, 3)
            R = look_at(centre, target, math.radians(rng.normal(0.0, 4.0)))
            t = -R @ centre
            shown = renderer.in_view(R, t)
            if all(s.label in shown for s in want) and (i > 0 or shown == [signs[0].label]):
                photos.append(SurveyPhoto(f"photo_{i:03d}.jpg", R, t, shown))
                break
        else:
            raise ValueError(f"no place in the room sees {' and '.join(s.label for s in want)} together: "
                             "closer spacing or a larger room")
    return photos


def write_survey(out_dir: str | Path, library: Library, camera: Camera, *, labels: Sequence[str], n_photos: int,
                 spacing_m: tuple[float, float] = (2.0, 4.0), pair_share: float = 2 / 3, seed: int = 0,
                 quality: int = 90, progress: Callable[[int, int], None] | None = None) -> Room:
    """Render a survey into `out_dir`: photo_NNN.jpg, camera.yaml, truth_map.yaml (every sign's pose in
    the room's frame, `save_sign_map`) and truth.json ({"photos": [{"image", "R", "t" (X_cam =
    R·X_world + t), "camera_position" (world m), "signs" (labels in full view)}]}). `pair_share`: the
    share of photos aimed between two neighbours (`plan_photos`). Returns the room."""
    rng = np.random.default_rng(seed)
    room = room_layout(labels, rng, spacing_m=spacing_m)
    renderer = SurveyRenderer(library, camera, room, seed=seed)
    photos = plan_photos(renderer, n_photos, rng, pair_share=pair_share)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for i, photo in enumerate(photos):
        cv2.imwrite(str(out / photo.name), renderer.photo(photo.R, photo.t), [cv2.IMWRITE_JPEG_QUALITY, quality])
        if progress is not None:
            progress(i + 1, len(photos))
    save_camera(camera, out / "camera.yaml")
    save_sign_map(room.sign_map(), out / "truth_map.yaml",
                  comments={s.label: [f"on the {_WALLS[s.wall]} wall"] for s in room.signs})
    truth = {"photos": [{"image": p.name, "R": p.R.tolist(), "t": p.t.tolist(),
                         "camera_position": camera_position(p.R, p.t).tolist(), "signs": p.signs} for p in photos]}
    (out / "truth.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
    return room
