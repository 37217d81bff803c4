"""Stage 1: threshold segmentation, bright candidate blobs and crops (the paper's first step).

The paper normalises gray levels, thresholds at 0.75, keeps the largest white connected
component and crops its bounding box. Beyond the paper we keep the K largest blobs as
candidates, so a larger white object (a door, a whiteboard) does not hide the sign.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .settings import Settings

Box = tuple[int, int, int, int]
"""(x0, y0, x1, y1) in image pixels, half-open: columns x0..x1-1, rows y0..y1-1."""


@dataclass(frozen=True)
class Blob:
    """One white connected component: `area` in px, `bbox` as a `Box`, `label` in `Segmentation.labels`."""

    label: int
    area: int
    bbox: Box


# `Segmentation.labels` of a white pixel in no candidate blob (candidates are labelled 1, 2, ...).
OTHER_WHITE = 255


@dataclass(frozen=True, eq=False)
class Segmentation:
    """Intermediates of segmentation, all (H, W) like the input.

    source: the uint8 gray image segmented; normalization: its `normalize_gray` mode;
    labels: uint8, 0 below the threshold, k for the pixels of candidate blob k (`blobs[k - 1]`,
    whose `label` is k) and OTHER_WHITE for the other white pixels; blobs: candidate blobs,
    largest first; crops: one `Box` per blob, with margin, clipped to the image.

    A server keeps one per image held, so it keeps one byte a pixel besides `source`: the mask is
    derived on use (the normalised gray from `normalize_gray` or `normalize_levels`), and the
    labels of the components that are not candidates, which nothing reads, are not kept (as
    int32 they were four bytes a pixel).
    """

    source: np.ndarray = field(repr=False)
    normalization: str
    labels: np.ndarray = field(repr=False)
    blobs: list[Blob]
    crops: list[Box]

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8 0/255: the white pixels, those at or above the threshold."""
        return cv2.threshold(self.labels, 0, 255, cv2.THRESH_BINARY)[1]


def normalize_gray(gray: np.ndarray, mode: str) -> np.ndarray:
    """(H, W) uint8 -> float32 in [0, 1]. "scale": /255. "minmax": (g - min) / (max - min), the paper's remap."""
    return normalize_levels(gray, mode)[gray]


def normalize_levels(gray: np.ndarray, mode: str) -> np.ndarray:
    """(256,) float32: what `normalize_gray` maps each uint8 level of `gray` to."""
    levels = np.arange(256, dtype=np.float32)
    if mode == "scale":
        return levels / 255.0
    lo, hi = (float(v) for v in cv2.minMaxLoc(gray)[:2])
    if hi <= lo:
        return np.zeros(256, np.float32)
    return (levels - lo) / (hi - lo)


def threshold_lut(gray: np.ndarray, mode: str, threshold: float, high_threshold: float | None) -> np.ndarray:
    """(256,) uint8 lookup table: 255 for the levels of uint8 `gray` whose normalised value passes
    `threshold_mask`. Applied with cv2.LUT it gives the same mask without a float image."""
    return threshold_mask(normalize_levels(gray, mode), threshold, high_threshold)


def threshold_mask(gray01: np.ndarray, threshold: float, high_threshold: float | None) -> np.ndarray:
    """(H, W) float [0, 1] -> uint8 mask, 255 where threshold <= g (<= high_threshold when given)."""
    mask = gray01 >= threshold
    if high_threshold is not None:
        mask &= gray01 <= high_threshold
    return mask.astype(np.uint8) * 255


def expand_box(bbox: Box, margin: float, width: int, height: int) -> Box:
    """Grow `bbox` by `margin` times its size on every side, clipped to a `width` x `height` image."""
    x0, y0, x1, y1 = bbox
    mx, my = round((x1 - x0) * margin), round((y1 - y0) * margin)
    return max(0, x0 - mx), max(0, y0 - my), min(width, x1 + mx), min(height, y1 + my)


def box_iou(a: Box, b: Box) -> float:
    """Intersection over union of two boxes."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def label_components(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(labels (H, W) uint16, int32 beyond 65535 components; stats (N + 1, 5) as
    cv2.connectedComponentsWithStats) of the 8-connected components of an (H, W) uint8 mask;
    label 0 is the background."""
    # OpenCV labels int32 in parallel, uint16 not: on 640x480 masks on 2 cores (AMD EPYC) uint16
    # took 0.73 ms at 1 and 2 OpenCV threads, int32 (Grana's, its fastest) 0.74 ms one-threaded
    # but 1.27 ms two-threaded; same labels and stats. OpenCV refuses a mask of more components
    # than uint16 holds, which is labelled again as int32.
    try:
        _, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_16U, cv2.CCL_SPAGHETTI)
    except cv2.error:
        _, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)
    return labels, stats


def component_blob(stats: np.ndarray, label: int) -> Blob:
    """The `Blob` of component `label` from `label_components`' stats."""
    x, y, bw, bh, area = (int(v) for v in stats[label])
    return Blob(label=label, area=area, bbox=(x, y, x + bw, y + bh))


def segment(gray: np.ndarray, settings: Settings) -> Segmentation:
    """Find candidate sign regions in an (H, W) uint8 gray image."""
    h, w = gray.shape
    mask = cv2.LUT(gray, threshold_lut(gray, settings.normalization, settings.threshold, settings.high_threshold))
    labels, stats = label_components(mask)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = np.argsort(-areas, kind="stable")
    min_area = max(16, settings.min_blob_area * h * w)
    blobs: list[Blob] = []
    for i in order[: settings.candidates]:
        if areas[i] < min_area:
            break
        blob = component_blob(stats, int(i + 1))
        # The mask becomes the kept labels: OTHER_WHITE (its 255) but where a candidate is, whose
        # pixels go from 255 to their label k by subtracting 255 - k (in OpenCV: numpy's boolean
        # assignment took 8-11 % of the whole segmentation).
        x0, y0, x1, y1 = blob.bbox
        inside = cv2.compare(labels[y0:y1, x0:x1], blob.label, cv2.CMP_EQ)
        cv2.subtract(mask[y0:y1, x0:x1], cv2.bitwise_and(inside, 255 - (len(blobs) + 1)), dst=mask[y0:y1, x0:x1])
        blobs.append(Blob(len(blobs) + 1, blob.area, blob.bbox))
    crops = [expand_box(b.bbox, settings.crop_margin, w, h) for b in blobs]
    return Segmentation(source=gray, normalization=settings.normalization, labels=mask, blobs=blobs, crops=crops)
