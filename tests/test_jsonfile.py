"""Every JSON file a user hands over fails the same way: its loader's error, naming the file."""

import shutil

import pytest

from signpose.pipeline.evaluate import DatasetError, load_dataset
from signpose.pipeline.library import SAMPLE_LIBRARY, LibraryError, load_library
from signpose.pipeline.settings import SettingsError, load_settings

BOM = b"\xef\xbb\xbf"  # UTF-8's byte-order mark, which Windows editors (Notepad, PowerShell) begin files with

LOADERS = [  # (file name, loader given the folder, its error)
    ("settings.json", lambda d: load_settings(d / "settings.json"), SettingsError),
    ("library.json", load_library, LibraryError),
    ("truth.json", load_dataset, DatasetError),
]


@pytest.mark.parametrize("content, message", [(b'{"a": ', "is not valid JSON"), (b"\xff\xfe{}", "is not valid JSON"),
                                              # said so, not "Expecting value: line 1 column 1 (char 0)"
                                              (b"", r"is an empty file \(nothing in it to read\)"),
                                              (BOM + b" \r\n", r"is an empty file \(nothing in it to read\)"),
                                              # a RecursionError's traceback (an HTTP 500 in the page's import)
                                              (b"[" * 100_000 + b"]" * 100_000, "is JSON nested too deep to read"),
                                              # a ValueError's traceback: Python reads no int of 4301 digits
                                              (b'{"a": ' + b"1" * 5000 + b"}",
                                               "is JSON with a whole number of over 4300 digits"),
                                              # read as the last one without a word
                                              (b'{"a": [{"threshold": 0.7, "threshold": 0.8}]}',
                                               "is JSON in which the key 'threshold' is given twice in one object: "
                                               "keep the one meant")],
                         ids=["cut short", "not UTF-8", "empty", "blank", "nested deep", "long number", "key twice"])
@pytest.mark.parametrize("name, load, error", LOADERS, ids=[n for n, _, _ in LOADERS])
def test_bad_json_is_the_loaders_error_naming_the_file(tmp_path, name, load, error, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(error, match=message) as info:
        load(tmp_path)
    assert name in str(info.value)


def test_missing_settings_file_names_it(tmp_path):
    with pytest.raises(SettingsError, match="settings file .*nope.json not found"):
        load_settings(tmp_path / "nope.json")


def with_bom(path):
    path.write_bytes(BOM + path.read_bytes())


@pytest.mark.parametrize("name", ["settings.json", "library.json", "truth.json"])
def test_a_json_file_saved_with_a_byte_order_mark_is_read(tmp_path, name):
    """`--settings bom.json` failed with "Unexpected UTF-8 BOM" while the page's import took the same file."""
    if name == "settings.json":
        (tmp_path / name).write_text('{"threshold": 0.7}', encoding="utf-8")
        with_bom(tmp_path / name)
        assert load_settings(tmp_path / name).threshold == 0.7
    elif name == "library.json":
        shutil.copytree(SAMPLE_LIBRARY, tmp_path / "library")
        with_bom(tmp_path / "library" / name)
        assert load_library(tmp_path / "library").ids == load_library(SAMPLE_LIBRARY).ids
    else:
        sample = SAMPLE_LIBRARY.parent / "scenes"
        shutil.copytree(sample, tmp_path / "scenes")
        with_bom(tmp_path / "scenes" / name)
        assert len(load_dataset(tmp_path / "scenes").samples) == len(load_dataset(sample).samples)
