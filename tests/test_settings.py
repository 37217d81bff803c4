import json
import math
import re

import pytest

from signpose.pipeline.settings import PRESETS, Settings, SettingsError, load_settings, preset, settings_schema


def test_paper_preset_is_the_published_method():
    p = preset("paper")
    assert (p.normalization, p.threshold, p.candidates, p.ratio) == ("minmax", 0.75, 1, 0.667)
    assert (p.ransac_method, p.ransac_iterations, p.pose_method) == ("own", 50, "paper")
    assert not p.full_frame_fallback


@pytest.mark.parametrize("changes, message", [
    ({"threshold": math.nan}, "finite"),
    ({"threshold": math.inf}, "finite"),
    ({"threshold": -0.1}, "between"),
    ({"ransac_iterations": 2.5}, "whole number"),
    ({"ransac_iterations": "50"}, "number"),
    ({"ransac_iterations": 10**400}, "between"),  # a JSON integer too big for a float
    ({"full_frame_fallback": 1}, "true or false"),
    ({"detector": "akaze"}, "one of"),
    ({"thresold": 0.5}, "unknown setting"),
    ({"threshold": 0.8, "high_threshold": 0.7}, "above threshold"),
    ({"candidates": None}, "null"),
    # taken, though every crop was then both upscaled to 500 px and downscaled to 160
    ({"min_crop_size": 500, "max_crop_size": 160}, r"^min_crop_size \(500\) must be at most max_crop_size \(160\), "
                                                   r"or max_crop_size 0 \(never downscale\)$"),
])
def test_invalid_values_are_clear_errors(changes, message):
    with pytest.raises(SettingsError, match=message):
        Settings().replace(**changes)


@pytest.mark.parametrize("changes", [{"min_crop_size": 500, "max_crop_size": 0}, {"min_crop_size": 160,
                                                                                   "max_crop_size": 160}])
def test_a_min_crop_size_up_to_max_crop_size_or_with_no_max_is_taken(changes):
    assert Settings().replace(**changes).min_crop_size == changes["min_crop_size"]


@pytest.mark.parametrize("changes, message", [
    ({"threshold": [1] * 1_000_000}, "threshold must be a number; got [1, 1, 1, 1, 1, 1, ...]"),
    ({"detector": "x" * 100_000}, 'detector must be one of sift, orb; got "xxxxxxxxxxxx...xxxxxxxxxxxxx"'),
    ({"x" * 100_000: 1, "thresold": 0.5}, 'unknown setting(s): "thresold", "xxxxxxxxxxxx...xxxxxxxxxxxxx"; known: '),
    # in JSON's words, as the file or request wrote them
    ({"candidates": True}, "candidates must be a number; got true"),
    ({"refine": ["a"]}, 'refine must be one of auto, ecc, none; got ["a"]'),
    ({"threshold": math.inf}, "threshold must be finite; got Infinity"),
])
def test_an_error_shows_a_value_or_name_shortened(changes, message):
    """A settings file's million-number value was written out whole: a 6 MB error line, or detail of a 422."""
    with pytest.raises(SettingsError) as info:
        Settings().replace(**changes)
    assert str(info.value).startswith(message) and len(str(info.value)) < 1000


def test_partial_json_round_trip(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"threshold": 0.7, "high_threshold": None}))
    s = load_settings(path, base=preset("paper"))
    assert s.threshold == 0.7 and s.ransac_iterations == 50
    path.write_text("{not json")
    with pytest.raises(SettingsError, match="not valid JSON"):
        load_settings(path)
    path.write_text('{"threshold": 5}')   # a value out of range names the file it came from
    with pytest.raises(SettingsError, match=rf"^{re.escape(str(path))}: threshold must be between"):
        load_settings(path)
    path.write_text('{"threshold": NaN}')
    with pytest.raises(SettingsError, match="finite"):
        load_settings(path)


def test_schema_covers_every_field_with_help_and_range():
    schema = {e["name"]: e for e in settings_schema()}
    assert set(schema) == set(Settings().to_dict())
    for e in schema.values():
        assert e["help"] and e["group"]
        if e["type"] in ("int", "float"):
            assert e["min"] <= (e["default"] if e["default"] is not None else e["min"]) <= e["max"]
        if e["type"] == "choice":
            assert e["default"] in e["choices"]
    assert schema["ransac_iterations"]["type"] == "int"
    assert schema["threshold"]["type"] == "float"
    assert schema["full_frame_fallback"]["type"] == "bool"
    assert all(isinstance(p, Settings) for p in PRESETS.values())


@pytest.mark.parametrize("name, value", [("candidates", 2.0), ("seed", 1.0), ("ransac_iterations", 100.0)])
def test_whole_numbers_written_as_floats_are_held_as_ints(name, value):
    # JSON writers and sliders send 2.0 for 2; the pipeline slices and counts with these values.
    for s in (Settings.from_dict({name: value}), Settings().replace(**{name: value})):
        held = getattr(s, name)
        assert type(held) is int and held == value
    assert type(Settings.from_dict({"threshold": 0.5}).threshold) is float


def test_settings_saved_from_the_api_work_as_a_settings_file(tmp_path):
    """`GET /api/settings` answers {"version", "settings"}; saved as a file it was "unknown setting(s)"."""
    path = tmp_path / "settings.json"
    path.write_text(json.dumps({"version": 7, "settings": preset("paper").to_dict()}))
    assert load_settings(path) == preset("paper")
