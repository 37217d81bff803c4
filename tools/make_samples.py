"""Regenerate the committed synthetic samples from fixed seeds.

`sample_images/scenes/`: 12 scenes (7 easy, 2 hard, 3 negatives) for demos and the web gallery.
`sample_images/datasets/set1..set3/`: 10, 11 and 5 labelled images in the shape of the paper's
experiment (its Table 1), mixed signs with a negative or two. Every folder holds its images,
`camera.yaml` and `truth.json`.

    python tools/make_samples.py
"""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from signpose.pipeline.library import load_library
from signpose.pipeline.synth import generate_dataset

ROOT = Path(__file__).resolve().parent.parent / "sample_images"

# folder: (images, (easy, hard, negative) counts, seed)
SAMPLES = {
    "scenes": (12, (7, 2, 3), 2024),
    "datasets/set1": (10, (7, 2, 1), 1),
    "datasets/set2": (11, (7, 2, 2), 2),
    "datasets/set3": (5, (3, 1, 1), 3),
}


def main() -> None:
    library = load_library()
    for folder, (n, counts, seed) in SAMPLES.items():
        out = ROOT / folder
        for stale in out.glob("scene_*.jpg"):  # a smaller set must not leave old images behind
            stale.unlink()
        with tqdm(total=n, desc=folder, unit="scene") as bar:
            generate_dataset(out, library, n=n, seed=seed, weights=counts,
                             progress=lambda done, total: bar.update(done - bar.n))


if __name__ == "__main__":
    main()
