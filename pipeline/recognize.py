"""Stage 5: which library sign is in the image, where, and the camera pose it gives.

For each candidate region (the largest white blobs, then optionally the full frame) every
library sign is scored by its RANSAC inliers; the winner needs enough inliers, a plausible
homography and a margin over the runner-up. "No sign" is a first-class answer.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera, CameraError, assumed_camera
from .features import Features, detect, library_affine_features, library_features, search_settings
from .homography import HomographyEstimate, estimate_homography
from .image import to_gray
from .library import Library, LibrarySign
from .match import Matches, match_library
from .outline import Outline, outline_pose, refine_outline
from .plaque import (PlaqueMatch, grid_correspondences, match_plaque, project, refine_ecc, seen_grid, seen_homography,
                     sign_to_quad)
from .plaque_search import (MAX_ALIGNED, MIN_NCC, SAME_PLAQUE_IOU, BlobReading, QuadCandidate, confirm_plaque, cut_image,
                           cut_levels, level_quads, plaque_order, quad_levels, ranked, read_blob, search_plaques)
from .pose import CORNER_SIGMA_PX, Pose, PoseError, estimate_pose
from .segment import Box, Segmentation, box_iou, expand_box, segment
from .settings import Settings
from .stages import StageCache, StageRunner
from .verify import (MOSTLY_IN_VIEW, OUTLINE_FLOOR_PX, TextCheck, check_text, dense_agrees, overwhelming,
                     text_threshold, visible_fraction)

# A sign seen from any usable viewpoint projects to a convex quad whose opposite sides differ
# in length by far less than this factor; larger means a degenerate H fitted to a few points.
MAX_SIDE_RATIO = 8.0
# Corners may leave the image (a sign at the frame edge, or one closer than the frame is wide), but
# not by more than this many image sizes: a sign up to 4 frames wide. At 0.5 a UAV closing in on a
# plaque lost it at twice the frame's width with 28 inliers; 1.5 answered the same as 0.5 on 550
# synthetic scenes, sample datasets and decoy plaques.
MAX_CORNER_EXCURSION = 1.5
# A picture (a poster, a facade) is often seen from closer than its size: the homogr pair BostonLib
# shows a part of its A, whose corners lie 2.5 frames beyond B's edge (its H 0.6 px off).
MAX_PICTURE_CORNER_EXCURSION = 4.0
MIN_QUAD_AREA_PX = 64.0
# Below this ECC correlation the dense alignment has latched onto something other than the sign.
MIN_ECC = 0.5
# refine="auto" aligns densely below this many inliers, where a point-based pose wanders.
AUTO_ECC_MAX_INLIERS = 30
# A homography needs four correspondences, whatever settings.min_matches says.
MIN_HOMOGRAPHY_POINTS = 4
# The zoom (`zoom_region`): a square this fraction of the image's width, where the full frame's
# matches (to any sign) crowd most, searched again ZOOM_SCALE times larger when it holds at least
# ZOOM_MIN_MATCHES. A sign 50-150 px wide yields a handful of true matches in the full frame, too few
# for a homography among the clutter's, but they crowd where it is; searched at twice the resolution,
# 4 of the photo world's misses gave their sign 9-15 inliers where the full frame gave 0-6. On its
# 150 scenes (seed 0) the signs it found held 11-26 matches in the window, the 15 photos without a
# plaque 6-18: at 15, 7 of the 9 found and 2 of those 15 photos searched again. At 11, a window of
# 0.2 found 4 more hard views, 0.3 6, 0.4 4.
ZOOM_WINDOW = 0.3
ZOOM_SCALE = 2.0
ZOOM_MIN_MATCHES = 15


@dataclass(eq=False)
class SignScore:
    """How well one library sign explains one region of the image.

    src, dst: (M, 2) matched points in library px and image px; `estimate.inliers` marks the
    RANSAC inliers among them; corners: (4, 2) image px of the sign's TL, TR, BR, BL, or None.
    """

    sign: str
    matches: Matches = field(repr=False)
    src: np.ndarray = field(repr=False)
    dst: np.ndarray = field(repr=False)
    estimate: HomographyEstimate | None = field(repr=False)
    corners: np.ndarray | None = field(repr=False)
    reason: str | None = None
    skipped: bool = False  # not fitted: too few matches to win or to narrow the winner's margin

    @property
    def n_matches(self) -> int:
        return len(self.matches)

    @property
    def n_inliers(self) -> int:
        return self.estimate.n_inliers if self.estimate is not None else 0

    @property
    def inlier_bound(self) -> int:
        """Its inliers, or for a sign not fitted because it could not matter, at most its matches."""
        return self.n_matches if self.skipped else self.n_inliers

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_matches if self.n_matches else 0.0

    @property
    def H(self) -> np.ndarray | None:
        return self.estimate.H if self.estimate is not None else None

    def to_json(self) -> dict:
        return {"sign": self.sign, "matches": self.n_matches, "inliers": self.n_inliers, "reason": self.reason}


@dataclass(eq=False)
class Attempt:
    """One candidate region searched: its features, every sign's score and the decision.

    margin: the best sign's inliers minus the runner-up's, counting a sign that was not fitted
    at its match count (so a lower bound on the margin fitting every sign would give).
    """

    region: Box
    source: str  # "blob 1", "blob 2", ..., "plaque 1", ..., "full frame"
    features: Features = field(repr=False)
    scores: list[SignScore]
    winner: int | None
    margin: int

    @property
    def best_inliers(self) -> int:
        return max((s.n_inliers for s in self.scores), default=0)

    @property
    def leader(self) -> SignScore | None:
        """The sign with the most inliers, won or not; None without scores. Of signs tied on
        inliers, one with a `reason` (the one `decide` turned down for its margin), then the
        one with more matches."""
        return max(self.scores, key=lambda s: (s.n_inliers, s.reason is not None, s.n_matches), default=None)


@dataclass(frozen=True, eq=False)
class Refined:
    """A winner after `refine_winner`: its homography H (library px -> image px), the
    correspondences src, dst (N, 2) library and image px its pose is fitted to, the ECC
    correlation or outline that refined it (else None), its `sign`, the check of its text
    (None: not checked) and the warnings refinement gave."""

    H: np.ndarray = field(repr=False)
    src: np.ndarray = field(repr=False)
    dst: np.ndarray = field(repr=False)
    ecc: float | None
    outline: Outline | None = field(repr=False)
    sign: LibrarySign = field(repr=False)
    text: TextCheck | None
    notes: list[str]

    def text_problem(self, min_correlation: float) -> str | None:
        """Why the winner is turned down for its text at `min_correlation` (`verify.text_threshold`), None if it is not."""
        return None if self.text is None else self.text.problem(self.sign, min_correlation)


@dataclass(frozen=True, eq=False)
class TurnedDown:
    """A winner the text check turned down: its `sign` id, where it was found (`source`: an
    Attempt's, or "plaque fallback"), its refined H (library px -> image px) and the check."""

    sign: str
    source: str
    H: np.ndarray = field(repr=False)
    text: TextCheck

    def to_json(self) -> dict:
        return {"sign": self.sign, "source": self.source, "text_check": self.text.to_json()}


def why_no_feature_winner(attempt: Attempt | None) -> str:
    """Why features recognised nothing in `attempt`, the region their answer came from: its
    leader's reason, or that no region was searched."""
    leader = attempt.leader if attempt is not None else None
    return leader.reason if leader is not None else "no candidate region"


@dataclass(eq=False)
class Recognition:
    """Everything the pipeline computed for one image; `attempt` is the region the answer came from.

    H: the final homography (library px -> image px) of the recognised sign, after refinement;
    ecc: the correlation of the dense alignment that refined it (None when not refined);
    outline: the plaque outline that refined it instead (None when not refined so);
    text_check: how its text, rectified through H, correlates with the sign's (None: not checked).
    turned_down: the winners the text check turned down before it, in the order found.
    timing_ms: milliseconds per stage of `stages.STAGES` and in "total"; reused_stages: the stages,
    in STAGES order, whose results came in whole or part from the caller's `StageCache`, so their
    times are a lookup's, not what the stage costs.
    """

    image_size: tuple[int, int]
    settings: Settings
    camera: Camera
    segmentation: Segmentation | None = field(repr=False)
    attempts: list[Attempt] = field(repr=False)
    attempt: Attempt | None = field(repr=False)
    plaque: PlaqueMatch | None = field(repr=False)
    H: np.ndarray | None = field(repr=False)
    ecc: float | None
    pose: Pose | None
    timing_ms: dict[str, float]
    reused_stages: list[str]
    warnings: list[str]
    sign_corners_px: np.ndarray | None = field(repr=False, default=None)
    outline: Outline | None = field(repr=False, default=None)
    text_check: TextCheck | None = None
    turned_down: list[TurnedDown] = field(default_factory=list)

    @property
    def best(self) -> SignScore | None:
        """The winning sign's feature score, when features decided."""
        a = self.attempt
        return None if no_feature_winner(a) else a.scores[a.winner]

    @property
    def by_plaque(self) -> bool:
        """True when the plaque fallback, not features, recognised the sign."""
        return self.best is None and self.plaque is not None and self.plaque.sign is not None

    @property
    def label(self) -> str | None:
        if self.best is not None:
            return self.best.sign
        return self.plaque.sign if self.by_plaque else None

    @property
    def recognized(self) -> bool:
        return self.label is not None

    @property
    def scores(self) -> list[SignScore]:
        return self.attempt.scores if self.attempt is not None else []

    @property
    def margin(self) -> int:
        return self.attempt.margin if self.attempt is not None else 0

    @property
    def corners(self) -> np.ndarray | None:
        """(4, 2) image px of the recognised sign's TL, TR, BR, BL through the final H."""
        if self.H is None:
            return None
        hom = project(self.H, self.sign_corners_px)
        return hom[:, :2] / hom[:, 2:]

    def to_json(self, image: str) -> dict:
        """The CLI's and API's JSON schema for one image."""
        return {
            "image": image,
            "recognized": self.recognized,
            "label": self.label,
            "scores": [s.to_json() for s in self.scores],
            "homography": _list(self.H),
            "corners": _list(self.corners),
            "pose": self.pose.to_json() if self.pose is not None else None,
            "text_check": self.text_check.to_json() if self.text_check is not None else None,
            "turned_down": [t.to_json() for t in self.turned_down],
            "timing_ms": {k: round(v, 3) for k, v in self.timing_ms.items()},
            "reused_stages": list(self.reused_stages),
            "warnings": list(self.warnings),
        }


def _list(a: np.ndarray | None):
    return None if a is None else np.asarray(a, dtype=float).tolist()


def quad_problem(H: np.ndarray, sign: LibrarySign, width: int, height: int) -> tuple[np.ndarray | None, str | None]:
    """Project the sign's corners through H and say what, if anything, makes the result implausible.

    Returns ((4, 2) corners or None, reason or None).
    """
    # Four points: plain floats, not numpy's per-call overhead (the tracker checks every sign on every frame).
    w_px, h_px = sign.size_px
    (a, b, c), (d, e, f), (g, h, i) = np.asarray(H, dtype=np.float64).tolist()
    hom = [(a * x + b * y + c, d * x + e * y + f, g * x + h * y + i)
           for x, y in ((0.0, 0.0), (w_px, 0.0), (w_px, h_px), (0.0, h_px))]
    if any(z <= 1e-12 * max(abs(u), abs(v)) for u, v, z in hom):
        return None, "degenerate homography: the sign plane crosses the horizon"
    xy = [(u / z, v / z) for u, v, z in hom]
    corners = np.array(xy)
    edges = [(xy[(k + 1) % 4][0] - xy[k][0], xy[(k + 1) % 4][1] - xy[k][1]) for k in range(4)]
    if any(edges[k][0] * edges[(k + 1) % 4][1] - edges[k][1] * edges[(k + 1) % 4][0] <= 0 for k in range(4)):
        # TL, TR, BR, BL run clockwise on screen (y down); anything else is mirrored, self-crossing or concave.
        return corners, "degenerate homography: non-convex, self-crossing or mirrored quad"
    area = 0.5 * abs(sum(xy[k][0] * xy[(k + 1) % 4][1] - xy[k][1] * xy[(k + 1) % 4][0] for k in range(4)))
    sides = [math.hypot(ex, ey) for ex, ey in edges]
    if area < MIN_QUAD_AREA_PX or max(sides[0] / sides[2], sides[2] / sides[0],
                                      sides[1] / sides[3], sides[3] / sides[1]) > MAX_SIDE_RATIO:
        return corners, "absurd scale: the sign would be tiny or extremely foreshortened"
    excursion = MAX_PICTURE_CORNER_EXCURSION if sign.kind == "picture" else MAX_CORNER_EXCURSION
    margin_x, margin_y = excursion * width, excursion * height
    if any(x < -margin_x or x > width + margin_x or y < -margin_y or y > height + margin_y for x, y in xy):
        return corners, "corners far outside the image"
    return corners, None


def match_points(query: Features, train: Features, matches: Matches) -> tuple[np.ndarray, np.ndarray]:
    """(M, 2) float64 library px and (M, 2) float64 image px of the matched keypoints."""
    return train.xy[matches.train_idx].astype(np.float64), query.xy[matches.query_idx].astype(np.float64)


def min_fit_matches(settings: Settings) -> int:
    """The fewest matches a sign is fitted with: `score_sign` refuses one with fewer as "too few
    matches", and `score_signs` skips (as "not fitted") only signs with at least this many."""
    return max(MIN_HOMOGRAPHY_POINTS, settings.min_matches)


def score_sign(sign: LibrarySign, query: Features, train: Features, matches: Matches, settings: Settings,
               image_size: tuple[int, int], timing: dict[str, float]) -> SignScore:
    """Fit H to the `matches` between `query` and one sign's features by RANSAC and check it."""
    t1 = time.perf_counter()
    score = SignScore(sign.id, matches, *match_points(query, train, matches), None, None)
    least = min_fit_matches(settings)
    if len(matches) < least:
        score.reason = f"too few matches ({len(matches)} < {least})"
        return score
    score.estimate = estimate_homography(score.src, score.dst, settings.ransac_method, settings.ransac_iterations,
                                         settings.ransac_threshold_px, settings.ransac_confidence, settings.seed,
                                         settings.ransac_adaptive)
    timing["ransac"] += (time.perf_counter() - t1) * 1e3
    if score.estimate.H is None:
        score.reason = "no homography found"
    elif score.n_inliers < settings.min_inliers:
        score.reason = f"too few inliers ({score.n_inliers} < {settings.min_inliers})"
    if score.estimate.H is not None:
        score.corners, problem = quad_problem(score.estimate.H, sign, *image_size)
        score.reason = score.reason or problem
    return score


def score_signs(library: Library, query: Features, lib: dict[str, Features], matches: list[Matches],
                settings: Settings, image_size: tuple[int, int], timing: dict[str, float]) -> list[SignScore]:
    """Every library sign's score, in library order.

    Signs are fitted in order of their match count. Once a sign is valid, a sign with no more
    matches than the leader's inliers minus `min_margin` can neither win nor narrow the margin
    below `min_margin` (its inliers are at most its matches), so RANSAC on it is skipped: the
    decision is the one fitting it would give, and `decide` counts it at its match count.
    """
    scores: dict[str, SignScore] = {}
    leader = None
    for sign, m in sorted(zip(library.signs, matches), key=lambda sm: -len(sm[1])):
        if leader is not None and min_fit_matches(settings) <= len(m) <= leader - settings.min_margin:
            scores[sign.id] = SignScore(sign.id, m, *match_points(query, lib[sign.id], m), None, None,
                                        f"not fitted: {len(m)} matches cannot challenge the leader's "
                                        f"{leader} inliers (the margin counts them as {len(m)} inliers)",
                                        skipped=True)
            continue
        score = score_sign(sign, query, lib[sign.id], m, settings, image_size, timing)
        if score.reason is None:
            leader = max(leader or 0, score.n_inliers)
        scores[sign.id] = score
    return [scores[sign.id] for sign in library.signs]


def decide(scores: list[SignScore], settings: Settings) -> tuple[int | None, int]:
    """Index of the winning sign (or None) and its inlier margin over the runner-up.

    Sets the reason of a best sign whose margin is too small.
    """
    order = sorted(range(len(scores)), key=lambda i: -scores[i].n_inliers)
    valid = [i for i in order if scores[i].reason is None]
    if not valid:
        return None, 0
    best = valid[0]
    runner_up = max((scores[i].inlier_bound for i in order if i != best), default=0)
    margin = scores[best].n_inliers - runner_up
    if margin < settings.min_margin:
        scores[best].reason = f"margin over the runner-up too small ({margin} < {settings.min_margin})"
        return None, margin
    return best, margin


def candidate_regions(segmentation: Segmentation | None, settings: Settings, width: int, height: int,
                      quads: Callable[[int], Iterator[list[QuadCandidate]]],
                      first_is_no_sign: bool) -> Iterator[tuple[Box, str]]:
    """(region, source) pairs in the order they are searched, made as the search asks for them.

    The largest blob's crop (the paper's); then the crops of up to `settings.plaque_candidates`
    of the `quads` (plaque-shaped regions at the threshold and lower gray levels, in
    `plaque_order`: best correlation with a sign first, but one correlating strongly as soon as
    its level is cut) that correlate at least MIN_NCC; then the other candidate blobs' crops,
    largest first; then the full frame. A crop about the same as one searched already is
    skipped. When the largest blob is not the sign, a lamp or a white door usually is, and it may
    also have pushed the sign below the threshold: on the synthetic scenes the sign was then the
    best-correlating quad in 40 of 60 scenes (13 of the 14 whose sign was a smaller blob), and
    one crop costs a fraction of the full frame. `quads(shrink)`, the quads level by level
    (`cut_levels`), is called, with the lower levels at half resolution, only once the largest
    blob has failed or been put after the plaques, and a level is cut only when the search gets
    to it.

    With plaque candidates, the largest blob waits until after them when `first_is_no_sign`
    (`BlobReading.no_sign`: a lamp, a white door, a plaque of other words), since searching it
    first only costs the time of a crop.
    """
    full = (0, 0, width, height)
    searched: list[Box] = []

    def fresh(crop: Box) -> bool:
        if any(box_iou(crop, other) > SAME_PLAQUE_IOU for other in searched):
            return False
        searched.append(crop)
        return True

    crops = segmentation.crops if segmentation is not None else []
    with_plaques = segmentation is not None and settings.plaque_candidates > 0
    no_sign = with_plaques and bool(crops) and first_is_no_sign
    if crops and not no_sign and fresh(crops[0]):
        yield crops[0], "blob 1"
    if with_plaques:
        plaques = 0
        for quad in plaque_order(quads(2)):
            if quad.best_ncc < MIN_NCC or plaques == settings.plaque_candidates:
                break
            if fresh(crop := expand_box(quad.blob.bbox, settings.crop_margin, width, height)):
                plaques += 1
                yield crop, f"plaque {plaques}"
    if no_sign and fresh(crops[0]):
        yield crops[0], "blob 1"
    for i, crop in enumerate(crops[1:], 2):
        if fresh(crop):
            yield crop, f"blob {i}"
    if segmentation is None or (settings.full_frame_fallback and full not in searched):
        yield full, "full frame"


def zoom_region(attempt: Attempt, width: int, height: int) -> Box | None:
    """The square ZOOM_WINDOW of the `width` x `height` px image wide where `attempt`'s matches to any
    sign crowd most, when it holds at least ZOOM_MIN_MATCHES; else None.

    The matches are counted in cells an eighth of the window wide; of the 8 x 8 cells holding the
    most (the first of equals), the window is centred on the median of the matches in them."""
    points = np.vstack([score.dst for score in attempt.scores] or [np.zeros((0, 2))])
    if len(points) < ZOOM_MIN_MATCHES:
        return None
    side = max(8, round(ZOOM_WINDOW * width))
    cell = side / 8
    cols, rows = int(np.ceil(width / cell)), int(np.ceil(height / cell))
    ix = np.clip((points[:, 0] / cell).astype(int), 0, cols - 1)
    iy = np.clip((points[:, 1] / cell).astype(int), 0, rows - 1)
    summed = np.zeros((max(rows, 8) + 1, max(cols, 8) + 1), np.int64)  # summed-area table, a zero row and column first
    np.add.at(summed, (iy + 1, ix + 1), 1)
    summed = summed.cumsum(axis=0).cumsum(axis=1)
    windows = summed[8:, 8:] - summed[:-8, 8:] - summed[8:, :-8] + summed[:-8, :-8]  # by top-left cell
    top, left = np.unravel_index(int(np.argmax(windows)), windows.shape)
    if windows[top, left] < ZOOM_MIN_MATCHES:
        return None
    # centred on the median of the matches in it: the first window holding the most has them at its edge
    inside = (ix >= left) & (ix < left + 8) & (iy >= top) & (iy < top + 8)
    x0, y0 = np.median(points[inside], axis=0) - side / 2
    return (max(0, int(x0)), max(0, int(y0)), min(width, int(np.ceil(x0 + side))), min(height, int(np.ceil(y0 + side))))


class PipelineError(ValueError):
    """The pipeline failed on an image for a reason of its own (a defect, or numerical trouble under
    extreme settings or intrinsics), not because the image or camera was unusable."""


def run_pipeline(name: str, image: np.ndarray, library: Library, settings: Settings, camera: Camera | None = None,
                 cache: StageCache | None = None) -> Recognition:
    """`recognize`, with any failure inside it turned into a PipelineError naming the image, so a
    batch can report it as that image's error and go on with the others. A CameraError (the
    camera cannot be scaled to this image) is the camera's, not the pipeline's, and passes as it is."""
    with pipeline_errors(name):
        return recognize(image, library, settings, camera, cache)


@contextmanager
def pipeline_errors(name: str) -> Iterator[None]:
    """Inside, any failure but a CameraError is raised as a PipelineError naming the image `name` (`run_pipeline`)."""
    try:
        yield
    except CameraError:
        raise
    except Exception as exc:
        raise PipelineError(f"pipeline failed on {name} ({type(exc).__name__}: {exc}); the other images are "
                            "unaffected: try other settings, and report it with this image and the settings") from exc


def recognize(image: np.ndarray, library: Library, settings: Settings, camera: Camera | None = None,
              cache: StageCache | None = None, *, with_pose: bool = True,
              plaque_search_shrink: int = 1) -> Recognition:
    """Recognise a library sign in an (H, W, 3) BGR or (H, W) gray uint8 image and estimate the camera pose.

    Without `camera`, a 60° horizontal field of view is assumed. When there is a pose, a warning
    says why it is approximate: the assumed field of view, a `camera` the caller assumed
    (`Camera.is_assumed`, e.g. the server's field of view) or EXIF intrinsics.
    `cache`: a `StageCache` kept by the caller for this image; re-running with changed settings then
    re-uses every stage the change does not affect (a RANSAC change re-uses features and
    matches, a ratio change re-uses features). The cache must be dropped with the image and
    whenever the library changes.
    `with_pose` False leaves the pose None, and the warnings that come with a pose (the partial view,
    the strips read, the refinement's notes) unsaid, for a caller that fits its own pose to the
    answer's H (a tracker re-anchoring a sign it follows, from the pose it had). `plaque_search_shrink`: the plaque
    search cuts its lower gray levels in the image shrunk this many times (`cut_image`; 2 as the plaque
    candidates are cut, losing more plaques under about 70 px across at 640 x 480).
    """
    t_start = time.perf_counter()
    gray = to_gray(image)
    height, width = gray.shape
    camera, warnings, approximate = image_camera(camera, width, height)
    run = Run(gray, library, settings, camera, StageRunner(settings, cache), plaque_search_shrink)
    # Pictures are no bright plaques: their crops, shrunk to max_crop_size, only cost accuracy.
    if settings.segment_mode == "threshold" and not library.pictures_only:
        run.segmentation = run.stages.run("segment", lambda: segment(gray, settings))
        if not run.segmentation.blobs:
            warnings.append("no white blob above the threshold")
    attempts, refined = run.search_regions()
    chosen = next((a for a in attempts if a.winner is not None), None)
    if chosen is None and attempts:
        chosen = max(attempts, key=lambda a: a.best_inliers)
    plaque = None
    if no_feature_winner(chosen) and settings.plaque_fallback and run.segmentation is not None:
        plaque, refined = run.plaque_fallback(chosen, warnings)
    if refined is None and settings.affine_fallback:
        steep = run.affine_fallback(attempts, chosen, warnings)
        if steep is not None:
            chosen, refined = steep
            attempts.append(chosen)
    pose = (run.winner_pose(refined, not no_feature_winner(chosen), warnings)
            if refined is not None and with_pose else None)
    if pose is not None and approximate is not None:
        # Last, after what the run found: where the server's clients have always read it.
        warnings.append(approximate)
    timing = run.stages.timing
    timing["total"] = (time.perf_counter() - t_start) * 1e3
    H, ecc, corners_px, outline, text = ((refined.H, refined.ecc, refined.sign.corners_px, refined.outline,
                                          refined.text) if refined is not None else (None,) * 5)
    return Recognition((width, height), settings, camera, run.segmentation, attempts, chosen, plaque, H, ecc, pose,
                       timing, run.stages.reused_stages(), warnings, corners_px, outline, text, run.turned_down)


def image_camera(camera: Camera | None, width: int, height: int) -> tuple[Camera, list[str], str | None]:
    """(the camera for a width x height px image, warnings of scaling it to the image, why a pose
    from it is approximate or None): `camera` scaled, or without one a 60° field of view."""
    if camera is None:
        camera = assumed_camera(width, height)
        return camera, [], f"no camera file: {camera.source}, so the pose is approximate"
    assumed_by_caller = camera.is_assumed  # e.g. the server's field of view
    camera, warnings = camera.for_image(width, height)
    approximate = None
    if assumed_by_caller:
        approximate = f"no camera set and no usable EXIF focal length: {camera.source}, so the pose is approximate"
    elif camera.is_exif:
        approximate = (f"no camera file: intrinsics from the {camera.source}, without distortion; "
                       "the pose is approximate")
    return camera, list(warnings), approximate


@dataclass(eq=False)
class Run:
    """The steps of one `recognize` call, over what they all read: the (H, W) uint8 `gray` image,
    the library, settings, the camera scaled to the image and the runner that times and caches
    the stages, how many times the plaque search shrinks the image it cuts at lower gray levels;
    `segmentation` (None: `segment_mode` none), the largest blob's reading (`first`), the winners
    the text check turned down as they are found and the quads cut so far by (shrink, level) (`quads`)."""

    gray: np.ndarray = field(repr=False)
    library: Library
    settings: Settings
    camera: Camera
    stages: StageRunner
    plaque_search_shrink: int = 1
    segmentation: Segmentation | None = field(default=None, repr=False)
    first: BlobReading | None = None
    turned_down: list[TurnedDown] = field(default_factory=list)
    cut_quads: dict[tuple[int, float], list[QuadCandidate]] = field(default_factory=dict, repr=False)

    def search_regions(self) -> tuple[list[Attempt], Refined | None]:
        """The candidate regions searched in order until a winner passes the text check: (the
        attempts, that winner refined or None). A winner whose text is not its sign's is turned
        down and the search goes on: the sign may be elsewhere in the image."""
        segmentation, settings = self.segmentation, self.settings
        if settings.plaque_candidates and segmentation is not None and segmentation.blobs:
            # The largest blob read for its look decides where it is searched (`candidate_regions`).
            self.first = self.stages.run("first blob", lambda: read_blob(self.gray, segmentation.labels,
                                                                         segmentation.blobs[0], self.library))
        height, width = self.gray.shape
        attempts: list[Attempt] = []
        for region, source in candidate_regions(segmentation, settings, width, height, self.quads,
                                                self.first is not None and self.first.no_sign):
            attempt = self.search_region(region, source)
            attempts.append(attempt)
            refined = self.accepted(attempt)
            if refined is not None:
                return attempts, refined
        # Only where the full frame named no sign at all: one the text check turned down would be read again.
        full = attempts[-1] if attempts and attempts[-1].source == "full frame" else None
        if full is None or not settings.zoom_fallback or any(t.source == full.source for t in self.turned_down):
            return attempts, None
        zoom = zoom_region(full, width, height)
        if zoom is None:
            return attempts, None
        attempt = self.search_region(zoom, "zoom on the full frame's matches", ZOOM_SCALE)
        attempts.append(attempt)
        return attempts, self.accepted(attempt)

    def accepted(self, attempt: Attempt) -> Refined | None:
        """The winner of `attempt` refined, or None without one or when the text check turned it down
        (its score then says why and `attempt` has no winner)."""
        if attempt.winner is None:
            return None
        refined, why = self.verified_winner(attempt, attempt.source)
        if why is None:
            return refined
        attempt.scores[attempt.winner].reason, attempt.winner = why, None
        return None

    def search_region(self, region: Box, source: str, scale: float | None = None) -> Attempt:
        """Detect features in `region`, resized by `scale` (default: `region_scale`'s), and score every
        library sign against them."""
        gray, library, settings = self.gray, self.library, self.settings
        # A picture's view gets a feature budget grown with the region's area: the features, and the
        # matches made of them, are keyed by the settings they were detected with.
        searched_with = self.region_settings(region)
        with self.stages.timed("features"):
            query = self.stages.run("features", lambda: detect(gray, searched_with, region, scale=scale),
                                    (region, scale), settings=searched_with)
            lib = library_features(library, settings)
        trains = [lib[sign.id].descriptors for sign in library.signs]
        matches = self.stages.run("match", lambda: match_library(query.descriptors, trains, settings.ratio, query.norm),
                                  (region, scale), settings=searched_with)
        scores = score_signs(library, query, lib, matches, settings, (gray.shape[1], gray.shape[0]),
                             self.stages.timing)
        winner, margin = decide(scores, settings)
        return Attempt(region, source, query, scores, winner, margin)

    def region_settings(self, region: Box) -> Settings:
        """The settings `region` is searched with: `search_settings`', the full frame at its full size
        where it is the search itself (no segmentation) or where a picture, which is found in it
        rather than in the crops, may be in view."""
        searched_with = search_settings(self.settings, self.library, region)
        if searched_with.full_frame_scale != 1.0 and (
                self.segmentation is None or any(sign.kind == "picture" for sign in self.library.signs)):
            return searched_with.replace(full_frame_scale=1.0)
        return searched_with

    def affine_fallback(self, attempts: list[Attempt], chosen: Attempt | None,
                        warnings: list[str]) -> tuple[Attempt, Refined] | None:
        """The affine fallback, where neither features nor the plaque fallback named a sign: each
        region of `attempts` in turn, its features matched with the library's simulated steep views
        (`library_affine_features`) and scored as `search_region` scores them, until a winner passes
        the text check. Returns (that region's attempt, its winner refined), or None; adds a warning
        that says so to `warnings`. No feature is detected in the image again."""
        library, settings = self.library, self.settings
        with self.stages.timed("features"):
            lib = library_affine_features(library, settings)
        trains = [lib[sign.id].descriptors for sign in library.signs]
        image_size = (self.gray.shape[1], self.gray.shape[0])
        for searched in attempts:
            query, region = searched.features, searched.region
            matches = self.stages.run("affine match",
                                      lambda: match_library(query.descriptors, trains, settings.ratio, query.norm),
                                      (region,), settings=self.region_settings(region))
            scores = score_signs(library, query, lib, matches, settings, image_size, self.stages.timing)
            winner, margin = decide(scores, settings)
            if winner is None:
                continue
            source = f"{searched.source}, simulated steep views"
            attempt = Attempt(region, source, query, scores, winner, margin)
            refined, why = self.verified_winner(attempt, source)
            if why is None:
                warnings.append(f"recognised by the affine fallback, matching simulated steep views of the signs "
                                f"({scores[winner].n_inliers} inliers in {searched.source}): features did not "
                                f"decide ({why_no_feature_winner(chosen)})")
                return attempt, refined
        return None

    def quads(self, shrink: int) -> Iterator[list[QuadCandidate]]:
        """The segmentation's plaque-shaped regions level by level (`cut_levels`), the levels other
        than its threshold cut from the image shrunk `shrink` times. A level is cut once a run: the
        plaque fallback cutting at the plaque candidates' resolution reads their levels again."""
        segmentation = self.segmentation
        assert segmentation is not None, "quads are cut from a segmentation"
        read = (self.first.quad,) if self.first is not None and self.first.quad is not None else ()
        # made once, when the first level not in the cache needs it
        image = functools.cache(lambda: cut_image(segmentation.source, segmentation.normalization, shrink))

        def cut(level: float, taken: Sequence[QuadCandidate]) -> list[QuadCandidate]:
            # `taken` is what the brighter levels at this shrink gave: the same on each pass
            if (shrink, level) not in self.cut_quads:
                self.cut_quads[shrink, level] = self.stages.run(
                    "quads", lambda: level_quads(self.gray, segmentation, self.library, self.settings, image, level,
                                                 taken, read), (shrink, level))
            return self.cut_quads[shrink, level]

        return cut_levels(cut, quad_levels(self.settings))

    def verified_winner(self, attempt: Attempt, source: str) -> tuple[Refined, str | None]:
        """The features' winner of `attempt`, found in `source`, refined and its text checked: (it, why
        the text check turned it down or None). A winner of few inliers the check turns down is read
        again through other homographies, and answered from the first its text passes through: refined
        from the affine fit to its inliers (`affine_start`), then its own H unrefined, where the
        refinement moved it wrong (on the photo world, a sharp shadow's edge across a plaque taken for
        one of its sides: a strip read 0.51 through the outline, every strip 0.83 or more through the
        15 inliers' H)."""
        refined = self.refined_winner(attempt, None)
        why = refined.text_problem(text_threshold(refined.sign, self.settings))
        n_inliers = attempt.scores[attempt.winner].n_inliers
        if why is None or n_inliers >= AUTO_ECC_MAX_INLIERS:
            return refined, self.turn_down(refined, source)
        width, height = self.gray.shape[1], self.gray.shape[0]
        if (start := affine_start(attempt, refined.sign, width, height)) is not None:
            again = self.refined_winner(attempt, None, start)
            if again.text_problem(text_threshold(again.sign, self.settings)) is None:
                return dataclasses.replace(again, notes=[*again.notes, (
                    f"refined from the affine fit to its {n_inliers} inliers: refined from their homography, "
                    "its text check failed")]), None
        H, src, dst, sign = winner_homography(attempt, None, self.library)
        if not np.allclose(H, refined.H):
            text = dataclasses.replace(check_text(self.gray, self.library, sign.id, H, self.camera),
                                       overwhelming=overwhelming(sign, src))
            if text.problem(sign, text_threshold(sign, self.settings)) is None:
                return Refined(H, src, dst, None, None, sign, text, [
                    f"placed by its {n_inliers} inliers' homography, unrefined: refined, its text check failed"]), None
        return refined, self.turn_down(refined, source)

    def refined_winner(self, attempt: Attempt | None, plaque: PlaqueMatch | None,
                       start: np.ndarray | None = None) -> Refined:
        """The winner of `attempt` (else of `plaque`) refined, from `start` (3, 3) library px -> image
        px where given, else from its own H, with its text checked."""
        gray, settings, camera = self.gray, self.settings, self.camera
        with self.stages.timed("pose"):
            H, src, dst, sign = winner_homography(attempt, plaque, self.library)
            H = H if start is None else start
            inliers = src if plaque is None else src[:0]  # the plaque fallback's are a grid, not matches
            # A RANSAC or decision change usually leaves the winner's H as it was: refined once.
            inputs = (sign.id, H.tobytes(), src.tobytes(), dst.tobytes(),
                      wants_dense_refinement(settings.refine, attempt),
                      (camera.K.tobytes(), camera.dist.tobytes()) if camera.has_distortion else None)
            warned: list[str] = []  # what refining warns of when it runs, cached with its result
            (refined_H, refined_src, refined_dst, ecc, outline), notes = self.stages.run("refine", lambda: (
                refine_winner(gray, sign, H, src, dst, settings, attempt, camera, warned), warned), inputs)
            text = (dataclasses.replace(check_text(gray, self.library, sign.id, refined_H, camera),
                                        overwhelming=overwhelming(sign, inliers))
                    if text_threshold(sign, settings) > 0 else None)
        return Refined(refined_H, refined_src, refined_dst, ecc, outline, sign, text, notes)

    def turn_down(self, refined: Refined, source: str) -> str | None:
        """Why `refined`, found in `source`, is turned down for its text (kept in `turned_down`), or None."""
        why = refined.text_problem(text_threshold(refined.sign, self.settings))
        if why is not None and refined.text is not None:
            self.turned_down.append(TurnedDown(refined.sign.id, source, refined.H, refined.text))
        return why

    def plaque_fallback(self, chosen: Attempt | None,
                        warnings: list[str]) -> tuple[PlaqueMatch | None, Refined | None]:
        """The plaque fallback, where features named no sign in `chosen`: (its plaque or None, the
        plaque's sign refined, None without one or when the text check turned it down). Adds its
        warnings to `warnings`."""
        segmentation = self.segmentation
        assert segmentation is not None, "the plaque fallback reads the segmentation's blobs"
        plaque, notes = self.stages.run("plaque", lambda: find_plaque(self.gray, segmentation, self.library,
                                                                      self.settings, self.quads,
                                                                      self.plaque_search_shrink),
                                        (self.plaque_search_shrink,))
        warnings += notes
        if plaque is None or plaque.sign is None:
            read = self.plaque_by_text() if self.settings.plaque_search else None
            if read is None:
                return plaque, None
            warnings.append(f"recognised by its plaque's outline and text (correlation {read[0].correlation:.2f}), "
                            f"which dense alignment did not confirm: features did not decide "
                            f"({why_no_feature_winner(chosen)})")
            return read
        refined = self.refined_winner(None, plaque)
        why = self.turn_down(refined, "plaque fallback")
        if why is not None:
            return dataclasses.replace(plaque, sign=None, H=None, reason=why), None
        warnings.append(f"recognised by the plaque fallback (correlation {plaque.correlation:.2f}): "
                        f"features did not decide ({why_no_feature_winner(chosen)})")
        return plaque, refined

    def plaque_by_text(self) -> tuple[PlaqueMatch, Refined] | None:
        """(plaque, its sign refined) of the first of the plaque search's best-correlating quads whose
        outline is found and whose text passes the check, for the sign it correlates best with; None
        without one. Dense alignment judges a quad by its correlation with the sign's whole image, which
        light falling unevenly across the plaque (a shadow's edge, glare, a steep gradient) takes below
        its threshold, or from which it diverges; the outline is read off the plaque's edges and the text
        check evens its light out."""
        for quad in ranked(self.quads(self.plaque_search_shrink))[:MAX_ALIGNED]:
            if quad.best_ncc < MIN_NCC:
                break
            sign = self.library[max(quad.ncc, key=quad.ncc.__getitem__)]
            if text_threshold(sign, self.settings) <= 0:
                continue
            H = sign_to_quad(sign, np.roll(quad.corners, -quad.rolls[sign.id], axis=0))
            plaque = PlaqueMatch(quad.blob, quad.corners, quad.ncc, sign.id, H, None)
            refined = self.refined_winner(None, plaque)
            if refined.outline is not None and self.turn_down(refined, "plaque read by its text") is None:
                return plaque, refined
        return None

    def winner_pose(self, refined: Refined, by_features: bool, warnings: list[str]) -> Pose | None:
        """The camera pose from the `refined` winner (`by_features`: a feature match's, else the
        plaque fallback's), None when it cannot be estimated; adds the warnings to `warnings`."""
        H, src, dst, ecc, outline, sign, text = (refined.H, refined.src, refined.dst, refined.ecc, refined.outline,
                                                 refined.sign, refined.text)
        pose = None
        with self.stages.timed("pose"):
            warnings += refined.notes
            height, width = self.gray.shape
            if sign.kind == "picture" and (in_view := visible_fraction(H, sign, width, height)) < MOSTLY_IN_VIEW:
                warnings.append(f"only {in_view:.0%} of {sign.id} is in the image: recognised from that part")
            if text is not None and text.kind == "plaque" and text.seen < len(text.strips):
                # The check cannot tell the sign from a plaque sharing the words seen: a cut look-alike
                # whose other words are out of the image reads as the sign.
                washed = f" ({len(text.washed)} washed out by glare)" if text.washed else ""
                warnings.append(f"only {text.seen} of the {len(text.strips)} strips of {sign.id}'s text could be "
                                f"read{washed}: a plaque sharing the words read would read the same; check the rest "
                                "of it")
            measured_by = ("outline" if outline is not None else
                           "features" if ecc is None and by_features else "dense")
            corner_sigma = CORNER_SIGMA_PX[measured_by]
            try:
                pose = estimate_pose(H, src, dst, sign, self.camera, self.settings.pose_method,
                                     self.settings.ambiguity_ratio, corner_sigma, with_covariance=outline is None)
                if outline is not None:
                    pose = outline_pose(pose, outline, sign, self.camera)
            except PoseError as exc:
                warnings.append(f"no pose: {exc}")
        if pose is not None and pose.ambiguous:
            warnings.append("pose is ambiguous: a second pose, the planar solution flipped, fits the measurements "
                            "nearly as well (a small, far or near-frontal sign)")
        return pose


def find_plaque(gray: np.ndarray, segmentation: Segmentation, library: Library, settings: Settings,
                quads: Callable[[int], Iterator[list[QuadCandidate]]],
                shrink: int = 1) -> tuple[PlaqueMatch | None, list[str]]:
    """The plaque fallback: the candidate blobs read as plaques, then (`settings.plaque_search`)
    the search among the `quads` at lower gray levels, cut in the image shrunk `shrink` times.
    Returns (the plaque or None, warnings to report)."""
    plaque = read_plaques(gray, segmentation, library, settings)
    if (plaque is None or plaque.sign is None) and settings.plaque_search:
        found = search_plaques(gray, ranked(quads(shrink)), library, settings)
        if found is not None:
            return found[0], [f"plaque found by the search at lower gray levels (aligned correlation {found[1]:.2f})"]
    return plaque, []


def uses_outline(sign: LibrarySign, settings: Settings) -> bool:
    """Whether `sign` is placed by its outline (`refine_outline`) under `settings`: a plaque's four
    straight edges. A picture's are not its own (on box.mp4 a box's printed face was drawn 9 px off
    it, on the lid's edges), nor are a landmark's searched without segmentation."""
    return settings.refine_outline and settings.segment_mode != "none" and sign.kind == "plaque"


def refine_winner(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, src: np.ndarray, dst: np.ndarray,
                  settings: Settings, attempt: Attempt | None, camera: Camera, warnings: list[str]):
    """(H, src, dst, ecc, outline): the winner's homography and the correspondences for its pose,
    after refinement, with the ECC correlation or the plaque outline that refined it (else None).

    The plaque's four edges (`refine_outline`) come first: where they are found, their H beats
    both the feature inliers, which sit on the text away from the corners, and ECC (measured on
    synthetic scenes: corner error median 0.98 -> 0.25 px, rotation median 1.27 -> 0.09
    degrees). Otherwise ECC refines as `settings.refine` says, and the edges are looked for
    again from its H, which may be closer than the first. Where the edges were missed, ECC
    runs for that second look even where `settings.refine` ("auto" with many inliers) does not
    want its H, which is then kept only if the edges are found from it. The outline's edges are
    fitted as `camera`'s ideal pinhole image shows them, straight under lens distortion too.
    """
    why = None
    use_outline = uses_outline(sign, settings)
    if use_outline:
        outline, why = outline_agreeing(gray, sign, H, src, dst, settings, attempt, camera)
        if outline is not None:
            return outline.H, *outline.grid(sign, camera), None, outline
    ecc = None
    # A picture's texture aligns densely where a plaque's few strokes do not: on the homogr pairs
    # ECC took graf's corners from 6.6 to 4.0 px off, Brussels' points from 2.6 to 1.3 px.
    wanted = wants_dense_refinement(settings.refine, attempt) or (sign.kind == "picture" and settings.refine != "none")
    # Many inliers do not keep the features' corners within the edge search (8 px): a photo with
    # 31 inliers had one 20 px off, its pose 14.6 mm off, against 2.4 mm outlined when turned.
    if wanted or (use_outline and settings.refine != "none"):
        refined = refine_ecc(gray, sign, H, camera)
        problem = "did not converge"
        if refined is not None and refined[1] >= MIN_ECC:
            ideal_H = refined[0]
            # Under distortion no H is exact: keep the one through the corners, as the outline does.
            dense_H = seen_homography(sign, ideal_H, camera) if camera.has_distortion else ideal_H
            # ECC can settle on a warp no view of a sign gives: a look-alike cut by the frame was
            # drawn to a corner 1500 px beyond a 640 px frame, its pose 68 px RMSE off its points.
            _, implausible = quad_problem(dense_H, sign, gray.shape[1], gray.shape[0])
            problem = None if implausible is None else f"gave an implausible sign ({implausible})"
            if problem is None and sign.kind == "picture" and not dense_agrees(H, dense_H, src, dst):
                problem = "disagreed with the matched points"
        if problem is None:
            if use_outline:
                outline, why = outline_agreeing(gray, sign, dense_H, src, dst, settings, attempt, camera)
                if outline is not None:
                    return outline.H, *outline.grid(sign, camera), None, outline
            # Without the edges, many inliers still pose better than ECC's H: of the 500 synthetic
            # bench scenes, the 74 with 30 or more, outline off, rotation p90 5.6 against 9.0 degrees.
            if wanted:
                H, (src, dst), ecc = dense_H, seen_grid(ideal_H, sign, camera), refined[1]
        else:
            warnings.append(f"dense refinement {problem}; H and pose come from the matches alone")
    if why is not None:
        warnings.append(f"plaque outline not used: {why}")
    return H, src, dst, ecc, None


def outline_agreeing(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, src: np.ndarray, dst: np.ndarray,
                     settings: Settings, attempt: Attempt | None, camera: Camera) -> tuple[Outline | None, str | None]:
    """`refine_outline` from H, but for a features' winner (`attempt`) an outline whose H moves
    its matched points src -> dst ((N, 2) library and image px) much further than H leaves them
    (`dense_agrees` at OUTLINE_FLOOR_PX) is none: an edge of something beside the sign (a shadow's, a card's, a photo's)
    taken for one of the plaque's, which put a corner 4-7 px off and the text check's strips far
    below its bar on the photo world's frontal signs."""
    outline, why = refine_outline(gray, sign, H, settings.seed, camera, gamma=settings.edge_gamma)
    if (outline is not None and not no_feature_winner(attempt)
            and not dense_agrees(H, outline.H, src, dst, floor_px=OUTLINE_FLOOR_PX)):
        return None, "its edges disagreed with the matched points"
    return outline, why


def affine_start(attempt: Attempt, sign: LibrarySign, width: int, height: int) -> np.ndarray | None:
    """For `attempt`'s winner, `sign`, of fewer than AUTO_ECC_MAX_INLIERS inliers, the (3, 3) affine
    map (library px -> image px) fitted to them by least squares, where its corners make a
    plausible sign; else None.

    A few inliers crowd on a plaque's text, away from its corners, and leave a homography's
    perspective free: on the photo world's turned-down small and blurred signs (8-12 inliers) the
    winner's corners were 16-68 px off, the affine fit's to the same inliers 1-7 px, within reach of
    the outline's edge search. A sign small enough to give so few inliers is seen nearly affinely.
    `width` x `height`: the image's size in px, for `quad_problem`."""
    best = attempt.scores[attempt.winner]
    if best.estimate is None or not MIN_HOMOGRAPHY_POINTS <= best.n_inliers < AUTO_ECC_MAX_INLIERS:
        return None
    inliers = best.estimate.inliers
    src, dst = best.src[inliers], best.dst[inliers]
    fit, *_ = np.linalg.lstsq(np.column_stack([src, np.ones(len(src))]), dst, rcond=None)
    H = np.vstack([fit.T, [0.0, 0.0, 1.0]])
    return H if quad_problem(H, sign, width, height)[1] is None else None


def no_feature_winner(attempt: Attempt | None) -> bool:
    """Whether features named no sign in `attempt`, the region their answer came from (None: no
    region searched), so that any sign is the plaque fallback's."""
    return attempt is None or attempt.winner is None


def wants_dense_refinement(refine: str, attempt: Attempt | None) -> bool:
    """Whether to refine the winner's H by ECC under the `refine` setting.

    A plaque's outline is too crude for a pose, so the plaque fallback always refines. With
    many inliers IPPE on the points is the better pose; with few, dense alignment is (measured
    on synthetic scenes), hence "auto".
    """
    if refine == "ecc" or no_feature_winner(attempt):
        return True
    return refine == "auto" and attempt.scores[attempt.winner].n_inliers < AUTO_ECC_MAX_INLIERS


def read_plaques(gray: np.ndarray, segmentation: Segmentation, library: Library,
                 settings: Settings) -> PlaqueMatch | None:
    """The first candidate blob that reads as a library sign's plaque, confirmed by dense
    alignment (`confirm_plaque`), else the first that is a quad."""
    first = None
    for blob in segmentation.blobs:
        match = match_plaque(gray, segmentation.labels, blob, library, settings.min_plaque_ncc,
                             settings.plaque_margin)
        if match is not None and match.sign is not None:
            match = confirm_plaque(gray, match, library, settings.min_plaque_ecc)
            if match.sign is not None:
                return match
        first = first or match
    return first


def winner_homography(attempt: Attempt | None, plaque: PlaqueMatch | None, library: Library):
    """(H, src (N, 2) library px, dst (N, 2) image px, sign) of the winner, or None without one.

    For the plaque fallback, a grid over the sign mapped through the outline's H stands in for matches.
    """
    if not no_feature_winner(attempt):
        best = attempt.scores[attempt.winner]
        inl = best.estimate.inliers
        return best.H, best.src[inl], best.dst[inl], library[best.sign]
    if plaque is not None and plaque.sign is not None:
        sign = library[plaque.sign]
        return (plaque.H, *grid_correspondences(plaque.H, sign), sign)
    return None
