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
checked by the detector where it is every `detect_interval_s`, which re-anchors it on the library
image.

The detector runs where it is needed and on a budget. A check of one sign (`recognize_near`: its
neighbourhood cut from the frame, no full-frame fallback) confirms each tentative track on every
frame and re-anchors the tracks without an outline. A search of the whole frame, with the healthy
followed tracks masked out, looks for new signs: every frame while a track is tentative (signs
come into view together), every `weak_retry_frames` for a weak or lost track, every
`search_interval_s` while something is tracked and every `idle_interval_s` while nothing is.
Several signs per frame: once a sign is found, the frame is searched again with the found signs'
quads masked out (`recognize_every_sign`), up to `searches_per_frame` times (once by default: the
next frame is searched anyway while the new track is tentative, with it masked out); a search beside signs
found or tracked leaves out the full-frame fallback, the costliest part of a search that finds no
(new) sign. The affine fallback runs only in searches with nothing tracked, when
`TrackerConfig.affine_fallback` asks for it; with nothing tracked, a library of plaques alone has
its full-frame fallback on the frame shrunk to `idle_search_size`.

Points are seeded and followed in the sign's neighbourhood alone: Lucas-Kanade's pyramids and the
corner measure then cost the sign's area, not the frame's.

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
from .every_sign import recognize_every_sign, recognize_near
from .frames import Frame
from .image import to_gray
from .library import Library, LibrarySign
from .localise import CameraInMap, locate_in_map
from .outline import Outline, outline_corner_sigma, outline_fit, outline_pose, refine_outline
from .plaque import grid_correspondences, ideal_homography, seen_homography, sign_corners
from .pose import CORNER_SIGMA_PX, Pose, PoseError, estimate_pose, pose_near, undistort_pixels, with_corner_floor
from .pose_filter import MAX_GAP_S, PoseFilter
from .recognize import Recognition, image_camera, quad_problem, uses_outline
from .segment import Box, box_iou
from .settings import Settings
from .sign_map import SignMap

STATES = ("detected", "tracked")
# 1σ px of the corners of a sign followed by its points alone, beyond what the fit's residuals
# show: the points' shared drift since the frame that seeded them. (A plaque its outline places,
# detected or followed, has its corners' σ from its edges, `outline_corner_sigma`, as `recognize`
# gives it.)
TRACK_CORNER_SIGMA_PX = 0.5
# 1σ px the filter adds to the corners of a pose its outline or the detector placed. Such a pose's
# own covariance is honest for that frame (NEES 2.3 / 7.2 median / p90 within 3 m on the 12 s
# corridor flight), but a plaque's edges err alike on consecutive frames (the same blur, the same
# wall beside them), which the filter would take for independent evidence and follow. On that flight
# and the sample flight in its wall's map: 0.25 px gives filtered jitter within 3 m of 2.0 / 7.5 mm
# median / p90 and the filtered camera in the map a NEES of 2.1 / 6.5 (3 dof; honest 2.37 / 6.25);
# 0.5 px 1.8 / 6.6 mm and 1.5 / 5.9; none, 4.4 / 14.0 (overconfident).
FILTER_CORNER_SIGMA_PX = 0.25
# Detections of one label whose quads' boxes overlap more than this are the same sign.
SAME_SIGN_IOU = 0.2
# Image px around a quad's box read when seeding its points: more than the corner measure's block.
SEED_MARGIN_PX = 8


@dataclass(frozen=True)
class TrackerConfig:
    """How the tracker spends its time and when it trusts a track.

    Intervals are in seconds of video (frames at the tracker's fps); points and px are image px.
    """

    detect_interval_s: float = 0.5  # detector checks of a track followed by its points alone
    # Searches of the whole frame for new signs while every track is healthy. Each costs 5-32 ms on
    # the corridor flight, 13 ms median (`recognize`'s blobs, features and plaque quads, the tracks
    # masked out; 11-32 ms with `beside_search_shrink` 1); every 1 s rather than 0.5 s took the
    # tracker's CPU a frame from 6.99 to 6.18 ms (with `beside_search_shrink` 1), but a
    # sign coming into view beside a tracked one (the room's sign beside a corridor's) would be found
    # up to 1 s after it could be (a lost or weak track asks every `weak_retry_frames`, and nothing
    # tracked every `idle_interval_s`).
    search_interval_s: float = 0.5
    # Searches while nothing is tracked. At 0.1 s a sign coming in at the frame's edge through a wide
    # lens was answered 2 frames after it was fully in view instead of 5 (bench/track.py --lens), the
    # corridor flight's second sign 0 frames instead of 2, for 6 % more of the tracker's CPU; its
    # track, taken up sooner, then placed the camera 3.4 cm off at p90 within 3 m instead of 3.1.
    idle_interval_s: float = 0.2
    # The plaque search's lower gray levels in a search beside followed tracks are cut in the frame
    # shrunk this many times, as the plaque candidates' are (and then cut once for both): at full
    # resolution the levels' connected components were over a third of such a search. On the corridor
    # flight, on it rendered with another seed and on the sample flight every frame's answers and
    # poses stayed the same at 2 (the far signs, 45-50 px wide, found beside each other on the second
    # frame as before), the searches beside tracked signs 13.0 ms median against 19.6; a plaque under
    # about 70 px across that only this search finds may be found later.
    beside_search_shrink: int = 2
    # Recognize calls per detection frame (one more per sign found). One: a search that finds a sign
    # makes a tentative track, which has the next frame searched with it masked out, so a second
    # search on this frame finds a sign beside it one frame sooner. On the corridor flight two took
    # 53 calls (1.36 s of CPU) against one's 47 (1.06 s), each sign first confirmed on the same frame.
    searches_per_frame: int = 1
    # The settings' affine fallback in the searches with nothing tracked. It finds a sign seen 60-80°
    # off its normal where features fail; a flight sees a sign from a less steep view a moment later,
    # and on the corridor flight it found none, while it took 14 % of the tracker's time (its
    # simulated views of the library are computed on first use, then matched on every search that
    # finds nothing). A picture's neighbourhood check keeps it (`_detect`).
    affine_fallback: bool = False
    # Longer side (px) the frame is shrunk to for the full-frame fallback of a search with nothing
    # tracked, for a library of plaques alone (the settings' max_search_size, if smaller, still
    # holds): a plaque the blobs and quads at full resolution did not find is a large one, which
    # half a 640x480 frame still shows. On the corridor flight it halved the searches between signs
    # (100 to 45 ms), finding the same. A picture has its features alone, in the full frame.
    idle_search_size: int = 320
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
    # Pyramid levels above the frame: 2 follow a move of about 40 px a frame (half the window at the
    # top level). The corridor flight's points move 11 px p90, 38 px at most; on box.mp4 three levels
    # gave the same answers on every frame (corners within 0.8 px of each other, 0.004 px median),
    # for 26 % more time, the pyramids costing the points' box grown by their reach.
    lk_levels: int = 2


@dataclass(frozen=True, eq=False)
class SignObservation:
    """One sign reported on one frame: its `label`, `track_id`, `state` ("detected": the detector
    found it on this frame; "tracked": followed from the previous one), `corners` (4, 2) image px
    TL, TR, BR, BL, `H` (3, 3) library px -> image px, the measured `pose` and the `filtered_pose`
    (None when none could be computed), `points`, how many points supported the frame's H, and the
    measured pose as the filters take it (`filter_measurement`)."""

    label: str
    track_id: int
    state: str
    corners: np.ndarray = field(repr=False)
    H: np.ndarray = field(repr=False)
    pose: Pose | None = field(repr=False)
    filtered_pose: Pose | None = field(repr=False)
    points: int
    filter_measurement: Pose | None = field(default=None, repr=False)

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
    intermediates the detector's `recognitions` of the whole frame (empty when it did not search
    it), the ids of the tracks it checked where they are (`checked`, `recognize_near`) and the ids
    of the tentative tracks (`tentative`). With a sign map (`mapped`), the camera in the map frame
    from this frame's signs (`camera_in_map`) and filtered over time (`filtered_camera_in_map`), None
    on a frame without a mapped sign."""

    frame: int
    time_s: float
    signs: list[SignObservation]
    timing_ms: dict[str, float]
    warnings: list[str]
    recognitions: list[Recognition] = field(default_factory=list, repr=False)
    checked: list[int] = field(default_factory=list)
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
    pose_filter: PoseFilter
    seeded: int = 0  # points when last seeded
    born: int = 0  # frame index of its first detection
    detected_at: int = 0  # frame index of its last detection
    detections: int = 0
    confirmed: bool = False
    misses: int = 0
    weak: bool = False
    filtered: Pose | None = None
    outlined: bool = False  # its plaque's outline placed it on the frame it was last followed in
    # Frames followed by its points alone since the detector or its outline last placed it.
    unanchored: int = 0

    @property
    def corners(self) -> np.ndarray:
        return sign_corners(self.sign, self.H)

    def ideal_H(self, camera: Camera) -> np.ndarray:
        """(3, 3) library px -> px of an ideal pinhole camera with `camera`'s K, through the corners:
        the plane's homography. Through a distorting lens no homography maps it to the image's px,
        and `H`, through the corners as seen, is exact at them alone (as `Outline.H`)."""
        return ideal_homography(self.sign, self.H, camera) if camera.has_distortion else self.H


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


def filter_measurement(pose: Pose, unanchored: int, sign: LibrarySign, camera: Camera) -> Pose:
    """`pose` of `sign` as the filter takes it: followed by its points alone for `unanchored` frames,
    as `drifting_measurement` weighs it; placed on this frame (`unanchored` 0), with its corners
    counted FILTER_CORNER_SIGMA_PX less certain besides."""
    if unanchored > 0 or pose.covariance is None:
        return drifting_measurement(pose, unanchored)
    return dataclasses.replace(pose, covariance=with_corner_floor(pose.covariance, pose.R, pose.t, sign, camera,
                                                                  FILTER_CORNER_SIGMA_PX))


def drifting_measurement(pose: Pose, unanchored: int) -> Pose:
    """`pose` as the filter takes it from a track followed by its points alone for `unanchored` frames
    since it was last placed (by the detector or its outline): the σ of its rotation times 1 +
    `unanchored`, that of its t times √(1 + `unanchored`) (covariance blocks scaled accordingly).

    Such poses are not independent measurements: each carries its anchor's error and the points'
    drift since, so their errors run together from frame to frame (on the corridor flight a sign
    4.5-7 m away drifted 103 mm a frame median, then jumped 2.6-2.9 m when re-anchored), while the
    filter takes each as new evidence and followed the drift as a velocity. The drift is in the
    sign's tilt, which a few points on a small sign hardly pin and which builds up frame after
    frame (its variance grows as the square of the frames); t, where the points are, is each
    frame's own. Replayed through the filter on the corridor flight, against both weighted by
    1 + `unanchored` in variance, this took the filtered jitter over every frame from 54 to 37 mm
    p90 (median 5.5 and 5.4 mm), within 3 m from 6.5 to 6.2 mm p90."""
    if unanchored <= 0 or pose.covariance is None:
        return pose
    scale = np.repeat([1.0 + unanchored, math.sqrt(1.0 + unanchored)], 3)
    return dataclasses.replace(pose, covariance=pose.covariance * np.outer(scale, scale))


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
        self.given_camera = camera
        self.camera: Camera | None = None
        rate = fps if fps is not None and fps > 0 and math.isfinite(fps) else 30.0
        # A filter starts again after a gap it cannot bridge: MAX_GAP_S, or as many frames as a track
        # outlives unseen where frames come further apart (a folder of photos at 1 a second).
        self.max_gap_s = max(MAX_GAP_S, self.config.drop_after_misses / rate)
        self.sign_map, self.map_filter = sign_map, PoseFilter(max_gap_s=self.max_gap_s)
        self.detect_every = max(1, round(self.config.detect_interval_s * rate))
        self.search_every = max(1, round(self.config.search_interval_s * rate))
        self.idle_every = max(1, round(self.config.idle_interval_s * rate))
        self.tracks: list[Track] = []
        self.next_id = 1
        self.last_detect: int | None = None
        self.last_time_s: float | None = None

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
        if self.last_time_s is not None and time_s < self.last_time_s:
            # A bag's stamps out of order: the filters take it as no time passed, and the pose as it is.
            warnings.append(f"frame {index} is stamped {self.last_time_s - time_s:.3f} s before an earlier frame: "
                            "taken as no time passed")
        self.last_time_s = time_s if self.last_time_s is None else max(self.last_time_s, time_s)

        followed: dict[int, Followed] = {}
        for track in self.tracks:
            result = self._follow(track, gray, camera)
            if result is not None:
                followed[track.track_id] = result
        t_tracked = time.perf_counter()

        recognitions: list[Recognition] = []
        detected: set[int] = set()
        checks = self._checks_due(index, followed)
        search = self._search_due(index, followed)
        if checks or search:
            if search:
                self.last_detect = index
            recognitions, detected = self._detect(gray, camera, followed, index, checks, search)
            for track in self.tracks:
                if track.track_id in detected:
                    track.detected_at = index
        t_detected = time.perf_counter()

        signs = self._settle(gray, camera, followed, detected, time_s, warnings)
        located = filtered = None
        if self.sign_map is not None:
            located = locate_in_map(found=signs, sign_map=self.sign_map, library=self.library, camera=camera)
            if located is not None:
                # The filter takes the camera as the signs' poses as the filters take them place it: their
                # errors run on from frame to frame, which the frame's own fit cannot know.
                measured = locate_in_map(found=[dataclasses.replace(s, pose=s.filter_measurement) for s in signs],
                                         sign_map=self.sign_map, library=self.library, camera=camera) or located
                filtered = CameraInMap(self.map_filter.update(measured.pose, time_s), measured.signs_used,
                                       measured.signs_rejected)
        t_end = time.perf_counter()
        tracking = (t_tracked - t_start) + (t_end - t_detected)
        timing = {"detect": (t_detected - t_tracked) * 1e3, "track": tracking * 1e3, "total": (t_end - t_start) * 1e3}
        return FrameResult(index, time_s, signs, timing, warnings, recognitions, [t.track_id for t in checks],
                           [t.track_id for t in self.tracks if not t.confirmed], self.sign_map is not None, located,
                           filtered)

    def _checks_due(self, index: int, followed: dict[int, Followed]) -> list[Track]:
        """The tracks the detector checks where they are on this frame: each tentative one (to confirm
        it), and each healthy confirmed one followed by its points alone (a picture, or a plaque whose
        edges were not found), every `detect_every` frames, which re-anchors it on the library image
        before its points' drift builds up. A track held by its plaque's outline needs no check."""
        def drifting(t: Track) -> bool:
            step = followed.get(t.track_id)
            return (step is not None and not step.weak and step.outline is None
                    and index - t.detected_at >= self.detect_every)

        return [t for t in self.tracks if not t.confirmed or drifting(t)]

    def _search_due(self, index: int, followed: dict[int, Followed]) -> bool:
        """Whether the detector searches the whole frame (the followed tracks masked out) on this one."""
        # While a track is tentative, every frame: signs come into view together, and a small one
        # is found on some frames only.
        if self.last_detect is None or any(not t.confirmed for t in self.tracks):
            return True
        # A lost or weak track asks again only some frames after its last detection: one leaving
        # the frame weakens on every frame, and the detector cannot do better with it.
        last = self.last_detect
        if any((t.track_id not in followed or followed[t.track_id].weak)
               and index - max(t.detected_at, last) >= self.config.weak_retry_frames for t in self.tracks):
            return True
        every = self.search_every if any(t.confirmed for t in self.tracks) else self.idle_every
        return index - self.last_detect >= every

    # -- following ---------------------------------------------------------------------------

    def _follow(self, track: Track, gray: np.ndarray, camera: Camera) -> Followed | None:
        """Track's points from its reference frame onto `gray`, its new H, or None (a miss)."""
        cfg = self.config
        if len(track.points) < cfg.min_points or track.reference.shape != gray.shape:
            return None
        height, width = gray.shape
        lk = {"winSize": (cfg.lk_window_px, cfg.lk_window_px), "maxLevel": cfg.lk_levels,
              "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)}
        # Both frames cut to the points' box grown by the farthest move the pyramid follows (half a
        # window at its top level): its pyramids cost the box's area, not the whole frame's.
        reach = (cfg.lk_window_px // 2 + 1) << cfg.lk_levels
        x0, y0 = np.maximum(np.floor(track.points.min(axis=0)).astype(int) - reach, 0)
        x1, y1 = np.minimum(np.ceil(track.points.max(axis=0)).astype(int) + reach + 1, [width, height])
        before, after = track.reference[y0:y1, x0:x1], gray[y0:y1, x0:x1]
        p0 = (track.points - (x0, y0)).astype(np.float32).reshape(-1, 1, 2)
        p1, status, _ = cv2.calcOpticalFlowPyrLK(before, after, p0, None, **lk)
        if p1 is None:
            return None
        good = status.ravel() == 1
        if not (track.outlined and uses_outline(track.sign, self.settings)):
            # Checked backward where the points alone place the sign. Where its outline does, they
            # only start the search for its edges, and RANSAC drops the strays among them.
            back, status_back, _ = cv2.calcOpticalFlowPyrLK(after, before, p1, None, **lk)
            fb = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
            good &= (status_back.ravel() == 1) & (fb < cfg.forward_backward_px)
        if good.sum() < cfg.min_points:
            return None
        src, dst = track.src[good], p1.reshape(-1, 2)[good].astype(np.float64) + (x0, y0)
        # USAC_FAST: 0.03 ms a call on the corridor flight's tracks (12 points median) against cv2.RANSAC's
        # 0.15, with the same recall and position errors there. Fitted in the ideal pinhole's px, where
        # the plane's points keep to a homography whatever the lens (a sign filling a frame of k1 -0.25
        # lost its outline there, and its points' H put corners 5-14 px off).
        H, inliers = cv2.findHomography(src, undistort_pixels(dst, camera), cv2.USAC_FAST, cfg.ransac_px)
        if H is None:
            return None
        if camera.has_distortion:
            H = seen_homography(track.sign, H, camera)
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
        if uses_outline(track.sign, self.settings):
            # The plaque's edges put H where the sign is now, not where the points drifted to.
            outline, _ = refine_outline(gray, track.sign, H, self.settings.seed, camera,
                                            gamma=self.settings.edge_gamma)
            if outline is not None:
                return Followed(outline.H, src[inl], dst[inl], weak, outline)
        return Followed(H, src[inl], dst[inl], weak)

    def _seed(self, track: Track, gray: np.ndarray, camera: Camera) -> None:
        """New points for `track`: corners inside its quad in `gray`, their library px through its H."""
        cfg = self.config
        height, width = gray.shape
        # Looked for in the quad's box alone (the corner measure over the whole frame costs more than
        # the tracking itself), with a margin that keeps the image's border off the plaque's corners.
        x0, y0, x1, y1 = quad_box(track.corners, width, height)
        x0, y0 = max(0, x0 - SEED_MARGIN_PX), max(0, y0 - SEED_MARGIN_PX)
        x1, y1 = min(width, x1 + SEED_MARGIN_PX), min(height, y1 + SEED_MARGIN_PX)
        points = np.zeros((0, 2), np.float32)
        if x1 > x0 and y1 > y0:
            mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
            cv2.fillConvexPoly(mask, np.round(track.corners - (x0, y0)).astype(np.int32), 255)
            found = cv2.goodFeaturesToTrack(gray[y0:y1, x0:x1], cfg.max_points, 0.01, 5, mask=mask, blockSize=5)
            if found is not None:
                points = (found.reshape(-1, 2) + (x0, y0)).astype(np.float32)
        track.points, track.seeded = points, len(points)
        track.src = cv2.perspectiveTransform(undistort_pixels(points, camera).reshape(-1, 1, 2),
                                             np.linalg.inv(track.ideal_H(camera))).reshape(-1, 2)
        track.reference = gray

    # -- detecting ---------------------------------------------------------------------------

    def _detect(self, gray: np.ndarray, camera: Camera, followed: dict[int, Followed], index: int, checks: list[Track],
                search: bool) -> tuple[list[Recognition], set[int]]:
        """Run the detector on `gray`: around each of the `checks` (`recognize_near`), then, when
        `search`, over the frame with the healthy followed tracks masked out, as long as it finds signs
        and the budget allows. Returns (the recognitions of the whole frame, the ids of tracks found)."""
        height, width = gray.shape
        # A plaque seen steeply is found by the plaque fallback's quads; a picture has its features
        # alone, and keeps the settings' affine fallback for steep views of it.
        plaque_check = dataclasses.replace(self.settings, affine_fallback=False)
        # A check's pose is fitted from the track's own (`_claim`): `recognize`'s would go unused.
        nearby = [recognize_near(gray, self.library, self.settings if t.sign.kind == "picture" else plaque_check,
                                 camera, quad=sign_corners(t.sign, followed[t.track_id].H if t.track_id in followed
                                                           else t.H), with_pose=False)
                  for t in checks]
        seen = [(n.recognition, n.H, n.corners, n.outline) for n in nearby]
        recognitions: list[Recognition] = []
        if search:
            hidden = [sign_corners(t.sign, followed[t.track_id].H) for t in self.tracks
                      if t.track_id in followed and not followed[t.track_id].weak]
            # Beside tracked signs the search is for new ones, which come into view as plaques of
            # their own; the affine fallback, for steep views where features fail, costs more than
            # the rest of such a search.
            affine = self.settings.affine_fallback and self.config.affine_fallback and not hidden
            size = self.settings.max_search_size
            if not hidden and all(sign.kind == "plaque" for sign in self.library.signs):
                size = int(min(size or math.inf, self.config.idle_search_size))
            settings = dataclasses.replace(self.settings, affine_fallback=affine, max_search_size=size)
            recognitions = recognize_every_sign(gray, self.library, settings, camera, known=hidden,
                                                most=self.config.searches_per_frame,
                                                plaque_search_shrink=self.config.beside_search_shrink if hidden else 1)
            seen += [(rec, rec.H, rec.corners, rec.outline) for rec in recognitions]
        # A sign mostly out of the frame would be lost again on the next frame: it is not followed.
        found = {self._claim(rec, H, corners, outline, width, height, gray, camera, index).track_id
                 for rec, H, corners, outline in seen if rec.label is not None and H is not None and corners is not None
                 and visible_fraction(corners, width, height) >= self.config.min_visible}
        # A tentative track the detector has not found `confirm_frames` times within
        # `confirm_window` frames is a look-alike (or too uncertain to report) and goes.
        for track in list(self.tracks):
            if track.track_id in found:
                track.detections += 1
                track.confirmed = track.confirmed or track.detections >= self.config.confirm_frames
            elif not track.confirmed and index - track.born + 1 >= self.config.confirm_window:
                self.tracks.remove(track)
        return recognitions, found

    def _claim(self, rec: Recognition, H: np.ndarray, corners: np.ndarray, outline: Outline | None, width: int,
               height: int, gray: np.ndarray, camera: Camera, index: int) -> Track:
        """The track a detection belongs to, re-anchored on it, or a new tentative one: `rec` names the
        sign and gives its pose; `H` (3, 3), `corners` (4, 2) and the plaque `outline` that placed it
        (or None) are in `gray`'s px."""
        assert rec.label is not None
        sign = self.library[rec.label]
        box = quad_box(corners, width, height)
        same = [t for t in self.tracks if box_iou(box, quad_box(t.corners, width, height)) > SAME_SIGN_IOU]
        mine = next((t for t in same if t.sign.id == sign.id), None)
        for other in same:
            if other is not mine and not other.confirmed:
                self.tracks.remove(other)  # a tentative track the detector now reads as another sign
        H = H / H[2, 2]
        # The pose refitted to the detection's H from the track's own (a new track's: the detection's;
        # without either, as from a check, which estimates none, estimated afresh), so the ambiguity
        # stays settled. Its corners count with the σ `recognize` gives them: from the outline's edges
        # (their RMS off the pose's sides, which a check leaves to be measured here), else as a dense
        # alignment's.
        start = rec.pose if mine is None else mine.pose or rec.pose
        pose = rec.pose
        # Through a distorting lens the outline's H is exact at its corners alone; its grid is not.
        src, dst = outline.grid(sign, camera) if outline is not None else grid_correspondences(H, sign)
        try:
            if start is None:
                start = estimate_pose(H, src, dst, sign, camera, self.settings.pose_method,
                                      self.settings.ambiguity_ratio)
            if outline is None:
                sigma = CORNER_SIGMA_PX["dense"]
            elif rec.pose is not None:
                sigma = outline_corner_sigma(rec.pose.reprojection_rmse_px)
            else:
                start = pose_near(start.R, start.t, src, dst, sign, camera, with_covariance=False)
                sigma = outline_corner_sigma(outline_fit(start.R, start.t, outline, sign, camera)[0])
            pose = pose_near(start.R, start.t, src, dst, sign, camera, sigma)
        except PoseError:
            pass
        if mine is None:
            mine = Track(self.next_id, sign, H, pose, np.zeros((0, 2), np.float32), np.zeros((0, 2)), gray,
                         born=index, pose_filter=PoseFilter(max_gap_s=self.max_gap_s))
            self.next_id += 1
            self.tracks.append(mine)
        else:
            mine.pose, mine.H = pose, H
        mine.misses, mine.weak, mine.outlined, mine.unanchored = 0, False, outline is not None, 0
        self._seed(mine, gray, camera)
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
            measured = None
            if track.pose is not None:
                measured = filter_measurement(track.pose, track.unanchored, track.sign, camera)
                track.filtered = track.pose_filter.update(measured, time_s)
            elif track.pose_filter.started:
                # No pose measured on this frame: the filter's prediction, as uncertain as the time since says.
                track.pose_filter.predict(time_s)
                track.filtered = track.pose_filter.pose()
            if not track.confirmed:
                continue
            state = "detected" if track.track_id in detected else "tracked"
            points = len(step.dst) if step is not None and state == "tracked" else len(track.points)
            signs.append(SignObservation(track.sign.id, track.track_id, state, track.corners, track.H, track.pose,
                                         track.filtered, points, measured))
        return signs

    def _advance(self, track: Track, step: Followed, gray: np.ndarray, camera: Camera, warnings: list[str]) -> None:
        """Move `track` onto the frame it was followed to."""
        track.H, track.misses, track.weak, track.outlined = step.H, 0, step.weak, step.outline is not None
        track.unanchored = 0 if track.outlined else track.unanchored + 1
        src = step.src
        if step.outline is not None:
            # The points' library px re-read through the outline: their drift does not build up.
            src = cv2.perspectiveTransform(undistort_pixels(step.dst, camera).reshape(-1, 1, 2),
                                           np.linalg.inv(step.outline.ideal_H)).reshape(-1, 2)
        try:
            # A track whose pose was lost on an earlier frame has it estimated afresh: else it stayed
            # without one for as long as it was followed.
            start = track.pose or estimate_pose(step.H, src, step.dst, track.sign, camera, self.settings.pose_method,
                                                self.settings.ambiguity_ratio, with_covariance=False)
            track.pose = self._tracked_pose(track.sign, start, step, src, camera)
            if track.pose.reprojection_rmse_px > self.config.max_rmse_px:
                track.weak = True
        except PoseError as exc:
            warnings.append(f"track {track.track_id} ({track.sign.id}): no pose: {exc}")
            track.pose = None
        if step.weak:
            self._seed(track, gray, camera)
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
        pose = pose_near(start.R, start.t, grid_src, grid_dst, sign, camera, with_covariance=False)
        return outline_pose(pose, step.outline, sign, camera)


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
