"""Reading the JSON files users hand to signpose (settings, library.json, truth.json)."""

from __future__ import annotations

import json
from pathlib import Path


def read_json(path: Path, error: type[Exception], what: str = "") -> object:
    """The document in the JSON file at `path`.

    A missing file, bytes that are not UTF-8 or text that is not JSON raise `error` with a
    message naming the file (prefixed by `what`, e.g. "settings file").
    """
    name = f"{what} {path}".strip()
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{name} not found") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{name} is not valid JSON: {exc}") from None
