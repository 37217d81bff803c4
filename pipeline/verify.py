"""Stage 6: check that the winner shows all of its sign's text, strip by strip.

Features and RANSAC name a sign from the part of it that matched. A plaque of other words in
the same font that shares a word or a few letter shapes with a library sign (رئيس الوزراء
against رئيس الأمن, مكتب أمني against مجمع أمني) wins with 15-40 inliers on what it shares.
Rectified through the winner's refined homography, the plaque is compared with the library
sign in STRIPS vertical strips across the sign's content (its text), each by its own zero-mean
normalised cross-correlation, so that light falling unevenly across the sign does not count
against it; the weakest strip seen in the image decides.

Measured with STRIPS 6 at CHECK_WIDTH 128 px: 18 plaques of other Arabic words in the library's
font, on real photos, reached at most 0.67 with the sign they were read as; 568 true signs with
a pose within 5° (synthetic scenes at 640x480 and 1280x960, the sample datasets, signs pasted
on real photos under glare, blur, noise and low light) at least 0.73 (one dim, noisy scene;
the next 0.79). Signs read with a pose 34° and 68° off reached 0.63 and 0.04.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .library import Library, LibrarySign
from .plaque import COMPARE_BLUR_SIGMA, bounding_box, quad_width, rectify, shrunk_view, sign_corners
from .segment import expand_box

STRIPS = 6
CHECK_WIDTH = 128  # px of the rectified sign: fine enough for the words' letters, coarse enough to pool noise
# A sign wider than 4 CHECK_WIDTH px is shrunk to 2 CHECK_WIDTH before rectifying: warping
# alone would alias it, and the blur of a rectified patch covers a shrink of up to 4x.
# A strip counts only when this fraction of it lies inside the image (a sign at the frame's edge).
MIN_VISIBLE = 0.9
# Content: template pixels at least this fraction of the template's range away from its background.
CONTENT_CONTRAST = 0.25


@dataclass(frozen=True)
class TextCheck:
    """The winner's rectified text against its sign's: each strip's correlation, left to right on
    the sign, None for a strip mostly outside the image."""

    strips: tuple[float | None, ...]

    @property
    def weakest(self) -> float | None:
        """The lowest correlation of the strips seen, None when none was seen."""
        seen = [c for c in self.strips if c is not None]
        return min(seen) if seen else None

    def passes(self, min_correlation: float) -> bool:
        """Whether every strip seen reaches `min_correlation` (a check with no strip seen passes:
        there is nothing to hold against the sign)."""
        return self.weakest is None or self.weakest >= min_correlation

    def to_json(self) -> dict:
        return {"strips": [None if c is None else round(c, 4) for c in self.strips],
                "weakest": None if self.weakest is None else round(self.weakest, 4)}


@dataclass(frozen=True)
class _Template:
    """A sign at CHECK_WIDTH, blurred like a rectified plaque; `rows` (y0, y1) and `columns`
    (STRIPS + 1 x edges) of the strips over its content."""

    image: np.ndarray
    rows: tuple[int, int]
    columns: np.ndarray


def _template(sign: LibrarySign) -> _Template:
    """The sign's `_Template`: strips over the bounding box of its content (pixels well away from the
    level of its border, its background), with a margin of a quarter of its height above and below."""
    w, h = sign.size_px
    size = (CHECK_WIDTH, max(8, round(CHECK_WIDTH * h / w)))
    small = cv2.resize(sign.image, size, interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(small.astype(np.float32), (0, 0), COMPARE_BLUR_SIGMA)
    border = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    content = np.abs(image - np.median(border)) > CONTENT_CONTRAST * max(float(np.ptp(image)), 1e-6)
    ys, xs = np.nonzero(content)
    if len(xs) == 0:  # a flat image: strips over all of it
        ys, xs = np.array([0, size[1] - 1]), np.array([0, size[0] - 1])
    margin = max(1, (ys.max() + 1 - ys.min()) // 4)
    rows = (max(0, int(ys.min()) - margin), min(size[1], int(ys.max()) + 1 + margin))
    return _Template(image, rows, np.linspace(xs.min(), xs.max() + 1, STRIPS + 1).round().astype(int))


def _templates(library: Library) -> dict[str, _Template]:
    """Every sign's `_Template`, cached on the library."""
    cached = library.cache.get("text_templates")
    if cached is None or cached.keys() != set(library.ids):
        cached = {sign.id: _template(sign) for sign in library.signs}
        library.cache["text_templates"] = cached
    return cached


def _strip_sums(values: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(S,) sums of the (h, w) `values` over each strip of columns `columns[i]:columns[i + 1]`."""
    return np.add.reduceat(values[:, :columns[-1]].sum(axis=0, dtype=np.float64), columns[:-1])


def _strip_correlations(a: np.ndarray, b: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(S,) zero-mean normalised cross-correlation of two (h, w) arrays in each strip of
    `columns`; 0 where either is flat."""
    n = np.diff(columns) * a.shape[0]
    sa, sb = _strip_sums(a, columns), _strip_sums(b, columns)
    cov = _strip_sums(a * b, columns) - sa * sb / n
    var = (_strip_sums(a * a, columns) - sa**2 / n) * (_strip_sums(b * b, columns) - sb**2 / n)
    return np.where(var > 0, cov / np.sqrt(np.maximum(var, 1e-300)), 0.0)


def check_text(gray: np.ndarray, library: Library, sign_id: str, H: np.ndarray) -> TextCheck:
    """Compare the (H, W) uint8 image, rectified through H (library px -> image px), with sign
    `sign_id`'s text strip by strip (see the module docstring)."""
    template = _templates(library)[sign_id]
    w, h = size = template.image.shape[::-1]
    corners = sign_corners(library[sign_id], H)
    x0, y0, x1, y1 = expand_box(bounding_box(corners), 0.0, gray.shape[1], gray.shape[0])
    if x1 - x0 < 2 or y1 - y0 < 2:
        return TextCheck((None,) * STRIPS)
    # Only the sign's neighbourhood is read (and shrunk, when large).
    view, corners = gray[y0:y1, x0:x1], corners - (x0, y0)
    f = 2 * CHECK_WIDTH / quad_width(corners)
    if f < 0.5:
        view, to_small, _ = shrunk_view(view, f, None)
        corners = cv2.perspectiveTransform(corners[None], to_small)[0]
    patch = rectify(view, corners, size)
    # Where each rectified pixel centre falls in the view: inside it or not.
    to_view = cv2.getPerspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]), corners.astype(np.float32))
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    at = cv2.perspectiveTransform(np.dstack([u, v]).reshape(1, -1, 2), to_view)[0]
    seen = ((at[:, 0] >= 0) & (at[:, 0] <= view.shape[1] - 1) & (at[:, 1] >= 0)
            & (at[:, 1] <= view.shape[0] - 1)).reshape(h, w)
    top, bottom = template.rows
    columns = template.columns
    visible = _strip_sums(seen[top:bottom], columns) / (np.diff(columns) * (bottom - top)) >= MIN_VISIBLE
    correlations = _strip_correlations(patch[top:bottom], template.image[top:bottom], columns)
    return TextCheck(tuple(float(c) if v else None for c, v in zip(correlations, visible)))
