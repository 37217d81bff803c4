"""Sign libraries (`pipeline/library.py`): what a library.json entry and a sign image may be."""

from __future__ import annotations

import json
import shutil

import pytest

from pipeline.library import SAMPLE_LIBRARY, LibraryError, load_library, validate_sign_entry


def entry(**sizes) -> dict:
    return {"id": "a", "image": "a.png", **sizes}


@pytest.mark.parametrize("sizes, words", [
    ({"width_m": 30}, "typed in centimetres or millimetres? 30 cm is 0.3 m; 30 mm is 0.03 m; give it in metres"),
    ({"width_m": 300}, "typed in centimetres or millimetres? 300 cm is 3 m; 300 mm is 0.3 m"),  # was "not mm?"
    ({"width_m": 12}, "typed in centimetres? 12 cm is 0.12 m; give it in metres"),
    ({"width_m": 0.6, "height_m": 24}, "height_m = 24 m is larger than any indoor sign"),
    ({"width_m": 50_000}, "larger than any indoor sign (signs are 0.02-10 m): give it in metres"),
    ({"width_m": 0.0003}, "width_m = 0.0003 m is 0.3 mm, smaller than any sign (signs are 0.02-10 m): converted to "
                          "metres twice?"),
])
def test_a_size_in_the_wrong_unit_is_refused_naming_the_slip(sizes, words):
    """A width in centimetres (30 for an A4 sign) was taken as 30 m, and 0.0003 m as a sign, while 300
    was refused: every pose from such a sign is off by the same factor."""
    with pytest.raises(LibraryError) as refused:
        validate_sign_entry(entry(**sizes), "sign #0")
    assert str(refused.value).startswith("sign #0: ") and words in str(refused.value)


@pytest.mark.parametrize("width_m", [0.02, 0.6, 10])
def test_sizes_of_indoor_signs_are_taken(width_m):
    assert validate_sign_entry(entry(width_m=width_m), "sign #0")["width_m"] == width_m


def test_a_library_file_with_a_size_in_centimetres_is_refused(tmp_path):
    shutil.copytree(SAMPLE_LIBRARY, tmp_path / "library")
    meta = tmp_path / "library" / "library.json"
    signs = json.loads(meta.read_text(encoding="utf-8"))["signs"]
    signs[1] |= {"width_m": 60, "height_m": 24}
    meta.write_text(json.dumps({"signs": signs}), encoding="utf-8")
    with pytest.raises(LibraryError, match=r"sign #1: width_m = 60 m .* 60 cm is 0\.6 m"):
        load_library(tmp_path / "library")
