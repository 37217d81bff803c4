"""Flights held by `signpose serve`: videos and ROS bags uploaded, tracked in the background.

A flight is a source file (a video, a ROS bag, or a rosbag2 folder sent as a zip) kept in a
private temporary folder for the server's life, run through `pipeline.track.tracked_frames` on
one worker thread of its own (never the event loop, never the images' pool), with the same
per-frame records `signpose track --json` prints. What is kept per flight: the records of its last
complete run, each frame as a JPEG (for the page and the MCAP export; at most
`FRAME_MAX_WIDTH_PX` wide) and the camera the tracker used. A change of settings, camera, assumed
field of view or library re-runs every flight from its source file (decoding a 640x480 frame takes
a few ms, a tenth of tracking it; holding decoded frames would take 0.9 MB each), the old records
shown until the new run ends; a newer change stops the run going on and starts again.

Progress and changes are published on the workspace's event bus as `flights` events (the whole
list's progress, so collapsing events of one kind loses nothing); the 3D scene follows the same
events and `Flights.cursor` (the frame the page shows).

Frames and poses as in `signpose track` (docs/flights.md): times in seconds from the first frame,
corners in frame px, poses X_cam = R·X_sign + t.
"""

from __future__ import annotations

import logging
import secrets
import shutil
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import cv2
import numpy as np

from signpose.pipeline.camera import Camera, CameraError, assumed_camera
from signpose.pipeline.frames import (ROS1_SUFFIX, ROS2_SUFFIXES, VIDEO_SUFFIXES, FrameSource, SourceError,
                                      open_source, unused_options)
from signpose.pipeline.track import Tracker, tracked_frames

from .events import Event
from .flight_output import open_flight_output
from .image_store import Conflict, display_name
from .settings_history import Snapshot

log = logging.getLogger(__name__)

FLIGHT_ID_LENGTH = 12  # hex digits, as image ids
ZIP_SUFFIX = ".zip"
FLIGHT_SUFFIXES = frozenset(VIDEO_SUFFIXES | ROS2_SUFFIXES | {ROS1_SUFFIX, ZIP_SUFFIX})
JPEG_QUALITY = 85
# Frames wider than this are kept (and served) scaled down: the page shows them in a column.
FRAME_MAX_WIDTH_PX = 1280
# Progress events while a flight runs, at most this often (s).
PROGRESS_INTERVAL_S = 0.25
STATUSES = ("queued", "processing", "done", "error")


class FlightError(ValueError):
    """An upload that cannot be a flight (unreadable video, a bag without images, a camera that does not
    fit); the message says what is wrong and what to do."""


class FlightTooLarge(ValueError):
    """A flight over the frames a flight may hold (`--max-flight-frames`)."""


@dataclass(eq=False)
class Flight:
    """One uploaded flight. `source` is what `open_source` reads (a file, or a rosbag2 folder); `camera`
    its own camera file, if one came with it. The rest is its processing's state, guarded by `Flights`'
    lock: `status` (STATUSES), `done` of `total` frames (None: not known), `error`, `warnings`, the
    `records` of the last complete run (`signpose track --json` lines), each frame's `stamps` (ns
    since the epoch, a bag's) and `jpegs`, the camera the tracker used (`tracked_camera`, and its `intrinsics`
    for the page), `fps`, the `generation`
    (workspace snapshot) the records are of (-1: none yet) and `result_version`, new on each run's end."""

    id: str
    name: str
    kind: str  # "video" or "bag"
    folder: Path
    source: Path
    width: int
    height: int
    camera: Camera | None = None
    topic: str | None = None
    status: str = "queued"
    done: int = 0
    total: int | None = None
    error: str | None = None
    warnings: list[str] = field(default_factory=list)
    records: list[dict] = field(default_factory=list, repr=False)
    stamps: list[int | None] = field(default_factory=list, repr=False)
    jpegs: list[bytes] = field(default_factory=list, repr=False)
    intrinsics: dict | None = None
    tracked_camera: Camera | None = None
    fps: float | None = None
    generation: int = -1
    result_version: int = 0
    cursor: int = 0

    def summary(self) -> dict:
        """The flight as `GET /api/flights` lists it."""
        return {"id": self.id, "name": self.name, "kind": self.kind, "status": self.status, "done": self.done,
                "total": self.total, "frames": len(self.records), "width": self.width, "height": self.height,
                "fps": self.fps, "error": self.error, "warnings": list(self.warnings),
                "result_version": self.result_version, "cursor": self.cursor,
                "camera": self.intrinsics}


@dataclass(frozen=True)
class Probe:
    """What opening a source told before any processing: its first frame's size, frame count (None:
    not known), rate and the camera it carries (a bag's CameraInfo)."""

    width: int
    height: int
    count: int | None
    fps: float | None
    camera: Camera | None


def probe(source: Path, name: str, *, topic: str | None, max_pixels: int) -> Probe:
    """Open `source` and decode its first frame; FlightError saying why it cannot be a flight (named `name`)."""
    try:
        with open_source(source, topic=topic, max_pixels=max_pixels) as frames:
            if (unused := unused_options(frames, topic=topic, fps=None)) is not None:
                raise SourceError(unused)
            first = next(iter(frames), None)
            if first is None:
                raise FlightError(f"{name}: holds no frames")
            height, width = first.image.shape[:2]
            return Probe(width, height, frames.count, frames.fps, frames.camera)
    except SourceError as exc:
        raise FlightError(str(exc).replace(str(source), name)) from None


def unpacked_bag(archive: Path, folder: Path, *, max_bytes: int) -> Path:
    """The ROS bag inside the zip `archive` (a rosbag2 folder with its metadata.yaml, or one .mcap, .db3 or
    .bag file), extracted into `folder`; FlightError when there is none, or it would unpack to more
    than `max_bytes` or outside `folder`."""
    try:
        with zipfile.ZipFile(archive) as zipped:
            members = [m for m in zipped.infolist() if not m.is_dir()]
            if sum(m.file_size for m in members) > max_bytes:
                raise FlightError(f"the zip unpacks to more than {max_bytes / 1e6:.0f} MB, the limit of an upload: "
                                  "send the bag's .mcap file, or start the server with a higher --max-flight-mb")
            root = folder.resolve()
            for member in members:
                target = (folder / member.filename).resolve()
                if not target.is_relative_to(root):
                    raise FlightError(f"the zip holds a path outside its folder ({member.filename!r}); zip the bag "
                                      "folder itself")
            zipped.extractall(folder, members)
    except (zipfile.BadZipFile, OSError) as exc:
        raise FlightError(f"cannot be read as a zip: {exc}") from None
    metadata = sorted(folder.rglob("metadata.yaml"), key=lambda p: len(p.parts))
    if metadata:
        return metadata[0].parent
    bags = sorted(p for p in folder.rglob("*") if p.suffix.lower() in ROS2_SUFFIXES | {ROS1_SUFFIX})
    if len(bags) == 1:
        return bags[0]
    raise FlightError("the zip holds no ROS bag: zip a rosbag2 folder (its metadata.yaml and .db3 or .mcap "
                      "files), or send the .mcap, .db3 or .bag file itself" if not bags else
                      f"the zip holds {len(bags)} bag files and no metadata.yaml: send one bag at a time")


def frame_jpeg(image: np.ndarray) -> bytes:
    """A frame ((H, W, 3) BGR or (H, W) gray uint8) as JPEG bytes, at most FRAME_MAX_WIDTH_PX wide."""
    if image.shape[1] > FRAME_MAX_WIDTH_PX:
        scale = FRAME_MAX_WIDTH_PX / image.shape[1]
        image = cv2.resize(image, (FRAME_MAX_WIDTH_PX, round(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()


def camera_json(camera: Camera) -> dict:
    """The intrinsics a flight was tracked with, for the page and the 3D scene (px)."""
    K = camera.K
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "width": camera.width, "height": camera.height, "source": camera.source}


class Flights:
    """The flights of one server and the thread that tracks them (see the module docstring).

    `_lock` (and the condition `_wake` on it) guards `_flights` and every Flight's processing state;
    it is never held while a frame is tracked or an event published. `snapshot()` gives the
    workspace state flights are tracked under; `publish(kind, payload)` sends events.
    """

    def __init__(self, *, snapshot: Callable[[], Snapshot], publish: Callable[[str, dict], None],
                 max_flights: int, max_frames: int, max_bytes: int, max_pixels: int) -> None:
        """At most `max_flights` held, `max_frames` frames each; `max_bytes` what a zipped bag may unpack
        to (the upload's own limit); `max_pixels` a frame's pixels, as for photos."""
        self._snapshot, self._publish = snapshot, publish
        self.max_flights, self.max_frames = max_flights, max_frames
        self.max_bytes, self.max_pixels = max_bytes, max_pixels
        self._folder = Path(tempfile.mkdtemp(prefix="signpose-flights-"))
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._flights: dict[str, Flight] = {}
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name="signpose-flights", daemon=True)
        self._thread.start()

    # ---- held flights

    def held(self) -> list[Flight]:
        """Every flight held, in the order they came."""
        with self._lock:
            return list(self._flights.values())

    def get(self, flight_id: str) -> Flight:
        """The flight `flight_id`; KeyError when there is none."""
        with self._lock:
            return self._flights[flight_id]

    def add(self, name: str, data: IO[bytes], *, camera: Camera | None = None, topic: str | None = None) -> Flight:
        """Keep the upload `data` (a file object, read to its end) named `name` as a flight and queue it.

        FlightError when it cannot be one (its kind, an unreadable video, a bag without images, a zip
        without a bag, a camera that does not fit its frames), FlightTooLarge when it has more frames
        than a flight may hold, Conflict when `max_flights` are held already.
        """
        name = display_name(name)
        suffix = Path(name).suffix.lower()
        if suffix not in FLIGHT_SUFFIXES:
            raise FlightError(f"{name}: not a video or a ROS bag; send a video "
                              f"({', '.join(sorted(VIDEO_SUFFIXES))}), a ROS bag (.mcap, .db3, .bag) or a rosbag2 "
                              "folder as a .zip")
        self._check_room()
        flight_id = secrets.token_hex(FLIGHT_ID_LENGTH // 2)
        folder = self._folder / flight_id
        folder.mkdir()
        try:
            upload = folder / f"upload{suffix}"
            with upload.open("wb") as file:
                shutil.copyfileobj(data, file)
            source = upload
            if suffix == ZIP_SUFFIX:
                source = unpacked_bag(upload, folder / "bag", max_bytes=self.max_bytes)
                upload.unlink()
            flight = self._flight(flight_id, name, folder, source, camera, topic)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        with self._lock:
            if len(self._flights) >= self.max_flights:
                shutil.rmtree(folder, ignore_errors=True)
                raise Conflict(self._full())
            self._flights[flight.id] = flight
            self._wake.notify_all()
        self._changed()
        return flight

    def _flight(self, flight_id: str, name: str, folder: Path, source: Path, camera: Camera | None,
                topic: str | None) -> Flight:
        """The Flight of `source`, checked: it opens, its first frame decodes, it holds no more than
        `max_frames` and its camera fits it."""
        found = probe(source, name, topic=topic, max_pixels=self.max_pixels)
        if found.count is not None and found.count > self.max_frames:
            seconds = f" ({found.count / found.fps:.0f} s at {found.fps:g} fps)" if found.fps else ""
            raise FlightTooLarge(f"{name}: {found.count} frames{seconds}, more than the {self.max_frames} a flight "
                                 "may hold: cut it shorter, or start the server with a higher --max-flight-frames")
        kind = "video" if source.suffix.lower() in VIDEO_SUFFIXES else "bag"
        flight = Flight(flight_id, name, kind, folder, source, found.width, found.height, camera, topic,
                        total=found.count, fps=found.fps)
        given = self._given_camera(flight, self._snapshot(), found.camera)
        if given is not None:
            try:
                given.for_image(found.width, found.height)
            except CameraError as exc:
                raise FlightError(f"{name}: the camera ({given.source}) does not fit its {found.width}x{found.height} "
                                  f"px frames: {exc}; send the camera file of the camera that filmed it") from None
        return flight

    @staticmethod
    def _given_camera(flight: Flight, snap: Snapshot, carried: Camera | None) -> Camera | None:
        """The camera a flight is tracked with: its own camera file, else the workspace's camera, else
        the one its bag carries; None: the assumed field of view."""
        return flight.camera or snap.camera or carried

    def _check_room(self) -> None:
        with self._lock:
            if len(self._flights) >= self.max_flights:
                raise Conflict(self._full())

    def _full(self) -> str:
        return (f"{self.max_flights} flights are held, as many as this server keeps: delete one first, or start "
                "the server with a higher --max-flights")

    def remove(self, flight_id: str) -> None:
        """Forget a flight and delete its files; KeyError when there is none."""
        with self._lock:
            flight = self._flights.pop(flight_id)
        shutil.rmtree(flight.folder, ignore_errors=True)
        self._changed()

    def set_cursor(self, flight_id: str, frame: int) -> Flight:
        """Note that the page shows frame `frame` of the flight (the 3D scene follows it); KeyError when
        there is no such flight, IndexError when it has no such frame."""
        with self._lock:
            flight = self._flights[flight_id]
            if not 0 <= frame < max(len(flight.records), 1):
                raise IndexError(frame)
            flight.cursor = frame
        self._publish("flight_cursor", {"id": flight_id, "frame": frame})
        return flight

    def progress(self) -> dict:
        """The `flights` event payload: every flight's id, status and progress."""
        with self._lock:
            return {"flights": [{"id": f.id, "status": f.status, "done": f.done, "total": f.total,
                                 "result_version": f.result_version} for f in self._flights.values()]}

    def _changed(self) -> None:
        self._publish("flights", self.progress())

    # ---- processing

    def on_event(self, event: Event) -> None:
        """Workspace changes that change what a flight's tracking gives: re-run every flight."""
        if event.kind in ("settings", "camera", "library"):
            with self._lock:
                self._wake.notify_all()

    def _due(self) -> Flight | None:
        """The first flight whose records are not of the current snapshot. The caller holds the lock."""
        generation = self._snapshot().generation
        return next((f for f in self._flights.values() if f.generation != generation), None)

    def _loop(self) -> None:
        while True:
            with self._wake:
                self._wake.wait_for(lambda: self._closed or self._due() is not None)
                if self._closed:
                    return
                flight = self._due()
            if flight is not None:
                try:
                    self._run(flight, self._snapshot())
                except Exception:  # a defect on one flight must not stop the others
                    log.exception("tracking flight %s failed", flight.name)
                    self._finish(flight, self._snapshot().generation, error="tracking failed: see the server's log")

    def _stale(self, flight: Flight, snap: Snapshot) -> bool:
        """Whether the run of `flight` under `snap` is pointless now: a newer change, the flight
        removed, or the server closing."""
        return self._closed or snap is not self._snapshot() or self._flights.get(flight.id) is not flight

    def _run(self, flight: Flight, snap: Snapshot) -> None:
        with self._lock:
            flight.status, flight.done = "processing", 0
        self._changed()
        try:
            source = open_source(flight.source, topic=flight.topic, max_pixels=self.max_pixels)
        except SourceError as exc:
            self._finish(flight, snap.generation, error=str(exc).replace(str(flight.source), flight.name))
            return
        with source:
            given = self._given_camera(flight, snap, source.camera)
            camera = given if given is not None else assumed_camera(flight.width, flight.height, snap.assumed_hfov_deg)
            tracker = Tracker(snap.library, snap.settings, camera, fps=source.fps)
            warnings = [w.replace(str(flight.source), flight.name) for w in source.warnings]
            outcome = self._track(flight, snap, source, tracker, warnings)
        if outcome is None:
            return   # stopped: it runs again under the newer state
        records, stamps, jpegs, error = outcome
        self._finish(flight, snap.generation, records=records, stamps=stamps, jpegs=jpegs, warnings=warnings,
                     camera=tracker.camera, error=error)

    def _track(self, flight: Flight, snap: Snapshot, source: FrameSource, tracker: Tracker, warnings: list[str],
               ) -> tuple[list[dict], list[int | None], list[bytes], str | None] | None:
        """Every frame of `source` tracked: (records, stamps, JPEG frames, why it ended early or None);
        None when the run was stopped for a newer one."""
        records: list[dict] = []
        stamps: list[int | None] = []
        jpegs = list(flight.jpegs)   # a re-run reads the same frames: those kept stay
        error = None
        last_report = time.monotonic()
        frames: Iterator = tracked_frames(source, tracker, flight.name)
        while True:
            if self._stale(flight, snap):
                return None
            try:
                tracked = next(frames, None)
            except SourceError as exc:
                error = str(exc).replace(str(flight.source), flight.name)
                break
            except CameraError as exc:
                error = f"{flight.name}: the camera does not fit its frames: {exc}"
                break
            if tracked is None:
                break
            frame, _, record = tracked
            if len(records) >= self.max_frames:
                warnings.append(f"only the first {self.max_frames} frames are held (signpose serve "
                                "--max-flight-frames)")
                break
            records.append(record)
            stamps.append(frame.stamp_ns)
            if len(jpegs) < len(records):
                jpegs.append(frame_jpeg(frame.image))
            with self._lock:
                flight.done = len(records)
            if time.monotonic() - last_report > PROGRESS_INTERVAL_S:
                last_report = time.monotonic()
                self._changed()
        return records, stamps, jpegs, error

    def _finish(self, flight: Flight, generation: int, *, records: list[dict] | None = None,
                stamps: list[int | None] | None = None, jpegs: list[bytes] | None = None,
                warnings: list[str] | None = None, camera: Camera | None = None, error: str | None = None) -> None:
        with self._lock:
            flight.generation = generation
            flight.error = error
            if records:
                flight.records, flight.stamps = records, stamps or []
                flight.jpegs = jpegs or []
                flight.tracked_camera = camera
                flight.intrinsics = camera_json(camera) if camera is not None else None
                flight.warnings = warnings or []
                flight.total = len(records)
                flight.cursor = min(flight.cursor, len(records) - 1)
            flight.done = len(flight.records)
            flight.status = "error" if error is not None and not records else "done"
            flight.result_version += 1
        self._changed()

    def export(self, flight: Flight, suffix: str) -> Path:
        """The flight's records written by `open_flight_output` to a file of `suffix` (.mcap, .csv, .jsonl) in
        its folder, the frames with them in an MCAP of a video; the caller sends it and deletes it."""
        with self._lock:
            records, stamps, jpegs = flight.records, flight.stamps, flight.jpegs
        images = flight.kind == "video" and suffix == ".mcap"
        path = flight.folder / f"export-{secrets.token_hex(4)}{suffix}"
        with open_flight_output(path) as output:
            for i, record in enumerate(records):
                image = cv2.imdecode(np.frombuffer(jpegs[i], np.uint8), cv2.IMREAD_COLOR) if images else None
                output.write(record, image=image, stamp_ns=stamps[i])
        return path

    def close(self) -> None:
        """Stop the thread (after the frame being tracked) and delete every flight's files."""
        with self._lock:
            self._closed = True
            self._wake.notify_all()
        self._thread.join(timeout=10)
        shutil.rmtree(self._folder, ignore_errors=True)
