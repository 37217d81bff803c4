"""Every JSON file a user hands over fails the same way: its loader's error, naming the file."""

import pytest

from pipeline.evaluate import DatasetError, load_dataset
from pipeline.library import LibraryError, load_library
from pipeline.settings import SettingsError, load_settings

LOADERS = [  # (file name, loader given the folder, its error)
    ("settings.json", lambda d: load_settings(d / "settings.json"), SettingsError),
    ("library.json", load_library, LibraryError),
    ("truth.json", load_dataset, DatasetError),
]


@pytest.mark.parametrize("content, message", [(b'{"a": ', "is not valid JSON"), (b"\xff\xfe{}", "is not valid JSON")])
@pytest.mark.parametrize("name, load, error", LOADERS, ids=[n for n, _, _ in LOADERS])
def test_bad_json_is_the_loaders_error_naming_the_file(tmp_path, name, load, error, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(error, match=message) as info:
        load(tmp_path)
    assert name in str(info.value)


def test_missing_settings_file_names_it(tmp_path):
    with pytest.raises(SettingsError, match="settings file .*nope.json not found"):
        load_settings(tmp_path / "nope.json")
