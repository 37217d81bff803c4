"""Reading the JSON files users hand to signpose (settings, library.json, truth.json, the page's settings import)."""

from __future__ import annotations

import json
import reprlib
import sys
from pathlib import Path

EMPTY_FILE = "an empty file (nothing in it to read)"


class JsonError(ValueError):
    """JSON bytes that cannot be read; the message ("not valid JSON: ...", or EMPTY_FILE) says why and
    where, but not which file: the caller names it."""


def parse_json(data: bytes) -> object:
    """The document in JSON `data`: UTF-8 text, with or without the byte-order mark (BOM) that
    Windows editors (Notepad, PowerShell) begin it with, as browsers and `json.loads` on bytes
    accept it. Raises JsonError for nothing but blanks, bytes that are not UTF-8, text that is not
    JSON, JSON that gives an object a key twice (`_object`), or JSON Python cannot hold: nested deeper
    than its stack, or a whole number of thousands of digits (no file of signpose's has either; each
    was a traceback, and an HTTP 500)."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise JsonError(f"not valid JSON: {exc}") from None
    if not text.strip():
        raise JsonError(EMPTY_FILE)
    try:
        return json.loads(text, object_pairs_hook=_object)
    except json.JSONDecodeError as exc:
        raise JsonError(f"not valid JSON: {exc}") from None
    except JsonError:  # a key given twice, which is a ValueError too
        raise
    except ValueError:  # Python reads no whole number of more than sys.get_int_max_str_digits() digits
        raise JsonError(f"JSON with a whole number of over {sys.get_int_max_str_digits()} digits, which no value of "
                        "signpose's has") from None
    except RecursionError:
        raise JsonError("JSON nested too deep to read (hundreds of levels), where nothing signpose reads is more "
                        "than a few levels deep") from None


def key_given_twice(key: object) -> str:
    """Why a file (JSON, a camera file's YAML) whose object gives `key` twice is refused. Readers keep one
    of the two without a word (Python's json the last, OpenCV's FileStorage the first): a setting typed
    twice, or a camera value pasted below the old one, would be read as whichever that is."""
    return f"the key {reprlib.repr(key)} is given twice in one object: keep the one meant"


def _object(pairs: list[tuple[str, object]]) -> dict:
    """The JSON object of key-value `pairs`, in order; JsonError naming a key given twice."""
    obj: dict = {}
    for key, value in pairs:
        if key in obj:
            raise JsonError(f"JSON in which {key_given_twice(key)}")
        obj[key] = value
    return obj


def read_json(path: Path, error: type[Exception], what: str = "") -> object:
    """The document in the JSON file at `path` (as `parse_json` reads it).

    A missing or empty file, bytes that are not UTF-8 or text that is not JSON raise `error` with a
    message naming the file (prefixed by `what`, e.g. "settings file").
    """
    name = f"{what} {path}".strip()
    try:
        return parse_json(path.read_bytes())
    except FileNotFoundError:
        raise error(f"{name} not found") from None
    except JsonError as exc:
        raise error(f"{name} is {exc}") from None
