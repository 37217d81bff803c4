"""The state directory: what `signpose serve` keeps across restarts.

Layout (every file name is chosen by the server, never by a client)::

    settings.json           the current settings; a plain settings file (`--settings` reads it)
    settings.replaced-<UTC time>.json
                            settings `--settings` replaced, as they were in settings.json (`--settings` reads it,
                            unless settings.json was damaged: then it is kept as it was, to mend by hand)
    camera.json             {fx, fy, cx, cy, dist, width, height, source}; absent: EXIF or assumed per image
    camera.replaced-<UTC time>.json
                            a camera `--camera` replaced, as it was in camera.json (`--camera` reads it)
    assumed_fov.json        {"hfov_deg": float}: the field of view assumed without camera or EXIF; absent: 60°
    library/library.json    a complete sign library (`signpose recognize --library <state>/library`
                            works), plus "copied_from": the library folder it started as a copy of
    library/<image files>
    images/index.json       [{"id", "name", "expected", "file", "media_type"}] in the order listed (the order chosen)
    images/<id>.<ext>       the original uploaded bytes

Every write is atomic (temporary file in the same folder, fsync, rename, fsync the folder), so a
crash or power cut leaves either the old or the new version of a file, never a torn one. Files
are written before the index that names them and removed after it, so the index never names a
missing file; orphans left by a crash are swept on the next start.
"""

from __future__ import annotations

import contextlib
import json
import operator
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TypeVar

from pipeline.camera import ASSUMED_HFOV_DEG, Camera, CameraError, camera_from_json, check_hfov
from pipeline.jsonfile import JsonError, parse_json
from pipeline.library import Library, LibraryError, load_library
from pipeline.settings import Settings, SettingsError, load_settings

TMP_SUFFIX = ".tmp"
T = TypeVar("T")


class StateError(ValueError):
    """A state directory that cannot be used; the message names the file and what to do."""


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: Path, data: bytes) -> None:
    """Replace `path` with `data` so that readers (and a crash) see the old or the new file, never a mix."""
    if not path.parent.is_dir():
        path.parent.mkdir(parents=True, exist_ok=True)
        _fsync_dir(path.parent.parent)  # else a power cut could lose the new folder with all in it
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write(path, (json.dumps(data, ensure_ascii=False, indent=2) + "\n").encode("utf-8"))


def remove_file(path: Path) -> None:
    """Delete `path` (if present) and make the deletion durable."""
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
        _fsync_dir(path.parent)


def unused_path(folder: Path, stem: str, suffix: str) -> Path:
    """`folder/<stem><suffix>`, or `<stem>-2<suffix>`, `-3`, ... when taken: a backup never overwrites another."""
    path, n = folder / f"{stem}{suffix}", 1
    while path.exists():
        n += 1
        path = folder / f"{stem}-{n}{suffix}"
    return path


def same_intrinsics(a: Camera, b: Camera) -> bool:
    """Whether `a` and `b` are the same camera, wherever each was read from (`source` aside)."""
    return {**a.to_json(), "source": None} == {**b.to_json(), "source": None}


@dataclass(frozen=True)
class Replaced:
    """A state file that a start option replaced: where it is `kept` now, and whether it was `damaged`
    (unreadable) rather than a usable one that differed."""

    kept: Path
    damaged: bool


@dataclass(frozen=True)
class StoredImage:
    """One entry of `images/index.json`; `file` is a server-chosen name inside `images/`."""

    id: str
    name: str
    expected: str | None
    file: str
    media_type: str

    def to_json(self) -> dict:
        return {"id": self.id, "name": self.name, "expected": self.expected, "file": self.file,
                "media_type": self.media_type}


class StateDir:
    """Reads and atomically writes one state directory (see the module docstring for its layout)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).resolve()
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StateError(f"cannot create the state directory {self.root}: {exc.strerror}") from None
        self.settings_path = self.root / "settings.json"
        self.camera_path = self.root / "camera.json"
        self.fov_path = self.root / "assumed_fov.json"
        self.library_dir = self.root / "library"
        self.images_dir = self.root / "images"
        self.index_path = self.images_dir / "index.json"

    # ---- settings and camera

    def load_settings(self) -> Settings | None:
        if not self.settings_path.exists():
            return None
        try:
            return load_settings(self.settings_path)
        except SettingsError as exc:
            raise StateError(f"{exc}; fix or delete {self.settings_path} to start from the defaults") from None

    def save_settings(self, settings: Settings) -> None:
        atomic_write_json(self.settings_path, settings.to_dict())

    def replace_settings(self, settings: Settings) -> Replaced | None:
        """Save `settings` as the state's. Different settings held before (e.g. tuned in the page) are
        not lost: they are moved to a new `settings.replaced-<UTC time>.json` (None: nothing was moved)."""
        return self._replace(self.settings_path, self.load_settings, settings, operator.eq, self.save_settings)

    def load_camera(self) -> Camera | None:
        if not self.camera_path.exists():
            return None
        try:
            data = parse_json(self.camera_path.read_bytes())
            return camera_from_json(data, source=str(data.get("source") or "json"))
        except (JsonError, AttributeError, CameraError) as exc:
            raise StateError(f"{self.camera_path}: {exc}; fix or delete it to use an assumed camera") from None

    def save_camera(self, camera: Camera | None) -> None:
        if camera is None:
            remove_file(self.camera_path)
        else:
            atomic_write_json(self.camera_path, camera.to_json())

    def replace_camera(self, camera: Camera) -> Replaced | None:
        """Save `camera` as the state's camera. A different camera held before is not lost: it is
        moved to a new `camera.replaced-<UTC time>.json` (None: nothing was moved)."""
        return self._replace(self.camera_path, self.load_camera, camera, same_intrinsics, self.save_camera)

    def _replace(self, path: Path, load: Callable[[], T | None], new: T, same: Callable[[T, T], bool],
                 save: Callable[[T], None]) -> Replaced | None:
        """`save(new)` over `path`, whose content `load()` reads (None: no file). When that differs from
        `new` (not `same`), or is damaged (`load` raises StateError), the file is first moved, as it is, to
        a new `<stem>.replaced-<UTC time><suffix>` beside it, and said where; None when nothing was moved.
        A damaged file therefore neither stops a start that replaces it nor is lost."""
        try:
            held = load()
            keep, damaged = held is not None and not same(held, new), False
        except StateError:
            keep = damaged = True
        replaced = None
        if keep:
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            replaced = Replaced(unused_path(path.parent, f"{path.stem}.replaced-{stamp}", path.suffix), damaged)
            os.replace(path, replaced.kept)
            _fsync_dir(path.parent)
        save(new)
        return replaced

    def load_assumed_hfov(self) -> float:
        """The horizontal field of view (degrees) to assume for images without camera or EXIF: the one
        set, else ASSUMED_HFOV_DEG."""
        if not self.fov_path.exists():
            return ASSUMED_HFOV_DEG
        try:
            hfov = parse_json(self.fov_path.read_bytes())["hfov_deg"]
            return check_hfov(hfov)
        except (JsonError, TypeError, KeyError, CameraError) as exc:
            raise StateError(f"{self.fov_path}: {exc}; fix or delete it to assume "
                             f"{ASSUMED_HFOV_DEG:g}°") from None

    def save_assumed_hfov(self, hfov_deg: float) -> None:
        atomic_write_json(self.fov_path, {"hfov_deg": hfov_deg})

    # ---- library

    def library_origin(self) -> Path | None:
        try:
            meta = parse_json((self.library_dir / "library.json").read_bytes())
        except (OSError, JsonError):
            return None
        origin = meta.get("copied_from") if isinstance(meta, dict) else None
        return Path(origin) if isinstance(origin, str) else None

    def open_library(self, source: Path | None, default: Path) -> Library:
        """The state's library, first copied from `source` (or `default` on a fresh state).

        A `source` other than the one the state was copied from replaces the state's library
        (edits made to the old one are dropped).
        """
        meta = self.library_dir / "library.json"
        wanted = Path(source).resolve() if source is not None else None
        copy_from = None
        if not meta.exists():
            copy_from = wanted or Path(default).resolve()
        elif wanted is not None and wanted != self.library_origin():
            copy_from = wanted
        if copy_from is not None:
            try:
                library = load_library(copy_from)  # validate before replacing anything
            except LibraryError as exc:
                raise StateError(str(exc)) from None
            self._copy_library(library, copy_from)
        try:
            return load_library(self.library_dir)
        except LibraryError as exc:
            raise StateError(f"{exc}; delete {self.library_dir} to start again from --library") from None

    def _copy_library(self, library: Library, origin: Path) -> None:
        staging = Path(tempfile.mkdtemp(dir=self.root, prefix=".library.", suffix=TMP_SUFFIX))
        try:
            for sign in library.signs:
                shutil.copyfile(library.root / sign.image_file, staging / sign.image_file)
            (staging / "library.json").write_text(json.dumps(
                {"signs": [s.to_json() for s in library.signs], "copied_from": str(origin)},
                ensure_ascii=False, indent=2) + "\n", encoding="utf-8")
            for path in staging.iterdir():
                with open(path, "rb") as f:
                    os.fsync(f.fileno())
            _fsync_dir(staging)
            # A folder cannot be replaced atomically; move the old one aside first so a crash
            # leaves either it or the new copy in place (`sweep` removes the leftovers).
            old = self.root / f".library.old{TMP_SUFFIX}"
            shutil.rmtree(old, ignore_errors=True)
            if self.library_dir.exists():
                os.replace(self.library_dir, old)
            os.replace(staging, self.library_dir)
            _fsync_dir(self.root)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(staging, ignore_errors=True)

    def save_library(self, library: Library) -> None:
        """Rewrite `library/library.json` for the signs in `library` (their files must already be there)."""
        origin = self.library_origin()
        atomic_write_json(self.library_dir / "library.json", {
            "signs": [s.to_json() for s in library.signs],
            "copied_from": str(origin) if origin is not None else None,
        })

    def write_library_file(self, name: str, data: bytes) -> None:
        atomic_write(self.library_dir / name, data)

    def remove_library_file(self, name: str) -> None:
        remove_file(self.library_dir / name)

    # ---- images

    def load_images(self) -> list[StoredImage] | None:
        """The stored images in the order listed, or None for a state that never held any."""
        if not self.index_path.exists():
            return None
        try:
            entries = parse_json(self.index_path.read_bytes())
            return [StoredImage(**e) for e in entries]
        except (JsonError, TypeError) as exc:
            raise StateError(f"{self.index_path} is damaged ({exc}); delete {self.images_dir} to start "
                             "without images") from None

    def save_images(self, entries: list[StoredImage]) -> None:
        atomic_write_json(self.index_path, [e.to_json() for e in entries])

    def write_image(self, name: str, data: bytes) -> None:
        atomic_write(self.images_dir / name, data)

    def read_image(self, name: str) -> bytes:
        return (self.images_dir / name).read_bytes()

    def image_path(self, name: str) -> Path:
        return self.images_dir / name

    def remove_image(self, name: str) -> None:
        remove_file(self.images_dir / name)

    def sweep(self, images: list[StoredImage], library: Library) -> None:
        """Delete files no index names: leftovers of a crash between writing a file and its index."""
        keep_images = {e.file for e in images} | {self.index_path.name}
        keep_library = {s.image_file for s in library.signs} | {"library.json"}
        for folder, keep in ((self.images_dir, keep_images), (self.library_dir, keep_library)):
            if folder.is_dir():
                for path in folder.iterdir():
                    if path.name not in keep and path.is_file():
                        path.unlink()
        for path in self.root.glob(f".*{TMP_SUFFIX}"):
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink()
