"""The one holder of `signpose serve` state: settings, library, camera, images and their results.

The FastAPI routes and the viser scene share one `Workspace` (docs/web-contract.md). The
pipeline runs on a thread pool (OpenCV releases the GIL, so threads use every core). After a
change, one re-run thread waits until changes stop for `debounce_s` (at most `max_wait_s`),
takes a `Snapshot` of the state and re-runs every image whose result is stale, each with its
own `StageCache` so a RANSAC change does not re-detect features. A newer change supersedes the
run in progress: images not yet started are skipped and one new run follows, so a slider storm
costs one or two runs, not one per change. Every result is tagged with the snapshot it was
computed from and never mixes two states.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import logging
import mimetypes
import os
import re
import secrets
import struct
import threading
import time
import warnings
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NamedTuple, TypeVar

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from signpose.pipeline.camera import Camera, CameraError, check_hfov, load_camera
from signpose.pipeline.evaluate import CORES, release_freed_memory
from signpose.pipeline.exif import ExifCamera, decode_with_exif
from signpose.pipeline.features import library_features
from signpose.pipeline.image import ImageError, to_gray, unreadable
from signpose.pipeline.jsonfile import parse_json
from signpose.pipeline.library import (MAX_LIKENESS, NO_SIGN, SAMPLE_LIBRARY, Library, LibraryError, LibrarySign, alike_sign,
                              make_sign, validate_sign_entry)
from signpose.pipeline.recognize import PipelineError, Recognition, StageCache, run_pipeline
from signpose.pipeline.settings import PRESETS, Settings, load_settings

from .state import Replaced, StateDir, StoredImage

log = logging.getLogger(__name__)

SAMPLE_SCENES = SAMPLE_LIBRARY.parent / "scenes"
MAX_NAME_CHARS = 200
IMAGE_ID = re.compile(r"^[0-9a-f]{12}$")
# Settings versions whose settings are kept, so a result's version can be checked against them.
SETTINGS_HISTORY = 1000
# Colour photos kept decoded for figures (`Workspace.photo`): a detail view draws five from one.
PHOTOS_KEPT = 2
# The memory freed by deletions and finished work goes back to the system this long after (by
# then the requests that deleted images have let go of them), once for a burst.
TRIM_DELAY_S = 1.0
EVENT_KINDS = ("settings", "results", "library", "camera", "images", "calibration")
# An image held keeps its gray (1 byte a pixel) and its result's segmentation labels (1), and
# its stage cache may keep CACHE_BYTES_PER_PIXEL more as the cache counts them (a segmentation
# counts 2: its labels and the gray it shares with the image) plus CACHE_MIN_BYTES for features
# and matches. The memory limit charges every image all of it: `held_bytes`.
CACHE_BYTES_PER_PIXEL = 3
CACHE_MIN_BYTES = 1_000_000
HELD_BYTES_PER_PIXEL = 2 + CACHE_BYTES_PER_PIXEL


def held_bytes(pixels: int) -> int:
    """The most memory an image of `pixels` px takes while the workspace holds it."""
    return HELD_BYTES_PER_PIXEL * pixels + CACHE_MIN_BYTES


def memory_size() -> int | None:
    """Bytes of memory this process may use: the machine's, or its container's (cgroup) limit when
    lower; None when neither can be read."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):  # no sysconf (Windows) or no such name
        total = None
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            limit = int(Path(limit_file).read_text().strip())
        except (OSError, ValueError):  # no such file, or "max": no limit
            continue
        total = limit if total is None else min(total, limit)
    return total


# The images held may take half the memory; the rest is for the pipeline's working memory (a
# 12 MP photo takes a few hundred MB while it is processed), the page's figures and the system.
DEFAULT_MAX_MEMORY_BYTES = (memory_size() or 8_000_000_000) // 2


class Conflict(ValueError):
    """A request the current state refuses (too many images, duplicate sign id, ...); the message says why."""


class ImageTooLarge(ImageError):
    """An image whose pixel count exceeds the limit (a decompression bomb or a huge scan)."""


Upload = TypeVar("Upload")
Read = TypeVar("Read")


def read_each(uploads: dict[int, Upload], read: Callable[[Upload], Read],
              refused: dict[int, ImageError]) -> dict[int, Read]:
    """`read` of each of `uploads` (by its place in the request) that it does not refuse; those it refuses go
    into `refused` with why. The files of a request are added all or none, and the error names every
    unusable one (`refused_together`), not the first alone."""
    done = {}
    for place, upload in uploads.items():
        try:
            done[place] = read(upload)
        except ImageError as exc:
            refused[place] = exc
    return done


def refused_together(refused: dict[int, ImageError], total: int) -> ImageError:
    """One error for the files `refused` (by their place) among the `total` of a request, none of which is
    added: the file's own when it came alone, else naming each in turn; ImageTooLarge (413) when each
    was too large."""
    errors = [refused[place] for place in sorted(refused)]
    if total == 1:
        return errors[0]
    kind = ImageTooLarge if all(isinstance(e, ImageTooLarge) for e in errors) else ImageError
    return kind(f"{len(errors)} of the {total} files cannot be used, so none was added: "
                + "; ".join(f"({n}) {error}" for n, error in enumerate(errors, 1)))


@dataclass(frozen=True)
class WorkspaceConfig:
    """Options of `signpose serve` (sizes in bytes and pixels, times in seconds)."""

    state_dir: Path = Path("signpose_state")
    library_dir: Path | None = None  # None: the state's library; on a fresh state the samples
    camera_file: Path | None = None  # None: the state's camera
    settings_file: Path | None = None  # None: the state's settings
    load_samples: bool = True  # on a fresh state with the sample library, load sample_images/scenes
    max_images: int = 500
    max_pixels: int = 40_000_000
    max_upload_bytes: int = 25_000_000
    max_memory_bytes: int = DEFAULT_MAX_MEMORY_BYTES  # what the images held may take, as `held_bytes` counts
    request_timeout_s: float = 120.0  # longest a request waits for pipeline work (recognise, sweep)
    workers: int = CORES  # every core; `signpose evaluate --workers` defaults to it too
    debounce_s: float = 0.15
    max_wait_s: float = 1.0


@dataclass(frozen=True)
class Event:
    """A change notice; `kind` is one of EVENT_KINDS, `payload` JSON-ready (see the contract)."""

    kind: str
    payload: dict


@dataclass(frozen=True)
class Snapshot:
    """Everything a result depends on. `generation` grows with every change to any of it.

    `camera` None: per image its EXIF focal length, else `assumed_hfov_deg` (horizontal, degrees).
    """

    generation: int
    settings_version: int
    settings: Settings
    library: Library
    camera: Camera | None
    assumed_hfov_deg: float

    def camera_for(self, exif: ExifCamera, width: int, height: int) -> Camera:
        """The intrinsics an image decoded to `width` x `height` px is recognised with: the workspace's
        camera turned as its EXIF orientation turned it, else the image's EXIF focal length, else the
        assumed field of view (`ExifCamera.camera_for`). CameraError when the camera does not fit it."""
        return exif.camera_for(self.camera, width, height, self.assumed_hfov_deg)


@dataclass(frozen=True, order=True)
class Slot:
    """Where an upload is listed: lists of uploads keep the order their files were chosen in.

    A client sends a batch of files a request each, several at once, so they land in any order; it
    names the batch and each file's `position` in it. A batch's files are listed together, by
    position, where its first file to land went; `group` numbers the batches in that order."""

    group: int
    position: int = 0
    batch: str = field(default="", compare=False)


def slot_for(held: list[Slot], batch: str, position: int) -> Slot:
    """The slot of an upload at `position` in `batch` ("": a batch of its own), among those `held`."""
    group = next((s.group for s in held if batch and s.batch == batch), None)
    if group is None:
        group = max((s.group for s in held), default=-1) + 1
    return Slot(group, position, batch)


@dataclass(frozen=True)
class Outcome:
    """One image's latest result and the snapshot it came from (replaced as a whole, never torn)."""

    recognition: Recognition | None = None
    settings_version: int = 0
    generation: int = -1
    error: str | None = None


@dataclass(eq=False)
class ImageRecord:
    """One loaded image. `gray` is (H, W) uint8, what the pipeline reads (the colour photo, three
    times its size, is decoded again from the stored file for the figures that show it:
    `Workspace.photo`); `file` its stored name in the state directory; `exif` the intrinsics its
    EXIF implies (or why none), used while the workspace has no camera; `slot` where it is listed."""

    id: str
    name: str
    expected: str | None
    gray: np.ndarray = field(repr=False)
    file: str
    media_type: str
    exif: ExifCamera = ExifCamera()
    slot: Slot = Slot(0)
    cache: StageCache = field(init=False, repr=False)
    outcome: Outcome = field(default_factory=Outcome)
    # Held while the pipeline uses `cache`: StageCache is not thread-safe and a sweep may run
    # alongside a re-run.
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        self.cache = self.new_cache()

    def new_cache(self) -> StageCache:
        """An empty stage cache that keeps at most what `held_bytes` allows for this image."""
        return StageCache(max_bytes=CACHE_BYTES_PER_PIXEL * self.gray.size + CACHE_MIN_BYTES)

    @property
    def recognition(self) -> Recognition | None:
        return self.outcome.recognition

    @property
    def settings_version(self) -> int:
        return self.outcome.settings_version

    @property
    def error(self) -> str | None:
        return self.outcome.error

    @property
    def width(self) -> int:
        return int(self.gray.shape[1])

    @property
    def height(self) -> int:
        return int(self.gray.shape[0])

    def stored(self) -> StoredImage:
        return StoredImage(self.id, self.name, self.expected, self.file, self.media_type)


def is_correct(expected: str | None, recognition: Recognition) -> bool | None:
    """Whether `recognition` matches `expected` (None when the image is unlabelled)."""
    if expected is None:
        return None
    return recognition.label == (None if expected == NO_SIGN else expected)


def status_of(expected: str | None, outcome: Outcome, generation: int) -> str:
    """"pending" (no result for the current state yet), "error", "correct", "wrong", "recognized" or "none"."""
    if outcome.generation != generation:
        return "pending"
    if outcome.error is not None or outcome.recognition is None:
        return "error"
    correct = is_correct(expected, outcome.recognition)
    if correct is not None:
        return "correct" if correct else "wrong"
    return "recognized" if outcome.recognition.recognized else "none"


def display_name(name: str) -> str:
    """A client's file name reduced to something safe to show (it never becomes a path)."""
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    base = "".join(ch for ch in base if ch.isprintable()).strip()
    return base[:MAX_NAME_CHARS] or "image"


class ImageHeader(NamedTuple):
    media_type: str
    width: int  # px, as stored (before any EXIF rotation)
    height: int


def check_image_header(data: bytes, name: str, max_pixels: int) -> ImageHeader:
    """The media type and size of encoded image `data`, after checking its header says at most `max_pixels` px.

    Reads only the header (no pixel data is decoded), so a small file claiming a huge image
    is refused before it can take gigabytes of memory.
    """
    if not data:
        raise ImageError(f"{name}: file is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
                media_type = im.get_format_mimetype() or "application/octet-stream"
    except Image.DecompressionBombError:  # past Pillow's own ceiling, which a higher max_pixels cannot lift
        raise _too_large(name, *_claimed_size(data, name), max_pixels) from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError):  # a header cut short, or no image
        raise unreadable(data, name) from None
    if width * height > max_pixels:
        raise _too_large(name, width, height, max_pixels)
    return ImageHeader(media_type, width, height)


def _too_large(name: str, width: int, height: int, max_pixels: int) -> ImageTooLarge:
    """The error for image `name` of `width` x `height` px, more than `max_pixels` px or Pillow's ceiling (twice
    Image.MAX_IMAGE_PIXELS, which it refuses to open): its size, and whether a higher --max-megapixels would let it
    through."""
    pixels, ceiling = width * height, 2 * Image.MAX_IMAGE_PIXELS
    size = f"{name}: {width}x{height} px is {pixels / 1e6:.1f} megapixels, more than the"
    if pixels > ceiling:
        return ImageTooLarge(f"{size} {ceiling / 1e6:.0f} that can be read at any --max-megapixels; downscale it")
    return ImageTooLarge(f"{size} limit of {max_pixels / 1e6:g}; downscale it, or raise --max-megapixels")


def _claimed_size(data: bytes, name: str) -> tuple[int, int]:
    """The size (px) the header of image `data` claims, where Image.open refused it past Pillow's ceiling without
    saying it: read by the first format that accepts its first bytes, as Image.open reads it, without the ceiling."""
    Image.init()
    for factory, accept in (Image.OPEN[f] for f in Image.ID):
        accepted = accept is None or accept(data[:16])
        if accepted and not isinstance(accepted, str):  # a str is Pillow's warning that it cannot read this kind
            try:
                with factory(io.BytesIO(data), name) as image:
                    return image.size
            except (SyntaxError, IndexError, TypeError, struct.error):  # not this format, as Image.open takes it
                continue
    raise unreadable(data, name)


def decode_upload(data: bytes, name: str, max_pixels: int) -> tuple[np.ndarray, str, ExifCamera]:
    """Check and decode an uploaded image: ((H, W, 3) uint8 BGR, media type, what its EXIF gives for the camera).

    Raises ImageError.
    """
    media_type = check_image_header(data, name, max_pixels).media_type
    image, exif = decode_with_exif(data, name)
    return image, media_type, exif


def decode_gray(data: bytes, name: str) -> tuple[np.ndarray, ExifCamera]:
    """Decode an image whose header is checked: ((H, W) uint8 gray as the pipeline makes it, what its
    EXIF gives for the camera). The colour copy is dropped at once: the workspace keeps the gray."""
    image, exif = decode_with_exif(data, name)
    return to_gray(image), exif


def sample_scenes(folder: Path = SAMPLE_SCENES) -> list[tuple[Path, str | None]]:
    """(image path, expected label) of the sample scenes; negatives are expected `NO_SIGN`."""
    try:
        truth = parse_json((folder / "truth.json").read_bytes())["images"]
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("no usable %s; starting without sample scenes", folder / "truth.json")
        return []
    return [(path, (truth[path.name].get("label") or NO_SIGN) if path.name in truth else None)
            for path in sorted(folder.glob("*.jpg"))]


def say_kept(what: str, file: Path, replaced: Replaced | None) -> None:
    """The one log line saying that `--<what> file` (what: "camera" or "settings") replaced what the state
    held, where that is kept and how to use it again; nothing when `replaced` is None (nothing moved)."""
    if replaced is None:
        return
    option = f"--{what}"
    if replaced.damaged:
        log.warning("%s %s replaced the state's %s, which could not be read; it is kept as it was in %s",
                    option, file, what, replaced.kept)
    else:
        held, them = ("camera, which is", "that one") if what == "camera" else ("settings, which are", "them")
        log.warning(f"%s %s replaced the state's {held} kept in %s: to use {them} again, start with %s %s",
                    option, file, replaced.kept, option, replaced.kept)


class Workspace:
    """Server state shared by the HTTP API and the viser scene (the interface is in docs/web-contract.md).

    Thread-safe: routes call it from FastAPI's thread pool, the scene from viser's threads.
    Call `close()` to stop its threads.
    """

    def __init__(self, config: WorkspaceConfig = WorkspaceConfig()) -> None:
        self.config = config
        self.state = StateDir(config.state_dir)
        self._lock = threading.RLock()  # guards _snap, _records and the images and library on disk
        self._disk_lock = threading.Lock()  # orders writes of settings.json and camera.json
        self._idle = threading.Condition(self._lock)
        self._records: dict[str, ImageRecord] = {}
        self._photos: OrderedDict[str, np.ndarray] = OrderedDict()  # image id -> colour photo, see photo()
        self._photo_lock = threading.Lock()
        self._subscribers: list[Callable[[Event], None]] = []
        self._pool = ThreadPoolExecutor(max_workers=max(1, config.workers), thread_name_prefix="signpose-pipeline")
        self._opencv_threads = cv2.getNumThreads()  # the process's, given back by close()
        if config.workers > 1:
            # The pool's threads already share the cores; OpenCV's own threads inside each only
            # compete with them (2 cores, 200 images re-run by 2 workers: 2.33 s with one OpenCV
            # thread each, 2.65 s with two).
            cv2.setNumThreads(max(1, CORES // config.workers))
        self._dirty = False
        self._first_change = self._last_change = 0.0
        self._batch_running = False
        self._in_flight = 0
        self._closed = False
        self._trim_timer: threading.Timer | None = None

        library, reread = self.state.open_library(config.library_dir, SAMPLE_LIBRARY)
        if reread is not None:  # e.g. a sign's size corrected in the folder, or signs added in the page kept
            log.warning("%s", reread.describe())
        if config.settings_file is None:
            settings = self.state.load_settings() or PRESETS["default"]
        else:  # e.g. settings tuned in the page since the last start are kept, not lost
            settings = load_settings(config.settings_file)
            say_kept("settings", config.settings_file, self.state.replace_settings(settings))
        if config.camera_file is None:
            camera = self.state.load_camera()
        else:  # e.g. a calibration applied in the page since the last start is kept, not lost
            camera = load_camera(config.camera_file)
            say_kept("camera", config.camera_file, self.state.replace_camera(camera))
        self._snap = Snapshot(1, 1, settings, library, camera, self.state.load_assumed_hfov())
        self._history: dict[int, Settings] = {1: settings}  # settings_version -> settings, oldest first

        stored = self.state.load_images()
        self.state.sweep(stored or [], library)
        for entry, decoded in zip(stored or [], self._pool.map(self._decode_stored, stored or [])):
            if decoded is not None:
                gray, exif = decoded
                self._records[entry.id] = ImageRecord(entry.id, entry.name, entry.expected, gray, entry.file,
                                                      entry.media_type, exif, Slot(len(self._records)))
        if len(self._records) != len(stored or []):
            self.state.save_images([r.stored() for r in self._records.values()])

        self._runner = threading.Thread(target=self._rerun_loop, name="signpose-rerun", daemon=True)
        self._runner.start()
        from_samples = self.state.library_record().copied_from == SAMPLE_LIBRARY.resolve()
        if stored is None and config.load_samples and from_samples:
            self._load_samples()
        elif self._records:
            self._request_rerun()

    def _decode_stored(self, entry: StoredImage) -> tuple[np.ndarray, ExifCamera] | None:
        """(gray, EXIF camera) of a stored image, None when its file is unusable."""
        try:
            return decode_gray(self.state.read_image(entry.file), entry.name)
        except (OSError, ImageError) as exc:  # a file damaged on disk: drop it rather than refuse to start
            log.warning("dropping stored image %s (%s): %s", entry.name, entry.file, exc)
            return None

    # ---- state

    @property
    def snapshot(self) -> Snapshot:
        return self._snap

    @property
    def settings(self) -> Settings:
        return self._snap.settings

    @property
    def settings_version(self) -> int:
        return self._snap.settings_version

    def settings_at(self, version: int) -> Settings:
        """The settings of `version` (one of `settings_versions()`); KeyError when not kept."""
        return self._history[version]

    def settings_versions(self) -> range:
        """The settings versions whose settings are kept: the last SETTINGS_HISTORY."""
        with self._lock:
            return range(next(iter(self._history)), self._snap.settings_version + 1)

    @property
    def library(self) -> Library:
        return self._snap.library

    @property
    def camera(self) -> Camera | None:
        return self._snap.camera

    def _load_samples(self) -> None:
        for path, expected in sample_scenes():
            try:
                self.add_image(path.name, path.read_bytes(), expected)
            except (OSError, ValueError) as exc:
                log.warning("sample scene %s not loaded: %s", path, exc)

    # ---- images

    def images(self) -> list[ImageRecord]:
        """All images, in the order they were chosen (`Slot`)."""
        with self._lock:
            return list(self._records.values())

    def get(self, image_id: str) -> ImageRecord:
        """The image with `image_id`; KeyError when there is none."""
        return self._records[image_id]

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
        checked = [(display_name(name), data, self.check_expected(expected)) for name, data, expected in uploads]
        by_place, refused = dict(enumerate(checked)), {}
        headers = read_each(by_place, lambda u: check_image_header(u[1], u[0], self.config.max_pixels), refused)
        sizes = [(by_place[place][0], header.width * header.height) for place, header in headers.items()]
        with self._lock:
            self._check_room(sizes)  # before decoding anything
        # Decoded here, in the caller's thread: the pipeline pool may be busy with a long re-run.
        decoded = read_each({place: by_place[place] for place in headers}, lambda u: decode_gray(u[1], u[0]), refused)
        if refused:
            raise refused_together(refused, len(checked))
        records = []
        try:
            # Files first, outside the lock (each write is fsync'd); until the index names them a
            # crash leaves only orphans, which the next start sweeps.
            for (name, data, expected), (gray, exif), (media_type, _, _) in zip(checked, decoded.values(),
                                                                                headers.values()):
                image_id = secrets.token_hex(6)
                records.append(ImageRecord(image_id, name, expected, gray, image_id + _extension(media_type),
                                           media_type, exif))
                self.state.write_image(records[-1].file, data)
            with self._lock:
                self._check_room(sizes)  # again: another upload may have landed meanwhile
                first = slot_for([r.slot for r in self._records.values()], batch, position)
                for i, record in enumerate(records):
                    record.slot = dataclasses.replace(first, position=position + i)
                listed = sorted([*self._records.values(), *records], key=lambda r: r.slot)
                self.state.save_images([r.stored() for r in listed])
                self._records = {r.id: r for r in listed}
                for record in records:
                    self._submit(record)
        except BaseException:
            for record in records:
                self.state.remove_image(record.file)
            raise
        self.publish("images", {"ids": [r.id for r in self.images()]})
        return records

    def photo(self, record: ImageRecord) -> np.ndarray:
        """(H, W, 3) uint8 BGR: the image in colour, as uploaded, for the figures drawn on it.

        Decoded again from the stored file (the last PHOTOS_KEPT kept, as a detail view asks for
        several figures of one image at once); the gray it holds, when the file is gone (the
        image was deleted meanwhile) or no longer readable.
        """
        with self._photo_lock:  # one decode of an image however many figures ask for it at once
            if (photo := self._photos.get(record.id)) is not None:
                self._photos.move_to_end(record.id)
                return photo
            try:
                photo = decode_with_exif(self.state.read_image(record.file), record.name)[0]
            except (OSError, ImageError) as exc:
                log.warning("%s: drawn in gray, its stored file is unusable: %s", record.name, exc)
                return cv2.cvtColor(record.gray, cv2.COLOR_GRAY2BGR)
            self._photos[record.id] = photo
            while len(self._photos) > PHOTOS_KEPT:
                self._photos.popitem(last=False)
            return photo

    def memory_held(self) -> int:
        """Bytes the images held take as `held_bytes` counts them: what `max_memory_bytes` limits."""
        with self._lock:
            return sum(held_bytes(r.gray.size) for r in self._records.values())

    def _check_room(self, uploads: list[tuple[str, int]]) -> None:
        """Refuse to add `uploads` ((display name, pixels)) beyond `max_images` or `max_memory_bytes`
        (Conflict), or an image that alone would take more than `max_memory_bytes` (ImageTooLarge);
        the message says what fits. The caller holds the lock."""
        held, limit = len(self._records), self.config.max_memory_bytes
        if held + len(uploads) > self.config.max_images:
            raise Conflict(f"the workspace holds {held} images and its limit is {self.config.max_images}; "
                           f"delete some before adding {len(uploads)} more")
        for name, pixels in uploads:
            if held_bytes(pixels) > limit:
                raise ImageTooLarge(f"{name}: {pixels / 1e6:.1f} megapixels would take "
                                    f"{memory_text(held_bytes(pixels))} held, more than the server's memory limit of "
                                    f"{memory_text(limit)}; downscale it, or restart signpose serve with a higher "
                                    "--max-memory-gb")
        used = self.memory_held()
        needed = [held_bytes(pixels) for _, pixels in uploads]
        if used + sum(needed) <= limit:
            return
        left = max(0, limit - used)
        fit = sum(total <= left for total in itertools.accumulate(needed))
        largest = (left - CACHE_MIN_BYTES) // HELD_BYTES_PER_PIXEL // 100_000  # tenths of a megapixel, down
        if fit:
            room = "only the first of them fits" if fit == 1 else f"the first {fit} of them fit"
        elif largest > 0:
            room = f"an image of up to {largest / 10:.1f} megapixels fits"
        else:
            room = "no image fits"
        what = f"{uploads[0][0]} ({uploads[0][1] / 1e6:.1f} megapixels)" if len(uploads) == 1 else \
            f"these {len(uploads)} images"
        raise Conflict(f"the {held} images held take {memory_text(used)} of the server's memory limit of "
                       f"{memory_text(limit)} (--max-memory-gb); {what} would take {memory_text(sum(needed))} "
                       f"more and {memory_text(left)} is left: {room}; delete some images, or restart signpose "
                       "serve with a higher --max-memory-gb")

    def set_expected(self, image_id: str, expected: str | None) -> ImageRecord:
        with self._lock:
            record = self._records[image_id]
            record.expected = self.check_expected(expected)
            self.state.save_images([r.stored() for r in self._records.values()])
        self.publish("images", {"ids": [r.id for r in self.images()]})
        return record

    def remove_image(self, image_id: str) -> None:
        """Forget an image and delete its stored file; KeyError when there is none."""
        self._forget([image_id])

    def remove_images(self) -> int:
        """Forget every image and delete their stored files; how many there were."""
        return self._forget(None)

    def _forget(self, image_ids: list[str] | None) -> int:
        """Forget the images `image_ids` (None: every one held) and delete their stored files, with
        one write of the index; how many. KeyError, and nothing forgotten, for an id not held."""
        with self._lock:
            records = [self._records[i] for i in (list(self._records) if image_ids is None else image_ids)]
            for record in records:
                del self._records[record.id]
            self.state.save_images([r.stored() for r in self._records.values()])
            for record in records:
                self.state.remove_image(record.file)
        with self._photo_lock:
            for record in records:
                self._photos.pop(record.id, None)
        self._trim_soon()
        self.publish("images", {"ids": [r.id for r in self.images()]})
        return len(records)

    def image_path(self, record: ImageRecord) -> Path:
        return self.state.image_path(record.file)

    # ---- settings, camera, library (each change schedules a re-run)

    def _change(self, **changes: Any) -> Snapshot:
        """Swap in a new snapshot with `changes`; the caller holds the lock."""
        snap = self._snap
        bump = "settings" in changes
        self._snap = dataclasses.replace(snap, generation=snap.generation + 1,
                                         settings_version=snap.settings_version + bump, **changes)
        if bump:
            self._history[self._snap.settings_version] = self._snap.settings
            if len(self._history) > SETTINGS_HISTORY:
                del self._history[next(iter(self._history))]
        return self._snap

    def update_settings(self, changes: dict) -> Settings:
        """Apply a full or partial settings dict; SettingsError (message for the user) when invalid."""
        return self._set_settings(lambda current: Settings.from_dict(changes, base=current))

    def replace_settings(self, settings: Settings) -> Settings:
        """Make `settings` current and schedule a re-run."""
        return self._set_settings(lambda _: settings)

    def _set_settings(self, make: Callable[[Settings], Settings]) -> Settings:
        # Merge and swap under the lock, so concurrent partial changes all land. Write to disk after
        # releasing it (an fsync takes ~10 ms; readers should not wait), always the newest settings
        # so the last write wins; notify last, so no subscriber runs while the workspace is locked.
        with self._lock:
            settings = make(self.settings)
            if settings == self.settings:
                return settings
            snap = self._change(settings=settings)
        with self._disk_lock:
            self.state.save_settings(self.settings)
        self.publish("settings", {"version": snap.settings_version, "settings": settings.to_dict()})
        self._request_rerun()
        return settings

    def set_camera(self, camera: Camera | None) -> None:
        """Use `camera` for every image (None: each image's EXIF focal length, else the assumed field of view)."""
        with self._lock:
            self._change(camera=camera)
        with self._disk_lock:  # as in _set_settings
            self.state.save_camera(self.camera)
        self._camera_changed()

    def set_assumed_hfov(self, hfov_deg: float) -> None:
        """Assume a `hfov_deg` horizontal field of view (degrees) for images without camera or EXIF
        intrinsics; CameraError outside ASSUMED_HFOV_RANGE_DEG."""
        hfov_deg = check_hfov(hfov_deg)
        with self._lock:
            if hfov_deg == self._snap.assumed_hfov_deg:
                return
            self._change(assumed_hfov_deg=hfov_deg)
        with self._disk_lock:
            self.state.save_assumed_hfov(self._snap.assumed_hfov_deg)
        self._camera_changed()

    def _camera_changed(self) -> None:
        snap = self._snap
        self.publish("camera", {"camera": snap.camera.to_json() if snap.camera is not None else None,
                              "assumed_hfov_deg": snap.assumed_hfov_deg})
        self._request_rerun()

    def _set_library(self, signs: list[LibrarySign]) -> None:
        """Replace the library (the caller holds the lock and has written the sign files)."""
        library = Library(root=self.state.library_dir, signs=signs)
        self.state.save_library(library)
        self._change(library=library)
        for record in self._records.values():
            # Cached matches are keyed by sign id, which a new sign may reuse: start afresh.
            record.cache = record.new_cache()

    def add_sign(self, sign_id: str, data: bytes, name: str = "", text: str = "",
                 width_m: float = 0.0, height_m: float | None = None) -> LibrarySign:
        """Add a library sign from an encoded image; LibraryError / ImageError when unusable, Conflict on a
        taken id or an image that cannot be told apart from a sign's already there."""
        entry = validate_sign_entry({"id": sign_id, "name": name or sign_id, "text": text,
                                     "image": f"{sign_id}-{secrets.token_hex(4)}.png", "width_m": width_m,
                                     "height_m": height_m}, "new sign")
        image, _, _ = decode_upload(data, f"sign {sign_id}", self.config.max_pixels)
        sign = make_sign(entry, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), f"sign {sign_id}")
        with self._lock:
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
        self._request_rerun()
        return sign

    def remove_sign(self, sign_id: str) -> None:
        """Delete a library sign (results naming it are re-run); KeyError if unknown, Conflict if it is the last."""
        with self._lock:
            sign = self.library[sign_id]
            if len(self.library.signs) == 1:
                raise Conflict("cannot delete the library's last sign; add another sign first")
            self._set_library([s for s in self.library.signs if s.id != sign_id])
            self.state.remove_library_file(sign.image_file)
        self.publish("library", {"ids": self.library.ids})
        self._request_rerun()

    def sign_path(self, sign_id: str) -> Path:
        """The image file of a library sign; KeyError if unknown."""
        library = self.library
        return library.root / library[sign_id].image_file

    # ---- events

    def subscribe(self, callback: Callable[[Event], None]) -> Callable[[], None]:
        """Call `callback(event)` on every change, from worker threads; returns the unsubscribe function."""
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def publish(self, kind: str, payload: dict) -> None:
        """Send `Event(kind, payload)` to every subscriber: the workspace's own changes, and those of the
        calibration session beside it (app/calibration.py), which clients follow on the same stream."""
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(Event(kind, payload))
            except Exception:  # one broken subscriber must not stop the others or the pipeline
                log.exception("event subscriber failed on %s", kind)

    # ---- processing

    @property
    def busy(self) -> bool:
        """Whether any image is being processed or a re-run is due (advisory: read without the lock)."""
        return self._dirty or self._batch_running or self._in_flight > 0

    def progress(self) -> dict:
        """The "results" event payload: {version, running, done, total} for the current state."""
        with self._lock:
            generation = self._snap.generation
            done = sum(r.outcome.generation == generation for r in self._records.values())
            return {"version": self._snap.settings_version, "running": self.busy, "done": done,
                    "total": len(self._records)}

    def wait_idle(self, timeout: float) -> bool:
        """Block until every result is current (True) or `timeout` seconds pass (False)."""
        with self._idle:
            return self._idle.wait_for(lambda: not self.busy, timeout)

    def _submit(self, record: ImageRecord) -> None:
        """Process a new image now, outside the debounce (the caller holds the lock)."""
        self._in_flight += 1
        self._pool.submit(self._process_and_report, record)

    def _process_and_report(self, record: ImageRecord) -> None:
        try:
            self._process(record, self._snap)
        finally:
            with self._lock:
                self._in_flight -= 1
                self._idle.notify_all()
            self.publish("results", self.progress())
            self._trim_soon()

    def _process(self, record: ImageRecord, snap: Snapshot) -> None:
        """Bring one image's result up to `snap`, unless a newer change or a removal made that pointless."""
        if snap is not self._snap or record.id not in self._records or self._closed:
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

    def _request_rerun(self) -> None:
        with self._lock:
            now = time.monotonic()
            if not self._dirty:
                self._first_change = now
            self._dirty = True
            self._last_change = now
            self._idle.notify_all()

    def _rerun_loop(self) -> None:
        while True:
            with self._idle:
                self._idle.wait_for(lambda: self._dirty or self._closed)
                if self._closed:
                    return
                # Debounce: wait for a quiet spell, but not past max_wait_s, so a long slider
                # drag still shows intermediate results.
                while not self._closed:
                    due = min(self._last_change + self.config.debounce_s, self._first_change + self.config.max_wait_s)
                    if time.monotonic() >= due:
                        break
                    self._idle.wait(due - time.monotonic())
                self._dirty = False
                self._batch_running = True
                snap = self._snap
                stale = [r for r in self._records.values() if r.outcome.generation != snap.generation]
            try:
                self._run_batch(snap, stale)
            finally:
                # Not kept while the loop waits for the next change: images deleted meanwhile would
                # stay in memory until then.
                del stale
                with self._lock:
                    self._batch_running = False
                    self._idle.notify_all()
                self.publish("results", self.progress())
                self._trim_soon()

    def _trim_soon(self) -> None:
        """Hand the memory freed by deletions and finished work back to the system TRIM_DELAY_S from
        now, unless work is still going on then (its end calls this again). glibc would keep it
        (`release_freed_memory`): a tester's server stayed at 3.7 GB after deleting all its photos."""
        with self._lock:
            if self._trim_timer is None and not self._closed:
                self._trim_timer = threading.Timer(TRIM_DELAY_S, self._trim)
                self._trim_timer.daemon = True
                self._trim_timer.start()

    def _trim(self) -> None:
        with self._lock:
            self._trim_timer = None
            if self.busy or self._closed:
                return
        release_freed_memory()

    def _run_batch(self, snap: Snapshot, records: list[ImageRecord]) -> None:
        if records:
            library_features(snap.library, snap.settings)  # once here, not once per worker
        futures = [self._pool.submit(self._process, record, snap) for record in records]
        for future in as_completed(futures):
            future.result()
            self.publish("results", self.progress())

    # ---- one-off runs

    def recognize_upload(self, data: bytes, name: str) -> Recognition:
        """Recognise an uploaded image with the current state without keeping it.

        Runs in the caller's thread (a request worker), not behind a re-run in the pipeline pool.
        Raises ImageError when the upload is unusable, CameraError when the camera does not fit it,
        PipelineError when the pipeline fails on it.
        """
        image, _, exif = decode_upload(data, name, self.config.max_pixels)
        snap = self._snap
        try:
            return run_logged(name, image, snap.library, snap.settings,
                              snap.camera_for(exif, image.shape[1], image.shape[0]))
        finally:
            self._trim_soon()

    def run_with(self, record: ImageRecord, settings: Settings) -> Recognition:
        """Recognise one stored image under `settings`, re-using (and feeding) its stage cache."""
        snap = self._snap
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
            self._trim_soon()
        return [[results[i] for results in per_image] for i in range(len(variants))]

    def close(self) -> None:
        """Stop the re-run thread and the pool (waits for the images being processed), and give
        the process back the OpenCV thread count it had."""
        with self._lock:
            self._closed = True
            self._idle.notify_all()
            if self._trim_timer is not None:
                self._trim_timer.cancel()
        self._runner.join(timeout=10)
        self._pool.shutdown(wait=True, cancel_futures=True)
        cv2.setNumThreads(self._opencv_threads)


def run_logged(name: str, image: np.ndarray, library: Library, settings: Settings, camera: Camera | None,
               cache: StageCache | None = None) -> Recognition:
    """`run_pipeline`, with the traceback of a failure in the server's log."""
    try:
        return run_pipeline(name, image, library, settings, camera, cache)
    except PipelineError:
        log.exception("pipeline failed on %s", name)
        raise


def memory_text(size: int) -> str:
    """`size` bytes for people: "2.5 MB", "61 MB", "11.6 GB"."""
    return f"{size / 1e9:.3g} GB" if size >= 1e9 else f"{size / 1e6:.3g} MB"


def _extension(media_type: str) -> str:
    return mimetypes.guess_extension(media_type) or ".bin"
