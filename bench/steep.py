"""Steep-view benchmark: the default preset with its affine fallback and without it, side by side.

N synthetic scenes at 640x480 (pipeline.synth, fixed seed): two thirds "steep" (a sign 60-75 degrees
off its normal), one third without a sign. Printed: the library side's preparation per sign (the
simulated views, once per library, beside its ordinary features), steep views identified and false
positives with the fallback and without, and what the fallback adds to an image's time where it
runs (the ordinary path named no sign) and where it does not (the ordinary path decided). Both
configurations take turns over the images, the fastest of --rounds runs kept per image
(`speed.measure`).

    python bench/steep.py [--n 60] [--seed 0] [--rounds 3] [--data DIR]
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from signpose.pipeline.evaluate import Dataset, load_dataset
from signpose.pipeline.features import library_affine_features, library_features
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.settings import preset
from signpose.pipeline.synth import RENDERING, generate_dataset

from speed import Outcome, identified_percent, machine, measure, scene_parser

WITH = preset("default")
CONFIGS = {"without": WITH.replace(affine_fallback=False), "with": WITH}
MIX = {"steep": 2.0, "negative": 1.0}


def steep_scenes(data: Path, n: int, seed: int, library: Library) -> Dataset:
    """`n` scenes of the MIX from `seed`, rendered into `data` unless already there."""
    root = data / f"steep-seed{seed}-n{n}-r{RENDERING}"
    if not (root / "truth.json").is_file():
        with tqdm(total=n, desc="render", unit="scene") as bar:
            generate_dataset(root, library, n=n, seed=seed, categories=tuple(MIX), weights=tuple(MIX.values()),
                             progress=lambda i, total: bar.update(1))
    return load_dataset(root)


def preparation_ms() -> tuple[float, float]:
    """ms per sign of the sample library's ordinary features and of its simulated views, each computed once."""
    library = load_library()  # fresh: nothing cached on it
    t0 = time.perf_counter()
    library_features(library, WITH)
    t1 = time.perf_counter()
    library_affine_features(library, WITH)
    t2 = time.perf_counter()
    return (t1 - t0) * 1e3 / len(library.signs), (t2 - t1) * 1e3 / len(library.signs)


def added_ms(without: list[Outcome], with_: list[Outcome], images: list[int]) -> str:
    """Median and p90 over `images` of the time the fallback adds, and the median time with it."""
    if not images:
        return "no image"
    added = [with_[i].timing_ms["total"] - without[i].timing_ms["total"] for i in images]
    total = [with_[i].timing_ms["total"] for i in images]
    return (f"{len(images)} images: added {np.median(added):+.1f} ms median, {np.percentile(added, 90):+.1f} ms p90 "
            f"(total {np.median(total):.1f} ms median)")


def main() -> None:
    parser = scene_parser(__doc__)
    parser.set_defaults(n=60, data=Path(tempfile.gettempdir()) / "signpose-steep")
    args = parser.parse_args()

    print(machine(), f"load average at start: {os.getloadavg()[0]:.2f}", sep="\n")
    ordinary, simulated = preparation_ms()
    print(f"library preparation per sign, once: ordinary features {ordinary:.0f} ms, simulated steep views "
          f"{simulated:.0f} ms")
    library = load_library()
    dataset = steep_scenes(args.data, args.n, args.seed, library)
    outcomes, _ = measure(dataset, library, args.rounds, CONFIGS)
    without, with_ = outcomes["without"], outcomes["with"]
    for name, runs in outcomes.items():
        wrong = sum(o.label not in (None, s.label) for o, s in zip(runs, dataset.samples) if s.label is not None)
        false = sum(o.label is not None for o, s in zip(runs, dataset.samples) if s.label is None)
        print(f"{name:>8} the affine fallback: steep identified {identified_percent(runs, dataset, 'steep')}, "
              f"wrong sign {wrong}, false positives {false} of {sum(s.label is None for s in dataset.samples)}")
    ran = [i for i, o in enumerate(without) if o.label is None]
    decided = [i for i, o in enumerate(without) if o.label is not None]
    print(f"where it runs (the ordinary path named no sign), {added_ms(without, with_, ran)}")
    negatives = [i for i in ran if dataset.samples[i].label is None]
    print(f"  of which without a sign, {added_ms(without, with_, negatives)}")
    print(f"where the ordinary path decided (the fallback does not run), {added_ms(without, with_, decided)}")


if __name__ == "__main__":
    main()
