"""Stage 2: local features (SIFT by default, ORB as an option), in a crop or the full frame.

Keypoints are returned as plain arrays in full-image pixel coordinates (OpenCV convention,
pixel centres at integers), so results pickle cheaply to worker processes; a library sign's in
library px, whose pixel u spans [u, u + 1] (`at_pixel_edges`, docs/conventions.md).
"""

from __future__ import annotations

import dataclasses

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .library import Library, LibrarySign
from .segment import Box
from .settings import Settings
from .stages import stage_key

# Beyond this, upscaling invents no detail and only costs time.
MAX_UPSCALE = 4.0
# `max_features` is a budget for this many px (a 640 x 480 frame); a picture landmark, and a view
# searched for one, get as many more as their area holds, up to the setting's bound. A photo's
# keypoints spread over all of it: at 2000 on the homogr pair Eiffel (1198 x 958, 15 % of A in B's
# view) 48 inliers put its points 5.9 px off, at its area's 7500 370 inliers 1.5 px.
BUDGET_AREA_PX = 640 * 480
MAX_BUDGET = 20000
# The simulated views of `sign_affine_features`, as ASIFT samples them (Morel and Yu, 2009): tilts
# sqrt(2)^k for k in AFFINE_TILTS, 2 to 4 (a plane seen 60 to 76 degrees off its normal; the ordinary
# features cover less), each at in-plane rotations AFFINE_ROTATE_STEP_DEG / tilt apart.
AFFINE_TILTS = (2, 4)
AFFINE_ROTATE_STEP_DEG = 72.0
# A library image is simulated at most this many px on its longer side: a sign seen that steeply is
# far narrower across than its library image. On 60 synthetic steep scenes 400 px found as many as
# 560 (53), at a tenth of the 22 views' cost for an 800 x 320 px sign (0.14 against 1.3 s).
AFFINE_MAX_SIDE = 400


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and descriptors of one image region.

    xy: (N, 2) float32 full-image px; size: (N,) keypoint diameter in full-image px;
    descriptors: (N, D) float32 (SIFT) or uint8 (ORB); region: the `Box` searched;
    scale: the factor the region was resized by before detection.
    """

    xy: np.ndarray = field(repr=False)
    size: np.ndarray = field(repr=False)
    descriptors: np.ndarray = field(repr=False)
    region: Box
    scale: float
    detector: str

    def __len__(self) -> int:
        return len(self.xy)

    @property
    def norm(self) -> int:
        return cv2.NORM_HAMMING if self.detector == "orb" else cv2.NORM_L2


def create_detector(settings: Settings):
    if settings.detector == "orb":
        return cv2.ORB_create(nfeatures=settings.max_features)
    return cv2.SIFT_create(nfeatures=settings.max_features, contrastThreshold=settings.contrast_threshold)


def no_features(region: Box, scale: float, detector: str) -> Features:
    """The Features of a `region` in which `detector` found no keypoint."""
    dim, dtype = (32, np.uint8) if detector == "orb" else (128, np.float32)
    return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros((0, dim), dtype),
                    region, scale, detector)


def region_scale(long_side: int, settings: Settings, full_frame: bool = False) -> float:
    """The factor a region whose longer side is `long_side` px is resized by before detection.

    Below `settings.min_crop_size` it is upscaled (at most `MAX_UPSCALE` times), so a sign 60 px
    wide still yields enough keypoints. A crop above `settings.max_crop_size` (when not 0) is
    downscaled: SIFT's cost grows with the area, and a blob that large is a sign seen large
    enough to match from fewer pixels. The full frame is shrunk by `settings.full_frame_scale`
    alone, since a small sign anywhere in it needs its pixels (at 0.75 a frame without a sign took
    half the CPU, and `bench/worlds.py` missed, net, 2 easy, 3 hard and 1 steep view more of its
    300 scenes), and at most to `settings.max_search_size` (when not 0), which bounds any region:
    SIFT doubles its input first and holds about 11 float copies of that, so a 12 MP photo would
    take 2.8 GB.
    """
    if 0 < long_side < settings.min_crop_size:
        return min(settings.min_crop_size / long_side, MAX_UPSCALE)
    if 0 < settings.max_crop_size < long_side and not full_frame:
        return settings.max_crop_size / long_side
    scale = settings.full_frame_scale if full_frame else 1.0
    if 0 < settings.max_search_size < long_side * scale:
        return settings.max_search_size / long_side
    return scale


def detect(gray: np.ndarray, settings: Settings, region: Box | None = None, resize: bool = True,
           scale: float | None = None) -> Features:
    """Detect and describe keypoints of an (H, W) uint8 image inside `region` (default: all of it),
    resized first by `scale` when given, else by `region_scale` unless `resize` is False."""
    h, w = gray.shape
    x0, y0, x1, y1 = region if region is not None else (0, 0, w, h)
    patch = gray[y0:y1, x0:x1]
    if scale is None:
        scale = region_scale(max(patch.shape), settings, patch.shape == gray.shape) if resize else 1.0
    if scale != 1.0:
        patch = cv2.resize(patch, None, fx=scale, fy=scale,
                           interpolation=cv2.INTER_CUBIC if scale > 1 else cv2.INTER_AREA)
    keypoints, descriptors = create_detector(settings).detectAndCompute(patch, None)
    if descriptors is None or not keypoints:
        return no_features((x0, y0, x1, y1), scale, settings.detector)
    return resized_features(keypoints, descriptors, (x0, y0, x1, y1), scale, settings.detector)


def resized_features(keypoints: Sequence[cv2.KeyPoint], descriptors: np.ndarray, region: Box, scale: float,
                     detector: str) -> Features:
    """The Features of `keypoints` and their (N, D) `descriptors`, detected in `region` (x0, y0, x1, y1
    px) resized by `scale`, with their positions and sizes in the full image's px."""
    pts = cv2.KeyPoint_convert(keypoints).reshape(-1, 2)
    # cv2.resize aligns pixel centres: x_src = (x_dst + 0.5) / scale - 0.5.
    xy = (pts + 0.5) / scale - 0.5 + np.array(region[:2], dtype=np.float32)
    size = np.array([k.size for k in keypoints], dtype=np.float32) / scale
    return Features(xy, size, descriptors, region, scale, detector)


def picture_budget(settings: Settings, width: int, height: int) -> Settings:
    """`settings` with `max_features` grown for a `width` x `height` px view of a picture (see BUDGET_AREA_PX)."""
    wanted = round(settings.max_features * width * height / BUDGET_AREA_PX)
    return settings.replace(max_features=min(MAX_BUDGET, wanted)) if wanted > settings.max_features else settings


def search_settings(settings: Settings, library: Library, region: Box) -> Settings:
    """The settings `region` (x0, y0, x1, y1 px) is searched with: a library holding a picture gets
    `picture_budget`'s features there, as its pictures get them (`sign_features`)."""
    if all(sign.kind != "picture" for sign in library.signs):
        return settings
    x0, y0, x1, y1 = region
    return picture_budget(settings, x1 - x0, y1 - y0)


def sign_features(sign: LibrarySign, settings: Settings) -> Features:
    """Features of a library sign image, in library pixels (never resized); a picture's with
    `picture_budget`'s features."""
    if sign.kind == "picture":
        settings = picture_budget(settings, *sign.size_px)
    return at_pixel_edges(detect(sign.image, settings, resize=False))


def library_features(library: Library, settings: Settings) -> dict[str, Features]:
    """Features of every library sign, computed once per feature settings and cached on the library."""
    return library.per_sign(("features", *stage_key(settings, "library features")),
                            lambda sign: sign_features(sign, settings))


def sign_affine_features(sign: LibrarySign, settings: Settings) -> Features:
    """Features of simulated steep views of a library sign (`AFFINE_TILTS`), detected as
    `sign_features` detects them in each view, their keypoints mapped back to library px, so a
    homography fitted to their matches maps library px to image px as the ordinary ones do.

    A view 60-80 degrees off a sign's normal compresses it 2-6 times across: SIFT's descriptors,
    invariant to similarity only, no longer match the frontal sign's, but match a view of it
    compressed alike. The image's own features serve as they are: only the library is simulated.
    """
    if sign.kind == "picture":
        settings = picture_budget(settings, *sign.size_px)
    low, high = AFFINE_TILTS
    simulated = cv2.AffineFeature_create(create_detector(settings), high, low, 2 ** 0.5, AFFINE_ROTATE_STEP_DEG)
    image = sign.image
    scale = min(1.0, AFFINE_MAX_SIDE / max(image.shape))
    if scale < 1.0:
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    # AffineFeature maps each view's keypoints back to the image it was given
    keypoints, descriptors = simulated.detectAndCompute(image, None)
    region = (0, 0, *sign.size_px)
    if descriptors is None or not keypoints:
        return no_features(region, scale, settings.detector)
    return at_pixel_edges(resized_features(keypoints, descriptors, region, scale, settings.detector))


def at_pixel_edges(features: Features) -> Features:
    """A library sign's `features` with their positions in the library's px, whose pixel i spans [i, i + 1]
    (`LibrarySign.corners_px` at 0 and the width), from OpenCV's, which put pixel i's centre at i."""
    return dataclasses.replace(features, xy=features.xy + np.float32(0.5))


def library_affine_features(library: Library, settings: Settings) -> dict[str, Features]:
    """`sign_affine_features` of every library sign, computed once per feature settings (those of
    `library_features`) and cached on the library; only when the affine fallback first needs them."""
    return library.per_sign(("affine features", *stage_key(settings, "library features")),
                            lambda sign: sign_affine_features(sign, settings))
