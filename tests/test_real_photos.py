"""Homography estimation on real photo pairs with ground truth (../shared/data/homogr).

Image A plays the library sign and B the scene; the default preset runs on the full frame
(`segment_mode="none"`), as for any landmark that is not a bright plaque.
"""

import cv2
import numpy as np
import pytest
from signpose.pipeline.library import Library, make_sign
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset
from tests.support.shared_data import shared_folder

DATA = shared_folder() / "data" / "homogr"
SOLVABLE = ["adam", "boat", "city", "WhiteBoard", "BruggeSquare"]

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"real photo pairs not found at {DATA}")


def run_pair(name: str, **changes):
    """(recognition, ground-truth RMSE in B pixels of the label-1 points, or None without H), under the
    default preset with `changes`."""
    a = cv2.imread(str(next(DATA.glob(f"{name}A.*"))), cv2.IMREAD_GRAYSCALE)
    b = cv2.imread(str(next(DATA.glob(f"{name}B.*"))))
    pts = np.loadtxt(DATA / f"{name}_pts.txt")
    truth = pts[pts[:, 6] == 1]
    library = Library(DATA, [make_sign({"id": "a", "image": "a.png", "width_m": 1.0}, a, name)])
    rec = recognize(b, library, preset("default").replace(segment_mode="none", **changes))
    H = rec.H if rec.recognized else rec.scores[0].H
    if H is None:
        return rec, None
    # The truth's A points are OpenCV px, pixel x's centre at x; H takes library px, where it is at x + 0.5.
    mapped = cv2.perspectiveTransform(truth[None, :, :2] + 0.5, H)[0]
    return rec, float(np.sqrt(np.mean(np.sum((mapped - truth[:, 3:5]) ** 2, axis=1))))


def test_default_preset_is_accurate_on_real_photos():
    runs = {name: run_pair(name) for name in SOLVABLE}
    rmse = {name: run[1] for name, run in runs.items()}
    assert all(v is not None for v in rmse.values()), rmse
    assert np.median(list(rmse.values())) <= 1.5, rmse
    assert rmse["city"] < 1.0 and rmse["adam"] < 1.0, rmse
    # Photo A is a picture (no plain margin round it), checked with its light evened out and judged
    # by its median strip: WhiteBoard (one strip in glare, its board written on again), city (other
    # light) and BruggeSquare (partly in view) were turned down as plaques of other words.
    answered = {name for name, (rec, _) in runs.items() if rec.recognized}
    assert answered == set(SOLVABLE), answered
    assert all(rec.text_check.kind == "picture" for rec, _ in runs.values())
    assert runs["WhiteBoard"][0].text_check.overwhelming  # its strips alone would not pass


def test_a_picture_larger_than_the_view_is_recognised_saying_how_much_was_in_view():
    """BostonLib's B shows a third of its A, whose corners lie 2.5 frames beyond B's edge: it was
    refused for "corners far outside the image". Dense alignment, which bends what is out of view
    (its truth 4.2 px off), is not used where the matched points contradict it."""
    rec, rmse = run_pair("BostonLib")
    assert rec.recognized and rmse is not None and rmse < 1.5, (rmse, rec.warnings)
    assert any(w.startswith("only ") and "% of a is in the image" in w for w in rec.warnings), rec.warnings
    assert any("dense refinement disagreed with the matched points" in w for w in rec.warnings), rec.warnings

def test_unsolvable_pair_is_reported_not_guessed():
    """LePoint1 is a magazine seen far off its normal: SIFT on the photos finds 5 inliers."""
    rec, rmse = run_pair("LePoint1", affine_fallback=False)
    score = rec.scores[0]
    assert not rec.recognized
    assert score.reason is not None, f"LePoint1 accepted with H error {rmse} px"


def test_an_extreme_viewpoint_pair_is_solved_by_the_affine_fallback():
    """The simulated steep views of LePoint1's A match 148 of its B's features."""
    rec, rmse = run_pair("LePoint1")
    assert rec.recognized and rmse is not None and rmse < 5.0, (rmse, rec.warnings)
    assert any(w.startswith("recognised by the affine fallback") for w in rec.warnings)


def test_a_picture_seen_in_a_small_part_gets_features_by_its_area():
    """Eiffel's B shows a sixth of its A (1198 x 958 px): with max_features' 2000 over the whole of
    each photo, 48 inliers put its points 5.9 px off."""
    rec, rmse = run_pair("Eiffel")
    assert rec.recognized and rmse is not None and rmse < 2.5, (rmse, rec.warnings)
    assert rec.best.n_inliers > 200


def test_a_picture_on_a_plain_ground_is_not_taken_for_a_plaque():
    """LePoint2's A is a magazine lying on a gray table: a plain margin all round, no paper among its
    marks. Taken for a plaque, its text check failed through the true homography (weakest strip
    0.62) and passed only through a dense alignment 7.3 px off it; as a picture, its 15 inliers from
    the simulated steep views place it."""
    rec, rmse = run_pair("LePoint2")
    assert rec.recognized and rec.text_check.kind == "picture", rec.warnings
    assert rmse is not None and rmse < 5.0, (rmse, rec.warnings)
