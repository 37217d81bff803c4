"""Helping a person choose settings: threshold calibration from a sign's gray levels, and sweeps.

Gray levels are the pipeline's normalised gray in [0, 1] (`pipeline.segment.normalize_gray`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from signpose.pipeline.image import to_gray
from signpose.pipeline.recognize import Recognition
from signpose.pipeline.segment import Box, normalize_levels

HISTOGRAM_BINS = 256
# The paper measured the sign at 0.8 and thresholded at 0.75: just below the sign's white.
WHITE_MARGIN = 0.05
# The ring of surroundings compared with the sign is this fraction of the region's size wide.
RING_FRACTION = 0.15
MIN_RING_PX = 4
BACKGROUND_PERCENTILE = 90


@dataclass(frozen=True)
class ThresholdSuggestion:
    """Gray levels of a sign region and the threshold they suggest.

    white_level: the sign's white (median of the brightest half of the region); background_level:
    the bright end (90th percentile) of a ring around the region, None when the region fills
    the image; histogram: 256 counts over [0, 1] inside the region; rect: the region's bounding box.
    """

    white_level: float
    background_level: float | None
    suggested_threshold: float
    histogram: list[int]
    rect: Box
    source: str
    warning: str | None


def sign_region(recognition: Recognition, width: int, height: int) -> tuple[np.ndarray, str] | None:
    """(H, W) bool mask of where the pipeline found the sign, and what it is; None when it found nothing.

    The detected sign's quad when there is one, else the blob of the region searched last.
    """
    if recognition.corners is not None:
        mask = np.zeros((height, width), np.uint8)
        cv2.fillPoly(mask, [np.round(recognition.corners).astype(np.int32)], 1)
        if mask.any():
            return mask.astype(bool), "detected sign"
    seg, attempt = recognition.segmentation, recognition.attempt
    if seg is not None and attempt is not None and attempt.source.startswith("blob "):
        blob = seg.blobs[int(attempt.source.split()[1]) - 1]
        return seg.labels == blob.label, "blob"
    return None


def rect_mask(rect: Box, width: int, height: int) -> np.ndarray:
    mask = np.zeros((height, width), bool)
    x0, y0, x1, y1 = rect
    mask[y0:y1, x0:x1] = True
    return mask


def suggest_threshold(image: np.ndarray, normalization: str, inside: np.ndarray, source: str) -> ThresholdSuggestion:
    """Suggest a segmentation threshold from the gray levels inside the (H, W) bool mask `inside`.

    Slightly below the sign's white, but above the brightest part of its surroundings, so the
    sign comes out as one blob separate from the wall.
    """
    gray8 = to_gray(image)
    levels = normalize_levels(gray8, normalization)
    gray = levels[gray8]  # normalize_gray's, with the levels the histogram needs
    values = gray[inside]
    white = float(np.median(values[values >= np.median(values)]))
    ys, xs = np.nonzero(inside)
    rect = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    ring_px = max(MIN_RING_PX, round(RING_FRACTION * max(rect[2] - rect[0], rect[3] - rect[1])))
    grown = cv2.dilate(inside.astype(np.uint8), np.ones((2 * ring_px + 1, 2 * ring_px + 1), np.uint8)).astype(bool)
    ring = gray[grown & ~inside]
    background = float(np.percentile(ring, BACKGROUND_PERCENTILE)) if ring.size else None
    suggested, warning = white - WHITE_MARGIN, None
    if background is not None and suggested <= background:
        suggested = (white + background) / 2
        if white <= background:
            # A box drawn inside the sign has sign all around it: the commonest cause.
            fixes = "segment_mode 'none'" if normalization == "minmax" else "normalization 'minmax' or segment_mode 'none'"
            warning = ("around the box is as bright as inside it: if the box lies inside the sign, draw it around "
                       "the whole sign, just outside its edge; if it does already, no threshold separates this "
                       f"sign from its wall: try {fixes}")
    return ThresholdSuggestion(
        white_level=round(white, 4),
        background_level=None if background is None else round(background, 4),
        suggested_threshold=round(float(np.clip(suggested, 0.0, 1.0)), 2),
        histogram=level_histogram(gray8[inside], levels).tolist(), rect=rect, source=source,
        warning=warning,
    )


def level_histogram(pixels: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """(HISTOGRAM_BINS,) int64 counts over [0, 1] of the uint8 `pixels` (any shape) normalised by
    `levels` ((256,) float: what each uint8 level becomes, `normalize_levels`), each level's pixels
    spread evenly over the span of normalised values it stands for (half-way to its neighbours'),
    and summing to the pixels.

    Binned as they are, the 62 levels of a dim photo stretched over 256 bins left three bins in four
    empty: a comb that hid the histogram's shape.
    """
    counts = np.bincount(pixels.ravel(), minlength=256)
    levels = levels.astype(np.float64)
    bounds = np.concatenate([[levels[0]], (levels[:-1] + levels[1:]) / 2, [levels[-1]]])
    below = np.interp(np.linspace(0.0, 1.0, HISTOGRAM_BINS + 1)[1:-1], bounds, np.concatenate([[0], np.cumsum(counts)]))
    return np.diff(np.concatenate([[0], np.round(below), [counts.sum()]])).astype(np.int64)


def sweep_values(lo: float, hi: float, steps: int, integer: bool) -> list[float]:
    """`steps` evenly spaced values from `lo` to `hi`; whole and distinct for an integer setting."""
    values = np.linspace(lo, hi, steps)
    if integer:
        return sorted({int(round(v)) for v in values})
    return [round(float(v), 10) for v in values]


def working_band(values: list[float], all_correct: list[bool]) -> tuple[float, float] | None:
    """The longest run of consecutive values (the first on a tie) where every labelled image is right."""
    best: tuple[int, int] | None = None
    start = None
    for i, ok in enumerate([*all_correct, False]):
        if ok and start is None:
            start = i
        elif not ok and start is not None:
            if best is None or i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    return None if best is None else (values[best[0]], values[best[1] - 1])


def band_centre(values: list[float], band: tuple[float, float] | None, integer: bool) -> float | None:
    """The middle of the working `band` of swept `values`, None without a band.

    For an integer setting, the swept value in the band nearest the middle (the lower on a tie):
    the setting takes whole numbers only, and that value was seen to work.
    """
    if band is None:
        return None
    middle = (band[0] + band[1]) / 2
    if not integer:
        return middle
    return min((v for v in values if band[0] <= v <= band[1]), key=lambda v: abs(v - middle))
