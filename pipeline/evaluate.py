"""Accuracy and timing on labelled datasets: the paper's Table 1, plus pose and corner errors.

A dataset is a folder of images labelled either by `truth.json` (written by `pipeline.synth`)::

    {"camera": "camera.yaml",
     "images": {"scene_000.jpg": {"label": "security_compound", "category": "easy",
                                  "R": [[...]x3], "t": [...], "H": [[...]x3], "corners": [[x, y]x4]}}}

(only "label" is required; pose fields may be null) or by sub-folders named after the sign ids,
`dir/<label>/*.jpg`, where `none` or `negative` holds images without a sign. A `camera.yaml`
next to them is used when no camera is given.

Errors are measured where the truth has a pose and the sign was identified correctly:
rotation as the geodesic angle between true and estimated R (degrees), translation as
|t_est - t_true| / |t_true| (percent of the camera-sign distance), the camera's position in
the sign frame as |C_est - C_true| with C = -Rᵀt (metres: what localisation uses, where a tilt
error swings the camera around the sign while t stays put), corners as the mean distance of the
four corners (image px).
"""

from __future__ import annotations

import ctypes
import math
import multiprocessing
import multiprocessing.connection
import os
import pickle
import queue
import reprlib
import signal
import threading
import traceback
import unicodedata
from collections.abc import Callable, Generator, Sequence

from concurrent.futures.process import BrokenProcessPool
from contextlib import closing
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess
from multiprocessing.sharedctypes import Synchronized
from pathlib import Path

import cv2
import numpy as np

from .camera import ASSUMED_HFOV_DEG, Camera, CameraError, load_camera
from .exif import ExifCamera
from .features import library_affine_features, library_features
from .image import ImageError, decode_image, exif_orientation, read_file
from .jsonfile import read_json
from .library import NO_SIGN, Library
from .pose import camera_position, rotation_error_deg
from .recognize import PipelineError, Recognition, run_pipeline
from .settings import Settings
from .stages import StageCache

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
NEGATIVE_FOLDERS = {"none", "negative"}
CORES = os.cpu_count() or 1  # os.cpu_count() is None where it cannot tell


class DatasetError(ValueError):
    """A dataset folder or truth file that cannot be used; the message says which and why."""


@dataclass(eq=False)
class Sample:
    """One labelled image. `label` None means no sign; pose fields are None when unknown.

    R (3, 3), t (3,) metres: X_cam = R·X_sign + t. H (3, 3): library px -> image px.
    corners (4, 2): image px, TL, TR, BR, BL. `params`: whatever else the truth recorded.
    """

    path: Path
    label: str | None
    category: str | None = None
    R: np.ndarray | None = field(default=None, repr=False)
    t: np.ndarray | None = field(default=None, repr=False)
    H: np.ndarray | None = field(default=None, repr=False)
    corners: np.ndarray | None = field(default=None, repr=False)
    params: dict = field(default_factory=dict, repr=False)


@dataclass(eq=False)
class Dataset:
    """A named list of samples and, when the folder has one, its camera."""

    name: str
    root: Path
    samples: list[Sample]
    camera: Camera | None = None

    def __len__(self) -> int:
        return len(self.samples)


@dataclass(eq=False)
class ImageResult:
    """The pipeline's answer on one sample and its errors against the truth (None: not measurable)."""

    dataset: str
    sample: Sample
    predicted: str | None
    time_ms: float
    rotation_error_deg: float | None = None
    translation_error_pct: float | None = None
    position_error_m: float | None = None
    corner_error_px: float | None = None
    error: str | None = None  # the image could not be read

    @property
    def correct(self) -> bool:
        return self.error is None and self.predicted == self.sample.label

    @property
    def false_positive(self) -> bool:
        return self.sample.label is None and self.predicted is not None


@dataclass(frozen=True)
class Summary:
    """Figures over a set of results. Errors are None when nothing was measurable."""

    images: int
    correct: int
    negatives: int
    false_positives: int
    mean_time_ms: float
    median_time_ms: float
    p90_time_ms: float
    rotation_deg: tuple[float, float] | None  # median, p90
    translation_pct: tuple[float, float] | None  # median, p90
    position_m: tuple[float, float] | None  # median, p90
    corner_px: tuple[float, float] | None  # median, p90

    @property
    def accuracy(self) -> float:
        return self.correct / self.images if self.images else math.nan

    def to_json(self) -> dict:
        """Counts, times in ms and errors as {"median", "p90"}; NaN and unmeasured as null."""
        def pair(value):
            return None if value is None else {"median": value[0], "p90": value[1]}
        return {"images": self.images, "correct": self.correct, "accuracy": _finite(self.accuracy),
                "negatives": self.negatives, "false_positives": self.false_positives,
                "time_ms": {"mean": _finite(self.mean_time_ms), "median": _finite(self.median_time_ms),
                            "p90": _finite(self.p90_time_ms)},
                "rotation_error_deg": pair(self.rotation_deg), "translation_error_pct": pair(self.translation_pct),
                "position_error_m": pair(self.position_m), "corner_error_px": pair(self.corner_px)}


def _finite(value: float) -> float | None:
    """`value`, or None for NaN (JSON has no NaN)."""
    return None if math.isnan(value) else value


@dataclass(eq=False)
class Report:
    """Per-image results, per-dataset summaries and the confusion matrix over `labels`.

    confusion[i, j] counts images whose truth is labels[i] and answer labels[j]; the last label
    is "none" (no sign).
    """

    settings: Settings
    results: list[ImageResult]
    datasets: dict[str, Summary]
    total: Summary
    labels: list[str]
    confusion: np.ndarray

    def to_json(self) -> dict:
        """`signpose evaluate --json`: the settings, each dataset's summary and the total, the
        confusion matrix, and every image's answer and errors against the truth."""
        return {
            "settings": self.settings.to_dict(),
            "datasets": {name: s.to_json() for name, s in self.datasets.items()},
            "total": self.total.to_json(),
            "labels": self.labels,
            "confusion": self.confusion.tolist(),
            "images": [{"dataset": r.dataset, "image": str(r.sample.path), "truth": r.sample.label or NO_SIGN,
                        "answer": None if r.error is not None else r.predicted or NO_SIGN, "correct": r.correct,
                        "time_ms": _finite(r.time_ms), "rotation_error_deg": r.rotation_error_deg,
                        "translation_error_pct": r.translation_error_pct, "position_error_m": r.position_error_m,
                        "corner_error_px": r.corner_error_px,
                        "error": r.error} for r in self.results],
        }


def _matrix(value, shape: tuple[int, ...], what: str) -> np.ndarray | None:
    if value is None:
        return None
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{what} must be numbers") from None
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise DatasetError(f"{what} must be {'x'.join(map(str, shape))} finite numbers; got shape {array.shape}")
    return array


def _is_file(path: Path) -> bool:
    """Whether `path` is a file; False, not OSError, for a name longer than the file system allows (its
    message would quote it whole)."""
    try:
        return path.is_file()
    except OSError:
        return False


def _load_truth(root: Path) -> tuple[list[Sample], Path | None]:
    truth_path = root / "truth.json"
    truth = read_json(truth_path, DatasetError)
    images = truth.get("images") if isinstance(truth, dict) else None
    if not isinstance(truth, dict) or not isinstance(images, dict) or not images:
        raise DatasetError(f'{truth_path} must hold {{"images": {{"file.jpg": {{"label": ...}}}}}} '
                           "with at least one image")
    samples = []
    for name, entry in images.items():
        where = f"{truth_path} image {reprlib.repr(name)}"
        if not isinstance(entry, dict) or "label" not in entry:
            raise DatasetError(f'{where}: each image needs an object with "label" (a sign id or null)')
        label = entry["label"]
        if label is not None and not isinstance(label, str):
            raise DatasetError(f"{where}: label must be a sign id or null; got {reprlib.repr(label)}")
        path = root / name
        if not _is_file(path):
            raise DatasetError(f"{where}: file not found in {root}")
        samples.append(Sample(
            path, label, entry.get("category"),
            _matrix(entry.get("R"), (3, 3), f"{where}: R"), _matrix(entry.get("t"), (3,), f"{where}: t"),
            _matrix(entry.get("H"), (3, 3), f"{where}: H"), _matrix(entry.get("corners"), (4, 2), f"{where}: corners"),
            entry.get("params") or {},
        ))
    return samples, _named_camera(root, truth_path, truth.get("camera"))


def _named_camera(root: Path, truth_path: Path, name) -> Path | None:
    """The camera file truth.json's "camera" names, relative to `root`; None when it names none. A named file
    that is missing is refused, as a missing image is: ignoring it measured the poses under an assumed field of
    view without a word."""
    if name is None:
        return None
    if not isinstance(name, str):
        raise DatasetError(f'{truth_path}: "camera" must be a camera file name; got {reprlib.repr(name)}')
    path = root / name
    if not _is_file(path):
        raise DatasetError(f'{truth_path}: the "camera" file {reprlib.repr(name)} is not a file in {root}; '
                           'put the camera file there, or remove "camera" from truth.json')
    return path


def _load_folders(root: Path) -> list[Sample]:
    samples = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        label = None if folder.name.lower() in NEGATIVE_FOLDERS else folder.name
        category = "negative" if label is None else None
        samples += [Sample(path, label, category) for path in sorted(folder.iterdir())
                    if path.suffix.lower() in IMAGE_SUFFIXES]
    return samples


def load_dataset(root: str | Path) -> Dataset:
    """Samples of the dataset folder `root`, labelled by `truth.json` or by sub-folder names."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root} is not a folder")
    camera_path = root / "camera.yaml"
    if (root / "truth.json").is_file():
        samples, named = _load_truth(root)
        camera_path = named or camera_path
    else:
        samples = _load_folders(root)
    if not samples:
        raise DatasetError(f"{root}: no truth.json and no images in label sub-folders (<label>/*.jpg, none/*.jpg)")
    camera = None
    if camera_path.is_file():
        try:
            camera = load_camera(camera_path)
        except CameraError as exc:
            raise DatasetError(str(exc)) from None
    return Dataset(root.name, root, samples, camera)


def _percentiles(values: list[float]) -> tuple[float, float] | None:
    if not values:
        return None
    return float(np.median(values)), float(np.percentile(values, 90))


def summarize(results: Sequence[ImageResult]) -> Summary:
    """Counts, times and error percentiles over `results` (any subset: a dataset, a category)."""
    times = [r.time_ms for r in results if r.error is None] or [math.nan]

    def errors(name: str) -> list[float]:
        return [getattr(r, name) for r in results if getattr(r, name) is not None]

    return Summary(
        images=len(results),
        correct=sum(r.correct for r in results),
        negatives=sum(r.sample.label is None for r in results),
        false_positives=sum(r.false_positive for r in results),
        mean_time_ms=float(np.mean(times)),
        median_time_ms=float(np.median(times)),
        p90_time_ms=float(np.percentile(times, 90)),
        rotation_deg=_percentiles(errors("rotation_error_deg")),
        translation_pct=_percentiles(errors("translation_error_pct")),
        position_m=_percentiles(errors("position_error_m")),
        corner_px=_percentiles(errors("corner_error_px")),
    )


Job = tuple[str, Sample, Camera | None]  # dataset name, sample, camera (None: an assumed field of view)
# Called with an image file's bytes and name before they are decoded; raises ImageError to refuse
# the image, e.g. when its header claims more pixels than memory allows (a decompression bomb).
ImageCheck = Callable[[bytes, str], object]


@dataclass(eq=False)
class Outcome:
    """What the pipeline answered on one image under one set of settings, without the truth: what a
    result store keeps and a cluster's worker sends back.

    label: the sign recognised (None: no sign); margin: the winner's inlier margin over the runner-up;
    time_ms: the pipeline's time; R (3, 3), t (3,) metres: the pose, X_cam = R·X_sign + t; corners (4, 2):
    image px, TL, TR, BR, BL; error: why the image could not be used (the rest is then empty).
    """

    label: str | None = None
    by_plaque: bool = False
    margin: int = 0
    time_ms: float = math.nan
    R: np.ndarray | None = field(default=None, repr=False)
    t: np.ndarray | None = field(default=None, repr=False)
    corners: np.ndarray | None = field(default=None, repr=False)
    error: str | None = None

    @property
    def recognized(self) -> bool:
        return self.label is not None

    @classmethod
    def of(cls, rec: Recognition) -> Outcome:
        pose = rec.pose
        return cls(rec.label, rec.by_plaque, rec.margin, rec.timing_ms["total"], None if pose is None else pose.R,
                   None if pose is None else pose.t, rec.corners)

    def to_json(self) -> dict:
        """JSON that `from_json` reads back to the same values (floats in full)."""
        def array(value: np.ndarray | None) -> list | None:
            return None if value is None else np.asarray(value, dtype=np.float64).tolist()
        return {"label": self.label, "by_plaque": self.by_plaque, "margin": int(self.margin),
                "time_ms": _finite(float(self.time_ms)), "R": array(self.R), "t": array(self.t),
                "corners": array(self.corners), "error": self.error}

    @classmethod
    def from_json(cls, data: dict) -> Outcome:
        def array(value: list | None) -> np.ndarray | None:
            return None if value is None else np.asarray(value, dtype=np.float64)
        return cls(data["label"], data["by_plaque"], data["margin"],
                   math.nan if data["time_ms"] is None else data["time_ms"], array(data["R"]), array(data["t"]),
                   array(data["corners"]), data["error"])


def outcomes_of(data: bytes, name: str, camera: Camera | None, library: Library, variants: Sequence[Settings],
                check_image: ImageCheck | None = None) -> list[Outcome]:
    """The pipeline's `Outcome` on the image file's bytes `data` (called `name`) under each of `variants`, in
    order; each the image's error when it cannot be used. The image is decoded once; with several variants,
    each run reuses what the runs before it computed (a `StageCache`, as the page's sweep does).

    `camera` describes the pixels as stored, and the assumed field of view spans the sensor as it stored them:
    either is turned as the photo's EXIF orientation turned it.
    """
    try:
        if check_image is not None:
            check_image(data, name)
        image = decode_image(data, name)
        orientation = ExifCamera(orientation=exif_orientation(data))
        camera = orientation.camera_for(camera, image.shape[1], image.shape[0], ASSUMED_HFOV_DEG)
    # CameraError: the camera cannot be turned or scaled to this image
    except (ImageError, CameraError) as exc:
        return [Outcome(error=str(exc)) for _ in variants]
    cache = StageCache() if len(variants) > 1 else None
    outcomes = []
    for settings in variants:
        try:
            outcomes.append(Outcome.of(run_pipeline(name, image, library, settings, camera, cache)))
        # CameraError: the camera cannot be scaled to this image; PipelineError: a failure inside the pipeline
        except (CameraError, PipelineError) as exc:
            outcomes.append(Outcome(error=str(exc)))
    return outcomes


def judged(dataset: str, sample: Sample, outcome: Outcome) -> ImageResult:
    """The `ImageResult` of `outcome`, the pipeline's answer on `sample`, against the sample's truth."""
    if outcome.error is not None:
        return ImageResult(dataset, sample, None, math.nan, error=outcome.error)
    result = ImageResult(dataset, sample, outcome.label, outcome.time_ms)
    if not result.correct or sample.label is None:
        return result
    if outcome.R is not None and outcome.t is not None and sample.R is not None and sample.t is not None:
        result.rotation_error_deg = rotation_error_deg(sample.R, outcome.R)
        result.translation_error_pct = float(100 * np.linalg.norm(outcome.t - sample.t) / np.linalg.norm(sample.t))
        result.position_error_m = float(np.linalg.norm(camera_position(outcome.R, outcome.t)
                                                       - camera_position(sample.R, sample.t)))
    if outcome.corners is not None and sample.corners is not None:
        result.corner_error_px = float(np.linalg.norm(outcome.corners - sample.corners, axis=1).mean())
    return result


def _measure(job: Job, library: Library, settings: Settings, check_image: ImageCheck | None) -> ImageResult:
    """The pipeline's answer on one job's sample and its errors against the truth."""
    dataset, sample, camera = job
    try:
        data = read_file(sample.path)
    except ImageError as exc:
        return judged(dataset, sample, Outcome(error=str(exc)))
    return judged(dataset, sample, outcomes_of(data, str(sample.path), camera, library, [settings], check_image)[0])


# glibc's mallopt parameters (malloc.h) and the values `keep_freed_memory` sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_TRIM_BYTES, _MMAP_BYTES = 128 << 20, 32 << 20  # 32 MB: glibc's largest mmap threshold

def keep_freed_memory() -> None:
    """Have glibc keep freed memory for reuse instead of returning it to the system at once.

    The pipeline allocates and frees image-sized buffers (float copies, SIFT pyramids) for
    every image. In a process's main thread glibc hands those back to the kernel and faults
    them in again: 200 scenes at 640x480 took 10.2 s there against 7.7 s on a worker thread,
    3 s of it system time; with these thresholds the main thread takes 7.6 s. Process-wide,
    so only for processes that exist to run the pipeline; no-op without glibc.
    """
    mallopt = _glibc("mallopt")
    if mallopt is not None:
        mallopt(_M_MMAP_THRESHOLD, _MMAP_BYTES)
        mallopt(_M_TRIM_THRESHOLD, _TRIM_BYTES)


def release_freed_memory() -> None:
    """Hand the memory glibc holds freed back to the system (malloc_trim); no-op without glibc.

    glibc returns only the top of each heap by itself: image-sized buffers freed between
    others stay in the process, in the arena of the thread that used them, so a server's memory
    does not fall when it drops images. For long-running processes, when they have freed much.
    """
    trim = _glibc("malloc_trim")
    if trim is not None:
        trim(0)


def _glibc(name: str):
    """The C library function `name` of this process, or None (not glibc)."""
    return getattr(ctypes.CDLL(None), name, None)


# What a worker process is handed once the calling process has the library's features: the library, the
# settings, the image check and the jobs, pickled; None when the calling process stopped before that.
Work = tuple[Library, Settings, ImageCheck | None, list[Job]]


@dataclass(eq=False)
class _Failed:
    """An error raised in a worker process and its traceback there, which a pickled exception loses."""

    error: Exception
    traceback: str


class WorkerTraceback(Exception):
    """Where in the worker process an error that `evaluate` raises again came from: the error's cause."""


def _work_through_jobs(next_job: Synchronized, work: multiprocessing.Queue, done: multiprocessing.Queue) -> None:
    """A worker process's whole life: wait for its `Work`, take jobs until none are left, sending each result
    (or the error that stopped it) back at once, and end.

    One OpenCV thread per worker: the processes already fill the cores, and more threads than cores only
    make them wait for each other. Ctrl-C reaches the whole process group: the calling process handles it
    and stops the workers after their image. Ends by os._exit once its results are in the pipe: tearing the
    interpreter down (OpenCV, numpy, the pipeline's buffers) took 30 ms that the calling process waited for.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_parent, name="exit with parent", daemon=True).start()
    cv2.setNumThreads(1)
    keep_freed_memory()
    try:
        if (given := pickle.loads(work.get())) is not None:
            library, settings, check_image, jobs = given
            while (index := _take(next_job)) < len(jobs):
                done.put((index, _measure(jobs[index], library, settings, check_image)))
    except Exception as exc:
        done.put(_Failed(exc, traceback.format_exc()))
    done.close()
    done.join_thread()
    os._exit(0)


def _exit_with_parent() -> None:
    """End this worker process as soon as the process that started it has ended. One that stops as it should
    stops its workers first; one killed outright (SIGKILL, the OOM killer) left them measuring the rest of the
    images, then waiting forever to send results nobody would read, each holding its memory."""
    multiprocessing.connection.wait([multiprocessing.parent_process().sentinel])
    os._exit(1)


def _take(next_job: Synchronized) -> int:
    """The index of the next job nobody has taken yet, shared by all the processes."""
    with next_job.get_lock():
        index = next_job.value
        next_job.value += 1
    return index


def _measure_all(jobs: list[Job], library: Library, settings: Settings, check_image: ImageCheck | None,
                 workers: int) -> Generator[ImageResult, None, None]:

    """`_measure` of every (dataset name, sample, camera) job, in order, on `workers` processes.

    Processes, not threads: OpenCV releases the GIL inside SIFT, but RANSAC, matching and pose
    are many small numpy calls that hold it. Spawned rather than forked: a fork copies OpenCV's
    thread pool in whatever state it is, and its workers hang. This process is one of the
    workers and starts at once; the others join as soon as they are up (a fraction of a
    second). Every process takes the next job from one shared counter, so none waits for
    another to hand it work, and the last images end together.
    """
    if workers <= 1 or len(jobs) <= 1:
        yield from (_measure(job, library, settings, check_image) for job in jobs)
        return
    context = multiprocessing.get_context("spawn")
    next_job, work, done = context.Value("q", 0), context.Queue(), context.Queue()
    work.cancel_join_thread()  # a worker killed before it read its work: exiting must not wait to write it
    helpers: list[BaseProcess] = []
    finished: dict[int, ImageResult] = {}
    next_result = 0
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # like the workers: one OpenCV thread per process
    try:
        _start_workers(helpers, min(workers, len(jobs)) - 1, context, next_job, work, done,
                       (library, settings, check_image, jobs))
        while next_result < len(jobs):
            if (index := _take(next_job)) < len(jobs):
                finished[index] = _measure(jobs[index], library, settings, check_image)
                finished.update(_receive(done, helpers, wait_s=0))
            else:
                finished.update(_receive(done, helpers, wait_s=0.1))
            while next_result in finished:
                yield finished.pop(next_result)
                next_result += 1
    finally:  # done, interrupted or closed early
        _stop_workers(helpers, next_job, len(jobs), done)
        cv2.setNumThreads(threads)


def _start_workers(helpers: list[BaseProcess], count: int, context: multiprocessing.context.SpawnContext,
                   next_job: Synchronized, work: multiprocessing.Queue, done: multiprocessing.Queue,
                   given: Work) -> None:
    """Start `count` worker processes into `helpers`, compute the library's features (and, for the affine
    fallback, its simulated steep views) and hand each the `given` work.

    Started first: a worker takes about 0.3 s to import numpy, OpenCV and the pipeline, which it does
    while this process computes the features (0.1-0.3 s for the sample library when not cached). The
    work goes on a queue, not in the process's arguments: those are written to the new process before
    `start` returns, and the library with its features (1.5 MB) filled the pipe, so this process sat
    idle until the worker had imported everything. Pickled here, not by the queue's thread: this process
    goes on to fill the library's caches while that thread would be pickling them. Interrupted or failing
    before the work is handed out, each worker is told there is none: it would wait for it forever.
    """
    handed = pickle.dumps(None)
    try:
        for _ in range(count):
            helper = context.Process(target=_work_through_jobs, args=(next_job, work, done), name="evaluate worker")
            helper.start()
            helpers.append(helper)
        library_features(given[0], given[1])  # computed here once, pickled to every worker with the library
        if given[1].affine_fallback:  # a batch has images without a sign, on which the affine fallback runs
            library_affine_features(given[0], given[1])
        handed = pickle.dumps(given)
    finally:
        for _ in helpers:
            work.put(handed)


def _stop_workers(helpers: list[BaseProcess], next_job: Synchronized, jobs: int, done: multiprocessing.Queue) -> None:
    """Have the worker processes `helpers` stop after their image, by leaving no job of the `jobs` to take, and wait
    until they have ended, reading and dropping the results they still send: one whose result waits for room in
    a full pipe would never end."""
    with next_job.get_lock():
        next_job.value = jobs
    while running := [helper.sentinel for helper in helpers if helper.is_alive()]:
        multiprocessing.connection.wait(running, timeout=0.1)
        _read_results(done, wait_s=0)


def _read_results(done: multiprocessing.Queue, wait_s: float) -> list[tuple[int, ImageResult] | _Failed]:
    """What the workers have sent, waiting up to `wait_s` for the first (0: not at all)."""
    received = []
    try:
        received.append(done.get(timeout=wait_s) if wait_s else done.get_nowait())
        while True:
            received.append(done.get_nowait())
    except queue.Empty:
        pass
    return received


def _receive(done: multiprocessing.Queue, helpers: list[BaseProcess], wait_s: float) -> list[tuple[int, ImageResult]]:
    """The results the worker processes `helpers` have sent, waiting up to `wait_s` for the first; raises a worker's
    error, or BrokenProcessPool if they have all ended with results still missing (one was killed: out of memory?)."""
    ended = not any(helper.is_alive() for helper in helpers)  # before reading: an ended worker has sent everything
    received = _read_results(done, wait_s)
    for item in received:
        if isinstance(item, _Failed):
            raise item.error from WorkerTraceback(item.traceback)
    if ended and not received and wait_s:
        raise BrokenProcessPool("evaluate's worker processes stopped before measuring every image")
    return [item for item in received if not isinstance(item, _Failed)]  # none is: a failure raised above


def check_labels(datasets: Sequence[Dataset], library: Library) -> None:
    """DatasetError naming the labels of `datasets` that are no sign of `library`."""
    unknown = sorted({s.label for d in datasets for s in d.samples if s.label is not None} - set(library.ids))
    if unknown:
        raise DatasetError(f"label(s) {reprlib.repr(unknown)[1:-1]} are not in the library ({', '.join(library.ids)})")


def measure(datasets: Sequence[Dataset], library: Library, settings: Settings, camera: Camera | None = None,
            workers: int | None = None, check_image: ImageCheck | None = None) -> Generator[ImageResult, None, None]:
    """Run the pipeline on every sample and compare with the truth: each sample's result, in order, as soon as
    it and those before it are done. Closed early (`contextlib.closing`) or interrupted, the worker processes
    stop after their image.

    `camera`, when given, is used for every dataset; otherwise each dataset's own camera file,
    and without one a 60° horizontal field of view across the sensor as it stored each photo
    (`ExifCamera.camera_for`).
    `workers`: processes sharing the images (default `CORES`, every core), each on one OpenCV thread,
    which is what the per-image times then measure; 1 runs them in this process.
    `check_image(data, name)`, when given, sees each file's bytes before decoding and may refuse the
    image (ImageError, reported as that image's error); it must pickle to reach the worker processes.
    """
    check_labels(datasets, library)
    return _measure_all(jobs_of(datasets, camera), library, settings, check_image, workers or CORES)


def jobs_of(datasets: Sequence[Dataset], camera: Camera | None = None) -> list[Job]:
    """Every sample of `datasets` in order, with its dataset's name and the camera it is measured with:
    `camera` when given, else its dataset's (None: an assumed field of view)."""
    return [(d.name, sample, camera or d.camera) for d in datasets for sample in d.samples]


def report_on(datasets: Sequence[Dataset], library: Library, settings: Settings,
              results: Sequence[ImageResult]) -> Report:
    """The report on `results`: `measure`'s on `datasets`, all of them or the first few (a dataset without
    any has no summary)."""
    labels = [*library.ids, NO_SIGN]
    confusion = np.zeros((len(labels), len(labels)), int)
    for r in results:
        if r.error is None:
            confusion[labels.index(r.sample.label or NO_SIGN), labels.index(r.predicted or NO_SIGN)] += 1
    by_dataset = {d.name: summarize(mine) for d in datasets if (mine := [r for r in results if r.dataset == d.name])}
    return Report(settings, list(results), by_dataset, summarize(results), labels, confusion)


def evaluate(datasets: Sequence[Dataset], library: Library, settings: Settings, camera: Camera | None = None,
             progress: Callable[[int, int], None] | None = None, workers: int | None = None,
             check_image: ImageCheck | None = None) -> Report:
    """The `report_on` every sample of `datasets`, `measure`d (see there for the options); `progress(done, total)`
    follows each image."""
    total = sum(len(d) for d in datasets)
    results: list[ImageResult] = []
    with closing(measure(datasets, library, settings, camera, workers, check_image)) as measured:
        for result in measured:
            results.append(result)
            if progress:
                progress(len(results), total)
    return report_on(datasets, library, settings, results)


def _pair(value: tuple[float, float] | None, unit: str, scale: float = 1.0) -> str:
    """(median, p90) times `scale`, in `unit`."""
    return "-" if value is None else f"{scale * value[0]:.2f} / {scale * value[1]:.2f}{unit}"


def text_columns(text: str) -> int:
    """Terminal columns `text` takes: none for combining marks (Arabic vowel signs) and format
    characters, two for wide (CJK) characters, one for the rest. `len` counts the marks, so names
    with them came out short and the columns after them shifted left."""
    return sum(0 if unicodedata.combining(c) or unicodedata.category(c) == "Cf" else
               2 if unicodedata.east_asian_width(c) in "WF" else 1 for c in text)


def pad_to(text: str, columns: int) -> str:
    """`text` left-aligned in at least `columns` terminal columns (`text_columns`)."""
    return text + " " * max(0, columns - text_columns(text))


def format_table(report: Report) -> str:
    """Readable text: per-dataset table, the confusion matrix and the images answered wrongly."""
    rows = list(report.datasets.items())
    if len(rows) > 1:
        rows.append(("all", report.total))
    name_width = max(16, *(text_columns(name) + 2 for name, _ in rows))
    head = (f"{'dataset':<{name_width}}{'images':>7}{'correct':>8}{'accuracy':>10}{'avg time':>11}{'false pos':>10}"
            f"   {'rotation med/p90':>17}{'translation med/p90':>21}{'position med/p90':>19}{'corners med/p90':>18}")
    lines = [head, "-" * len(head)]
    for name, s in rows:
        fp = f"{s.false_positives}/{s.negatives}" if s.negatives else "-"
        lines.append(f"{pad_to(name, name_width)}{s.images:>7}{s.correct:>8}{100 * s.accuracy:>9.1f}%{s.mean_time_ms:>8.1f} ms"
                     f"{fp:>10}   {_pair(s.rotation_deg, '°'):>17}{_pair(s.translation_pct, '%'):>21}"
                     f"{_pair(s.position_m, ' cm', 100):>19}"
                     f"{_pair(s.corner_px, ' px'):>18}")
    width = max(len(label) for label in report.labels) + 2
    lines += ["", "confusion (rows: truth, columns: answer)",
              " " * width + "".join(f"{label:>{width}}" for label in report.labels)]
    for label, row in zip(report.labels, report.confusion):
        lines.append(f"{label:<{width}}" + "".join(f"{n:>{width}}" for n in row))
    wrong = [r for r in report.results if not r.correct]
    if wrong:
        lines += ["", "wrong answers:"]
        for r in wrong:
            if r.error:  # an image's error names it first, as this line does
                what = r.error.removeprefix(f"{r.sample.path}: ")
            else:
                what = f"truth {r.sample.label or NO_SIGN}, answer {r.predicted or NO_SIGN}"
            lines.append(f"  {r.sample.path}: {what}")
    return "\n".join(lines)
