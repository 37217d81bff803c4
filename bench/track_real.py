"""Real footage: a landmark cut from one frame of `box.mp4`, tracked through the whole video.

The landmark is the box's large top face in frame LANDMARK_FRAME, rectified to a fronto-parallel
image through its four corners (CORNERS_PX, found by fitting lines to the face's edges in that frame
and intersecting them; the back-left corner lies under the holding hand and is where the back and
left edges meet). Its size: FACE_WIDTH_M x FACE_HEIGHT_M, the mean of the proportions (1.08, 1.03)
at which the face's edges meet at right angles in frames 152 and 304 (square pixels, focal length
690 and 743 px), at which the rectified face's frame is square and its corner ornaments round; the
box's true size is not known. The README's intrinsics, far from square-pixel ones, are used for the
pose all the same, as a user would. The one-picture library is written to a temporary
folder and loaded as `signpose track --library` loads one.

Over every frame, in one run on one OpenCV thread: the `Tracker`, and separately a fresh
`recognize`. A frame's face is fully visible when the fresh detection answers the landmark with its
four corners inside the frame; on those frames the bench reports the share on which the tracker
reports the landmark, and the distance (px) between the tracker's corners and the fresh detection's
(the largest of the four per frame): median, p90, max. Frames the fresh detection does not answer
cannot be judged and are counted apart.

    python bench/track_real.py [--frames N] [--json OUT]

The video is read where it lies (`shared` beside the checkout, or SIGNPOSE_SHARED), never copied.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from signpose.pipeline.camera import Camera
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import Settings
from signpose.pipeline.track import Tracker
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for tests.support
from tests.support.shared_data import shared_folder  # noqa: E402

LANDMARK_ID = "box_top"
LANDMARK_FRAME = 304
# The top face's corners in frame LANDMARK_FRAME, image px: TL, TR (the back edge, the picture's
# top), BR, BL (the front edge, under the word CAMPRODON).
CORNERS_PX = ((262.94, 106.32), (472.29, 171.93), (389.27, 295.38), (130.48, 197.46))
FACE_WIDTH_M, FACE_HEIGHT_M = 0.26, 0.245
LANDMARK_WIDTH_PX = 400
# The README's approximate intrinsics of the webcam, for 640x480 frames.
FX, FY, CX, CY = 1578.5, 1771.8, 320.0, 240.0
TARGET_TRACKED = 0.95
TARGET_CORNER_PX = 3.0


def video_path(shared: Path) -> Path:
    return shared / "data" / "video" / "box.mp4"


def read_frames(video: Path, limit: int | None = None) -> Iterator[np.ndarray]:
    """The video's frames, (480, 640, 3) uint8 BGR, in order; at most `limit`."""
    capture = cv2.VideoCapture(str(video))
    try:
        count = 0
        while limit is None or count < limit:
            ok, frame = capture.read()
            if not ok:
                return
            yield frame
            count += 1
    finally:
        capture.release()


def video_fps(video: Path) -> float:
    capture = cv2.VideoCapture(str(video))
    try:
        return float(capture.get(cv2.CAP_PROP_FPS)) or 30.0
    finally:
        capture.release()


def box_camera() -> Camera:
    K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
    return Camera(K, width=640, height=480, source="box.mp4 README")


def landmark_image(frame: np.ndarray) -> np.ndarray:
    """The top face of (H, W, 3) BGR `frame` rectified through CORNERS_PX, its aspect the face's."""
    width = LANDMARK_WIDTH_PX
    height = round(width * FACE_HEIGHT_M / FACE_WIDTH_M)
    target = np.float32([[0, 0], [width, 0], [width, height], [0, height]])
    H = cv2.getPerspectiveTransform(np.float32(CORNERS_PX), target)
    return cv2.warpPerspective(frame, H, (width, height), flags=cv2.INTER_CUBIC)


def landmark_library(video: Path, root: Path) -> Library:
    """The one-picture library of the box's top face, written to folder `root` and loaded from it."""
    frame = next((f for i, f in enumerate(read_frames(video, LANDMARK_FRAME + 1)) if i == LANDMARK_FRAME), None)
    if frame is None:
        raise ValueError(f"{video}: no frame {LANDMARK_FRAME}")
    cv2.imwrite(str(root / f"{LANDMARK_ID}.png"), landmark_image(frame))
    entry = {"id": LANDMARK_ID, "name": "Box top", "text": "", "image": f"{LANDMARK_ID}.png",
             "width_m": FACE_WIDTH_M, "height_m": FACE_HEIGHT_M, "kind": "picture"}
    (root / "library.json").write_text(json.dumps({"signs": [entry]}), encoding="utf-8")
    return load_library(root)


def inside(corners: np.ndarray, width: int, height: int) -> bool:
    """Whether all of (4, 2) image px `corners` lie within the width x height frame."""
    return bool(np.all((corners >= 0) & (corners <= [width, height])))


def corner_distance(a: np.ndarray | None, b: np.ndarray | None) -> float:
    """The largest of the four distances (px) between (4, 2) corners `a` and `b`."""
    assert a is not None and b is not None
    return float(np.linalg.norm(a - b, axis=1).max())


@dataclass
class RealTally:
    """Per frame: the fresh detection's corners (None: no answer) and the tracker's (None: not reported)."""

    fresh: list[np.ndarray | None] = field(default_factory=list)
    tracked: list[np.ndarray | None] = field(default_factory=list)
    states: list[str | None] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=lambda: {"tracker": 0.0, "recognize": 0.0})

    def summary(self, width: int = 640, height: int = 480) -> dict:
        visible = [i for i, c in enumerate(self.fresh) if c is not None and inside(c, width, height)]
        on_visible = [i for i in visible if self.tracked[i] is not None]
        frames = len(self.fresh)

        def spread(indices: list[int]) -> dict[str, float | None]:
            distances = [corner_distance(self.tracked[i], self.fresh[i]) for i in indices]
            if not distances:
                return {"median": None, "p90": None, "max": None}
            return {"median": round(float(np.median(distances)), 2),
                    "p90": round(float(np.percentile(distances, 90)), 2), "max": round(max(distances), 2)}

        return {
            "frames": frames,
            "fresh_answered": sum(c is not None for c in self.fresh),
            "fully_visible": len(visible),
            "tracked_on_visible": len(on_visible),
            "tracked_share": round(len(on_visible) / len(visible), 4) if visible else None,
            "tracked_any": sum(c is not None for c in self.tracked),
            "tracked_state": sum(s == "tracked" for s in self.states),
            "unjudged_tracked": sum(self.fresh[i] is None and self.tracked[i] is not None for i in range(frames)),
            "corner_px": spread(on_visible),
            # the frames the tracker answered from its points alone: on the others it reports the detector's own answer
            "corner_px_tracked_state": spread([i for i in on_visible if self.states[i] == "tracked"]),
            "fps": {k: round(frames / s, 1) if s > 0 else None for k, s in self.seconds.items()},
        }


def run(video: Path, library: Library, *, limit: int | None = None, fresh: bool = True) -> RealTally:
    """The tracker over the first `limit` frames (all: None) and, when `fresh`, `recognize` on each."""
    settings, camera = Settings(), box_camera()
    fps = video_fps(video)
    tracker = Tracker(library, settings, camera, fps=fps)
    tally = RealTally()
    for index, frame in enumerate(read_frames(video, limit)):
        start = time.perf_counter()
        result = tracker.step(frame, index=index, time_s=index / fps)
        tally.seconds["tracker"] += time.perf_counter() - start
        sign = next((s for s in result.signs if s.label == LANDMARK_ID), None)
        tally.tracked.append(None if sign is None else np.asarray(sign.corners, float))
        tally.states.append(None if sign is None else sign.state)
        if fresh:
            start = time.perf_counter()
            rec = recognize(frame, library, settings, camera)
            tally.seconds["recognize"] += time.perf_counter() - start
            tally.fresh.append(np.asarray(rec.corners, float) if rec.label == LANDMARK_ID and rec.corners is not None
                               else None)
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames")
    parser.add_argument("--json", type=Path, default=None, help="write the summary here too")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    video = video_path(shared_folder())
    if not video.is_file():
        raise SystemExit(f"{video}: not found; set SIGNPOSE_SHARED to the shared data folder")
    with tempfile.TemporaryDirectory() as folder:
        library = landmark_library(video, Path(folder))
        summary = run(video, library, limit=args.frames).summary()
    summary["targets"] = {"tracked_share": TARGET_TRACKED, "corner_px": TARGET_CORNER_PX,
                          "met": bool((summary["tracked_share"] or 0) >= TARGET_TRACKED
                                      and (summary["corner_px"]["p90"] or np.inf) <= TARGET_CORNER_PX)}
    print(json.dumps(summary, indent=2))
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
