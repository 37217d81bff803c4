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

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from itertools import chain

import cv2
import numpy as np

from .library import Library
from .plaque import PlaqueMatch, blob_boundary, blob_quad, plaque_correlations, refine_ecc, sign_corners, sign_to_quad
from .segment import (Blob, Box, Segmentation, box_iou, component_blob, label_components, normalize_levels,
                      threshold_mask)
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
# A candidate correlating this well is searched as soon as its level is cut (`plaque_order`);
# plaques of other words reach 0.69.
STRONG_NCC = 0.8
# Plaques smaller than this squared (px²) must align better than settings.min_plaque_ecc; see required_correlation.
FULL_TRUST_PX = 60.0
# Quads wider than this (px) are aligned on a shrunk copy of their neighbourhood.
MAX_ALIGN_WIDTH = 240.0
# A blob with less than this fraction of its area in holes shows no text (see `BlobReading.no_sign`).
MIN_TEXT_HOLES = 0.01
# Levels other than the threshold are cut in the image brought to at most this longer side (px)
# before any `shrink` (`cut_image`): candidates are sized by the frame, and on a 12 MP photo each
# level's connected components took 39 ms at full resolution.
MAX_CUT_SIDE = 1280


def quad_levels(settings: Settings) -> tuple[float, ...]:
    """The normalised gray levels the plaque search cuts the image at, brightest first: LEVELS and
    the segmentation threshold."""
    return tuple(sorted({*LEVELS, settings.threshold}, reverse=True))


@dataclass(frozen=True, eq=False)
class CutImage:
    """What the plaque search cuts at levels other than the segmentation threshold (`cut_image`):
    `small`, the (h, w) uint8 image shrunk; `scale` (2,), image px per px of `small` across and
    down; `levels` (256,) float32, what `normalize_gray` maps each uint8 level of the full image to,
    so that each cut means what it means at full resolution."""

    small: np.ndarray = field(repr=False)
    scale: np.ndarray
    levels: np.ndarray = field(repr=False)


def cut_image(gray: np.ndarray, normalization: str, shrink: int) -> CutImage:
    """The (H, W) uint8 image as the plaque search cuts it: brought to at most MAX_CUT_SIDE px on
    its longer side, then shrunk `shrink` times, where connected components with their statistics
    cost 1/shrink² (at 2, plaques under about 70 px across at 640 x 480 are lost more often)."""
    h, w = gray.shape
    factor = shrink * max(1.0, max(h, w) / MAX_CUT_SIDE)
    small = gray if factor == 1 else cv2.resize(gray, (max(1, int(w / factor)), max(1, int(h / factor))),
                                                 interpolation=cv2.INTER_AREA)
    return CutImage(small, np.array([w / small.shape[1], h / small.shape[0]]), normalize_levels(gray, normalization))


def candidate_quads(segmentation: Segmentation, threshold: float, level: float, image: Callable[[], CutImage],
                    taken: Sequence[Box] = ()) -> list[tuple[Blob, np.ndarray]]:
    """(blob, corners (4, 2) image px TL, TR, BR, BL) of every quadrilateral component of plausible
    size of the segmented image cut at normalised `level`, one per plaque and none of the plaques
    whose boxes are `taken` (cut at brighter levels).

    At `threshold`, the cut `segmentation` made, only its candidate blobs are taken, as they are.
    Other levels are cut in `image()` (`cut_image`), asked for only then.
    """
    h, w = segmentation.source.shape
    lo, hi = MIN_AREA_FRACTION * h * w, MAX_AREA_FRACTION * h * w
    if level == threshold:
        labels, blobs, f = segmentation.labels, [b for b in segmentation.blobs if lo <= b.area <= hi], np.ones(2)
    else:
        cut = image()
        f = cut.scale
        labels, stats = label_components(cv2.LUT(cut.small, threshold_mask(cut.levels, level, None)))
        areas = stats[1:, cv2.CC_STAT_AREA] * f.prod()
        blobs = [component_blob(stats, int(i + 1)) for i in np.flatnonzero((areas >= lo) & (areas <= hi))]
    found: list[tuple[Blob, np.ndarray]] = []
    boxes = list(taken)
    for blob in blobs:
        # shrunk px -> image px: boxes outward to whole pixels, corners with pixel centres
        # aligned as cv2.resize does
        x0, y0, x1, y1 = blob.bbox
        box = (int(x0 * f[0]), int(y0 * f[1]), int(np.ceil(x1 * f[0])), int(np.ceil(y1 * f[1])))
        if any(box_iou(box, other) > SAME_PLAQUE_IOU for other in boxes):
            continue
        quad = blob_quad(labels, blob)
        if quad is not None:
            found.append((Blob(blob.label, round(blob.area * f.prod()), box), (quad + 0.5) * f - 0.5))
            boxes.append(box)
    return found


@dataclass(frozen=True, eq=False)
class QuadCandidate:
    """A quadrilateral component of the normalised image at some gray level, read as a plaque:
    its `blob`, `corners` (4, 2) image px TL, TR, BR, BL, each sign's correlation `ncc` and the
    cyclic corner order `rolls` that gave it (`pipeline.plaque.plaque_correlations`)."""

    blob: Blob
    corners: np.ndarray = field(repr=False)
    ncc: dict[str, float]
    rolls: dict[str, int]

    @property
    def best_ncc(self) -> float:
        """The highest correlation with any sign; -1, the lowest there is, with no sign to read."""
        return max(self.ncc.values(), default=-1.0)


def holes_fraction(boundary: np.ndarray, area: int) -> float:
    """The pixels inside a blob's outer `boundary` (`blob_boundary`) that are not among its `area`
    px, over that area: its holes, which the dark text inside a white plaque makes. By Pick's
    theorem the pixels a boundary through their centres encloses are its polygon's area plus half
    the pixels on it, plus one; a run between two of its points holds as many pixels as its longer
    coordinate step."""
    pts = boundary.reshape(-1, 2)
    on_boundary = int(np.abs(np.roll(pts, -1, axis=0) - pts).max(axis=1).sum())
    return max(0.0, cv2.contourArea(boundary) + on_boundary / 2 + 1 - area) / max(area, 1)


@dataclass(frozen=True, eq=False)
class BlobReading:
    """A blob read for its look (`read_blob`): `holes`, the fraction of its area in holes
    (`holes_fraction`), and `quad`, the blob read as a plaque, None when it shows no text
    (under MIN_TEXT_HOLES in holes: not read further) or its outline is no quadrilateral."""

    holes: float
    quad: QuadCandidate | None

    @property
    def no_sign(self) -> bool:
        """Whether the blob is no sign's plaque by its look: it shows no text (a lamp, a white door),
        or it is a quadrilateral that correlates below MIN_NCC with every library sign (a plaque of
        other words).

        Of the largest blobs of the 538 bench and sample scenes, the 257 found to be a sign had at
        least 0.021 of their area in holes (then 0.061), and 7 were quads correlating under MIN_NCC
        (a sign seen obliquely or blurred: searched after the plaques, still found); of the 239 that
        were no sign, 58 had under 0.01 in holes and 50 more were quads correlating under MIN_NCC."""
        return self.holes < MIN_TEXT_HOLES or (self.quad is not None and self.quad.best_ncc < MIN_NCC)


def read_blob(gray: np.ndarray, labels: np.ndarray, blob: Blob, library: Library) -> BlobReading:
    """`blob` (its pixels labelled `blob.label` in `labels`, (H, W) like `gray`) read for its look."""
    boundary = blob_boundary(labels, blob)
    holes = 0.0 if boundary is None else holes_fraction(boundary, blob.area)
    corners = None if holes < MIN_TEXT_HOLES else blob_quad(labels, blob, boundary)
    return BlobReading(holes, None if corners is None else
                       QuadCandidate(blob, corners, *plaque_correlations(gray, corners, library)))


def level_quads(gray: np.ndarray, segmentation: Segmentation, library: Library, settings: Settings,
                image: Callable[[], CutImage], level: float, taken: Sequence[QuadCandidate] = (),
                read: Sequence[QuadCandidate] = ()) -> list[QuadCandidate]:
    """The quadrilateral candidates cut at `level` (`candidate_quads`, in `image()` but at the
    segmentation threshold), other than the plaques `taken` at brighter levels, read as plaques
    against every library sign. A candidate among `read` (the same blob and corners, read already:
    `read_blob`) is not read again."""
    known = {(quad.blob, quad.corners.tobytes()): quad for quad in read}
    return [known.get((blob, corners.tobytes())) or QuadCandidate(blob, corners, *plaque_correlations(gray, corners,
                                                                                                       library))
            for blob, corners in candidate_quads(segmentation, settings.threshold, level, image,
                                                 [q.blob.bbox for q in taken])]


def cut_levels(cut: Callable[[float, Sequence[QuadCandidate]], list[QuadCandidate]],
               levels: Sequence[float]) -> Iterator[list[QuadCandidate]]:
    """The quads `cut(level, taken)` gives at each of `levels` in turn, `taken` being those of the
    levels before (`level_quads`), one level's list at a time as they are asked for."""
    found: list[QuadCandidate] = []
    for level in levels:
        quads = cut(level, tuple(found))
        found += quads
        yield quads


def best_first(quads: Iterable[QuadCandidate]) -> list[QuadCandidate]:
    return sorted(quads, key=lambda q: -q.best_ncc)


def ranked(levels: Iterable[list[QuadCandidate]]) -> list[QuadCandidate]:
    """The quads of every level (`cut_levels`), best correlation first."""
    return best_first(chain.from_iterable(levels))


def plaque_order(levels: Iterable[list[QuadCandidate]]) -> Iterator[QuadCandidate]:
    """The quads of `levels` (`cut_levels`, brightest level first) in the order their crops are
    searched: after each level is cut, its quads correlating STRONG_NCC or more with a sign, best
    first; then all the others, best first. A strong quad is searched before the darker levels are
    cut (about 1 ms each at 640 x 480): of the 35 bench scenes at 640 x 480 answered from the first
    plaque crop, 31 correlated at least 0.8, and 28 of those were answered with 1 (5 scenes), 2
    (15) or 3 (8) of the 4 levels cut instead of all 4. On the 726 bench, accuracy and sample
    scenes no answer or pose changed."""
    rest: list[QuadCandidate] = []
    for quads in levels:
        yield from best_first(q for q in quads if q.best_ncc >= STRONG_NCC)
        rest += [q for q in quads if q.best_ncc < STRONG_NCC]
    yield from best_first(rest)


def _aligned(gray: np.ndarray, corners: np.ndarray, roll: int, sign) -> tuple[np.ndarray | None, float]:
    """(H, ECC correlation) of `sign` aligned densely from the quad in the given corner order; (None, -1) if ECC fails.

    A quad wider than MAX_ALIGN_WIDTH px is aligned in its neighbourhood shrunk to that width:
    the verdict needs no more, and ECC's cost grows with the area (the final H is refined again
    at full resolution by the caller).
    """
    H = sign_to_quad(sign, np.roll(corners, -roll, axis=0).astype(np.float64))
    refined = refine_ecc(gray, sign, H, max_width=MAX_ALIGN_WIDTH, shrunk_width=MAX_ALIGN_WIDTH)
    return (None, -1.0) if refined is None else refined


def required_correlation(corners: np.ndarray, min_ecc: float) -> float:
    """The aligned correlation a quad (4, 2) image px must reach: `min_ecc` for a plaque of at
    least FULL_TRUST_PX² pixels; for a smaller one, the shortfall from a perfect 1 allowed shrinks
    with its area. With a few hundred pixels ECC's eight degrees of freedom fit other text too:
    plaques of other text 24-30 px across (square root of the area) reached 0.82-0.87 with a
    sign, where true signs of that size, legible only when sharp, reached 0.97-0.99."""
    area = abs(cv2.contourArea(np.asarray(corners, np.float32)))
    return 1.0 - (1.0 - min_ecc) * min(1.0, area / FULL_TRUST_PX**2)


def confirm_plaque(gray: np.ndarray, match: PlaqueMatch, library: Library, min_ecc: float) -> PlaqueMatch:
    """`match`, a plaque whose low-resolution correlation named a sign, if that sign aligned
    densely from its corners reaches `required_correlation(corners, min_ecc)`; else the same
    plaque with no sign and the reason.

    The correlation's margin over the runner-up tells signs apart only as far as the library
    holds the runner-up: with the sample library cut to Chief of Security, Security Compound's
    plaques correlated 0.70-0.71 with it (0.95-0.96 with their own sign) and were read as it.
    Aligned, a wrong sign reached 0.65-0.78 and the right one 0.89-0.996 on the sample scenes
    and datasets.
    """
    _, cc = _aligned(gray, match.corners, 0, library[match.sign])
    need = required_correlation(match.corners, min_ecc)
    if cc >= need:
        return match
    return dataclasses.replace(match, sign=None, H=None,
                               reason=f"{match.sign} not confirmed by dense alignment (correlation {cc:.2f} < {need:.2f})")


def search_plaques(gray: np.ndarray, quads: list[QuadCandidate], library: Library,
                   settings: Settings) -> tuple[PlaqueMatch, float] | None:
    """(plaque, its aligned correlation) of the first of the `quads` (`ranked`) that reads as a
    library sign, or None.

    Candidates are tried best correlation first. A candidate is accepted for its best-correlating
    sign when, after ECC alignment, that sign's correlation is at least `settings.min_plaque_ecc`
    (more for small plaques: `required_correlation`) and beats the second-best-correlating sign's, aligned the same way, by
    `settings.plaque_ecc_margin`.
    """
    for quad in quads[:MAX_ALIGNED]:
        if quad.best_ncc < MIN_NCC:
            break
        ranked = sorted(quad.ncc, key=lambda sign: quad.ncc[sign], reverse=True)

        H, cc = _aligned(gray, quad.corners, quad.rolls[ranked[0]], library[ranked[0]])
        if H is None or cc < required_correlation(quad.corners, settings.min_plaque_ecc):
            continue
        second = (_aligned(gray, quad.corners, quad.rolls[ranked[1]], library[ranked[1]])[1]
                  if len(ranked) > 1 else -1.0)
        if cc - second >= settings.plaque_ecc_margin:
            return PlaqueMatch(quad.blob, sign_corners(library[ranked[0]], H), quad.ncc, ranked[0], H, None), cc
    return None
