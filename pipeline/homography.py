"""Plane-to-plane homographies: normalised DLT, the paper's fixed-iteration RANSAC, OpenCV backends.

Homographies map library-sign pixels (src) to image pixels (dst), act on homogeneous column
vectors (x, y, 1) and are scaled so that H[2, 2] = 1 (see `normalize_scale`). A point whose
mapped homogeneous coordinate w is not positive lies on or beyond the vanishing line: with that
scaling, w > 0 means "on the same side of the camera as the src origin", which for a library
sign (origin at its top-left corner) means in front of the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .settings import RANSAC_METHODS

# Mapped w at or below this counts as at/behind infinity (w is ~1 for H[2, 2] = 1 near the src origin).
_MIN_W = 1e-12
# A sample triple is collinear when twice its triangle's area is below this fraction of its
# longest side squared: scale-free, and it also catches repeated or nearly coincident points.
_MIN_TRIANGLE_SHAPE = 1e-3
# The four triples of a 4-point sample; each must be non-collinear for the DLT to be determined.
_TRIPLES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
# Refit/re-classify rounds after RANSAC: the inlier set settles in one or two.
_MAX_REFITS = 3
# Before them, refits on the matches within these multiples of the threshold (local
# optimisation, as in LO-RANSAC): pulls in inliers far from the winning sample's four points.
_WIDER_REFIT_FACTORS = (3.0, 2.0, 1.5)
# Hypotheses scored per block, so that (block, N) error arrays stay around 8 MB at any N.
_SCORE_BLOCK_ELEMENTS = 1 << 20
# Hypotheses per round when stopping adaptively: a clear winner (inlier ratio 0.6 needs ~50 at
# 0.999) stops after a round or two, and numpy's per-call overhead stays small beside the work.
_ADAPTIVE_BLOCK = 64


@dataclass(frozen=True, eq=False)
class HomographyEstimate:
    """A robust homography fit.

    `H`: (3, 3) float64 library px -> image px with H[2, 2] = 1, or None when estimation failed.
    `inliers`: (N,) bool over the input matches. `iterations`: hypotheses drawn (for OpenCV
    backends the maximum allowed, since OpenCV does not report how many it used).
    `method`: one of `pipeline.settings.RANSAC_METHODS`.
    """

    H: np.ndarray | None
    inliers: np.ndarray
    iterations: int
    method: str

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _as_points(pts: np.ndarray, name: str) -> np.ndarray:
    """`pts` as a contiguous (N, 2) float64 array; anything else is a ValueError."""
    arr = np.ascontiguousarray(pts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2); got {arr.shape}")
    return arr


def _as_matches(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Matched (N, 2) src and dst points, checked to have the same length."""
    src, dst = _as_points(src, "src"), _as_points(dst, "dst")
    if len(src) != len(dst):
        raise ValueError(f"src and dst must have the same length; got {len(src)} and {len(dst)}")
    return src, dst


def _normalize_batch(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation of (B, N, 2) points: returns T (B, 3, 3) and T-mapped points (B, N, 2)."""
    centroid = pts.mean(axis=1, keepdims=True)
    centred = pts - centroid
    mean_dist = np.sqrt(centred[..., 0] ** 2 + centred[..., 1] ** 2).mean(axis=1)
    # Coincident points have no scale; leave them unscaled and let the DLT report degeneracy.
    scale = np.sqrt(2.0) / np.where(mean_dist > 0, mean_dist, np.sqrt(2.0))
    T = np.zeros((len(pts), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = scale
    T[:, :2, 2] = -scale[:, None] * centroid[:, 0, :]
    T[:, 2, 2] = 1.0
    return T, centred * scale[:, None, None]


def normalize_points(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation of (N, 2) points (px).

    Returns T (3, 3), the similarity moving the centroid to the origin and scaling the mean
    distance from it to sqrt(2), and the normalised points (N, 2) = T applied to `pts`.
    """
    T, pts_n = _normalize_batch(_as_points(pts, "pts")[None])
    return T[0], pts_n[0]


def normalize_scale(H: np.ndarray) -> np.ndarray:
    """(..., 3, 3) homographies scaled to H[2, 2] = 1.

    When H[2, 2] is ~0 (the src origin maps to infinity) the unit-Frobenius-norm scaling is
    returned instead, so the result is always finite.
    """
    H = np.asarray(H, dtype=np.float64)
    h22 = H[..., 2, 2]
    frob = np.linalg.norm(H, axis=(-2, -1))
    usable = np.abs(h22) > 1e-12 * frob
    scale = np.where(usable, h22, np.where(frob > 0, frob, 1.0))
    return H / scale[..., None, None]


def dlt_homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Normalised DLT for a batch: src, dst (B, N, 2) px with N >= 4 -> H (B, 3, 3), H[2, 2] = 1.

    Each H minimises the algebraic error of its N correspondences; all B systems go through one
    batched SVD, which is what keeps RANSAC's thousands of minimal fits fast.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 3 or src.shape[2] != 2 or src.shape[1] < 4:
        raise ValueError(f"src and dst must both have shape (B, N>=4, 2); got {src.shape} and {dst.shape}")
    B, N = src.shape[:2]
    T_src, s = _normalize_batch(src)
    T_dst, d = _normalize_batch(dst)
    x, y = s[..., 0], s[..., 1]
    u, v = d[..., 0], d[..., 1]
    A: np.ndarray = np.zeros((B, N, 2, 9))  # per point a row for u, then one for v
    A[..., 0, 0], A[..., 0, 1], A[..., 0, 2] = -x, -y, -1.0
    A[..., 1, 3], A[..., 1, 4], A[..., 1, 5] = -x, -y, -1.0
    A[..., 0, 6], A[..., 0, 7], A[..., 0, 8] = u * x, u * y, u
    A[..., 1, 6], A[..., 1, 7], A[..., 1, 8] = v * x, v * y, v
    A = A.reshape(B, 2 * N, 9)
    # full_matrices=True gives all nine right singular vectors even for the 8 x 9 minimal system,
    # but would also build a (2N, 2N) U for large N; the reduced SVD has them once 2N >= 9.
    _, _, vh = np.linalg.svd(A, full_matrices=2 * N < 9)
    H_n = vh[:, -1, :].reshape(B, 3, 3)
    return normalize_scale(np.linalg.inv(T_dst) @ H_n @ T_src)


def dlt_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Normalised DLT: src, dst (N, 2) px with N >= 4 -> H (3, 3) with H[2, 2] = 1."""
    src, dst = _as_matches(src, dst)
    return dlt_homographies(src[None], dst[None])[0]


def minimal_homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Exact H for each 4-point sample: src, dst (B, 4, 2) px, no triple collinear -> (B, 3, 3), H[2, 2] = 1."""
    return _homographies_from_areas(src, dst, _triangle_areas(src)[0], _triangle_areas(dst)[0])


def _homographies_from_areas(src: np.ndarray, dst: np.ndarray, src_area: np.ndarray,
                             dst_area: np.ndarray) -> np.ndarray:
    """`minimal_homographies` given each side's `_triangle_areas`, which RANSAC has already computed.

    In closed form, an order of magnitude faster than the SVD of `dlt_homographies`: with P the
    3x3 matrix of the first three points (homogeneous columns) and P lam = p4, the map
    M = P diag(lam) sends the projective basis onto the sample, and H = M_dst M_src^-1
    = P_dst diag(mu / lam) adj(P_src) up to scale. By Cramer's rule lam (and mu) are the
    triangle areas with p4 substituted, over a common det(P) that scale absorbs.
    """
    def lam(area: np.ndarray) -> np.ndarray:  # (B, 3), up to a common scale, from the `_TRIPLES` areas
        return np.stack([area[:, 3], -area[:, 2], area[:, 1]], axis=1)

    ls, ld = lam(src_area), lam(dst_area)
    # mu / lam without the division: all three times lam0 lam1 lam2.
    coef = ld * ls[:, [1, 0, 0]] * ls[:, [2, 2, 1]]
    hom_dst = np.concatenate([dst[:, :3], np.ones((len(dst), 3, 1))], axis=2)
    # Rows of adj(P) are cross products of P's columns: p2 x p3, p3 x p1, p1 x p2, here with
    # each point's w = 1 written out.
    x, y = src[:, :3, 0], src[:, :3, 1]
    x1, y1, x2, y2 = x[:, [1, 2, 0]], y[:, [1, 2, 0]], x[:, [2, 0, 1]], y[:, [2, 0, 1]]
    adj = np.stack([y1 - y2, x2 - x1, x1 * y2 - y1 * x2], axis=2)
    return normalize_scale((hom_dst.transpose(0, 2, 1) * coef[:, None, :]) @ adj)


def transfer_errors(H: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Forward reprojection distance |H src - dst| in dst px.

    H: (3, 3) or (B, 3, 3); src, dst: (N, 2) px. Returns (N,) or (B, N). Points that H maps to
    or beyond infinity (w <= 0, see the module docstring) get +inf.
    """
    src, dst = _as_matches(src, dst)
    H = np.asarray(H, dtype=np.float64)
    # Coordinates-first (..., 3, N) keeps each row contiguous: the batched case is RANSAC's hot loop.
    mapped = H @ np.vstack([src.T, np.ones(len(src))])
    w = mapped[..., 2, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        du = mapped[..., 0, :] / w - dst[:, 0]
        dv = mapped[..., 1, :] / w - dst[:, 1]
        dist = np.sqrt(du * du + dv * dv)
    return np.where(w > _MIN_W, dist, np.inf)


def _draw_samples(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """(count, 4) indices into n >= 4 points, each row 4 distinct indices drawn uniformly.

    The k-th pick is drawn from the n - k unused indices by shifting past the earlier picks
    in ascending order: exact, vectorised and with no rejection loop.
    """
    picks = np.empty((count, 4), dtype=np.intp)
    for k in range(4):
        r = rng.integers(0, n - k, size=count)
        for earlier in np.sort(picks[:, :k], axis=1).T:
            r += r >= earlier
        picks[:, k] = r
    return picks


def _triangle_areas(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (B, 4, 2) samples: (B, 4) twice the signed area of each triple in `_TRIPLES`, and
    (B, 4) bool, the triple is collinear (`_MIN_TRIANGLE_SHAPE`)."""
    x, y = pts[..., 0], pts[..., 1]
    i, j, k = _TRIPLES.T
    abx, aby = x[:, j] - x[:, i], y[:, j] - y[:, i]
    acx, acy = x[:, k] - x[:, i], y[:, k] - y[:, i]
    area = abx * acy - aby * acx
    longest_sq = np.maximum(np.maximum(abx * abx + aby * aby, acx * acx + acy * acy),
                            (acx - abx) ** 2 + (acy - aby) ** 2)
    return area, np.abs(area) <= _MIN_TRIANGLE_SHAPE * longest_sq


def _usable_samples(src_areas: tuple[np.ndarray, np.ndarray], dst_areas: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(B,) bool: samples, given each side's `_triangle_areas`, that determine a homography that can be real.

    Rejects samples with a collinear triple on either side, and samples whose triples change
    orientation inconsistently: a homography keeping all four points in front of the camera
    flips either every triangle or none.
    """
    (s, s_flat), (d, d_flat) = src_areas, dst_areas
    agree = np.sign(s) * np.sign(d)
    consistent = np.all(agree == 1, axis=1) | np.all(agree == -1, axis=1)
    return consistent & ~np.any(s_flat | d_flat, axis=1)


def _failed(n: int, iterations: int, method: str) -> HomographyEstimate:
    """The result of an estimation that found no homography among n matches."""
    return HomographyEstimate(H=None, inliers=np.zeros(n, dtype=bool), iterations=iterations, method=method)


def _inlier_masks(H: np.ndarray, src: np.ndarray, dst: np.ndarray, threshold: float) -> np.ndarray:
    """(B, N) bool: `transfer_errors(H, src, dst) < threshold` for H (B, 3, 3) and (N, 2) matches.

    Without its divisions and square roots, which dominate RANSAC's scoring: for w > 0,
    |m / w - d| < threshold is |m - d w|^2 < (threshold w)^2.
    """
    src_h = np.vstack([src.T, np.ones(len(src))])
    # One (B, 3) x (3, N) product per row of H keeps x, y and w contiguous (B, N) arrays, which
    # the element-wise test below runs on several times faster than on strided (B, 3, N) slices.
    x, y, w = (H[:, row] @ src_h for row in range(3))
    x -= dst[:, 0] * w
    y -= dst[:, 1] * w
    return (w > _MIN_W) & (x * x + y * y < threshold * threshold * (w * w))


def hypotheses_needed(n_inliers: int, n: int, confidence: float) -> float:
    """Random 4-point samples needed to draw at least one all-inlier sample with `confidence`,
    when `n_inliers` of `n` matches are inliers (the standard adaptive RANSAC bound)."""
    p_clean = (n_inliers / n) ** 4
    if p_clean >= 1.0:
        return 1.0
    if p_clean <= 0.0:
        return math.inf
    return math.log1p(-confidence) / math.log1p(-p_clean)


def _block_best(src: np.ndarray, dst: np.ndarray, samples: np.ndarray, threshold: float) -> np.ndarray | None:
    """The (N,) inlier mask of the usable sample (of (B, 4)) with most inliers, the earliest on ties;
    None when no sample is usable."""
    s, d = src[samples], dst[samples]
    s_areas, d_areas = _triangle_areas(s), _triangle_areas(d)
    usable = _usable_samples(s_areas, d_areas)
    if not usable.any():
        return None
    H = _homographies_from_areas(s[usable], d[usable], s_areas[0][usable], d_areas[0][usable])
    inliers = _inlier_masks(H, src, dst, threshold)
    return inliers[int(np.argmax(np.count_nonzero(inliers, axis=1)))]


def _best_consensus(src: np.ndarray, dst: np.ndarray, samples: np.ndarray, threshold: float,
                    confidence: float | None = None) -> tuple[np.ndarray | None, int]:
    """Fit the usable samples (S, 4) in order; the (N,) inlier mask of the one with most inliers
    (None when no sample is usable) and how many samples were used.

    Without `confidence` every sample is used. With it, a first block of `_ADAPTIVE_BLOCK`, then
    on in one block to as many as `hypotheses_needed` says the best consensus so far still
    needs, until that many were drawn. Ties go to the earliest sample, so the result depends
    only on the sample order.
    """
    best: np.ndarray | None = None
    max_block = max(1, _SCORE_BLOCK_ELEMENTS // len(src))  # bounds the (block, N) arrays
    target = len(samples) if confidence is None else min(_ADAPTIVE_BLOCK, len(samples))
    drawn = 0
    while drawn < target:
        stop = min(target, drawn + max_block)
        found = _block_best(src, dst, samples[drawn:stop], threshold)
        if found is not None and (best is None or np.count_nonzero(found) > np.count_nonzero(best)):
            best = found
        drawn = stop
        if confidence is not None and drawn == target:
            needed = math.inf if best is None else hypotheses_needed(int(np.count_nonzero(best)), len(src), confidence)

            target = len(samples) if needed >= len(samples) else max(drawn, math.ceil(needed))
    return best, drawn


def _refine(src: np.ndarray, dst: np.ndarray, inliers: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """The refit of the winning sample's inliers (`_refit`) or of a wider set, whichever keeps more
    inliers. Returns (H, inliers under that H).

    The minimal-sample H interpolates 4 noisy points and extrapolates poorly: with its inliers
    bunched on one side of the sign, a refit at `threshold` can settle without the inliers on the
    other. The wider set comes from refits on the matches within `_WIDER_REFIT_FACTORS` times the
    threshold of the plain refit's H, shrinking to it. With 30 matches, 35-50 % outliers and 1 px
    noise, 10 % of random cases kept under 90 % of the inliers without it, 0.2 % with it (3000
    cases each). But with few inliers among many outliers the wide refits can take in outliers
    and lose the sign (a sample scene went from 10+ inliers to 0), so the plain refit stays the
    fallback. Where no match lies in the widest band, as on most clean images, there is nothing
    to widen and the wide refits are skipped.
    """
    H, inliers, errors = _refit(src, dst, inliers, threshold)
    plain = H, inliers
    if np.count_nonzero(errors < _WIDER_REFIT_FACTORS[0] * threshold) == np.count_nonzero(inliers):
        return plain
    wider = None
    for factor in _WIDER_REFIT_FACTORS:
        band = errors < factor * threshold
        if np.count_nonzero(band) < 4:
            break
        wider = band
        errors = transfer_errors(dlt_homography(src[wider], dst[wider]), src, dst)
    if wider is None:  # not even the widest band holds 4 matches (the plain refit may have kept fewer)
        return plain
    widened = _refit(src, dst, wider, threshold)[:2]
    return widened if np.count_nonzero(widened[1]) > np.count_nonzero(plain[1]) else plain


def _refit(src: np.ndarray, dst: np.ndarray, inliers: np.ndarray,
           threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refit H by DLT on all `inliers` and re-classify with it; repeat while the inlier set grows.
    The least-squares refit is kept even if a borderline match drops out, and usually admits a few
    more. Returns (H, inliers under that H, (N,) transfer errors under that H)."""
    for _ in range(_MAX_REFITS):
        H = dlt_homography(src[inliers], dst[inliers])
        errors = transfer_errors(H, src, dst)
        refit_inliers = errors < threshold
        grew = refit_inliers.sum() > inliers.sum()
        inliers = refit_inliers
        if not grew:
            break
    return H, inliers, errors


def ransac_homography(src: np.ndarray, dst: np.ndarray, iterations: int = 50, threshold: float = 3.0,
                      seed: int = 0, confidence: float | None = None) -> HomographyEstimate:
    """The paper's RANSAC: exactly `iterations` random 4-point hypotheses, most inliers wins.

    src, dst: (N, 2) library px and image px of the matches. A match is an inlier when its
    forward transfer error is below `threshold` image px. Samples come from
    `np.random.default_rng(seed)`, so a seed always gives the same answer. Degenerate samples
    (see `_usable_samples`) are drawn but not fitted: they still count as iterations. The
    winner's inliers are then refitted (`_refine`). Fewer than 4 matches, or no usable sample,
    gives H None. With `confidence`, `iterations` is a maximum: drawing stops early once the
    best consensus makes a better one unlikely (`hypotheses_needed`), and the estimate's
    `iterations` says how many were drawn; it is a prefix of the same samples, so still
    deterministic for a seed.
    """
    src, dst = _as_matches(src, dst)
    if len(src) < 4:
        return _failed(len(src), 0, "own")
    samples = _draw_samples(np.random.default_rng(seed), len(src), iterations)
    best, drawn = _best_consensus(src, dst, samples, threshold, confidence)
    if best is None or best.sum() < 4:
        return _failed(len(src), drawn, "own")
    H, inliers = _refine(src, dst, best, threshold)
    return HomographyEstimate(H=H, inliers=inliers, iterations=drawn, method="own")


def _usac_params(method: str, iterations: int, threshold: float, confidence: float, seed: int) -> cv2.UsacParams:
    """UsacParams reproducing OpenCV's `cv2.USAC_MAGSAC` / `cv2.USAC_ACCURATE` presets, plus a seed.

    The flag presets always seed USAC's generator with 0; only UsacParams exposes the state.
    The values mirror OpenCV's `setParameters` for each flag (with seed 0 the results are identical).
    """
    p = cv2.UsacParams()
    p.threshold = threshold
    p.confidence = confidence
    p.maxIterations = iterations
    p.randomGeneratorState = seed
    p.sampler = cv2.SAMPLING_UNIFORM
    p.neighborsSearch = cv2.NEIGH_GRID
    if method == "usac_magsac":
        p.score, p.loMethod, p.loSampleSize, p.loIterations = cv2.SCORE_METHOD_MAGSAC, cv2.LOCAL_OPTIM_SIGMA, 75, 15
        p.final_polisher = cv2.MAGSAC
    else:
        p.score, p.loMethod, p.loSampleSize, p.loIterations = cv2.SCORE_METHOD_MSAC, cv2.LOCAL_OPTIM_GC, 20, 25
        p.final_polisher = cv2.COV_POLISHER
    return p


def _cv2_homography(src: np.ndarray, dst: np.ndarray, method: str, iterations: int, threshold: float,
                    confidence: float, seed: int) -> HomographyEstimate:
    """An OpenCV backend; inliers are re-classified with the returned H (see `estimate_homography`)."""
    if len(src) < 4:
        return _failed(len(src), 0, method)
    if method == "cv2_ransac":
        H, _ = cv2.findHomography(src, dst, cv2.RANSAC, threshold, maxIters=iterations, confidence=confidence)
    else:
        H, _ = cv2.findHomography(src, dst, _usac_params(method, iterations, threshold, confidence, seed))
    if H is None or H.shape != (3, 3) or not np.all(np.isfinite(H)):
        return _failed(len(src), iterations, method)
    H = normalize_scale(H)
    return HomographyEstimate(H=H, inliers=transfer_errors(H, src, dst) < threshold, iterations=iterations,
                              method=method)


def estimate_homography(src: np.ndarray, dst: np.ndarray, method: str = "own", iterations: int = 500,
                        threshold: float = 4.0, confidence: float = 0.999, seed: int = 0,
                        adaptive: bool = False) -> HomographyEstimate:
    """Robust homography library px -> image px from (N, 2) matches by `method` (`RANSAC_METHODS`).

    "own": `ransac_homography`, exactly `iterations` hypotheses, or with `adaptive` at most that
    many, stopping early at `confidence` (`confidence` is otherwise unused). "cv2_ransac":
    `cv2.findHomography(..., cv2.RANSAC)`, which seeds its own generator with a constant, so it
    is deterministic but ignores `seed`. "usac_magsac" / "usac_accurate": OpenCV's USAC presets
    with `seed` as the generator state. OpenCV backends stop adaptively at `confidence` and do
    not report how many hypotheses they drew: `iterations` in the result is the maximum allowed.
    Every backend's inliers are the matches whose forward transfer error under the returned H is
    below `threshold` px, so inlier counts mean the same thing whichever backend produced them.
    """
    if method not in RANSAC_METHODS:
        raise ValueError(f"unknown homography method {method!r}; choose from {', '.join(RANSAC_METHODS)}")
    if method == "own":
        return ransac_homography(src, dst, iterations=iterations, threshold=threshold, seed=seed,
                                 confidence=confidence if adaptive else None)
    return _cv2_homography(*_as_matches(src, dst), method, iterations, threshold, confidence, seed)
