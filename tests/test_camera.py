import json

import numpy as np
import pytest

from pipeline.camera import Camera, CameraError, assumed_camera, load_camera, save_camera

ROS = """image_width: 640
image_height: 480
camera_name: cam
camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 510, 240, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0, 0, 0]}
"""


def test_ros_yaml(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(ROS)
    cam = load_camera(p)
    assert cam.K[0, 0] == 500 and cam.K[1, 1] == 510 and (cam.width, cam.height) == (640, 480)
    assert cam.dist[0] == -0.1 and cam.has_distortion


def test_save_round_trip(tmp_path):
    cam = Camera(np.array([[600.0, 0, 330], [0, 601, 250], [0, 0, 1]]), np.array([0.1, -0.2, 0.001, 0.002, 0.05]),
                 640, 480, "test")
    save_camera(cam, tmp_path / "c.yaml")
    back = load_camera(tmp_path / "c.yaml")
    assert np.allclose(back.K, cam.K) and np.allclose(back.dist, cam.dist)


def test_plain_json_and_opencv_filestorage(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"fx": 400, "fy": 400, "cx": 320, "cy": 240, "dist": [0, 0, 0, 0]}))
    assert load_camera(p).K[0, 2] == 320
    import cv2

    fs_path = tmp_path / "cv.yaml"
    fs = cv2.FileStorage(str(fs_path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[700.0, 0, 300], [0, 700, 200], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    assert load_camera(fs_path).K[0, 0] == 700


@pytest.mark.parametrize("text, message", [
    ('{"fx": 0, "fy": 400, "cx": 320, "cy": 240}', "positive"),
    ('{"fx": -5, "fy": 400, "cx": 320, "cy": 240}', "positive"),
    ('{"fx": 400, "fy": 400}', "missing"),
    ('camera_matrix: {rows: 2, cols: 2, data: [1, 0, 0, 1]}', "9 values"),
    ('camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 1]}', "declares 3x3"),
    ('{"fx": 400, "fy": 400, "cx": 320, "cy": 240, "dist": [1, 2, 3]}', "coefficients"),
    ('just text', "expected a mapping"),
    ('{"fx": "a", "fy": 400, "cx": 320, "cy": 240}', "numbers"),
])
def test_malformed_camera_files_are_clear_errors(tmp_path, text, message):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(CameraError, match=message):
        load_camera(p)


def test_missing_file_and_scaling():
    with pytest.raises(CameraError, match="not found"):
        load_camera("/nonexistent/cam.yaml")
    cam = assumed_camera(640, 480)
    assert cam.is_assumed and abs(cam.K[0, 0] - 554.256) < 1e-3
    scaled, warnings = cam.for_image(1280, 960)
    assert scaled.K[0, 0] == pytest.approx(2 * cam.K[0, 0]) and warnings
