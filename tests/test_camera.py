import codecs
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from signpose.pipeline.camera import Camera, CameraError, assumed_camera, camera_from_json, load_camera, save_camera
from signpose.pipeline.image import read_image
from signpose.pipeline.pose import camera_position
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset
from signpose.pipeline.synth import render_scene, synthetic_camera

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


# The end of a CameraInfo message as `ros2 topic echo` and ROS 1's `rostopic echo` print it.
MESSAGE_END = """binning_x: 0
binning_y: 0
roi:
  x_offset: 0
  y_offset: 0
  height: 0
  width: 0
  do_rectify: false
---
"""
# `ros2 topic echo --once /camera_info > cam.yaml`: the same camera as ROS above, as a message.
ROS2_MESSAGE = """header:
  stamp:
    sec: 1718000000
    nanosec: 250000000
  frame_id: camera_optical_frame
height: 480
width: 640
distortion_model: plumb_bob
d:
- -0.1
- 0.01
- 0.0
- 0.0
- 0.0
k:
- 500.0
- 0.0
- 320.0
- 0.0
- 510.0
- 240.0
- 0.0
- 0.0
- 1.0
r:
- 1.0
- 0.0
- 0.0
- 0.0
- 1.0
- 0.0
- 0.0
- 0.0
- 1.0
p:
- 500.0
- 0.0
- 320.0
- 0.0
- 0.0
- 510.0
- 240.0
- 0.0
- 0.0
- 0.0
- 1.0
- 0.0
""" + MESSAGE_END
# ROS 1's `rostopic echo -n 1 /camera_info`: the same fields in capitals, flow lists.
ROS1_MESSAGE = """header:
  seq: 42
  stamp:
    secs: 1718000000
    nsecs: 250000000
  frame_id: "camera"
height: 480
width: 640
distortion_model: "plumb_bob"
D: [-0.1, 0.01, 0.0, 0.0, 0.0]
K: [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0]
R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
P: [500.0, 0.0, 320.0, 0.0, 0.0, 510.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]
""" + MESSAGE_END


@pytest.mark.parametrize("text", [ROS2_MESSAGE, ROS1_MESSAGE, ROS2_MESSAGE + ROS2_MESSAGE.replace("500.0", "501.0")],
                         ids=["ros2", "ros1", "several messages"])
def test_a_camera_info_message_as_ros_topic_echo_prints_it(tmp_path, text):
    (tmp_path / "file.yaml").write_text(ROS)
    (tmp_path / "message.yaml").write_text(text)
    file, message = load_camera(tmp_path / "file.yaml"), load_camera(tmp_path / "message.yaml")
    assert np.array_equal(message.K, file.K) and np.array_equal(message.dist, file.dist)  # the first message
    assert (message.width, message.height) == (640, 480)


def k_list(values: list[object]) -> str:
    return "k:\n" + "".join(f"- {v}\n" for v in values)


K_VALUES = [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("replace, by, message", [
    (k_list(K_VALUES), k_list(K_VALUES[:4]), "k must have 9 values (the 3x3 matrix, row by row); got 4"),
    (k_list(K_VALUES), k_list(["abc", *K_VALUES[1:]]), "k must be a number; got 'abc'"),
    (k_list(K_VALUES), k_list([0.0] * 9), "k is all zeros: this camera_info is of an uncalibrated camera"),
    ("- 0.01\n", "- x\n", "d must be a number; got 'x'"),
    ("width: 640\n", "width: wide\n", "width must be a whole number; got 'wide'"),
    ("height: 480\n", "height: 480.5\n", "height must be a whole number; got 480.5"),
    ("plumb_bob", "equidistant", "distortion_model 'equidistant' is not supported"),
    ("k:\n", "kk:\n", "expected camera_matrix (ROS camera_info file), k (ROS 2 camera_info message"),
], ids=["k size", "k text", "k zeros", "d text", "width text", "height fraction", "fisheye", "no k"])
def test_a_bad_camera_info_message_is_one_line_naming_the_key(tmp_path, replace, by, message):
    assert replace in ROS2_MESSAGE
    p = tmp_path / "cam.yaml"
    p.write_text(ROS2_MESSAGE.replace(replace, by, 1))
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {message}")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("model", ["equidistant", "fisheye", "kannala_brandt", 7])
def test_a_distortion_model_other_than_opencvs_is_refused(tmp_path, model):
    """Fisheye coefficients read as OpenCV's would move the pose without a word."""
    p = tmp_path / "cam.yaml"
    p.write_text(ROS.replace("plumb_bob", str(model)))
    with pytest.raises(CameraError, match=r"distortion_model .* is not supported: signpose uses OpenCV's model"):
        load_camera(p)
    p.write_text(ROS.replace("plumb_bob", "rational_polynomial"))
    assert load_camera(p).has_distortion


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial", "radtan"])
def test_a_distortion_model_without_its_coefficients_is_refused(tmp_path, model):
    """A file whose coefficients were lost on the way was read as distortion-free: the pose moved 0.25 m at 1.7 m."""
    p = tmp_path / "cam.yaml"
    p.write_text(ROS.replace("plumb_bob", model).replace("distortion_coefficients: {rows: 1, cols: 5, data: "
                                                         "[-0.1, 0.01, 0, 0, 0]}\n", ""))
    with pytest.raises(CameraError, match=f"distortion_model {model} names a lens with distortion, but the file "
                                          "gives no coefficients"):
        load_camera(p)
    p.write_text(ROS.replace("plumb_bob", "none").replace("data: [-0.1, 0.01, 0, 0, 0]", "data: [0, 0, 0, 0, 0]"))
    assert not load_camera(p).has_distortion


@pytest.mark.parametrize("model, count, message", [
    ("plumb_bob", 8, "distortion_model plumb_bob has 5 coefficients (k1 k2 p1 p2 k3), but 8 are given (k1 k2 p1 p2 k3 "
                     "k4 k5 k6): set distortion_model to rational_polynomial, or give 5"),
    ("PLUMB_BOB", 14, "distortion_model PLUMB_BOB has 5 coefficients (k1 k2 p1 p2 k3), but 14 are given (k1 ... k6 s1 "
                      "... s4 tx ty, thin-prism and tilt terms), which ROS and Kalibr name no model for: leave "
                      "distortion_model out, or give 5"),
    ("radtan", 5, "distortion_model radtan has 4 coefficients (k1 k2 p1 p2), but 5 are given (k1 k2 p1 p2 k3): set "
                  "distortion_model to plumb_bob, or give 4"),
    ("rational_polynomial", 12, "distortion_model rational_polynomial has 8 coefficients"),
])
def test_more_coefficients_than_the_model_named_has_are_refused_naming_the_model_they_are(tmp_path, model, count,
                                                                                          message):
    """plumb_bob's 8 coefficients were taken as OpenCV's rational model: the file says two things."""
    d = ROS2_MESSAGE[ROS2_MESSAGE.index("d:\n"):ROS2_MESSAGE.index("k:\n")]
    text = ROS2_MESSAGE.replace(d, f"d: {[-0.1] + [0.0] * (count - 1)}\n").replace("plumb_bob", model)
    assert_one_line_error(tmp_path / "cam.yaml", text, message)
    for fewer, fine in (("plumb_bob", 4), ("rational_polynomial", 5), ("rational_polynomial", 8)):  # the rest 0
        (tmp_path / "fine.yaml").write_text(text.replace(model, fewer).replace(f"d: {[-0.1] + [0.0] * (count - 1)}",
                                                                               f"d: {[-0.1] + [0.0] * (fine - 1)}"))
        assert load_camera(tmp_path / "fine.yaml").dist.size == fine


def test_an_unset_distortion_model_without_coefficients_is_no_distortion(tmp_path):
    p = tmp_path / "cam.yaml"
    d = ROS2_MESSAGE[ROS2_MESSAGE.index("d:\n"):ROS2_MESSAGE.index("k:\n")]
    unset = ROS2_MESSAGE.replace(d, "d: []\n").replace("plumb_bob", "''")
    p.write_text(unset)
    camera = load_camera(p)
    assert camera.K[0, 0] == 500.0 and not camera.has_distortion
    p.write_text(unset.replace(k_list(K_VALUES), k_list([0.0] * 9)))  # a default CameraInfo: nobody calibrated it
    with pytest.raises(CameraError, match="k is all zeros: this camera_info is of an uncalibrated camera"):
        load_camera(p)
    p.write_text(ROS2_MESSAGE.replace("plumb_bob", "''"))  # coefficients of no named model: what do they mean?
    with pytest.raises(CameraError, match="distortion_model '' is not supported"):
        load_camera(p)


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial", "radtan"])
@pytest.mark.parametrize("empty", ["D: []", "distortion_coefficients: {rows: 1, cols: 0, data: []}"])
def test_a_distortion_model_with_an_empty_coefficient_list_is_refused(tmp_path, model, empty):
    """`D: []` under plumb_bob was read as no distortion, where the same file without D is refused."""
    key = empty.split(":")[0]
    text = ROS_MATRIX.format(rows=3, data=K_DATA) + f"distortion_model: {model}\n{empty}\n"
    assert_one_line_error(tmp_path / "cam.yaml", text, f"distortion_model {model} names a lens with distortion, but "
                                                       f"the file gives no coefficients ({key} is empty): add them")
    # No model, or one naming none, with an empty list: a lens without distortion, as without the list.
    for unnamed in ("", "distortion_model: none\n", "distortion_model: ''\n"):
        (tmp_path / "none.yaml").write_text(ROS_MATRIX.format(rows=3, data=K_DATA) + unnamed + empty + "\n")
        assert not load_camera(tmp_path / "none.yaml").has_distortion


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
    # as a Windows editor saves them, with a byte-order mark: OpenCV's own reading refused the FileStorage
    for path in (p, fs_path):
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert load_camera(p).K[0, 2] == 320 and load_camera(fs_path).K[0, 0] == 700


@pytest.mark.parametrize("text, message", [
    ('{"fx": 0, "fy": 400, "cx": 320, "cy": 240}', "positive"),
    ('{"fx": -5, "fy": 400, "cx": 320, "cy": 240}', "positive"),
    ('{"fx": 400, "fy": 400}', "missing"),
    ('camera_matrix: {rows: 2, cols: 2, data: [1, 0, 0, 1]}', "9 values"),
    ('camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 1]}', "declares 3x3"),
    ('{"fx": 400, "fy": 400, "cx": 320, "cy": 240, "dist": [1, 2, 3]}', "coefficients"),
    ('just text', "expected a mapping"),
    ('{"fx": "a", "fy": 400, "cx": 320, "cy": 240}', "fx must be a number"),
    ("", r"an empty file \(nothing in it to read\)"),
    ("\n  \n", r"an empty file \(nothing in it to read\)"),
])
def test_malformed_camera_files_are_clear_errors(tmp_path, text, message):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(CameraError, match=message):
        load_camera(p)


OPENCV_MATRIX = """%YAML:1.0
---
{fields}camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ {fx}, 0., 320., 0., 554., 240., 0., 0., 1. ]
"""
ROS_MATRIX = "camera_matrix: {{rows: {rows}, cols: 3, data: {data}}}\n"
K_DATA = "[554, 0, 320, 0, 554, 240, 0, 0, 1]"


@pytest.mark.parametrize("text, message", [
    (ROS_MATRIX.format(rows=3, data="[abc, 0, 320, 0, 554, 240, 0, 0, 1]"),
     "camera_matrix.data must be a number; got 'abc'"),
    (ROS_MATRIX.format(rows=3, data="[true, 0, 320, 0, 554, 240, 0, 0, 1]"),
     "camera_matrix.data must be a number; got true"),
    (ROS_MATRIX.format(rows=3, data="[[554, 0, 320], [0, 554], 240, 0, 0, 1]"), "camera_matrix.data must be a number"),
    (ROS_MATRIX.format(rows="three", data=K_DATA), "camera_matrix.rows must be a whole number; got 'three'"),
    ("camera_matrix: [[554, 0, 320], [0, 554, x], [0, 0, 1]]\n", "camera_matrix must be a number; got 'x'"),
    (ROS_MATRIX.format(rows=3, data=K_DATA) + "distortion_coefficients: {rows: 1, cols: 5, data: [0, x, 0, 0, 0]}\n",
     "distortion_coefficients.data must be a number; got 'x'"),
    (ROS_MATRIX.format(rows=3, data=K_DATA) + "image_width: wide\n", "image_width must be a whole number; got 'wide'"),
    ('{"fx": 1%s, "fy": 554, "cx": 320, "cy": 240}' % ("0" * 400), "fx must be a number; got 1000"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "dist": [0, "x", 0, 0]}', "dist must be a number; got 'x'"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "height": "tall"}', "height must be a whole number; got 'tall'"),
    (OPENCV_MATRIX.format(fields="", fx="abc"), "camera_matrix.data must be a number; got 'abc'"),
    (OPENCV_MATRIX.format(fields="image_width: wide\n", fx="554."), "image_width must be a whole number; got 'wide'"),
    (OPENCV_MATRIX.format(fields="image_height: 480.5\n", fx="554."), "image_height must be a whole number; got 480.5"),
])
def test_non_numeric_entries_are_one_line_errors_naming_the_field(tmp_path, text, message):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {message}")
    assert "\n" not in str(info.value)



D_VALUES = [-0.1209, 0.0515, 0.0, 0.0001, 0.0]
# One camera (a 1600 x 1200 px calibration) as each format writes its matrix; {distortion} is
# where the distortion goes, as that format writes a key and a list.
MATRIX_FORMATS = {
    "json matrix": ('{{"camera_matrix": [[1299.5, 0, 805.7], [0, 1294.6, 596], [0, 0, 1]], {distortion}, '
                    '"image_width": 1600, "image_height": 1200}}', '"{key}": {values}'),
    "json fx": ('{{"fx": 1299.5, "fy": 1294.6, "cx": 805.7, "cy": 596, {distortion}}}', '"{key}": {values}'),
    "ros": ("camera_matrix: {{rows: 3, cols: 3, data: [1299.5, 0, 805.7, 0, 1294.6, 596, 0, 0, 1]}}\n"
            "distortion_model: plumb_bob\n{distortion}\n", "{key}: {values}"),
    "opencv": ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
               "   data: [ 1299.5, 0., 805.7, 0., 1294.6, 596., 0., 0., 1. ]\n{distortion}\n",
               "{key}: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: {values}"),
}


def camera_text(form: str, key: str, values: list[float] = D_VALUES) -> str:
    """The camera of MATRIX_FORMATS[`form`] with distortion `values` under `key`."""
    text, distortion = MATRIX_FORMATS[form]
    return text.format(distortion=distortion.format(key=key, values=json.dumps(values)))


@pytest.mark.parametrize("form", MATRIX_FORMATS)
@pytest.mark.parametrize("key", ["distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "d", "dist"])
def test_distortion_is_read_under_each_of_its_names_in_every_format(tmp_path, form, key):
    """`dist_coeffs` beside a camera_matrix list was dropped: a distortion-free camera, wrong poses, no word."""
    p = tmp_path / "cam.yaml"
    p.write_text(camera_text(form, key))
    assert load_camera(p).dist.tolist() == D_VALUES


@pytest.mark.parametrize("form", MATRIX_FORMATS)
@pytest.mark.parametrize("key", ["distortion", "dist_coef", "distortionCoefficients", "Distortion_Coeffs", "k1"])
def test_a_key_that_looks_like_distortion_but_is_not_read_is_refused(tmp_path, form, key):
    p = tmp_path / "cam.yaml"
    p.write_text(camera_text(form, key))
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {key}: not a key signpose reads, and without it the lens would be "
                                      "taken as distortion-free; give the coefficients as one list in OpenCV's order")
    assert "distortion_coefficients, d, D, dist_coeffs, distCoeffs" in str(info.value)


def test_keys_that_are_not_distortion_are_ignored(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(camera_text("json matrix", "dist_coeffs")[:-1] + ', "distance_m": 2.5, "avg_reprojection_error": '
                 '0.2, "model": "pinhole", "notes": {"dist": "n/a"}}')
    assert load_camera(p).dist.tolist() == D_VALUES


@pytest.mark.parametrize("form", MATRIX_FORMATS)
def test_distortion_given_twice_is_refused(tmp_path, form):
    """Which of two lists the file means cannot be known."""
    p = tmp_path / "cam.yaml"
    text, distortion = MATRIX_FORMATS[form]
    separator = ", " if form.startswith("json") else "\n"
    twice = separator.join(distortion.format(key=key, values=values)
                           for key, values in (("D", [0.0] * 5), ("dist_coeffs", D_VALUES)))
    p.write_text(text.format(distortion=twice))
    with pytest.raises(CameraError, match="the distortion is given twice, as D and dist_coeffs: keep the one meant"):
        load_camera(p)


FISHEYE_FS = """%YAML:1.0
---
K: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1299.5, 0., 805.7, 0., 1294.6, 596., 0., 0., 1. ]
D: !!opencv-matrix
   rows: 4
   cols: 1
   dt: d
   data: [ 0.05, -0.01, 0.002, -0.0005 ]
"""


@pytest.mark.parametrize("model, message", [
    ("distortion_model: fisheye\n", "distortion_model 'fisheye' is not supported"),
    ("distortion_model: equidistant\n", "distortion_model 'equidistant' is not supported"),
    # what OpenCV's calibration sample (camera_calibration.cpp) writes for a fisheye calibration
    ("fisheye_model: 1\n", "fisheye_model 1 is not supported"),
])
def test_an_opencv_filestorage_file_of_another_model_is_refused(tmp_path, model, message):
    """A fisheye's k1 k2 k3 k4 were read as OpenCV's k1 k2 p1 p2 without a word."""
    p = tmp_path / "fisheye.yml"
    p.write_text(FISHEYE_FS + model)
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {message}: signpose uses OpenCV's model (plumb_bob, rational_polynomial "
                                      "or radtan: k1 k2 p1 p2 k3 ...) on a pinhole camera")
    for usable in ("distortion_model: plumb_bob\n", "fisheye_model: 0\n", ""):
        p.write_text(FISHEYE_FS + usable)
        assert load_camera(p).dist.tolist() == [0.05, -0.01, 0.002, -0.0005]



OPENCV_FS = """%YAML:1.0
---
calibration_time: "Mon 01 Jan 2024"
image_width: 1600
image_height: 1200
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1299.5, 0., 805.7, 0., 1294.6, 596., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -0.1209, 0.0515, 0., 0.0001, 0. ]
"""


@pytest.mark.parametrize("text, k1", [(OPENCV_FS, -0.1209), (ROS, -0.1)], ids=["opencv", "ros"])
@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "utf-16-be", "utf-8"])
def test_a_camera_file_with_a_byte_order_mark_is_read(tmp_path, text, k1, encoding):
    """Windows editors start UTF-8 with a byte-order mark, which OpenCV read as YAML and failed on;
    Windows PowerShell 5's `ros2 topic echo ... > cam.yaml` writes UTF-16, said to be no text."""
    p = tmp_path / "cam.yaml"
    data = text.encode(encoding)
    p.write_bytes(codecs.BOM_UTF16_BE + data if encoding == "utf-16-be" else data)  # Python writes no mark for it
    assert load_camera(p).dist[0] == k1


def test_a_nul_character_is_not_text(tmp_path):
    """OpenCV reads text up to a NUL: the distortion after it was dropped."""
    p = tmp_path / "cam.yml"
    p.write_text(OPENCV_FS.replace("distortion_coefficients", "\0distortion_coefficients"))
    with pytest.raises(CameraError, match=re.escape(f"camera file {p} is not text (UTF-8, or UTF-16 with a ")):
        load_camera(p)



# What OpenCV's calibration sample writes by default (its camera_calibration.cpp, out_camera_data.xml).
OPENCV_XML = """<?xml version="1.0"?>
<opencv_storage>
<calibration_time>"Mon 01 Jan 2024"</calibration_time>
<image_width>1600</image_width>
<image_height>1200</image_height>
<fisheye_model>0</fisheye_model>
<camera_matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    1299.5 0. 805.70000000000005 0. 1294.5999999999999 596. 0. 0. 1.</data></camera_matrix>
<distortion_coefficients type_id="opencv-matrix">
  <rows>5</rows>
  <cols>1</cols>
  <dt>d</dt>
  <data>
    -0.12089999999999999 0.051499999999999997 0. 0.0001 0.</data></distortion_coefficients>
<avg_reprojection_error>0.083000000000000004</avg_reprojection_error>
</opencv_storage>
"""


@pytest.mark.parametrize("text", [OPENCV_XML, OPENCV_XML.replace("\n", "\r\n"),
                                  OPENCV_XML.removeprefix('<?xml version="1.0"?>\n'),
                                  "\n" + OPENCV_XML.removeprefix('<?xml version="1.0"?>\n'), "\n \n" + OPENCV_XML],
                         ids=["sample", "crlf", "no declaration", "a blank line, no declaration",
                              "blank lines before the declaration"])
def test_an_opencv_filestorage_xml_file_is_read(tmp_path, text):
    """It was refused with "expected a mapping with camera_matrix or k ...", which says nothing of XML."""
    p = tmp_path / "out_camera_data.xml"
    p.write_text(text)
    camera = load_camera(p)
    assert camera.K[0, 0] == 1299.5 and camera.dist.tolist() == D_VALUES
    assert (camera.width, camera.height) == (1600, 1200)


@pytest.mark.parametrize("text, message", [
    (OPENCV_XML.replace("<fisheye_model>0", "<fisheye_model>1"), "fisheye_model 1 is not supported: signpose uses"),
    (OPENCV_XML.replace("camera_matrix", "intrinsic_matrix"),
     "expected camera_matrix (ROS camera_info file), k (ROS 2 camera_info message, as `ros2 topic echo --once` prints "
     "it), K, cameraMatrix, intrinsics (Kalibr) or fx, fy, cx, cy keys; this OpenCV FileStorage XML file has none"),
    # Agisoft Metashape's calibration XML, say
    ('<?xml version="1.0" encoding="UTF-8"?>\n<calibration>\n  <projection>frame</projection>\n'
     '  <width>1600</width>\n</calibration>\n',
     "not a readable OpenCV FileStorage XML file (line 2: <opencv_storage> tag is missing)"),
    (OPENCV_XML.replace("</rows>", "</cols>", 1),
     "not a readable OpenCV FileStorage XML file (line 8: Mismatched closing tag)"),
    (OPENCV_XML.replace("</rows>", "</cols>", 1).removeprefix('<?xml version="1.0"?>\n'),
     "not a readable OpenCV FileStorage XML file (line 7: Mismatched closing tag)"),
    ("\n\n" + OPENCV_XML.replace("</rows>", "</cols>", 1),
     "not a readable OpenCV FileStorage XML file (line 10: Mismatched closing tag)"),
], ids=["fisheye", "no matrix", "not opencv", "broken", "broken without declaration",
        "broken after blank lines"])
def test_an_unusable_xml_file_is_a_one_line_error_naming_the_format(tmp_path, text, message):
    assert_one_line_error(tmp_path / "cam.xml", text, message)


def assert_one_line_error(p: Path, text: str, message: str) -> None:
    """Loading `text` written to `p` is a CameraError of one line: the path, then `message`."""
    p.write_text(text)
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {message}") and "\n" not in str(info.value)



# `kalibr_calibrate_cameras --models pinhole-radtan` for one camera: camchain.yaml
@pytest.mark.parametrize("text, message", [
    (ROS + "image_width: 1280\n", "line 7, column 1: the key 'image_width' is given twice"),
    (ROS.replace("rows: 3, cols: 3", "rows: 3, rows: 3"), "line 4, column 26: the key 'rows' is given twice"),
    ('{"fx": 500, "fy": 500, "cx": 320, "cy": 240, "fx": 550}', "line 1, column 46: the key 'fx' is given twice"),
    (OPENCV_FS + "image_width: 1280\n", "the key 'image_width' is given twice"),
    (OPENCV_FS.replace("   cols: 3\n", "   cols: 3\n   rows: 3\n"), "the key 'rows' is given twice"),
    (OPENCV_XML.replace("<image_height>", "<image_width>1280</image_width>\n<image_height>"),
     "the key 'image_width' is given twice"),
], ids=["ros", "ros nested", "json", "opencv yaml", "opencv matrix", "opencv xml"])
def test_a_key_given_twice_is_refused_naming_it(tmp_path, text, message):
    """PyYAML read the last of the two, OpenCV the first: a value pasted below the old one was used or not,
    without a word."""
    p = tmp_path / "cam.yaml"
    p.write_text(text)
    with pytest.raises(CameraError, match=re.escape(f"{p}: {message} in one object: keep the one meant")):
        load_camera(p)


KALIBR = """cam0:
  cam_overlaps: []
  camera_model: pinhole
  distortion_coeffs: [-0.1209, 0.0515, 0.0, 0.0001]
  distortion_model: radtan
  intrinsics: [1299.5, 1294.6, 805.7, 596.0]
  resolution: [1600, 1200]
  rostopic: /cam0/image_raw
"""


def test_a_kalibr_camchain_of_one_pinhole_radtan_camera_is_read(tmp_path):
    """radtan is OpenCV's k1 k2 p1 p2; the file was refused with "expected camera_matrix ..."."""
    p = tmp_path / "camchain.yaml"
    p.write_text(KALIBR)
    camera = load_camera(p)
    assert camera.K.tolist() == [[1299.5, 0, 805.7], [0, 1294.6, 596.0], [0, 0, 1]]
    assert camera.dist.tolist() == D_VALUES[:4] and (camera.width, camera.height) == (1600, 1200)
    p.write_text(KALIBR.replace("cam0", "cam1"))  # one camera of a rig, kept alone
    assert load_camera(p).dist.tolist() == D_VALUES[:4]
    p.write_text(KALIBR.replace("radtan", "none").replace("-0.1209, 0.0515, 0.0, 0.0001", ""))
    assert not load_camera(p).has_distortion


@pytest.mark.parametrize("replace, by, message", [
    ("radtan", "equidistant", "cam0: distortion_model 'equidistant' is not supported: signpose uses OpenCV's model"),
    ("radtan", "fov", "cam0: distortion_model 'fov' is not supported"),
    ("radtan", "none", "cam0: distortion_model 'none' is not supported"),  # with coefficients: of which model?
    # the omnidirectional model's intrinsics are [xi, fu, fv, pu, pv]: refused by its model, not their count
    ("pinhole", "omni", "cam0: camera_model 'omni' is not supported: signpose uses OpenCV's model"),
    ("[1299.5, 1294.6, 805.7, 596.0]", "[1299.5, 805.7, 596.0]",
     "cam0: intrinsics must be Kalibr's pinhole [fu, fv, pu, pv] (fx, fy, cx, cy in px); got [1299.5, 805.7, 596.0]"),
    ("[1600, 1200]", "[1600]", "cam0: resolution must be [width, height] in px; got [1600]"),
    ("[1600, 1200]", "[1600, 1200.5]", "cam0: resolution height must be a whole number; got 1200.5"),
    ("rostopic", "image_width: 1600\n  rostopic",
     "cam0: the image size is given twice, as resolution and image_width: keep the one meant"),
    (KALIBR, KALIBR + KALIBR.replace("cam0", "cam1"), "this Kalibr camchain has 2 cameras (cam0, cam1) and signpose "
     "needs the one that took the photos: give a copy of the file with only that camera's block"),
], ids=["equidistant", "fov", "none", "omni", "intrinsics", "resolution", "fraction", "size twice", "two cameras"])
def test_a_kalibr_camchain_signpose_cannot_use_is_refused_naming_the_camera(tmp_path, replace, by, message):
    p = tmp_path / "camchain.yaml"
    p.write_text(KALIBR.replace(replace, by))
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value).startswith(f"{p}: {message}") and "\n" not in str(info.value)


@pytest.mark.parametrize("text, given, missing", [
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "width": 640}', "width", "height"),
    (ROS_MATRIX.format(rows=3, data=K_DATA) + "image_height: 480\n", "height", "width"),
    (ROS2_MESSAGE.replace("height: 480\n", ""), "width", "height"),
    (OPENCV_MATRIX.format(fields="image_width: 640\n", fx="554."), "width", "height"),
], ids=["json", "ros-file", "ros-message", "opencv"])
def test_a_camera_file_with_the_image_width_or_height_alone_is_refused(tmp_path, text, given, missing):
    """Intrinsics are scaled to another image size by both; with one alone they were used unscaled."""
    p = tmp_path / "half.yaml"
    p.write_text(text)
    with pytest.raises(CameraError) as info:
        load_camera(p)
    assert str(info.value) == (f"{p}: the image {given} is given without the image {missing}: give both, the size in "
                               "px the intrinsics are for (scaling them to other image sizes needs both), or neither")


def test_a_number_with_an_exponent_is_a_number(tmp_path):
    """YAML 1.1 reads 5.54e2 (an exponent without a sign) as a string; written without quotes, it is a number."""
    p = tmp_path / "c.yaml"
    p.write_text(ROS_MATRIX.format(rows=3, data="[5.54e2, 0, 3.2E+2, 0, 5.54e2, 24e1, 0, 0, 1e0]"))
    assert load_camera(p).K.tolist() == [[554, 0, 320], [0, 554, 240], [0, 0, 1]]
    p.write_text('{"fx": 5.54e2, "fy": 554, "cx": 3.2e2, "cy": 240, "dist": [-1e-1, 0, 0, 0]}')
    assert load_camera(p).K[0, 0] == 554 and load_camera(p).dist[0] == -0.1


@pytest.mark.parametrize("text, message", [
    ('{"fx": "554", "fy": 554, "cx": 320, "cy": 240}', "fx must be a number, not text: write 554 without quotes"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "dist": [-0.1, "0.02", 0, 0]}',
     "dist must be a number, not text: write 0.02 without quotes"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "width": "640", "height": 480}',
     "width must be a whole number, not text: write 640 without quotes"),
    ('K: ["554", 0, 320, 0, 554, 240, 0, 0, 1]\n', "K must be a number, not text: write 554 without quotes"),
    ("K: [554, 0, 320, 0, 554, 240, 0, 0, '1e0']\n", "K must be a number, not text: write 1e0 without quotes"),
    (OPENCV_MATRIX.format(fields='image_width: "640"\nimage_height: 480\n', fx="554."),
     "image_width must be a whole number, not text: write 640 without quotes"),
], ids=["json fx", "json dist", "json width", "yaml K", "yaml exponent", "opencv width"])
def test_a_number_written_as_text_is_refused_naming_the_key(tmp_path, text, message):
    """`{"fx": "554"}` was read as 554 from a file, where PUT /api/camera refused it: a value that is not a number
    is refused, and one typed in quotes is said to be."""
    assert_one_line_error(tmp_path / "quoted.yaml", text, message)


@pytest.mark.parametrize("text, message", [
    ('{"fx": null, "fy": 554, "cx": 320, "cy": 240}', "fx is null: give it a number"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": null}', "cy is null: give it a number"),
    ('{"K": null, "width": 640, "height": 480}', "K is null: give it the camera matrix"),
    ('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "width": null, "height": 480}',
     "width is null: give it a number, or leave out both the image width and height"),
    (ROS_MATRIX.format(rows=3, data=K_DATA) + "image_width: 640\nimage_height:\n",
     "image_height is null: give it a number, or leave out both the image width and height"),
], ids=["fx", "cy", "K", "width", "yaml height"])
def test_a_null_value_is_said_to_be_null(tmp_path, text, message):
    """A null fx was "this file has none" of fx, fy, cx, cy, and a null width "the image height is given without the
    image width"."""
    assert_one_line_error(tmp_path / "null.yaml", text, message)


def test_a_null_image_size_is_no_image_size(tmp_path):
    """GET /api/camera/file gives a camera without an image size with width and height null."""
    p = tmp_path / "unsized.json"
    p.write_text('{"fx": 554, "fy": 554, "cx": 320, "cy": 240, "width": null, "height": null}')
    assert (load_camera(p).width, load_camera(p).height) == (None, None)


def test_missing_file_and_scaling():
    with pytest.raises(CameraError, match="not found"):
        load_camera("/nonexistent/cam.yaml")
    cam = assumed_camera(640, 480)
    assert cam.is_assumed and abs(cam.K[0, 0] - 554.256) < 1e-3
    scaled, warnings = cam.for_image(1280, 960)
    assert scaled.K[0, 0] == pytest.approx(2 * cam.K[0, 0]) and warnings[0].endswith("intrinsics scaled by 2 x 2")
    # the image resized as cv2.resize does moves a pixel centre u to (u + 0.5) s - 0.5 (0.25 px from u s at s 0.5)
    points = np.array([[0.3, -0.2, 2.0], [-0.5, 0.4, 3.0]])
    for size in ((1280, 960), (320, 240)):
        s = size[0] / 640
        seen = cv2.projectPoints(points, np.zeros(3), np.zeros(3), cam.K, None)[0].reshape(-1, 2)
        resized = cv2.projectPoints(points, np.zeros(3), np.zeros(3), cam.for_image(*size)[0].K, None)[0].reshape(-1, 2)
        assert np.abs(resized - ((seen + 0.5) * s - 0.5)).max() < 1e-9
    # a scale near 1 is not rounded to 1, which would say nothing was scaled
    assert cam.for_image(641, 481)[1][0].endswith("intrinsics scaled by 1.0016 x 1.0021")


def intrinsics(fx: float, fy: float, cx: float = 320, cy: float = 240, s: float = 0) -> np.ndarray:
    """K in px."""
    return np.array([[fx, s, cx], [0, fy, cy], [0, 0, 1]])


@pytest.mark.parametrize("K, size, message", [
    (intrinsics(1e300, 1e300), (None, None), r"fx=1e\+300 px is longer than 1e\+06 px"),
    (intrinsics(1e100, 1e100), (None, None), "give the file the image width and height"),
    (intrinsics(4e5, 4e5), (640, 480), "fx=400000 px makes the image's 640 px a field of view under 0.1°"),
    (intrinsics(500, 500), (None, 480), "the image height is given without the image width: give both"),
    (intrinsics(500, 6000), (None, None), "fx/fy = 0.0833"),
    (intrinsics(5010, 500), (640, 480), "fx/fy = 10"),
    (intrinsics(500, 500, s=1e300), (640, 480), "skew"),
    (intrinsics(500, 500, cx=1e300), (None, None), "principal point"),
    (intrinsics(500, 500), (2**31, 480), "under 2"),
    # a lens's focal length in mm typed where pixels belong: the camera 1 cm from the sign, silently
    (intrinsics(4.2, 4.2), (640, 480), r"fx=4\.2 px gives a field of view of 178\.5° across the image.*not mm"),
    (intrinsics(4.2, 4.2), (None, None), r"fx=4\.2 px gives a field of view of 178\.5° across twice its "
                                         "principal point"),
    (intrinsics(1e-9, 1e-9), (640, 480), "wider than a pinhole camera sees"),
    (intrinsics(600, 20), (640, 480), r"fy=20 px gives a field of view of 170\.5°"),
])
def test_implausible_intrinsics_are_refused(K, size, message):
    with pytest.raises(CameraError, match=message):
        Camera(K, np.zeros(5), *size)


@pytest.mark.parametrize("dist", [[1e308, 0, 0, 0], [50, 0, 0, 0, 0], [0, 0, 0, 0, -1e4], [-1e3, 0, 0, 0]])
@pytest.mark.parametrize("size", [(640, 480), (None, None)])
def test_distortion_no_lens_has_is_refused(dist, size):
    """A typed 1e308 is refused: applied, it would turn every image into an SVD error."""
    with pytest.raises(CameraError, match="moves image points by more than 5x"):
        Camera(intrinsics(554, 554), np.array(dist, float), *size)


@pytest.mark.parametrize("dist", [[-0.3, 0.1, 0, 0, 0], [-0.45, 0.25, 0.001, -0.001, -0.1], [0.1, 0, 0, 0]])
def test_wide_angle_distortion_is_a_camera(dist):
    Camera(intrinsics(554, 554), np.array(dist, float), 640, 480)


@pytest.mark.parametrize("hfov_deg", [120, 160])
def test_the_widest_lenses_are_cameras(hfov_deg):
    """A 120° rectilinear action camera, and a pinhole field of 160° (a fisheye's fx is longer than that)."""
    f = 320 / np.tan(np.radians(hfov_deg) / 2)
    Camera(intrinsics(f, f), np.zeros(5), 640, 480)
    Camera(intrinsics(f, f), np.zeros(5))


def test_a_long_lens_with_its_image_size_is_a_camera():
    """0.2° across 8000 px needs fx = 2.3e6 px: past the cap for files without a size, not with one."""
    f = 4000 / math.tan(math.radians(0.1))
    assert Camera(intrinsics(f, f, 4000, 3000), np.zeros(5), 8000, 6000).K[0, 0] == f
    with pytest.raises(CameraError, match="without an image size"):
        Camera(intrinsics(f, f, 4000, 3000))


def test_a_thin_crop_is_held_against_its_long_side():
    """A 4000 x 1 px strip is a camera's: vertically it sees a sliver, but 4000 px span 60°.
    Turned upright, 60° across 1 px made it 180° tall, and the assumption was refused as a
    focal length in mm; it is held to 169°."""
    assert assumed_camera(4000, 1).for_image(4000, 1)[1] == []
    tall = assumed_camera(1, 4000)
    assert tall.K[1, 1] == pytest.approx(2000 / math.tan(math.radians(84.5)))
    assert tall.source == "assumed 60° horizontal field of view (narrower, as the image is 169° tall)"


def test_sample_camera_files_load():
    paths = sorted(Path(__file__).parents[1].glob("sample_images/**/camera.yaml"))
    assert paths and all(load_camera(p).width == 640 for p in paths)


@pytest.mark.parametrize("size, message", [
    ((480, 640), "this 480x640 px image is the camera's 640x480 px turned on its side: rotate the photo back"),
    # a portrait photo resized too: it was "a cropped or re-framed photo"
    ((1536, 2048), "this 1536x2048 px image is the camera's 640x480 px turned on its side: rotate the photo back"),
    ((640, 360), "this 640x360 px image has another aspect than the 640x480 px the camera was calibrated at"),
    ((6400, 48), "calibrate the camera at 6400x48"),
])
def test_an_image_of_another_aspect_than_the_calibration_is_an_error(size, message):
    """Scaling fx and fy apart gives a camera no lens is: a portrait photo was 0.5 m off."""
    cam = Camera(intrinsics(500, 500), np.zeros(5), 640, 480)
    with pytest.raises(CameraError, match=re.escape(message)):
        cam.for_image(*size)
    assert cam.for_image(1281, 960)[0].K[0, 0] == pytest.approx(1000.78, abs=0.01)  # within 1 %: scaled


@pytest.mark.parametrize("fx, cx, cy, message", [
    (8e5, 640, 480, "fx=800000 px makes the image's 1280 px a field of view under 0.1°"),
    # a lens's focal length and the sensor's centre in mm: about the principal point the field of
    # view across 1280 px came to 123°, and the pose was 15° and 2 m off with no word
    (4.2, 2.8, 2.1, r"fx=4\.2 px gives a field of view of 179\.2° across the image.*not mm"),
])
def test_a_camera_without_size_that_cannot_take_the_image_is_an_error(fx, cx, cy, message):
    """Its pose would be meaningless; it was answered, with a warning."""
    with pytest.raises(CameraError, match="the camera has no image size and does not fit this 1280x960 px image: "
                                          + message):
        Camera(intrinsics(fx, fx, cx, cy)).for_image(1280, 960)


CENTRE_PROBLEM = "principal point ({:g}, {:g}) px is far from the centre (640, 480) of the 1280x960 px image"


@pytest.mark.parametrize("data, message", [
    ({"fx": 4.2, "fy": 4.2, "cx": 2.8, "cy": 2.1}, r"fx=4\.2 px gives a field of view of 179\.2°.*not mm"),  # in mm
    ({"fx": 1000, "fy": 1000, "cx": 20, "cy": 15}, re.escape(CENTRE_PROBLEM.format(20, 15))),
    ({"fx": 500, "fy": 500, "cx": 320, "cy": 240}, re.escape(CENTRE_PROBLEM.format(320, 240))),  # a 640x480 calibration
])
def test_a_principal_point_far_from_the_centre_of_the_image_size_given_is_refused(data, message):
    """Each gave a pose without a warning (the first 15° and 2 m off): a principal point in the
    image was all that was asked of it, and the field of view was measured about it."""
    with pytest.raises(CameraError, match=message):
        camera_from_json({**data, "width": 1280, "height": 960})
    assert camera_from_json({"fx": 1000, "fy": 1000, "cx": 640 + 0.19 * 1280, "cy": 480 - 0.19 * 960, "width": 1280,
                             "height": 960})


def test_the_principal_point_is_held_to_a_calibrations_bounds_where_one_comes_in():
    """A camera file's, or a chessboard fit's: not the camera of a crop of the image, whose principal
    point may lie anywhere, even outside it."""
    with pytest.raises(CameraError, match=re.escape("principal point (320, -1) px is far from the centre (320, 240) "
                                                    "of the 640x480 px image: a calibration puts it within")):
        camera_from_json({"fx": 500, "fy": 500, "cx": 320, "cy": -1, "width": 640, "height": 480})
    crop = Camera(intrinsics(500, 500, cx=320, cy=-1), np.zeros(5), 640, 480)
    assert crop.for_image(320, 240)[0].K[1, 2] == -0.75  # (-1 + 0.5) / 2 - 0.5


CORNER_JSON = {"fx": 1108.5, "fy": 1108.5, "cx": 640, "cy": 480}  # a 1280 x 960 calibration without its size


def test_a_camera_without_size_for_another_resolution_is_a_warning():
    cam = camera_from_json(CORNER_JSON)
    assert cam.for_image(1280, 960) == (cam, [])
    assert cam.for_image(1000, 700) == (cam, [])  # 14 % and 19 % off the centre: under a quarter
    same, warnings = cam.for_image(640, 480)
    assert same is cam and len(warnings) == 1
    assert "principal point (640, 480) px is far from the centre (320, 240)" in warnings[0]
    assert "another resolution" in warnings[0] and "width and height" in warnings[0]


def test_a_camera_without_size_whose_principal_point_lies_outside_the_image_cannot_take_it():
    """A phone's calibration at 4032x3024 without its size, on a 640x480 image: a warning, and a pose 9 m
    off, where the same camera with its size is refused (another aspect) or scaled (the same)."""
    phone = camera_from_json({"fx": 3000, "fy": 3000, "cx": 2016, "cy": 1512})
    with pytest.raises(CameraError, match=re.escape(
            "the camera has no image size and its principal point (2016, 1512) px lies outside this 640x480 px image, "
            "where a calibration puts it near the centre: the file was probably made for another resolution, "
            "4032x3024 px (twice its principal point): give it that width and height, and it is scaled to this "
            "image")):
        phone.for_image(640, 480)
    assert phone.for_image(4032, 3024) == (phone, [])
    # what the error says to do works
    sized = camera_from_json({"fx": 3000, "fy": 3000, "cx": 2016, "cy": 1512, "width": 4032, "height": 3024})
    assert sized.for_image(640, 480)[0].K[0, 2] == pytest.approx((2016 + 0.5) * 640 / 4032 - 0.5)
    # a crop's own size named: no image size twice the principal point has this image's aspect
    with pytest.raises(CameraError, match="made for another resolution: give it that resolution's width and height"):
        camera_from_json({"fx": 554, "fy": 554, "cx": 800, "cy": 240}).for_image(640, 480)


@pytest.mark.parametrize("cx, cy, message", [
    (-20, 240, "principal point (-20, 240) px is left of or above the image: it is in px from the image's top-left "
               "corner, near the image's centre"),
    (320, 2e6, "principal point (320, 2e+06) px is beyond 1e+06 px, past any image; check the values, or give the "
               "file the image width and height"),
])
def test_a_principal_point_no_image_has_is_refused_with_what_to_do(cx, cy, message):
    """It was "outside the image (0..1e+06 x 0..1e+06 px)", an image nobody had given."""
    with pytest.raises(CameraError, match=re.escape(message)):
        camera_from_json({"fx": 4e5, "fy": 4e5, "cx": cx, "cy": cy})  # a focal length that allows it


def test_the_other_resolution_warning_reaches_the_recognition(library):
    scenes = Path(__file__).parents[1] / "sample_images" / "scenes"
    rec = recognize(read_image(scenes / "scene_002.jpg"), library, preset("default"),
                    camera_from_json(CORNER_JSON))
    assert any("another resolution" in w for w in rec.warnings)


@pytest.mark.parametrize("text, message", [
    ("image_width: 640\ncamera_matrix:\n  rows: 3\n    cols: 3\n",
     "neither valid YAML nor JSON (line 4, column 9: mapping values are not allowed here)"),
    ('{"fx": 554, "fy": 554,\n "cx": [320, "cy": 240}\n',
     "neither valid YAML nor JSON (line 2, column 23: expected ',' or ']', but got '}', "
     "while parsing a flow sequence that starts at line 2, column 8)"),
    ("fx: 554\x01\n", "neither valid YAML nor JSON (character 8: unacceptable character #x0001"),
    ("%YAML:1.0\n---\ncamera_matrix: [1, 2\nfoo: : bar\n",
     "not a readable OpenCV FileStorage YAML file (line 4: Incorrect indentation)"),
    # OpenCV puts text read without a final newline where the file name goes, "(9): " and all
    ('{"type_id": "opencv-matrix", "a": (9): }',
     "not a readable OpenCV FileStorage JSON file (line 1: Unrecognized value)"),
])
def test_unparsable_files_are_one_line_errors_with_the_position(tmp_path, text, message):
    assert_one_line_error(tmp_path / "camera.yaml", text, message)


def alias_bomb(levels: int) -> str:
    """A YAML file whose `k` stands, through `levels` of aliases, for 9**levels values: 421 bytes and
    9**8 of them took 19 s and 3 GB to refuse."""
    lines = ["a0: &a0 [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels)]
    return "\n".join([*lines, f"k: *a{levels - 1}", ""])


@pytest.mark.parametrize("text, message", [
    (alias_bomb(5), "line 2, column 10: YAML alias *a0: camera files are read without anchors and aliases"),
    # aliases sparing a repeat in a file of sound numbers are refused all the same
    (ROS2_MESSAGE.replace("\nk:\n", "\nk: &k\n").replace("\np:\n", "\npp: *k\np:\n"), "line 35, column 5: YAML alias *k"),
    # a merge key is an alias too
    ("base: &b {width: 640, height: 480}\n<<: *b\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n",
     "line 2, column 5: YAML alias *b"),
], ids=["bomb", "repeat", "merge"])
def test_yaml_aliases_are_refused_saying_where(tmp_path, text, message):
    assert_one_line_error(tmp_path / "camera.yaml", text, message)


@pytest.mark.parametrize("data, message", [
    ({"k": [0.0] * 1_000_000}, "k has more than 9 values"),
    ({"camera_matrix": {"rows": 1000, "cols": 1000, "data": [0.0] * 1_000_000}},
     "camera_matrix.data has more than 9 values"),
    ({"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1], [0, 0, 0]]}, "K has more than 9 values"),
    ({"K": np.eye(4)}, "K has more than 9 values"),  # an OpenCV FileStorage matrix is read as an array
    ({"fx": 500, "fy": 500, "cx": 320, "cy": 240, "dist": [0.0] * 15}, "dist has more than 14 values"),
    ({"intrinsics": [500, 500, 320, 240, 0], "resolution": [640, 480]}, "intrinsics has more than 4 values"),
    ({"intrinsics": [500, 500, 320, 240], "resolution": [640, 480, 3]}, "resolution has more than 2 values"),
    ({"k": [[[500, 0, 320], [0, 500, 240], [0, 0, 1]]]}, "k must be numbers, or rows of numbers; got lists nested"),
])
def test_a_value_holding_more_numbers_than_it_can_is_refused_before_it_is_read(data, message):
    """A camera matrix is 9 numbers, a distortion vector at most 14: a million (0.6 s to refuse, when
    they were read before they were counted), or lists nested three deep, are no camera's."""
    with pytest.raises(CameraError, match=re.escape(message)):
        camera_from_json(data)
    assert camera_from_json({"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]], "dist": [[-0.1] + [0] * 13]})


def indented(levels: int) -> str:
    """Mappings nested `levels` deep by indentation alone, a number at the bottom."""
    return "".join(f"{'  ' * i}a{i}:\n" for i in range(levels)) + "  " * levels + "1\n"


# Deeper than Python's stack takes; from 20,000 to 40,000 levels OpenCV's parser crashed the process,
# which tests/test_cli.py tries in a process of its own.
DEEP = 10_000


@pytest.mark.parametrize("text, message", [
    ("k: " + "[" * DEEP + "]" * DEEP, "line 1, column 23: values nested more than 20 levels deep"),
    ("k:\n" + "- " * DEEP + "1\n", "line 2, column 39: values nested more than 20 levels deep"),
    (indented(600), "line 20, column 39: values nested more than 20 levels deep"),
    ("%YAML:1.0\n---\nk: " + "[" * DEEP + "]" * DEEP, "values nested more than 20 levels deep"),
    ("%YAML:1.0\n---\nk:\n  " + "- " * DEEP + "1\n", "values nested more than 20 levels deep"),
    ('{"type_id": "opencv-matrix", "k": ' + "[" * DEEP + "]" * DEEP + "}", "values nested more than 20 levels"),
    ('<?xml version="1.0"?>\n<opencv_storage>\n' + "<a>" * DEEP + "</a>" * DEEP + "\n</opencv_storage>\n",
     "values nested more than 20 levels deep"),
    # too few bytes to take OpenCV's parser past its stack, as many as take Python's past its own
    ("%YAML:1.0\n---\n" + indented(600), "values nested more than 20 levels deep"),
], ids=["yaml flow", "yaml dashes", "yaml indented", "opencv yaml flow", "opencv yaml dashes", "opencv json",
        "opencv xml", "opencv yaml indented"])
def test_values_nested_deeper_than_any_camera_files_are_refused(tmp_path, text, message):
    """Each was a RecursionError's traceback (an HTTP 500 in PUT /api/camera)."""
    assert_one_line_error(tmp_path / "camera.yaml", text, message)


def test_a_whole_number_too_long_for_python_is_refused_saying_where(tmp_path):
    """A ValueError's traceback (an HTTP 500 in PUT /api/camera): Python reads no int of 4301 digits."""
    assert_one_line_error(tmp_path / "camera.yaml", "fy: 500\nfx: " + "1" * 5000 + "\ncx: 320\ncy: 240\n",
                          "line 2, column 5: a whole number of 5000 characters, which no value in a camera file has")


def test_a_camera_file_too_large_for_one_or_with_too_many_values_is_refused(tmp_path):
    """A YAML list of a million numbers (5 MB) took 38 s and 830 MB to refuse."""
    sound = json.dumps({"fx": 500, "fy": 500, "cx": 320, "cy": 240})
    (tmp_path / "a.json").write_text(sound + " " * 1_000_000)
    with pytest.raises(CameraError, match=re.escape(f"camera file {tmp_path / 'a.json'} is over 1000 kB, which no "
                                                    "camera file is")):
        load_camera(tmp_path / "a.json")
    many = sound[:-1] + "".join(f', "n{i}": {i}' for i in range(5000)) + "}"
    assert_one_line_error(tmp_path / "b.json", many, "line 1, column 72760: more than 10000 values, where a camera")
    # `ros2 topic echo` run on past its first message, 600 kB of them: the first is read, not the rest
    (tmp_path / "echo.yaml").write_text(ROS2_MESSAGE * 600)
    assert load_camera(tmp_path / "echo.yaml").K[0, 0] == 500


# ---- a camera whose images are part of its sensor: ROS's roi and binning

SCENES = Path(__file__).parents[1] / "sample_images" / "scenes"


@pytest.fixture(scope="module")
def sensor_render(library):
    """(library, the 1280x960 sensor's camera, a render of a sign through it, the recognition of the whole
    render); the sign lies at x 366..774, y 393..613 px."""
    sensor = synthetic_camera((1280, 960))
    scene = render_scene(library, "security_compound", sensor, np.random.default_rng(11), "easy")
    return library, sensor, scene, recognize(scene.image, library, preset("default"), sensor)


def read_out(image: np.ndarray, roi: tuple[int, int, int, int], binning: tuple[int, int]) -> np.ndarray:
    """What a sensor delivers of `image`, its full frame: the `roi` (x_offset, y_offset, width, height) px,
    each `binning` (x, y) block of px averaged into one, the last px of a row or column short of a whole
    block left out."""
    x, y, w, h = roi
    (bx, by), size = binning, (w // binning[0], h // binning[1])
    return cv2.resize(image[y:y + size[1] * by, x:x + size[0] * bx], size, interpolation=cv2.INTER_AREA)


def ros2_message(K: np.ndarray, size: tuple[int, int], roi: tuple[int, int, int, int], binning: tuple[int, int],
                 do_rectify: bool = False) -> str:
    """A CameraInfo as `ros2 topic echo --once` prints it, the camera K (3, 3) px of a sensor of `size` px."""
    x, y, w, h = roi
    return (ROS2_MESSAGE.replace("height: 480\nwidth: 640\n", f"height: {size[1]}\nwidth: {size[0]}\n")
            .replace(k_list(K_VALUES), k_list(K.ravel().tolist())).replace("d:\n- -0.1\n- 0.01\n", "d:\n- 0.0\n- 0.0\n")
            .replace(MESSAGE_END, f"binning_x: {binning[0]}\nbinning_y: {binning[1]}\nroi:\n  x_offset: {x}\n"
                                  f"  y_offset: {y}\n  height: {h}\n  width: {w}\n  do_rectify: {str(do_rectify).lower()}\n"
                                  "---\n"))


def ros_file(K: np.ndarray, size: tuple[int, int], roi: tuple[int, int, int, int], binning: tuple[int, int]) -> str:
    """camera_calibration's file of a sensor of `size` px, with the roi and binning a driver reads it out with."""
    x, y, w, h = roi
    return (ROS.replace("[500, 0, 320, 0, 510, 240, 0, 0, 1]", str(K.ravel().tolist())).replace("-0.1, 0.01", "0, 0")
            .replace("image_width: 640\nimage_height: 480", f"image_width: {size[0]}\nimage_height: {size[1]}")
            + f"binning_x: {binning[0]}\nbinning_y: {binning[1]}\n"
              f"roi: {{x_offset: {x}, y_offset: {y}, width: {w}, height: {h}}}\n")


def plain_json(K: np.ndarray, size: tuple[int, int], roi: tuple[int, int, int, int], binning: tuple[int, int]) -> str:
    return json.dumps({"K": K.tolist(), "width": size[0], "height": size[1], "binning_x": binning[0],
                       "binning_y": binning[1], "roi": dict(zip(("x_offset", "y_offset", "width", "height"), roi))})


@pytest.mark.slow
@pytest.mark.parametrize("form, roi, binning", [
    (ros2_message, (300, 250, 640, 480), (0, 0)),  # ROS's 0: no binning
    (ros_file, (300, 250, 640, 480), (2, 2)),
    (plain_json, (0, 0, 0, 0), (2, 1)),  # all zeros: the whole sensor
    (ros2_message, (0, 0, 0, 0), (3, 3)),  # 1280 px are 426 whole blocks of 3
], ids=["message roi", "file roi binned", "json binned 2x1", "message binned 3x3"])
def test_part_of_the_sensor_gives_the_pose_and_corners_the_whole_sensor_does(tmp_path, sensor_render, form, roi,
                                                                             binning):
    """A camera_info of a 1280x960 sensor read out 640x480 at (320, 240) gave the sample scene a camera
    0.5 m off: its roi was ignored and its K scaled by 0.5. Each image here is a render read out as a
    sensor does; its camera, from the file, must put the sign where the whole render's recognition
    does (the pixel-centre convention: ROS's image_geometry's cx / binning is 0.25 px off at 2, 0.33 px
    at 3), and the camera where the render's truth has it."""
    library, sensor, scene, whole = sensor_render
    path = tmp_path / "camera.yaml"
    path.write_text(form(sensor.K, (1280, 960), roi, binning))
    window = roi if any(roi) else (0, 0, 1280, 960)
    image = read_out(scene.image, window, tuple(b or 1 for b in binning))
    camera = load_camera(path)
    assert camera.for_image(image.shape[1], image.shape[0]) == (camera, [])  # its images' size: not scaled
    rec = recognize(image, library, preset("default"), camera)
    assert rec.label == "security_compound" and rec.outline is not None
    # sensor px -> image px, as the camera has it
    to_image = camera.K @ np.linalg.inv(sensor.K)
    expected = np.column_stack([whole.corners, np.ones(4)]) @ to_image.T
    assert np.abs((rec.corners - expected[:, :2]).mean(axis=0)).max() < 0.1
    truth = camera_position(scene.R, scene.t)
    assert np.linalg.norm(rec.pose.camera_position - truth) < 0.005


@pytest.mark.parametrize("roi, binning, size, message", [
    ((10, 0, 400, 300), (0, 0), (1280, 960), "its roi 400x300 px at (10, 0) of the 1280x960 px sensor makes them "
                                             "400x300 px, and its intrinsics are for that size only; for images of the "
                                             "whole sensor (at any resolution), leave the roi out of the file"),
    ((1200, 900, 80, 60), (0, 0), (640, 480), "makes them 80x60 px, and its intrinsics are for that size only; for "
                                              "images of the whole sensor (at any resolution), leave the roi out"),
    ((0, 0, 0, 0), (2, 0), (640, 480), "its binning 2x1 of the 1280x960 px sensor makes them 640x960 px, and its "
                                       "intrinsics are for that size only; for images of the whole sensor (at any "
                                       "resolution), leave the binning out of the file"),
    ((0, 0, 1280, 960), (2, 2), (300, 400), "its binning 2x2 of the 1280x960 px sensor makes them 640x480 px, and its "
                                            "intrinsics are for that size only; give it images as read out with that "
                                            "binning, or a camera file for 300x400 px images"),
    ((10, 0, 400, 300), (2, 2), (400, 300), "its roi 400x300 px at (10, 0) and binning 2x2 of the 1280x960 px sensor "
                                            "make them 200x150 px"),
], ids=["whole sensor", "corner roi, sensor scaled", "binning across only", "binned, turned", "roi binned"])
def test_the_camera_of_part_of_a_sensor_takes_only_images_of_its_size(roi, binning, size, message):
    """The whole sensor's 1280x960 image was taken with a 400x300 roi's camera scaled by 3.2 ("calibrated at
    400x300", which the file does not say), its principal point at 2085 px, outside the image, and the sign
    7.8 m away, not 2.3 m; an 80x60 roi's, scaled by 16, put it 40 m away."""
    data = {"fx": 1100, "fy": 1096, "cx": 661.3, "cy": 472.7, "width": 1280, "height": 960, "binning_x": binning[0],
            "binning_y": binning[1], "roi": dict(zip(("x_offset", "y_offset", "width", "height"), roi))}
    camera = camera_from_json(data)
    with pytest.raises(CameraError, match=re.escape(f"this {size[0]}x{size[1]} px image is not the size of the images "
                                                    "the camera file describes: ")) as info:
        camera.for_image(*size)
    assert message in str(info.value)


def test_do_rectify_does_not_change_the_raw_images_camera(tmp_path):
    """do_rectify asks consumers for a rectified roi; the image given is still the raw roi."""
    K = synthetic_camera((1280, 960)).K
    cameras = []
    for do_rectify in (False, True):
        (tmp_path / "camera.yaml").write_text(ros2_message(K, (1280, 960), (300, 250, 640, 480), (2, 2), do_rectify))
        cameras.append(load_camera(tmp_path / "camera.yaml"))
    assert np.array_equal(cameras[0].K, cameras[1].K) and cameras[0].width == cameras[1].width == 320


@pytest.mark.parametrize("roi, binning, size, message", [
    ((700, 0, 640, 480), (0, 0), (1280, 960), "roi 640x480 px at (700, 0) reaches past the 1280x960 px sensor: the "
                                              "roi is in px of the full, unbinned sensor"),
    ((320, 240, 0, 480), (0, 0), (1280, 960), "roi width and height must be positive (an all-zero roi is the whole "
                                              "sensor); got 0x480"),
    ((0, 0, 640, 480), (1024, 1), (1280, 960), "binning 1024x1 leaves no image px of the 640x480 px roi"),
    ((320, 240, 640, 480), (0, 0), None, "roi and binning are in px of the full, unbinned sensor: give its "
                                         "image_width and image_height"),
    ((-5, 0, 640, 480), (0, 0), (1280, 960), "roi.x_offset must be a whole number of px from 0 to 2**31 - 1; got -5"),
    # read as the whole sensor (ROS's all zeros), and one null among numbers was a TypeError's traceback
    ((None, None, None, None), (0, 0), (1280, 960), "roi.x_offset is null: give the roi as whole numbers of px (all "
                                                    "zeros for the whole sensor), or leave the roi out"),
    ((0, 0, 640, None), (0, 0), (1280, 960), "roi.height is null"),
])
def test_a_roi_or_binning_the_sensor_cannot_have_is_refused(roi, binning, size, message):
    data = {"K": synthetic_camera((1280, 960)).K.tolist(), "binning_x": binning[0], "binning_y": binning[1],
            "roi": dict(zip(("x_offset", "y_offset", "width", "height"), roi))}
    with pytest.raises(CameraError, match=re.escape(message)):
        camera_from_json(data | ({"width": size[0], "height": size[1]} if size else {}))


@pytest.mark.parametrize("roi", [{"x": 0, "y": 0, "w": 640, "h": 480}, [0, 0, 640, 480],
                                 {"x_offset": 0, "y_offset": 0, "width": 640}])
def test_a_roi_that_is_not_rosss_four_numbers_is_refused(roi):
    with pytest.raises(CameraError, match="roi must be x_offset, y_offset, width and height, in px of the full"):
        camera_from_json({"fx": 500, "fy": 500, "cx": 640, "cy": 480, "width": 1280, "height": 960, "roi": roi})


def test_part_of_a_sensor_is_written_as_its_file_gives_it_and_read_back():
    """The state directory's camera.json, which `--camera` reads: the crop's own K and size would be
    refused there, its principal point far from their centre."""
    data = {"fx": 554.0, "fy": 554.0, "cx": 640.0, "cy": 480.0, "dist": [-0.1, 0.0, 0.0, 0.0, 0.0], "width": 1280,
            "height": 960, "roi": {"x_offset": 700, "y_offset": 0, "width": 580, "height": 480}, "binning_x": 2,
            "binning_y": 2}
    camera = camera_from_json(data, source="file:cam.yaml")
    assert camera.to_json() == {"fx": 277.0, "fy": 277.0, "cx": -30.25, "cy": 239.75, "dist": [-0.1, 0, 0, 0, 0],
                                "width": 290, "height": 240, "source": "file:cam.yaml"}
    assert camera.file_json() == data | {"source": "file:cam.yaml"}
    again = camera_from_json(json.loads(json.dumps(camera.file_json())), source="file:cam.yaml")
    assert np.array_equal(again.K, camera.K) and again.file_json() == camera.file_json()
    with pytest.raises(CameraError, match="far from the centre"):
        camera_from_json(camera.to_json())


# scene_002 read out of a sensor 400 px wide from its left edge: the sign lies at x 166..346 px
CROP = {"fx": 554.2562584220408, "fy": 554.2562584220408, "cx": 320, "cy": 240}


def test_a_crop_given_with_its_own_size_is_refused_saying_how_to_give_it(library, tmp_path):
    """The crop's own K and size look like a file for another resolution; the refusal said only to check
    the values and the size, which were right, and the crop had no way in."""
    image = read_image(SCENES / "scene_002.jpg")
    path = tmp_path / "crop.json"
    path.write_text(json.dumps(CROP | {"width": 400, "height": 480}))
    with pytest.raises(CameraError, match=re.escape("far from the centre (200, 240) of the 400x480 px image: a "
                                                    "calibration puts it within a few percent of the centre; check "
                                                    "that the values are in pixels and that the file's image size is "
                                                    "the calibration's; for a crop of a larger sensor, give the "
                                                    "sensor's camera matrix, width and height, with the crop as roi")):
        load_camera(path)
    with pytest.raises(CameraError, match="for a crop of a larger sensor"):  # as PUT /api/camera's JSON gives it
        camera_from_json(CROP | {"width": 400, "height": 480, "roi": None, "binning_x": None, "binning_y": None})
    # as it says: the sensor's K and size with the crop as roi, which gives the whole image's pose
    path.write_text(json.dumps(CROP | {"width": 640, "height": 480,
                                       "roi": {"x_offset": 0, "y_offset": 0, "width": 400, "height": 480}}))
    crop = recognize(image[:, :400], library, preset("default"), load_camera(path))
    whole = recognize(image, library, preset("default"), load_camera(SCENES / "camera.yaml"))
    assert np.linalg.norm(crop.pose.camera_position - whole.pose.camera_position) < 0.002
    truth = json.loads((SCENES / "truth.json").read_text())["images"]["scene_002.jpg"]
    assert np.linalg.norm(crop.pose.camera_position - camera_position(np.array(truth["R"]), np.array(truth["t"]))) < 0.005
    # without a size the crop's K is used as it is, with a warning that must not lead to the refusal alone
    unsized = camera_from_json(CROP)
    assert unsized.for_image(400, 480)[1] == [
        "the camera has no image size and its principal point (320, 240) px is far from the centre (200, 240) of the "
        "400x480 px image: the file was probably made for another resolution: give it that resolution's width and "
        "height, and it is scaled to this image; for a crop of a larger sensor, give the sensor's camera matrix, "
        "width and height, with the crop as roi (x_offset, y_offset, width, height, in the sensor's px), or the pose "
        "is wrong"]
