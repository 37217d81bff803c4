"""Plaque search: find a sign that neither features nor the plaque fallback found, by its plaque.

A blurred or dim plaque is often not white enough for the segmentation threshold (a lamp or
a white door sets the normalisation's maximum), and its text too soft for features, yet it is
still a bright quadrilateral against its wall at some lower gray level. Here the normalised
image is cut at several levels; every connected component of plausible size whose outline is
a quadrilateral is a candidate. Each candidate is rectified and correlated with every library
sign (as `pipeline.plaque` does); the best-correlating candidates are then aligned densely
(ECC) with their two best signs, and one is accepted only when the aligned correlation is high
and clearly above the other sign's. Correlation at a fixed low resolution cannot separate a
blurred Arabic sign from a plaque of other text (negatives reach 0.69); correlation after
dense alignment can, except on the smallest plaques, which must align better
(`required_correlation`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .library import Library
from .plaque import PlaqueMatch, blob_quad, bounding_box, plaque_correlations, refine_ecc
from .segment import Blob, Segmentation, expand_box
from .settings import Settings

# Normalised gray levels the image is cut at, besides the segmentation threshold.
LEVELS = (0.3, 0.45, 0.6)
# A candidate's area, as a fraction of the image: from a plaque about 40 px wide at 640 x 480
# up to a quarter of the frame.
MIN_AREA_FRACTION = 0.0015
MAX_AREA_FRACTION = 0.25
# Candidates whose outlines overlap this much (intersection over union of their boxes) are one plaque.
SAME_PLAQUE_IOU = 0.7
# Only candidates correlating this well with some sign before alignment are aligned, at most MAX_ALIGNED.
MIN_NCC = 0.45
MAX_ALIGNED = 4
# Plaques smaller than this squared (px²) must align better than settings.min_plaque_ecc; see required_correlation.
FULL_TRUST_PX = 60.0
# Quads wider than this (px) are aligned on a shrunk copy of their neighbourhood.
MAX_ALIGN_WIDTH = 240.0


def _iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def candidate_quads(gray01: np.ndarray, levels: tuple[float, ...],
                    segmentation: Segmentation | None = None, threshold: float | None = None
                    ) -> list[tuple[Blob, np.ndarray]]:
    """(blob, corners (4, 2) image px TL, TR, BR, BL) of every quadrilateral component of plausible
    size of the normalised (H, W) image cut at each level, one per plaque (the first level's).

    At `threshold`, the cut `segmentation` made, only its candidate blobs are taken, as they are.
    """
    h, w = gray01.shape
    lo, hi = MIN_AREA_FRACTION * h * w, MAX_AREA_FRACTION * h * w
    found: list[tuple[Blob, np.ndarray]] = []
    for level in levels:
        if segmentation is not None and level == threshold:
            labels, blobs = segmentation.labels, [b for b in segmentation.blobs if lo <= b.area <= hi]
        else:
            n, labels, stats, _ = cv2.connectedComponentsWithStats((gray01 >= level).view(np.uint8), connectivity=8,
                                                                   ltype=cv2.CV_32S)
            areas = stats[1:, cv2.CC_STAT_AREA]
            blobs = []
            for i in np.flatnonzero((areas >= lo) & (areas <= hi)):
                x, y, bw, bh = (int(v) for v in stats[i + 1, :4])
                blobs.append(Blob(int(i + 1), int(areas[i]), (x, y, x + bw, y + bh)))
        for blob in blobs:
            if any(_iou(blob.bbox, other.bbox) > SAME_PLAQUE_IOU for other, _ in found):
                continue
            quad = blob_quad(labels, blob)
            if quad is not None:
                found.append((blob, quad))
    return found


def _aligned(gray: np.ndarray, corners: np.ndarray, roll: int, sign) -> tuple[np.ndarray | None, float]:
    """(H, ECC correlation) of `sign` aligned densely from the quad in the given corner order; (None, -1) if ECC fails.

    A quad wider than MAX_ALIGN_WIDTH px is aligned in its neighbourhood shrunk to that width:
    the verdict needs no more, and ECC's cost grows with the area (the final H is refined again
    at full resolution by the caller).
    """
    corners = np.roll(corners, -roll, axis=0).astype(np.float64)
    width = float(np.max(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))
    f = min(1.0, MAX_ALIGN_WIDTH / width)
    # image px -> shrunk neighbourhood px (pixel centres aligned as cv2.resize does)
    x0, y0, x1, y1 = expand_box(bounding_box(corners), 0.5, gray.shape[1], gray.shape[0])
    to_small = np.array([[f, 0, (0.5 - x0) * f - 0.5], [0, f, (0.5 - y0) * f - 0.5], [0, 0, 1]])
    patch = gray[y0:y1, x0:x1]
    if f < 1.0:
        patch = cv2.resize(patch, (max(1, round((x1 - x0) * f)), max(1, round((y1 - y0) * f))),
                           interpolation=cv2.INTER_AREA)
    small = cv2.perspectiveTransform(corners[None], to_small)[0]
    start = cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32), small.astype(np.float32)).astype(np.float64)
    refined = refine_ecc(patch, sign, start / start[2, 2])
    if refined is None:
        return None, -1.0
    H = np.linalg.inv(to_small) @ refined[0]
    return H / H[2, 2], refined[1]


def required_correlation(corners: np.ndarray, min_ecc: float) -> float:
    """The aligned correlation a quad (4, 2) image px must reach: `min_ecc` for a plaque of at
    least FULL_TRUST_PX² pixels; for a smaller one, the shortfall from a perfect 1 allowed shrinks
    with its area. With a few hundred pixels ECC's eight degrees of freedom fit other text too:
    plaques of other text 24-30 px across (square root of the area) reached 0.82-0.87 with a
    sign, where true signs of that size, legible only when sharp, reached 0.97-0.99."""
    area = abs(cv2.contourArea(np.asarray(corners, np.float32)))
    return 1.0 - (1.0 - min_ecc) * min(1.0, area / FULL_TRUST_PX**2)


def search_plaques(gray: np.ndarray, segmentation: Segmentation, library: Library,
                   settings: Settings) -> tuple[PlaqueMatch, float] | None:
    """(plaque, its aligned correlation) of the first candidate that reads as a library sign, or None.

    Candidates are tried best correlation first. A candidate is accepted for its best-correlating
    sign when, after ECC alignment, that sign's correlation is at least `settings.min_plaque_ecc`
    (more for small plaques: `required_correlation`) and beats the second-best-correlating sign's, aligned the same way, by
    `settings.plaque_ecc_margin`.
    """
    levels = tuple(sorted({*LEVELS, settings.threshold}, reverse=True))
    scored = []
    for blob, corners in candidate_quads(segmentation.gray, levels, segmentation, settings.threshold):
        scores, rolls = plaque_correlations(gray, corners, library)
        scored.append((max(scores.values()), blob, corners, scores, rolls))
    scored.sort(key=lambda c: -c[0])
    for best_ncc, blob, corners, scores, rolls in scored[:MAX_ALIGNED]:
        if best_ncc < MIN_NCC:
            break
        ranked = sorted(scores, key=scores.get, reverse=True)
        H, cc = _aligned(gray, corners, rolls[ranked[0]], library[ranked[0]])
        if H is None or cc < required_correlation(corners, settings.min_plaque_ecc):
            continue
        second = _aligned(gray, corners, rolls[ranked[1]], library[ranked[1]])[1] if len(ranked) > 1 else -1.0
        if cc - second >= settings.plaque_ecc_margin:
            corners = cv2.perspectiveTransform(library[ranked[0]].corners_px[None], H)[0]
            return PlaqueMatch(blob, corners, scores, ranked[0], H, None), cc
    return None
