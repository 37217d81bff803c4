"""The affine fallback: a sign seen 60-80 degrees off its normal, which the ordinary features and the
plaque fallback miss, recognised from simulated steep views of the library's signs, computed once."""

import numpy as np
import pytest

import signpose.pipeline.features as features
from signpose.app.workspace import SAMPLE_SCENES
from signpose.pipeline.features import library_affine_features
from signpose.pipeline.image import read_image
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import Settings, preset
from tests.support.scene_images import corners_seen_from, plaque_of, steep_plaque

SIGN = "security_compound"
# shares مجمع with security_compound, and most of its letters' shapes
DECOY = "مجمع تجاري"


@pytest.fixture(scope="module")
def library() -> Library:
    """The sample library with SIGN alone: its simulated views take a quarter of the three signs' time."""
    full = load_library()
    return Library(full.root, [full[SIGN]])


@pytest.fixture
def counted(monkeypatch) -> list[str]:
    """The ids of the signs whose simulated views are computed, in the order computed."""
    computed: list[str] = []
    simulate = features.sign_affine_features

    def counting(sign, settings):
        computed.append(sign.id)
        return simulate(sign, settings)

    monkeypatch.setattr(features, "sign_affine_features", counting)
    return computed


def test_a_steep_view_is_recognised_by_the_affine_fallback_alone(library):
    image = steep_plaque(library[SIGN], 65)
    without = recognize(image, library, Settings(affine_fallback=False))
    assert without.label is None and not without.by_plaque
    found = recognize(image, library, Settings())
    assert found.label == SIGN and found.best is not None
    assert found.attempt is found.attempts[-1] and found.attempt.source.endswith("simulated steep views")
    assert any(w.startswith("recognised by the affine fallback") for w in found.warnings)
    # the homography maps library px to image px, as the ordinary features' does
    truth = corners_seen_from(library[SIGN], (np.sin(np.radians(65)), 0.0, -np.cos(np.radians(65))))
    assert np.abs(found.corners - truth).max() < 3.0
    assert found.to_json("steep.png")["label"] == SIGN


def test_a_steep_look_alike_is_still_refused(library):
    found = recognize(steep_plaque(plaque_of(DECOY), 65), library, Settings())
    assert found.label is None
    assert not any("affine fallback" in w for w in found.warnings)
    # matched as the sign through its simulated views, and turned down for its text, as a frontal one is
    assert [t.source for t in found.turned_down] == ["blob 1, simulated steep views"]


def test_the_simulated_views_are_computed_once_per_library_and_feature_settings(counted):
    full = load_library()
    library = Library(full.root, [full[SIGN]])
    settings = Settings(max_features=300)
    first = library_affine_features(library, settings)
    assert library_affine_features(library, settings.replace(ratio=0.6, affine_fallback=False)) is first
    assert counted == [SIGN]
    assert len(first[SIGN]) > 0
    library_affine_features(library, settings.replace(max_features=200))
    assert counted == [SIGN, SIGN]


def test_keypoints_of_the_simulated_views_are_in_library_pixels(library):
    simulated = library_affine_features(library, Settings())[SIGN]
    w, h = library[SIGN].size_px
    assert np.all((simulated.xy >= -1) & (simulated.xy <= [w, h]))


def test_an_image_the_ordinary_path_decides_never_computes_them(counted):
    library = load_library()
    found = recognize(read_image(SAMPLE_SCENES / "scene_002.jpg"), library, preset("default"))
    assert found.recognized and counted == []
    assert not any("affine fallback" in w for w in found.warnings)


def test_the_paper_preset_has_no_affine_fallback():
    assert preset("paper").affine_fallback is False and Settings().affine_fallback is True
