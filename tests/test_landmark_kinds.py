"""Landmark kinds (`kind` in library.json): a plaque of text is checked against plaques of other
words, a picture (a box, a poster, a photo) for its likeness under any light; each entry may set
its own `min_text_correlation`."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Hashable
from typing import TypeVar

import cv2
import numpy as np
import pytest
from signpose.pipeline.features import MAX_BUDGET, picture_budget, search_settings
from signpose.pipeline.library import (
    SAMPLE_LIBRARY,
    Library,
    LibraryError,
    infer_kind,
    load_library,
    make_sign,
    save_library_json,
    validate_sign_entry,
)
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset
from signpose.pipeline.stages import StageCache, stage_key
from signpose.pipeline.verify import text_threshold
from tests.support.scene_images import decoy_image
from tests.support.shared_data import shared_folder

OPENCV = shared_folder() / "data" / "opencv"
T = TypeVar("T")


def test_a_library_json_with_kind_and_its_own_bar_round_trips(tmp_path):
    root = tmp_path / "library"
    shutil.copytree(SAMPLE_LIBRARY, root)
    meta = json.loads((root / "library.json").read_text(encoding="utf-8"))
    meta["signs"][0].update(kind="picture", min_text_correlation=0.3)
    del meta["signs"][1]["kind"]  # told from its image: paper all round its text
    (root / "library.json").write_text(json.dumps(meta), encoding="utf-8")
    library = load_library(root)
    save_library_json(library)
    again = load_library(root)
    assert [(s.kind, s.min_text_correlation) for s in again.signs] == [("picture", 0.3), ("plaque", None),
                                                                       ("plaque", None)]
    assert again.signs[0].to_json()["min_text_correlation"] == 0.3 and "min_text_correlation" not in again.signs[1].to_json()
    settings = preset("default")
    assert [text_threshold(s, settings) for s in again.signs] == [0.3, settings.min_text_correlation,
                                                                  settings.min_text_correlation]


@pytest.mark.parametrize("fields, words", [
    ({"kind": "poster"}, "kind 'poster' must be \"plaque\" (a plaque of text on plain paper"),
    ({"kind": 3}, "kind 3 must be \"plaque\""),
    ({"min_text_correlation": 1.5}, "min_text_correlation must be a number from 0 (no check) to 1"),
    ({"min_text_correlation": "high"}, "min_text_correlation must be a number from 0 (no check) to 1"),
])
def test_a_bad_kind_or_bar_is_refused_saying_what_it_may_be(fields, words):
    with pytest.raises(LibraryError) as refused:
        validate_sign_entry({"id": "a", "image": "a.png", "width_m": 0.3, **fields}, "sign #0")
    assert str(refused.value).startswith("sign #0: ") and words in str(refused.value)


def test_kind_is_told_from_the_image_when_not_given():
    library = load_library(SAMPLE_LIBRARY)
    assert {infer_kind(s.image) for s in library.signs} == {"plaque"}
    texture = np.random.default_rng(0).integers(0, 256, (120, 200), dtype=np.uint8)
    assert infer_kind(cv2.GaussianBlur(texture, (0, 0), 2)) == "picture"
    # A picture on a plain ground (a magazine on a table) has a plain margin too, but no paper among its marks.
    on_table = np.full((300, 400), 230, np.uint8)
    on_table[90:210, 100:300] = cv2.GaussianBlur(texture, (0, 0), 2)
    assert infer_kind(on_table) == "picture"
    bold = np.full((200, 500), 235, np.uint8)
    cv2.putText(bold, "EXIT 8", (40, 150), cv2.FONT_HERSHEY_SIMPLEX, 4.5, 20, 18)
    assert infer_kind(bold) == "plaque"


def test_a_plaque_of_other_words_is_refused_when_the_kinds_are_told_from_the_images(tmp_path):
    """The sample signs without a kind are plaques: their look-alike check holds, and its reason says
    what a user whose landmark is no plaque of text may change."""
    root = tmp_path / "library"
    shutil.copytree(SAMPLE_LIBRARY, root)
    meta = json.loads((root / "library.json").read_text(encoding="utf-8"))
    for sign in meta["signs"]:
        del sign["kind"]
    (root / "library.json").write_text(json.dumps(meta), encoding="utf-8")
    library = load_library(root)
    rec = recognize(decoy_image("رئيس الوزراء", 0), library, preset("default"))
    assert rec.label is None and rec.turned_down, rec.to_json("x")
    reason = next(s.reason for a in rec.attempts for s in a.scores if s.reason and "text differs" in s.reason)
    assert '"kind": "picture" in library.json' in reason and '"min_text_correlation"' in reason, reason


@pytest.mark.skipif(not OPENCV.is_dir(), reason=f"OpenCV's sample photos not found at {OPENCV}")
@pytest.mark.parametrize("crop", [None, (40, 30, 280, 200)])
def test_the_box_is_recognised_as_a_picture(crop):
    """OpenCV's box.png (whole, or a crop of its front) in box_in_scene.png: 78 inliers, turned down as
    a plaque of other words (one strip in shadow correlated 0.28)."""
    box = cv2.imread(str(OPENCV / "box.png"), cv2.IMREAD_GRAYSCALE)
    if crop is not None:
        x0, y0, x1, y1 = crop
        box = box[y0:y1, x0:x1].copy()
    entry = validate_sign_entry({"id": "box", "image": "box.png", "width_m": 0.2}, "box")
    library = Library(OPENCV, [make_sign(entry, box, "box")])
    assert library.signs[0].kind == "picture"
    rec = recognize(cv2.imread(str(OPENCV / "box_in_scene.png")), library, preset("default"))
    assert rec.label == "box" and rec.text_check.kind == "picture", rec.to_json("x")
    assert rec.best.n_inliers >= 50
    # as a plaque it is turned down, saying what to change
    entry["kind"] = "plaque"
    as_plaque = recognize(cv2.imread(str(OPENCV / "box_in_scene.png")),
                          Library(OPENCV, [make_sign(entry, box, "box")]), preset("default"))
    assert as_plaque.label is None
    assert any(s.reason and '"kind": "picture"' in s.reason for a in as_plaque.attempts for s in a.scores)


@pytest.mark.skipif(not OPENCV.is_dir(), reason=f"OpenCV's sample photos not found at {OPENCV}")
def test_a_landmarks_own_bar_decides_and_its_refusal_says_so():
    """The entry's own min_text_correlation is the bar, whatever the settings say; turned down, the
    reason names the check that failed and the value to change."""
    box = cv2.imread(str(OPENCV / "box.png"), cv2.IMREAD_GRAYSCALE)
    entry = validate_sign_entry({"id": "box", "image": "box.png", "width_m": 0.2, "min_text_correlation": 0.99},
                                "box")
    library = Library(OPENCV, [make_sign(entry, box, "box")])
    rec = recognize(cv2.imread(str(OPENCV / "box_in_scene.png")), library,
                    preset("default").replace(min_picture_correlation=0.1))
    assert rec.label is None
    reason = rec.scores[0].reason
    assert reason.startswith("the picture differs from box's (median strip correlation 0.") and "< 0.99" in reason
    assert reason.endswith('lower its "min_text_correlation" in library.json'), reason


def test_a_pictures_feature_budget_grows_with_its_area_and_a_plaques_does_not():
    settings = preset("default")
    assert picture_budget(settings, 640, 480) is settings
    assert picture_budget(settings, 1280, 960).max_features == 4 * settings.max_features
    assert picture_budget(settings, 8000, 6000).max_features == MAX_BUDGET
    plaques = load_library(SAMPLE_LIBRARY)
    assert search_settings(settings, plaques, (0, 0, 4000, 3000)) is settings
    picture = make_sign({"id": "p", "image": "p.png", "width_m": 1.0, "kind": "picture"},
                        np.full((100, 100), 128, np.uint8) + np.eye(100, dtype=np.uint8) * 50, "p")
    mixed = Library(plaques.root, [*plaques.signs, picture])
    assert search_settings(settings, mixed, (0, 0, 1280, 960)).max_features == 4 * settings.max_features


class KeyRecordingCache(StageCache):
    """A stage cache that records the key of every lookup."""

    def __init__(self) -> None:
        super().__init__()
        self.keys: list[Hashable] = []

    def get(self, key: Hashable, compute: Callable[[], T]) -> T:
        self.keys.append(key)
        return super().get(key, compute)


def test_a_view_searched_for_a_picture_is_cached_under_the_budget_it_was_detected_with():
    """The grown budget reaches the features' and the matches' keys through the settings they ran
    with (`StageRunner.run`), derived as every stage key is, not written out beside them."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (0, 0), 1.5)
    picture = make_sign({"id": "p", "image": "p.png", "width_m": 1.0, "kind": "picture"}, texture, "p")
    library = Library(SAMPLE_LIBRARY, [picture])
    scene = np.full((960, 1280), 90, np.uint8)
    scene[300:540, 400:720] = texture
    settings = preset("default")
    grown = search_settings(settings, library, (0, 0, 1280, 960))
    assert grown.max_features == 4 * settings.max_features
    cache = KeyRecordingCache()
    recognize(scene, library, settings, cache=cache)
    keyed = {key[0]: key[2] for key in cache.keys if isinstance(key, tuple) and key[0] in ("features", "match")}
    assert keyed == {"features": stage_key(grown, "features"), "match": stage_key(grown, "match")}
    # the same run again is handed them; one under another max_features is not
    assert {"features", "match"} <= set(recognize(scene, library, settings, cache=cache).reused_stages)
    smaller = settings.replace(max_features=settings.max_features // 2)
    assert "features" not in recognize(scene, library, smaller, cache=cache).reused_stages
