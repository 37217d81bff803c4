"""The `signpose` command line on real files: by its `main` in this process, and as a process of its own where
the process is what is tested (what C libraries write to its stderr, signals, terminals, pipes)."""

import argparse
import contextlib
import fcntl
import json
import os
import pty
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import termios
import time
import tomllib
import types
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from signpose.app.cli import build_parser, main
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.camera import assumed_camera, save_camera
from signpose.pipeline.library import load_library
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset
from tests.support.cli import signpose, signpose_process
from tests.support.scene_images import (OFF_CENTRE, TURNED_SCENE, TURNED_WITHIN_M, png_bomb, turned_photos,
                                        turned_scene_position)

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "sample_images" / "scenes"
SURVEY = ROOT / "sample_images" / "surveys" / "room"
POSE_KEYS = {"R", "t", "camera_position", "quaternion_wxyz", "euler_deg", "reprojection_rmse_px", "ambiguous",
             "covariance"}
TIMING_KEYS = {"segment", "features", "match", "ransac", "pose", "total"}


def check_schema(obj):
    assert set(obj) == {"image", "recognized", "label", "scores", "homography", "corners", "pose", "text_check",
                        "turned_down", "timing_ms", "reused_stages", "warnings", "signs"}
    # every sign found, the answer first
    assert [s["label"] for s in obj["signs"][:1]] == ([obj["label"]] if obj["recognized"] else [])
    assert all(set(s) == {"label", "corners", "pose"} for s in obj["signs"])
    assert all(set(t) == {"sign", "source", "text_check"} for t in obj["turned_down"])
    if obj["recognized"]:
        assert len(obj["text_check"]["strips"]) == 6 and obj["text_check"]["weakest"] >= 0.7
    assert obj["reused_stages"] == []  # the CLI keeps no cache between runs
    assert isinstance(obj["recognized"], bool) and obj["recognized"] == (obj["label"] is not None)
    for s in obj["scores"]:
        assert set(s) == {"sign", "matches", "inliers", "reason"}
        assert isinstance(s["matches"], int) and isinstance(s["inliers"], int)
    assert set(obj["timing_ms"]) == TIMING_KEYS
    assert all(isinstance(w, str) for w in obj["warnings"])
    if obj["recognized"]:
        assert len(obj["homography"]) == 3 and all(len(r) == 3 for r in obj["homography"])
        assert len(obj["corners"]) == 4 and all(len(c) == 2 for c in obj["corners"])
        pose = obj["pose"]
        assert set(pose) == POSE_KEYS
        assert len(pose["t"]) == 3 and len(pose["quaternion_wxyz"]) == 4
        assert set(pose["euler_deg"]) == {"yaw", "pitch", "roll"}
        assert pose["covariance"] is None or (len(pose["covariance"]) == 6 and len(pose["covariance"][0]) == 6)
    else:
        assert obj["homography"] is None and obj["corners"] is None and obj["pose"] is None


def test_json_schema_and_labels_on_sample_scenes():
    truth = json.loads((SCENES / "truth.json").read_text())["images"]
    names = sorted(truth)
    result = signpose("recognize", *[SCENES / n for n in names], "--camera", SCENES / "camera.yaml", "--json")
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == len(names)
    for name, obj in zip(names, lines):
        check_schema(obj)
        assert obj["label"] == truth[name]["label"], (name, obj["scores"], obj["warnings"])
        assert not any("assumed" in w for w in obj["warnings"])


def test_recognize_gives_every_sign_in_view_and_with_a_map_the_camera_in_the_map_frame(tmp_path):
    truth = {p["image"]: p for p in json.loads((SURVEY / "truth.json").read_text())["photos"]}
    # two signs in view; one, and chief_of_security whole but 57 px wide, under the 70 px the truth lists
    names, also = ["photo_002.jpg", "photo_004.jpg"], [[], ["chief_of_security"]]
    result = signpose("recognize", *[SURVEY / n for n in names], "--library", SURVEY / "library", "--camera",
                      SURVEY / "camera.yaml", "--map", SURVEY / "truth_map.yaml", "--json")
    assert result.returncode == 0, result.stderr
    for name, small, line in zip(names, also, result.stdout.splitlines()):
        obj = json.loads(line)
        check_schema({k: v for k, v in obj.items() if k != "camera_in_map"})
        assert sorted(s["label"] for s in obj["signs"]) == sorted(truth[name]["signs"] + small)
        located = obj["camera_in_map"]
        assert sorted(located["signs_used"]) == sorted(truth[name]["signs"] + small)
        assert np.linalg.norm(np.subtract(located["position_m"], truth[name]["camera_position"])) < 0.03
        assert np.array(located["covariance_xyz_rpy"]).shape == (6, 6)
    # a map of a sign not in view: null, and the table says so
    elsewhere = tmp_path / "map.yaml"
    elsewhere.write_text("frame: building\nsigns:\n  - {id: emergency_exit, position_m: [0, 0, 0], "
                         "orientation_wxyz: [1, 0, 0, 0]}\n")
    common = ("--library", SURVEY / "library", "--camera", SURVEY / "camera.yaml", "--map", elsewhere)
    obj = json.loads(signpose("recognize", SURVEY / names[1], *common, "--json").stdout)
    assert obj["signs"] and obj["camera_in_map"] is None
    table = signpose("recognize", SURVEY / names[0], *common)
    assert table.returncode == 0 and "  and " in table.stdout and "in building: no mapped sign in view" in table.stdout


@pytest.mark.parametrize("content, message", [
    ("signs: []", "signs must be a list of at least one sign"),
    ("signs:\n  - {id: nowhere, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0]}",
     "signs[0].id: 'nowhere' is not a sign of the library"),
])
def test_a_bad_map_file_is_one_clear_line_before_any_image(tmp_path, content, message):
    path = tmp_path / "map.yaml"
    path.write_text(content)
    for command in ("recognize", "track", "evaluate"):
        result = signpose(command, SCENES / "scene_000.jpg" if command != "evaluate" else SCENES, "--map", path)
        assert result.returncode == 2 and result.stdout == "", (command, result.stderr)
        assert result.stderr.splitlines() == [f"signpose {command}: error: {path}: {message}, which has "
                                              "chief_of_security, ministry_of_torture, security_compound"
                                              if "library" in message else f"signpose {command}: error: {path}: {message}"]


@pytest.mark.slow
def test_bad_files_get_an_error_line_and_the_rest_still_run(tmp_path):
    good = SCENES / "scene_002.jpg"  # a sign: the pose, and so the note on it, is there
    fake = tmp_path / "notes.jpg"
    fake.write_text("this is not a jpeg")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    result = signpose("recognize", fake, good, empty, tmp_path / "missing.jpg", "--json")
    assert result.returncode != 0
    objs = [json.loads(line) for line in result.stdout.splitlines()]
    assert [("error" in o) for o in objs] == [True, False, True, True]
    assert "not an image file" in objs[0]["error"] and "empty" in objs[2]["error"]  # as the server says
    check_schema(objs[1])
    # no --camera: the assumed FOV is said, once, in the server's words
    assert objs[1]["warnings"].count("no camera set and no usable EXIF focal length: assumed 60° horizontal field of "
                                     "view, so the pose is approximate") == 1
    no_sign = json.loads(signpose("recognize", SCENES / "scene_000.jpg", "--json").stdout)
    assert no_sign["pose"] is None and not any("approximate" in w for w in no_sign["warnings"])
    table = signpose("recognize", fake, good)
    assert table.returncode != 0 and good.name in table.stdout
    error_row = next(line for line in table.stdout.splitlines() if "error" in line)
    assert error_row.split() == ["notes.jpg", "error:", "not", "an", "image", "file", "(use", "JPEG,", "PNG,",
                                 "TIFF,", "WebP,", "BMP", "or", "GIF)"]  # named once, by its file name as the other rows


def test_a_failure_inside_the_pipeline_is_that_images_error_line(fail_first_segmentation, capsys):
    # fail_first_segmentation patched this process: main() runs here
    names = [SCENES / "scene_002.jpg", SCENES / "scene_004.jpg"]
    assert main(["recognize", *map(str, names), "--json"]) == 1
    failed, recognised = map(json.loads, capsys.readouterr().out.splitlines())
    assert failed["image"] == str(names[0]) and "pipeline failed on" in failed["error"]
    assert "simulated defect" in failed["error"] and recognised["label"] == "chief_of_security"


def test_images_over_the_pixel_limit_are_refused_from_their_header(tmp_path):
    good = SCENES / "scene_002.jpg"  # 640 x 480
    huge = tmp_path / "huge.png"
    huge.write_bytes(png_bomb())  # 20000 x 20000 in a few hundred bytes: decoded, gigabytes
    result = signpose("recognize", huge, good, "--json")
    assert result.returncode == 1
    refused, recognised = map(json.loads, result.stdout.splitlines())
    # past Pillow's ceiling, it said neither the size nor what --max-megapixels can do
    assert refused["image"] == str(huge) and refused["error"] == (
        f"{huge}: 20000x20000 px is 400.0 megapixels, more than the 179 that can be read at any --max-megapixels; "
        "downscale it")
    check_schema(recognised)
    table = signpose("recognize", good, "--max-megapixels", 0.2)
    assert table.returncode == 1 and "640x480 px is 0.3 megapixels, more than the limit of 0.2" in table.stdout


def test_evaluate_and_calibrate_refuse_images_over_the_pixel_limit(tmp_path):
    (tmp_path / "none").mkdir()
    big = tmp_path / "none" / "big.png"
    big.write_bytes(png_bomb(3000, 2000))
    result = signpose("evaluate", tmp_path, "--max-megapixels", 5, "--workers", 1)
    assert result.returncode == 1 and "1 of 1 image(s) could not be used" in result.stderr  # as recognize says
    assert "big.png: 3000x2000 px is 6.0 megapixels, more than the limit of 5" in result.stdout
    result = signpose("calibrate", big, "--board", "9x6", "--square", 0.03, "-o", tmp_path / "c.yaml",
                      "--max-megapixels", 5)
    assert result.returncode == 2
    assert "big.png: 3000x2000 px is 6.0 megapixels, more than the limit of 5" in result.stderr


def test_a_truncated_image_gets_signposes_line_and_not_opencvs_warning(tmp_path):
    truncated = tmp_path / "cut.png"
    truncated.write_bytes(cv2.imencode(".png", cv2.imread(str(SCENES / "scene_002.jpg")))[1].tobytes()[:5000])
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "cut.png").write_bytes(truncated.read_bytes())
    for args in (("recognize", truncated), ("evaluate", tmp_path, "--workers", 1)):
        result = signpose_process(*args)
        out = result.stdout
        assert "cut.png" in out and "damaged or truncated PNG file" in out and "WARN" not in result.stderr, result.stderr


def test_decoders_say_nothing_on_the_terminal_of_an_image_signpose_refuses(tmp_path):
    """libjpeg's "Corrupt JPEG data: premature end of data segment" and OpenCV's "[ERROR:0@1.6] ... imdecode_" of a
    float TIFF were printed among the table's rows; each image has signpose's own line."""
    photo = bytearray((SCENES / "scene_002.jpg").read_bytes())
    photo[5000:25000] = bytes(20000)  # zeros over its data: libjpeg runs out and warns
    (tmp_path / "zeroed.jpg").write_bytes(photo)
    Image.fromarray(np.full((48, 64), 0.5, np.float32)).save(tmp_path / "float.tiff")  # OpenCV fails, and logs it
    result = signpose_process("recognize", tmp_path / "zeroed.jpg", tmp_path / "float.tiff", SCENES / "scene_002.jpg",
                              "--camera", SCENES / "camera.yaml")
    rows = result.stdout.splitlines()
    assert [row.split()[0] for row in rows] == ["image", "zeroed.jpg", "float.tiff", "scene_002.jpg"], rows
    assert "damaged JPEG file" in rows[1] and "float32 samples" in rows[2]
    assert result.stderr == "2 of 3 image(s) could not be used\n"


def test_a_damaged_jpeg_is_told_apart_from_a_file_that_is_no_image(tmp_path):
    photo = (SCENES / "scene_002.jpg").read_bytes()
    cases = {"header_cut.jpg": photo[:300],          # cut inside its header: not even its size can be read
             "data_cut.jpg": photo[:len(photo) // 2],  # a whole header, half the image data
             "notes.jpg": b"meeting at 10, bring the photos"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    result = signpose("recognize", *(tmp_path / name for name in cases), "--json")
    assert result.returncode == 1
    errors = {Path(o["image"]).name: o["error"] for o in map(json.loads, result.stdout.splitlines())}
    assert errors["header_cut.jpg"] == (f"{tmp_path / 'header_cut.jpg'}: damaged or truncated JPEG file (it begins "
                                        "as a JPEG but its image data cannot be read); copy or export it again")
    assert errors["data_cut.jpg"] == (f"{tmp_path / 'data_cut.jpg'}: damaged or truncated JPEG file (it ends inside "
                                      "its image data: cut short); copy or export it again")
    assert errors["notes.jpg"] == f"{tmp_path / 'notes.jpg'}: not an image file (use JPEG, PNG, TIFF, WebP, BMP or GIF)"


@pytest.mark.parametrize("option, content, message", [
    ("--settings", '{"threshold": 2}', "threshold must be between"),
    ("--settings", '{"colour": 1}', "unknown setting"),
    ("--camera", '{"fx": 0, "fy": 1, "cx": 1, "cy": 1}', "positive"),
])
def test_bad_settings_and_camera_files_are_one_clear_line(tmp_path, option, content, message):
    path = tmp_path / "file.json"
    path.write_text(content)
    result = signpose("recognize", sorted(SCENES.glob("*.jpg"))[0], option, path)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr


DEEP = 100_000  # levels of nesting: far past Python's stack, and OpenCV's parser's (from 20,000 to 40,000)


@pytest.mark.parametrize("option, name, content, message", [
    ("--camera", "deep.yaml", "k: " + "[" * DEEP + "]" * DEEP,
     "{path}: line 1, column 23: values nested more than 20 levels deep"),
    ("--camera", "deep.xml", '<?xml version="1.0"?>\n<opencv_storage>\n' + "<a>" * DEEP + "</a>" * DEEP
     + "\n</opencv_storage>\n", "{path}: values nested more than 20 levels deep"),
    ("--camera", "dashes.yaml", "%YAML:1.0\n---\nk:\n  " + "- " * DEEP + "1\n",
     "{path}: values nested more than 20 levels deep"),
    ("--settings", "deep.json", '{"a": ' * DEEP + "1" + "}" * DEEP, "settings file {path} is JSON nested too deep"),
], ids=["yaml", "opencv xml", "opencv yaml", "settings"])
def test_a_file_nested_deeper_than_any_is_one_line_naming_it(tmp_path, option, name, content, message):
    """A RecursionError's traceback, or a segmentation fault (exit -11) in OpenCV's FileStorage parser."""
    path = tmp_path / name
    path.write_text(content)
    result = signpose("recognize", sorted(SCENES.glob("*.jpg"))[0], option, path)
    assert result.returncode == 2, result.stderr[-300:]
    assert result.stderr.splitlines()[-1].startswith("signpose recognize: error: " + message.format(path=path))
    assert "Traceback" not in result.stderr


def test_a_camera_info_of_part_of_the_sensor_gives_the_true_pose(tmp_path):
    """`ros2 topic echo` of a 1280x960 sensor read out 640x480 from (320, 240): scene_002 exactly. Its roi
    was ignored and its K scaled by 0.5, and the camera was put at (0.429, 0.13, -0.86)."""
    camera = tmp_path / "camera_info.yaml"
    camera.write_text("""header:
  stamp:
    sec: 0
    nanosec: 0
  frame_id: camera
height: 960
width: 1280
distortion_model: plumb_bob
d: [0.0, 0.0, 0.0, 0.0, 0.0]
k: [554.2562584220408, 0.0, 640.0, 0.0, 554.2562584220408, 480.0, 0.0, 0.0, 1.0]
r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
p: [554.2562584220408, 0.0, 640.0, 0.0, 0.0, 554.2562584220408, 480.0, 0.0, 0.0, 0.0, 1.0, 0.0]
binning_x: 0
binning_y: 0
roi:
  x_offset: 320
  y_offset: 240
  height: 480
  width: 640
  do_rectify: false
---
""")
    result = signpose("recognize", SCENES / "scene_002.jpg", "--camera", camera, "--json")
    assert result.returncode == 0, result.stderr
    obj = json.loads(result.stdout)
    truth = json.loads((SCENES / "truth.json").read_text())["images"]["scene_002.jpg"]
    R, t = np.array(truth["R"]), np.array(truth["t"])
    assert np.linalg.norm(np.array(obj["pose"]["camera_position"]) + R.T @ t) < 0.005
    assert obj["warnings"] == []  # no scaling


def test_a_camera_without_size_whose_principal_point_is_off_the_image_fails_it(tmp_path):
    """A phone's calibration (4032x3024) without its size gave this 640x480 sample a pose 9 m off, with a
    warning; its numbers cannot describe this image."""
    camera = tmp_path / "phone.json"
    camera.write_text('{"fx": 3000, "fy": 3000, "cx": 2016, "cy": 1512}')
    result = signpose("recognize", SCENES / "scene_002.jpg", "--camera", camera, "--json")
    assert result.returncode == 1, result.stdout
    line = json.loads(result.stdout)
    assert line["error"].startswith("the camera has no image size and its principal point (2016, 1512) px lies "
                                    "outside this 640x480 px image")
    assert "4032x3024" in line["error"]


@pytest.mark.slow
def test_the_assumed_field_of_view_is_the_pages(tmp_path):
    """The page's assumed FOV had no counterpart in the CLI (always 60°): a photo without a camera file or EXIF
    could not give in the CLI what it gave in the page."""
    scene = SCENES / "scene_002.jpg"
    obj = json.loads(signpose("recognize", scene, "--assumed-fov", "65", "--json").stdout)
    image = cv2.imread(str(scene))
    expected = recognize(image, load_library(), preset("default"), assumed_camera(640, 480, 65.0))
    assert obj["pose"]["t"] == pytest.approx(expected.pose.t.tolist(), abs=1e-9)
    assert obj["warnings"] == expected.warnings and "assumed 65° horizontal field of view" in obj["warnings"][-1]
    for typed in ("170", "-0"):  # as typed: -0 was said as "got -0.0", over the API as "got 0.0"
        refused = signpose("recognize", scene, "--assumed-fov", typed)
        assert refused.returncode == 2, refused.stderr
        assert refused.stderr.endswith(f"the horizontal field of view must be 10° to 140°; got {typed}\n")


def test_whole_numbers_written_as_floats_in_a_settings_file_work(tmp_path):
    path = tmp_path / "settings.json"
    path.write_text('{"candidates": 2.0, "seed": 1.0, "ransac_iterations": 100.0}')
    result = signpose("recognize", SCENES / "scene_002.jpg", "--settings", path, "--json")
    assert result.returncode == 0, result.stderr
    check_schema(json.loads(result.stdout))


@pytest.mark.parametrize("sign_id, message", [
    ("../x", "id '../x' must be 1-64 characters"),
    ("none", "id 'none' is reserved for images without a sign"),  # else "truth none, answer none" was wrong
    ('a", "heigth_m": "0.5', "sign #0: unknown key(s) 'heigth_m': correct or remove them"),  # was dropped unsaid
])
def test_bad_library_is_a_clear_error(tmp_path, sign_id, message):
    (tmp_path / "library.json").write_text(f'{{"signs": [{{"id": "{sign_id}", "image": "a.png", "width_m": 0.6}}]}}')
    result = signpose("recognize", sorted(SCENES.glob("*.jpg"))[0], "--library", tmp_path)
    assert result.returncode == 2 and message in result.stderr


def test_a_library_drawn_on_a_transparent_ground_reads_as_signs_on_white(tmp_path):
    """A library folder's artwork with a transparent ground was read black on black and refused
    as blank, though the server's library dialog took the same file."""
    library = tmp_path / "library"
    shutil.copytree(ROOT / "sample_images" / "library", library)
    sign = cv2.imread(str(library / "security_compound.png"), cv2.IMREAD_GRAYSCALE)
    ink = cv2.merge([0 * sign, 0 * sign, 0 * sign, 255 - sign])  # only the ink is opaque
    cv2.imwrite(str(library / "security_compound.png"), ink)
    result = signpose("recognize", SCENES / "scene_002.jpg", "--library", library, "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["label"] == "security_compound"


def test_readable_table(tmp_path):
    result = signpose("recognize", *sorted(SCENES.glob("*.jpg"))[:3], "--camera", SCENES / "camera.yaml")
    assert result.returncode == 0
    assert result.stdout.splitlines()[0].split()[:4] == ["image", "label", "inliers", "margin"]


def test_the_table_gives_the_plaque_fallbacks_answer_as_the_json_does():
    scene = ROOT / "sample_images" / "datasets" / "set2" / "scene_007.jpg"  # features fail, the plaque does not
    obj = json.loads(signpose("recognize", scene, "--json").stdout)
    assert obj["recognized"] and obj["pose"] is not None
    row = signpose("recognize", scene).stdout.splitlines()[1]
    assert row.split()[:4] == [scene.name, obj["label"], "-", "-"]
    x, y, z = obj["pose"]["camera_position"]
    assert "by plaque (correlation" in row and f"cam at ({x:+.2f}, {y:+.2f}, {z:+.2f}) m" in row
    assert "no sign" not in row


def test_exif_focal_length_is_used_without_a_camera_file(tmp_path):
    src = SCENES / json.loads((SCENES / "truth.json").read_text())["camera"]
    assert src.exists()
    scene = next(n for n, t in json.loads((SCENES / "truth.json").read_text())["images"].items() if t["label"])
    exif = Image.Exif()
    exif[0x8769] = {0x920A: 4.0, 0xA405: 28}  # Exif IFD: FocalLength 4 mm, 35 mm equivalent 28 mm
    path = tmp_path / "with_exif.jpg"
    Image.open(SCENES / scene).save(path, exif=exif, quality=95)
    obj = json.loads(signpose("recognize", path, "--json").stdout)
    assert any("EXIF" in w for w in obj["warnings"]) and not any("assumed" in w for w in obj["warnings"])


def test_an_implausible_exif_focal_length_is_said_where_the_field_of_view_is_assumed(tmp_path):
    scene = SCENES / "scene_002.jpg"  # a sign: the pose, and so the note on it, is there
    for focal_35mm in (0, 65535):  # what cameras write when they do not know it
        exif = Image.Exif()
        exif[0x8769] = {0xA405: focal_35mm}  # Exif IFD: FocalLengthIn35mmFilm
        Image.open(scene).save(tmp_path / f"f{focal_35mm}.jpg", exif=exif, quality=95)
    result = signpose("recognize", tmp_path / "f0.jpg", tmp_path / "f65535.jpg", "--json")
    assert result.returncode == 0, result.stderr
    for focal_35mm, obj in zip((0, 65535), map(json.loads, result.stdout.splitlines())):
        assumed = [w for w in obj["warnings"] if "assumed 60° horizontal field of view" in w]
        assert len(assumed) == 1 and obj["pose"] is not None
        assert (f"(the photo's EXIF 35 mm-equivalent focal length of {focal_35mm} mm is implausible and was ignored)"
                in assumed[0])


def on_a_terminal(*args: object, cwd=ROOT, stdout_too: bool = False) -> tuple[subprocess.Popen, int]:
    """`signpose *args` with its stderr on a pseudo-terminal, as in a shell: the process (stdout
    piped, or on the terminal too when `stdout_too`) and the terminal's end to read from (`terminal_output`)."""
    terminal, stderr = pty.openpty()
    fcntl.ioctl(stderr, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 24 x 100 (new ones are 0 x 0)
    # stdout into a file, not a pipe: a test reading the terminal to its end first would wait forever
    # on a command blocked writing more than a pipe holds (64 KB).
    written = None if stdout_too else tempfile.TemporaryFile("w+")
    proc = subprocess.Popen([sys.executable, "-m", "signpose.app.cli", *map(str, args)], cwd=cwd,
                            stdout=stderr if stdout_too else written, stderr=stderr, text=True,
                            start_new_session=True)
    proc.written = written  # type: ignore[attr-defined]
    os.close(stderr)
    return proc, terminal


def stdout_of(proc: subprocess.Popen, timeout: float = 300) -> str:
    """What an `on_a_terminal` command wrote on its stdout, once it has ended."""
    proc.wait(timeout=timeout)
    proc.written.seek(0)  # type: ignore[attr-defined]
    return proc.written.read()  # type: ignore[attr-defined]


def terminal_output(terminal: int) -> str:
    """What is left to read on an `on_a_terminal` terminal, until the process has closed it."""
    out = b""
    try:
        while chunk := os.read(terminal, 65536):
            out += chunk
    except OSError:  # EIO: the other end is closed
        pass
    os.close(terminal)
    return out.decode()


def test_evaluate_json_has_every_images_answer_against_the_truth(tmp_path):
    data = tmp_path / "set"
    shutil.copytree(ROOT / "sample_images" / "datasets" / "set3", data)
    truth = json.loads((data / "truth.json").read_text())
    truth["images"]["broken.jpg"] = {"label": None}
    (data / "truth.json").write_text(json.dumps(truth))
    (data / "broken.jpg").write_bytes(b"not a jpeg")
    result = signpose("evaluate", data, "--workers", 1, "--json")
    assert result.returncode == 1  # as the table: an unusable image
    report = json.loads(result.stdout)  # one document, no table around it
    images = {Path(i["image"]).name: i for i in report["images"]}
    assert len(images) == report["total"]["images"] == 6
    assert sum(map(sum, report["confusion"])) == 5  # the unreadable image has no answer to count
    assert images["broken.jpg"]["answer"] is None and "not an image file" in images["broken.jpg"]["error"]
    for entry in images.values():
        assert entry["correct"] == (entry["error"] is None and entry["answer"] == entry["truth"])
        if entry["correct"] and entry["truth"] != "none" and entry["rotation_error_deg"] is not None:
            assert entry["rotation_error_deg"] < 1.0
    assert report["total"]["correct"] == sum(e["correct"] for e in images.values())
    assert report["labels"][-1] == "none" and report["settings"]["ratio"] == 0.75


def test_evaluate_with_a_map_measures_the_camera_in_the_map_frame_on_a_survey_and_says_where_it_is_not_used(tmp_path):
    survey = tmp_path / "room"
    survey.mkdir()
    photos = json.loads((SURVEY / "truth.json").read_text())["photos"][1:4]  # one sign, then two
    for name in ("camera.yaml", *(p["image"] for p in photos)):
        shutil.copy(SURVEY / name, survey / name)
    (survey / "truth.json").write_text(json.dumps({"photos": photos}))
    common = ("--map", SURVEY / "truth_map.yaml", "--library", SURVEY / "library", "--workers", 1)
    result = signpose("evaluate", survey, ROOT / "sample_images" / "datasets" / "set3", *common, "--json")
    assert result.returncode == 0, result.stderr
    assert "the map is not used for set3: no camera poses in the map frame" in result.stderr
    report = json.loads(result.stdout)
    assert report["total"]["images"] == 5 and set(report["camera_in_map"]) == {"room"}
    room = report["camera_in_map"]["room"]
    assert room["photos"] == room["located"] == 3
    assert room["position_error_m"]["median"] < 0.03 and room["rotation_error_deg"]["median"] < 0.5
    table = signpose("evaluate", survey, *common)
    assert table.returncode == 0, table.stderr
    assert table.stdout.splitlines()[:3] == ["camera in the map frame (map)",
                                              "survey           photos located      position med/p90   rotation med/p90",
                                              "-" * 72]


@pytest.mark.slow
def test_synth_then_evaluate_report_with_progress_bars_on_a_terminal_only(tmp_path):
    data = tmp_path / "scenes"
    made = signpose("synth", "--n", 4, "--seed", 3, data)
    assert made.returncode == 0 and len(list(data.glob("*.jpg"))) == 4 and (data / "truth.json").is_file()
    assert made.stderr == "" and made.stdout.startswith("wrote 4 scenes")
    # Into a log (here a pipe): no bar and its carriage-return redraws, the table all the same.
    result = signpose_process("evaluate", data, "--workers", 2)
    assert result.returncode == 0
    assert result.stderr == ""
    row = next(line.split() for line in result.stdout.splitlines() if line.startswith("scenes "))
    assert row[1] == "4" and int(row[2]) >= 3  # images, correct
    proc, terminal = on_a_terminal("evaluate", data, "--workers", 2)
    out = stdout_of(proc)
    assert proc.returncode == 0 and "4/4" in terminal_output(terminal)  # the progress bar reached the end
    assert any(line.startswith("scenes ") for line in out.splitlines())


def test_synth_refuses_a_folder_with_older_scenes_it_would_leave_unlisted(tmp_path):
    old = [tmp_path / f"scene_{i:03d}.jpg" for i in range(4)]
    for path in old:
        path.write_bytes(b"an earlier run's scene")
    result = signpose("synth", "--n", 2, tmp_path)
    assert result.returncode == 2
    assert result.stderr == (f"signpose synth: error: {tmp_path} already holds 2 scene file(s) that truth.json would "
                             "not list (scene_002.jpg, scene_003.jpg); pick an empty folder or remove them\n")
    assert all(path.read_bytes() == b"an earlier run's scene" for path in old)
    assert not (tmp_path / "truth.json").exists()


@pytest.mark.parametrize("args, message", [
    (("synth", "--n", 0, "{tmp}/out"), "--n: '0' is not a whole number of at least 1"),
    (("synth", "--n", 2, "{tmp}/file"), "cannot write into {tmp}/file: File exists"),
    (("evaluate", ROOT / "sample_images" / "datasets" / "set3", "--workers", "two"), "--workers: 'two'"),
    (("evaluate", "{tmp}/file"), "file is not a folder"),
    (("evaluate", "{tmp}/labelled"), "label(s) 'bogus' are not in the library"),
    (("evaluate", "{tmp}/labelled", "{tmp}/../{tmp.name}/labelled"), "a dataset folder is given twice"),
])
def test_bad_synth_and_evaluate_arguments_are_one_clear_line(tmp_path, args, message):
    (tmp_path / "file").write_text("not a dataset")
    (tmp_path / "labelled" / "bogus").mkdir(parents=True)
    shutil.copy(SCENES / "scene_004.jpg", tmp_path / "labelled" / "bogus")
    result = signpose(*(str(a).format(tmp=tmp_path) for a in args))
    assert result.returncode == 2
    assert message.format(tmp=tmp_path) in result.stderr and "Traceback" not in result.stderr


def test_evaluate_refuses_a_dataset_whose_named_camera_is_missing(tmp_path):
    """It was ignored: the table came out, the poses measured under an assumed 60° field of view."""
    shutil.copy(SCENES / "scene_000.jpg", tmp_path)
    (tmp_path / "truth.json").write_text(json.dumps(
        {"camera": "cam_missing.yaml", "images": {"scene_000.jpg": {"label": "security_compound"}}}))
    result = signpose("evaluate", tmp_path, "--workers", 1)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == (f'signpose evaluate: error: {tmp_path / "truth.json"}: the "camera" file '
                             f"'cam_missing.yaml' is not a file in {tmp_path}; put the camera file there, "
                             'or remove "camera" from truth.json\n')


@pytest.mark.parametrize("args, message", [
    (("recognize", "{tmp}/missing.jpg", "--camera", "{tmp}"), "--camera: '{tmp}' is a folder, not a file"),
    (("recognize", "{tmp}/missing.jpg", "--settings", "{tmp}"), "--settings: '{tmp}' is a folder, not a file"),
    (("evaluate", "{tmp}/missing", "--settings", "{tmp}"), "--settings: '{tmp}' is a folder, not a file"),
    (("serve", "--state-dir", "{tmp}/state", "--settings", "{tmp}"), "--settings: '{tmp}' is a folder, not a file"),
    (("serve", "--state-dir", "{tmp}/state", "--port", 70000), "--port: '70000' is not a whole number from 0 to 65535"),
    (("serve", "--state-dir", "{tmp}/state", "--port", -1), "--port: '-1' is not a whole number from 0 to 65535"),
    (("synth", "{tmp}/out", "--seed", -1), "--seed: '-1' is not a whole number of at least 0"),
    # Refused before reading any photo: the missing one is never mentioned.
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", 0.03, "-o", "{tmp}/no/such/c.yaml"),
     "-o/--output: folder '{tmp}/no/such' does not exist"),
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", 0.03, "-o", "{tmp}"),
     "-o/--output: '{tmp}' is a folder, not a file"),
    # sysfs takes no new files, even from root: as a read-only file system, refused before the calibration
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", 0.03, "-o", "/sys/c.yaml"),
     "-o/--output: cannot write into folder '/sys'"),
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", 0, "-o", "{tmp}/c.yaml"),
     "square size must be a positive number"),
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", "nan", "-o", "{tmp}/c.yaml"),
     "square size must be a positive number"),
    (("calibrate", "{tmp}/missing.png", "--board", "9x6", "--square", 30, "-o", "{tmp}/c.yaml"),
     "square size 30 m is no chessboard's: it is in metres (0.025 for 25 mm)"),
])
def test_bad_paths_ports_and_numbers_are_refused_up_front_in_one_line(tmp_path, args, message):
    result = signpose(*(str(a).format(tmp=tmp_path) for a in args))
    assert result.returncode == 2, result.stderr
    # one line: argparse's own errors came below 3 to 5 lines of the command's usage
    assert len(result.stderr.splitlines()) == 1 and message.format(tmp=tmp_path) in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and "missing" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no state, scenes or camera file made


def test_serve_refuses_a_bad_map_file_in_one_line_as_a_bad_camera(tmp_path):
    bad = tmp_path / "map.yaml"
    bad.write_text("signs:\n  - id: archives\n    position_m: [0, 0, 0]\n    orientation_wxyz: [1, 0, 0, 0]\n")
    result = signpose_process("serve", "--port", 0, "--state-dir", tmp_path / "state", "--library",
                              shutil.copytree(load_library().root, tmp_path / "library"), "--map", bad)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == (f"signpose serve: error: {bad}: signs[0].id: 'archives' is not a sign of the library, "
                             "which has chief_of_security, ministry_of_torture, security_compound\n")


def evaluate_under_way(tmp_path: Path) -> tuple[subprocess.Popen, int]:
    """`signpose evaluate` of 200 images on 2 worker processes, as `on_a_terminal` gives it, once its progress
    bar has passed 20 images: the workers are measuring."""
    copies = [shutil.copytree(ROOT / "sample_images" / "datasets" / "set3", tmp_path / f"set{i}") for i in range(40)]
    proc, terminal = on_a_terminal("evaluate", *copies, "--workers", "2")
    progress = ""
    while not re.search(r"\| *([2-9]\d|1\d\d)/200 ", progress):
        char = os.read(terminal, 1).decode(errors="replace")
        assert char, f"evaluate ended before its progress bar moved: {progress}"
        progress += char
    return proc, terminal


def children(pid: int) -> list[int]:
    """The processes whose parent is process `pid` (read from /proc: the tests do without psutil)."""
    return [int(entry.name) for entry in Path("/proc").iterdir()
            if entry.name.isdigit() and (fields := process_status(int(entry.name))) and int(fields[1]) == pid]


def process_status(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state, parent, ...), None once the process is gone."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rpartition(")")[2].split()
    except OSError:
        return None


def left_running(pids: list[int], within_s: float = 5.0) -> list[int]:
    """Those of processes `pids` still running after `within_s` seconds (a zombie, ended but not yet reaped, is not),
    killed so that a failing test leaves none behind."""
    deadline = time.monotonic() + within_s
    while (running := [p for p in pids if (process_status(p) or ["Z"])[0] != "Z"]) and time.monotonic() < deadline:
        time.sleep(0.1)
    for pid in running:
        os.kill(pid, signal.SIGKILL)
    return running


@pytest.mark.slow
def test_ctrl_c_stops_evaluate_and_its_workers_with_one_line(tmp_path):
    proc, terminal = evaluate_under_way(tmp_path)
    # Ctrl-C in a terminal reaches the whole process group: the CLI and its worker processes.
    os.killpg(proc.pid, signal.SIGINT)
    proc.wait(timeout=30)
    err = terminal_output(terminal)
    assert proc.returncode == 130
    assert re.search(r"signpose evaluate: interrupted after \d+ of 200 images", err) and "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_or_sighup_stop_evaluate_and_its_workers_as_ctrl_c_does(tmp_path, signum):
    """`kill PID` (SIGTERM) reaches the CLI alone: it ended at once, and its worker went on measuring,
    then waited forever to send results nobody read, holding its memory. SIGHUP, the terminal closing,
    is stopped the same way."""
    proc, terminal = evaluate_under_way(tmp_path)
    helpers = children(proc.pid)  # the worker and multiprocessing's resource tracker
    assert len(helpers) == 2
    os.kill(proc.pid, signum)
    proc.wait(timeout=30)
    assert left_running(helpers) == []
    out = stdout_of(proc, 30)
    err = terminal_output(terminal)
    assert proc.returncode == 128 + signum
    said = re.search(rf"signpose evaluate: stopped by {signal.Signals(signum).name} after (\d+) of 200 images", err)
    assert said and "Traceback" not in err, err
    # What was measured, labelled as such: rows for the datasets reached and their total.
    assert out.startswith(f"partial results: the first {said[1]} of 200 images\n")
    assert next(line.split() for line in out.splitlines() if line.startswith("all "))[1] == said[1]
    assert "nan" not in out


@pytest.mark.slow
def test_evaluates_worker_ends_with_it_when_it_is_killed_outright(tmp_path):
    """SIGKILL (or the out-of-memory killer) leaves the CLI no way to stop its workers: they notice."""
    proc, terminal = evaluate_under_way(tmp_path)
    helpers = children(proc.pid)
    proc.kill()
    proc.wait(timeout=30)
    assert left_running(helpers) == []
    os.close(terminal)


@pytest.mark.slow
def test_sigterm_stops_recognize_between_whole_json_lines_and_says_how_many():
    images = sorted(SCENES.glob("*.jpg")) * 4
    proc = subprocess.Popen([sys.executable, "-m", "signpose.app.cli", "recognize", *images, "--json"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    # Sent while an image is being measured: in the microseconds after a line, whether it counts is a toss-up.
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    rest, err = proc.communicate(timeout=60)
    lines = [first, *rest.splitlines()]
    assert [json.loads(line)["image"] for line in lines] == list(map(str, images[:len(lines)]))
    assert proc.returncode == 143 and "Traceback" not in err
    assert err.splitlines()[-1] == f"signpose recognize: stopped by SIGTERM after {len(lines)} of {len(images)} images"


@pytest.mark.slow
def test_a_sweep_of_a_whole_number_setting_says_when_its_steps_give_fewer_values():
    """Three steps of min_inliers from 8 to 9 ran two values without a word."""
    run = signpose("sweep", "min_inliers", "--lo", "8", "--hi", "9", "--steps", "3",
                   ROOT / "sample_images" / "datasets" / "set3")
    assert run.returncode == 0, run.stderr
    assert "note: min_inliers takes whole numbers: 3 steps from 8 to 9 give 2 values" in run.stderr


def test_recognize_rows_tell_apart_images_of_one_name(tmp_path):
    """Rows named by the file's name alone read `scene_002.jpg` twice for set1/ and set2/'s."""
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        shutil.copy(SCENES / "scene_002.jpg", tmp_path / folder)
    run = signpose("recognize", tmp_path / "a" / "scene_002.jpg", tmp_path / "b" / "scene_002.jpg")
    rows = run.stdout.splitlines()[1:]
    assert run.returncode == 0 and rows[0].split()[0] != rows[1].split()[0], run.stdout
    run = signpose("recognize", SCENES / "scene_002.jpg", SCENES / "scene_007.jpg")
    assert [row.split()[0] for row in run.stdout.splitlines()[1:] if not row.startswith(" ")] == ["scene_002.jpg",
                                                                                                 "scene_007.jpg"]


def test_recognize_json_draws_its_progress_bar_between_whole_lines():
    """`recognize --json > out.jsonl` drew no bar; and a line printed while the bar was drawn on the same
    terminal began at the bar's end, in the table as in the JSON."""
    images = sorted(SCENES.glob("*.jpg"))[:12]
    proc, terminal = on_a_terminal("recognize", *images, "--json")
    bar = terminal_output(terminal)  # read as it comes: a terminal nobody reads fills up, and its writer waits
    assert len(stdout_of(proc).splitlines()) == 12 and "/12 [" in bar
    proc, terminal = on_a_terminal("recognize", *images, "--json", stdout_too=True)
    # What is left of each terminal line: what was written after its last carriage return.
    shown = [line.rpartition("\r")[2] for line in terminal_output(terminal).split("\r\n")]
    assert proc.wait(timeout=300) == 0
    assert [json.loads(line)["image"] for line in shown if line.startswith("{")] == list(map(str, images))


def test_recognize_refuses_a_named_pipe_without_waiting_for_a_writer(tmp_path):
    fifo = tmp_path / "photo.jpg"
    os.mkfifo(fifo)
    result = subprocess.run([sys.executable, "-m", "signpose.app.cli", "recognize", fifo, SCENES / "scene_002.jpg", "--json"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    refused, recognised = map(json.loads, result.stdout.splitlines())
    assert refused == {"image": str(fifo), "error": f"{fifo}: is a named pipe (FIFO), not a regular file"}
    assert recognised["recognized"]


def console_script() -> list[str]:
    """The `signpose` command as pip's console-script wrapper runs it: pyproject.toml's entry point."""
    target = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]["signpose"]
    module, function = target.split(":")
    return [sys.executable, "-c", f"import sys; from {module} import {function}; sys.exit({function}())"]


@pytest.mark.parametrize("signum, said", [(signal.SIGINT, "interrupted"), (signal.SIGTERM, "stopped by SIGTERM")])
def test_a_signal_while_the_command_is_still_starting_is_one_line_and_128_plus_it(signum, said):
    # -X importtime writes a line to stderr as each module finishes importing: once numpy has, the
    # CLI's imports (OpenCV, FastAPI, the pipeline) are under way. Its stderr is a pipe of one page,
    # left unread until the signal is sent: the command cannot finish its imports before it comes
    # (a test process kept waiting by a busy machine saw every image done, exit status 0).
    images = sorted(SCENES.glob("*.jpg"))
    command = [sys.executable, "-X", "importtime", *console_script()[1:], "recognize", *images]
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=write_end)
    os.close(write_end)
    with os.fdopen(read_end, encoding="utf-8") as stderr:
        for line in stderr:
            if line.split("|")[-1].strip() == "numpy":
                break
        else:
            raise AssertionError("numpy was never imported")
        proc.send_signal(signum)
        err = stderr.read()
    proc.wait(timeout=60)
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and "Interrupted" not in err
    assert re.fullmatch(rf"signpose( recognize)?: {said}( after \d+ of {len(images)} images)?", err.splitlines()[-1])


def test_a_signal_while_a_c_extension_loads_is_one_line_and_128_plus_it(monkeypatch, capsys):
    """SIGTERM while gtsam loads (`map build` imports it): its module init turned the interruption into
    ImportError("initialization failed"), and the command ended with exit 1 and a traceback."""
    import signpose.app.cli as cli
    from signpose.app.entry import Interrupted, main as console_main

    def loading_gtsam(argv=None):
        try:
            raise Interrupted(signal.SIGTERM)
        except Interrupted as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(cli, "main", loading_gtsam)
    assert console_main() == 128 + signal.SIGTERM
    assert capsys.readouterr().err == "signpose: stopped by SIGTERM\n"
    monkeypatch.setattr(cli, "main", lambda argv=None: __import__("no_such_module_of_signpose"))
    with pytest.raises(ImportError, match="no_such_module_of_signpose"):   # not an interruption: as it was
        console_main()


def test_a_ctrl_c_dropped_while_the_command_imports_still_stops_it(monkeypatch, capsys):
    """A C extension initialising clears the errors of the Python it calls: a Ctrl-C raised there was lost, and
    the command ran to its end with exit status 0."""
    from signpose.app.entry import main as console_main

    def importing(name):
        with contextlib.suppress(KeyboardInterrupt):   # as the extension's init does
            signal.raise_signal(signal.SIGINT)
        return lambda argv=None: pytest.fail("the command ran")

    loading = types.ModuleType("signpose.app.cli")
    loading.__getattr__ = importing   # type: ignore[method-assign]
    monkeypatch.setitem(sys.modules, "signpose.app.cli", loading)
    assert console_main() == 128 + signal.SIGINT
    assert capsys.readouterr().err == "signpose: interrupted\n"


def test_a_reader_that_stops_early_ends_the_output_quietly():
    # `signpose recognize ... --json | head -1`: the pipe closes while images are still coming.
    proc = subprocess.Popen([sys.executable, "-m", "signpose.app.cli", "recognize", *sorted(SCENES.glob("*.jpg")), "--json"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert json.loads(proc.stdout.readline())["image"].endswith(".jpg")
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_an_image_the_camera_cannot_be_scaled_to_is_that_images_error(tmp_path):
    """The sample camera is for 640x480 landscape; no scaling gives a portrait photo's intrinsics
    (scaled anyway, its pose was 0.5 m off). That image gets an error line, the others are still processed."""
    portrait = tmp_path / "portrait.png"
    cv2.imwrite(str(portrait), cv2.rotate(cv2.imread(str(SCENES / "scene_004.jpg")), cv2.ROTATE_90_CLOCKWISE))
    good = SCENES / "scene_004.jpg"
    result = signpose("recognize", portrait, good, "--camera", SCENES / "camera.yaml", "--json")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    objs = [json.loads(line) for line in result.stdout.splitlines()]
    # in the camera's words: no pipeline failure to report, no settings that would help
    assert objs[0]["error"].startswith("this 480x640 px image is the camera's 640x480 px turned on its side")
    assert objs[1]["label"] == "chief_of_security"
    assert "1 of 2 image(s) could not be used" in result.stderr


def write_turned_photos(folder: Path) -> dict[int, Path]:
    """turned_photos of every orientation (1-8) written into `folder`, with OFF_CENTRE as its camera.yaml."""
    folder.mkdir(exist_ok=True)
    save_camera(OFF_CENTRE, folder / "camera.yaml")
    paths = {o: folder / f"turned_{o}.jpg" for o in range(1, 9)}
    for orientation, photo in turned_photos(*paths).items():
        paths[orientation].write_bytes(photo)
    return paths


def test_a_camera_file_turns_with_the_photos_exif_orientation(tmp_path):
    """A camera file describes the pixels as the camera stored them; a photo is read turned as its EXIF orientation
    says. The camera stayed as it was: upside down (3), its principal point 60 px off centre put the camera 8 cm
    from where it stood, with no warning, and a quarter turn (6, 8) was refused as a photo turned on its side."""
    paths = write_turned_photos(tmp_path)
    result = signpose("recognize", *paths.values(), "--camera", tmp_path / "camera.yaml", "--json")
    answers = {o: json.loads(line) for o, line in zip(paths, result.stdout.splitlines())}
    for orientation in (1, 3, 6, 8):
        position = answers[orientation]["pose"]["camera_position"]
        assert np.linalg.norm(position - turned_scene_position()) < TURNED_WITHIN_M, (orientation, position)
    for orientation in (2, 4, 5, 7):  # no camera sees a mirror image
        assert "mirrored" in answers[orientation]["error"], answers[orientation]


def test_evaluate_turns_the_datasets_camera_with_each_photos_exif_orientation(tmp_path):
    """As `recognize --camera` does: the dataset's camera.yaml describes the pixels as stored."""
    paths = write_turned_photos(tmp_path / "turned")
    truth = json.loads((SCENES / "truth.json").read_text())["images"][TURNED_SCENE]
    (tmp_path / "turned" / "truth.json").write_text(json.dumps(
        {"images": {paths[o].name: {"label": truth["label"], "R": truth["R"], "t": truth["t"]} for o in (1, 3, 6, 8)}}))
    for o in (2, 4, 5, 7):
        paths[o].unlink()
    report = json.loads(signpose("evaluate", tmp_path / "turned", "--workers", 1, "--json").stdout)
    errors = [image["position_error_m"] for image in report["images"]]
    assert len(errors) == 4 and max(errors) < TURNED_WITHIN_M, report["images"]


def test_option_defaults_are_read_from_the_workspace_config(monkeypatch):
    # In this process: a default is written once, in WorkspaceConfig, so changing it there changes the option's.
    changed = {"workers": 3, "state_dir": Path("elsewhere"), "max_images": 7, "max_upload_bytes": 5_000_000,
               "request_timeout_s": 9.0}
    for name, value in changed.items():
        monkeypatch.setattr(WorkspaceConfig, name, value)
    assert build_parser().parse_args(["evaluate", "data"]).workers == 3
    serve = build_parser().parse_args(["serve"])
    assert (Path(serve.state_dir), serve.max_images, serve.max_upload_mb, serve.request_timeout) == (
        Path("elsewhere"), 7, 5.0, 9.0)


def test_evaluate_tells_datasets_and_images_of_the_same_name_apart(tmp_path):
    for root, label in (("a", "chief_of_security"), ("b", "none")):
        (tmp_path / root / "set" / label).mkdir(parents=True)
        shutil.copy(SCENES / "scene_000.jpg", tmp_path / root / "set" / label / "s.jpg")  # no sign in it
    a, b = tmp_path / "a" / "set", tmp_path / "b" / "set"
    result = signpose("evaluate", a, b, "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert [line.split()[:3] for line in result.stdout.splitlines()[2:5]] == [
        [str(a), "1", "0"], [str(b), "1", "1"], ["all", "2", "1"]]
    assert f"  {a / 'chief_of_security' / 's.jpg'}: truth chief_of_security, answer none" in result.stdout


def test_every_argument_of_every_command_says_what_it_is_in_help():
    """`signpose synth --help` listed --library with nothing beside it."""
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    bare = [f"{name} {action.dest}" for name, command in commands.items() for action in command._actions
            if not action.help]
    assert bare == []


def test_recognize_help_gives_the_assumed_field_of_views_range():
    """`recognize --help` gives --assumed-fov's range, 10-140, so that a value out of it is not the first a user
    hears of it."""
    result = signpose("recognize", "--help")
    assert result.returncode == 0
    assert "horizontal field of view, 10 to 140 degrees, assumed for" in " ".join(result.stdout.split())


def test_a_settings_file_with_min_crop_size_above_max_crop_size_is_refused(tmp_path):
    path = tmp_path / "settings.json"
    path.write_text('{"min_crop_size": 500, "max_crop_size": 160}')
    result = signpose("recognize", SCENES / "scene_002.jpg", "--settings", path)
    assert result.returncode == 2 and result.stdout == ""
    assert "min_crop_size (500) must be at most max_crop_size (160), or max_crop_size 0 (never downscale)" in \
        result.stderr and len(result.stderr.splitlines()) == 1
