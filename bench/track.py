"""Tracking benchmark: `Tracker` side by side with `recognize` on every frame of a synthetic flight.

Both read the same video (pipeline.synth_flight's corridor: far from the wall in to the first sign
until it fills the frame, past a white look-alike plaque, to the second and away) in one run, on
one OpenCV thread, decode included: each frame is decoded once and given to one method, then the
other, so a machine shared with other work slows both alike. Each method has a library of its own
(the library's features are computed on first use and kept: neither warms them for the other).
Per method: frames a second, by the clock and by the CPU time of the thread (less sensitive to
the machine's load), and by CPU time without the first frame (where each computes the library's
features, once a run); recall, the share of (frame, sign)
pairs with the sign at least MIN_WIDTH_PX wide and fully in view that are answered with its
label, and per run of such frames of one sign the frames from its first to its first answer (None:
not answered in it); wrong labels (a label for a sign not in front of the camera); camera position error
p50 / p90 for signs within MAX_DISTANCE_M, raw and filtered; and the frame-to-frame jitter of the camera position
beyond the true motion (median, p90), raw and, for the tracker, filtered, over every frame and
for signs within MAX_DISTANCE_M; and the normalised estimation error squared (NEES) of the raw and
filtered poses against the truth under their own covariances, over [rotation vector, t] (6 dof: an
honest covariance gives a median of 5.35 and a p90 of 10.6, chi-squared), within and beyond
MAX_DISTANCE_M.

    python bench/track.py [--flight DIR] [--duration 12] [--lens=K1,K2] [--settings FILE] [--json OUT]

With --lens (written --lens=-0.25,0.08, as its value may start with a minus) the frames are seen
through a lens of radial distortion k1, k2 and both methods are given that camera: the flight is
rendered by a pinhole wider than the frame by the most the lens reaches beyond it (a barrel lens
shows at its frame's edges what lies outside the pinhole's), and each frame remapped through the
lens outside both methods' time; a sign is in view where its corners, so distorted, are in the frame.

Without --flight the 12 s corridor flight is rendered into the temp folder (once; re-used until the
renderer's `RENDERING` changes).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from signpose.pipeline.camera import Camera, load_camera
from signpose.pipeline.flight_truth import MAX_DISTANCE_M, MIN_WIDTH_PX
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.pose import Pose, distort_pixels, undistort_pixels
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import Settings, load_settings
from signpose.pipeline.synth import synthetic_camera
from signpose.pipeline.synth_flight import RENDERING, write_flight
from signpose.pipeline.track import Tracker
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for tests.support
from tests.support.scene_images import lens_maps  # noqa: E402


@dataclass
class Tally:
    """What one method answered over the flight."""

    name: str
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    first_cpu_seconds: float = 0.0  # the first frame's: the library's features are computed on first use
    frames: int = 0
    due: int = 0  # (frame, sign) pairs that should be answered
    answered: int = 0
    wrong: list[tuple[int, str]] = field(default_factory=list)
    errors_m: dict[str, list[float]] = field(default_factory=dict)  # "raw" / "filtered": position errors
    # per kind and "near" / "far" (within / beyond MAX_DISTANCE_M): each pose's NEES against the truth
    nees: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    # per label and kind ("raw", "filtered"): (frame, measured position, true position, distance m)
    tracks: dict[str, dict[str, list[tuple[int, np.ndarray, np.ndarray, float]]]] = field(default_factory=dict)
    # per label: [first frame of its current run of frames due, frames until first answered in it or None]
    runs: dict[str, list] = field(default_factory=dict)
    latencies: list[int | None] = field(default_factory=list)  # per run of frames due, in order of its end

    def add(self, index: int, truth: dict, answers: list[tuple[str, Pose | None, Pose | None]]) -> None:
        present = {s["label"]: s for s in truth["signs"]}
        labels = {label for label, _, _ in answers}
        for label, sign in present.items():
            run = self.runs.get(label)
            if sign["in_view"] and sign["width_px"] >= MIN_WIDTH_PX:
                self.due += 1
                self.answered += label in labels
                if run is None:
                    run = self.runs[label] = [index, None]
                if label in labels and run[1] is None:
                    run[1] = index - run[0]
            elif run is not None:
                self.latencies.append(self.runs.pop(label)[1])
        for label, pose, filtered in answers:
            if label not in present:
                self.wrong.append((index, label))
                continue
            sign = present[label]
            R, t = np.array(sign["R"]), np.array(sign["t"])
            true_position = -R.T @ t
            for kind, measured in (("raw", pose), ("filtered", filtered)):
                if measured is None:
                    continue
                position = measured.camera_position
                self.tracks.setdefault(label, {}).setdefault(kind, []).append(
                    (index, position, true_position, float(np.linalg.norm(t))))
                near = np.linalg.norm(t) <= MAX_DISTANCE_M
                if measured.covariance is not None:
                    self.nees.setdefault(kind, {}).setdefault("near" if near else "far", []).append(
                        nees(measured, R, t))
                if near:
                    self.errors_m.setdefault(kind, []).append(float(np.linalg.norm(position - true_position)))

    def jitter_mm(self, kind: str, max_distance_m: float = np.inf) -> list[float]:
        """|measured step - true step| between consecutive frames answering the same sign, mm
        (of signs within `max_distance_m` on the second frame)."""
        out = []
        for per_kind in self.tracks.values():
            seen = per_kind.get(kind, [])
            for (i0, p0, g0, _), (i1, p1, g1, distance) in zip(seen, seen[1:]):
                if i1 == i0 + 1 and distance <= max_distance_m:
                    out.append(float(np.linalg.norm((p1 - p0) - (g1 - g0))) * 1e3)
        return out

    def summary(self) -> dict:
        latencies = self.latencies + [run[1] for run in self.runs.values()]

        def pct(values: list[float], q: float) -> float | None:
            return round(float(np.percentile(values, q)), 2) if values else None

        errors_cm = [e * 100 for e in self.errors_m.get("raw", [])]
        filtered_cm = [e * 100 for e in self.errors_m.get("filtered", [])]
        return {
            "method": self.name, "frames": self.frames, "fps": round(self.frames / self.seconds, 1),
            "cpu_fps": round(self.frames / self.cpu_seconds, 1),
            "first_frame_cpu_ms": round(self.first_cpu_seconds * 1e3, 1),
            "cpu_fps_after_the_first_frame": round((self.frames - 1) / (self.cpu_seconds - self.first_cpu_seconds), 1),
            "recall_pct": round(100 * self.answered / self.due, 1) if self.due else None,
            "sign_frames_due": self.due, "wrong_labels": len(self.wrong),
            "frames_to_first_answer": latencies,
            "position_error_cm_p50": pct(errors_cm, 50), "position_error_cm_p90": pct(errors_cm, 90),
            "filtered_position_error_cm_p50": pct(filtered_cm, 50),
            "filtered_position_error_cm_p90": pct(filtered_cm, 90),
            "jitter_mm_median": pct(self.jitter_mm("raw"), 50), "jitter_mm_p90": pct(self.jitter_mm("raw"), 90),
            "filtered_jitter_mm_median": pct(self.jitter_mm("filtered"), 50),
            "filtered_jitter_mm_p90": pct(self.jitter_mm("filtered"), 90),
            "within_3m_jitter_mm_median": pct(self.jitter_mm("raw", MAX_DISTANCE_M), 50),
            "within_3m_jitter_mm_p90": pct(self.jitter_mm("raw", MAX_DISTANCE_M), 90),
            "within_3m_filtered_jitter_mm_median": pct(self.jitter_mm("filtered", MAX_DISTANCE_M), 50),
            "within_3m_filtered_jitter_mm_p90": pct(self.jitter_mm("filtered", MAX_DISTANCE_M), 90),
            **{f"{kind}_nees_{where}_p{q}": pct(self.nees.get(kind, {}).get(where, []), q)
               for kind in ("raw", "filtered") for where in ("near", "far") for q in (50, 90)},
        }


def nees(pose: Pose, R: np.ndarray, t: np.ndarray) -> float:
    """The normalised estimation error squared of `pose` against the true R (3, 3), t (3,) m: its error
    over [rotation vector, t] under its own (6, 6) covariance."""
    error = np.concatenate([cv2.Rodrigues(np.asarray(pose.R, dtype=np.float64))[0].ravel() - cv2.Rodrigues(R)[0].ravel(),
                            np.ravel(pose.t) - t])
    return float(error @ np.linalg.solve(pose.covariance, error))


Answer = Callable[[np.ndarray, int, float], list[tuple[str, Pose | None, Pose | None]]]


def clocks() -> tuple[float, float]:
    """(wall clock, this thread's CPU time), s."""
    return time.perf_counter(), time.thread_time()


def lens_margin(lens: Camera) -> int:
    """How far (px, whole) beyond `lens`'s frame the ideal pinhole's px its frame shows reach."""
    w, h = lens.width, lens.height
    edge = np.concatenate([np.column_stack([np.arange(w), np.zeros(w)]), np.column_stack([np.arange(w), np.full(w, h - 1)]),
                           np.column_stack([np.zeros(h), np.arange(h)]), np.column_stack([np.full(h, w - 1), np.arange(h)])])
    ideal = undistort_pixels(edge.astype(np.float64), lens)
    return int(np.ceil(max(0.0, -ideal.min(), (ideal - [w - 1, h - 1]).max()))) + 2  # + bilinear's reach


def widened(camera: Camera, margin: int) -> Camera:
    """`camera` (distortion-free) with `margin` px more on every side of its frame."""
    if not margin:
        return camera
    K = camera.K.copy()
    K[:2, 2] += margin
    return Camera(K, np.zeros(5), camera.width + 2 * margin, camera.height + 2 * margin, f"{camera.source}, widened")


def through_lens(lens: Camera, margin: int) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[dict], dict]]:
    """(frame -> the frame as `lens` shows it, frame truth -> the same with each sign in view where
    its corners, distorted, are in the frame), for frames rendered by `widened(lens, margin)`'s pinhole."""
    map_x, map_y = lens_maps(lens, widened(lens, margin).K, (lens.width, lens.height))

    def frame(image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)

    def truth(frame_truth: dict) -> dict:
        def seen(sign: dict) -> dict:
            corners = distort_pixels(np.array(sign["corners"]) - margin, lens)
            in_view = bool(np.all((corners >= 0) & (corners <= [lens.width - 1, lens.height - 1])))
            return {**sign, "corners": corners.tolist(), "in_view": in_view}
        return {**frame_truth, "signs": [seen(sign) for sign in frame_truth["signs"]]}

    return frame, truth


def measure(video: Path, truth: dict, methods: dict[str, Answer], lens: Camera | None = None,
            margin: int = 0) -> list[Tally]:
    """Decode each frame of `video` once and run each of `methods` on it in turn; each method's time
    is the frame's decode and its own answer (scoring is no method's time). With `lens`, each frame
    is first seen through it (`through_lens` of frames `margin` px wider, no method's time either)."""
    tallies = {name: Tally(name) for name in methods}
    fps = truth["fps"]
    seen, seen_truth = (through_lens(lens, margin) if lens is not None
                        else (lambda image: image, lambda frame_truth: frame_truth))
    capture = cv2.VideoCapture(str(video))
    try:
        for index in itertools.count():
            wall, cpu = clocks()
            ok, frame = capture.read()
            decode_wall, decode_cpu = (b - a for a, b in zip((wall, cpu), clocks()))
            if not ok:
                break
            frame = seen(frame)
            for name, answer in methods.items():
                wall, cpu = clocks()
                answers = answer(frame, index, index / fps)
                end_wall, end_cpu = clocks()
                tally = tallies[name]
                tally.seconds += decode_wall + end_wall - wall
                tally.cpu_seconds += decode_cpu + end_cpu - cpu
                if index == 0:
                    tally.first_cpu_seconds = tally.cpu_seconds
                tally.add(index, seen_truth(truth["frames"][index]), answers)
                tally.frames += 1
    finally:
        capture.release()
    return list(tallies.values())


def tracker_answers(library: Library, settings: Settings, camera: Camera, fps: float):
    tracker = Tracker(library, settings, camera, fps=fps)

    def answer(frame: np.ndarray, index: int, time_s: float):
        result = tracker.step(frame, index=index, time_s=time_s)
        return [(s.label, s.pose, s.filtered_pose) for s in result.signs]

    return answer


def recognize_answers(library: Library, settings: Settings, camera: Camera):
    def answer(frame: np.ndarray, index: int, time_s: float):
        rec = recognize(frame, library, settings, camera)
        return [(rec.label, rec.pose, None)] if rec.label is not None else []

    return answer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flight", type=Path, help="a folder with flight.mp4, truth.json, camera.yaml")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds of the rendered flight")
    parser.add_argument("--lens", help="K1,K2: the flight seen through a lens of this radial distortion")
    parser.add_argument("--settings", type=Path, help="settings JSON for both methods (default: the default preset)")
    parser.add_argument("--json", type=Path, help="write the figures here as JSON")
    args = parser.parse_args()
    settings = load_settings(args.settings) if args.settings else Settings()
    cv2.setNumThreads(1)
    library = load_library()
    pinhole = synthetic_camera()
    lens, margin = None, 0
    if args.lens:
        if args.flight:
            parser.error("--lens renders a flight of its own, wider than the frame it is seen in: give no --flight")
        k1, k2 = (float(k) for k in args.lens.split(","))
        lens = Camera(pinhole.K, np.array([k1, k2, 0.0, 0.0, 0.0]), pinhole.width, pinhole.height, f"--lens {args.lens}")
        margin = lens_margin(lens)
    flight = args.flight or Path(tempfile.gettempdir()) / (f"signpose-flight-{args.duration:g}s-r{RENDERING}"
                                                          + (f"-wider{margin}" if margin else ""))
    if not (flight / "truth.json").exists():
        print(f"rendering the {args.duration:g} s corridor flight into {flight}")
        t0 = time.perf_counter()
        write_flight(flight, library, widened(pinhole, margin), duration_s=args.duration)
        print(f"  rendered in {time.perf_counter() - t0:.1f} s")
    truth = json.loads((flight / "truth.json").read_text())
    camera = lens or load_camera(flight / "camera.yaml")
    video = flight / truth["video"]
    methods = {"tracker": tracker_answers(load_library(), settings, camera, truth["fps"]),
               "recognize": recognize_answers(load_library(), settings, camera)}
    results = [tally.summary() for tally in measure(video, truth, methods, lens, margin)]
    results[0]["speedup"] = round(results[0]["fps"] / results[1]["fps"], 2)
    results[0]["cpu_speedup"] = round(results[0]["cpu_fps"] / results[1]["cpu_fps"], 2)
    results[0]["cpu_speedup_after_the_first_frame"] = round(
        results[0]["cpu_fps_after_the_first_frame"] / results[1]["cpu_fps_after_the_first_frame"], 2)
    results[0]["load_average"] = [round(v, 2) for v in os.getloadavg()]
    for result in results:
        print(json.dumps(result))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
