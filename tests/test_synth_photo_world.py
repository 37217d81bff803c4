"""The second test world: library signs printed and pasted into real photographs
(pipeline/synth_photo_world.py), its truth and the default preset on a few of its scenes."""

import cv2
import numpy as np
import pytest

from signpose.pipeline.evaluate import load_dataset
from signpose.pipeline.recognize import recognize
from signpose.pipeline.pose import rotation_error_deg
from signpose.pipeline.settings import preset
from signpose.pipeline.synth_photo_world import (PhotoWorldError, generate_photo_world, photo_world_camera,
                                                 render_photo_scene)
from tests.support.shared_data import shared_folder
from tools.make_photo_world import look_alike_plaques

BACKGROUNDS = [shared_folder() / "data" / "homogr", shared_folder() / "data" / "opencv"]

pytestmark = pytest.mark.skipif(not BACKGROUNDS[0].is_dir(), reason=f"real photos not found at {BACKGROUNDS[0]}")



@pytest.fixture(scope="module")
def photos():
    return sorted(p for folder in BACKGROUNDS for p in folder.iterdir() if p.suffix in (".png", ".jpg"))


def scene(library, photos, seed, look="easy", sign_id="security_compound", category="easy", decoy=None):
    return render_photo_scene(library, sign_id=sign_id, decoy=decoy, category=category, look=look, photos=photos,
                              camera=photo_world_camera(), rng=np.random.default_rng(seed))


def rectified(image: np.ndarray, corners: np.ndarray, size=(200, 80)) -> np.ndarray:
    """The (80, 200) gray quad of `image` at `corners` (4, 2) px, TL, TR, BR, BL, rectified."""
    w, h = size
    H = cv2.getPerspectiveTransform(corners.astype(np.float32), np.float32([[0, 0], [w, 0], [w, h], [0, h]]))
    return cv2.warpPerspective(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), H, size, flags=cv2.INTER_AREA).astype(float)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_the_same_seed_renders_the_same_scene(library, photos):
    first, again, other = (scene(library, photos, seed) for seed in (3, 3, 4))
    assert first.jpeg == again.jpeg and first.params == again.params
    assert first.jpeg != other.jpeg


@pytest.mark.parametrize("look", ["easy", "small", "shadow", "oblique", "steep"])
def test_the_truth_corners_land_on_the_printed_sign(library, photos, look):
    """Rectified through its truth corners, the image shows the sign (distortion and all), better
    than through the corners moved 3 px any way. The truth is one pose: the corners are its
    projection."""
    rendered = scene(library, photos, 11, look=look)
    sign = library["security_compound"]
    target = cv2.resize(sign.image, (200, 80), interpolation=cv2.INTER_AREA).astype(float)
    at_truth = ncc(rectified(rendered.image, rendered.corners), target)
    moved = [ncc(rectified(rendered.image, rendered.corners + 3 * np.array(step)), target)
             for step in [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)]]
    assert at_truth > 0.6 and at_truth > max(moved), (look, at_truth, moved)
    camera = photo_world_camera()
    projected = cv2.projectPoints(sign.to_metric(sign.corners_px), cv2.Rodrigues(rendered.R)[0], rendered.t,
                                  camera.K, camera.dist)[0].reshape(4, 2)
    assert np.allclose(projected, rendered.corners, atol=1e-6)
    assert np.allclose(cv2.perspectiveTransform(sign.corners_px[None], rendered.H)[0], rendered.corners, atol=1e-3)
    assert np.all(rendered.corners >= 0) and np.all(rendered.corners <= [640, 480])


@pytest.mark.slow
def test_sign_widths_and_angles_follow_the_look(library, photos):
    small = [scene(library, photos, seed, look="small", category="hard") for seed in range(4)]
    steep = [scene(library, photos, seed, look="steep", category="steep") for seed in range(4)]
    assert all(38 <= s.params["sign_width_px"] <= 82 for s in small), [s.params["sign_width_px"] for s in small]
    assert all(55 <= s.params["off_axis_deg"] <= 78 for s in steep), [s.params["off_axis_deg"] for s in steep]


@pytest.mark.slow
def test_a_set_loads_back_with_its_distorted_camera(library, tmp_path):
    images = generate_photo_world(tmp_path / "set", library, backgrounds=BACKGROUNDS, decoys=look_alike_plaques()[:2],
                                  counts={"easy": 2, "negative": 2}, seed=0)
    dataset = load_dataset(tmp_path / "set")
    assert len(dataset) == 4 and dataset.camera.has_distortion
    assert sorted(t["params"]["look"] for t in images.values()) == ["easy", "easy", "look-alike", "no sign"]
    assert all((s.label is None) == (s.category == "negative") for s in dataset.samples)
    with pytest.raises(PhotoWorldError, match="already holds scenes"):
        generate_photo_world(tmp_path / "set", library, backgrounds=BACKGROUNDS, decoys=[], counts={"easy": 1}, seed=0)
    with pytest.raises(PhotoWorldError, match="no photos"):
        generate_photo_world(tmp_path / "other", library, backgrounds=[tmp_path / "none"], decoys=[],
                             counts={"easy": 1}, seed=0)


# Scenes the default preset answers: a frontal sign, one 53 px wide, a dim one in clutter, one
# 60 degrees off its normal; and two it must refuse: a plaque of other words, and none.
FIXED = [("easy", "easy", "chief_of_security", 21), ("hard", "small", "ministry_of_torture", 27),
         ("hard", "dim", "security_compound", 23), ("steep", "steep", "chief_of_security", 24),
         ("negative", "look-alike", None, 25), ("negative", "no sign", None, 26)]


@pytest.mark.slow
def test_the_default_preset_on_a_fixed_set_of_the_photo_world(library, photos):
    decoy = look_alike_plaques()[0]
    camera = photo_world_camera()
    for category, look, sign_id, seed in FIXED:
        rendered = scene(library, photos, seed, look=look, sign_id=sign_id, category=category,
                         decoy=decoy if look == "look-alike" else None)
        rec = recognize(rendered.image, library, preset("default"), camera)
        assert rec.label == sign_id, (look, rec.label, rec.warnings)
        if sign_id is not None:
            assert rotation_error_deg(rendered.R, rec.pose.R) < 3.0, look


def test_a_small_sign_no_threshold_cuts_out_is_found_by_zooming_where_the_full_frames_matches_crowd(library, photos):
    """A sign about 60 px wide in clutter: no crop holds it, and the full frame's few matches give no
    homography among the clutter's, but they crowd on it; that window, searched at twice the
    resolution, names the sign, which nothing finds without it."""
    rendered = scene(library, photos, 10, look="small", sign_id="ministry_of_torture", category="hard")
    camera = photo_world_camera()
    rec = recognize(rendered.image, library, preset("default"), camera)
    assert rec.label == "ministry_of_torture" and rec.attempt.source.startswith("zoom"), rec.warnings
    assert rotation_error_deg(rendered.R, rec.pose.R) < 3.0
    assert recognize(rendered.image, library, preset("default").replace(zoom_fallback=False), camera).label is None


def bench_scene(library, photos, index: int, sign_id: str, category: str, look: str):
    """(scene `index` of `bench/worlds.py`'s photo world, seed 0, rendered again alone; the default
    preset's recognition of it): `generate_photo_world` seeds scene i with the (i + 1)th spawn of its seed."""
    rendered = render_photo_scene(library, sign_id=sign_id, decoy=None, category=category, look=look, photos=photos,
                                  camera=photo_world_camera(),
                                  rng=np.random.default_rng(np.random.SeedSequence(0, spawn_key=(index + 1,))))
    return rendered, recognize(rendered.image, library, preset("default"), photo_world_camera())


def test_a_small_sign_whose_few_inliers_misplace_its_corners_is_refined_from_their_affine_fit(library, photos):
    """Scene 148 of the photo world (seed 0), a sign 76 px wide: the zoom gives it 11 inliers, all on
    its text, whose homography puts a corner 16 px off and the text check turns it down (weakest strip
    0.68); the affine fit to the same inliers puts the corners within the outline's reach, and the
    sign is answered from there, saying so."""
    rendered, rec = bench_scene(library, photos, 148, "security_compound", "hard", "small")
    assert rec.label == "security_compound", rec.warnings
    assert any(w.startswith("refined from the affine fit") for w in rec.warnings), rec.warnings
    # its corners through the answered H within 2 px of the truth (a 76 px sign: its rotation is 4-5 degrees off)
    assert np.abs(rec.corners - rendered.corners).max() < 2.0


def test_a_plaque_whose_outline_a_sharp_shadow_misplaces_is_answered_from_its_own_homography(library, photos):
    """Scene 94 of the photo world (seed 0), its edges read as encoded (`edge_gamma` 1): a sharp shadow's
    edge across a plaque's left end is taken for one of its sides, and through the outline the strip
    there fails the text check (0.51); through its 15 inliers' own homography every strip reads above
    0.8 and the sign is answered from it, saying so. Read in linear light, as by default, the side is
    the plaque's own."""
    rendered, rec = bench_scene(library, photos, 94, "chief_of_security", "easy", "easy")
    assert rec.label == "chief_of_security" and rec.outline is not None, rec.warnings
    assert np.abs(rec.corners - rendered.corners).max() < 1.5
    encoded = recognize(rendered.image, library, preset("default").replace(edge_gamma=1.0), photo_world_camera())
    assert encoded.label == "chief_of_security", encoded.warnings
    assert any(w.startswith("placed by its 15 inliers' homography, unrefined") for w in encoded.warnings), \
        encoded.warnings
    assert encoded.outline is None and encoded.text_check.weakest > 0.8
    assert np.abs(encoded.corners - rendered.corners).max() < 5.0


def test_a_steep_plaque_dense_alignment_does_not_confirm_is_answered_by_its_outline_and_text(library, photos):
    """Scene 5 of the photo world (seed 0), a plaque 102 px wide seen 60-75° off its normal: features
    give it 5 inliers, and dense alignment from its quad correlates 0.916 where the plaque search asks
    0.92; its outline is found from that quad and its text passes the check, so it is answered,
    saying so, its corners within half a pixel of the truth."""
    rendered, rec = bench_scene(library, photos, 5, "chief_of_security", "steep", "steep")
    assert rec.label == "chief_of_security", rec.warnings
    assert any(w.startswith("recognised by its plaque's outline and text") for w in rec.warnings), rec.warnings
    assert rec.outline is not None and rec.text_check.weakest >= 0.75
    assert np.abs(rec.corners - rendered.corners).max() < 0.5
