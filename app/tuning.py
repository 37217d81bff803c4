"""Helping a person choose settings: threshold calibration from a sign's gray levels, and sweeps.

Gray levels are the pipeline's normalised gray in [0, 1] (`pipeline.segment.normalize_gray`).
A request that cannot be answered as asked raises TuningError, which the server answers with 422.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from signpose.pipeline.image import to_gray
from signpose.pipeline.recognize import Recognition
from signpose.pipeline.segment import Box, normalize_levels
from signpose.pipeline.settings import Settings, SettingsError, check_setting, settings_schema

from .image_store import Answer, is_correct

HISTOGRAM_BINS = 256
# The paper measured the sign at 0.8 and thresholded at 0.75: just below the sign's white.
WHITE_MARGIN = 0.05
# The ring of surroundings compared with the sign is this fraction of the region's size wide.
RING_FRACTION = 0.15
MIN_RING_PX = 4
BACKGROUND_PERCENTILE = 90
# The smallest box, px a side, whose gray levels say anything of a sign.
MIN_BOX_PX = 2
MAX_SWEEP_STEPS = 101
NUMERIC_SETTINGS = [f["name"] for f in settings_schema() if f["type"] in ("int", "float")]
INTEGER_SETTINGS = {f["name"] for f in settings_schema() if f["type"] == "int"}


class TuningError(ValueError):
    """A threshold or sweep request that cannot be answered as asked; the message says what to send."""


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

    The detected sign's quad when there is one, else the blob the answer came from, else the
    largest candidate blob: the segmentation figure draws them all, and an answer from a plaque
    candidate or the full frame leaves none of them its own.
    """
    if recognition.corners is not None:
        mask = np.zeros((height, width), np.uint8)
        cv2.fillPoly(mask, [np.round(recognition.corners).astype(np.int32)], 1)
        if mask.any():
            return mask.astype(bool), "detected sign"
    seg, attempt = recognition.segmentation, recognition.attempt
    if seg is None or not seg.blobs:
        return None
    if attempt is not None and attempt.source.startswith("blob "):
        blob = seg.blobs[int(attempt.source.split()[1]) - 1]
        return seg.labels == blob.label, "blob"
    return seg.labels == seg.blobs[0].label, "blob"


def rect_mask(rect: Box, width: int, height: int) -> np.ndarray:
    mask = np.zeros((height, width), bool)
    x0, y0, x1, y1 = rect
    mask[y0:y1, x0:x1] = True
    return mask


def box_region(rect: Box, width: int, height: int) -> tuple[np.ndarray, str]:
    """(H, W) bool mask of the box `rect` (x0, y0, x1, y1) px drawn on a `width` x `height` image,
    cut to the image, and what it is; TuningError when less than MIN_BOX_PX a side of it is inside."""
    x0, y0, x1, y1 = rect
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(width, x1), min(height, y1)
    if x1 - x0 < MIN_BOX_PX or y1 - y0 < MIN_BOX_PX:
        raise TuningError(f"rect {list(rect)} does not cover at least {MIN_BOX_PX}x{MIN_BOX_PX} px of the "
                          f"{width}x{height} image; give [x0, y0, x1, y1] in image pixels with x0 < x1 and y0 < y1")
    return rect_mask((x0, y0, x1, y1), width, height), "rectangle"


def found_region(recognition: Recognition, width: int, height: int, name: str) -> tuple[np.ndarray, str]:
    """`sign_region` of the image `name`; TuningError, asking for a box, when the pipeline found nothing."""
    region = sign_region(recognition, width, height)
    if region is None:
        # The page words this for its own users (static/detail.js): they drag a box.
        raise TuningError(f"no sign or white blob was found in {name}; send rect [x0, y0, x1, y1] "
                          "in image pixels around the sign, with some wall in it")
    return region


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


def values_to_sweep(settings: Settings, param: str, lo: float, hi: float, steps: int) -> list[float]:
    """The values of `param` that a sweep of `steps` values from `lo` to `hi` runs beside `settings`.

    TuningError when `param` is no numeric setting, `lo` or `hi` is not finite, or `lo` is not below `hi`; when an end is out of
    the setting's own range, naming it as given (the first value refused was often one between them
    that nobody typed); and when no value goes with the other settings. Values that contradict
    another setting are left out (a max_crop_size swept up from 0, never downscale, passes sizes
    below min_crop_size).
    """
    if param not in NUMERIC_SETTINGS:
        raise TuningError(f"cannot sweep {param!r}; choose a numeric setting: {', '.join(NUMERIC_SETTINGS)}")
    for end, given in (("lo", lo), ("hi", hi)):
        if not math.isfinite(given):
            raise TuningError(f"{end} must be a finite number, got {given}")
    if not lo < hi:
        raise TuningError(f"lo ({lo}) must be below hi ({hi})")
    values = sweep_values(lo, hi, steps, param in INTEGER_SETTINGS)
    for end, given, value in (("lo", lo, values[0]), ("hi", hi, values[-1])):
        try:
            check_setting(param, value)
        except SettingsError as exc:
            raise TuningError(f"{end} ({given:g}): {exc}") from None
    taken = [value for value in values if refusal(settings, param, value) is None]
    if not taken:
        raise TuningError(f"no value of {param} from lo ({lo:g}) to hi ({hi:g}) goes with the other settings: "
                          f"{refusal(settings, param, values[0])}")
    return taken


def refusal(settings: Settings, param: str, value: float) -> SettingsError | None:
    """Why `settings` with `param` set to `value` are invalid; None when they are not."""
    try:
        settings.replace(**{param: value})
    except SettingsError as exc:
        return exc
    return None


@dataclass(frozen=True)
class SweepTally:
    """What a sweep says of the labelled images, per value swept (lists in the values' order).

    correct: images recognised as labelled; failed: images the pipeline failed on (not correct);
    by_plaque: of those correct, the ones the plaque fallback recognised; min_margin: the smallest
    inlier margin among those correct by feature matches, None when there are none.
    band: the longest run of values where every image is correct (`working_band`), None without
    one; centre: its middle (`band_centre`).
    """

    correct: list[int]
    min_margin: list[int | None]
    by_plaque: list[int]
    failed: list[int]
    band: tuple[float, float] | None
    centre: float | None


def tally_sweep(values: list[float], expected: list[str | None], runs: Sequence[Sequence[Answer | None]],
                *, integer: bool) -> SweepTally:
    """Count the `runs` of a sweep ([value index][image index], None where the image could not be
    run) of images labelled `expected` (None, a label cleared since, is never correct), over the
    `values` of a setting that takes whole numbers when `integer`: the page's `Recognition`s, or the
    `Outcome`s of `signpose sweep`."""
    correct: list[int] = []
    min_margin: list[int | None] = []
    by_plaque: list[int] = []
    failed: list[int] = []
    for recs in runs:
        good = [rec for label, rec in zip(expected, recs) if rec is not None and is_correct(label, rec)]
        correct.append(len(good))
        failed.append(sum(rec is None for rec in recs))
        # The plaque fallback matches no features: its margin is no inlier margin.
        min_margin.append(min((rec.margin for rec in good if rec.recognized and not rec.by_plaque), default=None))
        by_plaque.append(sum(rec.by_plaque for rec in good))
    band = working_band(values, [c == len(expected) for c in correct])
    return SweepTally(correct=correct, min_margin=min_margin, by_plaque=by_plaque, failed=failed, band=band,
                      centre=band_centre(values, band, integer))


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
