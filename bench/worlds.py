"""Two independent synthetic worlds side by side: the `paper` and `default` presets on
`pipeline.synth`'s rendered rooms and on `pipeline.synth_photo_world`'s signs pasted into real
photographs, so that a default tuned on one world alone shows on the other.

Per world and preset: easy and hard views identified, signs 40-80 px wide (of the easy, hard and
steep views, by their truth corners), dim plaques, steep views (60-75 degrees off the normal),
false positives on the negatives (and on the photo world's look-alike plaques of other words),
answers naming another sign, the rotation error median and p90, and time per image. `--misses`
lists the default preset's misses with their look, width and angle, and for each positive missed
the stage that dropped it (`dropped_by`, the image recognised again).

    SIGNPOSE_SHARED=/path/to/shared python bench/worlds.py [--n 150] [--seed 0] [--data DIR] [--misses]

Scenes are rendered once into --data (default: signpose-worlds in the temp folder) and re-used.
The photographs are read from the shared folder, never copied.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for bench, tools, tests.support
from bench.accuracy import _fraction, _pair  # noqa: E402
from bench.speed import machine  # noqa: E402
from signpose.pipeline.evaluate import Dataset, ImageResult, Report, evaluate, load_dataset, summarize  # noqa: E402
from signpose.pipeline.camera import Camera  # noqa: E402
from signpose.pipeline.library import Library, load_library  # noqa: E402
from signpose.pipeline.recognize import recognize  # noqa: E402
from signpose.pipeline.settings import preset  # noqa: E402
from signpose.pipeline.synth import RENDERING, generate_dataset  # noqa: E402
from signpose.pipeline.synth_photo_world import generate_photo_world  # noqa: E402
from tools.make_photo_world import MIX, default_backgrounds, look_alike_plaques, mix_counts  # noqa: E402

PRESETS = ("paper", "default")
SMALL_PX = (40.0, 80.0)  # a sign this wide (the wider of its top and bottom edges) is small


def rooms(root: Path, library: Library, n: int, seed: int) -> Dataset:
    """`pipeline.synth`'s world: n scenes in MIX proportions, rendered into `root` unless there."""
    if not (root / "truth.json").is_file():
        with tqdm(total=n, desc="render rooms", unit="scene") as bar:
            generate_dataset(root, library, n=n, seed=seed, categories=tuple(MIX), weights=tuple(MIX.values()),
                             progress=lambda i, total: bar.update(1))
    return load_dataset(root)


def photos(root: Path, library: Library, n: int, seed: int, backgrounds: list[Path]) -> Dataset:
    """`pipeline.synth_photo_world`'s world: n scenes in MIX proportions, rendered into `root` unless there."""
    if not (root / "truth.json").is_file():
        with tqdm(total=n, desc="render photos", unit="scene") as bar:
            generate_photo_world(root, library, backgrounds=backgrounds, decoys=look_alike_plaques(),
                                 counts=mix_counts(n), seed=seed, progress=lambda i, total: bar.update(1))
    return load_dataset(root)


def width_px(result: ImageResult) -> float:
    """The sign's width in the image (the wider of its top and bottom edges), from its truth corners."""
    c = result.sample.corners
    return float(max(np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[2] - c[3])))


def rows(report: Report) -> list[tuple[str, str]]:
    """(row name, value) of one preset on one world."""
    results = report.results
    positives = [r for r in results if r.sample.label is not None]

    def where(keep: Callable[[ImageResult], bool]) -> list[ImageResult]:
        return [r for r in results if keep(r)]

    small = [r for r in positives if SMALL_PX[0] <= width_px(r) <= SMALL_PX[1]]
    summary = summarize(positives)
    return [
        ("easy: identified", _fraction(where(lambda r: r.sample.category == "easy"), lambda r: r.correct)),
        ("hard: identified", _fraction(where(lambda r: r.sample.category == "hard"), lambda r: r.correct)),
        (f"  small ({SMALL_PX[0]:.0f}-{SMALL_PX[1]:.0f} px), any view", _fraction(small, lambda r: r.correct)),
        ("  dim", _fraction(where(lambda r: r.sample.params.get("look") == "dim"), lambda r: r.correct)),
        ("steep: identified", _fraction(where(lambda r: r.sample.category == "steep"), lambda r: r.correct)),
        ("negatives: false positives", _fraction(where(lambda r: r.sample.label is None),
                                                 lambda r: r.false_positive)),
        ("  look-alike plaques answered", _fraction(where(lambda r: r.sample.params.get("look") == "look-alike"),
                                                    lambda r: r.false_positive)),
        ("positives: wrong sign", _fraction(positives, lambda r: r.predicted not in (None, r.sample.label))),
        ("rotation error med / p90 (deg)", _pair(summary.rotation_deg)),
        ("corner error med / p90 (px)", _pair(summary.corner_px)),
        ("time per image med / p90 (ms)", _pair((report.total.median_time_ms, report.total.p90_time_ms), 0)),
    ]


def dropped_by(result: ImageResult, library: Library, camera: Camera | None) -> str:
    """The stage that dropped a positive the default preset missed, its image recognised again: the
    text check (the weakest strip or the side the plaque went on beyond, and where), else the most
    inliers the sign had in a region searched (which, and whether any region searched held all of
    its truth corners), or the plaque fallback's reason."""
    label, corners = result.sample.label, result.sample.corners
    rec = recognize(cv2.imread(str(result.sample.path)), library, preset("default"), camera)
    turned = [t for t in rec.turned_down if t.sign == label]
    if turned:
        text = turned[0].text
        what = (f"continued {'/'.join(text.continued)}" if text.continued else
                "no strip read" if text.score is None else f"strip score {text.score:.2f}")
        return f"text check ({what}) in {turned[0].source}"
    held = [a for a in rec.attempts if a.region[0] <= corners[:, 0].min() and a.region[1] <= corners[:, 1].min()
            and a.region[2] >= corners[:, 0].max() and a.region[3] >= corners[:, 1].max()]
    best = max(((s.n_inliers, s.n_matches, a.source) for a in rec.attempts for s in a.scores if s.sign == label),
               default=(0, 0, "nothing"))
    plaque = f"; plaque fallback: {rec.plaque.reason}" if rec.plaque is not None and rec.plaque.reason else ""
    return (f"features: at most {best[0]} inliers ({best[1]} matches) in {best[2]}; "
            f"{len(held)} of {len(rec.attempts)} regions searched held it{plaque}")


def misses(report: Report, library: Library, camera: Camera | None) -> list[str]:
    """One line per positive the preset did not identify, with the stage that dropped it (`dropped_by`),
    and per negative it answered."""
    lines = []
    for r in report.results:
        if r.correct:
            continue
        p = r.sample.params
        seen = (f"{width_px(r):.0f} px, {p.get('off_axis_deg', float('nan')):.0f} deg: {dropped_by(r, library, camera)}"
                if r.sample.label else "")
        lines.append(f"  {r.sample.path.name}: {r.sample.category}/{p.get('look')} {r.sample.label} -> {r.predicted} "
                     f"{seen}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=150, help="scenes per world (default 150)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "signpose-worlds",
                        help="folder the scenes are rendered into and re-used from")
    parser.add_argument("--backgrounds", type=Path, nargs="+", default=None,
                        help="folders of real photographs (default: the shared homogr and opencv folders)")
    parser.add_argument("--misses", action="store_true", help="list the default preset's misses")
    parser.add_argument("--world", choices=("rooms", "photos"), action="append",
                        help="run only this world (again for both; default both)")
    args = parser.parse_args()
    library = load_library()
    load_start = os.getloadavg()[0]
    render = {"rooms": lambda: rooms(args.data / f"rooms-n{args.n}-seed{args.seed}-r{RENDERING}", library, args.n,
                                     args.seed),
              "photos": lambda: photos(args.data / f"photos-n{args.n}-seed{args.seed}", library, args.n, args.seed,
                                       args.backgrounds or default_backgrounds())}
    worlds = {world: make() for world, make in render.items() if world in (args.world or render)}
    reports: dict[tuple[str, str], Report] = {}
    for world, dataset in worlds.items():
        for name in PRESETS:
            with tqdm(total=len(dataset), desc=f"{world}, {name}", unit="img") as bar:
                reports[world, name] = evaluate([dataset], library, preset(name), progress=lambda i, n: bar.update(1))
    table = {key: dict(rows(report)) for key, report in reports.items()}
    names = list(next(iter(table.values())))
    width = max(map(len, names)) + 2
    print(f"\n{machine()}; load average {load_start:.2f} at start, {os.getloadavg()[0]:.2f} at end")
    for world, dataset in worlds.items():
        counts = ", ".join(f"{sum(s.category == c for s in dataset.samples)} {c}" for c in MIX)
        print(f"{world}: {len(dataset)} scenes, seed {args.seed} ({counts})")
    print(f"{'':<{width}}" + "".join(f"{f'{world}, {name}':>22}" for world, name in reports))
    for row in names:
        print(f"{row:<{width}}" + "".join(f"{table[key][row]:>22}" for key in reports))
    if args.misses:
        for world in worlds:
            print(f"\n{world}, default preset: misses")
            print("\n".join(misses(reports[world, "default"], library, worlds[world].camera)))


if __name__ == "__main__":
    main()
