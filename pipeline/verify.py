"""Stage 6: check that the winner shows all of its sign's text, strip by strip.

Features and RANSAC name a sign from the part of it that matched. A plaque of other words in
the same font that shares a word or a few letter shapes with a library sign (رئيس الوزراء
against رئيس الأمن, مكتب أمني against مجمع أمني) wins with 15-40 inliers on what it shares.
Rectified through the winner's refined homography, the plaque is compared with the library
sign in STRIPS vertical strips across the sign's content (its text), each by its own zero-mean
normalised cross-correlation after the smooth part of the light is taken out of both
(`without_smooth_light`), so that light falling unevenly across the sign (a shadow's edge, glare
on one side) does not count against it; the weakest strip seen in the image decides.

Measured with STRIPS 6 at CHECK_WIDTH 128 px, before the light was evened out: the 14 of 18 plaques of other Arabic words in the
library's font, on real photos, that features read as a library sign reached at most 0.64 with
it; 643 true signs (568 with a pose within 5° on synthetic scenes at 640x480 and 1280x960 and
the sample datasets, 75 pasted on real photos under glare, blur, noise and low light) at least
0.85. Signs read with a pose 34° and 68° off reached 0.68 and 0.14. وزارة التعليم, which
differs from وزارة التعذيب only in its last letters, reaches 0.72 in that strip, hence the default
`min_text_correlation` of 0.75 (right answers on 1684 test images reached at least 0.83).

A plaque of a sign's words and more (مجمع أمني جديد) matches it in every strip: the extra word lies
beyond the sign's outline, where the strips do not look. So the check also looks beyond each side
(`continued_sides`): where the plaque's paper goes on past the sign's edge and its text past the
text's, the winner is a plaque of more words than its sign's.

A landmark of kind "picture" (a poster, a box, a photo: see pipeline/library.py) has no words to
be mistaken for and no plaque to go on: its strips run across the whole image, the light across
it (shadows, glare on one side, vignetting) is taken out of both images by `local_contrast`
before they are compared, and the median strip seen decides, so that one strip in shadow or
behind a passer-by does not turn down a landmark every other strip confirms. A picture's strip
counts when PICTURE_MIN_VISIBLE of it is in the image: a poster seen from close up shows a part.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from .camera import Camera
from .image import inside_image
from .library import Library, LibrarySign
from .plaque import COMPARE_BLUR_SIGMA, quad_width, shrunk_view, sign_corners, sign_to_quad, without_smooth_light
from .pose import distort_pixels, undistort_pixels
from .settings import Settings

STRIPS = 6
CHECK_WIDTH = 128  # px of the rectified sign: fine enough for the words' letters, coarse enough to pool noise
# A sign wider than 4 CHECK_WIDTH px is shrunk to 2 CHECK_WIDTH before rectifying: warping
# alone would alias it, and the blur of a rectified patch covers a shrink of up to 4x.
# A strip counts only when this fraction of it lies inside the image (a sign at the frame's edge).
# At 0.9 a plaque cut by the frame across its text had no strip seen, and the check passed with
# nothing checked: رئيس الوزراء cut there was answered as رئيس الأمن. Measured on 240 windows of
# the 1280 x 960 benchmark scenes cutting the sign at either side, top or bottom (35-85 % of it
# in view), and 288 of plaques of other words pasted on real photos: at 0.5 every sign answered
# right at 0.9 still was, correct answers with no strip seen went from 19 to 2, and wrong ones
# from 12 to 11 (each warned that only part of the text is in view). A landmark partly in view
# under other light is checked too, and may be turned down (the WhiteBoard photo pair).
MIN_VISIBLE = 0.5
# Content: template pixels at least this fraction of the template's range away from its background.
CONTENT_CONTRAST = 0.25
SIDES = ("left", "right", "above", "below")
# The plaque goes on beyond a side when half a text height past the sign's edge this fraction of
# its margin is paper, and its text goes on when this fraction of the band beyond the text is ink
# (see `continued_sides`). Measured on 420 plaques pasted in perspective on real photos and plain
# walls: of 240 of a sign's words and another word beside or on a line above or below them
# (the word's font as the sign's, or all fitted to the plaque), features read 234 as the sign and
# with this look 25 are, every one with its extra line above or below (none with it beside); of 180
# true signs beside other words (a plaque of their own, or printed on the wall, 0.2-2 text heights
# away), 179 are read without it and 176 with it: the 3 lost have the words printed on a wall of
# nearly the plaque's shade, 0.2 text heights beyond its edge, much as a plaque of more words looks.
# On the 1684 images the 0.75 default was measured on, it loses no true sign and takes wrong
# answers from 73 to 49 (cut look-alikes 61 to 41). Not adopted: margins read across the sign's whole width
# above and below, and ink left out of them (more extra lines caught, 25 to 2, but 4 true signs
# cut by the frame's top lost over clouds of the paper's level above a dark mountain).
CONTINUED_PAPER = 0.75
CONTINUED_INK = 0.08
# Paper: within this fraction of the ink's difference from the paper's level.
PAPER_TOLERANCE = 0.2
# Template px of margin a sign needs on every side of its content for the look beyond its sides.
MIN_MARGIN = 2
# Glare that saturates the camera leaves no trace of the ink under it: a strip at least MAX_WASHED
# of whose dark ink reads SATURATED or brighter (uint8 gray, before the blur) is washed out and not
# judged, as a strip outside the image is not. Measured on 150 true signs pasted on real photos
# under a highlight (30 saturating a letter or more) and 9 sample scenes under glare washing out
# a word: with washed-out strips judged, 12 of 30 and 0 of 9 pass the check; with them set aside,
# 28 and 6 (all 30 and 8 of 9 with the check off); the 120 under milder glare pass either way.
# Leaving saturated pixels out of the correlation, their strips counted, won only 3 of the 30.
SATURATED = 250
MAX_WASHED = 0.25
# A picture's light is taken out over this many px of the 128 px wide template (`local_contrast`):
# wider than its texture's detail, narrower than a shadow's or a glare's extent across it.
LOCAL_SIGMA = 4.0
# A picture's strip counts when this fraction of it lies in the image (MIN_VISIBLE for a plaque's).
PICTURE_MIN_VISIBLE = 0.25
# Evidence no look-alike gives: at least this many inliers, their convex hull covering at least
# OVERWHELMING_SPREAD of the picture. A picture so matched passes whatever its strips (a
# whiteboard written on again between the photos: 206 inliers over 0.35 of it, median strip 0.33,
# its homography 1.7 px off). Not for plaques: a plaque of other words shares letter shapes all over.
OVERWHELMING_INLIERS = 100
OVERWHELMING_SPREAD = 0.2
# A picture less than this fraction in the image is answered saying how much of it was.
MOSTLY_IN_VIEW = 0.9
# A picture's dense alignment is kept when its matched points fit it within this many times the
# RMSE the matches' own H leaves them (at least DENSE_FLOOR_PX): see `dense_agrees`.
DENSE_AGREEMENT = 2.0
DENSE_FLOOR_PX = 0.5
# A plaque's outline is held to the same test with the matches' own RMSE taken as at least this
# (the outline may leave them twice that): the inliers, read in crops shrunk to 128-160 px, sit up
# to 1.6 px (RMSE) off a right outline on the synthetic rooms' near-frontal signs, against 0.2-0.7
# px off their own fitted H; an outline on an edge beside the plaque (a corner 7 px off) left them
# 4.0 px off. At DENSE_FLOOR_PX half the rooms' right outlines were refused, and ECC run to find
# them again, at 5 ms a sign.
OUTLINE_FLOOR_PX = 1.0
VISIBLE_GRID = 32  # points along each side of the landmark at which `visible_fraction` looks


def local_contrast(image: np.ndarray) -> np.ndarray:
    """The (h, w) float32 `image` less its local mean, over its local standard deviation (both
    Gaussian-weighted over LOCAL_SIGMA px): what is left of a texture under any smooth light."""
    mean = cv2.GaussianBlur(image, (0, 0), LOCAL_SIGMA)
    detail = image - mean
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), LOCAL_SIGMA))
    return detail / (spread + 1.0)


@dataclass(frozen=True)
class TextCheck:
    """The winner's rectified text against its sign's: each strip's correlation, left to right on
    the sign, None for a strip mostly outside the image or washed out by glare (`washed`: those, by
    their index in `strips`); and the sides (of SIDES) beyond which its plaque and text go on."""

    strips: tuple[float | None, ...]
    continued: tuple[str, ...] = ()
    washed: tuple[int, ...] = ()
    kind: str = "plaque"  # of the landmark checked: a picture is judged by its median strip
    overwhelming: bool = False  # a picture's matches leave no doubt: see `overwhelming`

    @property
    def seen(self) -> int:
        """How many strips were seen in the image (and not washed out)."""
        return sum(c is not None for c in self.strips)

    @property
    def weakest(self) -> float | None:
        """The lowest correlation of the strips seen, None when none was seen."""
        seen = [c for c in self.strips if c is not None]
        return min(seen) if seen else None

    @property
    def score(self) -> float | None:
        """What is held against the bar: a plaque's weakest strip, a picture's median strip
        (None when no strip was seen)."""
        seen = [c for c in self.strips if c is not None]
        if not seen:
            return None
        return float(np.median(seen)) if self.kind == "picture" else min(seen)

    def passes(self, min_correlation: float) -> bool:
        """Whether at least one strip was seen, the `score` reaches `min_correlation` and the
        text goes on beyond no side.

        With no strip seen (a sign cut by the frame across its text) nothing tells it from a plaque
        of other words: رئيس الوزراء and وزارة التعليم cut so would pass as رئيس الأمن and وزارة
        التعذيب. A plaque of the sign's words and more (مجمع أمني جديد) matches in every strip."""
        if self.score is None:
            return False
        return (self.score >= min_correlation or self.overwhelming) and not self.continued

    def problem(self, sign: LibrarySign, min_correlation: float) -> str | None:
        """Why `sign`'s winner is turned down by this check at `min_correlation`: which part failed
        and what may be changed; None when it passes."""
        if self.passes(min_correlation):
            return None
        as_picture = f"give it \"kind\": \"picture\" in library.json if {sign.id} is no plaque of text"
        if self.score is None and self.kind == "picture":
            return (f"too little of {sign.id} is in the image to compare (each of its {len(self.strips)} strips lies "
                    f"less than {PICTURE_MIN_VISIBLE:.0%} in it)")
        if self.score is None:
            where = ("lies mostly outside it or is washed out by glare" if self.washed else "lies mostly outside it")
            return (f"none of {sign.id}'s text can be read in the image (each of its {len(self.strips)} "
                    f"strips {where}): a plaque of other words would read the same; {as_picture}")
        if self.kind == "picture" and self.score < min_correlation:
            return (f"the picture differs from {sign.id}'s (median strip correlation {self.score:.2f} < "
                    f"{min_correlation:g}): another object, or a homography that is off; if it is {sign.id}, lower "
                    "its \"min_text_correlation\" in library.json")
        if self.score < min_correlation:
            return (f"its text differs from {sign.id}'s (weakest strip correlation {self.score:.2f} < "
                    f"{min_correlation:g}): another sign sharing some of its words, or a homography that is off; "
                    f"{as_picture}, or lower its \"min_text_correlation\" there")
        return (f"the plaque and its text go on beyond {sign.id}'s {' and '.join(self.continued)} "
                f"side: a plaque of {sign.id}'s words and more")

    def to_json(self) -> dict:
        return {"strips": [None if c is None else round(c, 4) for c in self.strips],
                "weakest": None if self.weakest is None else round(self.weakest, 4),
                "continued": list(self.continued), "washed_out": list(self.washed)}


@dataclass(frozen=True)
class TextTemplate:
    """A sign as the text check compares it: `image` (h, w) float32 gray levels 0-255, the sign
    shrunk to w = CHECK_WIDTH px and blurred like a rectified plaque; the strips over its content
    (its text), from row `rows[0]` to `rows[1]` (template px, end excluded), strip i from column
    `columns[i]` to `columns[i + 1]` (`columns` (STRIPS + 1,) int template px, left to right on the
    sign); `centres` (1, h w, 2): where its pixels' centres are in the sign's library px.

    For the look beyond its sides: `content` (top, bottom, left, right), the box of its content
    (template px, ends excluded); `paper` and `ink` (h, w) bool, its pixels at its background's level
    and those nearer its content's extreme than its background; `dark_ink`, whether its ink is
    darker than its paper (glare can wash out only such ink); `around` (1, H W, 2), the centres
    (library px) of the pixels of the template grown by `reach` px, the content's height, on every
    side (H = h + 2 reach, W = w + 2 reach); None when the content comes within MIN_MARGIN px of an
    edge (a photo used as a landmark): nothing then shows where such a sign ends."""

    image: np.ndarray
    rows: tuple[int, int]
    columns: np.ndarray
    centres: np.ndarray
    content: tuple[int, int, int, int]
    paper: np.ndarray
    ink: np.ndarray
    dark_ink: bool
    reach: int
    around: np.ndarray | None
    kind: str = "plaque"


def _template(sign: LibrarySign) -> TextTemplate:
    """The sign's `TextTemplate`: strips over the bounding box of its content (pixels well away from the
    level of its border, its background), with a margin of a quarter of its height above and below;
    a picture's over all of it, with no look beyond its sides."""
    w, h = sign.size_px
    size = (CHECK_WIDTH, max(8, round(CHECK_WIDTH * h / w)))
    small = cv2.resize(sign.image, size, interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(small.astype(np.float32), (0, 0), COMPARE_BLUR_SIGMA)
    if sign.kind == "picture":
        nothing = np.zeros(image.shape, bool)
        return TextTemplate(image, (0, size[1]), np.linspace(0, size[0], STRIPS + 1).round().astype(int),
                            _centres(size, (w, h), 0), (0, size[1], 0, size[0]), nothing, nothing, False, 0, None,
                            "picture")
    border = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    away = np.abs(image - np.median(border))
    span = max(float(away.max()), 1e-6)
    content = away > CONTENT_CONTRAST * max(float(np.ptp(image)), 1e-6)
    ys, xs = np.nonzero(content)
    if len(xs) == 0:  # a flat image: strips over all of it
        ys, xs = np.array([0, size[1] - 1]), np.array([0, size[0] - 1])
    top, bottom, left, right = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    margin = max(1, (bottom - top) // 4)
    rows = (max(0, top - margin), min(size[1], bottom + margin))
    reach = bottom - top
    bordered = min(top, left, size[1] - bottom, size[0] - right) >= MIN_MARGIN
    paper, ink = away < 0.1 * span, away > 0.5 * span
    dark_ink = bool(paper.any() and ink.any() and image[ink].mean() < image[paper].mean())
    return TextTemplate(image, rows, np.linspace(left, right, STRIPS + 1).round().astype(int),
                        _centres(size, (w, h), 0), (top, bottom, left, right), paper, ink, dark_ink, reach,
                        _centres(size, (w, h), reach) if bordered else None)


def _centres(size: tuple[int, int], sign_size: tuple[int, int], reach: int) -> np.ndarray:
    """(1, (h + 2 reach)(w + 2 reach), 2) library px of the pixel centres of a (w, h) = `size` px
    grid over a sign of `sign_size` (w, h) library px, grown by `reach` grid px on every side."""
    (gw, gh), (w, h) = size, sign_size
    u, v = np.meshgrid((np.arange(-reach, gw + reach) + 0.5) * w / gw, (np.arange(-reach, gh + reach) + 0.5) * h / gh)
    return np.dstack([u, v]).reshape(1, -1, 2)


def text_template(library: Library, sign_id: str) -> TextTemplate:
    """Sign `sign_id`'s `TextTemplate`, made once per library (cached on it, as every sign's)."""
    return library.per_sign("text_templates", _template)[sign_id]


@dataclass(frozen=True)
class Rectified:
    """An image read at a `TextTemplate`'s pixels through a homography: `raw` (h, w) uint8, the
    image's gray levels read (its edge repeated where a pixel's centre falls outside it, 0 when
    every pixel of the grid read does, which for `rectify_text` is the grid around the text);
    `patch` (h, w) float32, `raw` blurred as the template is; `seen` (h, w) bool, True where the
    centre falls inside the image."""

    raw: np.ndarray
    patch: np.ndarray
    seen: np.ndarray

    @property
    def saturated(self) -> np.ndarray:
        """(h, w) bool: True where the image read, before the blur, is SATURATED or brighter."""
        return self.raw >= SATURATED


def _rectified(raw: np.ndarray, seen: np.ndarray) -> Rectified:
    return Rectified(raw, cv2.GaussianBlur(raw.astype(np.float32), (0, 0), COMPARE_BLUR_SIGMA), seen)


def _strip_sums(values: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(S,) sums of the (h, w) `values` over each strip of columns `columns[i]:columns[i + 1]`."""
    return np.add.reduceat(values[:, :columns[-1]].sum(axis=0, dtype=np.float64), columns[:-1])


def _strip_correlations(a: np.ndarray, b: np.ndarray, columns: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(S,) zero-mean normalised cross-correlation of two (h, w) arrays in each strip of
    `columns`, over the pixels where the (h, w) bool `use` holds; 0 where either is flat."""
    use = use.astype(np.float32)
    a, b = a * use, b * use
    n = np.maximum(_strip_sums(use, columns), 1.0)
    sa, sb = _strip_sums(a, columns), _strip_sums(b, columns)
    cov = _strip_sums(a * b, columns) - sa * sb / n
    var = (_strip_sums(a * a, columns) - sa**2 / n) * (_strip_sums(b * b, columns) - sb**2 / n)
    return np.where(var > 0, cov / np.sqrt(np.maximum(var, 1e-300)), 0.0)


def rectify_text(gray: np.ndarray, sign: LibrarySign, template: TextTemplate, H: np.ndarray,
                 camera: Camera | None = None) -> Rectified:
    """The (H, W) uint8 image read at each pixel of `sign`'s `template` through H (library px ->
    image px), as a `Rectified`: the patch `check_text` correlates. Under `camera`'s lens distortion H is taken as
    exact at the corners (as refinement leaves it) and the sign is read along the curves the lens
    makes of it. A template with an `around` grid is read as the middle of `rectify_around`'s
    patch, as `check_text` reads it."""
    if template.around is None:
        return _read(gray, sign, template.centres, template.image.shape, H, camera)
    return _middle(rectify_around(gray, sign, template, H, camera), template)


def rectify_around(gray: np.ndarray, sign: LibrarySign, template: TextTemplate, H: np.ndarray,
                   camera: Camera | None = None) -> Rectified:
    """As `rectify_text`, over the template grown by `template.reach` px on every side: the
    (h + 2 reach, w + 2 reach) patch `continued_sides` looks at (`template.around` must not be None)."""
    h, w = template.image.shape
    return _read(gray, sign, template.around, (h + 2 * template.reach, w + 2 * template.reach), H, camera)


def _middle(around: Rectified, template: TextTemplate) -> Rectified:
    """The template's own (h, w) pixels of `rectify_around`'s patch, blurred by themselves as a
    patch read alone is: the levels such a read gives, but for the float rounding of where each
    pixel is read and for a sign read shrunk, whose shrunk view starts elsewhere. One read
    instead of two took a fifth off the check's time."""
    r, (h, w) = template.reach, template.image.shape
    middle = (slice(r, r + h), slice(r, r + w))
    return _rectified(around.raw[middle], around.seen[middle])


def _read(gray: np.ndarray, sign: LibrarySign, centres: np.ndarray, shape: tuple[int, int], H: np.ndarray,
          camera: Camera | None) -> Rectified:
    """The (H, W) uint8 image read through H at `centres` (1, h w, 2) library px, the pixel centres
    of an (h, w) = `shape` grid at the template's resolution (see `rectify_text`)."""
    h, w = shape
    corners = sign_corners(sign, H)
    if camera is not None:
        H = sign_to_quad(sign, undistort_pixels(corners, camera))  # the plane-to-pinhole map
    at = cv2.perspectiveTransform(centres, H)[0]  # where each grid pixel's centre lies
    if camera is not None:
        at = distort_pixels(at, camera)
    at = at.reshape(h, w, 2)
    seen = inside_image(at[..., 0], at[..., 1], gray.shape)
    # The box of every point read (a lens bows the sides outward, beyond the corners' box), and
    # a pixel more for the bilinear reads; cv2's, as numpy's min and max took half the check's time.
    bx, by, bw, bh = cv2.boundingRect(at.reshape(-1, 1, 2).astype(np.float32))
    x0, y0 = max(0, bx - 1), max(0, by - 1)
    x1, y1 = min(gray.shape[1], bx + bw + 2), min(gray.shape[0], by + bh + 2)
    if x1 - x0 < 2 or y1 - y0 < 2:  # the box is then wholly outside the image: nothing is seen
        return _rectified(np.zeros((h, w), np.uint8), seen)
    # Only the sign's neighbourhood is read (and shrunk, when large).
    view, at = gray[y0:y1, x0:x1], at - (x0, y0)
    f = 2 * CHECK_WIDTH / quad_width(corners)
    if f < 0.5:
        view, to_small, _ = shrunk_view(view, f, None)
        at = at * np.diag(to_small)[:2] + to_small[:2, 2]
    # Beyond the image its edge is repeated, not black, so that the blur does not darken the seen
    # pixels beside it; the correlation leaves the unseen ones out.
    patch = cv2.remap(view, at[..., 0].astype(np.float32), at[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
    return _rectified(patch, seen)


def compare_text(rectified: Rectified, template: TextTemplate) -> TextCheck:
    """`rectified` against `template`, strip by strip (see the module docstring)."""
    top, bottom = template.rows
    columns = template.columns
    seen = rectified.seen[top:bottom]
    least = PICTURE_MIN_VISIBLE if template.kind == "picture" else MIN_VISIBLE
    visible = _strip_sums(seen, columns) / (np.diff(columns) * (bottom - top)) >= least
    washed = visible & _washed_out(rectified, template)
    patch, image = rectified.patch[top:bottom], template.image[top:bottom]
    even = local_contrast if template.kind == "picture" else without_smooth_light
    patch, image = even(patch), even(image)
    correlations = _strip_correlations(patch, image, columns, seen)
    return TextCheck(tuple(float(c) if v and not x else None for c, v, x in zip(correlations, visible, washed)),
                     washed=tuple(int(i) for i in np.flatnonzero(washed)), kind=template.kind)


def _washed_out(rectified: Rectified, template: TextTemplate) -> np.ndarray:
    """(S,) bool: the strips at least MAX_WASHED of whose ink seen reads saturated; none for a sign
    whose ink is lighter than its background (saturated ink is then what it looks like)."""
    if not template.dark_ink:
        return np.zeros(len(template.columns) - 1, bool)
    top, bottom = template.rows
    ink = template.ink[top:bottom] & rectified.seen[top:bottom]
    clipped = _strip_sums(ink & rectified.saturated[top:bottom], template.columns)
    return clipped >= MAX_WASHED * np.maximum(_strip_sums(ink, template.columns), 1)


def _fraction(values: np.ndarray, seen: np.ndarray, regions: list[tuple[slice, slice]]) -> float | None:
    """The fraction of `values` (bool) True among the pixels `seen` (bool, same shape) in the union
    of the disjoint `regions` (row and column slices), None when fewer than MIN_VISIBLE of its
    pixels are seen (or it has none: a sign with no margin rows)."""
    size = sum(seen[r].size for r in regions)
    n_seen = sum(int(np.count_nonzero(seen[r])) for r in regions)
    if size == 0 or n_seen / size < MIN_VISIBLE:
        return None
    return sum(int(np.count_nonzero(values[r] & seen[r])) for r in regions) / n_seen


def continued_sides(around: Rectified, template: TextTemplate) -> tuple[str, ...]:
    """The sides (of SIDES) beyond which the plaque and its text go on, in `rectify_around`'s patch.

    Paper and ink are told by the levels the sign itself shows there (the medians at the template's
    `paper` and `ink` pixels): paper within PAPER_TOLERANCE of their difference of the paper's
    level, ink more than half of it towards the ink's. Beyond a side the plaque goes on when the
    sign's margin beside its content (the rows above and below the text for the left and right
    sides, the columns either side of it for those above and below), continued half a `reach`
    past the edge, is at least CONTINUED_PAPER paper; its text goes on when the band from the
    content's edge to `reach` beyond it is at least CONTINUED_INK ink: the text's rows for left
    and right, and for above and below the densest third of its columns (a word on a line of its
    own may be much shorter than the sign's). A side less than MIN_VISIBLE in the image is not
    judged."""
    r, (h, w) = template.reach, template.image.shape
    patch, seen = around.patch, around.seen
    inside, inside_seen = patch[r:r + h, r:r + w], seen[r:r + h, r:r + w]
    paper_at, ink_at = template.paper & inside_seen, template.ink & inside_seen
    if not paper_at.any() or not ink_at.any():
        return ()
    paper_level = float(np.median(inside[paper_at]))
    contrast = float(np.median(inside[ink_at])) - paper_level  # negative for dark ink
    if abs(contrast) < 1e-6:
        return ()
    paper = np.abs(patch - paper_level) < PAPER_TOLERANCE * abs(contrast)
    ink = (patch - paper_level) / contrast > 0.5
    top, bottom, left, right = (v + r for v in template.content)
    e = max(1, round(r / 2))
    # Each region is one or two boxes, read in place through slices.
    margin_rows, margin_columns = (slice(r, top), slice(bottom, r + h)), (slice(r, left), slice(right, r + w))
    margin = {"left": [(rows, slice(r - e, r)) for rows in margin_rows],
              "right": [(rows, slice(r + w, r + w + e)) for rows in margin_rows],
              "above": [(slice(r - e, r), columns) for columns in margin_columns],
              "below": [(slice(r + h, r + h + e), columns) for columns in margin_columns]}
    thirds = [slice(c[0], c[-1] + 1) for c in np.array_split(np.arange(left, right), 3)]
    band = {"left": [(slice(top, bottom), slice(left - r, left))], "right": [(slice(top, bottom), slice(right, right + r))],
            "above": [(slice(top - r, top), c) for c in thirds], "below": [(slice(bottom, bottom + r), c) for c in thirds]}
    continued = []
    for side in SIDES:
        plaque = _fraction(paper, seen, margin[side])
        inked = [f for b in band[side] if (f := _fraction(ink, seen, [b])) is not None]
        if plaque is not None and plaque >= CONTINUED_PAPER and max(inked, default=0.0) >= CONTINUED_INK:
            continued.append(side)
    return tuple(continued)


def overwhelming(sign: LibrarySign, inliers: np.ndarray) -> bool:
    """Whether a picture's (N, 2) library px feature inliers are evidence no look-alike gives (see
    OVERWHELMING_INLIERS); never for a plaque."""
    if sign.kind != "picture" or len(inliers) < OVERWHELMING_INLIERS:
        return False
    w, h = sign.size_px
    return cv2.contourArea(cv2.convexHull(inliers.astype(np.float32))) >= OVERWHELMING_SPREAD * w * h


def dense_agrees(H: np.ndarray, dense_H: np.ndarray, src: np.ndarray, dst: np.ndarray, *,
                 floor_px: float = DENSE_FLOOR_PX) -> bool:
    """Whether `dense_H`, a picture's dense alignment, fits the (N, 2) matched points `src` (library
    px) -> `dst` (image px) within DENSE_AGREEMENT times the RMSE that H, fitted to them, leaves.
    ECC aligns what is in view and may bend the rest: the homogr pair BostonLib, a third of its A in
    view, left its points 1.20 px RMSE off against the matches' 0.26, its truth 4.2 px off against
    0.6; where ECC helped (graf, Brussels, Eiffel, boat) the points moved by at most 1.7 times."""
    def rmse(homography: np.ndarray) -> float:
        mapped = cv2.perspectiveTransform(src.reshape(1, -1, 2).astype(np.float64), homography)[0]
        return float(np.sqrt(np.mean(np.sum((mapped - dst) ** 2, axis=1))))
    return len(src) == 0 or rmse(dense_H) <= DENSE_AGREEMENT * max(rmse(H), floor_px)


def visible_fraction(H: np.ndarray, sign: LibrarySign, width: int, height: int) -> float:
    """The fraction of `sign` that H (library px -> image px) puts inside a `width` x `height` px
    image (and in front of the camera), from a VISIBLE_GRID x VISIBLE_GRID grid of its points."""
    w, h = sign.size_px
    steps = (np.arange(VISIBLE_GRID) + 0.5) / VISIBLE_GRID
    u, v = np.meshgrid(steps * w, steps * h)
    hom = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]) @ np.asarray(H, np.float64).T
    ahead = hom[:, 2] > 1e-12
    x, y = hom[:, 0] / np.where(ahead, hom[:, 2], 1.0), hom[:, 1] / np.where(ahead, hom[:, 2], 1.0)
    return float(np.mean(ahead & (x >= 0) & (x <= width) & (y >= 0) & (y <= height)))


def text_threshold(sign: LibrarySign, settings: Settings) -> float:
    """The bar `sign`'s winner must reach in the check (0: not checked): the sign's own
    `min_text_correlation` when its library entry gives one; else none when the settings' is 0 (the
    check off), a picture's `settings.min_picture_correlation`, a plaque's `settings.min_text_correlation`."""
    if sign.min_text_correlation is not None:
        return sign.min_text_correlation
    if settings.min_text_correlation <= 0:
        return 0.0
    return settings.min_picture_correlation if sign.kind == "picture" else settings.min_text_correlation


def check_text(gray: np.ndarray, library: Library, sign_id: str, H: np.ndarray,
               camera: Camera | None = None) -> TextCheck:
    """Compare the (H, W) uint8 image, rectified through H (library px -> image px), with sign
    `sign_id`'s text strip by strip, and look beyond its sides: `compare_text` of `rectify_text`,
    `continued_sides` of `rectify_around` (see each)."""
    template, sign = text_template(library, sign_id), library[sign_id]
    if template.around is None:
        return compare_text(rectify_text(gray, sign, template, H, camera), template)
    around = rectify_around(gray, sign, template, H, camera)
    return replace(compare_text(_middle(around, template), template), continued=continued_sides(around, template))
