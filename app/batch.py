"""Images and flights in chunks, on a Dask cluster (`--dask`) or this machine's processes, with their results
kept in a `ResultStore` (`--results DIR`) so that a run cut short continues where it stopped.

The chunk functions (`image_outcomes`, `tracked_range`) run on the workers: plain Python over the pipeline,
handed the images' bytes (or, with `--shared-paths`, paths every worker can read) and the library, sent
once with its features. Results come back in any order and are put back in the jobs' order, so the output
is a local run's; a long flight is tracked in frame ranges (`tracked_range`), whose boundaries differ from a
single run as docs/cluster.md says. The Dask side is in `signpose.app.cluster`, imported only for `--dask`.
"""

from __future__ import annotations

import concurrent.futures
import itertools
import multiprocessing
import signal
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import cv2

from signpose.pipeline.camera import Camera
from signpose.pipeline.evaluate import ImageCheck, Outcome, keep_freed_memory, outcomes_of
from signpose.pipeline.features import library_affine_features, library_features
from signpose.pipeline.image import ImageError, read_file
from signpose.pipeline.library import Library
from signpose.pipeline.results import ResultStore, content_hash, files_hash, library_fingerprint, result_key
from signpose.pipeline.settings import Settings
from signpose.pipeline.sign_map import SignMap
from signpose.pipeline.stages import ALL_STAGES

EXTRA = "signpose[dask]"  # what `pip install` needs for --dask
IMAGES_PER_CHUNK = 8
# A flight's chunks: 30 s at 30 fps, each tracked after a warm-up of 1 s (`tracked_range`).
FRAMES_PER_CHUNK = 900
WARM_UP_FRAMES = 30


class BatchError(Exception):
    """A cluster that cannot be used, or a chunk that could not be run; the message says what to do."""


@dataclass(frozen=True)
class Chunk:
    """A piece of work sent to one worker: `work`, the chunk function's last argument; `name`, how the
    final table names it; `size`, how many images (or flights) it advances the progress bar."""

    name: str
    work: Any
    size: int


class Runner(Protocol):
    @property
    def slots(self) -> int:
        """Chunks it runs at once (worker processes or threads)."""

    def share(self, value: Any) -> Any: ...

    def run(self, function: Callable[..., Any], shared: tuple, chunks: Iterable[Chunk]) -> Iterator[tuple[Chunk, Any]]:
        ...

    def retried(self) -> list[str]: ...

    def close(self) -> None: ...


class LocalRunner:
    """Runs chunks on `workers` processes of this machine (spawned, one OpenCV thread each)."""

    def __init__(self, workers: int) -> None:
        self.slots = workers
        # Ctrl-C reaches the whole process group: this process stops the run, the workers finish their chunk.
        self.pool = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                           initializer=signal.signal,
                                                           initargs=(signal.SIGINT, signal.SIG_IGN))

    def share(self, value: Any) -> Any:
        return value  # pickled with each chunk

    def run(self, function: Callable[..., Any], shared: tuple, chunks: Iterable[Chunk]) -> Iterator[tuple[Chunk, Any]]:
        """(chunk, `function(*shared, chunk.work)`) as each finishes, two chunks a process in flight: the images'
        bytes of a long run are read when their turn comes."""
        pending = iter(chunks)
        running: dict[concurrent.futures.Future, Chunk] = {}
        while True:
            while len(running) < 2 * self.slots and (chunk := next(pending, None)) is not None:
                running[self.pool.submit(function, *shared, chunk.work)] = chunk
            if not running:
                return
            finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
            for future in finished:
                yield running.pop(future), future.result()

    def retried(self) -> list[str]:
        return []  # a process that dies breaks the pool: nothing is run again

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


def runner_for(address: str | None, workers: int) -> Runner:
    """A `DaskRunner` on the scheduler at `address`, else a `LocalRunner` of `workers` processes."""
    if address is None:
        return LocalRunner(workers)
    from signpose.app.cluster import DaskRunner, connect

    return DaskRunner(connect(address))


@dataclass
class Tally:
    """What a run did: items (images or flights) computed, taken from the result store, and the chunks the
    cluster ran more than once."""

    computed: int = 0
    reused: int = 0
    retried: list[str] = field(default_factory=list)

    def summary(self, unit: str) -> str:
        """One line for the end of the command's output: `unit` names the items ("images", "flights")."""
        retried = (f"{len(self.retried)} chunk(s) run again after a lost worker or an error: {', '.join(self.retried)}"
                   if self.retried else "no chunk run again")
        return f"{self.computed} {unit} computed, {self.reused} taken from --results; {retried}"


# -- images ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ImageItem:
    """One image of a chunk: its place among the jobs, its name, its bytes (or a path every worker can
    read), its camera and which of the run's settings variants it is still to be run with."""

    index: int
    name: str
    payload: bytes | str
    camera: Camera | None
    variants: tuple[int, ...]


def image_outcomes(library: Library, variants: Sequence[Settings], check_image: ImageCheck | None,
                   items: Sequence[ImageItem]) -> list[list[Outcome]]:
    """On a worker: each item's `Outcome`s under its settings variants, in the items' order."""
    worker_process()
    out = []
    for item in items:
        wanted = [variants[v] for v in item.variants]
        try:
            data = item.payload if isinstance(item.payload, bytes) else read_file(item.payload)
        except ImageError as exc:
            out.append([Outcome(error=str(exc)) for _ in wanted])
            continue
        out.append(outcomes_of(data, item.name, item.camera, library, wanted, check_image))
    return out


def worker_process() -> None:
    """Set a worker process up as the local pool's: one OpenCV thread (the processes fill the cores, and the
    per-image times compare), freed memory kept for the next image (about 25 % faster per image)."""
    cv2.setNumThreads(1)
    keep_freed_memory()


def with_features(library: Library, settings: Sequence[Settings]) -> Library:
    """`library` with its features (and simulated steep views where the affine fallback may run) computed for
    every distinct feature setting of `settings`, so that no worker computes them again."""
    for variant in settings:
        library_features(library, variant)
        if variant.affine_fallback:
            library_affine_features(library, variant)
    return library


def recognize_all(jobs: Sequence[tuple[str, Camera | None]], library: Library, variants: Sequence[Settings],
                  check_image: ImageCheck | None, *, runner: Runner, store: ResultStore | None, context: dict,
                  shared_paths: bool, images_per_chunk: int,
                  done: Callable[[int], None]) -> tuple[list[list[Outcome]], Tally]:
    """The pipeline's `Outcome` on every job (image file name, camera) under each of `variants`: [variant][job].

    Results in `store` (keyed by the image's bytes and the settings that feed recognition, with `context`:
    the library, the camera and limits) are taken from it; the rest are computed in chunks of at most
    `images_per_chunk` images on `runner` (`guided_size`) and stored as they arrive. `done(n)` follows each n
    images finished.
    An image that cannot be read here is that image's error, computed nowhere.
    """
    outcomes: list[list[Outcome | None]] = [[None] * len(jobs) for _ in variants]
    tally = Tally()
    keys: dict[int, tuple[str, list[str]]] = {}  # job index: (content hash, key per variant)
    base_context = {"kind": "recognize", "library": library_fingerprint(library), **context}

    def chunks() -> Iterator[Chunk]:
        items: list[ImageItem] = []
        size = images_per_chunk
        for index, (name, camera) in enumerate(jobs):
            if not items:
                size = guided_size(len(jobs) - index, most=images_per_chunk, slots=runner.slots)
            item = pending_item(index, name, camera)
            if item is None:
                continue
            items.append(item)
            if len(items) == size:
                yield image_chunk(items)
                items = []
        if items:
            yield image_chunk(items)

    def pending_item(index: int, name: str, camera: Camera | None) -> ImageItem | None:
        data = None
        if store is not None or not shared_paths:
            try:
                data = read_file(name)
            except ImageError as exc:
                for row in outcomes:
                    row[index] = Outcome(error=str(exc))
                done(1)
                return None
        missing = tuple(range(len(variants)))
        if store is not None and data is not None:
            content = content_hash(data)
            camera_context = {**base_context, "camera": None if camera is None else camera.to_json()}
            variant_keys = [result_key(v, ALL_STAGES, camera_context) for v in variants]
            keys[index] = (content, variant_keys)
            for v, key in enumerate(variant_keys):
                if (stored := store.get(content, key)) is not None:
                    outcomes[v][index] = Outcome.from_json(stored)
            missing = tuple(v for v in missing if outcomes[v][index] is None)
            if not missing:
                tally.reused += 1
                done(1)
                return None
        payload: bytes | str = data if data is not None and not shared_paths else str(Path(name).resolve())
        return ImageItem(index, name, payload, camera, missing)

    shared = (runner.share(with_features(library, variants)), list(variants), check_image)
    for chunk, results in runner.run(image_outcomes, shared, chunks()):
        for item, got in zip(chunk.work, results):
            for v, outcome in zip(item.variants, got):
                outcomes[v][item.index] = outcome
                if store is not None:
                    content, variant_keys = keys[item.index]
                    store.put(content, variant_keys[v], outcome.to_json())
            tally.computed += 1
        done(chunk.size)
    tally.retried = runner.retried()
    return outcomes, tally  # type: ignore[return-value]  # every place is filled above


def guided_size(left: int, *, most: int, slots: int) -> int:
    """Images in the next chunk when `left` images are still to be sent to `slots` workers: `most` while much
    is left, then smaller (a share of what is left), so that the workers finish together instead of one
    running the last full chunk while the others wait (guided self-scheduling)."""
    return max(1, min(most, -(-left // (2 * slots))))


def image_chunk(items: list[ImageItem]) -> Chunk:
    first, last = Path(items[0].name).name, Path(items[-1].name).name
    return Chunk(first if len(items) == 1 else f"{first}..{last}", list(items), len(items))


# -- flights -----------------------------------------------------------------------------------------

def source_files(spec: str) -> list[tuple[str, bytes]]:
    """A flight's files as (name relative to the source's parent, bytes): the file itself, or every file
    under the folder (a folder of frames, a rosbag2 folder), in sorted order."""
    path = Path(spec)
    if path.is_dir():
        return [(str(p.relative_to(path.parent)), p.read_bytes()) for p in sorted(path.rglob("*")) if p.is_file()]
    return [(path.name, path.read_bytes())]


def placed(files: Sequence[tuple[str, bytes]], folder: str) -> str:
    """Write a flight's `files` into `folder`: the path of its source there (the file, or the top folder)."""
    for name, data in files:
        target = Path(folder, name)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    return str(Path(folder, Path(files[0][0]).parts[0]))


@dataclass(frozen=True)
class FlightItem:
    """A frame range of a flight to track: the flight's place among the sources, the settings variant it is
    tracked with, the range's place among the flight's ranges, its name as given, the options of `signpose
    track`, and the range: frames `start` to `stop` (None: the flight's end) reported, after `warm_up` frames
    before `start` tracked and not reported."""

    index: int
    variant: int
    part: int
    name: str
    camera: Camera | None
    sign_map: SignMap | None
    topic: str | None
    fps: float | None
    max_pixels: int
    start: int
    stop: int | None
    warm_up: int


def tracked_range(library: Library, variants: Sequence[Settings],
                  work: tuple[FlightItem, list[tuple[str, bytes]] | str]) -> dict:
    """On a worker: the `signpose track --json` line of every frame of the range of `work` (the range, and its
    flight's files or a path this worker can read), and the error that cut it short
    ({"records": [...], "error": str | None}). The tracker starts cold `warm_up` frames before the
    range (a video seeks there; `FrameSource.frames_from`): a sign in view at `start` is then confirmed and its
    filter under way there, as in a run over the whole flight."""
    from signpose.pipeline.camera import CameraError
    from signpose.pipeline.frames import SourceError, open_source
    from signpose.pipeline.track import Tracker, tracked_frames

    worker_process()
    item, flight = work
    first = max(0, item.start - item.warm_up)
    with tempfile.TemporaryDirectory(prefix="signpose-flight-") as folder:
        where = flight if isinstance(flight, str) else placed(flight, folder)
        records: list[dict] = []
        try:
            with open_source(where, topic=item.topic, fps=item.fps, max_pixels=item.max_pixels) as source:
                tracker = Tracker(library, variants[item.variant],
                                  item.camera if item.camera is not None else source.camera, fps=source.fps,
                                  sign_map=item.sign_map)
                frames = itertools.takewhile(lambda frame: item.stop is None or frame.index < item.stop,
                                             source.frames_from(first))
                for _, _, record in tracked_frames(frames, tracker, item.name):
                    if record["frame"] >= item.start:
                        records.append(record)
        except (SourceError, CameraError) as exc:
            return {"records": records, "error": str(exc).replace(where, item.name)}
    return {"records": records, "error": None}


def frame_ranges(count: int | None, max_frames: int | None, frames_per_chunk: int) -> list[tuple[int, int | None]]:
    """(start, stop) of the chunks of a flight of `count` frames (None: not known) tracked up to `max_frames`:
    `frames_per_chunk` frames each, the last to the end (stop None, or `max_frames`). A flight whose length is
    not known is one chunk."""
    known = min(filter(None, (count, max_frames)), default=None)
    if known is None or known <= frames_per_chunk:
        return [(0, max_frames)]
    starts = list(range(0, known, frames_per_chunk))
    return [(start, start + frames_per_chunk) for start in starts[:-1]] + [(starts[-1], max_frames)]


def range_name(spec: str, start: int, stop: int | None, variant: int, variants: int) -> str:
    """How the final table names a flight's range: the flight, its frames, and which of the `variants`."""
    frames = f" frames {start}..{'end' if stop is None else stop - 1}"
    return f"{spec}{frames}" + (f" at value {variant + 1} of {variants}" if variants > 1 else "")


def joined(parts: Sequence[dict]) -> dict:
    """A flight's chunk results, in frame order, as one: the records up to the first chunk's error, with each
    chunk's track ids moved past those of the chunks before it (every chunk's tracker numbers its tracks from
    1, so a sign followed across a boundary gets a new id there)."""
    records: list[dict] = []
    offset = 0
    for part in parts:
        highest = offset
        for record in part["records"]:
            signs = [{**sign, "track_id": sign["track_id"] + offset} for sign in record["signs"]]
            highest = max([highest, *(sign["track_id"] for sign in signs)])
            records.append({**record, "signs": signs})
        if part["error"] is not None:
            return {"records": records, "error": part["error"]}
        offset = highest
    return {"records": records, "error": None}


def flight_count(spec: str, *, topic: str | None, fps: float | None, max_pixels: int) -> int | None:
    """How many frames the flight at `spec` holds, as its container says; None when it does not say or the
    source cannot be opened here (the chunk then says why)."""
    from signpose.pipeline.frames import SourceError, open_source

    try:
        with open_source(spec, topic=topic, fps=fps, max_pixels=max_pixels) as source:
            return source.count
    except SourceError:
        return None


def track_all(jobs: Sequence[tuple[str, Camera | None]], library: Library, variants: Sequence[Settings], *,
              sign_map: SignMap | None, topic: str | None, fps: float | None, max_frames: int | None, max_pixels: int,
              frames_per_chunk: int, runner: Runner, store: ResultStore | None, shared_paths: bool,
              planned: Callable[[int], None], done: Callable[[int], None]) -> tuple[list[list[dict]], Tally]:
    """Every job's flight (source, camera) tracked under each of `variants`, in chunks of `frames_per_chunk`
    frames (`tracked_range`, `WARM_UP_FRAMES` of warm-up), each taken from `store` where it holds it (keyed by
    the flight's files, every setting and the range: tracking runs every stage); joined per flight
    ([variant][job], `joined`). `planned(n)` is told the number of chunks before they run, `done(1)` follows
    each chunk."""
    context = {"kind": "track", "library": library_fingerprint(library), "topic": topic, "fps": fps,
               "max_pixels": max_pixels, "warm_up": WARM_UP_FRAMES,
               "map": None if sign_map is None else sign_map.to_json()}
    ranges = [frame_ranges(flight_count(spec, topic=topic, fps=fps, max_pixels=max_pixels), max_frames,
                           frames_per_chunk) for spec, _ in jobs]
    parts: list[list[list[dict | None]]] = [[[None] * len(r) for r in ranges] for _ in variants]
    keys: dict[tuple[int, int, int], tuple[str, str]] = {}  # (variant, job, chunk): (content hash, key)
    tally = Tally()
    planned(len(variants) * sum(map(len, ranges)))

    def chunks() -> Iterator[Chunk]:
        for index, (spec, camera) in enumerate(jobs):
            files = source_files(spec) if store is not None or not shared_paths else []
            content = files_hash(files) if store is not None else ""
            # The flight's files are shared with the workers once, when a range of it is first to be computed,
            # and each range names them: a chunk's task (a tuple, which Dask looks into) then holds no bytes.
            source = None
            for variant, settings in enumerate(variants):
                for part, (start, stop) in enumerate(ranges[index]):
                    if store is not None:
                        key = result_key(settings, ALL_STAGES, {**context, "start": start, "stop": stop,
                                                                "camera": None if camera is None else camera.to_json()})
                        keys[variant, index, part] = (content, key)
                        if (stored := store.get(content, key)) is not None:
                            parts[variant][index][part] = stored
                            tally.reused += 1
                            done(1)
                            continue
                    if source is None:
                        source = str(Path(spec).resolve()) if shared_paths else runner.share(files)
                    item = FlightItem(index, variant, part, spec, camera, sign_map, topic, fps, max_pixels,
                                      start, stop, WARM_UP_FRAMES)
                    yield Chunk(range_name(spec, start, stop, variant, len(variants)), (item, source), 1)

    shared = (runner.share(with_features(library, variants)), list(variants))
    for chunk, result in runner.run(tracked_range, shared, chunks()):
        item, _ = chunk.work
        parts[item.variant][item.index][item.part] = result
        if store is not None and result["error"] is None:
            store.put(*keys[item.variant, item.index, item.part], result)
        tally.computed += 1
        done(1)
    tally.retried = runner.retried()
    return [[joined(flight) for flight in row] for row in parts], tally  # type: ignore[arg-type]  # all filled
