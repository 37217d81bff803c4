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
