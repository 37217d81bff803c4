"""Every sign in one image: the two signs of the sample flight's first frame are both found."""

from pathlib import Path

import cv2
import numpy as np

from signpose.pipeline.camera import load_camera
from signpose.pipeline.every_sign import recognize_every_sign
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset

SAMPLE_FLIGHT = Path(__file__).resolve().parents[1] / "sample_images" / "flights" / "corridor"


def first_frame() -> np.ndarray:
    capture = cv2.VideoCapture(str(SAMPLE_FLIGHT / "flight.mp4"))
    ok, frame = capture.read()
    capture.release()
    assert ok
    return frame


def test_both_signs_in_view_are_found_and_the_first_answer_is_recognizes(library):
    frame, settings = first_frame(), preset("default")
    camera = load_camera(SAMPLE_FLIGHT / "camera.yaml")
    recognitions = recognize_every_sign(frame, library, settings, camera)
    assert sorted(r.label for r in recognitions[:-1]) == ["chief_of_security", "security_compound"]
    assert recognitions[-1].label is None
    assert recognitions[0].label == recognize(frame, library, settings, camera).label
    # the signs' quads are apart: the second search did not find the first sign again
    (a, b) = (r.corners.mean(axis=0) for r in recognitions[:2])
    assert np.linalg.norm(a - b) > 100


def test_a_known_quad_is_masked_and_most_bounds_the_searches(library):
    frame, settings = first_frame(), preset("default")
    first = recognize(frame, library, settings)
    rest = recognize_every_sign(frame, library, settings, known=[first.corners], most=1)
    assert len(rest) == 1 and rest[0].label not in (None, first.label)
