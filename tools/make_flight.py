"""Render synthetic corridor flights (`pipeline.synth_flight`) with their ground truth.

Without arguments, regenerates the committed sample `sample_images/flights/corridor/`: a short
flight in to the first sign, past the white look-alike plaque, to the second. With `--out`, renders
the whole corridor path (far from the wall in, along and away) for benchmarks:

    python tools/make_flight.py
    python tools/make_flight.py --out /tmp/corridor12 --duration 12
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tqdm import tqdm

from signpose.pipeline.library import load_library
from signpose.pipeline.synth import synthetic_camera
from signpose.pipeline.synth_flight import CORRIDOR_PATH, write_flight

SAMPLE = Path(__file__).resolve().parent.parent / "sample_images" / "flights" / "corridor"
# The sample: from 4 m out to the first sign, along past the look-alike to the second, in 5 s.
SAMPLE_PATH = CORRIDOR_PATH[1:6]
SAMPLE_SECONDS = 5.0
# mp4v quality of the committed sample: under 2 MB for a fresh clone.
SAMPLE_QUALITY = 60


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="render the whole corridor path here instead of the sample")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds of the whole path (with --out)")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    library, camera = load_library(), synthetic_camera()
    if args.out is None:
        out, path, duration, quality = SAMPLE, SAMPLE_PATH, SAMPLE_SECONDS, SAMPLE_QUALITY
    else:
        out, path, duration, quality = args.out, CORRIDOR_PATH, args.duration, 90
    with tqdm(total=round(duration * args.fps), desc=str(out), unit="frame") as bar:
        write_flight(out, library, camera, duration_s=duration, fps=args.fps, path=path, seed=args.seed,
                     quality=quality, progress=lambda done, total: bar.update(done - bar.n))


if __name__ == "__main__":
    main()
