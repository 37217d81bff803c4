"""The images `signpose serve` holds: uploads checked and decoded, their records and stored files, the
memory they take against the server's budget, and the colour photos kept decoded for figures.

`ImageStore` owns the records; the pipeline results on them are written by the re-run workers
(`ImageRecord.outcome`, replaced whole under the record's own lock).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import mimetypes
import os
import re
import secrets
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

import cv2
import numpy as np

from signpose.pipeline.every_sign import SignSeen
from signpose.pipeline.exif import ExifCamera, decode_with_exif
from signpose.pipeline.image import ImageError, ImageTooLarge, check_image_header, to_gray
from signpose.pipeline.library import NO_SIGN
from signpose.pipeline.recognize import Recognition, StageCache

from .state import StateDir, StoredImage

log = logging.getLogger(__name__)

MAX_NAME_CHARS = 200
IMAGE_ID = re.compile(r"^[0-9a-f]{12}$")
# Colour photos kept decoded for figures (`ImageStore.photo`): a detail view draws five from one.
PHOTOS_KEPT = 2
# An image held keeps its gray (1 byte a pixel) and its result's segmentation labels (1), and
# its stage cache may keep CACHE_BYTES_PER_PIXEL more as the cache counts them (a segmentation
# counts 2: its labels and the gray it shares with the image) plus CACHE_MIN_BYTES for features
# and matches. The memory limit charges every image all of it: `held_bytes`.
CACHE_BYTES_PER_PIXEL = 3
CACHE_MIN_BYTES = 1_000_000
HELD_BYTES_PER_PIXEL = 2 + CACHE_BYTES_PER_PIXEL


def held_bytes(pixels: int) -> int:
    """The most memory an image of `pixels` px takes while the store holds it."""
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
    `ImageStore.photo`); `file` its stored name in the state directory; `exif` the intrinsics its
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
    # Every library sign in the image (`Workspace.signs_in_view`) and the snapshot generation it is of.
    in_view: tuple[int, list[SignSeen]] | None = field(default=None, repr=False)
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


class Answer(Protocol):
    """What the pipeline answered on an image: a `Recognition`, or the `Outcome` a batch keeps of one."""

    @property
    def label(self) -> str | None: ...

    @property
    def recognized(self) -> bool: ...

    @property
    def by_plaque(self) -> bool: ...

    @property
    def margin(self) -> int: ...


def is_correct(expected: str | None, recognition: Answer) -> bool | None:
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


def decode_upload(data: bytes, name: str, max_pixels: int) -> tuple[np.ndarray, str, ExifCamera]:
    """Check and decode an uploaded image: ((H, W, 3) uint8 BGR, media type, what its EXIF gives for the camera).

    Raises ImageError.
    """
    media_type = check_image_header(data, name, max_pixels).media_type
    image, exif = decode_with_exif(data, name)
    return image, media_type, exif


def decode_gray(data: bytes, name: str) -> tuple[np.ndarray, ExifCamera]:
    """Decode an image whose header is checked: ((H, W) uint8 gray as the pipeline makes it, what its
    EXIF gives for the camera). The colour copy is dropped at once: the store keeps the gray."""
    image, exif = decode_with_exif(data, name)
    return to_gray(image), exif


class ImageStore:
    """The images held, in the order they were chosen (`Slot`), with their files and index in the state
    directory, within `max_images` and `max_memory_bytes` (each image counted as `held_bytes` says).

    Locks: `_lock` guards `_records` and the index on disk, so that the room check and the listing it
    allows are one step (two uploads cannot both take the last room) and the index lists exactly the
    images held. `_photo_lock` guards `_photos`. Neither is held while calling out, except for
    `queue` in `add`.
    """

    def __init__(self, state: StateDir, records: Iterable[ImageRecord] = (), *, max_images: int, max_pixels: int,
                 max_memory_bytes: int) -> None:
        self.state = state
        self.max_images = max_images
        self.max_pixels = max_pixels  # px an upload may have
        self.max_memory_bytes = max_memory_bytes
        self._lock = threading.Lock()
        self._records: dict[str, ImageRecord] = {r.id: r for r in records}
        self._photos: OrderedDict[str, np.ndarray] = OrderedDict()  # image id -> colour photo, see photo()
        self._photo_lock = threading.Lock()

    def images(self) -> list[ImageRecord]:
        """All images, in the order they were chosen (`Slot`)."""
        with self._lock:
            return list(self._records.values())

    def get(self, image_id: str) -> ImageRecord:
        """The image with `image_id`; KeyError when there is none."""
        return self._records[image_id]

    def holds(self, record: ImageRecord) -> bool:
        """Whether `record` is still held (not removed)."""
        return self._records.get(record.id) is record

    def stale(self, generation: int) -> list[ImageRecord]:
        """The images whose result is not of state `generation`."""
        with self._lock:
            return [r for r in self._records.values() if r.outcome.generation != generation]

    def count_current(self, generation: int) -> tuple[int, int]:
        """(images whose result is of state `generation`, images held), counted at one moment."""
        with self._lock:
            return sum(r.outcome.generation == generation for r in self._records.values()), len(self._records)

    def reset_caches(self) -> None:
        """Give every image an empty stage cache (its cached matches name signs a new library may reuse)."""
        with self._lock:
            for record in self._records.values():
                record.cache = record.new_cache()

    def add(self, uploads: list[tuple[str, bytes, str | None]], *, batch: str = "", position: int = 0,
            queue: Callable[[ImageRecord], None]) -> list[ImageRecord]:
        """Check, decode, store and list (client file name, encoded bytes, expected label) uploads, all or none;
        they are listed at `position` on in `batch` (`Slot`), or after every image held without one.

        `queue(record)` is called for each new record under the lock as it is listed, so no one sees an image
        held that is neither processed nor queued; it must neither wait nor call back into the store.
        Raises ImageError naming every unusable file (ImageTooLarge for too many pixels, or an image that
        alone would take more than `max_memory_bytes`), Conflict when the images would exceed `max_images`
        or `max_memory_bytes`.
        """
        checked = [(display_name(name), data, expected) for name, data, expected in uploads]
        by_place, refused = dict(enumerate(checked)), dict[int, ImageError]()
        headers = read_each(by_place, lambda u: check_image_header(u[1], u[0], self.max_pixels), refused)
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
                    queue(record)
        except BaseException:
            for record in records:
                self.state.remove_image(record.file)
            raise
        return records

    def set_expected(self, image_id: str, expected: str | None) -> ImageRecord:
        """Label image `image_id` `expected` (a label already checked); KeyError when there is none."""
        with self._lock:
            record = self._records[image_id]
            record.expected = expected
            self.state.save_images([r.stored() for r in self._records.values()])
        return record

    def forget(self, image_ids: list[str] | None) -> int:
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
        return len(records)

    def image_path(self, record: ImageRecord) -> Path:
        return self.state.image_path(record.file)

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

    def held_now(self) -> tuple[int, int]:
        """(images held, the bytes they take as `held_bytes` counts them: what `max_memory_bytes`
        limits), read without the lock, which is held across every fsync'd write of the index:
        /api/health answers at once, not behind a queue of uploads."""
        records = list(self._records.values())  # one step for the GIL, whatever other threads do
        return len(records), sum(held_bytes(r.gray.size) for r in records)

    def _held(self) -> int:
        return sum(held_bytes(r.gray.size) for r in self._records.values())

    def _check_room(self, uploads: list[tuple[str, int]]) -> None:
        """Refuse to add `uploads` ((display name, pixels)) beyond `max_images` or `max_memory_bytes`
        (Conflict), or an image that alone would take more than `max_memory_bytes` (ImageTooLarge);
        the message says what fits. The caller holds `_lock`."""
        held, limit = len(self._records), self.max_memory_bytes
        if held + len(uploads) > self.max_images:
            raise Conflict(f"the workspace holds {held} images and its limit is {self.max_images}; "
                           f"delete some before adding {len(uploads)} more")
        for name, pixels in uploads:
            if held_bytes(pixels) > limit:
                raise ImageTooLarge(f"{name}: {pixels / 1e6:.1f} megapixels would take "
                                    f"{memory_text(held_bytes(pixels))} held, more than the server's memory limit of "
                                    f"{memory_text(limit)}; downscale it, or restart signpose serve with a higher "
                                    "--max-memory-gb")
        used = self._held()
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


def memory_text(size: int) -> str:
    """`size` bytes for people: "2.5 MB", "61 MB", "11.6 GB"."""
    return f"{size / 1e9:.3g} GB" if size >= 1e9 else f"{size / 1e6:.3g} MB"


def _extension(media_type: str) -> str:
    return mimetypes.guess_extension(media_type) or ".bin"
