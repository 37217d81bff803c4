"""Recognition decisions on the committed sample scenes."""

import json
from pathlib import Path

import pytest

from pipeline.camera import load_camera
from pipeline.features import library_features
from pipeline.image import read_image
from pipeline.library import load_library
from pipeline.recognize import decide, recognize, score_sign
from pipeline.settings import preset

SCENES = Path(__file__).resolve().parents[1] / "sample_images" / "scenes"
TRUTH = json.loads((SCENES / "truth.json").read_text())["images"]


@pytest.fixture(scope="module")
def library():
    return load_library()


@pytest.mark.parametrize("name", sorted(n for n, t in TRUTH.items() if t["label"] is not None))
def test_signs_not_fitted_would_not_have_changed_the_decision(library, name):
    settings = preset("default")
    rec = recognize(read_image(SCENES / name), library, settings, load_camera(SCENES / "camera.yaml"))
    attempt = rec.attempt
    lib = library_features(library, settings)
    fitted = [score_sign(library[s.sign], attempt.features, lib[s.sign], s.matches, settings, rec.image_size,
                         dict.fromkeys(["ransac"], 0.0)) if s.skipped else s for s in attempt.scores]
    for skipped, score in zip(attempt.scores, fitted):
        if skipped.skipped:
            assert skipped.n_inliers == 0 and skipped.reason.startswith("not fitted")
            assert score.n_inliers <= skipped.n_matches
    winner, margin = decide(fitted, settings)
    assert winner == attempt.winner and library.signs[winner].id == rec.label == TRUTH[name]["label"]
    assert margin >= rec.margin >= settings.min_margin  # the reported margin is a lower bound


def test_a_clear_winner_skips_fitting_the_hopeless_signs(library):
    settings = preset("default")
    skipped = 0
    for name, truth in TRUTH.items():
        if truth["label"] is not None:
            rec = recognize(read_image(SCENES / name), library, settings, load_camera(SCENES / "camera.yaml"))
            skipped += sum(s.skipped for s in rec.scores)
    assert skipped > 0


def test_a_ransac_change_reuses_every_stage_it_does_not_affect(library):
    # All scenes, so that negatives (plaque fallback and search) and refined winners are both covered.
    import pipeline.recognize as recognize_module
    from unittest import mock

    from pipeline.recognize import StageCache

    settings, camera = preset("default"), load_camera(SCENES / "camera.yaml")
    changed = settings.replace(ransac_threshold_px=settings.ransac_threshold_px - 0.5)
    for name in sorted(TRUTH):
        image, cache = read_image(SCENES / name), StageCache()
        recognize(image, library, settings, camera, cache)
        fresh = recognize(image, library, changed, camera)
        with mock.patch.object(recognize_module, "refine_winner", wraps=recognize_module.refine_winner) as refine, \
                mock.patch.object(recognize_module, "find_plaque", wraps=recognize_module.find_plaque) as plaque:
            again = recognize(image, library, changed, camera, cache)
        assert again.label == fresh.label and again.warnings == fresh.warnings, name
        assert (again.H is None and fresh.H is None) or (again.H == fresh.H).all(), name
        assert plaque.call_count == 0, name
        if again.H is not None and (again.best is None or (again.best.estimate.inliers
                                                           == fresh.best.estimate.inliers).all()):
            assert refine.call_count == 0, name
