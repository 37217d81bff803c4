"""A flight tracked in frame ranges (`track --dask`, `--chunk-frames`) against one run over the whole flight.

Tracks the flight whole, then in ranges of --chunk-frames frames with each --warm-up, as a cluster's workers
do (`signpose.app.batch.tracked_range`, the ranges joined as the client joins them), all in this process on
one OpenCV thread. Per warm-up: the frames whose signs differ from the whole run's, the largest difference
of the camera position (raw and filtered, mm) on the frames where both saw a sign, and how many of those
differ by more than 0.01 mm. Then the CPU time (of the whole process: FFmpeg decodes on threads of its own)
a frame takes to decode and to track, what a range's worker spends on the frames it only decodes.

    python bench/ranges.py [--flight sample_images/flights/corridor] [--chunk-frames 50] [--warm-up 0 30]

The differences are not times; the decode and track times are: measure those with nothing else
running (`--no-times` leaves them out).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from signpose.app.batch import FlightItem, frame_ranges, joined, tracked_range
from signpose.pipeline.camera import load_camera
from signpose.pipeline.frames import open_source
from signpose.pipeline.library import load_library
from signpose.pipeline.settings import Settings

SAMPLE_FLIGHT = Path(__file__).resolve().parent.parent / "sample_images" / "flights" / "corridor"
MAX_PIXELS = 100_000_000


def tracked(video: str, camera, ranges: list[tuple[int, int | None]], warm_up: int) -> list[dict]:
    """The flight's `--json` records tracked in `ranges`, each after `warm_up` frames, joined."""
    library, settings = load_library(), [Settings()]
    parts = [tracked_range(library, settings, (FlightItem(0, 0, part, video, camera, None, None, None, MAX_PIXELS,
                                                          start, stop, warm_up), video))
             for part, (start, stop) in enumerate(ranges)]
    return joined(parts)["records"]


def differences(whole: list[dict], ranged: list[dict]) -> dict:
    """Frames whose labels differ, and the camera positions' differences (mm) of the signs both runs saw."""
    labels = 0
    mm: dict[str, list[float]] = {"pose": [], "filtered_pose": []}
    for ours, theirs in zip(ranged, whole, strict=True):
        if sorted(s["label"] for s in ours["signs"]) != sorted(s["label"] for s in theirs["signs"]):
            labels += 1
            continue
        for sign in ours["signs"]:
            same = next(s for s in theirs["signs"] if s["label"] == sign["label"])
            for kind, found in mm.items():
                if sign[kind] is not None and same[kind] is not None:
                    found.append(1e3 * float(np.linalg.norm(np.subtract(sign[kind]["camera_position"],
                                                                        same[kind]["camera_position"]))))
    return {"frames_with_other_signs": labels, "max_mm": round(max(mm["pose"], default=0.0), 3),
            "max_filtered_mm": round(max(mm["filtered_pose"], default=0.0), 3),
            "frames_over_0.01_mm": sum(d > 0.01 for d in mm["filtered_pose"])}


def decode_and_track_ms(video: str, camera) -> tuple[float, float]:
    """CPU ms a frame to decode the video, and to decode and track it."""
    started = time.process_time()
    with open_source(video, max_pixels=MAX_PIXELS) as source:
        count = sum(1 for _ in source)
    decode = (time.process_time() - started) / count * 1e3
    tracked(video, camera, [(0, None)], 0)  # the library's features, computed on first use
    started = time.process_time()
    tracked(video, camera, [(0, None)], 0)
    return decode, (time.process_time() - started) / count * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flight", type=Path, default=SAMPLE_FLIGHT, help="a folder with flight.mp4, camera.yaml")
    parser.add_argument("--chunk-frames", type=int, default=50, help="frames a range")
    parser.add_argument("--warm-up", type=int, nargs="+", default=[0, 30], help="warm-ups to compare, frames")
    parser.add_argument("--no-times", action="store_true", help="leave the decode and track times out")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    video, camera = str(args.flight / "flight.mp4"), load_camera(args.flight / "camera.yaml")
    with open_source(video, max_pixels=MAX_PIXELS) as source:
        count = source.count
    whole = tracked(video, camera, [(0, None)], 0)
    ranges = frame_ranges(count, None, args.chunk_frames)
    print(f"{args.flight.name}: {len(whole)} frames, ranges {ranges}; load average {os.getloadavg()}")
    for warm_up in args.warm_up:
        print(f"warm-up {warm_up} frames: {differences(whole, tracked(video, camera, ranges, warm_up))}")
    if not args.no_times:
        decode, track = decode_and_track_ms(video, camera)
        print(f"CPU a frame: decode {decode:.2f} ms, decode and track {track:.2f} ms; "
              f"load average {os.getloadavg()}")


if __name__ == "__main__":
    main()
