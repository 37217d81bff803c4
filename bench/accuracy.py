"""Accuracy benchmark on synthetic scenes: the `paper` and `default` presets side by side.

Renders N scenes (default 300) from a fixed seed - easy, hard and negatives in
`pipeline.synth.DEFAULT_WEIGHTS` proportions - and a set of --steep scenes (default 40) of the
"steep" category (a sign 60-75 degrees off its normal), runs both presets on them and prints
accuracy by category and hard look, steep views with the default's affine fallback and without it,
false positives on negatives, rotation / translation / corner errors, time per image and the
poses' NEES against the truth under their own covariances (of the first set; an honest covariance
gives chi-squared with 6 dof, median 5.35, p90 10.6). The figures in docs/benchmarks.md come from:

    python bench/accuracy.py [--n 300] [--steep 40] [--seed 0] [--data DIR]

`--data DIR` keeps the rendered scenes (and re-uses them when DIR already holds a truth.json; the
steep set in DIR/steep). Not a timed test: rendering takes about a second a scene.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for bench
from bench.track import nees  # noqa: E402
from signpose.pipeline.camera import Camera  # noqa: E402
from signpose.pipeline.evaluate import Dataset, ImageResult, Report, evaluate, load_dataset, summarize  # noqa: E402
from signpose.pipeline.library import Library, load_library  # noqa: E402
from signpose.pipeline.recognize import recognize  # noqa: E402
from signpose.pipeline.settings import Settings, preset  # noqa: E402
from signpose.pipeline.synth import HARD_MODES, generate_dataset  # noqa: E402

PRESETS = ("paper", "default")


def _fraction(results: list[ImageResult], hit: Callable[[ImageResult], bool]) -> str:
    if not results:
        return "-"
    n = sum(hit(r) for r in results)
    return f"{100 * n / len(results):5.1f}% ({n}/{len(results)})"


def _pair(value: tuple[float, float] | None, digits: int = 2, scale: float = 1.0) -> str:
    return "-" if value is None else f"{scale * value[0]:.{digits}f} / {scale * value[1]:.{digits}f}"


def pose_nees(report: Report, library: Library, settings: Settings, camera: Camera | None) -> dict[str, list[float]]:
    """The NEES (bench/track.py's `nees`) of each pose of a sign `report` identified, against its truth,
    under the pose's own covariance, by how the sign was placed: "outline" (its plaque's edges) or
    "other" (features, dense alignment). The images are recognised again with `settings`: a report
    keeps no covariance."""
    out: dict[str, list[float]] = {"outline": [], "other": []}
    for r in report.results:
        if not r.correct or r.sample.R is None or r.sample.t is None:
            continue
        rec = recognize(cv2.imread(str(r.sample.path)), library, settings, camera)
        if rec.label == r.sample.label and rec.pose is not None and rec.pose.covariance is not None:
            out["outline" if rec.outline is not None else "other"].append(nees(rec.pose, r.sample.R, r.sample.t))
    return out


def _nees_pair(values: list[float]) -> str:
    return "-" if not values else f"{np.median(values):.2f} / {np.percentile(values, 90):.2f} ({len(values)})"


def rows(report: Report, both_right: set[str], nees_by: dict[str, list[float]]) -> list[tuple[str, str]]:
    """(row name, value) for one preset; `both_right`: images every preset identified correctly;
    `nees_by`: `pose_nees` of its report."""
    results = report.results

    def of(category: str, look: str | None = None) -> list[ImageResult]:
        return [r for r in results if r.sample.category == category
                and (look is None or r.sample.params.get("look") == look)]

    positives = [r for r in results if r.sample.label is not None]
    negatives = of("negative")
    summary = summarize(positives)
    common = summarize([r for r in positives if r.sample.path.name in both_right])
    out = [("easy: identified", _fraction(of("easy"), lambda r: r.correct)),
           ("hard: identified", _fraction(of("hard"), lambda r: r.correct))]
    out += [(f"  hard, {look}", _fraction(of("hard", look), lambda r: r.correct)) for look in HARD_MODES]
    out += [
        ("negatives: false positives", _fraction(negatives, lambda r: r.false_positive)),
        ("positives: wrong sign", _fraction(positives, lambda r: r.predicted not in (None, r.sample.label))),
        ("rotation error med / p90 (deg)", _pair(summary.rotation_deg)),
        ("translation error med / p90 (% dist)", _pair(summary.translation_pct)),
        ("camera position error med / p90 (cm)", _pair(summary.position_m, scale=100)),
        ("corner error med / p90 (px)", _pair(summary.corner_px)),
        ("  same, images both got right: rot (deg)", _pair(common.rotation_deg)),
        ("  same, images both got right: corner (px)", _pair(common.corner_px)),
        ("time per image med / p90 (ms)", _pair((report.total.median_time_ms, report.total.p90_time_ms), 0)),
        ("pose NEES med / p90 (honest 5.35 / 10.6)", _nees_pair(nees_by["outline"] + nees_by["other"])),
        ("  placed by the outline", _nees_pair(nees_by["outline"])),
        ("  placed otherwise", _nees_pair(nees_by["other"])),
    ]
    return out


def rendered(data: Path, library: Library, n: int, seed: int, categories: tuple[str, ...] | None = None) -> Dataset:
    """The `n` scenes from `seed` in `data` (of `categories` in equal parts, default the default mix),
    rendered first unless `data` holds a truth.json."""
    if not (data / "truth.json").is_file():
        mix = {} if categories is None else {"categories": categories, "weights": (1.0,) * len(categories)}
        with tqdm(total=n, desc=f"render {data.name}", unit="scene") as bar:
            generate_dataset(data, library, n=n, seed=seed, progress=lambda i, total: bar.update(1), **mix)
    return load_dataset(data)


def steep_rows(reports: dict[str, Report]) -> list[tuple[str, str]]:
    """(row name, value): of the steep set, the views identified, those answered with another sign and
    the rotation error of those identified, by configuration (the names of `reports`)."""
    return [(f"steep: identified, {name}", _fraction(report.results, lambda r: r.correct))
            for name, report in reports.items()] + [
        (f"steep: wrong sign, {name}", _fraction(report.results, lambda r: r.predicted not in (None, r.sample.label)))
        for name, report in reports.items()] + [
        (f"steep: rotation error med / p90 (deg), {name}", _pair(summarize(report.results).rotation_deg))
        for name, report in reports.items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="scenes to render (default 300)")
    parser.add_argument("--steep", type=int, default=40, help="steep scenes to render besides them (default 40; 0: none)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", type=Path, help="folder for the scenes (default: a temporary folder)")
    args = parser.parse_args()

    library = load_library()
    steep_settings: dict[str, Settings] = {"paper": preset("paper"), "default": preset("default"),
                                           "default without affine fallback":
                                               preset("default").replace(affine_fallback=False)}
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp)
        dataset = rendered(data, library, args.n, args.seed)
        reports, nees_by = {}, {}
        for name in PRESETS:
            with tqdm(total=len(dataset), desc=name, unit="img") as bar:
                reports[name] = evaluate([dataset], library, preset(name), progress=lambda i, n: bar.update(1))
            nees_by[name] = pose_nees(reports[name], library, preset(name), dataset.camera)
        steep_reports = {}
        if args.steep > 0:
            steep = rendered(data / "steep", library, args.steep, args.seed, ("steep",))
            for name, settings in steep_settings.items():
                with tqdm(total=len(steep), desc=f"steep, {name}", unit="img") as bar:
                    steep_reports[name] = evaluate([steep], library, settings,
                                                   progress=lambda i, n: bar.update(1))

    both_right = set.intersection(*({r.sample.path.name for r in rep.results if r.correct and r.sample.label}
                                    for rep in reports.values()))
    table = {name: dict(rows(rep, both_right, nees_by[name])) for name, rep in reports.items()}
    names = list(next(iter(table.values())))
    width = max(map(len, names)) + 2
    counts = {c: sum(s.category == c for s in dataset.samples) for c in ("easy", "hard", "negative")}
    print(f"\n{len(dataset)} synthetic scenes, seed {args.seed}: "
          + ", ".join(f"{n} {c}" for c, n in counts.items()) + f"; {dataset.camera.width}x{dataset.camera.height}")
    print(f"{'':<{width}}" + "".join(f"{name:>24}" for name in PRESETS))
    for row in names:
        print(f"{row:<{width}}" + "".join(f"{table[name][row]:>24}" for name in PRESETS))
    if steep_reports:
        print(f"\n{args.steep} steep scenes (60-75 degrees off the sign's normal), seed {args.seed}")
        for row, value in steep_rows(steep_reports):
            print(f"{row:<{width + 24}}{value:>24}")


if __name__ == "__main__":
    main()
