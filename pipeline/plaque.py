"""Plaque fallback and dense refinement: recognise a sign too small or blurred for local
features by its outline, and align any recognised sign densely to the image.

Below roughly 110 px of sign width the glyph strokes are a few pixels thick and SIFT finds
almost nothing to match, yet the white plaque is still a clean quadrilateral blob. Its four
corners give a homography; rectifying the blob and correlating it with each library sign
(normalised cross-correlation at a common low resolution) says which sign it is. Dense ECC
alignment against the winner then refines a homography, from the outline or from feature
inliers, well beyond either (measured: corner error about 4x lower on synthetic scenes).
This assumes the library image is the whole plaque (white to its edges), as in the samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import Camera
from .image import resize_map
from .library import Library, LibrarySign
from .pose import distort_pixels, ideal_patch, undistort_pixels
from .segment import Blob, expand_box

# Width in px at which a rectified plaque is compared with the library; small enough that a
# 60 px sign is not invented detail, large enough to tell three words apart.
COMPARE_WIDTH = 96
COMPARE_BLUR_SIGMA = 1.0
# A plaque's light is evened out over this many px (`without_smooth_light`) of the text check's
# 128 px template and of the 96 px patch a candidate plaque is correlated at: wider than a letter's
# stroke, narrower than a shadow's, a glare's or a lamp's gradient across the plaque. On the photo
# world (pipeline/synth_photo_world.py) 7 of 10 true signs the text check turned down (weakest strip
# 0.21-0.71 under glare, a shadow's edge or a steep gradient across them) pass (0.80-0.91); of
# plaques of other words that features read as a sign, tests.support's six reach 0.67 at most and
# the photo world's look-alikes 0.31, but for one whose other word glare washes out (answered
# without the light evened out too). Rectified on their truth corners, 17 of its 120 signs
# correlated under 0.45 (plaque_search.MIN_NCC) with their own, none evened out (p10 0.40 ->
# 0.78); the best of the other signs rose from 0.50 to 0.61 median (at most 0.76 -> 0.71).
PLAQUE_LIGHT_SIGMA = 8.0
# An outline whose convex hull strays this far from its 4-corner fit is no plaque.
MIN_QUAD_FILL = 0.9
ECC_INSET = 0.04  # fraction of the sign cut from each side before dense alignment
ECC_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 60, 1e-5)
ECC_CROP_MARGIN = 0.25  # image kept around the sign for ECC, as a fraction of its bounding box
# A sign wider than MAX_DIRECT_WIDTH_PX (a 12 MP photo) is aligned, and outlined
# (`pipeline.outline`), in the image shrunk to make it SHRUNK_WIDTH_PX wide: the size these
# steps are tuned at, and ECC's time and memory grow with the area (4000 x 3000 through a wide
# lens: 8 s and 4.7 GB an image aligned at full resolution).
MAX_DIRECT_WIDTH_PX = 480.0
SHRUNK_WIDTH_PX = 400.0
# Only the sign's neighbourhood is shrunk: its bounding box grown by this fraction, room for ECC's
# crop (ECC_CROP_MARGIN), the outline's search and a lens's bowing of the sides.
SHRUNK_VIEW_MARGIN = 0.3


@dataclass(frozen=True, eq=False)
class PlaqueMatch:
    """A blob read as a plaque: `corners` (4, 2) image px TL, TR, BR, BL of its outline, the
    correlation with each sign, and for a winner the homography (library px -> image px) that
    maps the sign's corners onto the outline."""

    blob: Blob
    corners: np.ndarray = field(repr=False)
    ncc: dict[str, float]
    sign: str | None
    H: np.ndarray | None = field(repr=False)
    reason: str | None

    @property
    def correlation(self) -> float | None:
        """The winning sign's correlation, None without a winner."""
        return self.ncc[self.sign] if self.sign is not None else None


def blob_boundary(labels: np.ndarray, blob: Blob) -> np.ndarray | None:
    """The outer boundary of a blob (its pixels labelled `blob.label` in `labels`): (K, 1, 2) int32
    px from its bbox's top-left, the ends of its straight runs (cv2.CHAIN_APPROX_SIMPLE); None if
    it has no pixel."""
    x0, y0, x1, y1 = blob.bbox
    mask = (labels[y0:y1, x0:x1] == blob.label).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return max(contours, key=cv2.contourArea) if contours else None


def blob_quad(labels: np.ndarray, blob: Blob, boundary: np.ndarray | None = None) -> np.ndarray | None:
    """The 4 corners (4, 2) of a blob's convex outline, ordered TL, TR, BR, BL, or None if not a
    quad; from its `blob_boundary`, found here unless given."""
    x0, y0 = blob.bbox[:2]
    boundary = blob_boundary(labels, blob) if boundary is None else boundary
    if boundary is None:
        return None
    hull = cv2.convexHull(boundary)
    perimeter = cv2.arcLength(hull, True)
    for eps in (0.02, 0.04, 0.06):
        quad = cv2.approxPolyDP(hull, eps * perimeter, True)
        if len(quad) == 4:
            break
    else:
        return None
    quad = quad.reshape(4, 2).astype(np.float64)
    if cv2.contourArea(quad.astype(np.float32)) < MIN_QUAD_FILL * cv2.contourArea(hull):
        return None
    # Pixel centres of the outermost blob pixels lie half a pixel inside the plaque's edge.
    centre = quad.mean(axis=0)
    quad += 0.5 * np.sign(quad - centre) + np.array([x0, y0])
    return order_corners(quad)


def order_corners(quad: np.ndarray) -> np.ndarray:
    """(4, 2) points -> TL, TR, BR, BL: clockwise on screen (y down), starting nearest the top-left."""
    centre = quad.mean(axis=0)
    angle = np.arctan2(quad[:, 1] - centre[1], quad[:, 0] - centre[0])
    quad = quad[np.argsort(angle)]  # clockwise on screen, since y points down
    start = int(np.argmin(quad.sum(axis=1)))
    return np.roll(quad, -start, axis=0)


def project(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) points through a 3x3 homography -> (N, 3) homogeneous results (not divided)."""
    return np.column_stack([pts, np.ones(len(pts))]) @ H.T


def sign_to_quad(sign: LibrarySign, corners: np.ndarray) -> np.ndarray:
    """The (3, 3) float64 homography (library px -> image px, H[2, 2] = 1) taking the sign's
    corners onto `corners` (4, 2) image px TL, TR, BR, BL (cv2.getPerspectiveTransform wants float32)."""
    H = cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32), corners.astype(np.float32))
    return H.astype(np.float64) / H[2, 2]


def quad_width(corners: np.ndarray) -> float:
    """The longest side (px) of the quad `corners` (4, 2) px."""
    return float(np.max(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))


def sign_corners(sign: LibrarySign, H: np.ndarray) -> np.ndarray:
    """(4, 2) float64 image px of the sign's corners TL, TR, BR, BL through H (library px -> image px)."""
    return cv2.perspectiveTransform(sign.corners_px[None], H)[0]


def ideal_homography(sign: LibrarySign, H: np.ndarray, camera: Camera) -> np.ndarray:
    """The plane-to-pinhole map of `H` (3, 3) library px -> image px through the sign's corners as
    `camera`'s lens shows them: library px -> px of an ideal pinhole camera with its K, through the
    corners undistorted. Through a distorting lens no homography maps the sign onto the image."""
    return sign_to_quad(sign, undistort_pixels(sign_corners(sign, H), camera))


def seen_homography(sign: LibrarySign, ideal_H: np.ndarray, camera: Camera) -> np.ndarray:
    """The inverse of `ideal_homography`: library px -> image px through the corners of `ideal_H`
    as `camera`'s lens shows them, exact at them alone (as `Outline.H`)."""
    return sign_to_quad(sign, distort_pixels(sign_corners(sign, ideal_H), camera))


def grid_correspondences(H: np.ndarray, sign: LibrarySign, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid over the sign (library px) and its image through H: (n*n, 2) each.

    After dense alignment every pixel of the sign supports H, so a grid stands in for the matches.
    """
    w, h = sign.size_px
    gu, gv = np.meshgrid(np.linspace(0, w, n), np.linspace(0, h, n))
    src = np.column_stack([gu.ravel(), gv.ravel()])
    hom = project(H, src)
    return src, hom[:, :2] / hom[:, 2:]


def seen_grid(ideal_H: np.ndarray, sign: LibrarySign, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(src (N, 2) library px, dst (N, 2) image px): the `grid_correspondences` of `ideal_H`
    (library px -> px of an ideal pinhole camera with `camera`'s K) where `camera` sees them,
    lens distortion included; what a pose is fitted to after refinement."""
    src, ideal = grid_correspondences(ideal_H, sign)
    return src, distort_pixels(ideal, camera)


def compare_size(sign: LibrarySign) -> tuple[int, int]:
    w, h = sign.size_px
    return COMPARE_WIDTH, max(8, round(COMPARE_WIDTH * h / w))


def rectify(gray: np.ndarray, corners: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The image inside `corners` warped to a `size` = (w, h) float32 patch, blurred.

    The corners are the patch's outer pixel edges, so its pixels' centres sample the plaque as
    cv2.resize samples the library templates, and the patch turned by quarter turns is the
    plaque rectified from its corners in the other cyclic orders (`turned_templates`)."""
    w, h = size
    target = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]], np.float32)
    M = cv2.getPerspectiveTransform(target, corners.astype(np.float32))
    patch = cv2.warpPerspective(gray, M, size, flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP)
    return cv2.GaussianBlur(patch.astype(np.float32), (0, 0), COMPARE_BLUR_SIGMA)


def without_smooth_light(image: np.ndarray) -> np.ndarray:
    """The (h, w) float32 `image` less its Gaussian-weighted local mean over PLAQUE_LIGHT_SIGMA
    px: a plaque's print under any light that changes smoothly across it."""
    return image - cv2.GaussianBlur(image, (0, 0), PLAQUE_LIGHT_SIGMA)


def library_templates(library: Library) -> dict[str, np.ndarray]:
    """Each sign at the comparison resolution, blurred like a rectified plaque, its light evened out
    (`without_smooth_light`) and `standardized`; cached on the library."""
    def template(sign: LibrarySign) -> np.ndarray:
        small = cv2.resize(sign.image, compare_size(sign), interpolation=cv2.INTER_AREA)
        return standardized(without_smooth_light(cv2.GaussianBlur(small.astype(np.float32), (0, 0),
                                                                   COMPARE_BLUR_SIGMA)))

    return library.per_sign("plaque_templates", template)


def standardized(patch: np.ndarray) -> np.ndarray:
    """`patch` less its mean, scaled to unit norm (all zeros if it is flat): the zero-mean
    normalised cross-correlation of two such patches of equal size is their dot product."""
    centred = patch - patch.mean()
    norm = float(np.sqrt(np.vdot(centred, centred)))
    return centred / norm if norm > 0 else centred


def shrunk_view(gray: np.ndarray, f: float, camera: Camera | None,
                around: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, Camera | None]:
    """(small, to_small, lens): the (H, W) uint8 image shrunk by `f` < 1 (INTER_AREA), the (3, 3)
    map image px -> its px (pixel centres aligned as cv2.resize aligns them), and the camera that
    takes it: `camera`'s lens, its K mapped the same way (None without a camera).

    With `around` (N, 2) image px, only their neighbourhood is shrunk (their bounding box grown by
    SHRUNK_VIEW_MARGIN): shrinking all of a 12 MP photo took 7 ms, each time a sign was aligned or
    outlined."""
    x0, y0, x1, y1 = (0, 0, gray.shape[1], gray.shape[0]) if around is None else \
        expand_box(bounding_box(around), SHRUNK_VIEW_MARGIN, gray.shape[1], gray.shape[0])
    view = gray[y0:y1, x0:x1]
    h, w = view.shape
    small = cv2.resize(view, (max(1, round(w * f)), max(1, round(h * f))), interpolation=cv2.INTER_AREA)
    fx, fy = small.shape[1] / w, small.shape[0] / h
    to_small = resize_map(fx, fy) @ np.array([[1.0, 0, -x0], [0, 1, -y0], [0, 0, 1]])
    # Without an image size: it takes this copy only, never scaled to another size; a calibration's
    # bounds (principal_point_problem) are not its to meet.
    lens = None if camera is None else Camera(to_small @ camera.K, camera.dist, source=camera.source)
    return small, to_small, lens


def refine_ecc(gray: np.ndarray, sign: LibrarySign, H: np.ndarray, camera: Camera | None = None,
               max_width: float = MAX_DIRECT_WIDTH_PX,
               shrunk_width: float = SHRUNK_WIDTH_PX) -> tuple[np.ndarray, float] | None:
    """`_refine_ecc`, for a sign wider than `max_width` px in the image shrunk to make it
    `shrunk_width` px wide (`shrunk_view`), its H mapped back to the image's px."""
    corners = sign_corners(sign, H)
    width = quad_width(corners)
    if width <= max_width:
        return _refine_ecc(gray, sign, H, camera)
    small, to_small, lens = shrunk_view(gray, shrunk_width / width, camera, around=corners)
    refined = _refine_ecc(small, sign, to_small @ H, lens)
    if refined is None:
        return None
    H = np.linalg.solve(to_small, refined[0])
    return H / H[2, 2], refined[1]


def _refine_ecc(gray: np.ndarray, sign: LibrarySign, H: np.ndarray,
                camera: Camera | None) -> tuple[np.ndarray, float] | None:
    """Align the library sign to the image densely (ECC), starting from H (library px -> image px).

    The sign is shrunk to about its size in the image first, so ECC compares like with like, and
    cut to its interior: ECC smooths the template with a replicated border, so the plaque's own
    edge would look softer there than against the wall in the image and bias the scale.
    Under `camera`'s lens distortion no homography maps the sign onto the image, so the sign's
    neighbourhood is aligned as an ideal pinhole camera with the same K sees it (`ideal_patch`).
    Returns (refined H library px -> px of that ideal camera, which are image px without
    distortion; correlation coefficient), or None if ECC diverged.
    """
    corners = sign_corners(sign, H)
    distorted = camera is not None and camera.has_distortion
    if distorted:
        corners = undistort_pixels(corners, camera)
        H = sign_to_quad(sign, corners)
    w, h = sign.size_px
    s = min(1.0, float(np.sqrt(abs(cv2.contourArea(corners.astype(np.float32))) / (w * h))))
    small = cv2.resize(sign.image, (max(16, round(w * s)), max(16, round(h * s))), interpolation=cv2.INTER_AREA)
    sx, sy = small.shape[1] / w, small.shape[0] / h
    ix, iy = round(small.shape[1] * ECC_INSET), round(small.shape[0] * ECC_INSET)
    template = small[iy:small.shape[0] - iy, ix:small.shape[1] - ix]
    # template px -> library px: the template's pixel j is the small image's j + ix, whose centre lies at
    # (j + ix + 0.5) / sx of the library, where pixel i spans [i, i + 1] (`LibrarySign.corners_px`)
    to_library = np.array([[1 / sx, 0, (ix + 0.5) / sx], [0, 1 / sy, (iy + 0.5) / sy], [0, 0, 1]])
    # ECC smooths and differentiates its whole input image before iterating: give it only the
    # neighbourhood of the sign, with room for the alignment to move.
    x0, y0, x1, y1 = box = expand_box(bounding_box(corners), ECC_CROP_MARGIN, gray.shape[1], gray.shape[0])
    if x1 <= x0 or y1 <= y0:  # a lens can put a sign at the frame's edge wholly outside the ideal frame
        return None
    neighbourhood = ideal_patch(gray, box, camera) if distorted else gray[y0:y1, x0:x1]
    to_crop = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], dtype=np.float64)
    warp = (to_crop @ H @ to_library).astype(np.float32)
    try:
        cc, warp = cv2.findTransformECC(template, neighbourhood, warp / warp[2, 2], cv2.MOTION_HOMOGRAPHY,
                                        ECC_CRITERIA, None, 3)
    except cv2.error:
        return None
    refined = np.linalg.inv(to_crop) @ warp.astype(np.float64) @ np.linalg.inv(to_library)
    return refined / refined[2, 2], float(cc)


def bounding_box(pts: np.ndarray) -> tuple[int, int, int, int]:
    """The integer `Box` enclosing (N, 2) image px."""
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int) + 1
    return int(x0), int(y0), int(x1), int(y1)


def turned_templates(library: Library) -> dict[str, np.ndarray]:
    """Each sign's `library_templates` template (h, w) turned back by each cyclic corner order:
    (4, h w) float32, row k the template turned k quarter turns clockwise and flattened; cached on
    the library.

    The plaque read from its corners in order k (np.roll(corners, -k, axis=0)) is the upright
    patch (k even) or the sideways one (k odd) turned k quarter turns counter-clockwise, so its
    correlation with the template is row k dotted with that patch flattened: two warps and no
    turned copies of them (with the copies, 0.135 ms a quad against 0.099)."""
    templates = library_templates(library)
    return library.per_sign("plaque_templates_turned",
                            lambda sign: np.stack([np.rot90(templates[sign.id], -k).ravel() for k in range(4)]))


def plaque_correlations(gray: np.ndarray, corners: np.ndarray,
                        library: Library) -> tuple[dict[str, float], dict[str, int]]:
    """Each sign's best correlation with the plaque inside `corners` (4, 2) image px, both with their
    light evened out, over its four cyclic corner orders (a plaque seen upright, sideways or upside
    down), and that order."""
    turned = turned_templates(library)
    scores, rolls = {}, {}
    patches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # signs of one aspect share them

    def read(size: tuple[int, int]) -> np.ndarray:
        return standardized(without_smooth_light(rectify(gray, corners, size))).ravel()

    for sign in library.signs:
        size = compare_size(sign)
        if size not in patches:
            w, h = size
            upright = read((w, h))
            patches[size] = upright, upright if w == h else read((h, w))
        upright, sideways = patches[size]
        by_roll = np.empty(4)
        by_roll[0::2], by_roll[1::2] = turned[sign.id][0::2] @ upright, turned[sign.id][1::2] @ sideways
        rolls[sign.id] = int(np.argmax(by_roll))
        scores[sign.id] = float(by_roll[rolls[sign.id]])
    return scores, rolls


def match_plaque(gray: np.ndarray, labels: np.ndarray, blob: Blob, library: Library,
                 min_ncc: float, min_margin: float) -> PlaqueMatch | None:
    """Read `blob` as a plaque and decide which library sign it shows; None if it is no quad."""
    corners = blob_quad(labels, blob)
    if corners is None:
        return None
    scores, best_roll = plaque_correlations(gray, corners, library)
    ranked = sorted(scores, key=lambda sign: scores[sign], reverse=True)

    best = ranked[0]
    second = scores[ranked[1]] if len(ranked) > 1 else 0.0
    if scores[best] < min_ncc:
        return PlaqueMatch(blob, corners, scores, None, None,
                           f"plaque correlation too low ({scores[best]:.2f} < {min_ncc})")
    if scores[best] - second < min_margin:
        return PlaqueMatch(blob, corners, scores, None, None,
                           f"plaque correlation margin too small ({scores[best] - second:.2f} < {min_margin})")
    corners = np.roll(corners, -best_roll[best], axis=0)
    return PlaqueMatch(blob, corners, scores, best, sign_to_quad(library[best], corners), None)
