"""`signpose` command line: recognize, track, synth, evaluate, sweep, calibrate, serve, map build."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import closing, contextmanager, nullcontext, suppress
from pathlib import Path
from typing import NoReturn, TextIO

import cv2
import numpy as np
from tqdm import tqdm

from signpose.app.batch import (FRAMES_PER_CHUNK, IMAGES_PER_CHUNK, WARM_UP_FRAMES, BatchError, Runner, Tally,
                                runner_for)
from signpose.app.entry import STOP_SIGNALS, Interrupted, interrupted, stopping_on_signals
from signpose.app.image_store import HELD_BYTES_PER_PIXEL, check_image_header, decode_upload, held_bytes
from signpose.app.tuning import MAX_SWEEP_STEPS
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.camera import ASSUMED_HFOV_DEG, ASSUMED_HFOV_RANGE_DEG, Camera, CameraError, check_hfov, load_camera
from signpose.pipeline.evaluate import CORES, keep_freed_memory, pad_to
from signpose.pipeline.image import ImageError, read_file
from signpose.pipeline.library import SAMPLE_LIBRARY, Library, LibraryError, load_library
from signpose.pipeline.every_sign import SignSeen, recognize_every_sign
from signpose.pipeline.localise import CameraInMap, locate_in_map
from signpose.pipeline.recognize import PipelineError, Recognition, pipeline_errors, why_no_feature_winner
from signpose.pipeline.results import ResultStore
from signpose.pipeline.settings import PRESETS, Settings, SettingsError, load_settings, preset
from signpose.pipeline.sign_map import MapError, SignMap, load_sign_map

EXIT_USAGE = 2
EXIT_BROKEN_PIPE = 141  # the shell's 128 + SIGPIPE
STDOUT = "-"  # as an output file: standard output


class CliError(Exception):
    """A problem with the command's inputs: printed as one line, exit code 2."""


def load_inputs(args) -> tuple[Library, Settings, Camera | None]:
    """The library, settings and camera named by the common options."""
    try:
        library = load_library(args.library)
        settings = preset(args.preset)
        if args.settings:
            settings = load_settings(args.settings, base=settings)
        camera = load_camera(args.camera) if args.camera else None
    except (LibraryError, SettingsError, CameraError) as exc:
        raise CliError(str(exc)) from None
    return library, settings, camera


def load_map(args, library: Library) -> SignMap | None:
    """The map file of --map (None without one), its signs checked against `library`."""
    if args.map is None:
        return None
    try:
        return load_sign_map(args.map, library.ids)
    except MapError as exc:
        raise CliError(str(exc)) from None


def add_map_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", type=file_path, metavar="FILE",
                   help="sign map (YAML or JSON, docs/map.md): locate the camera in the map frame from the mapped "
                        "signs in view")


def add_common(p: argparse.ArgumentParser, camera: bool = True) -> None:
    p.add_argument("--library", default=str(SAMPLE_LIBRARY), help="sign library folder (default: the samples)")
    if camera:
        p.add_argument("--camera", type=file_path,
                       help="camera file: ROS camera_info YAML (the calibration file, or the message as "
                            "`ros2 topic echo --once` prints it), OpenCV FileStorage YAML/XML/JSON, a Kalibr "
                            "camchain of one camera, or {fx,fy,cx,cy,dist}")
    p.add_argument("--settings", type=file_path, help="settings JSON (full or partial), applied over --preset")
    p.add_argument("--preset", default="default", choices=sorted(PRESETS), help="base settings (default: default)")


def add_max_megapixels(p: argparse.ArgumentParser) -> None:
    """--max-megapixels, with the server's default: a few hundred bytes of PNG can claim gigabytes of pixels."""
    p.add_argument("--max-megapixels", type=positive_number, default=WorkspaceConfig.max_pixels / 1e6,
                   help="largest image accepted, checked from its header before decoding (default %(default)g)")


def max_pixels(args) -> int:
    """The --max-megapixels limit in pixels."""
    return round(args.max_megapixels * 1e6)


def add_cluster(p: argparse.ArgumentParser, what: str, *, images: bool, frames: bool) -> None:
    """--dask, --results, --shared-paths, and --chunk (`images`), --chunk-frames (`frames`): where the work runs,
    in what pieces, and where its results are kept."""
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on the Dask cluster whose scheduler is at ADDRESS (e.g. tcp://host:8786) instead of this "
                        "machine's processes; needs signpose[dask] installed here and on the workers (docs/cluster.md)")
    p.add_argument("--results", metavar="DIR",
                   help=f"keep each {what} in DIR, keyed by the file's content and the settings that feed it: "
                        "a re-run (after Ctrl-C, a lost worker or a settings change) computes only what is missing")
    p.add_argument("--shared-paths", action="store_true",
                   help="send the workers paths, not the files' bytes: every worker sees the files at the same paths")
    if images:
        p.add_argument("--chunk", type=positive_int, default=IMAGES_PER_CHUNK, metavar="N",
                       help="most images sent to a worker at a time; the last chunks are smaller, so that the "
                            "workers finish together (default %(default)s)")
    if frames:
        p.add_argument("--chunk-frames", type=positive_int, default=FRAMES_PER_CHUNK, metavar="N",
                       help="frames of a flight tracked by one worker at a time, each range after a warm-up of "
                            f"{WARM_UP_FRAMES} frames (default %(default)s; docs/cluster.md)")


@contextmanager
def batch_runner(args, workers: int) -> Iterator[Runner]:
    """Where the command's chunks run: the cluster at --dask, else `workers` processes here; its errors are the
    command's."""
    try:
        runner = runner_for(args.dask, workers)
    except BatchError as exc:
        raise CliError(str(exc)) from None
    try:
        yield runner
    except BatchError as exc:
        raise CliError(str(exc)) from None
    finally:
        runner.close()


def result_store(args) -> ResultStore | None:
    """The --results folder's store, None without one."""
    if args.results is None:
        return None
    if Path(args.results).exists() and not Path(args.results).is_dir():
        raise CliError(f"--results {args.results} is a file: give a folder, which is made if it does not exist")
    try:
        return ResultStore(args.results)
    except OSError as exc:
        raise CliError(f"cannot make or write the --results folder {args.results}: {exc.strerror or exc}") from None


def format_row(name: str, rec: Recognition) -> str:
    """One table row: the label, how it was recognised (feature inliers and margin, or the plaque
    fallback, which has neither) and the camera position in the sign's frame (metres)."""
    if not rec.recognized:
        return f"{pad_to(name, 28)} {'-':<22} {'':>7} {'':>6}  no sign ({why_no_feature_winner(rec.attempt)})"
    how = ""
    if rec.by_plaque:
        inliers, margin = "-", "-"
        how = f"by plaque (correlation {rec.plaque.correlation:.2f})"
    else:
        inliers, margin = rec.best.n_inliers, rec.margin
    pose = rec.pose
    where = ""
    if pose is not None:
        x, y, z = pose.camera_position
        where = f"cam at ({x:+.2f}, {y:+.2f}, {z:+.2f}) m, rmse {pose.reprojection_rmse_px:.2f} px"
        if pose.ambiguous:
            where += ", ambiguous"
    return f"{pad_to(name, 28)} {rec.label:<22} {inliers:>7} {margin:>6}  {'; '.join(filter(None, (how, where)))}"


def cmd_recognize(args) -> int:
    library, settings, camera = load_inputs(args)
    sign_map = load_map(args, library)
    keep_freed_memory()  # this process exists to run the pipeline: about 25 % faster per image
    limit = max_pixels(args)
    done = failed = 0
    if not args.json:
        print(f"{'image':<28} {'label':<22} {'inliers':>7} {'margin':>6}  pose")
    # A row names its image by its file name, unless two images share one (set1/scene_002.jpg, set2/scene_002.jpg).
    names = [Path(path).name for path in args.images]
    shown = names if len(set(names)) == len(names) else [str(path) for path in args.images]
    # The bar is on stderr, the table or the JSON on stdout: `--json > out.jsonl` shows it too.
    with progress(list(zip(args.images, shown)), desc="recognize", hidden=len(args.images) < 10,
                  leave=False) as images, stopped_after(lambda: done, len(args.images), "images"):
        for path, row_name in images:
            failed += not recognize_one(str(path), library, settings, camera, args.assumed_fov, limit, args.json,
                                        sign_map, row_name)
            done += 1
    return unusable_images(failed, len(args.images))


def recognize_one(name: str, library: Library, settings: Settings, camera: Camera | None, hfov_deg: float,
                  limit: int, as_json: bool, sign_map: SignMap | None = None, row_name: str | None = None) -> bool:
    """Recognise every library sign in the image file `name` (`recognize_every_sign`) and print its lines: a table
    row for the answer (the first; named `row_name`, default the file's name) with its warnings, a row for each
    other sign and, with `sign_map`, a line of the camera in the map frame; or, `as_json`, a JSON object. Returns
    whether the image could be used (else the line says why not).
    `camera` turned as the image's EXIF orientation turned it; without one, the image's EXIF focal length, else
    `hfov_deg` assumed, as the server chooses."""
    try:
        image, _, exif = decode_upload(read_file(name), name, limit)
        with pipeline_errors(name):
            recognitions = recognize_every_sign(image, library, settings,
                                                exif.camera_for(camera, image.shape[1], image.shape[0], hfov_deg))
            found = [r for r in recognitions if r.label is not None]
            located = (locate_in_map(found=found, sign_map=sign_map, library=library, camera=recognitions[0].camera)
                       if sign_map is not None else None)
    # CameraError: the camera cannot be turned or scaled to this image; PipelineError: a failure inside the pipeline
    except (ImageError, CameraError, PipelineError) as exc:
        if as_json:
            say(json.dumps({"image": name, "error": str(exc)}))
        else:
            # The row names the image already; the image errors begin with its path.
            say(f"{pad_to(row_name or Path(name).name, 28)} error: {str(exc).removeprefix(name + ': ')}")
        return False
    rec = recognitions[0]
    if as_json:
        document = rec.to_json(name)
        document["signs"] = [SignSeen.of(r).to_json() for r in found]
        if sign_map is not None:
            document["camera_in_map"] = located.to_json() if located is not None else None
        say(json.dumps(document))
    else:
        lines = [format_row(row_name or Path(name).name, rec), *(f"{'':<28}   warning: {w}" for w in rec.warnings)]
        for other in found[1:]:
            lines.append(format_row("  and", other))
        if sign_map is not None:
            lines.append(f"{'':<28}   {format_in_map(located, sign_map.frame)}")
        say("\n".join(lines))
    return True


def format_in_map(located: CameraInMap | None, frame: str) -> str:
    """The table's line of the camera in the map frame `frame`: position, 1σ, the signs it came from and
    those left out."""
    if located is None:
        return f"in {frame}: no mapped sign in view"
    x, y, z = located.position_m
    covariance = located.covariance_xyz_rpy
    sigma = ("" if covariance is None
             else f" ± {1e3 * math.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3]).max(), 0.0)):.0f} mm")
    left_out = f" (left out as disagreeing: {', '.join(located.signs_rejected)})" if located.signs_rejected else ""
    return f"in {frame}: cam at ({x:+.3f}, {y:+.3f}, {z:+.3f}) m{sigma}, from {', '.join(located.signs_used)}{left_out}"


def progress(iterable: Iterable | None = None, *, hidden: bool = False, **options) -> tqdm:
    """A progress bar over images on stderr, drawn only when stderr is a terminal (tqdm's
    disable=None): in a log file or a CI log its redraws are carriage-return clutter. `hidden`:
    never drawn. What a command prints when it is done (tables, counts) is printed either way;
    what it prints while the bar is drawn, it prints with `say`."""
    return tqdm(iterable, file=sys.stderr, disable=True if hidden else None, **{"unit": "img", **options})


def say(text: str, file: TextIO | None = None) -> None:
    """Print `text` on `file` (default stdout) at once, so that a reader sees each image's line as soon as it is
    done. A progress bar drawn on the same terminal is cleared first and drawn again below: printed over it,
    the text began at the bar's end."""
    with tqdm.external_write_mode(file=file):
        print(text, file=file, flush=True)


@contextmanager
def stopped_after(done: Callable[[], int], total: int, unit: str) -> Iterator[None]:
    """Inside, an interruption (Ctrl-C, SIGTERM, SIGHUP) says in the command's message how far it got:
    `done()` of `total` `unit` ("images")."""
    try:
        yield
    except KeyboardInterrupt as exc:
        raise Interrupted.after(exc, f"{done()} of {total} {unit}") from None


def unusable_images(failed: int, total: int) -> int:
    """The exit status of a run over `total` images of which `failed` could not be used, said on stderr."""
    if failed:
        print(f"{failed} of {total} image(s) could not be used", file=sys.stderr)
    return 1 if failed else 0


def cmd_track(args) -> int:
    from signpose.app.flight_output import FlightOutputError

    library, settings, camera = load_inputs(args)
    sign_map = load_map(args, library)
    keep_freed_memory()
    if args.dask or args.results:
        return track_in_chunks(args, library, settings, camera, sign_map)
    output = Path(args.output).resolve() if args.output else None
    if output is not None and any(Path(spec).exists() and (output == Path(spec).resolve()
                                                           or Path(spec).resolve() in output.parents)
                                  for spec in args.sources):
        raise CliError(f"-o {args.output} is a SOURCE or inside one (a bag's folder): it would be overwritten; "
                       "write the flight elsewhere")
    try:
        return track_locally(args, library, settings, camera, sign_map)
    except FlightOutputError as exc:
        say(f"signpose track: error: {exc}", sys.stderr)
        return 1


def track_locally(args, library: Library, settings: Settings, camera: Camera | None, sign_map: SignMap | None) -> int:
    """`track` in this process: its SOURCE (one, or a list of frames) tracked frame by frame, written to -o."""
    from signpose.app.flight_output import open_flight_output
    from signpose.pipeline.frames import BagSource, SourceError, open_source, unused_options
    from signpose.pipeline.track import Tracker, tracked_frames

    spec = args.sources[0] if len(args.sources) == 1 else args.sources
    try:
        source = open_source(spec, topic=args.topic, fps=args.fps, max_pixels=max_pixels(args))
    except SourceError as exc:
        raise CliError(str(exc)) from None
    if (unused := unused_options(source, topic=args.topic, fps=args.fps)) is not None:
        source.close()
        raise CliError(unused)
    frames = seen = 0
    labels: dict[int, str] = {}  # confirmed track id: label
    started = time.perf_counter()
    total = min(filter(None, (source.count, args.max_frames)), default=None)
    with source, (open_flight_output(args.output, sign_map=sign_map) if args.output else nullcontext()) as output, \
            progress(total=total, unit="frame", desc="track", leave=False) as bar, \
            stopped_after(lambda: frames, total or frames, "frames"):
        for warning in source.warnings:
            say(f"warning: {warning}", sys.stderr)
        tracker = Tracker(library, settings, camera if camera is not None else source.camera, fps=source.fps,
                          sign_map=sign_map)
        stream = tracked_frames(source, tracker, source.name)
        while args.max_frames is None or frames < args.max_frames:
            try:
                tracked = next(stream, None)
            except SourceError as exc:
                if not frames:  # the source cannot be used
                    raise CliError(str(exc)) from None
                say(f"signpose track: error: {exc}", sys.stderr)  # the frames before it were tracked and written
                return 1
            except CameraError as exc:
                raise CliError(f"{source.name}: {exc}") from None
            if tracked is None:
                break
            frame, result, record = tracked
            if output is not None:
                output.write(record, image=None if isinstance(source, BagSource) else frame.image,
                             stamp_ns=frame.stamp_ns)
            seen += told(record, labels, args.json)
            frames += 1
            bar.update()
        if not frames:
            raise CliError(f"{source.name}: holds no frames" + (f" on {source.topic}" if isinstance(source, BagSource)
                                                                 else ""))
    elapsed = time.perf_counter() - started
    print(f"{frames} frames, {seen} with a sign; signs seen: {signs_seen(labels)}; {frames / elapsed:.1f} frames/s",
          file=sys.stderr)
    return 0


def told(record: dict, labels: dict[int, str], as_json: bool) -> bool:
    """Print what a tracked frame's `record` (its `--json` line) tells: the line itself, or a line per track
    first confirmed on it (noted in `labels`, track id: label); whether a sign is on the frame."""
    if as_json:
        say(json.dumps(record))
    for sign in record["signs"]:
        if sign["track_id"] not in labels:
            labels[sign["track_id"]] = sign["label"]
            if not as_json:
                say(f"frame {record['frame']} ({record['time_s']:.2f} s): {sign['label']} confirmed as track "
                    f"{sign['track_id']}")
    return bool(record["signs"])


def signs_seen(labels: dict[int, str]) -> str:
    """The tracks confirmed, for the summary line."""
    return ", ".join(f"{label} (track {track_id})" for track_id, label in sorted(labels.items())) or "none"


def track_in_chunks(args, library: Library, settings: Settings, camera: Camera | None,
                    sign_map: SignMap | None) -> int:
    """`track --dask` or `--results`: every SOURCE a flight of its own, in frame ranges, printed in order."""
    if args.output:
        raise CliError("-o writes the flight of a local run; with --dask or --results use --json, whose lines name "
                       "their source")
    for spec in args.sources:
        if not Path(spec).exists():
            raise CliError(f"{spec}: no such file or folder; with --dask or --results each SOURCE is a video, a bag "
                           "or a folder of frames")
    started = time.perf_counter()
    results, tally = flights_in_chunks(args, [(spec, camera) for spec in args.sources], library, [settings],
                                       sign_map=sign_map, topic=args.topic, fps=args.fps, workers=CORES, desc="track")
    frames = failed = 0
    for spec, result in zip(args.sources, results[0]):
        labels: dict[int, str] = {}
        seen = sum(told(record, labels, args.json) for record in result["records"])
        frames += len(result["records"])
        if result["error"] is not None:
            say(f"signpose track: error: {result['error']}", sys.stderr)
            failed += 1
        print(f"{spec}: {len(result['records'])} frames, {seen} with a sign; signs seen: {signs_seen(labels)}",
              file=sys.stderr)
    elapsed = time.perf_counter() - started
    print(f"{frames} frames of {len(args.sources)} flight(s), {frames / elapsed:.1f} frames/s; "
          f"{tally.summary('chunk(s)')}", file=sys.stderr)
    return 1 if failed else 0


def flights_in_chunks(args, jobs: list[tuple[str, Camera | None]], library: Library, variants: list[Settings], *,
                      sign_map: SignMap | None, topic: str | None, fps: float | None, workers: int,
                      desc: str) -> tuple[list[list[dict]], Tally]:
    """Every flight of `jobs` (source, camera) tracked under each of `variants` ([variant][job]: its records and
    error), in ranges of --chunk-frames on the cluster at --dask or `workers` processes here, taken from
    --results where it holds them."""
    from signpose.app.batch import track_all

    with progress(total=0, unit="chunk", desc=desc, leave=False) as bar, batch_runner(args, workers) as runner:
        def planned(chunks: int) -> None:
            bar.total = chunks
            bar.refresh()

        return track_all(jobs, library, variants, sign_map=sign_map, topic=topic, fps=fps, max_frames=args.max_frames,
                         max_pixels=max_pixels(args), frames_per_chunk=args.chunk_frames, runner=runner,
                         store=result_store(args), shared_paths=args.shared_paths, planned=planned, done=bar.update)


def cmd_synth(args) -> int:
    from signpose.pipeline.synth import SynthError, generate_dataset

    written = 0

    def wrote(done: int, total: int) -> None:
        nonlocal written
        written = done
        bar.update(1)

    try:
        library = load_library(args.library)
        # Shown once rendering takes a while, so a refused folder gets its error line alone.
        with progress(total=args.n, desc="synth", delay=0.5) as bar, stopped_after(lambda: written, args.n, "scenes"):
            generate_dataset(Path(args.out_dir), library, n=args.n, seed=args.seed, progress=wrote)
    except (LibraryError, SynthError) as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:  # a file in the way of the folder, a folder that cannot be made or written
        raise CliError(f"cannot write into {exc.filename or args.out_dir}: {exc.strerror or exc}") from None
    print(f"wrote {args.n} scenes, truth.json and camera.yaml to {args.out_dir}")
    return 0


def cmd_evaluate(args) -> int:
    from signpose.pipeline.evaluate import ImageResult, format_table, measure, report_on
    from signpose.pipeline.evaluate_map import format_map_table

    library, settings, camera = load_inputs(args)
    sign_map = load_map(args, library)
    # This process measures images too (all of them on one worker): evaluating 200 scenes took 6.8 s without it
    # and 6.2 s with it on one worker, 4.4 s and 4.1 s on two.
    keep_freed_memory()
    roots = [Path(d).resolve() for d in args.datasets]
    if len(set(roots)) < len(roots):
        raise CliError("a dataset folder is given twice")
    try:
        surveys = {} if sign_map is None else map_surveys(args.datasets)
    except (ValueError, OSError) as exc:  # DatasetError, and what reading truth.json raises
        raise CliError(str(exc)) from None
    datasets = load_datasets([d for d in args.datasets if d not in surveys], library)
    if sign_map is not None and datasets:
        print(f"the map is not used for {', '.join(d.name for d in datasets)}: no camera poses in the map frame in "
              "their truth", file=sys.stderr)
    in_map: dict[str, dict] = {}
    failed_in_map, photos_in_map = 0, sum(len(p) for p in surveys.values())
    map_table = ""
    if sign_map is not None and surveys:
        in_map, failed_in_map = evaluate_in_map(surveys, library, settings, camera, sign_map, args)
        map_table = format_map_table(in_map, sign_map.frame)
        if not datasets:
            print(json.dumps({"camera_in_map": in_map}) if args.json else map_table)
            return unusable_images(failed_in_map, photos_in_map)
    total = sum(len(d) for d in datasets)
    results: list[ImageResult] = []
    tally = None
    if args.dask or args.results:
        results, tally = evaluated_in_chunks(args, datasets, library, settings, camera)
    else:
        check = functools.partial(check_image_header, max_pixels=max_pixels(args))
        try:
            with progress(total=total, desc="evaluate") as bar, stopped_after(lambda: len(results), total, "images"), \
                    closing(measure(datasets, library, settings, camera, args.workers, check)) as measured:
                for result in measured:
                    results.append(result)
                    bar.update(1)
        except BrokenProcessPool:
            raise CliError("a worker process stopped before it finished (out of memory?); "
                           "fewer workers, e.g. --workers 1, need less") from None
        except Interrupted as exc:
            if results and not args.json:  # the table of what was measured; a JSON reader would take it for all
                with suppress(OSError):  # after SIGHUP the terminal may be gone
                    print(f"partial results: the first {exc.done}\n"
                          + format_table(report_on(datasets, library, settings, results)), flush=True)
            raise
    report = report_on(datasets, library, settings, results)
    if args.json:
        print(json.dumps({**report.to_json(), **({"camera_in_map": in_map} if in_map else {})}))
        if tally is not None:
            print(tally.summary("images"), file=sys.stderr)
    else:
        print(format_table(report) + (f"\n\n{map_table}" if map_table else "")
              + (f"\n\n{tally.summary('images')}" if tally is not None else ""))
    failed = sum(r.error is not None for r in report.results) + failed_in_map
    return unusable_images(failed, len(report.results) + photos_in_map)


def map_surveys(folders: list[str]) -> dict:
    """{folder: its photos} of the `folders` whose truth gives camera poses in the map frame (surveys)."""
    from signpose.pipeline.evaluate_map import survey_photos

    found = {folder: survey_photos(Path(folder)) for folder in folders}
    return {folder: photos for folder, photos in found.items() if photos is not None}


def evaluate_in_map(surveys: dict, library: Library, settings: Settings, camera: Camera | None, sign_map: SignMap,
                    args) -> tuple[dict[str, dict], int]:
    """Each survey's photos located in `sign_map` (`pipeline.evaluate_map`), a photo at a time: ({survey name:
    `summary_in_map`}, how many photos could not be used, each named on stderr)."""
    from signpose.pipeline.evaluate_map import locate_photos, summary_in_map

    check = functools.partial(check_image_header, max_pixels=max_pixels(args))
    summaries, failed = {}, 0
    total = sum(len(p) for p in surveys.values())
    with progress(total=total, desc="evaluate in map") as bar:
        for folder, photos in surveys.items():
            root = Path(folder)
            survey_camera = camera
            if survey_camera is None and (root / "camera.yaml").is_file():
                try:
                    survey_camera = load_camera(root / "camera.yaml")
                except CameraError as exc:
                    raise CliError(str(exc)) from None
            results = []
            for result in locate_photos(photos, library, settings, survey_camera, sign_map, check):
                if result.error is not None:
                    say(f"{result.error}", sys.stderr)
                    failed += 1
                results.append(result)
                bar.update(1)
            summaries[root.name] = summary_in_map(results)
    return summaries, failed


def load_datasets(folders: list[str], library: Library) -> list:
    """The dataset folders `folders`, their labels checked against `library`; each named after its folder, or as
    given where two folders share a name."""
    from signpose.pipeline.evaluate import check_labels, load_dataset

    roots = [Path(d).resolve() for d in folders]
    if len(set(roots)) < len(roots):
        raise CliError("a dataset folder is given twice")
    try:
        datasets = [load_dataset(Path(d)) for d in folders]
        check_labels(datasets, library)
    except (ValueError, OSError) as exc:  # DatasetError, and what reading truth.json raises
        raise CliError(str(exc)) from None
    names = [d.name for d in datasets]
    for dataset, given in zip(datasets, folders):
        if names.count(dataset.name) > 1:  # a/set1 and b/set1: each its own row
            dataset.name = given
    return datasets


def outcomes_in_chunks(args, datasets: list, library: Library, variants: list[Settings], camera: Camera | None,
                       workers: int, desc: str) -> tuple[list, Tally]:
    """Every sample's `Outcome` under each of `variants` ([variant][sample]), on the cluster at --dask or
    `workers` processes here, taken from --results where it holds them."""
    from signpose.app.batch import recognize_all
    from signpose.pipeline.evaluate import jobs_of

    jobs = [(str(sample.path), cam) for _, sample, cam in jobs_of(datasets, camera)]
    check = functools.partial(check_image_header, max_pixels=max_pixels(args))
    done = 0

    def advance(images: int) -> None:
        nonlocal done
        done += images
        bar.update(images)

    with progress(total=len(jobs), desc=desc) as bar, stopped_after(lambda: done, len(jobs), "images"), \
            batch_runner(args, workers) as runner:
        return recognize_all(jobs, library, variants, check, runner=runner, store=result_store(args),
                             context={"max_pixels": max_pixels(args)}, shared_paths=args.shared_paths,
                             images_per_chunk=args.chunk, done=advance)


def evaluated_in_chunks(args, datasets: list, library: Library, settings: Settings,
                        camera: Camera | None) -> tuple[list, Tally]:
    """`evaluate --dask` or `--results`: each sample's result against its truth, in the samples' order."""
    from signpose.pipeline.evaluate import jobs_of, judged

    outcomes, tally = outcomes_in_chunks(args, datasets, library, [settings], camera, args.workers, "evaluate")
    jobs = jobs_of(datasets, camera)
    return [judged(name, sample, outcome) for (name, sample, _), outcome in zip(jobs, outcomes[0])], tally


def cmd_sweep(args) -> int:
    from signpose.app.tuning import INTEGER_SETTINGS, TuningError, sweep_values, values_to_sweep

    library, settings, camera = load_inputs(args)
    flights = flight_folders(args.datasets)
    datasets = load_datasets([d for d in args.datasets if d not in flights], library)
    try:
        values = values_to_sweep(settings, args.param, args.lo, args.hi, args.steps)
    except TuningError as exc:
        raise CliError(str(exc)) from None
    distinct = len(sweep_values(args.lo, args.hi, args.steps, args.param in INTEGER_SETTINGS))
    if distinct < args.steps:
        print(f"note: {args.param} takes whole numbers: {args.steps} steps from {args.lo:g} to {args.hi:g} give "
              f"{distinct} values", file=sys.stderr)
    variants = [settings.replace(**{args.param: value}) for value in values]
    answer: dict = {"param": args.param, "values": values}
    tables, summaries, failed = [], [], 0
    if datasets:
        labelled, swept, tally = swept_photos(args, datasets, library, values, variants, camera)
        answer.update({"labelled": labelled, **dataclasses.asdict(swept)})
        tables.append(format_sweep(args.param, values, labelled, swept))
        summaries.append(tally.summary("images"))
    if flights:
        scores, tally, failed = swept_flights(args, flights, library, variants, camera)
        answer["flights"] = scores
        tables += [format_flight_sweep(args.param, values, score) for score in scores]
        summaries.append(tally.summary("flight chunk(s)"))
    kept = args.dask or args.results
    if args.json:
        print(json.dumps(answer))
        if kept:
            print("\n".join(summaries), file=sys.stderr)
    else:
        print("\n\n".join(tables) + ("\n\n" + "\n".join(summaries) if kept else ""))
    return 1 if failed else 0


def flight_folders(folders: list[str]) -> dict:
    """{folder: its `FlightTruth`} of the `folders` that hold a flight with its ground truth."""
    from signpose.pipeline.flight_truth import load_flight_truth

    try:
        found = {folder: load_flight_truth(folder) for folder in folders}
    except (ValueError, OSError) as exc:  # DatasetError, and what reading truth.json raises
        raise CliError(str(exc)) from None
    return {folder: truth for folder, truth in found.items() if truth is not None}


def swept_photos(args, datasets: list, library: Library, values: list[float], variants: list[Settings],
                 camera: Camera | None):
    """The sweep's tally of the labelled photos of `datasets` over the `values` of --param, each in `variants`
    (as the page's sweep): (how many, `SweepTally`, the run's `Tally`)."""
    from signpose.app.tuning import INTEGER_SETTINGS, tally_sweep
    from signpose.pipeline.library import NO_SIGN

    outcomes, tally = outcomes_in_chunks(args, datasets, library, variants, camera, args.workers, "sweep")
    expected = [sample.label or NO_SIGN for d in datasets for sample in d.samples]
    # As the page's sweep: an image the pipeline could not run on at a value is None there.
    runs = [[None if o.error is not None else o for o in row] for row in outcomes]
    return len(expected), tally_sweep(values, expected, runs, integer=args.param in INTEGER_SETTINGS), tally


def swept_flights(args, flights: dict, library: Library, variants: list[Settings],
                  camera: Camera | None) -> tuple[list[dict], Tally, int]:
    """Each flight of `flights` ({folder: `FlightTruth`}) tracked under every variant and scored against its
    truth: ({"flight", then each of `FlightScore.to_json`'s figures as a list in the variants' order}, the
    run's tally, how many flights an error cut short, each error said on stderr). A flight is tracked with
    --camera, else the camera.yaml beside it."""
    from signpose.pipeline.flight_truth import score_flight

    try:
        jobs = [(str(truth.video), camera if camera is not None or truth.camera is None else load_camera(truth.camera))
                for truth in flights.values()]
    except CameraError as exc:
        raise CliError(str(exc)) from None
    tracked, tally = flights_in_chunks(args, jobs, library, variants, sign_map=None, topic=None, fps=None,
                                       workers=args.workers, desc="sweep flights")
    scores, failed = [], 0
    for index, (folder, truth) in enumerate(flights.items()):
        errors = sorted({row[index]["error"] for row in tracked} - {None})
        for error in errors:
            say(f"signpose sweep: error: {error}", sys.stderr)
        failed += bool(errors)
        per_value = [score_flight(truth, row[index]["records"]).to_json() for row in tracked]
        scores.append({"flight": Path(folder).name, **{k: [s[k] for s in per_value] for k in per_value[0]}})
    return scores, tally, failed


def format_sweep(param: str, values: list[float], labelled: int, swept) -> str:
    """The sweep's table: per value the images right, the smallest margin, those right by plaque and those the
    pipeline failed on; then the working band and its centre."""
    lines = [f"{param:>20} {'correct':>9} {'min margin':>11} {'by plaque':>10} {'failed':>7}"]
    for value, correct, margin, plaque, failed in zip(values, swept.correct, swept.min_margin, swept.by_plaque,
                                                      swept.failed):
        lines.append(f"{value:>20g} {f'{correct}/{labelled}':>9} {'-' if margin is None else margin:>11} "
                     f"{plaque:>10} {failed:>7}")
    if swept.band is None:
        lines.append(f"\nno value of {param} gets every labelled image right")
    else:
        lines.append(f"\nevery image right from {swept.band[0]:g} to {swept.band[1]:g}; centre {swept.centre:g}")
    return "\n".join(lines)


def format_flight_sweep(param: str, values: list[float], score: dict) -> str:
    """A flight's sweep table: per value its recall, wrong labels and camera position error (`swept_flights`)."""
    from signpose.pipeline.flight_truth import MAX_DISTANCE_M, MIN_WIDTH_PX

    def shown(value: float | None, unit: str) -> str:
        return "-" if value is None else f"{value:g}{unit}"

    lines = [f"flight {score['flight']}: {max(score['frames'])} frames",
             f"{param:>20} {'recall':>8} {'wrong labels':>13} {'position p50':>13} {'p90':>8}"]
    for i, value in enumerate(values):
        lines.append(f"{value:>20g} {shown(score['recall_pct'][i], ' %'):>8} {score['wrong_labels'][i]:>13} "
                     f"{shown(score['position_error_cm_p50'][i], ' cm'):>13} "
                     f"{shown(score['position_error_cm_p90'][i], ' cm'):>8}")
    lines.append(f"recall of the {max(score['sign_frames_due'])} (frame, sign) pairs fully in view and at least "
                 f"{MIN_WIDTH_PX:g} px wide; position: the camera's error from signs within {MAX_DISTANCE_M:g} m")
    return "\n".join(lines)


def cmd_calibrate(args) -> int:
    from signpose.app.calibration import read_gray
    from signpose.pipeline.calibrate import (BoardView, CalibrationError, calibrate, check_square, drop_outliers, find_board,
                                    format_report, parse_board)
    from signpose.pipeline.camera import ros_camera_yaml, save_camera

    try:  # before reading a single photo
        board, square = parse_board(args.board), check_square(args.square)
    except CalibrationError as exc:
        raise CliError(str(exc)) from None
    # A photo counted twice makes the fit look surer than it is (its ± 1σ shrink).
    resolved = [Path(p).resolve() for p in args.images]
    twice = sorted({str(p) for p, r in zip(args.images, resolved) if resolved.count(r) > 1})
    if twice:
        raise CliError(f"a photo is given more than once: {', '.join(twice)}; give each once")
    limit = max_pixels(args)

    def search(path: str) -> BoardView | ImageError:
        try:
            return find_board(read_gray(path, read_file(path), limit), board, Path(path).name)
        except ImageError as exc:
            return exc

    views: list[BoardView] = []
    unreadable = 0

    with ThreadPoolExecutor(CORES) as pool, \
            stopped_after(lambda: len(views) + unreadable, len(args.images), "photos searched"):
        # OpenCV releases the GIL: a photo per core
        for found in progress(pool.map(search, map(str, args.images)), total=len(args.images), desc="calibrate",
                              leave=False):
            if isinstance(found, ImageError):
                unreadable += 1
                say(f"error: {found}", file=sys.stderr)
            else:
                views.append(found)
    try:
        calibration = calibrate(views, board, square)
        if args.drop_outliers:
            calibration = drop_outliers(calibration)
    except CalibrationError as exc:
        raise CliError(str(exc)) from None
    # With `-o -` the camera file is what stdout carries (`> camera.yaml`, a pipe): the rest goes to stderr.
    to_stdout = args.output == STDOUT
    report = sys.stderr if to_stdout else sys.stdout
    print(format_report(calibration), file=report)
    if to_stdout:
        print(ros_camera_yaml(calibration.camera), end="", flush=True)
        return unusable_images(unreadable, len(args.images))
    try:
        save_camera(calibration.camera, args.output)
    except OSError as exc:  # checked up front, but the folder may be read-only or gone by now
        raise CliError(f"cannot write {args.output}: {exc.strerror}") from None
    print(f"wrote {args.output} (use it with: signpose recognize --camera {args.output} IMAGE...)")
    return unusable_images(unreadable, len(args.images))


def cmd_serve(args) -> int:
    from signpose.app.rerun import share_cores
    from signpose.app.security import TOKEN_ENV, access_token
    from signpose.app.server import bind, create_app, serve
    from signpose.app.state import StateError

    config = WorkspaceConfig(
        state_dir=Path(args.state_dir), library_dir=Path(args.library) if args.library else None,
        camera_file=Path(args.camera) if args.camera else None,
        settings_file=Path(args.settings) if args.settings else None,
        map_file=Path(args.map) if args.map else None,
        max_images=args.max_images, max_pixels=max_pixels(args), max_memory_bytes=round(args.max_memory_gb * 1e9),
        max_upload_bytes=round(args.max_upload_mb * 1e6), request_timeout_s=args.request_timeout,
        max_flight_upload_bytes=round(args.max_flight_mb * 1e6), max_flight_frames=args.max_flight_frames,
        max_flights=args.max_flights,
    )
    token = access_token(args.host, args.token or os.environ.get(TOKEN_ENV))
    try:
        sock = bind(args.host, args.port)
    except OSError as exc:
        raise CliError(f"cannot listen on {args.host}:{args.port} ({exc.strerror}); choose another --port") from None
    share_cores(config.workers)  # process-wide, so here where the serving process starts
    try:
        app = create_app(config, token=token)
    except (StateError, SettingsError, CameraError, LibraryError, MapError) as exc:
        sock.close()
        raise CliError(str(exc)) from None
    workspace = app.state.workspace
    if workspace.busy:
        print(f"processing {len(workspace.images())} image(s) from {config.state_dir} ...", file=sys.stderr)
        workspace.wait_idle(timeout=300)
    host, port = sock.getsockname()[:2]
    url = f"http://{host}:{port}/" + (f"?token={token}" if token else "")
    print(f"signpose serving {len(workspace.images())} image(s): open {url} "
          f"(3D view: /viser/, API docs: /docs; Ctrl+C stops)", flush=True)
    if token:
        print("every request needs the token in that address (share it only with your team); from other "
              "machines use this one's network address in place of the host; scripts send the header "
              "'Authorization: Bearer <token>'", file=sys.stderr)
    # uvicorn shuts down on SIGTERM as on Ctrl-C, then ends by the signal: Interrupted, raised inside its event
    # loop, would cut the shutdown short (and SIGHUP ends the server at once, as it always did).
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_DFL)
    serve(app, sock)
    return 0


def whole_number(least: int, most: int | None = None) -> Callable[[str], int]:
    """argparse type: a whole number from `least` to `most` (no upper bound when None)."""
    bounds = f"of at least {least}" if most is None else f"from {least} to {most}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < least or (most is not None and value > most):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number {bounds}")
        return value

    return parse


positive_int = whole_number(1)
port_number = whole_number(0, 65535)  # 0: any free port


def positive_number(text: str) -> float:
    """argparse type: a finite number above 0 (a limit: NaN would disable the check it feeds,
    and infinity cannot be turned into a pixel or byte count)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not above 0")
    return value


def field_of_view(text: str) -> float:
    """argparse type: a horizontal field of view in degrees that the page would take too."""
    try:
        return check_hfov(float(text))
    except (ValueError, CameraError) as exc:
        raise argparse.ArgumentTypeError(str(exc) if isinstance(exc, CameraError) else f"{text!r} is not a number") from None


def file_path(text: str) -> str:
    """argparse type: a file to read, refused at once when it is a folder (a missing file is
    left to its reader, whose message says what the file is for)."""
    if Path(text).is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, not a file")
    return text


def output_path(text: str) -> str:
    """argparse type: a file to write, or STDOUT, checked before any work: not a folder, in a folder that
    exists and takes new files (a read-only file system or one without write permission does not)."""
    if text == STDOUT:
        return text
    folder = Path(file_path(text)).parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(f"folder {str(folder)!r} does not exist")
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"cannot write into folder {str(folder)!r}: {exc.strerror}") from None
    return text


def flight_output_path(text: str) -> str:
    """argparse type: a file to write a flight to, by its suffix (.mcap, .csv, .jsonl)."""
    from signpose.app.flight_output import OUTPUT_SUFFIXES

    if Path(text).suffix.lower() not in OUTPUT_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text!r}: write a flight as {', '.join(OUTPUT_SUFFIXES)}")
    return output_path(text)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, whose errors are one line, as every other error of the CLI: argparse printed
    the command's usage (3 to 5 lines) above it, which `--help` gives."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    # sub-commands' parsers are made of the same class
    parser = ArgumentParser(prog="signpose", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("recognize", help="recognise signs and estimate camera pose in images")
    p.add_argument("images", nargs="+", help="image files")
    add_common(p)
    add_max_megapixels(p)
    add_map_option(p)
    p.add_argument("--json", action="store_true", help="one JSON object per image per line")
    p.add_argument("--assumed-fov", type=field_of_view, default=ASSUMED_HFOV_DEG, metavar="DEG",
                   help="horizontal field of view, {:g} to {:g} degrees, assumed for an image without --camera or "
                        "a usable EXIF focal length, as the page's assumed FOV (default %(default)g)"
                        .format(*ASSUMED_HFOV_RANGE_DEG))
    p.set_defaults(func=cmd_recognize)

    p = sub.add_parser("track", help="track signs through a video, a ROS bag or a folder of frames")
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="a video file, a ROS 2 bag (.mcap, .db3 or a rosbag2 folder), a ROS 1 .bag, a folder of "
                        "frames (natural order), image files (each a frame), camera:N or a stream URL")
    add_common(p)
    add_max_megapixels(p)
    add_map_option(p)
    p.add_argument("--topic", help="the bag's image topic (default: its only one)")
    p.add_argument("--fps", type=positive_number, help="frame rate of image files and folders (default 1)")
    p.add_argument("--max-frames", type=positive_int, metavar="N", help="stop after N frames")
    p.add_argument("--json", action="store_true", help="one JSON object per frame per line")
    p.add_argument("-o", "--output", type=flight_output_path, metavar="OUT",
                   help="write the flight as OUT.mcap (ROS 2: poses with covariance, /tf, the frames), OUT.csv "
                        "or OUT.jsonl")
    add_cluster(p, "flight range's result", images=False, frames=True)
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("synth", help="render synthetic scenes with ground truth")
    p.add_argument("out_dir", help="folder to write the scenes, truth.json and camera.yaml into (made if missing)")
    p.add_argument("--n", type=positive_int, default=20, help="number of scenes (default 20)")
    p.add_argument("--seed", type=whole_number(0), default=0, help="random seed, 0 or more (default 0)")
    p.add_argument("--library", default=str(SAMPLE_LIBRARY),
                   help="sign library folder whose signs the scenes show (default: the samples)")
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("evaluate", help="accuracy and timing on labelled datasets (the paper's Table 1)")
    p.add_argument("datasets", nargs="+", help="dataset folders: truth.json, or one sub-folder per label")
    p.add_argument("--workers", type=positive_int, default=WorkspaceConfig.workers,
                   help="processes sharing the images, one core each (default: every core, here %(default)s)")
    p.add_argument("--json", action="store_true",
                   help="one JSON object instead of the table: summaries, confusion and every image's answer")
    add_common(p)
    add_max_megapixels(p)
    add_map_option(p)
    add_cluster(p, "image's result", images=True, frames=False)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("sweep", help="the page's sweep over labelled datasets and flights with ground truth: images "
                                     "right, or a flight's recall and pose error, per value of one setting")
    p.add_argument("param", metavar="PARAM", help="the numeric setting to sweep, e.g. threshold")
    p.add_argument("--lo", type=float, required=True, help="first value")
    p.add_argument("--hi", type=float, required=True, help="last value")
    p.add_argument("--steps", type=whole_number(2, MAX_SWEEP_STEPS), default=13,
                   help=f"values from lo to hi, 2 to {MAX_SWEEP_STEPS} (default %(default)s)")
    p.add_argument("datasets", nargs="+", metavar="DATASET",
                   help="dataset folders, as for evaluate, or flight folders: a video with a truth.json of its frames "
                        "and camera.yaml, as pipeline.synth_flight writes them")
    p.add_argument("--max-frames", type=positive_int, metavar="N", help="track only the first N frames of each flight")
    p.add_argument("--workers", type=positive_int, default=WorkspaceConfig.workers,
                   help="processes sharing the images without --dask (default: every core, here %(default)s)")
    p.add_argument("--json", action="store_true", help="one JSON object, as the page's GET /api/sweep answers")
    add_common(p)
    add_max_megapixels(p)
    add_cluster(p, "image's and flight range's result at each value", images=True, frames=True)
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("calibrate", help="camera intrinsics from photos of a printed chessboard (docs/calibration.md)")
    p.add_argument("images", nargs="+", help="photos of the board, all the same size as the camera stored them "
                                             "(read without their EXIF orientation, as a camera file describes)")
    p.add_argument("--board", required=True, help="inner corners COLSxROWS, e.g. 9x6 for a board of 10x7 squares")
    p.add_argument("--square", type=float, required=True, help="side of one printed square in metres, e.g. 0.025")
    p.add_argument("-o", "--output", type=output_path, default="camera.yaml",
                   help="ROS camera_info YAML to write (default camera.yaml); - writes it on stdout, the report on "
                        "stderr")
    p.add_argument("--drop-outliers", action="store_true", help="recalibrate without the views whose error stands out")
    add_max_megapixels(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("serve", help="the browser tool: tune settings, inspect every stage, 3D view (one port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only); any other needs a token")
    p.add_argument("--token", help="access token for every request (default: $SIGNPOSE_TOKEN; beyond loopback "
                                   "without either, a random one is made and printed)")
    p.add_argument("--port", type=port_number, default=8000, help="port, 0 to 65535 (default 8000; 0: any free port)")
    p.add_argument("--library", help="sign library folder, read at every start: copied into the state directory "
                                     "when it is new or has changed, keeping signs added in the page (default: the "
                                     "state's library; on a fresh state the samples)")
    p.add_argument("--camera", type=file_path,
                   help="camera file; it becomes the state's camera, and one the state held that differs (e.g. "
                        "calibrated in the page) is kept as camera.replaced-<UTC time>.json in the state directory "
                        "(default: the state's camera, else per image its EXIF focal length or the assumed field "
                        f"of view, {ASSUMED_HFOV_DEG:g}° unless set in the page)")
    p.add_argument("--settings", type=file_path,
                   help="settings JSON to start from (full or partial, over the defaults); they become the state's "
                        "settings, and settings the state held that differ (e.g. tuned in the page) are kept as "
                        "settings.replaced-<UTC time>.json in the state directory (default: the state's settings)")
    p.add_argument("--map", type=file_path, metavar="FILE",
                   help="a sign map file (YAML or JSON, docs/map.md) to hold from the start: the 3D scene's map "
                        "world shows it (default: none; one can be loaded or built in the page)")
    p.add_argument("--state-dir", default=str(WorkspaceConfig.state_dir),
                   help="where settings, library, camera and images survive restarts (default ./%(default)s)")
    p.add_argument("--max-images", type=positive_int, default=WorkspaceConfig.max_images,
                   help="most images held at once (default %(default)s)")
    p.add_argument("--max-memory-gb", type=positive_number, default=round(WorkspaceConfig.max_memory_bytes / 1e9, 1),
                   help=f"memory the images held may take in GB, each counted {HELD_BYTES_PER_PIXEL} bytes a pixel "
                        f"plus 1 MB, a 12 MP photo {held_bytes(12_000_000) / 1e6:.0f} MB (default: half this "
                        "machine's memory, %(default)g)")
    add_max_megapixels(p)
    p.add_argument("--max-upload-mb", type=positive_number, default=WorkspaceConfig.max_upload_bytes / 1e6,
                   help="largest request body in MB (default %(default)g)")
    p.add_argument("--max-flight-mb", type=positive_number, default=WorkspaceConfig.max_flight_upload_bytes / 1e6,
                   help="largest flight upload (a video or a bag) in MB (default %(default)g)")
    p.add_argument("--max-flight-frames", type=positive_int, default=WorkspaceConfig.max_flight_frames,
                   help="most frames one flight may hold (default %(default)s, 100 s at 30 fps)")
    p.add_argument("--max-flights", type=positive_int, default=WorkspaceConfig.max_flights,
                   help="most flights held at once (default %(default)s)")
    p.add_argument("--request-timeout", type=positive_number, default=WorkspaceConfig.request_timeout_s,
                   help="longest a request waits for pipeline work (recognise, sweep) in seconds (default %(default)g)")
    p.set_defaults(func=cmd_serve)

    from signpose.app.map_command import add_map_command  # it builds on this module's helpers

    add_map_command(sub)
    return parser


def quiet_opencv() -> None:
    """Keep OpenCV's own "[ WARN:0@...]" lines (a truncated PNG, ...) off stderr: signpose says what
    went wrong with an image in one line of its own."""
    if "OPENCV_LOG_LEVEL" in os.environ:  # someone debugging OpenCV keeps the level they chose
        return
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    os.environ["OPENCV_LOG_LEVEL"] = "ERROR"  # for evaluate's worker processes, which import cv2 afresh


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    quiet_opencv()
    try:
        with stopping_on_signals():
            return args.func(args)
    except CliError as exc:
        command = " ".join(filter(None, (args.command, getattr(args, "map_command", None))))
        print(f"signpose {command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as exc:  # Ctrl-C, and SIGTERM or SIGHUP as Interrupted
        return interrupted(f"signpose {args.command}", exc)
    except BrokenPipeError:
        # The reader went away (`signpose recognize ... | head`): stop quietly, as Unix tools do.
        # Python would flush stdout again at exit and fail on the closed pipe, so point it at devnull.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
