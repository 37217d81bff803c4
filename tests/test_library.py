"""Sign libraries (`pipeline/library.py`): what a library.json entry and a sign image may be."""

from __future__ import annotations

import itertools
import json
import shutil

import cv2
import numpy as np
import pytest

from signpose.pipeline.library import (MAX_LIKENESS, SAMPLE_LIBRARY, LibraryError, alike_sign, likeness, load_library,
                              validate_sign_entry)
from tests.support.scene_images import DECOYS, plaque_of


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


HUGE = "x" * 1_000_000


@pytest.mark.parametrize("fields, words", [
    ({"id": HUGE}, "id 'xxxxxxxxxxxx...xxxxxxxxxxxxx' must be 1-64 characters"),
    ({"id": list(range(10_000))}, "id [0, 1, 2, 3, 4, 5, ...] must be 1-64 characters"),
    ({"image": HUGE}, "image 'xxxxxxxxxxxx...xxxxxxxxxxxxx' must be a plain file name (at most 255 characters)"),
    ({"image": "x" * 256 + ".png"}, "must be a plain file name (at most 255 characters)"),
    ({"width_m": list(range(10_000))}, "width_m must be a positive number of metres; got [0, 1, 2, 3, 4, 5, ...]"),
    ({"width_m": 0.3, "height_m": HUGE}, "height_m must be a positive number of metres; got 'xxxxxxxxxxxx...xxxxx"),
])
def test_a_library_file_error_quotes_a_huge_value_shortened(tmp_path, fields, words):
    """library.json's values were quoted whole: a megabyte id, or a file name no file system holds (as the
    error reading it named it), was a megabyte error line."""
    (tmp_path / "library.json").write_text(json.dumps({"signs": [{"id": "a", "image": "a.png", "width_m": 0.3,
                                                                  **fields}]}))
    with pytest.raises(LibraryError) as refused:
        load_library(tmp_path)
    assert words in str(refused.value) and len(str(refused.value)) < 300

def test_a_library_file_with_a_size_in_centimetres_is_refused(tmp_path):
    shutil.copytree(SAMPLE_LIBRARY, tmp_path / "library")
    meta = tmp_path / "library" / "library.json"
    signs = json.loads(meta.read_text(encoding="utf-8"))["signs"]
    signs[1] |= {"width_m": 60, "height_m": 24}
    meta.write_text(json.dumps({"signs": signs}), encoding="utf-8")
    with pytest.raises(LibraryError, match=r"sign #1: width_m = 60 m .* 60 cm is 0\.6 m"):
        load_library(tmp_path / "library")


@pytest.mark.parametrize("change, words", [
    (lambda meta: meta["signs"][1].update(heigth_m=0.5),
     " sign #1: unknown key(s) 'heigth_m': correct or remove them; the keys read are id, name, text, "
     "image, width_m, height_m, kind, min_text_correlation"),
    (lambda meta: meta.update(sign=[]),
     ": unknown key(s) 'sign': correct or remove them; the keys read are signs, copied_from, "
     "fingerprint, added"),
    (lambda meta: meta.update(sign=meta.pop("signs")),   # the only list misspelt: its name said, not "no signs"
     ": unknown key(s) 'sign': correct or remove them; the keys read are signs, copied_from, "
     "fingerprint, added"),
])
def test_a_library_file_with_an_unknown_key_is_refused_naming_it(tmp_path, change, words):
    """A typo such as "heigth_m" was dropped without a word, and the height taken from the image's aspect."""
    shutil.copytree(SAMPLE_LIBRARY, tmp_path / "library")
    path = tmp_path / "library" / "library.json"
    meta = json.loads(path.read_text(encoding="utf-8"))
    change(meta)
    path.write_text(json.dumps(meta), encoding="utf-8")
    with pytest.raises(LibraryError) as refused:
        load_library(tmp_path / "library")
    assert str(refused.value) == f"{path}{words}"


def test_a_library_given_as_its_file_or_a_missing_folder_says_which(tmp_path):
    with pytest.raises(LibraryError, match="is a file: give the sign library's folder"):
        load_library(SAMPLE_LIBRARY / "library.json")
    with pytest.raises(LibraryError, match="no such folder"):
        load_library(tmp_path / "nowhere")


def test_a_library_file_listing_a_copy_of_a_sign_is_refused_naming_both(tmp_path):
    """The page refused a copy of a sign under another id; library.json took it, and neither copy
    was recognised again (their margin over each other is nil)."""
    shutil.copytree(SAMPLE_LIBRARY, tmp_path / "library")
    meta = tmp_path / "library" / "library.json"
    signs = json.loads(meta.read_text(encoding="utf-8"))["signs"]
    signs.append(signs[0] | {"id": "entrance"})
    meta.write_text(json.dumps({"signs": signs}), encoding="utf-8")
    with pytest.raises(LibraryError, match=rf"sign #3 \('entrance'\) cannot be told apart from '{signs[0]['id']}' "
                                           r"\(likeness 1\.00; .*keep one of them"):
        load_library(tmp_path / "library")


def copies(image: np.ndarray) -> dict[str, np.ndarray]:
    """`image` as a team might add it again: re-encoded, at another size, turned, with a margin, at a slant."""
    h, w = image.shape
    corners = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    slant = cv2.getPerspectiveTransform(corners, corners + np.float32([[0.06 * w, 0], [0, 0.04 * h], [0, 0], [0, 0]]))
    return {"jpeg": cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 70])[1], cv2.IMREAD_GRAYSCALE),
            "half size": cv2.resize(image, (w // 2, h // 2), interpolation=cv2.INTER_AREA),
            "turned": np.ascontiguousarray(image[::-1, ::-1]),
            "margin": cv2.copyMakeBorder(image, h // 20, h // 20, w // 20, w // 20, cv2.BORDER_CONSTANT, value=255),
            "slant": cv2.warpPerspective(image, slant, (w, h), borderValue=255),
            "lit unevenly": (image * np.linspace(0.7, 1.0, w)[None]).astype(np.uint8)}


def test_copies_of_a_sign_are_alike_and_other_signs_are_not():
    """Signs that features cannot tell apart (a copy of one added under another id) are what `alike_sign`
    finds; the sample signs, and other words sharing one with them, stay far below the bar."""
    library = load_library(SAMPLE_LIBRARY)
    for sign in library.signs:
        for what, copy in copies(sign.image).items():
            found = alike_sign(copy, library.signs)
            assert found is not None and found[0] is sign, (sign.id, what)
    for a, b in itertools.permutations(library.signs, 2):
        assert likeness(a.image, b.image) < MAX_LIKENESS - 0.5, (a.id, b.id)
    for text in DECOYS:
        assert alike_sign(plaque_of(text).image, library.signs) is None, text
