"""Real photographs: signpose's default preset beside plain OpenCV on pairs nobody here made.

Every pair in `shared/data/homogr` (photo A the one-landmark library, photo B the scene; error:
RMSE in B px of the ground-truth points mapped through the answered homography, library px ->
image px), then OpenCV's classic box (the whole `box.png` and a crop of it as the library,
`box_in_scene.png` the scene; no ground truth) and graf (graf1 the library, graf3 the scene; error:
the largest of the four corners' distances from where `H1to3p.xml` puts them).

The library entry is made as `signpose recognize --library` and the page's "add sign" make it: the
image and a nominal width, nothing else. Plain OpenCV: SIFT 8000 features, ratio 0.8,
`cv2.findHomography` USAC_MAGSAC at 3 px, answered with at least 10 inliers.

    SIGNPOSE_SHARED=/path/to/shared python bench/real_pairs.py

The data is read where it lies (`shared` beside the checkout, or SIGNPOSE_SHARED), never copied.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from signpose.pipeline.library import Library, make_sign, validate_sign_entry
from signpose.pipeline.recognize import Recognition, recognize, why_no_feature_winner
from signpose.pipeline.settings import preset
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for tests.support
from tests.support.shared_data import shared_folder  # noqa: E402

GOOD_PX = 5.0  # an answer within this RMSE is right
WRONG_PX = 20.0  # an answer beyond it is a confident wrong one
CV_FEATURES, CV_RATIO, CV_THRESHOLD_PX, CV_MIN_INLIERS = 8000, 0.8, 3.0, 10
# The box's crop, library px (x0, y0, x1, y1) of box.png: its front face, cut inside its edges,
# as a user marking the landmark on the page would cut it.
BOX_CROP = (40, 30, 280, 200)


@dataclass(frozen=True)
class Case:
    """One landmark (gray library image) and one scene (BGR), with `error` (px) of an answered H
    (library px -> scene px) against the case's ground truth, None without one."""

    name: str
    landmark: np.ndarray
    scene: np.ndarray
    error: Callable[[np.ndarray], float] | None


@dataclass(frozen=True)
class Outcome:
    answered: bool
    error_px: float | None
    inliers: int
    reason: str | None  # why it was refused; for an answer, how much of the landmark was in view when not all
    ms: float


def _read(path: Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        sys.exit(f"cannot read {path}")
    return image


# The ground truth is in OpenCV's px on both sides, pixel x's centre at x; an answer's H takes library px,
# whose pixel u spans [u, u + 1] (docs/conventions.md): OpenCV's x of the landmark is its u = x + 0.5.
TO_LIBRARY_PX = 0.5


def _points_rmse(truth: np.ndarray) -> Callable[[np.ndarray], float]:
    """RMSE (B px) of the (N, 7) label-1 rows `xA yA 1 xB yB 1 label` mapped from A to B through H."""
    def error(H: np.ndarray) -> float:
        mapped = cv2.perspectiveTransform(truth[None, :, :2].astype(np.float64) + TO_LIBRARY_PX, H)[0]
        return float(np.sqrt(np.mean(np.sum((mapped - truth[:, 3:5]) ** 2, axis=1))))
    return error


def _corner_error(truth_H: np.ndarray, size: tuple[int, int]) -> Callable[[np.ndarray], float]:
    """The largest distance (scene px) between a (w, h) = `size` image's corners through H and through `truth_H`."""
    w, h = size
    corners = np.array([[[0, 0], [w, 0], [w, h], [0, h]]], dtype=np.float64)
    expected = cv2.perspectiveTransform(corners - TO_LIBRARY_PX, truth_H)[0]

    def error(H: np.ndarray) -> float:
        return float(np.linalg.norm(cv2.perspectiveTransform(corners, H)[0] - expected, axis=1).max())
    return error


def _opencv_matrix(path: Path) -> np.ndarray:
    """The first matrix's `data` of an OpenCV FileStorage XML file (cv2.FileStorage of OpenCV 5 cannot read
    this file of OpenCV 1's), as a (rows, cols) float64 array."""
    text = path.read_text(encoding="ascii")
    found = [re.search(pattern, text, re.DOTALL) for pattern in (r"<rows>\s*(\d+)", r"<cols>\s*(\d+)",
                                                                 r"<data>(.*?)</data>")]
    if any(f is None for f in found):
        sys.exit(f"{path} holds no OpenCV matrix")
    rows, cols, data = (f.group(1) for f in found if f is not None)
    return np.array(data.split(), dtype=np.float64).reshape(int(rows), int(cols))


def cases(shared: Path) -> list[Case]:
    homogr, opencv = shared / "data" / "homogr", shared / "data" / "opencv"
    out = []
    for points in sorted(homogr.glob("*_pts.txt"), key=lambda p: p.name.lower()):
        name = points.name[:-len("_pts.txt")]
        rows = np.loadtxt(points)
        out.append(Case(name, _read(next(homogr.glob(f"{name}A.*")), cv2.IMREAD_GRAYSCALE),
                        _read(next(homogr.glob(f"{name}B.*"))), _points_rmse(rows[rows[:, 6] == 1])))
    box, scene = _read(opencv / "box.png", cv2.IMREAD_GRAYSCALE), _read(opencv / "box_in_scene.png")
    x0, y0, x1, y1 = BOX_CROP
    out += [Case("box", box, scene, None), Case("box crop", box[y0:y1, x0:x1].copy(), scene, None)]
    graf1 = _read(opencv / "graf1.png", cv2.IMREAD_GRAYSCALE)
    truth = _opencv_matrix(opencv / "H1to3p.xml")
    out.append(Case("graf1->graf3", graf1, _read(opencv / "graf3.png"),
                    _corner_error(truth, (graf1.shape[1], graf1.shape[0]))))
    return out


def one_sign_library(landmark: np.ndarray, root: Path) -> Library:
    """The library a user makes of one image: its id, file name and a nominal width, as the page's "add sign"."""
    entry = validate_sign_entry({"id": "landmark", "image": "landmark.png", "width_m": 1.0}, "landmark")
    return Library(root, [make_sign(entry, landmark, "landmark")])


def refusal(rec: Recognition) -> str:
    """Why `rec` answered nothing: the plaque fallback's reason when it had the last word, else the features'."""
    if rec.plaque is not None and rec.plaque.reason is not None and not rec.scores:
        return rec.plaque.reason
    return why_no_feature_winner(rec.attempt)


def run_signpose(case: Case, settings_name: str) -> Outcome:
    library = one_sign_library(case.landmark, shared_folder())
    t0 = time.perf_counter()
    rec = recognize(case.scene, library, preset(settings_name))
    ms = (time.perf_counter() - t0) * 1e3
    best = rec.attempt.leader if rec.attempt is not None else None
    inliers = best.n_inliers if best is not None else 0
    if not rec.recognized or rec.H is None:
        return Outcome(False, None, inliers, refusal(rec), ms)
    in_view = next((w.split(":")[0] for w in rec.warnings if w.startswith("only ") and " is in the image" in w), None)
    return Outcome(True, case.error(rec.H) if case.error else None, inliers, in_view, ms)


def run_opencv(case: Case) -> Outcome:
    t0 = time.perf_counter()
    sift = cv2.SIFT_create(nfeatures=CV_FEATURES)
    kp_a, des_a = sift.detectAndCompute(case.landmark, None)
    kp_b, des_b = sift.detectAndCompute(cv2.cvtColor(case.scene, cv2.COLOR_BGR2GRAY), None)
    good = []
    if des_a is not None and des_b is not None and len(kp_b) >= 2:
        good = [m for m, n in (p for p in cv2.BFMatcher().knnMatch(des_a, des_b, k=2) if len(p) == 2)
                if m.distance < CV_RATIO * n.distance]
    H, mask = None, None
    if len(good) >= 4:
        src = np.array([kp_a[m.queryIdx].pt for m in good], dtype=np.float32)
        dst = np.array([kp_b[m.trainIdx].pt for m in good], dtype=np.float32)
        H, mask = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, CV_THRESHOLD_PX, maxIters=10000, confidence=0.999)
    ms = (time.perf_counter() - t0) * 1e3
    inliers = int(mask.sum()) if mask is not None else 0
    if H is None or inliers < CV_MIN_INLIERS:
        return Outcome(False, None, inliers, f"{inliers} inliers of {len(good)} matches", ms)
    # OpenCV's H takes the landmark's OpenCV px: in library px, as the error reads an answer's, it is H·(u - 0.5).
    in_library_px = H @ np.array([[1, 0, -TO_LIBRARY_PX], [0, 1, -TO_LIBRARY_PX], [0, 0, 1]])
    return Outcome(True, case.error(in_library_px) if case.error else None, inliers, None, ms)


def _cell(outcome: Outcome) -> str:
    if not outcome.answered:
        return f"{'refused':>9} {outcome.inliers:5d}"
    error = "answered" if outcome.error_px is None else f"{outcome.error_px:8.2f}"
    return f"{error:>9} {outcome.inliers:5d}"


def _tally(outcomes: list[tuple[Case, Outcome]]) -> str:
    scored = [o for c, o in outcomes if c.error is not None and c.name in _homogr_names(outcomes)]
    good = sum(o.answered and o.error_px is not None and o.error_px <= GOOD_PX for o in scored)
    wrong = sum(o.answered and o.error_px is not None and o.error_px > WRONG_PX for o in scored)
    return f"{good}/{len(scored)} within {GOOD_PX:g} px, {wrong} answered over {WRONG_PX:g} px"


def _homogr_names(outcomes: list[tuple[Case, Outcome]]) -> set[str]:
    return {c.name for c, _ in outcomes if c.name not in ("box", "box crop", "graf1->graf3")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="default", help="signpose preset (default: default)")
    args = parser.parse_args()
    shared = shared_folder()
    if not (shared / "data" / "homogr").is_dir():
        sys.exit(f"no real pairs at {shared / 'data' / 'homogr'}: set SIGNPOSE_SHARED to the shared folder")
    ours, theirs = [], []
    print(f"{'case':<14} {'signpose err':>9} {'inl':>5}   {'opencv err':>9} {'inl':>5}   signpose's reason or note")
    for case in cases(shared):
        mine, cv = run_signpose(case, args.preset), run_opencv(case)
        ours.append((case, mine))
        theirs.append((case, cv))
        print(f"{case.name:<14} {_cell(mine)}   {_cell(cv)}   {mine.reason or ''}", flush=True)
    print(f"\nreal pairs, signpose {args.preset}: {_tally(ours)}")
    print(f"real pairs, plain OpenCV:       {_tally(theirs)}")
    print(f"median time per scene: signpose {np.median([o.ms for _, o in ours]):.0f} ms, "
          f"OpenCV {np.median([o.ms for _, o in theirs]):.0f} ms")


if __name__ == "__main__":
    main()
