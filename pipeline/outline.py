"""Outline refinement: the plaque's four straight edges pin down a sign's homography.

Feature inliers sit on the text, in the middle of the plaque, so the corners a feature
homography extrapolates to are its least certain points, and near-frontal views turn a pixel
of corner error into degrees of tilt. The plaque's edges against the wall are long straight
lines: located to a fraction of a pixel at many points along each side and fitted robustly,
they give four lines, hence four corners, hence a homography, and from views where the text
is too blurred or too small for features as well.

Starting from a homography good to a few pixels, each side of the projected sign is sampled
at points along it; at each, the image is read across the side (a short profile along its
normal) and the strongest step with the side's dominant polarity is located to sub-pixel
precision (the centroid of the derivative's peak, so a blurred ramp counts from its middle).
The profiles are read in linear light (the image's gray levels through its encoding gamma): a
camera blurs the light before it encodes it, and read as encoded, a blurred edge's ramp leans
towards its dark side, which put a bright plaque's corners 0.1-0.6 px outwards.
A line is fitted to those edge points (RANSAC on pairs, then total least squares on the
inliers). A second, narrower search from the fitted lines changed little on the synthetic
scenes (rotation median 0.088 against 0.095 degrees, 4 fewer outlines accepted) and doubled
the cost, so there is one. The refinement is refused, and the
input kept, when a side has too few consistent edge points or the corners move further than
the search could justify. This assumes the library image is the whole sign, cropped to its
edges, as `pipeline.library` requires.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import Camera
from .homography import normalize_scale
from .image import inside_image
from .library import LibrarySign
from .plaque import MAX_DIRECT_WIDTH_PX, SHRUNK_WIDTH_PX, quad_width, seen_grid, shrunk_view, sign_corners, sign_to_quad
from .pose import CORNER_SIGMA_PX, Pose, distort_pixels, undistort_pixels, with_corner_floor

# Fraction of each side left out at either end: corners are rounded by blur and shared by two sides.
END_MARGIN = 0.12
# Most profiles per side, and the least spacing between them (image px).
MAX_SAMPLES = 32
MIN_SPACING_PX = 2.0
# Half-length of the search across a side (image px), and the profile step.
SEARCH_PX = 8.0
STEP_PX = 0.5
# Profiles averaged along the side at each sample, this far apart (image px): less noise.
TANGENT_OFFSETS_PX = (-0.75, 0.75)
# Edge points further than this from a side's line are outliers (image px).
LINE_INLIER_PX = 0.8
# A side needs this fraction of its profiles on its line, and at least MIN_SIDE_POINTS of them.
MIN_INLIER_FRACTION = 0.6
MIN_SIDE_POINTS = 8
# An edge step must be this steep (gray levels per px) and this fraction of the side's median step.
MIN_STEP = 1.0
MIN_RELATIVE_STEP = 0.3
LINE_RANSAC_ITERATIONS = 40
SMOOTH_SIGMA = 0.7  # Gaussian smoothing of the image before reading profiles (px)
SMOOTH_MARGIN_PX = 4  # beyond the kernel's radius for SMOOTH_SIGMA (3 px)
# Length along a side over which profiles share noise (tangent offsets plus smoothing), px.
CORRELATION_PX = 4.0


@dataclass(frozen=True, eq=False)
class Outline:
    """A refined plaque outline: `corners` (4, 2) image px TL, TR, BR, BL, the homography `H`
    (library px -> image px) through them, per side the edge points used (image px), and
    `ideal_H` (library px -> px of an ideal pinhole camera with the same K, `undistort_pixels`).

    Without lens distortion the two homographies are one. With it the sides are curves in the
    image, `H` is exact only at the corners, and `ideal_H` is the plane-to-pinhole map."""

    corners: np.ndarray = field(repr=False)
    H: np.ndarray = field(repr=False)
    points: list[np.ndarray] = field(repr=False)
    ideal_H: np.ndarray = field(repr=False)

    def moved(self, M: np.ndarray) -> Outline:
        """This outline in other pixels, which the (3, 3) affine `M` maps its image px (and its
        ideal pinhole px) to."""
        def move(pts: np.ndarray) -> np.ndarray:
            return pts @ M[:2, :2].T + M[:2, 2]
        return Outline(move(self.corners), normalize_scale(M @ self.H), [move(p) for p in self.points],
                       normalize_scale(M @ self.ideal_H))

    def grid(self, sign: LibrarySign, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(src (N, 2) library px, dst (N, 2) image px): `seen_grid` of `ideal_H`."""
        return seen_grid(self.ideal_H, sign, camera)


def _line_fits(pts: np.ndarray, side: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Per side, the total-least-squares line through the (N, 2) points `pts` of that side (N,)
    0..3 where `use` (N,) holds: (4, 3) rows (a, b, c) with a x + b y + c = 0, |(a, b)| = 1, NaN
    for a side with fewer than two such points."""
    s, p = side[use], pts[use]
    n = np.bincount(s, minlength=4)
    centre = np.column_stack([np.bincount(s, p[:, 0], 4), np.bincount(s, p[:, 1], 4)]) / np.maximum(n, 1)[:, None]
    q = p - centre[s]
    sxx, syy, sxy = (np.bincount(s, w, 4) for w in (q[:, 0] * q[:, 0], q[:, 1] * q[:, 1], q[:, 0] * q[:, 1]))
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # direction of largest spread
    a, b = -np.sin(theta), np.cos(theta)
    lines = np.column_stack([a, b, -(a * centre[:, 0] + b * centre[:, 1])])
    lines[n < 2] = np.nan
    return lines


def _distances(pts: np.ndarray, side: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """(N,) distance (image px) of each of the (N, 2) points from its side's line in `lines` (4, 3); NaN without one."""
    line = lines[side]
    return np.abs(pts[:, 0] * line[:, 0] + pts[:, 1] * line[:, 1] + line[:, 2])


def _robust_lines(pts: np.ndarray, side: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC lines through the (N, 2) edge points `pts` of each side (N,) 0..3, sorted by side:
    the line through the pair of a side's points with most points near it, then total least
    squares on those points, re-classified and refitted twice. Returns lines (4, 3) as
    `_line_fits` (NaN for a side without one) and the (N,) inlier mask of the last re-classification.

    Sides draw their pairs from `rng` in order; the first side with fewer than MIN_SIDE_POINTS
    points draws none and ends the drawing, since the outline is refused at that side anyway.
    """
    counts = np.bincount(side, minlength=4)
    first = np.cumsum(counts) - counts
    draws = []
    for i in range(4):
        if counts[i] < MIN_SIDE_POINTS:
            break
        draws.append(first[i] + rng.integers(0, counts[i], size=(2, LINE_RANSAC_ITERATIONS)))
    if not draws:
        return np.full((4, 3), np.nan), np.zeros(len(pts), dtype=bool)
    i, j = np.concatenate(draws, axis=1)  # (S K,) each: side s's hypotheses at s K .. s K + K - 1
    d = pts[j] - pts[i]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 1e-6
    length = np.where(keep, length, 1.0)
    nx, ny = -d[:, 1] / length, d[:, 0] / length
    # Each point is measured against its own side's hypotheses alone (the drawn sides' points come
    # first, sorted by side): a quarter of the distances of every point to every hypothesis.
    n = int(first[len(draws) - 1] + counts[len(draws) - 1])
    own = side[:n, None] * LINE_RANSAC_ITERATIONS + np.arange(LINE_RANSAC_ITERATIONS)  # (n, K)
    close = np.abs(pts[:n, :1] * nx[own] + pts[:n, 1:] * ny[own] - (pts[i, 0] * nx + pts[i, 1] * ny)[own]) < LINE_INLIER_PX
    votes = np.add.reduceat(close.astype(np.int32), first[:len(draws)], axis=0)  # (S, K)
    votes[~keep.reshape(len(draws), -1)] = -1  # pairs of coincident points define no line
    best = np.argmax(votes, axis=1)
    inliers = np.zeros(len(pts), dtype=bool)
    inliers[:n] = keep[own[np.arange(n), best[side[:n]]]] & close[np.arange(n), best[side[:n]]]
    for _ in range(2):
        inliers = _distances(pts, side, _line_fits(pts, side, inliers)) < LINE_INLIER_PX
    return _line_fits(pts, side, inliers), inliers


def _samples(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each side is read: base points (M, 2) on the sides, their side's unit tangent and
    outward normal (M, 2) each, and the side index (M,), sorted. Sides run corner i -> i + 1,
    clockwise on screen (y down), so the outward normal is the tangent turned a quarter left.
    Along each side the bases are spaced as np.linspace(END_MARGIN, 1 - END_MARGIN, n) spaces them."""
    d = corners[[1, 2, 3, 0]] - corners
    length = np.hypot(d[:, 0], d[:, 1])
    n = _expected(length)
    side = np.repeat(np.arange(4), n)
    first = np.cumsum(n) - n
    s = (np.arange(len(side)) - first[side]) * (((1 - END_MARGIN) - END_MARGIN) / (n - 1))[side] + END_MARGIN
    s[first + n - 1] = 1 - END_MARGIN
    tangent = (d / np.maximum(length, 1e-12)[:, None])[side]
    return corners[side] + s[:, None] * d[side], tangent, np.column_stack([tangent[:, 1], -tangent[:, 0]]), side


def _expected(length: np.ndarray) -> np.ndarray:
    """Profiles read across sides `length` px long (int, shaped like `length`)."""
    return np.clip(length * (1 - 2 * END_MARGIN) / MIN_SPACING_PX, 2, MAX_SAMPLES).astype(int)


def _through_lens(base: np.ndarray, tangent: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (M, 2) on straight sides in ideal pinhole px, with their sides' unit tangents (M, 2)
    -> where `camera` sees them (image px), the unit tangent of the curve the side becomes there
    and its outward normal."""
    seen = distort_pixels(base, camera)
    along = distort_pixels(base + 0.5 * tangent, camera) - distort_pixels(base - 0.5 * tangent, camera)
    along /= np.maximum(np.hypot(along[:, 0], along[:, 1]), 1e-12)[:, None]
    return seen, along, np.column_stack([along[:, 1], -along[:, 0]])


@functools.lru_cache(maxsize=8)
def _linear_light(gamma: float) -> np.ndarray:
    """(256,) float32: each uint8 gray level, encoded with `gamma`, as linear light on the same 0-255 scale."""
    return (255.0 * (np.arange(256) / 255.0) ** gamma).astype(np.float32)


def _edge_points(gray: np.ndarray, corners: np.ndarray, half: float, camera: Camera | None, *,
                 gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel edge points (K, 2) image px found within `half` px across the sides of the quad
    `corners` (4, 2), at most one per profile, and the side (K,) 0..3 of each, sorted, read in the
    linear light of an image encoded with `gamma` (`_linear_light`). With `camera`, `corners` are ideal
    pinhole px and the sides are read along the curves its lens distortion makes of them."""
    base, tangent, normal, side = _samples(corners)
    if camera is not None and camera.has_distortion:
        base, tangent, normal = _through_lens(base, tangent, camera)
    offsets = np.arange(-half, half + STEP_PX / 2, STEP_PX)
    # (M, T, O) x and y: along the side, beside it, across it
    along = np.asarray(TANGENT_OFFSETS_PX)[:, None]
    x, y = ((base[:, i, None, None] + along * tangent[:, i, None, None]) + offsets * normal[:, i, None, None]
            for i in (0, 1))
    h, w = gray.shape
    inside = inside_image(x, y, gray.shape).reshape(len(x), -1).all(axis=1)
    if not inside.any():
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    x, y, base, normal, side = x[inside], y[inside], base[inside], normal[inside], side[inside]
    # Smooth only the neighbourhood read, with a margin the smoothing kernel does not reach
    # past, not the whole image.
    x0, y0 = np.maximum(np.floor([x.min(), y.min()]).astype(int) - SMOOTH_MARGIN_PX, 0)
    x1, y1 = np.minimum(np.ceil([x.max(), y.max()]).astype(int) + 1 + SMOOTH_MARGIN_PX, [w, h])
    patch = cv2.GaussianBlur(cv2.LUT(gray[y0:y1, x0:x1], _linear_light(gamma)), (0, 0), SMOOTH_SIGMA)
    values = cv2.remap(patch, (x - x0).astype(np.float32).reshape(-1, 1), (y - y0).astype(np.float32).reshape(-1, 1),
                       cv2.INTER_LINEAR).reshape(x.shape)
    profile = values.mean(axis=1)  # (M, O)
    deriv = np.empty_like(profile)
    deriv[:, 1:-1] = 0.5 * (profile[:, 2:] - profile[:, :-2])
    deriv[:, 0], deriv[:, -1] = profile[:, 1] - profile[:, 0], profile[:, -1] - profile[:, -2]
    rows = np.arange(len(deriv))
    # Each side's polarity (plaque brighter or darker than what surrounds it) is the sign of its
    # strongest steps overall; a step of the other polarity is text, a frame or clutter.
    strongest = deriv[rows, np.argmax(np.abs(deriv), axis=1)]
    polarity = np.sign(np.bincount(side, weights=strongest, minlength=4))
    signed = deriv * polarity[side][:, None]
    peak = np.argmax(signed, axis=1)
    height = signed[rows, peak]
    # A side's edge has much the same contrast all along it; far weaker steps are something else.
    # MIN_STEP is in the image's own gray levels: in linear light a step at a dark level is that much
    # smaller (the encoding's slope there), and a dim plaque's edges would fall under it.
    level = np.clip(profile[rows, peak] / 255, 0.0, 1.0)
    least = MIN_STEP * STEP_PX * gamma * level ** ((gamma - 1) / gamma)
    ok = ((polarity[side] != 0) & (peak > 0) & (peak < len(offsets) - 1)
          & (height > np.maximum(least, MIN_RELATIVE_STEP * _side_medians(height, side)[side])))
    rows, peak, height = rows[ok], peak[ok], height[ok]
    # The edge is the centroid of the derivative above half its peak, in the run holding the
    # peak: sub-pixel for a sharp step, the middle of the ramp for a blurred one.
    above = signed[rows] > 0.5 * height[:, None]
    idx = np.arange(len(offsets))[None]
    left = np.where(~above & (idx < peak[:, None]), idx, -1).max(axis=1)
    right = np.where(~above & (idx > peak[:, None]), idx, len(offsets)).min(axis=1)
    weight = np.where((idx > left[:, None]) & (idx < right[:, None]), signed[rows] - 0.5 * height[:, None], 0.0)
    where = (weight @ offsets) / weight.sum(axis=1)
    # A run that reaches the end of the profile may go on beyond it: its centroid is biased.
    whole = (left >= 0) & (right < len(offsets))
    rows, where = rows[whole], where[whole]
    return base[rows] + where[:, None] * normal[rows], side[rows]


def _side_medians(values: np.ndarray, side: np.ndarray) -> np.ndarray:
    """(4,) np.median of the (M,) `values` of each side (M,) 0..3; 0 for a side without any."""
    ordered = values[np.lexsort((values, side))]  # by side, then value
    n = np.bincount(side, minlength=4)
    first = np.cumsum(n) - n
    medians = np.zeros(4, values.dtype)
    has = n > 0
    medians[has] = (ordered[(first + (n - 1) // 2)[has]] + ordered[(first + n // 2)[has]]) / 2
    return medians


def refine_outline(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, seed: int = 0,
                   camera: Camera | None = None, *, gamma: float) -> tuple[Outline | None, str | None]:
    """Refine H (library px -> image px) of `sign` from its plaque's four edges in the (H, W) uint8 image,
    encoded with `gamma` (`Settings.edge_gamma`; 1: its gray levels are linear).

    Under `camera`'s lens distortion the edges are curves: they are read along the curves the
    lens makes of straight sides, and the lines are fitted to the edge points as an ideal
    pinhole camera would see them (`undistort_pixels`), where they are straight. A sign wider
    than MAX_DIRECT_WIDTH_PX is outlined in the image shrunk (`_outline_shrunk`). Returns
    (outline, None), or (None, why) when some side shows no consistent straight edge near where
    H puts it; the caller then keeps H.
    """
    # A start H from features is good to about a pixel of the 128-160 px crops SIFT reads, so on a
    # sign much wider than that (a 12 MP photo) its corners can be further off than SEARCH_PX; shrunk,
    # the search reaches as far across it as on a 640 x 480 frame.
    width = quad_width(sign_corners(sign, H))
    if width > MAX_DIRECT_WIDTH_PX:
        return _outline_shrunk(gray, sign, H, seed, camera, SHRUNK_WIDTH_PX / width, gamma)
    return _outline(gray, sign, H, seed, camera, gamma)


def _outline_shrunk(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, seed: int, camera: Camera | None,
                    f: float, gamma: float) -> tuple[Outline | None, str | None]:
    """`_outline` in the image shrunk by `f` < 1, in the image's px.

    Read again at full resolution from there, the edges were no more precise on sharp
    synthetic 3200 x 2400 scenes (rotation median 0.057 against 0.058 degrees, shrunk to 320 px)
    and far less on soft ones (the sample scenes enlarged 5x: 0.093 against 0.061, up to 0.31)."""
    small, to_small, lens = shrunk_view(gray, f, camera, around=sign_corners(sign, H))
    outline, why = _outline(small, sign, to_small @ H, seed, lens, gamma)
    if outline is None:
        return None, f"{why}, in the image shrunk to {f:.2g}x"
    return outline.moved(np.linalg.inv(to_small)), None


def _outline(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, seed: int,
             camera: Camera | None, gamma: float) -> tuple[Outline | None, str | None]:
    """`refine_outline` searching SEARCH_PX px across the sides where H puts them."""
    start = sign_corners(sign, H)
    if camera is not None:
        start = undistort_pixels(start, camera)
    expected = _expected(np.hypot(*(start[[1, 2, 3, 0]] - start).T))
    # Each profile gives at most one edge point, so a side read by fewer profiles than a line needs
    # points (one under 21 px) is refused before the image is read: a far plaque's short sides, in
    # a video where its outline is looked for on every frame.
    short = np.flatnonzero(expected < MIN_SIDE_POINTS)
    if len(short):
        i = int(short[0])
        return None, _side_refused(i, f"{expected[i]} profiles fit along it, fewer than the {MIN_SIDE_POINTS} a "
                                      "line needs", start, gray.shape, camera)
    rng = np.random.default_rng(seed)
    pts, side = _edge_points(gray, start, SEARCH_PX, camera, gamma=gamma)
    ideal = pts if camera is None else undistort_pixels(pts, camera)
    lines, inliers = _robust_lines(ideal, side, rng)
    found = np.bincount(side[inliers], minlength=4)
    for i in range(4):
        if found[i] < max(MIN_SIDE_POINTS, MIN_INLIER_FRACTION * expected[i]):
            return None, _side_refused(i, f"{found[i]} of {expected[i]} profiles on a straight edge (search "
                                          f"{SEARCH_PX} px)", start, gray.shape, camera)
    # corner i joins sides i - 1 and i: the cross product of their lines
    (a1, b1, c1), (a2, b2, c2) = lines[[3, 0, 1, 2]].T, lines.T
    w = a1 * b2 - b1 * a2
    if np.any(np.abs(w) < 1e-12):
        return None, "two adjacent sides are parallel"
    ideal_corners = np.column_stack([(b1 * c2 - c1 * b2) / w, (c1 * a2 - a1 * c2) / w])
    moved = float(np.max(np.hypot(*(ideal_corners - start).T)))
    if moved > 2 * SEARCH_PX:
        return None, f"a corner moved {moved:.1f} px, more than the search allows ({2 * SEARCH_PX} px)"
    corners = ideal_corners if camera is None else distort_pixels(ideal_corners, camera)
    return Outline(corners, sign_to_quad(sign, corners), [pts[inliers & (side == i)] for i in range(4)],
                   sign_to_quad(sign, ideal_corners)), None


def _side_refused(i: int, detail: str, start: np.ndarray, shape: tuple[int, ...], camera: Camera | None) -> str:
    """Why side `i` of the quad `start` (4, 2) px (ideal pinhole px with `camera`) gives no edge: it
    lies mostly outside the (H, W) image `shape`, else `detail`."""
    if _inside_fraction(start[i], start[(i + 1) % 4], shape, camera) < MIN_INLIER_FRACTION:
        return f"side {i + 1} lies mostly outside the image"
    return f"side {i + 1}: {detail}"


def _inside_fraction(a: np.ndarray, b: np.ndarray, shape: tuple[int, ...], camera: Camera | None) -> float:
    """The fraction of the side from `a` to `b` (ideal pinhole px with `camera`, else image px)
    that the (H, W) image `shape` shows."""
    pts = a + np.linspace(0.0, 1.0, 33)[:, None] * (b - a)
    if camera is not None:
        pts = distort_pixels(pts, camera)
    return float(np.mean(inside_image(pts[:, 0], pts[:, 1], shape)))


def outline_fit(R: np.ndarray, t: np.ndarray, outline: Outline, sign: LibrarySign,
                camera: Camera) -> tuple[float, np.ndarray | None]:
    """(RMS residual in image px, (6, 6) covariance over [rotation vector (rad), translation (m)])
    of a pose (R, t) fitted to `outline`, from its edge points: each measures only its distance
    across its side.

    The grid of points a pose is fitted to after refinement is exact by construction, so its
    residuals say nothing about the fit or the noise. Here each edge point's residual is its
    distance from the projected library edge along that edge's image normal; σ² = SSE / (N - 6)
    and the covariance is σ²(JᵀJ)⁻¹ with one row per point (the normal component of the
    projection's Jacobian). The covariance is None when there are too few points or JᵀJ is
    singular; the residual is NaN without points.
    """
    side = np.repeat(np.arange(4), [len(p) for p in outline.points])
    if not len(side):
        return float("nan"), None
    pts = np.concatenate(outline.points)
    rvec = cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0]
    tvec = np.asarray(t, dtype=np.float64).reshape(3, 1)
    # library point of each edge point: through H⁻¹, then onto the library side it belongs to
    q = cv2.perspectiveTransform(undistort_pixels(pts, camera)[None], np.linalg.inv(outline.ideal_H))[0]
    a = sign.corners_px
    ab = a[[1, 2, 3, 0]] - a
    along = np.sum((q - a[side]) * ab[side], axis=1) / np.sum(ab * ab, axis=1)[side]
    q = a[side] + np.clip(along, 0.0, 1.0)[:, None] * ab[side]
    proj, jac = cv2.projectPoints(sign.to_metric(q), rvec, tvec, camera.K, camera.dist)
    proj, jac = proj.reshape(-1, 2), jac[:, :6].reshape(-1, 2, 6)
    # each side's normal in the image, between its projected ends
    ends = cv2.projectPoints(sign.to_metric(a), rvec, tvec, camera.K, camera.dist)[0].reshape(4, 2)
    d = ends[[1, 2, 3, 0]] - ends
    length = np.hypot(d[:, 0], d[:, 1])
    normal = (np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(length, 1e-12)[:, None])[side]
    r = np.sum((pts - proj) * normal, axis=1)
    # Profiles closer than their footprint along the side share noise: weigh each side's rows
    # by how many independent measurements its profiles amount to.
    spacing = length * (1 - 2 * END_MARGIN) / np.maximum(_expected(length) - 1, 1)
    weight = np.sqrt(np.minimum(1.0, spacing / CORRELATION_PX))
    J = (normal[:, :1] * jac[:, 0] + normal[:, 1:] * jac[:, 1]) * weight[side, None]
    rms = float(np.sqrt(r @ r / len(r)))
    dof = len(r) - 6
    JtJ = J.T @ J
    if dof <= 0 or np.linalg.cond(JtJ) > 1e12:
        return rms, None
    return rms, float(r @ r) / dof * np.linalg.inv(JtJ)


def outline_corner_sigma(edge_rms_px: float) -> float:
    """1σ px, in x and in y, of the corners of a sign placed by an outline whose edge points are
    `edge_rms_px` (RMS, image px) off its sides: that scatter, at least CORNER_SIGMA_PX["outline"].

    What blurs, noises or compresses the edges moves a whole side as it scatters its points, so
    the error a side shares, which the points' residuals cannot show, grows with them: the image's
    own evidence, the same for a sharp photo and a blurred video frame. Against the truth, the
    outlined poses' NEES (6 dof, honest median 5.35, p90 10.6) was 5.8 / 13.9 on the 12 s synthetic
    flight's video frames and 2.2 / 9.3 on 640x480 survey photos with a corner σ of 0.1 px, and
    3.8 / 9.7 and 1.6 / 6.8 with this: a tail that was 13 % and 7 % beyond chi-square's 95 % point
    became 6 % and 3 % (measured with the edges read as encoded; read in linear light, the flight's
    poses within 3 m read 2.3 / 7.2).
    """
    return max(CORNER_SIGMA_PX["outline"], edge_rms_px) if math.isfinite(edge_rms_px) else CORNER_SIGMA_PX["outline"]


def outline_pose(pose: Pose, outline: Outline, sign: LibrarySign, camera: Camera) -> Pose:
    """`pose`, fitted to `outline`'s grid (exact by construction, so its residuals say nothing),
    with its reprojection RMSE and covariance measured on the outline's edge points (`outline_fit`)
    plus corners off by `outline_corner_sigma` of that RMSE (`with_corner_floor`)."""
    rmse, covariance = outline_fit(pose.R, pose.t, outline, sign, camera)
    return dataclasses.replace(pose, reprojection_rmse_px=rmse, covariance=with_corner_floor(
        covariance, pose.R, pose.t, sign, camera, outline_corner_sigma(rmse)))
