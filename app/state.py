"""The state directory: what `signpose serve` keeps across restarts.

Layout (every file name is chosen by the server, never by a client)::

    settings.json           the current settings; a plain settings file (`--settings` reads it)
    settings.replaced-<UTC time>.json
                            settings `--settings` replaced, as they were in settings.json (`--settings` reads it,
                            unless settings.json was damaged: then it is kept as it was, to mend by hand)
    camera.json             {fx, fy, cx, cy, dist, width, height, source}, and roi and binning_x, binning_y for
                            part of a sensor (Camera.file_json); absent: EXIF or assumed per image
    camera.replaced-<UTC time>.json
                            a camera `--camera` replaced, as it was in camera.json (`--camera` reads it)
    assumed_fov.json        {"hfov_deg": float}: the field of view assumed without camera or EXIF; absent: 60°
    library/library.json    a complete sign library (`signpose recognize --library <state>/library`
                            works), plus "copied_from": the library folder it was last copied from,
                            "fingerprint": that folder's content then (`library_fingerprint`), and
                            "added": the ids of the signs added through the page or API since
    library/<image files>
    library.replaced-<UTC time>/
                            the state's library as it was before `--library` changed it (a library
                            folder: `--library` reads it)
    images/index.json       [{"id", "name", "expected", "file", "media_type"}] in the order listed (the order chosen)
    map.yaml                the sign map held (a map file: `--map` reads it); absent: no map
    map.origin.json         {"map_sha256", "source", "report"}: where map.yaml came from, and for a map built
                            by the server its build's report (sign_maps.BuildReport); used only while
                            map_sha256 is map.yaml's
    map.replaced-<UTC time>.yaml
                            a map `--map` replaced, or one that no longer fits the library, as it was in map.yaml
    images/<id>.<ext>       the original uploaded bytes

Every write is atomic (temporary file in the same folder, fsync, rename, fsync the folder), so a
crash or power cut leaves either the old or the new version of a file, never a torn one. Files
are written before the index that names them and removed after it, so the index never names a
missing file; orphans left by a crash are swept on the next start.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import operator
import os
import secrets
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Collection
from typing import Any, Callable, TypeVar

import numpy as np

from signpose.pipeline.camera import ASSUMED_HFOV_DEG, Camera, CameraError, camera_from_json, check_hfov
from signpose.pipeline.jsonfile import JsonError, parse_json
from signpose.pipeline.library import Library, LibraryError, LibrarySign, alike_sign, load_library
from signpose.pipeline.settings import Settings, SettingsError, load_settings
from signpose.pipeline.sign_map import MapError, SignMap, load_sign_map

TMP_SUFFIX = ".tmp"
LIBRARY_ASIDE = f".library.old{TMP_SUFFIX}"  # the state's library while its replacement is moved in
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


def json_bytes(data: Any) -> bytes:
    """`data` as the state's JSON files hold it: UTF-8, indented, one final newline."""
    return (json.dumps(data, ensure_ascii=False, indent=2) + "\n").encode("utf-8")


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write(path, json_bytes(data))


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


def replaced_path(folder: Path, stem: str, suffix: str) -> Path:
    """A new `folder/<stem>.replaced-<UTC time><suffix>`: where a start option keeps what it replaced."""
    return unused_path(folder, f"{stem}.replaced-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}", suffix)


def same_intrinsics(a: Camera, b: Camera) -> bool:
    """Whether `a` and `b` are the same camera file, wherever each was read from (`source` aside)."""
    return {**a.file_json(), "source": None} == {**b.file_json(), "source": None}


@dataclass(frozen=True)
class Replaced:
    """A state file that a start option replaced: where it is `kept` now, and whether it was `damaged`
    (unreadable) rather than a usable one that differed."""

    kept: Path
    damaged: bool


@dataclass(frozen=True)
class KeptMap:
    """Where the state's sign map came from (`source`, said for people) and, for a map the server
    built, its build's `report` as JSON (sign_maps.BuildReport.to_json); None: none."""

    source: str
    report: dict | None


@dataclass(frozen=True)
class LibraryRecord:
    """What the state's `library.json` records of where its signs came from: the folder it was last
    copied from and that folder's `library_fingerprint` then, the ids of the signs added through the
    page or API since (`added`), and the ids it lists. None where an older state wrote nothing (or the
    file cannot be read): unknown."""

    copied_from: Path | None
    fingerprint: str | None
    added: frozenset[str] | None
    ids: tuple[str, ...]


@dataclass(frozen=True)
class LibraryMerge:
    """The state's library merged with a library folder read again (`merge_library`): the signs of the
    state's library `carried` over (those added in the page or API), and for the log, each "id (what)":
    the folder's signs `changed` from the state's, the ids of its signs the state's library lacked
    (`back`: new in the folder, or removed in the page since), the `kept` added ones and the state's
    signs `dropped`."""

    carried: list[LibrarySign]
    changed: list[str]
    back: list[str]
    kept: list[str]
    dropped: list[str]


@dataclass(frozen=True)
class LibraryReread:
    """What a start with `--library folder` did to the state's library: read `folder` again (`why`),
    merged it (`merge`), and kept the state's library as it was in `kept` (None: nothing of it was
    dropped or changed), `damaged` when that could not be read."""

    folder: Path
    why: str
    merge: LibraryMerge
    kept: Path | None
    damaged: bool

    def describe(self) -> str:
        """The one log line saying what happened, and where the state's library as it was is kept."""
        m = self.merge
        parts = [f"--library {self.folder} was read again ({self.why})"]
        if not (m.changed or m.back or m.dropped):
            parts.append("no sign changed")
        for title, items in (("changed", m.changed),
                             ("from the folder (new there, or removed in the page since)", m.back),
                             ("kept, as added in the page", m.kept), ("dropped", m.dropped)):
            if items:
                parts.append(f"{title}: {', '.join(items)}")
        if self.kept is not None:
            parts.append(f"the state's library, which could not be read, is kept as it was in {self.kept}"
                         if self.damaged else f"the state's library as it was is kept in {self.kept} (to use it "
                         f"again, start with --library {self.kept})")
        return "; ".join(parts)


def text_sha256(text: str) -> str:
    """SHA-256 (hex) of `text` in UTF-8."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def library_fingerprint(library: Library) -> str:
    """SHA-256 (hex) of a library folder's content as `library` read it: its library.json and each
    sign's image file, bytes as on disk. Any edit to a size, a name or an image changes it."""
    digest = hashlib.sha256()
    for name in ["library.json", *dict.fromkeys(s.image_file for s in library.signs)]:
        data = (library.root / name).read_bytes()
        digest.update(f"{name}\0{len(data)}\0".encode())
        digest.update(data)
    return digest.hexdigest()


def library_meta(signs: list[LibrarySign], origin: Path | None, fingerprint: str | None,
                 added: list[str] | None) -> dict:
    """The state's `library.json`: a library file (`signpose recognize --library` reads it) with its record."""
    return {"signs": [s.to_json() for s in signs], "copied_from": str(origin) if origin is not None else None,
            "fingerprint": fingerprint, "added": added}


def sign_changes(old: LibrarySign, new: LibrarySign) -> str:
    """How `new` differs from `old` (same id), e.g. "width_m from 1.2 to 0.6 m, image"; "" when in nothing."""
    changes = [f"{key} from {getattr(old, key):g} to {getattr(new, key):g} m" for key in ("width_m", "height_m")
               if getattr(old, key) != getattr(new, key)]
    changes += [key for key in ("name", "text") if getattr(old, key) != getattr(new, key)]
    if old.image.shape != new.image.shape or not np.array_equal(old.image, new.image):
        changes.append("image")
    return ", ".join(changes)


def merge_library(held: Library | None, incoming: Library, added: frozenset[str] | None) -> LibraryMerge:
    """The state's library `held` (None: unreadable) merged into the folder's `incoming`: every sign
    of `incoming` is used; of `held`'s, those `added` in the page are carried over unless `incoming`
    has a sign of that id (the folder's wins) or one they cannot be told apart from (`alike_sign`).
    With `added` unknown (None: an older state), every sign the folder lacks counts as added."""
    held_signs = {s.id: s for s in held.signs} if held is not None else {}
    changed, back, dropped = [], [], []
    for sign in incoming.signs:
        old = held_signs.get(sign.id)
        if old is None:
            back.append(sign.id)
        elif changes := sign_changes(old, sign):
            if added is not None and sign.id in added:
                dropped.append(f"{sign.id} (added in the page; the folder's sign of that id is used: {changes})")
            else:
                changed.append(f"{sign.id} ({changes})")
    carried: list[LibrarySign] = []
    for sign in held_signs.values():
        if sign.id in incoming.ids:
            continue
        if added is not None and sign.id not in added:
            dropped.append(f"{sign.id} (not in the folder)")
        elif alike := alike_sign(sign.image, [*incoming.signs, *carried]):
            dropped.append(f"{sign.id} (added in the page; too like {alike[0].id} to be told apart)")
        else:
            carried.append(sign)
    return LibraryMerge(carried, changed, back, [s.id for s in carried], dropped)


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
        self.map_path = self.root / "map.yaml"
        self.map_origin_path = self.root / "map.origin.json"

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
            data: Any = parse_json(self.camera_path.read_bytes())  # a dict, or the errors below say what is wrong
            return camera_from_json(data, source=str(data.get("source") or "json"))
        except (JsonError, AttributeError, CameraError) as exc:
            raise StateError(f"{self.camera_path}: {exc}; fix or delete it to use an assumed camera") from None

    def save_camera(self, camera: Camera | None) -> None:
        if camera is None:
            remove_file(self.camera_path)
        else:
            atomic_write_json(self.camera_path, camera.file_json())

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
            replaced = Replaced(replaced_path(path.parent, path.stem, path.suffix), damaged)
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
            document: Any = parse_json(self.fov_path.read_bytes())  # a dict, or the errors below say what is wrong
            hfov = document["hfov_deg"]

            return check_hfov(hfov)
        except (JsonError, TypeError, KeyError, CameraError) as exc:
            raise StateError(f"{self.fov_path}: {exc}; fix or delete it to assume "
                             f"{ASSUMED_HFOV_DEG:g}°") from None

    def save_assumed_hfov(self, hfov_deg: float) -> None:
        atomic_write_json(self.fov_path, {"hfov_deg": hfov_deg})

    # ---- sign map

    def load_map(self, library_ids: Collection[str]) -> SignMap | None:
        """The sign map kept (None: none); StateError when it cannot be read or names a sign not in `library_ids`."""
        if not self.map_path.exists():
            return None
        try:
            return load_sign_map(self.map_path, library_ids)
        except MapError as exc:
            raise StateError(f"{exc}; fix or delete it to start without a sign map") from None

    def _map_text(self) -> str | None:
        return self.map_path.read_text(encoding="utf-8") if self.map_path.exists() else None

    def save_map(self, text: str | None, origin: KeptMap | None = None) -> None:
        """Keep the map file `text` as the state's sign map, and its `origin` (None: none kept); None: no map."""
        remove_file(self.map_origin_path)
        if text is None:
            remove_file(self.map_path)
            return
        atomic_write(self.map_path, text.encode("utf-8"))
        if origin is not None:
            atomic_write_json(self.map_origin_path, {"map_sha256": text_sha256(text), "source": origin.source,
                                                     "report": origin.report})

    def load_map_origin(self) -> KeptMap | None:
        """What `save_map` kept of where the state's map came from; None when nothing was, or it was
        kept for another map (a crash between the two writes, the file edited by hand) or cannot be read."""
        text = self._map_text()
        try:
            kept = parse_json(self.map_origin_path.read_bytes())
        except (OSError, JsonError):
            return None
        if text is None or not isinstance(kept, dict) or kept.get("map_sha256") != text_sha256(text):
            return None
        report = kept.get("report")
        return KeptMap(str(kept.get("source")), report if isinstance(report, dict) else None)

    def replace_map(self, text: str) -> Replaced | None:
        """Keep the map file `text` as the state's sign map. A different map kept before is not lost: it is
        moved to a new `map.replaced-<UTC time>.yaml` (None: nothing was moved)."""
        return self._replace(self.map_path, self._map_text, text, operator.eq, self.save_map)

    def set_map_aside(self) -> Path:
        """Move the state's map file, as it is, to a new `map.replaced-<UTC time>.yaml`; where it went."""
        kept = replaced_path(self.root, self.map_path.stem, self.map_path.suffix)
        remove_file(self.map_origin_path)
        os.replace(self.map_path, kept)
        _fsync_dir(self.root)
        return kept

    # ---- library

    def library_record(self) -> LibraryRecord:
        """What `library/library.json` records of its signs' origin; every field None when it cannot be read."""
        try:
            meta = parse_json((self.library_dir / "library.json").read_bytes())
        except (OSError, JsonError):
            meta = None
        if not isinstance(meta, dict):
            return LibraryRecord(None, None, None, ())
        origin, fingerprint, added, signs = (meta.get(k) for k in ("copied_from", "fingerprint", "added", "signs"))
        return LibraryRecord(
            Path(origin) if isinstance(origin, str) else None,
            fingerprint if isinstance(fingerprint, str) else None,
            frozenset(added) if isinstance(added, list) and all(isinstance(i, str) for i in added) else None,
            tuple(e["id"] for e in signs if isinstance(e, dict) and isinstance(e.get("id"), str))
            if isinstance(signs, list) else (),
        )

    def open_library(self, source: Path | None, default: Path) -> tuple[Library, LibraryReread | None]:
        """The state's library, and what reading `source` again did to it (None: not read again).

        Without `source` the state's library is used as it is (a fresh state starts as a copy of
        `default`). `source` (`--library`) is read at every start: when it is another folder than
        the state's library was copied from, or its content differs (`library_fingerprint`), the
        state's library becomes its signs plus the signs added through the page or API since
        (`merge_library`), and the library as it was is moved to a new `library.replaced-<UTC time>`
        when any of it is dropped or changed. Unchanged, it leaves the state's library as it is,
        signs removed in the page included. A damaged state library stops a start without
        `source`; with it, it is moved aside the same way.
        """
        self._recover_library()
        meta = self.library_dir / "library.json"
        held, damage = None, None
        if meta.exists():
            try:
                held = load_library(self.library_dir)
            except LibraryError as exc:
                damage = exc
        if source is None and meta.exists():
            if held is None:
                raise StateError(f"{damage}; start with --library <a library folder> to replace it (the damaged "
                                 "one is kept, moved aside)")
            return held, None
        folder = Path(source if source is not None else default).resolve()
        try:
            incoming = load_library(folder)  # validated before anything is replaced
            fingerprint = library_fingerprint(incoming)
        except (LibraryError, OSError) as exc:
            raise StateError(str(exc)) from None
        record = self.library_record()
        if not meta.exists():
            return self._write_library(incoming, [], fingerprint, keep_old=False)[0], None
        if held is not None and record.copied_from == folder and record.fingerprint == fingerprint:
            return held, None
        merge = merge_library(held, incoming, record.added)
        library, kept = self._write_library(incoming, merge.carried, fingerprint,
                                            keep_old=held is None or bool(merge.changed or merge.dropped))
        if held is None:
            why = "the state's library could not be read"
        elif record.copied_from != folder:
            why = (f"the state's library was a copy of {record.copied_from}" if record.copied_from is not None
                   else "the state had not recorded which folder it copied")
        else:
            why = ("it changed since the state copied it" if record.fingerprint is not None
                   else "the state had not recorded what it copied")
        return library, LibraryReread(folder, why, merge, kept, damaged=held is None)

    def _write_library(self, incoming: Library, carried: list[LibrarySign], fingerprint: str,
                       keep_old: bool) -> tuple[Library, Path | None]:
        """Make library/ hold `incoming`'s signs and the `carried` ones (from the state's library, as
        added), recorded as copied from `incoming.root` with `fingerprint`; returns that library (its signs
        were validated as read, so it is not read back) and where the folder it replaces was moved (a new
        `library.replaced-<UTC time>`, when `keep_old`; else it is deleted, and None)."""
        files = {sign.image_file: incoming.root / sign.image_file for sign in incoming.signs}
        kept_signs = []
        for sign in carried:
            origin = self.library_dir / sign.image_file
            if sign.image_file in files:  # a name the folder uses too
                sign = dataclasses.replace(sign, image_file=f"{sign.id}-{secrets.token_hex(4)}{origin.suffix}")
            files[sign.image_file] = origin
            kept_signs.append(sign)
        meta = library_meta([*incoming.signs, *kept_signs], incoming.root, fingerprint, [s.id for s in kept_signs])
        staging = Path(tempfile.mkdtemp(dir=self.root, prefix=".library.", suffix=TMP_SUFFIX))
        aside = self.root / LIBRARY_ASIDE
        try:
            for name, origin in files.items():
                shutil.copyfile(origin, staging / name)
            (staging / "library.json").write_bytes(json_bytes(meta))
            for path in staging.iterdir():
                with open(path, "rb") as f:
                    os.fsync(f.fileno())
            _fsync_dir(staging)
            # A folder cannot be replaced atomically: the old one is moved aside first, and a start
            # after a crash between the two moves puts it back (`_recover_library`).
            shutil.rmtree(aside, ignore_errors=True)
            if self.library_dir.exists():
                os.replace(self.library_dir, aside)
            os.replace(staging, self.library_dir)
            _fsync_dir(self.root)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        library = Library(self.library_dir, [*incoming.signs, *kept_signs])
        if not aside.exists():
            return library, None
        if not keep_old:
            shutil.rmtree(aside, ignore_errors=True)
            return library, None
        kept = replaced_path(self.root, "library", "")
        os.replace(aside, kept)
        _fsync_dir(self.root)
        return library, kept

    def _recover_library(self) -> None:
        """Put back the library a crash left moved aside, before its replacement was moved in."""
        aside = self.root / LIBRARY_ASIDE
        if not self.library_dir.exists() and (aside / "library.json").exists():
            os.replace(aside, self.library_dir)
            _fsync_dir(self.root)

    def save_library(self, library: Library) -> None:
        """Rewrite `library/library.json` for the signs in `library` (their files must already be there).
        A sign it did not list before was added (through the page or API), and is recorded so."""
        record = self.library_record()
        added = None if record.added is None else [i for i in library.ids if i in record.added or i not in record.ids]
        atomic_write_json(self.library_dir / "library.json",
                          library_meta(library.signs, record.copied_from, record.fingerprint, added))

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
            entries: Any = parse_json(self.index_path.read_bytes())  # a list of dicts, or TypeError below
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
