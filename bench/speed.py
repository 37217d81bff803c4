"""Speed benchmark: a naive OpenCV-tutorial pipeline, the `paper` and `default` presets side by side.

The same N synthetic scenes (pipeline.synth, fixed seed, easy / hard / negative mix) at
640x480 and at 1280x960 (the same seed gives the same scenes at either size). Each configuration
runs over all the images in turn, taking turns with the others, --rounds times; per image the
fastest run of each is kept (`measure`). Per configuration: median and p90 ms per image, the
mean of each stage, the peak memory of a fresh process, accuracy by category beside it, and the
median over images of naive time / configuration time. Then: SIFT alone on the crop each preset chose (the floor the
pipeline cannot go below), a RANSAC and a ratio slider change re-run on the loaded images with
their StageCaches, evaluate's wall time on 2 worker processes against 1, and a full re-run of
every image in `signpose serve`'s Workspace on one pipeline worker per core against one.

    python bench/speed.py [--n 200] [--seed 0] [--rounds 3] [--data DIR] [--quick] [--also SETTING=VALUE ...]

`--also` adds a configuration beside the others: the default preset with settings changed.

Scenes are rendered once into --data (default: signpose-speed in the temp folder) and re-used;
1280x960 takes several seconds a scene, so the first run renders for a while.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
from tqdm import tqdm

import signpose.pipeline.recognize as recognize_module
from signpose.app.rerun import share_cores
from signpose.app.workspace import Workspace, WorkspaceConfig
from signpose.pipeline.camera import Camera
from signpose.pipeline.evaluate import Dataset, evaluate, keep_freed_memory, load_dataset
from signpose.pipeline.features import detect
from signpose.pipeline.image import read_image, to_gray
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.pose import rotation_error_deg
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import Settings, SettingsError, preset
from signpose.pipeline.stages import STAGES, StageCache
from signpose.pipeline.synth import CATEGORIES, RENDERING, generate_dataset

SIZES = ((640, 480), (1280, 960))
# name -> the settings it runs the pipeline with; the naive reference (None) runs its own code.
CONFIGS: dict[str, Settings | None] = {"naive": None, "paper": preset("paper"), "default": preset("default")}
PRESETS = ("paper", "default")  # the configurations with a floor: SIFT on the crop they chose
MIN_MATCH_COUNT = 10  # the tutorial's: fewer inliers is "no sign"


@dataclass(frozen=True)
class Outcome:
    """One configuration on one image: its answer, rotation (3, 3) or None, ms per stage plus
    "total", and how many regions it ran SIFT on (the naive reference: the full frame, 1)."""

    label: str | None
    R: np.ndarray | None
    timing_ms: dict[str, float]
    regions: int = 1


def naive_recognize(image: np.ndarray, library: Library, camera: Camera) -> Outcome:
    """What a user writes from OpenCV's feature-homography tutorial, timed per stage.

    Gray conversion and SIFT on the full frame; every library image's SIFT recomputed for each query; brute-force
    2-NN with Lowe's ratio 0.75; cv2.findHomography RANSAC at 5 px per sign; the sign with most
    inliers wins if it has MIN_MATCH_COUNT of them; cv2.solvePnP on its four projected corners.
    """
    timing = dict.fromkeys(STAGES, 0.0)
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timing[stage] += (now - clock) * 1e3
        clock = now

    sift = cv2.SIFT_create()
    kp, des = sift.detectAndCompute(to_gray(image), None)
    signs = [(sign, *sift.detectAndCompute(sign.image, None)) for sign in library.signs]
    lap("features")
    best = (0, None, None)
    for sign, kp_sign, des_sign in signs if des is not None and len(kp) >= 2 else ():
        pairs = cv2.BFMatcher().knnMatch(des_sign, des, k=2)
        good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.75 * n.distance]
        lap("match")
        if len(good) >= 4:
            src = np.float32([kp_sign[m.queryIdx].pt for m in good]).reshape(-1, 1, 2)
            dst = np.float32([kp[m.trainIdx].pt for m in good]).reshape(-1, 1, 2)
            H, mask = cv2.findHomography(src, dst, cv2.RANSAC, 5.0)
            if H is not None and mask.sum() > best[0]:
                best = (int(mask.sum()), sign, H)
        lap("ransac")
    inliers, sign, H = best
    if inliers < MIN_MATCH_COUNT:
        timing["total"] = sum(timing.values())
        return Outcome(None, None, timing)
    corners = cv2.perspectiveTransform(sign.corners_px.reshape(-1, 1, 2), H)
    _, rvec, _ = cv2.solvePnP(sign.to_metric(sign.corners_px), corners, camera.K, camera.dist)
    lap("pose")
    timing["total"] = sum(timing.values())
    return Outcome(sign.id, cv2.Rodrigues(rvec)[0], timing)


def runner(settings: Settings | None) -> Callable[[np.ndarray, Library, Camera], tuple[Outcome, tuple | None]]:
    """(image -> (Outcome, region the answer came from or None)) for the pipeline with `settings`,
    or for the naive reference (None)."""
    if settings is None:
        return lambda image, library, camera: (naive_recognize(image, library, camera), None)

    def run(image: np.ndarray, library: Library, camera: Camera) -> tuple[Outcome, tuple | None]:
        rec = recognize(image, library, settings, camera)
        region = rec.attempt.region if rec.attempt is not None else None
        return (Outcome(rec.label, rec.pose.R if rec.pose is not None else None, rec.timing_ms, len(rec.attempts)),
                region)
    return run


def scenes(data: Path, size: tuple[int, int], n: int, seed: int, library: Library) -> Dataset:
    """The first n scenes of `size` (w, h) from `seed`, rendered into `data` unless already there."""
    root = data / f"{size[0]}x{size[1]}-seed{seed}-r{RENDERING}"
    if not (root / "truth.json").is_file() or len(load_dataset(root)) < n:
        with tqdm(total=n, desc=f"render {size[0]}x{size[1]}", unit="scene") as bar:
            generate_dataset(root, library, n=n, seed=seed, size=size, progress=lambda i, total: bar.update(1))
    dataset = load_dataset(root)
    dataset.samples = dataset.samples[:n]
    return dataset


def floor_ms(gray: np.ndarray, settings: Settings, region: tuple | None) -> float:
    """ms of the pipeline's own SIFT (crop resizing included) on `region` alone."""
    t0 = time.perf_counter()
    detect(gray, settings, region)
    return (time.perf_counter() - t0) * 1e3


def measure(dataset: Dataset, library: Library, rounds: int,
            configs: dict[str, Settings | None] = CONFIGS) -> tuple[dict[str, list[Outcome]], dict[str, list[float]]]:
    """Every configuration in `configs` (name -> settings, None for the naive reference) on every
    image, `rounds` times, and the floor of each pipeline configuration's run.

    A round runs each configuration over all the images in turn, as `signpose evaluate` or the
    server runs one, so each runs with the caches its own work leaves (run back to back on each
    image, the default preset ran with those the naive reference had just filled); the
    configurations take turns within a round, each round started by the next of them, so that
    load hits them alike. Per image and configuration the fastest round is kept, since noise
    only adds, and likewise its floor.
    """
    runs = {name: runner(settings) for name, settings in configs.items()}
    for run in runs.values():  # library features, imports and first-call costs out of the figures
        run(read_image(dataset.samples[0].path), library, dataset.camera)
    n = len(dataset.samples)
    outcomes: dict[str, list[Outcome | None]] = {name: [None] * n for name in configs}
    # nan: no region searched (paper, no blob), no floor
    floors = {name: [np.nan] * n for name, settings in configs.items() if settings is not None}
    size = f"{dataset.camera.width}x{dataset.camera.height}"
    names = list(configs)
    with tqdm(total=rounds * len(names) * n, desc=f"{size}, {rounds} rounds", unit="run") as bar:
        for r in range(rounds):
            for name in names[r % len(names):] + names[:r % len(names)]:
                run = runs[name]
                for i, sample in enumerate(dataset.samples):
                    image = read_image(sample.path)
                    outcome, region = run(image, library, dataset.camera)
                    best = outcomes[name][i]
                    if best is None or outcome.timing_ms["total"] < best.timing_ms["total"]:
                        outcomes[name][i] = outcome
                    if name in floors and region is not None:
                        floors[name][i] = np.fmin(floors[name][i], floor_ms(to_gray(image), configs[name], region))
                    bar.update()
    return outcomes, floors


def _rss_kb(field: str) -> int:
    """A `VmRSS` / `VmHWM` line of /proc/self/status, in kB."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith(field + ":"))


def _peak_rss_mb(settings: Settings | None, paths: list[Path], camera: Camera) -> float:
    """In a fresh process: peak RSS (MB) above the process's own after loading and one warm-up image,
    running the pipeline with `settings` (None: the naive reference).

    Linux: writing 5 to /proc/self/clear_refs resets the peak (VmHWM) to the current RSS.
    """
    library, run = load_library(), runner(settings)
    run(read_image(paths[0]), library, camera)
    images = [read_image(p) for p in paths]
    Path("/proc/self/clear_refs").write_text("5")
    baseline = _rss_kb("VmRSS")
    for image in images:
        run(image, library, camera)
    return (_rss_kb("VmHWM") - baseline) / 1024


def peak_memory(dataset: Dataset, count: int, configs: dict[str, Settings | None] = CONFIGS) -> dict[str, float]:
    """`_peak_rss_mb` of each configuration of `configs` over the first `count` images, each in a new process."""
    paths = [s.path for s in dataset.samples[:count]]
    peaks = {}
    for name, settings in configs.items():
        with ProcessPoolExecutor(1, multiprocessing.get_context("spawn")) as pool:
            peaks[name] = pool.submit(_peak_rss_mb, settings, paths, dataset.camera).result()
    return peaks


def rerun(dataset: Dataset, library: Library) -> list[str]:
    """Time slider changes over all loaded images, each with its StageCache, as `signpose serve`
    re-runs them: one image after another, and on a pool of one thread per core like its own.

    Checks that features are not extracted again: a region the first run already searched must
    come from the cache.
    """
    settings = preset("default")
    images = [read_image(s.path) for s in dataset.samples]
    caches = [StageCache() for _ in images]
    t0 = time.perf_counter()
    searched = [{a.region for a in recognize(im, library, settings, dataset.camera, c).attempts}
                for im, c in zip(images, caches)]
    lines = [f"{len(images)} images loaded and run once: {time.perf_counter() - t0:.2f} s"]
    changes = {"RANSAC threshold": {"ransac_threshold_px": settings.ransac_threshold_px - 1.0},
               "ratio": {"ratio": settings.ratio + 0.05}}
    for what, change in changes.items():
        changed = settings.replace(**change)
        with mock.patch.object(recognize_module, "detect", wraps=detect) as spy:
            t0 = time.perf_counter()
            again = 0
            for image, cache, regions in zip(images, caches, searched):
                spy.reset_mock()
                recognize(image, library, changed, dataset.camera, cache)
                again += sum(call.args[2] in regions for call in spy.call_args_list)
            alone = time.perf_counter() - t0
        with ThreadPoolExecutor(os.cpu_count()) as pool:
            t0 = time.perf_counter()
            list(pool.map(lambda job: recognize(job[0], library, changed, dataset.camera, job[1]), zip(images, caches)))
            pooled = time.perf_counter() - t0
        lines.append(f"one {what} change, all {len(images)} re-run: {alone:.2f} s one by one "
                     f"({alone / len(images) * 1e3:.1f} ms an image), {pooled:.2f} s on {os.cpu_count()} threads; "
                     f"features re-extracted: {again}")
    return lines


def best_times(runs: dict[str, tuple[int, Callable[[], None]]], repeats: int) -> dict[str, float]:
    """Best wall time in s of each (OpenCV threads, run) over `repeats` rounds, alternated so
    that load hits them alike."""
    threads = cv2.getNumThreads()
    best = dict.fromkeys(runs, np.inf)
    for _ in range(repeats):
        for name, (opencv_threads, run) in runs.items():
            cv2.setNumThreads(opencv_threads)
            t0 = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - t0)
    cv2.setNumThreads(threads)
    return best


def batch_speedup(dataset: Dataset, library: Library, repeats: int) -> str:
    """evaluate's wall time on 1 core, on 1 worker whose OpenCV calls use every core, and on 2
    worker processes; best of `repeats` each."""
    settings, threads = preset("default"), cv2.getNumThreads()
    best = best_times({"1 worker on 1 core": (1, lambda: evaluate([dataset], library, settings, workers=1)),
                       "1 worker, OpenCV on all cores": (threads, lambda: evaluate([dataset], library, settings,
                                                                                    workers=1)),
                       "2 workers": (threads, lambda: evaluate([dataset], library, settings, workers=2))}, repeats)
    return (f"evaluate on {len(dataset)} images, best of {repeats}: "
            + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in best.items())
            + f"; 2 workers vs 1 core {best['1 worker on 1 core'] / best['2 workers']:.2f}x, "
            f"vs 1 worker {best['1 worker, OpenCV on all cores'] / best['2 workers']:.2f}x")


def server_speedup(dataset: Dataset, repeats: int) -> str:
    """A full re-run of every loaded image in `signpose serve`'s Workspace (a features setting
    changed, so nothing is cached) on 1 pipeline worker on 1 core and on one worker per core
    with the OpenCV threads `signpose serve` chooses (`share_cores`)."""
    uploads = [(s.path.name, s.path.read_bytes(), s.label) for s in dataset.samples]
    best = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers, name in ((1, "1 worker on 1 core"), (os.cpu_count() or 1, f"{os.cpu_count()} workers")):
            config = WorkspaceConfig(state_dir=Path(tmp) / name, load_samples=False, workers=workers,
                                     debounce_s=0.0)
            threads = share_cores(workers)  # as `signpose serve` starts
            workspace = Workspace.open(config)
            opencv_threads = 1 if workers == 1 else cv2.getNumThreads()
            try:
                workspace.set_camera(dataset.camera)
                workspace.add_images(uploads)
                workspace.wait_idle(3600)
                contrast = iter(np.linspace(0.031, 0.039, 2 * repeats))

                def rerun_all() -> None:
                    workspace.update_settings({"contrast_threshold": float(next(contrast))})
                    workspace.wait_idle(3600)

                best |= best_times({name: (opencv_threads, rerun_all)}, repeats)
            finally:
                workspace.close()
                cv2.setNumThreads(threads)
    one, many = best.values()
    return (f"signpose serve, all {len(uploads)} images re-run after a features change, best of {repeats}: "
            + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in best.items()) + f"; {one / many:.2f}x")


def identified_percent(outcomes: list[Outcome], dataset: Dataset, category: str) -> str:
    hits = [o.label == s.label for o, s in zip(outcomes, dataset.samples) if s.category == category]
    return f"{100 * sum(hits) / len(hits):.0f}%" if hits else "-"


def rotation_median(outcomes: list[Outcome], dataset: Dataset) -> str:
    errors = [rotation_error_deg(s.R, o.R) for o, s in zip(outcomes, dataset.samples)
              if s.label is not None and o.label == s.label and o.R is not None]
    return f"{statistics.median(errors):.2f}" if errors else "-"


def table(dataset: Dataset, outcomes: dict[str, list[Outcome]], memory: dict[str, float]) -> list[str]:
    """One row per configuration: times, stages, memory, accuracy by category, ratio to naive."""
    naive = np.array([o.timing_ms["total"] for o in outcomes["naive"]])
    width = max(8, *map(len, outcomes))
    head = (f"{'':<{width}}{'median':>8}{'p90':>8}{'vs naive':>9} |" + "".join(f"{s:>9}" for s in STAGES)
            + f" |{'peak MB':>8} |" + "".join(f"{c:>9}" for c in CATEGORIES) + f"{'rot med':>9}")
    lines = [head, "-" * len(head)]
    for name, runs in outcomes.items():
        total = np.array([o.timing_ms["total"] for o in runs])
        stages = "".join(f"{np.mean([o.timing_ms[s] for o in runs]):>9.1f}" for s in STAGES)
        accuracy = "".join(f"{identified_percent(runs, dataset, c):>9}" for c in CATEGORIES)
        lines.append(f"{name:<{width}}{np.median(total):>8.1f}{np.percentile(total, 90):>8.1f}"
                     f"{np.median(naive / total):>8.1f}x |{stages} |{memory[name]:>8.1f} |{accuracy}"
                     f"{rotation_median(runs, dataset):>9}")
    return lines


def default_lines(dataset: Dataset, outcomes: dict[str, list[Outcome]], floors: dict[str, list[float]]) -> list[str]:
    """The default preset against the naive reference by category, and each preset against its floor."""
    ratio = np.array([naive.timing_ms["total"] / default.timing_ms["total"]
                      for naive, default in zip(outcomes["naive"], outcomes["default"])])
    category = np.array([s.category for s in dataset.samples])
    totals = {name: np.array([o.timing_ms["total"] for o in runs]) for name, runs in outcomes.items()}
    return ["default vs naive, median per image by category: "
            + ", ".join(f"{c} {np.median(ratio[category == c]):.1f}x" for c in CATEGORIES if np.any(category == c))
            + f"; at least 8x on {np.mean(ratio >= 8):.0%} of images",
            "median ms per image by category: " + "; ".join(
                f"{c} " + ", ".join(f"{name} {np.median(t[category == c]):.1f}" for name, t in totals.items())
                for c in CATEGORIES if np.any(category == c)),
            *(floor_line(name, outcomes[name], floors[name]) for name in PRESETS),
            one_region_line(outcomes["default"], np.array(floors["default"]))]


def floor_line(name: str, outcomes: list[Outcome], floors: list[float]) -> str:
    """A preset against its floor, SIFT alone on the crop it chose, over the images it searched a region of."""
    floors = np.array(floors)
    searched = ~np.isnan(floors)
    total = np.array([o.timing_ms["total"] for o in outcomes])[searched]
    sift = np.array([o.timing_ms["features"] for o in outcomes])[searched]
    floors = floors[searched]
    return (f"{name}: floor, SIFT alone on the crop it chose ({searched.sum()} images): median {np.median(floors):.1f} "
            f"ms; {name} / floor: median per image {np.median(total / floors):.2f}, ratio of medians "
            f"{np.median(total) / np.median(floors):.2f}; every SIFT pass the search made / floor (what {name} / "
            f"floor would be were every other stage free): median per image {np.median(sift / floors):.2f}")


def one_region_line(outcomes: list[Outcome], floors: np.ndarray) -> str:
    """Where the time of the images answered from the one region searched goes, beside their floor:
    the median per image of each stage, the floor and what is left besides them."""
    one = [(o, f) for o, f in zip(outcomes, floors) if o.regions == 1 and o.label is not None]
    if not one:
        return "no image was answered from one region"
    stages = {s: np.median([o.timing_ms[s] for o, _ in one]) for s in STAGES}
    total = np.median([o.timing_ms["total"] for o, _ in one])
    return (f"the {len(one)} images answered from one region, median per image: total {total:.2f} ms, floor "
            f"{np.median([f for _, f in one]):.2f}, " + ", ".join(f"{s} {v:.2f}" for s, v in stages.items())
            + f"; default / floor {np.median([o.timing_ms['total'] / f for o, f in one]):.2f}")


def machine() -> str:
    with open("/proc/cpuinfo") as cpuinfo:
        model = next((line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name")), "?")
    return f"{os.cpu_count()} cores, {model}, OpenCV {cv2.__version__}, {cv2.getNumThreads()} OpenCV threads"


def positive_int(text: str) -> int:
    """argparse type: an integer of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def scene_parser(doc: str) -> argparse.ArgumentParser:
    """A parser with the options every `measure` run takes: --n, --seed, --data and --rounds."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--n", type=positive_int, default=200, help="scenes per size (default 200)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "signpose-speed",
                        help="folder the scenes are rendered into and re-used from")
    parser.add_argument("--rounds", type=positive_int, default=3,
                        help="runs of each configuration on each image, the fastest kept (default 3)")
    return parser


def changed_default(spec: str) -> tuple[str, Settings]:
    """argparse type: (`spec`, the default preset with the changes it names), `spec` being
    "SETTING=VALUE[,SETTING=VALUE...]", each VALUE read as JSON (false, 0.5) and else as a string."""
    changes = {}
    for item in spec.split(","):
        key, sep, text = item.partition("=")
        if not sep:
            raise argparse.ArgumentTypeError(f"{item!r} is not SETTING=VALUE")
        try:
            changes[key.strip()] = json.loads(text)
        except json.JSONDecodeError:
            changes[key.strip()] = text
    try:
        return spec, preset("default").replace(**changes)
    except (SettingsError, TypeError, ValueError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def main() -> None:
    parser = scene_parser(__doc__)
    parser.add_argument("--memory-images", type=int, default=20, help="images per peak-memory run (default 20)")
    parser.add_argument("--quick", action="store_true",
                        help="640x480 only, at most 50 scenes, 5 images per memory run, evaluate once")
    parser.add_argument("--also", type=changed_default, action="append", default=[], metavar="SETTING=VALUE[,...]",
                        help="a further configuration beside the others: the default preset with these settings "
                             "changed, e.g. full_frame_fallback=false (repeatable)")
    args = parser.parse_args()
    configs: dict[str, Settings | None] = {**CONFIGS, **dict(args.also)}
    n, sizes, memory_images, repeats = args.n, SIZES, args.memory_images, 2
    if args.quick:
        n, sizes, memory_images, repeats = min(n, 50), SIZES[:1], 5, 1

    keep_freed_memory()  # as evaluate's workers do; every configuration runs in this process alike
    library = load_library()
    report = [machine(), f"load average at start: {os.getloadavg()[0]:.2f}"]
    for size in sizes:
        dataset = scenes(args.data, size, n, args.seed, library)
        outcomes, floors = measure(dataset, library, args.rounds, configs)
        counts = ", ".join(f"{sum(s.category == c for s in dataset.samples)} {c}" for c in CATEGORIES)
        report += ["", f"{size[0]}x{size[1]}: {len(dataset)} scenes ({counts}), seed {args.seed}; ms per image "
                       f"(the fastest of {args.rounds} runs), "
                       "stage means in ms, peak RSS above a warm process in MB, rotation error median in degrees"]
        report += table(dataset, outcomes, peak_memory(dataset, memory_images, configs))
        report += default_lines(dataset, outcomes, floors)
        if size == sizes[0]:
            report += ["", *rerun(dataset, library), batch_speedup(dataset, library, repeats),
                       server_speedup(dataset, repeats)]
    report.append(f"load average at end: {os.getloadavg()[0]:.2f}")
    print("\n".join(report))


if __name__ == "__main__":
    main()
