"""Flight output writers (app/flight_output.py): the ROS covariance conversion pinned numerically, and JSON lines,
CSV and MCAP files read back (the MCAP with rosbags and with mcap-ros2-support), whole even after Ctrl-C."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from signpose.app.flight_output import (CSV_COLUMNS, UNKNOWN_COVARIANCE, PoseValues, open_flight_output, pose_topic,
                                        ros_covariance, ros_jacobian, ros_name, sign_frame)
from signpose.pipeline.pose import Pose, camera_position, quaternion_wxyz

RNG = np.random.default_rng(31)


def _rotation(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]


def _log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R, exact at small angles too (cv2.Rodrigues gives 0 under about 1e-5 rad)."""
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin = float(np.linalg.norm(w))
    angle = np.arctan2(sin, 0.5 * (np.trace(R) - 1))
    return w if sin < 1e-12 else w * (angle / sin)


def _ros_coordinates(x: np.ndarray, base: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The camera pose of pipeline parameters x = [rotation vector, t] in ROS coordinates about `base`'s
    (position, orientation in the sign frame): [position, rotation vector of Q·Q_baseᵀ] (left, sign frame)."""
    R = _rotation(x[:3])
    position, orientation = base
    return np.concatenate([camera_position(R, x[3:]) - position, _log(R.T @ orientation.T)])


def _covariance() -> np.ndarray:
    """A correlated (6, 6) pose covariance of realistic size: ~1° in rotation, ~2 cm in translation."""
    A = RNG.normal(size=(6, 6)) * np.array([0.015] * 3 + [0.02] * 3)[:, None]
    return A @ A.T + np.diag([1e-5] * 3 + [1e-5] * 3)


R0 = _rotation([0.4, -2.1, 0.7])  # a large rotation, where the Rodrigues Jacobian is far from the identity
T0 = np.array([0.3, -0.2, 2.5])


def _pose(R=R0, t=T0, covariance=None) -> Pose:
    return Pose(R=R, t=t, method="outline", reprojection_rmse_px=0.2, ambiguous=False, solution_errors=(0.2, 3.0),
                covariance=_covariance() if covariance is None else covariance)


def test_ros_jacobian_matches_finite_differences():
    x0 = np.concatenate([_log(R0), T0])
    base = (camera_position(R0, T0), R0.T)
    step = 1e-6
    numeric = np.column_stack([(_ros_coordinates(x0 + step * e, base) - _ros_coordinates(x0 - step * e, base)) / (2 * step)
                               for e in np.eye(6)])
    np.testing.assert_allclose(ros_jacobian(R0, T0), numeric, atol=1e-7)


def test_ros_covariance_matches_a_monte_carlo_of_perturbed_poses():
    pose = _pose()
    x0 = np.concatenate([_log(R0), T0])
    base = (camera_position(R0, T0), R0.T)
    samples = RNG.multivariate_normal(x0, pose.covariance, size=20000)
    errors = np.array([_ros_coordinates(x, base) for x in samples])
    expected = ros_covariance(pose)
    sigma = np.sqrt(np.diag(expected))
    # Correlations within 0.03 and standard deviations within 3 % (20000 samples: ~1 % noise, and the
    # linearisation's error at 1-2° and a few cm is far smaller).
    np.testing.assert_allclose(np.sqrt(np.diag(np.cov(errors.T))), sigma, rtol=0.03)
    np.testing.assert_allclose(np.corrcoef(errors.T), expected / np.outer(sigma, sigma), atol=0.03)


def test_the_ros_order_is_position_then_rotation_about_the_sign_axes():
    """Camera 2 m in front of the sign looking at it (R = I, t = (0, 0, 2)): a rotation about x alone turns the
    camera about the sign's x and swings it in y by 2 m per radian; a translation in the camera's z moves it in z."""
    variance_rx, variance_tz = 1e-4, 4e-6
    covariance = np.zeros((6, 6))
    covariance[0, 0], covariance[5, 5] = variance_rx, variance_tz
    ros = ros_covariance(_pose(np.eye(3), np.array([0.0, 0.0, 2.0]), covariance))
    expected = np.zeros((6, 6))
    expected[2, 2] = variance_tz  # z
    expected[3, 3] = variance_rx  # rotation about x
    expected[1, 1] = 4 * variance_rx  # y: -2 m · δθ
    expected[1, 3] = expected[3, 1] = 2 * variance_rx  # y and rotation about x both from -δr_x
    np.testing.assert_allclose(ros, expected, atol=1e-15)
    assert ros_covariance(_pose(covariance=np.zeros((6, 6)))) is not None
    no_covariance = Pose(R=R0, t=T0, method="outline", reprojection_rmse_px=0.2, ambiguous=False,
                         solution_errors=None, covariance=None)
    assert ros_covariance(no_covariance) is None


def test_labels_become_ros_names():
    assert ros_name("exit") == "exit" and ros_name("Fire exit-2") == "Fire_exit_2" and ros_name("3rd floor") == "sign_3rd_floor"
    assert ros_name("--") == "sign" and sign_frame("Fire exit") == "sign_Fire_exit" and sign_frame("3f") == "sign_3f"
    assert pose_topic("exit") == "/signpose/exit/camera_pose"
    assert pose_topic("exit", filtered=True) == "/signpose/exit/camera_pose_filtered"


def _record(frame: int, signs: list[dict]) -> dict:
    return {"source": "flight.mp4", "frame": frame, "time_s": frame / 30, "signs": signs,
            "timing_ms": {"decode": 1.0, "detect": 2.0, "track": 0.5, "total": 3.5}, "warnings": []}


def _sign(label: str, pose: Pose | None, filtered: Pose | None = None, state: str = "detected") -> dict:
    corners = [[10.0, 10.0], [50.0, 10.0], [50.0, 40.0], [10.0, 40.0]]
    return {"label": label, "track_id": 1 if label == "exit" else 2, "state": state, "corners": corners,
            "homography": np.eye(3).tolist(), "pose": pose.to_json() if pose else None,
            "filtered_pose": filtered.to_json() if filtered else None}


POSE = _pose()
FILTERED = _pose(_rotation([0.41, -2.1, 0.7]), T0 + 0.01)
RECORDS = [_record(0, [_sign("exit", POSE), _sign("fire extinguisher", None)]),
           _record(1, []),
           _record(2, [_sign("exit", POSE, FILTERED, "tracked")])]


def test_json_lines_are_the_records_one_a_line(tmp_path):
    with open_flight_output(tmp_path / "flight.jsonl") as writer:
        for record in RECORDS:
            writer.write(record)
    lines = (tmp_path / "flight.jsonl").read_text().splitlines()
    assert [json.loads(line) for line in lines] == RECORDS


def test_the_csv_has_a_row_per_sign_observation(tmp_path):
    with open_flight_output(tmp_path / "flight.csv") as writer:
        for record in RECORDS:
            writer.write(record)
    with (tmp_path / "flight.csv").open(newline="") as file:
        rows = list(csv.DictReader(file))
    assert list(rows[0]) == list(CSV_COLUMNS)
    assert [(r["frame"], r["label"], r["track_id"], r["state"]) for r in rows] == [
        ("0", "exit", "1", "detected"), ("0", "fire extinguisher", "2", "detected"), ("2", "exit", "1", "tracked")]
    first, no_pose, tracked = rows
    pose = POSE
    np.testing.assert_allclose([float(first[f"camera_{a}"]) for a in "xyz"], pose.camera_position)
    np.testing.assert_allclose([float(first[q]) for q in ("qw", "qx", "qy", "qz")], pose.quaternion_wxyz)
    variances = [float(first[c]) for c in ("var_x", "var_y", "var_z", "var_rot_x", "var_rot_y", "var_rot_z")]
    np.testing.assert_allclose(variances, np.diag(ros_covariance(pose)))
    assert first["filtered_x"] == "" and float(first["time_s"]) == 0.0
    assert all(no_pose[c] == "" for c in CSV_COLUMNS[5:])
    np.testing.assert_allclose([float(tracked[f"filtered_{a}"]) for a in "xyz"], FILTERED.camera_position)


def test_an_unknown_output_kind_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"flight.txt: unknown output kind .txt; write .jsonl, .csv, .mcap"):
        open_flight_output(tmp_path / "flight.txt")


def _write_mcap(path, interrupt: bool = False) -> None:
    image = np.zeros((24, 32, 3), np.uint8)
    image[:, :16] = 255
    stamps = [1_700_000_000_000_000_000 + i * 33_000_000 for i in range(len(RECORDS))]
    with open_flight_output(path) as writer:
        for record, stamp in zip(RECORDS, stamps):
            writer.write(record, image=image, stamp_ns=stamp)
        if interrupt:
            raise KeyboardInterrupt


def _quaternion_xyzw(q: object) -> np.ndarray:
    return np.array([q.x, q.y, q.z, q.w])


def test_the_mcap_reads_back_with_rosbags_types_frames_stamps_and_covariance(tmp_path):
    path = tmp_path / "flight.mcap"
    _write_mcap(path)
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {"/signpose/exit/camera_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
                         "/signpose/exit/camera_pose_filtered": "geometry_msgs/msg/PoseWithCovarianceStamped",
                         "/tf": "tf2_msgs/msg/TFMessage",
                         "/signpose/image/compressed": "sensor_msgs/msg/CompressedImage"}
        messages = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    by_topic: dict[str, list] = {}
    for topic, logged, msg in messages:
        by_topic.setdefault(topic, []).append((logged, msg))
    t0 = 1_700_000_000_000_000_000
    assert [t for t, _ in by_topic["/signpose/exit/camera_pose"]] == [t0, t0 + 66_000_000]
    assert len(by_topic["/signpose/exit/camera_pose_filtered"]) == 1
    assert len(by_topic["/signpose/image/compressed"]) == 3 and len(by_topic["/tf"]) == 2

    logged, msg = by_topic["/signpose/exit/camera_pose"][0]
    assert msg.header.frame_id == "sign_exit"
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == logged
    pose = POSE
    position = msg.pose.pose.position
    np.testing.assert_allclose([position.x, position.y, position.z], pose.camera_position)
    w, x, y, z = quaternion_wxyz(R0.T)  # the camera's orientation in the sign frame
    np.testing.assert_allclose(_quaternion_xyzw(msg.pose.pose.orientation), [x, y, z, w])
    np.testing.assert_allclose(np.reshape(msg.pose.covariance, (6, 6)), ros_covariance(pose))

    # The sign a child of the camera, as apriltag_ros places tags: the camera keeps the parent the robot gives it.
    _, tf = by_topic["/tf"][1]
    (transform,) = tf.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("camera_optical", "sign_exit")
    translation = transform.transform.translation
    np.testing.assert_allclose([translation.x, translation.y, translation.z], FILTERED.t)
    w, x, y, z = quaternion_wxyz(FILTERED.R)
    np.testing.assert_allclose(_quaternion_xyzw(transform.transform.rotation), [x, y, z, w])

    _, image = by_topic["/signpose/image/compressed"][0]
    assert image.format == "jpeg" and image.header.frame_id == "camera_optical"
    decoded = cv2.imdecode(np.asarray(image.data), cv2.IMREAD_COLOR)
    assert decoded.shape == (24, 32, 3) and decoded[:, :14].min() > 240 and decoded[:, 18:].max() < 15


def test_the_mcap_reads_back_with_mcap_ros2_support_and_marks_an_unknown_covariance(tmp_path):
    path = tmp_path / "flight.mcap"
    no_covariance = Pose(R=R0, t=T0, method="outline", reprojection_rmse_px=0.2, ambiguous=False,
                         solution_errors=None, covariance=None)
    with open_flight_output(path) as writer:
        writer.write(_record(4, [_sign("3rd floor", no_covariance)]))
    with path.open("rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages(topics=["/signpose/sign_3rd_floor/camera_pose"]))
    ((schema, _, message, ros_msg),) = decoded
    assert schema.name == "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert ros_msg.header.frame_id == "sign_3rd_floor"
    assert message.log_time == round(4 / 30 * 1e9)
    assert tuple(ros_msg.pose.covariance) == UNKNOWN_COVARIANCE


def test_every_mcap_channel_says_the_qos_it_was_offered_with(tmp_path):
    """The ros2 profile requires it; `ros2 bag play` replays /tf_static as transient local only when it says so,
    and tf2 and rviz take /tf_static only so."""
    path = tmp_path / "flight.mcap"
    _write_mcap(path)
    with path.open("rb") as file:
        channels = make_reader(file).get_summary().channels.values()
    profiles = {c.topic: yaml.safe_load(c.metadata["offered_qos_profiles"]) for c in channels}
    assert set(profiles) == {"/signpose/exit/camera_pose", "/signpose/exit/camera_pose_filtered", "/tf",
                             "/signpose/image/compressed"}
    assert all(p == [p[0]] and (p[0]["durability"], p[0]["reliability"], p[0]["history"]) == (2, 1, 1)
               for p in profiles.values())
    with path.open("rb") as file:   # the distro whose words the profiles are in, as rosbag2 records it
        assert [(m.name, m.metadata) for m in make_reader(file).iter_metadata()] == [("rosbag2", {"ROS_DISTRO": "humble"})]


def test_an_interrupted_run_leaves_a_finished_mcap(tmp_path):
    path = tmp_path / "flight.mcap"
    with pytest.raises(KeyboardInterrupt):
        _write_mcap(path, interrupt=True)
    with path.open("rb") as file:
        reader = make_reader(file)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 3 + 2 + 1 + 2  # images, raw poses, the filtered one, tf
        assert {s.name for s in summary.schemas.values()} >= {"geometry_msgs/msg/PoseWithCovarianceStamped",
                                                               "tf2_msgs/msg/TFMessage"}
    assert path.read_bytes().endswith(b"\x89MCAP0\r\n")  # the closing magic after the footer


def test_pose_values_read_back_from_json():
    pose = _pose()
    values = PoseValues.from_json(pose.to_json())
    np.testing.assert_allclose(values.R, pose.R)
    np.testing.assert_allclose(values.covariance, pose.covariance)
    data = pose.to_json()
    data["covariance"][2][2] = None  # a non-finite variance, as to_json writes it
    assert PoseValues.from_json(data).covariance is None and PoseValues.from_json(None) is None
