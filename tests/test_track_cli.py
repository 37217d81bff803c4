"""`signpose track`: the sample flight and every kind of source through the real CLI, its outputs read
back with the ROS libraries, and a clear error and exit code for each bad input."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from mcap_ros2.reader import read_ros2_messages

from signpose.pipeline.camera import load_camera
from signpose.pipeline.library import load_library
from rosbags.rosbag2 import Writer as Bag2Writer

from tests.support.bags import ROS2, header, write_mcap
from tests.support.cli import signpose, signpose_process

ROOT = Path(__file__).resolve().parents[1]
FLIGHT = ROOT / "sample_images" / "flights" / "corridor"
VIDEO = FLIGHT / "flight.mp4"
CAMERA = FLIGHT / "camera.yaml"
LABELS = set(load_library().ids)
SIGN_KEYS = {"label", "track_id", "state", "corners", "homography", "pose", "filtered_pose"}
T0 = 1_700_000_000_000_000_000  # ns: a bag's first header stamp


def track(*args) -> subprocess.CompletedProcess:
    return signpose("track", *args)


def records(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines()]


def video_frames(n: int) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(VIDEO))
    frames = [capture.read()[1] for _ in range(n)]
    capture.release()
    return frames


@pytest.fixture(scope="module")
def flight_json() -> list[dict]:
    run = track(VIDEO, "--camera", CAMERA, "--max-frames", 40, "--json")
    assert run.returncode == 0, run.stderr
    return records(run.stdout)


def test_every_frame_is_one_json_line_in_the_pinned_schema(flight_json):
    assert [r["frame"] for r in flight_json] == list(range(40))
    for r in flight_json:
        assert set(r) == {"source", "frame", "time_s", "signs", "timing_ms", "warnings"}
        assert set(r["timing_ms"]) == {"decode", "detect", "track", "total"}
        assert r["time_s"] == pytest.approx(r["frame"] / 30, abs=1e-6)
        for sign in r["signs"]:
            assert set(sign) == SIGN_KEYS and sign["label"] in LABELS and sign["state"] in ("detected", "tracked")
            assert np.asarray(sign["corners"]).shape == (4, 2) and np.asarray(sign["homography"]).shape == (3, 3)
    states = [s["state"] for r in flight_json for s in r["signs"]]
    # both of the flight's first two signs are reported, and followed between detections
    assert {s["label"] for r in flight_json for s in r["signs"]} >= {"chief_of_security", "security_compound"}
    assert "tracked" in states and "detected" in states


def test_a_folder_of_frames_is_a_flight_at_the_rate_given(tmp_path, flight_json):
    for i, frame in enumerate(video_frames(12)):
        cv2.imwrite(str(tmp_path / f"frame{i}.png"), frame)
    run = track(tmp_path, "--camera", CAMERA, "--fps", 30, "--json")
    assert run.returncode == 0, run.stderr
    got = records(run.stdout)
    assert [r["frame"] for r in got] == list(range(12)) and got[11]["time_s"] == pytest.approx(11 / 30)
    # frame2 before frame10: the same signs on the same frames as the video
    assert [[s["label"] for s in r["signs"]] for r in got] == [[s["label"] for s in r["signs"]] for r in flight_json[:12]]


def test_a_bag_in_mcap_is_tracked_with_its_camera_info_and_written_as_ros2(tmp_path):
    """A ROS 2 bag written by mcap-ros2-support: JPEG frames with their CameraInfo, no --camera."""
    messages: list[tuple[str, object]] = []
    for i, frame in enumerate(video_frames(15)):
        stamp = T0 + i * 33_333_333
        jpeg = cv2.imencode(".jpg", frame)[1]
        messages.append(("/cam/image_raw/compressed", ROS2.types["sensor_msgs/msg/CompressedImage"](
            header=header(ROS2, stamp, False), format="jpeg", data=np.frombuffer(jpeg.tobytes(), np.uint8))))
    K = load_camera(CAMERA).K
    roi = ROS2.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    messages.insert(0, ("/cam/camera_info", ROS2.types["sensor_msgs/msg/CameraInfo"](
        header=header(ROS2, T0, False), height=480, width=640, distortion_model="plumb_bob", d=np.zeros(5),
        k=K.ravel(), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0, roi=roi)))
    bag = write_mcap(tmp_path / "flight.mcap", messages)
    out = tmp_path / "out.mcap"
    run = track(bag, "-o", out, "--json")
    assert run.returncode == 0, run.stderr
    got = records(run.stdout)
    assert len(got) == 15 and not any("no camera" in w for r in got for w in r["warnings"])
    assert got[14]["time_s"] == pytest.approx(14 * 0.033333333, abs=1e-6)
    topics: dict[str, list] = {}
    for msg in read_ros2_messages(str(out)):
        topics.setdefault(msg.channel.topic, []).append(msg.ros_msg)
    poses = topics["/signpose/chief_of_security/camera_pose"]
    assert poses and all(p.header.frame_id == "sign_chief_of_security" for p in poses)
    assert len(poses[0].pose.covariance) == 36
    transforms = [t for m in topics["/tf"] for t in m.transforms]
    assert {t.header.frame_id for t in transforms} == {"camera_optical"}
    assert "sign_chief_of_security" in {t.child_frame_id for t in transforms}
    assert "/signpose/image/compressed" not in topics  # the frames are in the bag already


def test_csv_and_jsonl_outputs_hold_what_json_prints(tmp_path, flight_json):
    run = track(VIDEO, "--camera", CAMERA, "--max-frames", 40, "-o", tmp_path / "f.csv")
    assert run.returncode == 0, run.stderr
    rows = list(csv.DictReader((tmp_path / "f.csv").open()))
    assert len(rows) == sum(len(r["signs"]) for r in flight_json)
    assert {r["label"] for r in rows} == {s["label"] for r in flight_json for s in r["signs"]}
    run = track(VIDEO, "--camera", CAMERA, "--max-frames", 5, "-o", tmp_path / "f.jsonl")
    assert run.returncode == 0, run.stderr
    assert [r["frame"] for r in records((tmp_path / "f.jsonl").read_text())] == list(range(5))
    assert "5 frames" in run.stderr.splitlines()[-1]  # the one-line summary


CORRIDOR_MAP = """frame: corridor
signs:
  - {id: security_compound, position_m: [0.0, -0.2, 0.0], orientation_wxyz: [1, 0, 0, 0]}
  - {id: chief_of_security, position_m: [2.6, -0.1, 0.0], orientation_wxyz: [1, 0, 0, 0]}
"""


def test_with_a_map_each_frame_locates_the_camera_in_it_and_every_output_carries_it(tmp_path):
    """The corridor's signs in a map of their wall's frame: the camera in it per frame, filtered, in the JSON, the
    CSV and the MCAP (PoseWithCovarianceStamped in the map frame, /tf_static map -> each sign)."""
    (tmp_path / "map.yaml").write_text(CORRIDOR_MAP)
    truth = json.loads((FLIGHT / "truth.json").read_text())["frames"]
    run = track(VIDEO, "--camera", CAMERA, "--map", tmp_path / "map.yaml", "--max-frames", 12, "--json",
                "-o", tmp_path / "out.mcap")
    assert run.returncode == 0, run.stderr
    got = records(run.stdout)
    assert all({"camera_in_map", "filtered_camera_in_map"} <= set(r) for r in got)
    located = [r for r in got if r["camera_in_map"] is not None]
    assert len(located) >= 8 and all(r["filtered_camera_in_map"] is not None for r in located)
    both = [r for r in located if len(r["camera_in_map"]["signs_used"]) == 2]
    assert both  # 6-7 m from the wall, both signs 45-50 px wide
    for r in both:  # within 2 % of the distance
        error = np.linalg.norm(np.subtract(r["camera_in_map"]["position_m"], truth[r["frame"]]["camera_position"]))
        assert error < 0.15, (r["frame"], error)
    topics: dict[str, list] = {}
    for msg in read_ros2_messages(str(tmp_path / "out.mcap")):
        topics.setdefault(msg.channel.topic, []).append(msg)
    poses = topics["/signpose/camera_in_map"]
    assert len(poses) == len(located) and len(topics["/signpose/camera_in_map_filtered"]) == len(located)
    for msg, r in zip(poses, located):
        assert msg.schema.name == "geometry_msgs/msg/PoseWithCovarianceStamped"
        assert msg.ros_msg.header.frame_id == "corridor"
        position = msg.ros_msg.pose.pose.position
        np.testing.assert_allclose([position.x, position.y, position.z], r["camera_in_map"]["position_m"])
        q = msg.ros_msg.pose.pose.orientation
        np.testing.assert_allclose([q.w, q.x, q.y, q.z], r["camera_in_map"]["orientation_wxyz"])
        # ROS order, as the JSON's: position block first, then rotation about the map's axes
        np.testing.assert_allclose(np.reshape(msg.ros_msg.pose.covariance, (6, 6)),
                                   r["camera_in_map"]["covariance_xyz_rpy"])
    (static,) = topics["/tf_static"]
    assert static.schema.name == "tf2_msgs/msg/TFMessage"
    assert yaml.safe_load(static.channel.metadata["offered_qos_profiles"])[0]["durability"] == 1  # transient local
    placed = {t.child_frame_id: (t.header.frame_id, t.transform.translation) for t in static.ros_msg.transforms}
    assert set(placed) == {"sign_security_compound", "sign_chief_of_security"}
    parent, translation = placed["sign_chief_of_security"]
    assert parent == "corridor" and (translation.x, translation.y, translation.z) == (2.6, -0.1, 0.0)
    # One tree: a mapped sign's parent is the map alone (camera_optical seeing it gives it no second one).
    assert not [t for m in topics.get("/tf", []) for t in m.ros_msg.transforms if t.child_frame_id in placed]

    run = track(VIDEO, "--camera", CAMERA, "--map", tmp_path / "map.yaml", "--max-frames", 4, "-o", tmp_path / "f.csv")
    assert run.returncode == 0, run.stderr
    rows = [r for r in csv.DictReader((tmp_path / "f.csv").open()) if r["map_x"]]
    assert rows
    frame = got[int(rows[-1]["frame"])]["camera_in_map"]
    np.testing.assert_allclose([float(rows[-1][f"map_{a}"]) for a in "xyz"], frame["position_m"])
    np.testing.assert_allclose(float(rows[-1]["map_var_rot_z"]), frame["covariance_xyz_rpy"][5][5])


@pytest.mark.parametrize("args, message", [
    (["missing.mp4"], "no such file"),
    (["README.md"], "README.md"),
    ([VIDEO, "-o", "flight.txt"], "write a flight as"),
])
def test_bad_sources_and_outputs_are_one_line_errors(args, message):
    run = signpose_process("track", *args)   # one line on the process' stderr: the decoders' own say nothing
    assert run.returncode == 2 and message in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr


def test_a_bag_without_images_says_so(tmp_path):
    bag = write_mcap(tmp_path / "imu.mcap", [("/cam/camera_info", ROS2.types["sensor_msgs/msg/CameraInfo"](
        header=header(ROS2, T0, False), height=480, width=640, distortion_model="plumb_bob", d=np.zeros(5),
        k=np.eye(3).ravel(), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0,
        roi=ROS2.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                            do_rectify=False)))])
    run = track(bag)
    assert run.returncode == 2 and "no image topics" in run.stderr, run.stderr
    run = track(bag, "--topic", "/nope")
    assert run.returncode == 2 and "/nope" in run.stderr, run.stderr


def test_an_image_topic_without_messages_is_an_error_not_an_empty_flight(tmp_path):
    with Bag2Writer(tmp_path / "empty", version=9) as writer:
        writer.add_connection("/cam/image_raw", "sensor_msgs/msg/Image", typestore=ROS2)
    run = track(tmp_path / "empty", "-o", tmp_path / "out.mcap")
    assert run.returncode == 2 and "holds no frames on /cam/image_raw" in run.stderr, run.stderr
    assert not (tmp_path / "out.mcap").exists()


def test_a_camera_that_does_not_fit_the_video_is_refused(tmp_path):
    portrait = tmp_path / "portrait.yaml"
    portrait.write_text("image_width: 480\nimage_height: 640\ncamera_matrix: {rows: 3, cols: 3, data: "
                        "[500, 0, 240, 0, 500, 320, 0, 0, 1]}\n")
    run = track(VIDEO, "--camera", portrait, "--max-frames", 3)
    assert run.returncode == 2 and "flight.mp4" in run.stderr, run.stderr


def test_a_run_that_cannot_start_leaves_the_output_there_as_it_was_and_the_source_is_never_the_output(tmp_path):
    """A camera refused on the first frame overwrote the last run's CSV with a header; `-o` naming the bag
    being read replaced the bag with the output of its first frames."""
    good = tmp_path / "good.csv"
    good.write_text("the last run\n")
    portrait = tmp_path / "portrait.yaml"
    portrait.write_text("image_width: 480\nimage_height: 640\ncamera_matrix: {rows: 3, cols: 3, data: "
                        "[500, 0, 240, 0, 500, 320, 0, 0, 1]}\n")
    run = track(VIDEO, "--camera", portrait, "-o", good)
    assert run.returncode == 2 and good.read_text() == "the last run\n", run.stderr
    run = track(tmp_path / "none", "-o", tmp_path / "new.jsonl")
    assert run.returncode == 2 and not (tmp_path / "new.jsonl").exists()

    bag = write_mcap(tmp_path / "in.mcap", [("/cam/image_raw/compressed", ROS2.types["sensor_msgs/msg/CompressedImage"](
        header=header(ROS2, T0, False), format="jpeg", data=np.frombuffer(cv2.imencode(".jpg", video_frames(1)[0])[1],
                                                                          np.uint8)))])
    before = bag.read_bytes()
    run = track(bag, "--camera", CAMERA, "-o", tmp_path / "." / "in.mcap")
    assert run.returncode == 2 and "is a SOURCE" in run.stderr and bag.read_bytes() == before, run.stderr
    (tmp_path / "bag").mkdir()   # inside a source folder (a rosbag2 folder's): checked before the folder is read
    run = track(tmp_path / "bag", "-o", tmp_path / "bag" / "out.mcap")
    assert run.returncode == 2 and "is a SOURCE or inside one" in run.stderr, run.stderr


def test_a_full_disk_is_one_line_and_leaves_no_half_written_file(tmp_path):
    """Written past what the file system takes (here the process' file size limit): a traceback per frame
    and an MCAP no reader opens."""
    import resource

    def small_files() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # EFBIG from write() rather than the signal's kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))

    out = tmp_path / "flight.mcap"
    run = subprocess.run([sys.executable, "-m", "signpose.app.cli", "track", str(VIDEO), "--camera", str(CAMERA),
                          "--max-frames", "60", "-o", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, preexec_fn=small_files)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 1 and lines[-1].startswith(f"signpose track: error: cannot write {out}"), run.stderr
    assert "the file is removed" in lines[-1] and "Traceback" not in run.stderr and not out.exists()


@pytest.mark.slow
def test_ctrl_c_leaves_a_finished_mcap(tmp_path):
    out = tmp_path / "cut.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "signpose.app.cli", "track", str(VIDEO), "--camera", str(CAMERA),
                             "-o", str(out), "--json"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    for _ in range(20):  # a few frames in
        proc.stdout.readline()
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "frames" in stderr
    written = list(read_ros2_messages(str(out)))  # a truncated MCAP has no summary and fails here
    assert any(m.channel.topic == "/signpose/image/compressed" for m in written)
