"""The one holder of `signpose serve` state: settings, library, camera, images and their results.

The FastAPI routes and the viser scene share one `Workspace` (docs/web-contract.md). It composes
the parts that each own their state and lock: `SettingsHistory` (the `Snapshot` every result is
computed from, app/settings_history.py), `ImageStore` (the images, their files and the memory
budget, app/image_store.py), `Rerunner` (debounced re-runs on the pipeline's thread pool,
app/rerun.py) and `EventBus` (change notices, app/events.py). The pipeline runs on a thread pool
(OpenCV releases the GIL, so threads use every core). After a change the re-run takes the current
snapshot and re-runs every image whose result is stale, each with its own `StageCache` so a RANSAC
change does not re-detect features; a newer change supersedes the run in progress (images not yet
started are skipped). Every result is tagged with the snapshot it was computed from and never
mixes two states.

`Workspace.open(config)` does the disk work of a start (the state directory, its library,
settings, camera and images, the sample scenes); `Workspace(...)` takes those parts loaded.
"""

from __future__ import annotations

import functools
import logging
import secrets
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any
from pathlib import Path

import cv2
import numpy as np

from signpose.pipeline.camera import Camera, CameraError, check_hfov, load_camera
from signpose.pipeline.evaluate import CORES
from signpose.pipeline.every_sign import SignSeen, recognize_every_sign
from signpose.pipeline.exif import ExifCamera
from signpose.pipeline.features import library_features
from signpose.pipeline.image import ImageError
from signpose.pipeline.jsonfile import parse_json
from signpose.pipeline.library import (MAX_LIKENESS, NO_SIGN, SAMPLE_LIBRARY, Library, LibraryError, LibrarySign, alike_sign,
                              make_sign, validate_sign_entry)
from signpose.pipeline.recognize import PipelineError, Recognition, StageCache, pipeline_errors, run_pipeline
from signpose.pipeline.settings import PRESETS, Settings, load_settings

from .events import Event, EventBus
from .image_store import (DEFAULT_MAX_MEMORY_BYTES, Conflict, ImageRecord, ImageStore, Outcome, Slot, decode_gray,
                          decode_upload)
from .rerun import Job, Rerunner
from .settings_history import SettingsHistory, Snapshot
from .state import Replaced, StateDir, StoredImage

log = logging.getLogger(__name__)

SAMPLE_SCENES = SAMPLE_LIBRARY.parent / "scenes"
SAMPLE_FLIGHT = SAMPLE_LIBRARY.parent / "flights" / "corridor"


@dataclass(frozen=True)
class WorkspaceConfig:
    """Options of `signpose serve` (sizes in bytes and pixels, times in seconds)."""

    state_dir: Path = Path("signpose_state")
    library_dir: Path | None = None  # None: the state's library; on a fresh state the samples
    camera_file: Path | None = None  # None: the state's camera
    settings_file: Path | None = None  # None: the state's settings
    map_file: Path | None = None  # None: the state's sign map, if it keeps one
    load_samples: bool = True  # on a fresh state with the sample library, load sample_images/scenes
    max_images: int = 500
    max_pixels: int = 40_000_000
    max_upload_bytes: int = 25_000_000
    max_flight_upload_bytes: int = 500_000_000  # a flight's upload (a video or a bag) is one request
    max_flight_frames: int = 3000  # frames one flight may hold: 100 s at 30 fps
    max_flights: int = 5  # flights held at once (each keeps its frames as JPEG)
    max_memory_bytes: int = DEFAULT_MAX_MEMORY_BYTES  # what the images held may take, as `held_bytes` counts
    request_timeout_s: float = 120.0  # longest a request waits for pipeline work (recognise, sweep)
    workers: int = CORES  # every core; `signpose evaluate --workers` defaults to it too
    debounce_s: float = 0.15
    max_wait_s: float = 1.0


def sample_scenes(folder: Path = SAMPLE_SCENES) -> list[tuple[Path, str | None]]:
    """(image path, expected label) of the sample scenes; negatives are expected `NO_SIGN`."""
    try:
        document: Any = parse_json((folder / "truth.json").read_bytes())
        truth = document["images"]
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("no usable %s; starting without sample scenes", folder / "truth.json")
        return []
    return [(path, (truth[path.name].get("label") or NO_SIGN) if path.name in truth else None)
            for path in sorted(folder.glob("*.jpg"))]


def say_kept(what: str, file: Path, replaced: Replaced | None) -> None:
    """The one log line saying that `--<what> file` (what: "camera", "map" or "settings") replaced what the state
    held, where that is kept and how to use it again; nothing when `replaced` is None (nothing moved)."""
    if replaced is None:
        return
    option = f"--{what}"
    if replaced.damaged:
        log.warning("%s %s replaced the state's %s, which could not be read; it is kept as it was in %s",
                    option, file, what, replaced.kept)
    else:
        held, them = ("settings, which are", "them") if what == "settings" else (f"{what}, which is", "that one")
        log.warning(f"%s %s replaced the state's {held} kept in %s: to use {them} again, start with %s %s",
                    option, file, replaced.kept, option, replaced.kept)


def load_images(state: StateDir, stored: list[StoredImage], *, workers: int) -> list[ImageRecord]:
    """The records of the `stored` images, listed in their order, decoded on `workers` threads; a file
    damaged on disk is dropped (logged) rather than refusing to start."""
    def decode(entry: StoredImage) -> tuple[np.ndarray, ExifCamera] | None:
        try:
            return decode_gray(state.read_image(entry.file), entry.name)
        except (OSError, ImageError) as exc:
            log.warning("dropping stored image %s (%s): %s", entry.name, entry.file, exc)
            return None

    records: list[ImageRecord] = []
    with ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="signpose-load") as pool:
        for entry, decoded in zip(stored, pool.map(decode, stored)):
            if decoded is not None:
                gray, exif = decoded
                records.append(ImageRecord(entry.id, entry.name, entry.expected, gray, entry.file,
                                           entry.media_type, exif, Slot(len(records))))
    return records


class Workspace:
    """Server state shared by the HTTP API and the viser scene (the interface is in docs/web-contract.md).

    Thread-safe: routes call it from FastAPI's thread pool, the scene from viser's threads. Each
    part guards its own state (see theirs); the workspace's own locks: `_library_lock` makes a
    library change one step (the check of its ids and likeness, the sign files, library.json, the
    new snapshot and the stage caches dropped), `_disk_lock` orders the writes of settings.json,
    camera.json and the assumed field of view so the newest lands last. A change swaps the
    snapshot before it asks for a re-run, so the re-run it schedules computes from it or a newer one.
    Call `close()` to stop its threads.
    """

    def __init__(self, config: WorkspaceConfig, *, state: StateDir, snapshot: Snapshot,
                 images: Iterable[ImageRecord] = ()) -> None:
        """A workspace on the opened `state`, starting from `snapshot` with the loaded `images` (re-run
        at once when there are any). No disk work: `Workspace.open` loads the parts."""
        self.config = config
        self.state = state
        self._library_lock = threading.Lock()
        self._disk_lock = threading.Lock()
        self._history = SettingsHistory(snapshot)
        # A state started from the sample library shows the samples: the sample scenes once, on a fresh
        # state; the sample flight (flights are not kept in the state) at every start. Set by `open`.
        self.shows_samples = False
        self._images = ImageStore(state, images, max_images=config.max_images, max_pixels=config.max_pixels,
                                  max_memory_bytes=config.max_memory_bytes)
        self._events = EventBus()
        self._pool = ThreadPoolExecutor(max_workers=max(1, config.workers), thread_name_prefix="signpose-pipeline")
        self._rerun = Rerunner(self._pool, debounce_s=config.debounce_s, max_wait_s=config.max_wait_s,
                               plan=self._plan, on_progress=lambda: self.publish("results", self.progress()))
        if self._images.stale(snapshot.generation):
            self._rerun.request()

    @classmethod
    def open(cls, config: WorkspaceConfig = WorkspaceConfig()) -> Workspace:
        """The workspace kept in `config.state_dir` (created when missing), with `config`'s library,
        settings and camera files replacing the state's (kept aside, and logged) and, on a fresh state
        with the sample library, the sample scenes. StateError, SettingsError, CameraError or
        LibraryError when the files cannot be used."""
        state = StateDir(config.state_dir)
        library, reread = state.open_library(config.library_dir, SAMPLE_LIBRARY)
        if reread is not None:  # e.g. a sign's size corrected in the folder, or signs added in the page kept
            log.warning("%s", reread.describe())
        if config.settings_file is None:
            settings = state.load_settings() or PRESETS["default"]
        else:  # e.g. settings tuned in the page since the last start are kept, not lost
            settings = load_settings(config.settings_file)
            say_kept("settings", config.settings_file, state.replace_settings(settings))
        if config.camera_file is None:
            camera = state.load_camera()
        else:  # e.g. a calibration applied in the page since the last start is kept, not lost
            camera = load_camera(config.camera_file)
            say_kept("camera", config.camera_file, state.replace_camera(camera))
        snapshot = Snapshot(1, 1, settings, library, camera, state.load_assumed_hfov())
        stored = state.load_images()
        state.sweep(stored or [], library)
        records = load_images(state, stored or [], workers=config.workers)
        if len(records) != len(stored or []):
            state.save_images([r.stored() for r in records])
        workspace = cls(config, state=state, snapshot=snapshot, images=records)
        workspace.shows_samples = config.load_samples and \
            state.library_record().copied_from == SAMPLE_LIBRARY.resolve()
        if stored is None and workspace.shows_samples:
            workspace._load_samples()
        return workspace

    def _load_samples(self) -> None:
        for path, expected in sample_scenes():
            try:
                self.add_image(path.name, path.read_bytes(), expected)
            except (OSError, ValueError) as exc:
                log.warning("sample scene %s not loaded: %s", path, exc)

    # ---- state

    @property
    def snapshot(self) -> Snapshot:
        return self._history.current

    @property
    def settings(self) -> Settings:
        return self.snapshot.settings

    @property
    def settings_version(self) -> int:
        return self.snapshot.settings_version

    def settings_at(self, version: int) -> Settings:
        """The settings of `version` (one of `settings_versions()`); KeyError when not kept."""
        return self._history.settings_at(version)

    def settings_versions(self) -> range:
        """The settings versions whose settings are kept: the last `settings_history.SETTINGS_HISTORY`."""
        return self._history.versions()

    @property
    def library(self) -> Library:
        return self.snapshot.library

    @property
    def camera(self) -> Camera | None:
        return self.snapshot.camera

    # ---- images

    def images(self) -> list[ImageRecord]:
        """All images, in the order they were chosen (`Slot`)."""
        return self._images.images()

    def get(self, image_id: str) -> ImageRecord:
        """The image with `image_id`; KeyError when there is none."""
        return self._images.get(image_id)

    def check_expected(self, expected: str | None) -> str | None:
        """`expected` normalised ("" -> None), or LibraryError naming the known labels."""
        if expected is None or expected == "":
            return None
        if expected != NO_SIGN and expected not in self.library.ids:
            raise LibraryError(f"expected label {expected!r} is not a sign in the library; use one of "
                               f"{', '.join(self.library.ids)}, {NO_SIGN!r} for an image without a sign, "
                               "or leave it empty")
        return expected

    def add_image(self, name: str, data: bytes, expected: str | None) -> ImageRecord:
        """Decode, store and queue one image for processing (see `add_images`)."""
        return self.add_images([(name, data, expected)])[0]

    def add_images(self, uploads: list[tuple[str, bytes, str | None]], batch: str = "",
                   position: int = 0) -> list[ImageRecord]:
        """Decode, store and queue (name, encoded bytes, expected label) uploads, all or none; they are
        listed at `position` on in `batch` (`Slot`), or after every image held without one.

        Raises ImageError naming every unusable file (ImageTooLarge for too many pixels, or an image
        that alone would take more than `max_memory_bytes`), LibraryError for an unknown expected
        label, Conflict when the images would exceed `max_images` or `max_memory_bytes`.
        """
        checked = [(name, data, self.check_expected(expected)) for name, data, expected in uploads]
        records = self._images.add(checked, batch=batch, position=position, queue=self._queue)
        self._images_changed()
        return records

    def _queue(self, record: ImageRecord) -> None:
        """Process a new image now, outside the debounce, with the snapshot current when it starts."""
        self._rerun.submit(lambda: self._process(record, self.snapshot))

    def photo(self, record: ImageRecord) -> np.ndarray:
        """(H, W, 3) uint8 BGR: the image in colour, as uploaded, for the figures drawn on it (`ImageStore.photo`)."""
        return self._images.photo(record)

    def held_now(self) -> tuple[int, int]:
        """(images held, the bytes they take as `held_bytes` counts them: what `max_memory_bytes`
        limits), read without waiting for any lock (`ImageStore.held_now`)."""
        return self._images.held_now()

    def set_expected(self, image_id: str, expected: str | None) -> ImageRecord:
        """Label image `image_id` `expected` (checked as `check_expected`); KeyError when there is none."""
        self._images.get(image_id)  # an unknown image is named before an unknown label
        record = self._images.set_expected(image_id, self.check_expected(expected))
        self._images_changed()
        return record

    def remove_image(self, image_id: str) -> None:
        """Forget an image and delete its stored file; KeyError when there is none."""
        self._forget([image_id])

    def remove_images(self) -> int:
        """Forget every image and delete their stored files; how many there were."""
        return self._forget(None)

    def _forget(self, image_ids: list[str] | None) -> int:
        count = self._images.forget(image_ids)
        self._rerun.trim_soon()
        self._images_changed()
        return count

    def _images_changed(self) -> None:
        self.publish("images", {"ids": [r.id for r in self.images()]})

    def image_path(self, record: ImageRecord) -> Path:
        return self._images.image_path(record)

    # ---- settings, camera, library (each change schedules a re-run)

    def update_settings(self, changes: dict) -> Settings:
        """Apply a full or partial settings dict; SettingsError (message for the user) when invalid."""
        return self._set_settings(lambda current: Settings.from_dict(changes, base=current))

    def replace_settings(self, settings: Settings) -> Settings:
        """Make `settings` current and schedule a re-run."""
        return self._set_settings(lambda _: settings)

    def _set_settings(self, make: Callable[[Settings], Settings]) -> Settings:
        # Merged and swapped as one step (`SettingsHistory.change`), so concurrent partial changes
        # all land. Written to disk after (an fsync takes ~10 ms; readers should not wait), always the
        # newest settings so the last write wins; notified last, so no subscriber runs inside a change.
        made: list[Settings] = []  # what `make` made, kept to be returned when it changes nothing

        def settings_change(snap: Snapshot) -> dict:
            made.append(make(snap.settings))
            return {} if made[-1] == snap.settings else {"settings": made[-1]}

        snap = self._history.change(settings_change)
        if snap is None:
            return made[-1]
        with self._disk_lock:
            self.state.save_settings(self.settings)
        self.publish("settings", {"version": snap.settings_version, "settings": snap.settings.to_dict()})
        self._rerun.request()
        return snap.settings

    def set_camera(self, camera: Camera | None) -> None:
        """Use `camera` for every image (None: each image's EXIF focal length, else the assumed field of view)."""
        self._history.change(lambda _: {"camera": camera})
        with self._disk_lock:  # as in _set_settings
            self.state.save_camera(self.camera)
        self._camera_changed()

    def set_assumed_hfov(self, hfov_deg: float) -> None:
        """Assume a `hfov_deg` horizontal field of view (degrees) for images without camera or EXIF
        intrinsics; CameraError outside ASSUMED_HFOV_RANGE_DEG."""
        hfov_deg = check_hfov(hfov_deg)
        if self._history.change(lambda snap: {} if hfov_deg == snap.assumed_hfov_deg
                                else {"assumed_hfov_deg": hfov_deg}) is None:
            return
        with self._disk_lock:
            self.state.save_assumed_hfov(self.snapshot.assumed_hfov_deg)
        self._camera_changed()

    def _camera_changed(self) -> None:
        snap = self.snapshot
        self.publish("camera", {"camera": snap.camera.to_json() if snap.camera is not None else None,
                              "assumed_hfov_deg": snap.assumed_hfov_deg})
        self._rerun.request()

    def _set_library(self, signs: list[LibrarySign]) -> None:
        """Replace the library (the caller holds `_library_lock` and has written the sign files)."""
        library = Library(root=self.state.library_dir, signs=signs)
        self.state.save_library(library)
        self._history.change(lambda _: {"library": library})
        # Cached matches are keyed by sign id, which a new sign may reuse: start afresh.
        self._images.reset_caches()

    def add_sign(self, sign_id: str, data: bytes, name: str = "", text: str = "",
                 width_m: float = 0.0, height_m: float | None = None, *, kind: str | None = None,
                 min_text_correlation: float | None = None) -> LibrarySign:
        """Add a library sign from an encoded image (`kind` None: told from the image;
        `min_text_correlation` None: the settings'); LibraryError / ImageError when unusable, Conflict on
        a taken id or an image that cannot be told apart from a sign's already there."""
        entry = validate_sign_entry({"id": sign_id, "name": name or sign_id, "text": text,
                                     "image": f"{sign_id}-{secrets.token_hex(4)}.png", "width_m": width_m,
                                     "height_m": height_m, "kind": kind,
                                     "min_text_correlation": min_text_correlation}, "new sign")
        image, _, _ = decode_upload(data, f"sign {sign_id}", self.config.max_pixels)
        sign = make_sign(entry, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), f"sign {sign_id}")
        with self._library_lock:
            if sign_id in self.library.ids:
                raise Conflict(f"the library already has a sign {sign_id!r}; delete it first or choose another id")
            alike = alike_sign(sign.image, self.library.signs)
            if alike is not None:
                other, value = alike
                raise Conflict(f"sign {sign_id!r}'s image is too like that of sign {other.id!r} ({other.name}) to "
                               f"be told apart from it (likeness {value:.2f}; from {MAX_LIKENESS} on they cannot): "
                               "photos of either would be answered as neither, or as the other. Choose an image of "
                               f"this sign, or delete {other.id!r} first to replace it")
            # PNG whatever was uploaded: lossless, and what GET /api/library/{id}/image promises.
            self.state.write_library_file(sign.image_file, cv2.imencode(".png", image)[1].tobytes())
            self._set_library([*self.library.signs, sign])
        self.publish("library", {"ids": self.library.ids})
        self._rerun.request()
        return sign

    def remove_sign(self, sign_id: str) -> None:
        """Delete a library sign (results naming it are re-run); KeyError if unknown, Conflict if it is the last."""
        with self._library_lock:
            sign = self.library[sign_id]
            if len(self.library.signs) == 1:
                raise Conflict("cannot delete the library's last sign; add another sign first")
            self._set_library([s for s in self.library.signs if s.id != sign_id])
            self.state.remove_library_file(sign.image_file)
        self.publish("library", {"ids": self.library.ids})
        self._rerun.request()

    def sign_path(self, sign_id: str) -> Path:
        """The image file of a library sign; KeyError if unknown."""
        library = self.library
        return library.root / library[sign_id].image_file

    # ---- events

    def subscribe(self, callback: Callable[[Event], None]) -> Callable[[], None]:
        """Call `callback(event)` on every change, from worker threads; returns the unsubscribe function."""
        return self._events.subscribe(callback)

    def publish(self, kind: str, payload: dict) -> None:
        """Send `Event(kind, payload)` to every subscriber: the workspace's own changes, and those of the
        calibration session beside it (app/calibration.py), which clients follow on the same stream."""
        self._events.publish(kind, payload)

    # ---- processing

    @property
    def busy(self) -> bool:
        """Whether any image is being processed or a re-run is due (advisory: read without a lock)."""
        return self._rerun.busy

    def progress(self) -> dict:
        """The "results" event payload: {version, running, done, total} for the current state."""
        snap = self.snapshot
        done, total = self._images.count_current(snap.generation)
        return {"version": snap.settings_version, "running": self.busy, "done": done, "total": total}

    def wait_idle(self, timeout: float) -> bool:
        """Block until every result is current (True) or `timeout` seconds pass (False)."""
        return self._rerun.wait_idle(timeout)

    def _plan(self) -> list[Job]:
        """The jobs of a re-run: every image whose result is not of the current snapshot."""
        snap = self.snapshot
        stale = self._images.stale(snap.generation)
        if stale:
            library_features(snap.library, snap.settings)  # once here, not once per worker
        return [functools.partial(self._process, record, snap) for record in stale]

    def _process(self, record: ImageRecord, snap: Snapshot) -> None:
        """Bring one image's result up to `snap`, unless a newer change or a removal made that pointless."""
        if snap is not self.snapshot or not self._images.holds(record) or self._rerun.closed:
            return
        with record.lock:
            if record.outcome.generation >= snap.generation:
                return
            try:
                rec = run_logged(record.name, record.gray, snap.library, snap.settings,
                                 snap.camera_for(record.exif, record.width, record.height), record.cache)
                outcome = Outcome(rec, snap.settings_version, snap.generation)
            # a camera that does not fit this image, or a failure on it, must not stop the others
            except (CameraError, PipelineError) as exc:
                outcome = Outcome(None, snap.settings_version, snap.generation, str(exc))
            record.outcome = outcome

    # ---- one-off runs

    def recognize_upload(self, data: bytes, name: str) -> list[Recognition]:
        """Recognise every library sign in an uploaded image (`recognize_every_sign`: the first is the answer)
        with the current state without keeping it.

        Runs in the caller's thread (a request worker), not behind a re-run in the pipeline pool.
        Raises ImageError when the upload is unusable, CameraError when the camera does not fit it,
        PipelineError when the pipeline fails on it.
        """
        image, _, exif = decode_upload(data, name, self.config.max_pixels)
        snap = self.snapshot
        try:
            with logged_failure(name), pipeline_errors(name):
                return recognize_every_sign(image, snap.library, snap.settings,
                                            snap.camera_for(exif, image.shape[1], image.shape[0]))
        finally:
            self._rerun.trim_soon()

    def run_with(self, record: ImageRecord, settings: Settings) -> Recognition:
        """Recognise one stored image under `settings`, re-using (and feeding) its stage cache."""
        snap = self.snapshot
        with record.lock:
            return run_logged(record.name, record.gray, snap.library, settings,
                              snap.camera_for(record.exif, record.width, record.height), record.cache)

    def sweep(self, param: str, values: list[float], records: list[ImageRecord],
              stop: threading.Event | None = None) -> list[list[Recognition | None]]:
        """Re-run `records` with `param` set to each value: results [value index][record index],
        None where that image could not be run at that value (the camera does not fit it, or the
        pipeline failed, which the log details): one failure must not hide what the sweep says
        of every other run.

        Values run in order per image (each run reuses what its cache holds), images in parallel.
        SettingsError when a value is invalid. Setting `stop` (the caller gave up waiting) ends it
        early with TimeoutError, freeing the pool.
        """
        variants = [self.settings.replace(**{param: v}) for v in values]

        def run(record: ImageRecord, settings: Settings) -> Recognition | None:
            try:
                return self.run_with(record, settings)
            except (CameraError, PipelineError):
                return None

        def runs(record: ImageRecord) -> list[Recognition | None]:
            out = []
            for settings in variants:
                if stop is not None and stop.is_set():
                    raise TimeoutError("sweep abandoned")
                out.append(run(record, settings))
            return out

        try:
            per_image = list(self._pool.map(runs, records))
        finally:
            self._rerun.trim_soon()
        return [[results[i] for results in per_image] for i in range(len(variants))]

    def signs_in_view(self, records: list[ImageRecord], stop: threading.Event | None = None,
                      ) -> list[list[SignSeen] | None]:
        """Every library sign in each of `records` under the current state (`recognize_every_sign`: what
        each of its searches found, the last one no sign), on the pipeline's pool; None for an
        image that could not be run (the camera does not fit it, or the pipeline failed on it: its own
        result says why). Kept on the record until the state changes: a map build and the map world's
        cameras search a photo once. Setting `stop` (the caller gave up waiting) ends it early with
        TimeoutError."""
        snap = self.snapshot

        def run(record: ImageRecord) -> list[SignSeen] | None:
            if stop is not None and stop.is_set():
                raise TimeoutError("abandoned")
            kept = record.in_view
            if kept is not None and kept[0] == snap.generation:
                return kept[1]
            try:
                camera = snap.camera_for(record.exif, record.width, record.height)
                found = [SignSeen.of(r) for r in recognize_every_sign(record.gray, snap.library, snap.settings, camera)]
            except (CameraError, PipelineError):
                return None
            record.in_view = (snap.generation, found)
            return found

        try:
            return list(self._pool.map(run, records))
        finally:
            self._rerun.trim_soon()

    def close(self) -> None:
        """Stop the re-run thread and the pool (waits for the images being processed)."""
        self._rerun.close()
        self._pool.shutdown(wait=True, cancel_futures=True)


def run_logged(name: str, image: np.ndarray, library: Library, settings: Settings, camera: Camera | None,
               cache: StageCache | None = None) -> Recognition:
    """`run_pipeline`, with the traceback of a failure in the server's log."""
    with logged_failure(name):
        return run_pipeline(name, image, library, settings, camera, cache)


@contextmanager
def logged_failure(name: str) -> Iterator[None]:
    """Inside, a PipelineError (on the image `name`) goes on with its traceback in the server's log."""
    try:
        yield
    except PipelineError:
        log.exception("pipeline failed on %s", name)
        raise
