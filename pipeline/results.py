"""Results kept on disk between runs (`--results DIR`), so that a run cut short continues where it stopped.

One JSON file per image (or per frame range of a flight) and key: ``DIR/<content hash>/<key>.json``. The
content hash is the SHA-256 of the file's bytes (of a flight's files), so a renamed or moved file keeps its
results and an edited one does not. The key is a hash of what else the result depends on: the settings that
feed the stages the result comes from (from each setting's declared stages, `settings.Settings` metadata, so a
setting added there reaches the keys by itself), the library's signs, the camera and what the caller names
(the kind of result, its limits). A changed setting changes the key of the results it feeds only; results
under other keys stay, and going back to earlier settings finds them.

Each file is written to a temporary name beside it and renamed into place, so a run killed while writing
leaves either the whole result or none. A file that cannot be read back is computed again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .library import Library
from .settings import Settings

# Bumped when what a stored result holds, or how it is computed, changes: older files are then not read.
FORMAT = 2


def content_hash(data: bytes) -> str:
    """SHA-256 of `data`, hex."""
    return hashlib.sha256(data).hexdigest()


def files_hash(files: Iterable[tuple[str, bytes]]) -> str:
    """SHA-256 over (relative name, bytes) pairs, in the order given: a flight of several files."""
    digest = hashlib.sha256()
    for name, data in files:
        encoded = name.encode()
        digest.update(len(encoded).to_bytes(8, "little") + encoded + len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()


def affecting_settings(settings: Settings, stages: Iterable[str]) -> dict[str, Any]:
    """{name: value} of the settings that feed any of `stages` (names of `stages.ALL_STAGES`), as each
    setting's metadata declares, in `Settings`' field order."""
    wanted = set(stages)
    return {f.name: getattr(settings, f.name) for f in dataclasses.fields(Settings)
            if wanted.intersection(f.metadata["stages"])}


def library_fingerprint(library: Library) -> str:
    """SHA-256 of what the library's signs are (ids, sizes, kinds, images), not where the folder is."""
    digest = hashlib.sha256()
    for sign in library.signs:
        described = json.dumps([sign.id, sign.name, sign.text, sign.width_m, sign.height_m, sign.kind,
                                sign.min_text_correlation, list(sign.image.shape)])
        digest.update(described.encode())
        digest.update(sign.image.tobytes())
    return digest.hexdigest()


def result_key(settings: Settings, stages: Iterable[str], context: Mapping[str, Any]) -> str:
    """The key of a result computed by `stages` under `settings`, with `context` (JSON values: the kind of
    result, the library's fingerprint, the camera, limits) naming the rest it depends on."""
    described = {"format": FORMAT, "settings": affecting_settings(settings, stages), **context}
    return hashlib.sha256(json.dumps(described, sort_keys=True).encode()).hexdigest()[:32]


class ResultStore:
    """Results in the folder `root` (made when missing), one JSON file per content hash and key."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, content: str, key: str) -> Path:
        return self.root / content / f"{key}.json"

    def get(self, content: str, key: str) -> Any | None:
        """The result stored for `content` under `key`; None when there is none or it cannot be read."""
        try:
            return json.loads(self.path(content, key).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def put(self, content: str, key: str, value: Any) -> None:
        """Store the JSON `value` for `content` under `key`, atomically (a temporary file renamed into place)."""
        path = self.path(content, key)
        path.parent.mkdir(exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=".part")
        try:
            with os.fdopen(handle, "w", encoding="utf-8") as out:
                json.dump(value, out)
            os.replace(temporary, path)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise
