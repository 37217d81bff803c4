"""`signpose map build`: a sign map from survey photos and flights (`pipeline.map_build`, docs/map.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from signpose.app.cli import (CliError, add_max_megapixels, file_path, load_inputs, max_pixels, output_path,
                              positive_int, progress, say, stopped_after, unusable_images)
from signpose.app.image_store import decode_upload
from signpose.pipeline.camera import ASSUMED_HFOV_DEG, Camera, CameraError
from signpose.pipeline.evaluate import keep_freed_memory
from signpose.pipeline.every_sign import recognize_every_sign
from signpose.pipeline.frames import FrameSource, ImageSource, SourceError, open_source
from signpose.pipeline.image import ImageError, read_file
from signpose.pipeline.library import SAMPLE_LIBRARY, Library
from signpose.pipeline.map_build import (FLIGHT_STEP, MapBuildError, Observation, build_map, format_report,
                                        observations_of, takes_frame)
from signpose.pipeline.recognize import PipelineError
from signpose.pipeline.settings import PRESETS, Settings
from signpose.pipeline.sign_map import MapError, load_sign_map, save_sign_map, sign_map_yaml
from signpose.pipeline.track import Tracker

# A survey folder may carry these beside its photos; used unless --camera or --library is given.
SURVEY_CAMERA, SURVEY_LIBRARY = "camera.yaml", "library"


def add_map_command(sub: argparse._SubParsersAction) -> None:
    """`signpose map build` on the CLI's sub-command parsers `sub`."""
    p = sub.add_parser("map", help="sign maps: build one from a survey (docs/map.md)")
    commands = p.add_subparsers(dest="map_command", required=True, metavar="{build}", help="what to do with a map")
    b = commands.add_parser("build", help="every sign's pose in one map frame, from photos and flights that see "
                                          "signs together")
    b.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="photos, folders of photos, and flights (a video, a ROS bag); a folder's camera.yaml and "
                        "library/ are used unless --camera or --library is given")
    b.add_argument("-o", "--output", type=output_path, required=True, metavar="MAP",
                   help="map file to write (YAML; - writes it on stdout, the report on stderr)")
    b.add_argument("--anchor", metavar="SIGN_ID", help="the sign whose frame is the map frame (default: the first "
                                                       "sign seen)")
    b.add_argument("--known", type=file_path, metavar="MAP",
                   help="a map file of signs whose poses are known (e.g. measured by tape): they fix the map frame, "
                        "held by their covariance when given, else tightly")
    b.add_argument("--library", help="sign library folder (default: the first source folder's library/, else the "
                                      "samples)")
    b.add_argument("--camera", type=file_path,
                   help="camera file (default: the first source folder's camera.yaml, else a photo's EXIF or an "
                        f"assumed {ASSUMED_HFOV_DEG:g}° field of view, a bag's CameraInfo)")
    b.add_argument("--settings", type=file_path, help="settings JSON (full or partial), applied over --preset")
    b.add_argument("--preset", default="default", choices=sorted(PRESETS), help="base settings (default: default)")
    b.add_argument("--topic", help="a bag's image topic (default: its only one)")
    b.add_argument("--flight-step", type=positive_int, default=FLIGHT_STEP, metavar="N",
                   help="take a flight's confirmed signs on one frame in N, and on every frame with two or more "
                        "(default %(default)s)")
    add_max_megapixels(b)
    b.set_defaults(func=cmd_map_build)


def beside_sources(sources: list[str], name: str) -> Path | None:
    """The first `name` in a source folder (or the folder of a source file), None when there is none."""
    for spec in sources:
        path = Path(spec)
        candidate = (path if path.is_dir() else path.parent) / name
        if candidate.exists():
            return candidate
    return None


def cmd_map_build(args: argparse.Namespace) -> int:
    if args.anchor is not None and args.known is not None:
        raise CliError("give --anchor or --known, not both: the known signs fix the map frame")
    if args.library is None:
        found = beside_sources(args.sources, SURVEY_LIBRARY)
        args.library = str(found if found is not None and (found / "library.json").is_file() else SAMPLE_LIBRARY)
    if args.camera is None and (found := beside_sources(args.sources, SURVEY_CAMERA)) is not None:
        args.camera = str(found)
    library, settings, camera = load_inputs(args)
    ids = [s.id for s in library.signs]
    if args.anchor is not None and args.anchor not in ids:
        raise CliError(f"--anchor {args.anchor!r} is not a sign of the library {args.library}, which has "
                       f"{', '.join(ids)}")
    try:
        known = load_sign_map(args.known, ids) if args.known is not None else None
    except MapError as exc:
        raise CliError(str(exc)) from None
    keep_freed_memory()
    try:
        sources = [open_source(spec, topic=args.topic, max_pixels=max_pixels(args)) for spec in args.sources]
    except SourceError as exc:
        raise CliError(str(exc)) from None
    counts = [len(s.paths) if isinstance(s, ImageSource) else s.count for s in sources]
    total = sum(c for c in counts if c is not None) if all(c is not None for c in counts) else None
    observations: list[Observation] = []
    done = failed = 0
    # A photo or flight given twice (a folder and a file in it, a folder twice) would count as two
    # independent views of its signs, and narrow their covariance for nothing.
    used: set[Path] = set()
    repeated: list[str] = []
    with progress(total=total, desc="map build", leave=False) as bar, \
            stopped_after(lambda: done, total or done, "images and frames"):
        for source in sources:
            with source:
                if not isinstance(source, ImageSource) and Path(source.name).exists():
                    if Path(source.name).resolve() in used:
                        repeated.append(source.name)
                        bar.update(source.count or 0)
                        continue
                    used.add(Path(source.name).resolve())
                if isinstance(source, ImageSource):
                    for path in source.paths:
                        if path.resolve() in used:
                            repeated.append(str(path))
                            bar.update()
                            continue
                        used.add(path.resolve())
                        seen = photo_observations(str(path), library, settings, camera, max_pixels(args))
                        if seen is None:
                            failed += 1
                        else:
                            observations += seen
                        done += 1
                        bar.update()
                else:
                    for frame_done, seen in flight_observations(source, library, settings, camera, args.flight_step):
                        observations += seen
                        done += frame_done
                        bar.update(frame_done)
    if repeated:
        print(f"warning: {len(repeated)} photo(s) or flight(s) given more than once, each used once: "
              f"{', '.join(repeated[:3])}{', ...' if len(repeated) > 3 else ''}", file=sys.stderr)
    signs = sorted({o.sign_id for o in observations})
    images = len({o.image for o in observations})
    print(f"{done} images and frames, {images} with a sign: {len(observations)} observations of "
          f"{len(signs)} sign(s)", file=sys.stderr)
    try:
        build = build_map(observations, anchor=args.anchor, known=known)
    except MapBuildError as exc:
        print(f"signpose map build: error: {exc}", file=sys.stderr)
        return 1
    report = format_report(build)
    if args.output == "-":
        print(sign_map_yaml(build.sign_map, build.comments()), end="")
        print(report, file=sys.stderr)
    else:
        save_sign_map(build.sign_map, args.output, comments=build.comments())
        print(report)
        print(f"wrote {len(build.sign_map.signs)} signs in frame {build.sign_map.frame!r} to {args.output}",
              file=sys.stderr)
    return unusable_images(failed, done)


def photo_observations(name: str, library: Library, settings: Settings, camera: Camera | None,
                       limit: int) -> list[Observation] | None:
    """The signs seen in photo `name` (its EXIF orientation applied, as `recognize` reads it); None, said on
    stderr, when it cannot be used."""
    try:
        image, _, exif = decode_upload(read_file(name), name, limit)
        height, width = image.shape[:2]
        recognitions = recognize_every_sign(image, library, settings,
                                            exif.camera_for(camera, width, height, ASSUMED_HFOV_DEG))
    except (ImageError, CameraError, PipelineError) as exc:
        say(f"warning: {name}: {str(exc).removeprefix(name + ': ')}", sys.stderr)
        return None
    return observations_of(name, recognitions)


def flight_observations(source: FrameSource, library: Library, settings: Settings, camera: Camera | None,
                        step: int):
    """Per frame of the flight `source`, (1, its observations): the tracker's confirmed signs on one
    frame in `step` and on every frame with two or more (the links between signs, which a flight
    past a wall gives a few frames of); the others give none. A frame that cannot be read ends the
    flight, said on stderr."""
    tracker = Tracker(library, settings, camera if camera is not None else source.camera, fps=source.fps)
    frames = iter(source)
    while True:
        try:
            frame = next(frames, None)
        except SourceError as exc:
            say(f"warning: {exc}; the frames before it are used", sys.stderr)
            return
        if frame is None:
            return
        try:
            result = tracker.step(frame.image, index=frame.index, time_s=frame.time_s)
        except CameraError as exc:
            raise CliError(f"{source.name}: {exc}") from None
        yield 1, (observations_of(f"{source.name}#{frame.index}", result.signs)
                  if takes_frame(frame.index, len(result.signs), step) else [])
