"""Floor benchmark: the default preset against its floor, beside the default preset stripped of
what it adds to the paper's steps for accuracy.

The floor is SIFT alone on the crop a configuration chose (`speed.floor_ms`). "stripped" is the
default preset without the outline refinement, ECC, the text check and the refined pose: what
dropping them would bring the ratio to, and what it would cost in rotation error. Both run over
the same 640x480 scenes as `bench/speed.py` (`speed.measure`: taking turns, the fastest of
--rounds runs kept per image).

    python bench/floor.py [--n 200] [--seed 0] [--rounds 3] [--data DIR]
"""

from __future__ import annotations

import os

from signpose.pipeline.evaluate import keep_freed_memory
from signpose.pipeline.library import load_library
from signpose.pipeline.settings import preset
from signpose.pipeline.synth import CATEGORIES

from speed import SIZES, floor_line, identified_percent, machine, measure, rotation_median, scene_parser, scenes

STRIPPED = preset("default").replace(refine="none", refine_outline=False, pose_method="ippe",
                                     min_text_correlation=0.0)


def main() -> None:
    args = scene_parser(__doc__).parse_args()

    keep_freed_memory()
    print(machine(), f"load average at start: {os.getloadavg()[0]:.2f}", sep="\n")
    library = load_library()
    dataset = scenes(args.data, SIZES[0], args.n, args.seed, library)
    configs = {"default": preset("default"), "stripped": STRIPPED}
    outcomes, floors = measure(dataset, library, args.rounds, configs)
    for name in configs:
        accuracy = ", ".join(f"{c} {identified_percent(outcomes[name], dataset, c)}" for c in CATEGORIES)
        print(f"{name}: {accuracy}, rotation median {rotation_median(outcomes[name], dataset)} deg")
        print(floor_line(name, outcomes[name], floors[name]))


if __name__ == "__main__":
    main()
