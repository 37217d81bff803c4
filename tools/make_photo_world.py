"""Render a set of the second test world (`pipeline.synth_photo_world`): library signs and
look-alike plaques of other words pasted into real photographs, with truth.json and camera.yaml,
as `signpose evaluate` reads them.

The photographs are read where they lie (by default `shared/data/homogr` and `shared/data/opencv`
beside the checkout, or under SIGNPOSE_SHARED), never copied:

    python tools/make_photo_world.py --out /tmp/photo-world --n 150 --seed 0
    signpose evaluate /tmp/photo-world
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for tools and tests.support
from signpose.pipeline.library import load_library  # noqa: E402
from signpose.pipeline.synth_photo_world import generate_photo_world  # noqa: E402
from tests.support.shared_data import shared_folder  # noqa: E402
from tools.render_library import render_sign  # noqa: E402

# Plaques of other words in the library's font, each sharing a word with one of its signs
# (مجمع, وزارة, رئيس, أمني, التعذيب, الأمن): the look-alike negatives.
LOOK_ALIKE_TEXTS = ("مجمع سكني", "وزارة العدل", "رئيس القسم", "مبنى أمني", "مكافحة التعذيب", "قسم الأمن")
# The share of each category in a set of n scenes.
MIX = {"easy": 0.25, "hard": 0.4, "steep": 0.15, "negative": 0.2}


def look_alike_plaques() -> list[np.ndarray]:
    """(h, w) uint8 plaques of LOOK_ALIKE_TEXTS, rendered as the sample library's signs are."""
    return [np.asarray(render_sign(text)) for text in LOOK_ALIKE_TEXTS]


def default_backgrounds() -> list[Path]:
    """The shared folders of real photographs the world's scenes are pasted into."""
    data = shared_folder() / "data"
    return [data / "homogr", data / "opencv"]


def mix_counts(n: int) -> dict[str, int]:
    """Scenes per category of MIX for `n` scenes, the remainder to the hard ones."""
    counts = {category: int(n * share) for category, share in MIX.items()}
    counts["hard"] += n - sum(counts.values())
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="an empty folder for the scenes")
    parser.add_argument("--n", type=int, default=150, help="scenes (default 150)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--backgrounds", type=Path, nargs="+", default=None,
                        help="folders of real photographs (default: the shared homogr and opencv folders)")
    args = parser.parse_args()
    with tqdm(total=args.n, desc=str(args.out), unit="scene") as bar:
        generate_photo_world(args.out, load_library(), backgrounds=args.backgrounds or default_backgrounds(),
                             decoys=look_alike_plaques(), counts=mix_counts(args.n), seed=args.seed,
                             progress=lambda done, total: bar.update(done - bar.n))


if __name__ == "__main__":
    main()
