"""A tracked flight scored against its ground truth (`signpose sweep` over flight folders).

A flight folder, as `pipeline.synth_flight.write_flight` writes it, holds the video, its camera.yaml
and a truth.json with every frame's signs: {"video": "flight.mp4", "frames": [{"frame", "signs":
[{"label", "R", "t" (X_cam = R·X_sign + t, metres), "in_view", "width_px"}]}]}.

The figures are those of `bench/track.py`: recall, the share of (frame, sign) pairs with the sign fully in
view and at least MIN_WIDTH_PX wide that are answered with its label; wrong labels, answers naming a sign
not in front of the camera on that frame; and the error of the camera's position in the sign frame
(|C_est - C_true|, C = -Rᵀt, of the measured, unfiltered pose) for signs within MAX_DISTANCE_M.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .evaluate import DatasetError
from .jsonfile import read_json

MIN_WIDTH_PX = 45.0  # narrower than this on a frame: a sign is not due there
MAX_DISTANCE_M = 3.0  # the position error is measured for signs this near


@dataclass(frozen=True, eq=False)
class FlightTruth:
    """A flight folder: its `video` and `camera` (camera.yaml, None without one) paths and, per frame index,
    the signs in front of the camera (truth.json's "signs" of that frame)."""

    root: Path
    video: Path
    camera: Path | None
    signs: dict[int, list[dict]]


def load_flight_truth(root: str | Path) -> FlightTruth | None:
    """The flight in folder `root`, None when `root` is no flight folder (no truth.json, or one of photos).
    DatasetError for a flight truth that cannot be used."""
    root = Path(root)
    truth_path = root / "truth.json"
    if not truth_path.is_file():
        return None
    truth = read_json(truth_path, DatasetError)
    if not isinstance(truth, dict) or "frames" not in truth:
        return None
    frames, video = truth["frames"], truth.get("video")
    if not isinstance(video, str) or not (root / video).is_file() or not isinstance(frames, list):
        raise DatasetError(f'{truth_path} must name its video, a file beside it ("video": "flight.mp4"), and list '
                           'its frames ("frames": [{"frame": 0, "signs": [...]}, ...])')
    try:
        signs = {int(f["frame"]): list(f["signs"]) for f in frames}
    except (TypeError, KeyError, ValueError):
        raise DatasetError(f'{truth_path}: every frame needs its "frame" index and its "signs"') from None
    camera = root / "camera.yaml"
    return FlightTruth(root, root / video, camera if camera.is_file() else None, signs)


@dataclass
class FlightScore:
    """What a tracked flight answered against its truth: `frames` tracked, `due` (frame, sign) pairs that
    should be answered and `answered` of them, `wrong` labels, and `position_errors_m` of signs within
    MAX_DISTANCE_M."""

    frames: int = 0
    due: int = 0
    answered: int = 0
    wrong: int = 0
    position_errors_m: list[float] = field(default_factory=list)

    def to_json(self) -> dict:
        """Recall in percent (None with nothing due) and the position error's median and 90th percentile in cm
        (None without any)."""
        def percentile_cm(q: float) -> float | None:
            errors = self.position_errors_m
            return round(float(np.percentile(errors, q)) * 100, 2) if errors else None

        return {"frames": self.frames, "sign_frames_due": self.due,
                "recall_pct": round(100 * self.answered / self.due, 1) if self.due else None,
                "wrong_labels": self.wrong, "position_error_cm_p50": percentile_cm(50),
                "position_error_cm_p90": percentile_cm(90)}


def score_flight(truth: FlightTruth, records: list[dict]) -> FlightScore:
    """Score the `signpose track --json` lines `records` of the flight against `truth`."""
    score = FlightScore()
    for record in records:
        score.frames += 1
        present = {s["label"]: s for s in truth.signs.get(record["frame"], [])}
        labels = {s["label"] for s in record["signs"]}
        for sign in present.values():
            if sign["in_view"] and sign["width_px"] >= MIN_WIDTH_PX:
                score.due += 1
                score.answered += sign["label"] in labels
        for answer in record["signs"]:
            sign = present.get(answer["label"])
            if sign is None:
                score.wrong += 1
                continue
            pose = answer["pose"]
            R, t = np.array(sign["R"]), np.array(sign["t"])
            if pose is None or None in pose["camera_position"] or np.linalg.norm(t) > MAX_DISTANCE_M:
                continue
            score.position_errors_m.append(float(np.linalg.norm(np.array(pose["camera_position"]) + R.T @ t)))
    return score
