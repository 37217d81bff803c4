"""Reading the JSON files users hand to signpose (settings, library.json, truth.json, the page's settings import)."""

from __future__ import annotations

import json
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
    JSON, or JSON Python cannot hold: nested deeper than its stack, or a whole number of thousands of
    digits (no file of signpose's has either; each was a traceback, and an HTTP 500)."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise JsonError(f"not valid JSON: {exc}") from None
    if not text.strip():
        raise JsonError(EMPTY_FILE)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise JsonError(f"not valid JSON: {exc}") from None
    except ValueError:  # Python reads no whole number of more than sys.get_int_max_str_digits() digits
        raise JsonError(f"JSON with a whole number of over {sys.get_int_max_str_digits()} digits, which no value of "
                        "signpose's has") from None
    except RecursionError:
        raise JsonError("JSON nested too deep to read (hundreds of levels), where nothing signpose reads is more "
                        "than a few levels deep") from None


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
