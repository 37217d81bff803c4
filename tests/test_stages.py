"""Each setting feeds the stages it declares: a change recomputes exactly those, and what the stage
cache hands back for the others is what computing them afresh under the changed settings gives.

Where a setting only decides whether a stage runs (plaque_fallback, segment_mode) or also changes
the inputs of the stage it feeds (refine, and seed through RANSAC's winner), the changed run has no
cached result of that stage to compare: its declaration is checked by the key alone."""

import dataclasses
import math
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from signpose.pipeline.camera import load_camera
from signpose.pipeline.image import read_image
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import Settings, settings_schema
from signpose.pipeline.stages import ALL_STAGES, CACHED_STAGES, StageCache, feeding_settings, stage_key
from tests.support.scene_images import dim_plaque_scene

SAMPLES = Path(__file__).resolve().parents[1] / "sample_images"
# Two without a sign (every region searched, the full frame too, and the plaque fallback and its search turn down
# a blob for its correlation, then for its margin), one found among the quads and one the plaque fallback reads:
# together they run every cached stage.
SCENE_PATHS = ("scenes/scene_000.jpg", "scenes/scene_003.jpg", "scenes/scene_009.jpg", "datasets/set2/scene_007.jpg")
FIELDS = {f.name: f for f in dataclasses.fields(Settings)}
# Changes that `changed_value`'s 0.8 x would make too small to change what the stages fed compute on the scenes.
CHANGES = {"min_blob_area": 0.01, "max_features": 300, "max_search_size": 320, "min_plaque_ncc": 0.3,
           "plaque_margin": 0.0, "min_plaque_ecc": 0.99, "plaque_ecc_margin": 0.9}


@pytest.fixture(scope="module")
def scenes(library):
    """(name, image, its camera, the settings changed from) of each scene searched."""
    photos = [(path, read_image(SAMPLES / path), load_camera((SAMPLES / path).parent / "camera.yaml"), Settings())
              for path in SCENE_PATHS]
    # A dim sign below a lamp, which only the plaque search finds (when no plaque candidate is searched for features)
    dim = ("dim sign", dim_plaque_scene(library["security_compound"], exit_plaque=(420, 330)), None,
           Settings(plaque_candidates=0))
    return [*photos, dim]


def test_every_setting_declares_the_stages_it_feeds():
    for f in FIELDS.values():
        stages = f.metadata.get("stages")
        assert isinstance(stages, tuple) and stages, f"{f.name} names no stage"
        assert set(stages) <= set(ALL_STAGES), f"{f.name}: unknown stage in {stages}"
    # the pipeline's own: the schema the API and the page read is as it was
    assert all("stages" not in entry for entry in settings_schema())


def test_a_stage_key_holds_the_settings_of_the_cached_stages_it_reads():
    assert "max_features" in feeding_settings("match") and "ratio" not in feeding_settings("features")
    assert {"threshold", "min_blob_area", "plaque_search"} <= set(feeding_settings("plaque"))
    assert feeding_settings("library features") == ("detector", "max_features", "contrast_threshold")
    settings = Settings()
    assert stage_key(settings, "match") == (*stage_key(settings, "features"), settings.ratio)
    with pytest.raises(KeyError):
        feeding_settings("ransac")  # run every time: no key


def changed_value(f: dataclasses.Field[Any]) -> Any:
    """A valid value of setting `f` other than its default, far enough from it to change what the
    stages it feeds compute on the scenes."""
    default: Any = f.default
    meta = f.metadata
    if f.name in CHANGES:
        return CHANGES[f.name]
    if "choices" in meta:
        return meta["choices"][(meta["choices"].index(default) + 1) % len(meta["choices"])]
    if isinstance(default, bool):
        return not default
    if default is None:
        return meta["max"] - meta["step"]
    value = type(default)(default * 0.8)
    return value if value != default else default + meta["step"]


def same(a: Any, b: Any) -> bool:
    """Whether two stage results hold the same values (arrays, dataclasses, containers)."""
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype
                and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if hasattr(a, "__dict__"):
        return type(a) is type(b) and same(vars(a), vars(b))
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


class RecordingCache(StageCache):
    """A stage cache that keeps everything, starting with the results in `warm` (by key), and records
    each lookup as (its key, found) in `calls` and each result in `results`."""

    def __init__(self, warm: dict[tuple, Any] | None = None) -> None:
        super().__init__(max_entries=10**6, max_bytes=2**40)  # nothing dropped: a miss is a recomputation
        self.calls: list[tuple[tuple, bool]] = []
        self.results: dict[tuple, Any] = dict(warm or {})
        for key, value in self.results.items():
            super().get(key, lambda value=value: value)

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        assert isinstance(key, tuple), key  # (stage, inputs, stage_key), as StageRunner.run makes it
        self.calls.append((key, key in self))
        value = self.results[key] = super().get(key, compute)
        return value


class ComputingCache(StageCache):
    """A stage cache that hands nothing back, so that every stage is computed as without one, and
    keeps each result (by key) in `results`."""

    def __init__(self) -> None:
        super().__init__()
        self.results: dict[tuple, Any] = {}

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        value = compute()
        assert isinstance(key, tuple), key
        self.results.setdefault(key, value)
        return value


def answer(result, scene: str) -> dict:
    """`result`'s JSON but for its times and the stages it reused."""
    return result.to_json(scene) | {"timing_ms": None, "reused_stages": None}


@pytest.fixture(scope="module")
def warm(library, scenes):
    """Per scene, the results of a run under its settings, by cache key."""
    results = []
    for scene, image, camera, settings in scenes:
        cache = RecordingCache()  # one per image, as its results are that image's
        cached = recognize(image, library, settings, camera, cache)
        results.append(cache.results)
        # a cache that hands nothing back computes the answer a run without one does
        assert answer(recognize(image, library, settings, camera, ComputingCache()), scene) == \
            answer(recognize(image, library, settings, camera), scene) == answer(cached, scene), scene
    return results


def test_the_scenes_run_every_cached_stage(warm):
    assert {stage for results in warm for stage, _, _ in results} == set(CACHED_STAGES)


@pytest.mark.parametrize("name", list(FIELDS))
def test_a_setting_change_recomputes_exactly_the_stages_it_feeds(library, scenes, warm, name):
    fed = {stage for stage in CACHED_STAGES if name in feeding_settings(stage)}
    for (scene, image, camera, base), results in zip(scenes, warm):
        changed = base.replace(**{name: changed_value(FIELDS[name])})
        cache = RecordingCache(results)
        again = recognize(image, library, changed, camera, cache)
        # every stage computed afresh under the changed settings, as a run without the cache does
        afresh = ComputingCache()
        fresh = recognize(image, library, changed, camera, afresh)
        before = {(stage, inputs) for stage, inputs, _ in results}
        for key, found in cache.calls:
            stage, inputs, _ = key
            if stage in fed:
                assert not found, f"{scene}: {name} feeds {stage}, which came from the cache"
            elif (stage, inputs) in before:
                assert found, f"{scene}: {name} does not feed {stage}, which was computed again"
            if found:
                assert key in afresh.results and same(cache.results[key], afresh.results[key]), \
                    f"{stage} on {inputs}: the cached result is stale"
        # and the whole answer is the one computing every stage gives
        assert answer(again, scene) == answer(fresh, scene), scene
