"""Outline refinement: a plaque's four edges give its homography to a fraction of a pixel;
and both refinements under lens distortion."""

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from signpose.pipeline.camera import Camera, assumed_camera
from signpose.pipeline.evaluate import load_dataset
from signpose.pipeline.image import read_image
from signpose.pipeline.outline import outline_corner_sigma, outline_fit, outline_pose, refine_outline
from signpose.pipeline.plaque import SHRUNK_WIDTH_PX, refine_ecc, sign_corners
from signpose.pipeline.pose import (CORNER_SIGMA_PX, corner_covariance, estimate_pose, homography_from_pose,
                                   rotation_error_deg, undistort_pixels)
from signpose.pipeline.recognize import StageCache, recognize
from signpose.pipeline.settings import preset
from signpose.pipeline.synth import render_scene, synthetic_camera
from tests.support.scene_images import like_a_camera, render_plaque, through_lens

TRUE_CORNERS = np.array([[212.3, 141.7], [431.9, 158.2], [425.6, 251.4], [205.8, 236.9]])
LINEAR = 1.0  # the encoding gamma of like_a_camera's images, whose gray levels are linear light


@pytest.fixture(scope="module")
def sign(library):
    return library.signs[0]


def plaque_image(sign, wall: float, plaque_gain: float = 1.0, seed: int = 0, corners=TRUE_CORNERS) -> np.ndarray:
    """A 640 x 480 image of `sign` at `corners` on a flat wall of gray level `wall`: rendered
    four times larger and shrunk (anti-aliased edges), blurred and noised like a camera."""
    return like_a_camera(render_plaque(sign, corners, wall, plaque_gain), 0.8, seed)


def start_homography(sign, shift_px: float, seed: int = 1, corners=TRUE_CORNERS) -> np.ndarray:
    """H whose corners are `corners` each moved `shift_px` in a random direction."""
    angle = np.random.default_rng(seed).uniform(0, 2 * np.pi, 4)
    corners = corners + shift_px * np.column_stack([np.cos(angle), np.sin(angle)])
    return cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32), corners.astype(np.float32)).astype(float)


def corner_error(sign, H) -> float:
    corners = cv2.perspectiveTransform(sign.corners_px[None], H)[0]
    return float(np.linalg.norm(corners - TRUE_CORNERS, axis=1).max())


@pytest.mark.parametrize("wall", [90.0, 200.0])  # a plaque brighter, then darker than the wall (text sign x 0.6)
def test_edges_recover_the_corners(sign, wall):
    gain = 1.0 if wall < 128 else 0.6
    image = plaque_image(sign, wall, gain)
    H0 = start_homography(sign, 4.0)
    assert corner_error(sign, H0) > 3.9
    outline, why = refine_outline(image, sign, H0, gamma=LINEAR)
    assert why is None and outline is not None
    assert corner_error(sign, outline.H) < 0.15
    assert np.allclose(outline.corners, cv2.perspectiveTransform(sign.corners_px[None], outline.H)[0], atol=1e-6)
    assert len(outline.points) == 4 and all(len(p) >= 8 for p in outline.points)


def test_edges_are_read_in_linear_light(sign):
    """A camera blurs light and then encodes it: read as encoded, a blurred edge's ramp leans towards its dark
    side and a bright plaque's corners moved outwards; read through the encoding gamma, they are where they are."""
    blurred = cv2.GaussianBlur(render_plaque(sign, TRUE_CORNERS, 40.0) / 255, (0, 0), 1.5)
    image = (255 * blurred ** (1 / 2.2) + np.random.default_rng(3).normal(0, 1.5, blurred.shape)).clip(0, 255)
    image = image.astype(np.uint8)
    centre = TRUE_CORNERS.mean(axis=0)
    outwards = (TRUE_CORNERS - centre) / np.linalg.norm(TRUE_CORNERS - centre, axis=1, keepdims=True)

    def radial_px(gamma: float) -> float:
        outline, why = refine_outline(image, sign, start_homography(sign, 2.0), gamma=gamma)
        assert outline is not None, why
        return float(np.mean(np.sum((outline.corners - TRUE_CORNERS) * outwards, axis=1)))

    assert radial_px(1.0) > 0.3 and abs(radial_px(2.2)) < 0.08, (radial_px(1.0), radial_px(2.2))


def test_a_dim_plaques_edges_are_found_in_linear_light_as_in_its_gray_levels(sign):
    """A plaque at gray level 33 on a wall at 13 (sRGB): its steps in linear light are a tenth of the
    gray levels', under the least step the gray levels are held to, but its edges are no weaker."""
    light = cv2.GaussianBlur(render_plaque(sign, TRUE_CORNERS, 255 * (13 / 255) ** 2.2, 255 * (33 / 255) ** 2.2 / 255),
                             (0, 0), 0.8) / 255
    image = (255 * light ** (1 / 2.2) + np.random.default_rng(4).normal(0, 0.5, light.shape)).clip(0, 255)
    outline, why = refine_outline(image.astype(np.uint8), sign, start_homography(sign, 2.0), gamma=2.2)
    assert outline is not None, why
    assert np.abs(outline.corners - TRUE_CORNERS).max() < 0.5


def test_dense_alignment_of_a_sign_the_lens_puts_beyond_the_ideal_frame_is_none(sign):
    """Through a barrel lens a sign at the frame's edge can lie wholly outside the frame an ideal pinhole with
    the same K takes: there is nothing to align, where an empty neighbourhood raised cv2.error mid-flight."""
    camera = Camera(assumed_camera(640, 480).K, np.array([-0.25, 0.08, 0.0, 0.0, 0.0]), 640, 480)
    beyond = cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32),
                                         (TRUE_CORNERS + [700.0, 0.0]).astype(np.float32)).astype(float)
    assert refine_ecc(plaque_image(sign, 90.0), sign, beyond, camera) is None


def test_no_edge_no_refinement(sign):
    """A plaque as bright as its wall has no outline: refused with the side that failed, not guessed."""
    image = plaque_image(sign, 255.0)
    outline, why = refine_outline(image, sign, start_homography(sign, 2.0), gamma=LINEAR)
    assert outline is None and why.startswith("side ")


def test_a_start_too_far_off_is_refused(sign):
    """Edges beyond the search are not looked for: the text's strokes must not pass for them."""
    image = plaque_image(sign, 90.0)
    outline, why = refine_outline(image, sign, start_homography(sign, 25.0), gamma=LINEAR)
    assert outline is None and why


def test_recognize_uses_the_outline_on_a_synthetic_scene(library):
    camera = synthetic_camera((640, 480))
    scene = render_scene(library, "chief_of_security", camera, np.random.default_rng(7), "easy")
    with_outline = recognize(scene.image, library, preset("default"), camera)
    without = recognize(scene.image, library, preset("default").replace(refine_outline=False), camera)
    assert with_outline.label == without.label == "chief_of_security"
    assert with_outline.outline is not None and without.outline is None
    assert with_outline.pose.covariance is not None
    errors = [float(np.linalg.norm(r.corners - scene.corners, axis=1).mean()) for r in (with_outline, without)]
    assert errors[0] < 0.5 and errors[0] < errors[1], errors
    assert preset("paper").refine_outline is False
    # A landmark searched without segmentation need not be a plaque: no outline, and no warning about it.
    unsegmented = recognize(scene.image, library, preset("default").replace(segment_mode="none"), camera)
    assert unsegmented.label == "chief_of_security" and unsegmented.outline is None
    assert not any("outline" in w for w in unsegmented.warnings), unsegmented.warnings


def test_pose_covariance_from_the_edges_matches_the_scatter(sign):
    """Poses fitted to outlines of 40 noisy images of one view scatter as the edge covariance says
    (the residuals of the exact grid the pose is fitted to claimed some twenty times less)."""
    camera = assumed_camera(640, 480)
    R, t = cv2.Rodrigues(np.array([0.15, 0.35, 0.05]))[0], np.array([0.05, 0.02, 1.6])
    corners = cv2.perspectiveTransform(sign.corners_px[None], homography_from_pose(R, t, camera.K, sign))[0]
    rotations, covariances = [], []
    for seed in range(40):
        outline, _ = refine_outline(plaque_image(sign, 90.0, seed=seed, corners=corners), sign,
                                    start_homography(sign, 3.0, seed + 100, corners), gamma=LINEAR)
        pose = estimate_pose(outline.H, *outline.grid(sign, camera), sign, camera)
        rotations.append(cv2.Rodrigues(pose.R)[0].ravel())
        rmse, covariance = outline_fit(pose.R, pose.t, outline, sign, camera)
        assert 0.005 < rmse < 0.5  # the edge points' scatter across their sides
        covariances.append(covariance)
    scatter = np.trace(np.cov(np.array(rotations).T))
    predicted = np.trace(np.mean(covariances, axis=0)[:3, :3])
    assert 0.4 < scatter / predicted < 2.5, (scatter, predicted)


SCENES = load_dataset(Path(__file__).parents[1] / "sample_images" / "scenes")
# The sample scenes' camera with a wide-angle lens: k1 -0.25 moves the frame's corners by ~40 px.
LENS = Camera(SCENES.camera.K, np.array([-0.25, 0.08, 0.001, -0.0005, 0.0]), 640, 480, source="wide-angle")


@pytest.mark.slow
def test_pose_under_lens_distortion_is_as_good_as_without(library):
    """The sample scenes seen through a wide-angle lens (k1 -0.25): the plaque's sides are curves
    in the image, and the pose is as accurate as on the scenes themselves. Fitting straight
    lines to the curved sides gave 0.4-1.5 degrees."""
    errors = []
    for sample in (s for s in SCENES.samples if s.label is not None):
        photo = through_lens(read_image(sample.path), LENS)
        rec = recognize(photo, library, preset("default"), LENS)
        assert rec.label == sample.label and rec.outline is not None, sample.path.name
        errors.append(rotation_error_deg(rec.pose.R, sample.R))
    assert np.median(errors) < 0.15 and max(errors) < 0.3, errors
    # The refinement depends on the lens: a cache filled with another camera's is not reused.
    cache = StageCache()
    recognize(photo, library, preset("default"), SCENES.camera, cache)
    assert np.array_equal(recognize(photo, library, preset("default"), LENS, cache).H, rec.H)


@pytest.mark.parametrize("name", ["scene_005.jpg", "scene_008.jpg", "scene_011.jpg"])
def test_a_sign_hundreds_of_pixels_wide_is_outlined_too(library, name):
    """The sample scenes enlarged 4x, as a 12 MP photo shows a sign: features on a 160 px crop
    put its corners 10-70 px off, beyond the edge search, where these would fall back to ECC (0.8
    degrees) or to the inliers alone (5.8 degrees). The outline is found in the image shrunk to
    the sign's usual size."""
    sample = next(s for s in SCENES.samples if s.path.name == name)
    photo = cv2.resize(read_image(sample.path), None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
    rec = recognize(photo, library, preset("default"), SCENES.camera)
    assert rec.label == sample.label and rec.outline is not None, rec.warnings
    assert rotation_error_deg(rec.pose.R, sample.R) < 0.15
    # in the photo's pixels: its corners are those of its H, its edge points on its sides
    corners = rec.outline.corners
    assert np.allclose(corners, sign_corners(library[rec.label], rec.outline.H), atol=1e-6)
    for i, points in enumerate(rec.outline.points):
        a, b = corners[i], corners[(i + 1) % 4]
        (dx, dy), (px, py) = b - a, (points - a).T
        across = (dx * py - dy * px) / np.hypot(dx, dy)
        assert len(points) >= 8 and np.abs(across).max() < 2.0


def test_only_the_signs_neighbourhood_is_shrunk(library, monkeypatch):
    """Each time a wide sign was outlined or aligned densely, the whole photo was shrunk first: 7 ms
    on 12 MP, most of it far from the sign. Here a sign 980 px wide in a 4000 x 3000 photo is
    outlined (the default) and aligned (ECC only)."""
    sample = next(s for s in SCENES.samples if s.path.name == "scene_004.jpg")
    enlarged = cv2.resize(read_image(sample.path), None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
    photo = cv2.copyMakeBorder(enlarged, 540, 540, 720, 720, cv2.BORDER_CONSTANT, value=(90, 90, 90))
    shrunk = []
    resize = cv2.resize

    def spy(image, *args, **kwargs):
        shrunk.append(image.shape[0] * image.shape[1])
        return resize(image, *args, **kwargs)

    monkeypatch.setattr(cv2, "resize", spy)
    for settings in (preset("default"), dataclasses.replace(preset("default"), refine_outline=False, refine="ecc")):
        shrunk.clear()
        rec = recognize(photo, library, settings, SCENES.camera)
        assert rec.label == sample.label and (rec.outline is not None or rec.ecc is not None), rec.warnings
        assert shrunk and max(shrunk) < 0.15 * photo.shape[0] * photo.shape[1]


def test_a_wide_sign_is_aligned_in_the_shrunk_image(library, monkeypatch):
    """ECC on a sign 1500 px wide in a 12 MP photo through a wide lens took 8 s and 4.7 GB: it
    ran on the sign's full-resolution neighbourhood. It is aligned where the sign is
    SHRUNK_WIDTH_PX wide, as the outline is read."""
    sample = next(s for s in SCENES.samples if s.path.name == "scene_005.jpg")
    photo = cv2.resize(through_lens(read_image(sample.path), LENS), None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
    lens = LENS.for_image(2560, 1920)[0]
    aligned_in = []
    find_transform_ecc = cv2.findTransformECC

    def spy(template, image, *args):
        aligned_in.append(image.shape)
        return find_transform_ecc(template, image, *args)

    monkeypatch.setattr(cv2, "findTransformECC", spy)
    ecc_only = dataclasses.replace(preset("default"), refine_outline=False, refine="ecc")
    rec = recognize(photo, library, ecc_only, lens)
    assert rec.label == sample.label and rec.ecc is not None and rec.outline is None
    assert aligned_in and max(max(shape) for shape in aligned_in) < 2 * SHRUNK_WIDTH_PX
    assert rotation_error_deg(rec.pose.R, sample.R) < 2.0  # ECC alone, as on the scenes themselves


@pytest.mark.slow
def test_dense_refinement_under_lens_distortion_aligns_as_without(library):
    """Without the outline, ECC alone refines H. Through the wide-angle lens it aligns the sign in
    the image an ideal pinhole camera would take, so the sign's corners (undistorted) come out
    as close to the truth as on the scenes themselves (about 1 px); aligned in the distorted
    image they were up to 11 px off."""
    ecc_only = dataclasses.replace(preset("default"), refine_outline=False, refine="ecc")
    for sample in (s for s in SCENES.samples if s.label is not None):
        image = read_image(sample.path)
        errors = []
        for photo, camera in ((image, SCENES.camera), (through_lens(image, LENS), LENS)):
            rec = recognize(photo, library, ecc_only, camera)
            assert rec.label == sample.label and rec.ecc is not None and rec.outline is None
            corners = undistort_pixels(sign_corners(library[rec.label], rec.H), camera)
            errors.append(np.abs(corners - sample.corners).max())
        assert errors[1] < errors[0] + 0.5, (sample.path.name, errors)


def test_a_close_sign_is_outlined_with_the_principal_point_at_the_image_edge(library, sign):
    """The camera of the shrunk image a wide sign is outlined in was held to a camera file's bounds:
    a file without an image size, its principal point at this image's edge (cx = 0, warned as
    made for another resolution), moved half a pixel out of the image there, and recognition failed."""
    corners = np.array([[60.0, 150], [580, 165], [575, 370], [66, 355]])
    camera = Camera(np.array([[554.0, 0, 0], [0, 554, 240], [0, 0, 1]]), np.zeros(5))
    rec = recognize(plaque_image(sign, 90, corners=corners), library, preset("default"), camera)
    assert rec.label == sign.id and rec.outline is not None
    assert any("another resolution" in w for w in rec.warnings)
    assert np.abs(rec.corners - corners).max() < 1.0


@pytest.mark.parametrize("blur, noise, sharp", [(0.8, 3.0, True), (2.0, 12.0, False)])
def test_an_outlines_corner_sigma_comes_from_its_edges(sign, blur, noise, sharp):
    """A sharp plaque's corners keep CORNER_SIGMA_PX["outline"]; a blurred, noisy one's count with its
    edge points' scatter, and the wider covariance still covers the pose's error (NEES, 6 dof)."""
    camera = assumed_camera(640, 480)
    R, t = cv2.Rodrigues(np.array([0.15, 0.35, 0.05]))[0], np.array([0.05, 0.02, 1.6])
    corners = cv2.perspectiveTransform(sign.corners_px[None], homography_from_pose(R, t, camera.K, sign))[0]
    plaque = render_plaque(sign, corners, 90.0, 1.0)
    errors = []
    for seed in range(8):
        noisy = cv2.GaussianBlur(plaque, (0, 0), blur) + np.random.default_rng(seed).normal(0, noise, plaque.shape)
        outline, _ = refine_outline(np.clip(noisy, 0, 255).astype(np.uint8), sign,
                                    start_homography(sign, 3.0, seed + 100, corners), gamma=LINEAR)
        fitted = estimate_pose(outline.H, *outline.grid(sign, camera), sign, camera, with_covariance=False)
        pose = outline_pose(fitted, outline, sign, camera)
        sigma = outline_corner_sigma(pose.reprojection_rmse_px)
        assert sigma == CORNER_SIGMA_PX["outline"] if sharp else sigma > 0.15, pose.reprojection_rmse_px
        _, edges = outline_fit(pose.R, pose.t, outline, sign, camera)
        assert np.allclose(pose.covariance, edges + corner_covariance(pose.R, pose.t, sign, camera, sigma))
        error = np.concatenate([cv2.Rodrigues(pose.R)[0].ravel() - cv2.Rodrigues(R)[0].ravel(), pose.t - t])
        errors.append(error @ np.linalg.solve(pose.covariance, error))
    assert np.mean(errors) < 12.6  # chi-squared's 95 % point for 6 dof: not overconfident
