"""Signs followed from frame to frame in a video: detected by `recognize`, then tracked.

A sign the detector finds becomes a tentative track; it is confirmed (and reported) once the
detector has found it on `TrackerConfig.confirm_frames` frames within `confirm_window`, so a
look-alike that fools the detector once never becomes a track. A confirmed track is followed by pyramidal
Lucas-Kanade on corners inside its quad, checked forward and backward, its homography
(library px -> image px) fitted by RANSAC to the tracked points and the camera pose refined from
the previous frame's (`pose_near`), which settles the planar two-fold ambiguity by continuity.
A track that weakens (few points, a poor fit, an implausible quad) asks for the detector on the
next frame; one not followed for `drop_after_misses` frames is dropped. Points are tracked from
the last frame the track was followed in, so one blank or corrupted frame does not lose them.

Each frame the plaque's outline (`refine_outline`) refines the tracked H where its edges are
found, and the points' library px are read again through it, so drift does not build up. A track
without an outline on a frame (a picture landmark, or a plaque whose edges were not found) is
not masked from the detector's budgeted runs, which re-anchor it on the library image.

The detector runs on a budget: every frame while a track is tentative, every
`weak_retry_frames` for a weak or lost one, otherwise every `detect_interval_s` while something
is tracked (to catch new signs; the healthy tracks held by an outline are masked out) and every `idle_interval_s`
while nothing is. Several signs per frame: once a sign is
found, the detector searches the frame again with the found signs' quads masked out (`recognize_every_sign`), up to
`searches_per_frame` times; a search beside signs found or tracked leaves out the full-frame
fallback, the costliest part of a frame without a (new) sign.

Each track's camera pose is smoothed by a constant-velocity filter on SE(3) (`PoseFilter`). Given a
sign map, each frame's confirmed signs also locate the camera in the map frame (`locate_in_map`, one
fit over all of them), smoothed by a filter of its own.
Conventions as in `pipeline.pose`: X_cam = R·X_sign + t; corners TL, TR, BR, BL in image px.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import Camera
from .every_sign import recognize_every_sign
from .frames import Frame
from .image import to_gray
from .library import Library, LibrarySign
from .localise import CameraInMap, locate_in_map
from .outline import Outline, outline_fit, refine_outline
from .plaque import grid_correspondences, sign_corners
from .pose import CORNER_SIGMA_PX, Pose, PoseError, pose_near, with_corner_floor
from .pose_filter import PoseFilter
from .recognize import Recognition, image_camera, quad_problem
from .segment import Box, box_iou
from .settings import Settings
from .sign_map import SignMap

STATES = ("detected", "tracked")
# 1σ px of a tracked sign's corners beyond what the fit's residuals show: the points' shared drift,
# or the edges of a plaque in a blurred, compressed video frame, off by more than in a still photo
# (CORNER_SIGMA_PX["outline"]). On the 12 s synthetic corridor flight 0.5 against 0.1 took the
# filtered jitter from 3.4 to 2.6 mm median (13.3 to 11.3 mm p90); 1.0 lagged, 14.7 mm p90.
TRACK_CORNER_SIGMA_PX = 0.5
# Detections of one label whose quads' boxes overlap more than this are the same sign.
SAME_SIGN_IOU = 0.2


@dataclass(frozen=True)
class TrackerConfig:
    """How the tracker spends its time and when it trusts a track.

    Intervals are in seconds of video (frames at the tracker's fps); points and px are image px.
    """

    detect_interval_s: float = 0.5  # detector while every track is healthy: new signs
    idle_interval_s: float = 0.2  # detector while nothing is tracked
    searches_per_frame: int = 2  # recognize calls per detection frame (one more per sign found)
    weak_retry_frames: int = 5  # frames between detector runs asked for by a weak or lost track
    confirm_frames: int = 2  # detections that confirm a track ...
    confirm_window: int = 4  # ... within this many frames from its first
    drop_after_misses: int = 3  # frames not followed before a track is dropped
    max_points: int = 120
    min_points: int = 8  # fewer tracked points: the frame is a miss
    keep_fraction: float = 0.5  # fewer of the points seeded left: reseed them, ask for the detector
    forward_backward_px: float = 1.0
    ransac_px: float = 2.0
    min_inlier_ratio: float = 0.6
    # Less of the sign in the frame than this: its points and edges no longer pin the pose (on the
    # corridor flight a sign leaving the frame, tracked down to half in view, was 5-30 cm off at 1 m).
    min_visible: float = 0.75
    max_rmse_px: float = 1.5  # pose residual beyond which a track asks for the detector
    lk_window_px: int = 21
    lk_levels: int = 3


@dataclass(frozen=True, eq=False)
class SignObservation:
    """One sign reported on one frame: its `label`, `track_id`, `state` ("detected": the detector
    found it on this frame; "tracked": followed from the previous one), `corners` (4, 2) image px
    TL, TR, BR, BL, `H` (3, 3) library px -> image px, the measured `pose` and the `filtered_pose`
    (None when none could be computed) and `points`, how many points supported the frame's H."""

    label: str
    track_id: int
    state: str
    corners: np.ndarray = field(repr=False)
    H: np.ndarray = field(repr=False)
    pose: Pose | None = field(repr=False)
    filtered_pose: Pose | None = field(repr=False)
    points: int

    def to_json(self) -> dict:
        return {
            "label": self.label, "track_id": self.track_id, "state": self.state,
            "corners": np.asarray(self.corners, dtype=float).tolist(),
            "homography": np.asarray(self.H, dtype=float).tolist(),
            "pose": self.pose.to_json() if self.pose is not None else None,
            "filtered_pose": self.filtered_pose.to_json() if self.filtered_pose is not None else None,
        }


@dataclass(eq=False)
class FrameResult:
    """What the tracker made of one frame: the confirmed `signs` seen on it, milliseconds spent
    (`timing_ms`: "detect", "track", "total"; the caller adds its decode), `warnings`, and as
    intermediates the detector's `recognitions` on this frame (empty when it did not run) and the
    ids of the tentative tracks (`tentative`). With a sign map (`mapped`), the camera in the map frame
    from this frame's signs (`camera_in_map`) and filtered over time (`filtered_camera_in_map`), None
    on a frame without a mapped sign."""

    frame: int
    time_s: float
    signs: list[SignObservation]
    timing_ms: dict[str, float]
    warnings: list[str]
    recognitions: list[Recognition] = field(default_factory=list, repr=False)
    tentative: list[int] = field(default_factory=list)
    mapped: bool = False
    camera_in_map: CameraInMap | None = field(default=None, repr=False)
    filtered_camera_in_map: CameraInMap | None = field(default=None, repr=False)

    def to_json(self, source: str) -> dict:
        """One line of `signpose track --json`; with a map, `camera_in_map` and `filtered_camera_in_map`."""
        record = {"source": source, "frame": int(self.frame), "time_s": float(self.time_s),
                  "signs": [s.to_json() for s in self.signs]}
        if self.mapped:
            for key, located in (("camera_in_map", self.camera_in_map),
                                 ("filtered_camera_in_map", self.filtered_camera_in_map)):
                record[key] = located.to_json() if located is not None else None
        return {**record, "timing_ms": {k: round(float(v), 3) for k, v in self.timing_ms.items()},
                "warnings": list(self.warnings)}


@dataclass(eq=False)
class Track:
    """One sign followed over frames. `points` (N, 2) float32 image px in `reference` (the last
    frame it was followed in, (H, W) uint8) and `src` (N, 2) float64 their library px; `H` and
    `pose` as of that frame."""

    track_id: int
    sign: LibrarySign
    H: np.ndarray
    pose: Pose | None
    points: np.ndarray
    src: np.ndarray
    reference: np.ndarray
    pose_filter: PoseFilter = field(default_factory=PoseFilter)
    seeded: int = 0  # points when last seeded
    born: int = 0  # frame index of its first detection
    detected_at: int = 0  # frame index of its last detection
    detections: int = 0
    confirmed: bool = False
    misses: int = 0
    weak: bool = False
    filtered: Pose | None = None

    @property
    def corners(self) -> np.ndarray:
        return sign_corners(self.sign, self.H)


@dataclass(frozen=True, eq=False)
class Followed:
    """One track followed onto a frame: its new `H`, the tracked points `dst` (N, 2) image px
    and their library px `src`, whether the track is weak (asks for the detector), and the
    plaque `outline` that refined H (None: H is the tracked points' fit)."""

    H: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    weak: bool
    outline: Outline | None = None


def quad_box(corners: np.ndarray, width: int, height: int) -> Box:
    """The image `Box` around (4, 2) image px `corners`, clipped to the frame."""
    x0, y0 = np.floor(corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int)
    return max(0, x0), max(0, y0), min(width, x1 + 1), min(height, y1 + 1)


def visible_fraction(corners: np.ndarray, width: int, height: int) -> float:
    """The fraction of the convex quad (4, 2) image px inside the width x height frame."""
    quad = corners.astype(np.float32)
    area = cv2.contourArea(quad)
    if area <= 0:
        return 0.0
    frame = np.array([[0, 0], [width, 0], [width, height], [0, height]], np.float32)
    inside, _ = cv2.intersectConvexConvex(quad, frame)
    return float(inside) / area


class Tracker:
    """Follows library signs through the frames of one video; `step` takes each frame in order.

    `camera`: the intrinsics (None: a 60° field of view, as for `recognize`), scaled to the frame
    size on the first frame. `fps` turns the config's intervals into frames (30 when not given).
    `sign_map`: each frame locates the camera in its frame too.
    """

    def __init__(self, library: Library, settings: Settings, camera: Camera | None, *, fps: float | None = None,
                 config: TrackerConfig | None = None, sign_map: SignMap | None = None) -> None:
        self.library, self.settings, self.config = library, settings, config or TrackerConfig()
        self.sign_map, self.map_filter = sign_map, PoseFilter()
        self.given_camera = camera
        self.camera: Camera | None = None
        rate = fps if fps is not None and fps > 0 and math.isfinite(fps) else 30.0
        self.detect_every = max(1, round(self.config.detect_interval_s * rate))
        self.idle_every = max(1, round(self.config.idle_interval_s * rate))
        self.tracks: list[Track] = []
        self.next_id = 1
        self.last_detect: int | None = None

    # -- the frame ---------------------------------------------------------------------------

    def step(self, image: np.ndarray, *, index: int, time_s: float) -> FrameResult:
        """Process frame `index` at `time_s` seconds: (H, W, 3) BGR or (H, W) gray uint8."""
        t_start = time.perf_counter()
        gray = to_gray(image)
        height, width = gray.shape
        warnings: list[str] = []
        if self.camera is None:
            self.camera, notes, approximate = image_camera(self.given_camera, width, height)
            warnings += notes + ([approximate] if approximate else [])
        camera = self.camera

        followed: dict[int, Followed] = {}
        for track in self.tracks:
            result = self._follow(track, gray, camera)
            if result is not None:
                followed[track.track_id] = result
        t_tracked = time.perf_counter()

        recognitions: list[Recognition] = []
        detected: set[int] = set()
        if self._detection_due(index, followed):
            self.last_detect = index
            recognitions, detected = self._detect(gray, camera, followed, index)
            for track in self.tracks:
                if track.track_id in detected:
                    track.detected_at = index
        t_detected = time.perf_counter()

        signs = self._settle(gray, camera, followed, detected, time_s, warnings)
        located = filtered = None
        if self.sign_map is not None:
            located = locate_in_map(found=signs, sign_map=self.sign_map, library=self.library, camera=camera)
            if located is not None:
                filtered = CameraInMap(self.map_filter.update(located.pose, time_s), located.signs_used)
        t_end = time.perf_counter()
        tracking = (t_tracked - t_start) + (t_end - t_detected)
        timing = {"detect": (t_detected - t_tracked) * 1e3, "track": tracking * 1e3, "total": (t_end - t_start) * 1e3}
        return FrameResult(index, time_s, signs, timing, warnings, recognitions,
                           [t.track_id for t in self.tracks if not t.confirmed], self.sign_map is not None, located,
                           filtered)

    def _detection_due(self, index: int, followed: dict[int, Followed]) -> bool:
        if self.last_detect is None:
            return True
        if any(not t.confirmed for t in self.tracks):
            return True
        # A lost or weak track asks again only some frames after its last detection: one leaving
        # the frame weakens on every frame, and the detector cannot do better with it.
        if any((t.track_id not in followed or followed[t.track_id].weak)
               and index - t.detected_at >= self.config.weak_retry_frames for t in self.tracks):
            return True
        every = self.detect_every if self.tracks else self.idle_every
        return index - self.last_detect >= every

    # -- following ---------------------------------------------------------------------------

    def _follow(self, track: Track, gray: np.ndarray, camera: Camera) -> Followed | None:
        """Track's points from its reference frame onto `gray`, its new H, or None (a miss)."""
        cfg = self.config
        if len(track.points) < cfg.min_points or track.reference.shape != gray.shape:
            return None
        lk = {"winSize": (cfg.lk_window_px, cfg.lk_window_px), "maxLevel": cfg.lk_levels,
              "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)}
        p0 = track.points.reshape(-1, 1, 2)
        p1, status, _ = cv2.calcOpticalFlowPyrLK(track.reference, gray, p0, None, **lk)
        if p1 is None:
            return None
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(gray, track.reference, p1, None, **lk)
        fb = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
        good = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb < cfg.forward_backward_px)
        if good.sum() < cfg.min_points:
            return None
        src, dst = track.src[good], p1.reshape(-1, 2)[good].astype(np.float64)
        H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, cfg.ransac_px)
        if H is None:
            return None
        inl = inliers.ravel().astype(bool)
        if inl.sum() < cfg.min_points or inl.mean() < cfg.min_inlier_ratio:
            return None
        height, width = gray.shape
        corners, problem = quad_problem(H, track.sign, width, height)
        if problem is not None or corners is None:
            return None
        if visible_fraction(corners, width, height) < cfg.min_visible:
            return None
        # Weak when most of the points seeded are lost: the view changed beyond what they can follow.
        weak = inl.sum() < max(cfg.min_points, cfg.keep_fraction * track.seeded)
        H = H / H[2, 2]
        if self.settings.refine_outline:
            # The plaque's edges put H where the sign is now, not where the points drifted to.
            outline, _ = refine_outline(gray, track.sign, H, self.settings.seed, camera)
            if outline is not None:
                return Followed(outline.H, src[inl], dst[inl], weak, outline)
        return Followed(H, src[inl], dst[inl], weak)

    def _seed(self, track: Track, gray: np.ndarray) -> None:
        """New points for `track`: corners inside its quad in `gray`, their library px through its H."""
        cfg = self.config
        mask = np.zeros(gray.shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(track.corners).astype(np.int32), 255)
        found = cv2.goodFeaturesToTrack(gray, cfg.max_points, 0.01, 5, mask=mask, blockSize=5)
        points = (np.zeros((0, 2), np.float32) if found is None else found.reshape(-1, 2).astype(np.float32))
        track.points, track.seeded = points, len(points)
        track.src = cv2.perspectiveTransform(points.astype(np.float64).reshape(-1, 1, 2),
                                             np.linalg.inv(track.H)).reshape(-1, 2)
        track.reference = gray

    # -- detecting ---------------------------------------------------------------------------

    def _detect(self, gray: np.ndarray, camera: Camera, followed: dict[int, Followed],
                index: int) -> tuple[list[Recognition], set[int]]:
        """Run the detector on `gray`, the healthy confirmed tracks masked out, as long as it finds
        signs and the budget allows. Returns (its recognitions, the ids of tracks it found)."""
        height, width = gray.shape
        # Healthy tracks held by their plaque's outline need no detector: the outline keeps their H
        # from drifting. One followed by its points alone (a picture, or a plaque whose edges were
        # not found) drifts with them, and the detector re-anchors it.
        hidden = [sign_corners(t.sign, followed[t.track_id].H) for t in self.tracks
                  if t.confirmed and t.track_id in followed and not followed[t.track_id].weak
                  and followed[t.track_id].outline is not None]
        recognitions = recognize_every_sign(gray, self.library, self.settings, camera, known=hidden,
                                            most=self.config.searches_per_frame)
        found = {self._claim(rec, rec.corners, width, height, gray, camera, index).track_id
                 for rec in recognitions if rec.label is not None and rec.corners is not None}
        # A tentative track the detector has not found `confirm_frames` times within
        # `confirm_window` frames is a look-alike (or too uncertain to report) and goes.
        for track in list(self.tracks):
            if track.track_id in found:
                track.detections += 1
                track.confirmed = track.confirmed or track.detections >= self.config.confirm_frames
            elif not track.confirmed and index - track.born + 1 >= self.config.confirm_window:
                self.tracks.remove(track)
        return recognitions, found

    def _claim(self, rec: Recognition, corners: np.ndarray, width: int, height: int, gray: np.ndarray,
               camera: Camera, index: int) -> Track:
        """The track a detection belongs to, re-anchored on it, or a new tentative one."""
        assert rec.label is not None and rec.H is not None
        sign = self.library[rec.label]
        box = quad_box(corners, width, height)
        same = [t for t in self.tracks if box_iou(box, quad_box(t.corners, width, height)) > SAME_SIGN_IOU]
        mine = next((t for t in same if t.sign.id == sign.id), None)
        for other in same:
            if other is not mine and not other.confirmed:
                self.tracks.remove(other)  # a tentative track the detector now reads as another sign
        H = rec.H / rec.H[2, 2]
        if mine is None:
            mine = Track(self.next_id, sign, H, rec.pose, np.zeros((0, 2), np.float32), np.zeros((0, 2)), gray,
                         born=index)
            self.next_id += 1
            self.tracks.append(mine)
        else:
            # Re-anchored: the pose refitted from the track's own, so the ambiguity stays settled.
            src, dst = grid_correspondences(H, sign)
            sigma = CORNER_SIGMA_PX["outline" if rec.outline is not None else "dense"]
            start = mine.pose or rec.pose
            mine.pose = rec.pose
            if start is not None:
                try:
                    mine.pose = pose_near(start.R, start.t, src, dst, sign, camera, sigma)
                except PoseError:
                    pass
            mine.H = H
        mine.misses, mine.weak = 0, False
        self._seed(mine, gray)
        return mine

    # -- reporting ---------------------------------------------------------------------------

    def _settle(self, gray: np.ndarray, camera: Camera, followed: dict[int, Followed], detected: set[int],
                time_s: float, warnings: list[str]) -> list[SignObservation]:
        """Update each track with what the frame gave it, drop the lost ones, report the confirmed."""
        signs: list[SignObservation] = []
        for track in list(self.tracks):
            step = followed.get(track.track_id)
            if track.track_id not in detected:
                if step is None:
                    track.misses += 1
                    if track.misses >= self.config.drop_after_misses:
                        self.tracks.remove(track)
                    continue
                self._advance(track, step, gray, camera, warnings)
            if track.pose is not None:
                track.filtered = track.pose_filter.update(track.pose, time_s)
            if not track.confirmed:
                continue
            state = "detected" if track.track_id in detected else "tracked"
            points = len(step.dst) if step is not None and state == "tracked" else len(track.points)
            signs.append(SignObservation(track.sign.id, track.track_id, state, track.corners, track.H, track.pose,
                                         track.filtered, points))
        return signs

    def _advance(self, track: Track, step: Followed, gray: np.ndarray, camera: Camera, warnings: list[str]) -> None:
        """Move `track` onto the frame it was followed to."""
        track.H, track.misses, track.weak = step.H, 0, step.weak
        src = step.src
        if step.outline is not None:
            # The points' library px re-read through the outline's H: their drift does not build up.
            src = cv2.perspectiveTransform(step.dst.reshape(-1, 1, 2), np.linalg.inv(step.H)).reshape(-1, 2)
        if track.pose is not None:
            try:
                track.pose = self._tracked_pose(track.sign, track.pose, step, src, camera)
                if track.pose.reprojection_rmse_px > self.config.max_rmse_px:
                    track.weak = True
            except PoseError as exc:
                warnings.append(f"track {track.track_id} ({track.sign.id}): no pose: {exc}")
                track.pose = None
        if step.weak:
            self._seed(track, gray)
        else:
            track.points, track.src, track.reference = step.dst.astype(np.float32), src, gray

    @staticmethod
    def _tracked_pose(sign: LibrarySign, start: Pose, step: Followed, src: np.ndarray, camera: Camera) -> Pose:
        """The pose on a followed frame, refined from `start`: fitted to the outline's grid, its
        covariance from the edge points as `recognize` measures it, or else to the tracked points
        (`src` (N, 2) library px of `step.dst`)."""
        if step.outline is None:
            return pose_near(start.R, start.t, src, step.dst, sign, camera, TRACK_CORNER_SIGMA_PX)
        grid_src, grid_dst = step.outline.grid(sign, camera)
        sigma = TRACK_CORNER_SIGMA_PX
        pose = pose_near(start.R, start.t, grid_src, grid_dst, sign, camera, sigma)
        rmse, covariance = outline_fit(pose.R, pose.t, step.outline, sign, camera)
        return dataclasses.replace(pose, reprojection_rmse_px=rmse,
                                   covariance=with_corner_floor(covariance, pose.R, pose.t, sign, camera, sigma))


def tracked_frames(frames: Iterable[Frame], tracker: Tracker, source: str) -> Iterator[tuple[Frame, FrameResult, dict]]:
    """Each of `frames` through `tracker`, in order: (the frame, the tracker's result, its line of
    `signpose track --json` named `source`, whose timings include the frame's decode, in ms).

    The frames' errors (SourceError) and the tracker's (CameraError: the camera does not fit the
    frames) are raised as they come; the frames before them have been yielded.
    """
    stream = iter(frames)
    while True:
        t_decode = time.perf_counter()
        frame = next(stream, None)
        if frame is None:
            return
        decode_ms = (time.perf_counter() - t_decode) * 1e3
        result = tracker.step(frame.image, index=frame.index, time_s=frame.time_s)
        record = result.to_json(source)
        record["timing_ms"] = {"decode": round(decode_ms, 3), **record["timing_ms"],
                               "total": round(decode_ms + result.timing_ms["total"], 3)}
        yield frame, result, record
