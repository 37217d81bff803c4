"""Writers of a flight's per-frame records: JSON lines, CSV, and a ROS 2 MCAP that Foxglove and `ros2 bag play` open.

A record is one frame's answer (the `signpose track --json` schema):
`{"source", "frame", "time_s", "signs": [{"label", "track_id", "state", "corners", "homography", "pose",
"filtered_pose"}], "timing_ms", "warnings"}`, where `pose` and `filtered_pose` are `Pose.to_json()` objects
(R, t, covariance over [rotation vector, translation], ...) or None; tracked with a sign map, also
`"camera_in_map"` and `"filtered_camera_in_map"` (`CameraInMap.to_json()`: position_m, orientation_wxyz,
covariance_xyz_rpy in ROS order, signs_used) or None.

Frames (REP 103/105): the sign frame `sign_<label>` has its origin at the sign centre, x right, y down the
sign, z into the wall, metres; `camera_optical` is the camera's, z forward, x right, y down. A pose (R, t)
maps sign points into the camera, X_cam = R·X_sign + t; the camera sits at -Rᵀt in the sign frame and its
axes are Rᵀ's columns there.

Every writer is a context manager that leaves a whole, readable file however the run ends (Ctrl-C
included): JSON lines and CSV are flushed a frame at a time, and the MCAP gets its summary and footer.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Protocol

import cv2
import numpy as np

from signpose.pipeline.pose import camera_position, quaternion_wxyz
from signpose.pipeline.pose_filter import ros_jacobian
from signpose.pipeline.sign_map import DEFAULT_FRAME, SignMap

OUTPUT_SUFFIXES = (".jsonl", ".csv", ".mcap")
CAMERA_FRAME = "camera_optical"
IMAGE_TOPIC = "/signpose/image/compressed"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
MAP_POSE_TOPIC = "/signpose/camera_in_map"
JPEG_QUALITY = 90
# The CSV's columns, one row per sign observation: the camera's position (m) and the quaternion (w, x, y, z)
# of R (sign frame -> camera frame, as in the JSON's pose), the filtered camera position, and the variances
# of the camera pose in ROS order (m², rad²: x, y, z, rotation about the sign frame's x, y, z; `ros_covariance`).
CSV_COLUMNS = ("frame", "time_s", "label", "track_id", "state", "camera_x", "camera_y", "camera_z",
               "qw", "qx", "qy", "qz", "filtered_x", "filtered_y", "filtered_z",
               "var_x", "var_y", "var_z", "var_rot_x", "var_rot_y", "var_rot_z",
               # the frame's camera in the map frame (tracked with a sign map; empty without), on each of its rows:
               # position (m), orientation (w, x, y, z), filtered position, variances in ROS order about the map's axes
               "map_x", "map_y", "map_z", "map_qw", "map_qx", "map_qy", "map_qz",
               "map_filtered_x", "map_filtered_y", "map_filtered_z",
               "map_var_x", "map_var_y", "map_var_z", "map_var_rot_x", "map_var_rot_y", "map_var_rot_z")
# The QoS each topic was offered with, as rosbag2 records it (the MCAP ros2 profile requires it of every channel):
# keep last, reliable, automatic liveliness, durations 0 (the default, none); durability volatile (2), but
# transient local (1) for /tf_static, whose subscribers (tf2, rviz) take it only so when a bag is played.
QOS_PROFILE = """- history: 1
  depth: {depth}
  reliability: 1
  durability: {durability}
  deadline:
    sec: 0
    nsec: 0
  lifespan:
    sec: 0
    nsec: 0
  liveliness: 1
  liveliness_lease_duration:
    sec: 0
    nsec: 0
  avoid_ros_namespace_conventions: false
"""
# geometry_msgs has no "covariance unknown" value; sensor_msgs' convention marks it so: -1 first, zeros after.
UNKNOWN_COVARIANCE = (-1.0, *([0.0] * 35))


class PoseLike(Protocol):
    """What the writers need of a pose: R (3, 3) and t (3,) m, X_cam = R·X_sign + t, and a (6, 6) covariance
    over [rotation vector of R (rad), t (m)] or None (`signpose.pipeline.pose.Pose` is one)."""

    @property
    def R(self) -> np.ndarray: ...
    @property
    def t(self) -> np.ndarray: ...
    @property
    def covariance(self) -> np.ndarray | None: ...


@dataclass(frozen=True)
class PoseValues:
    """The R, t and covariance of a pose read back from its JSON (`Pose.to_json`)."""

    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray | None

    @classmethod
    def from_json(cls, data: dict | None) -> PoseValues | None:
        """None for a null pose; a covariance with a null (non-finite) entry is no covariance."""
        if data is None:
            return None
        covariance = data.get("covariance")
        known = covariance is not None and all(v is not None for row in covariance for v in row)
        return cls(np.array(data["R"], dtype=np.float64), np.array(data["t"], dtype=np.float64),
                   np.array(covariance, dtype=np.float64) if known else None)


def ros_covariance(pose: PoseLike) -> np.ndarray | None:
    """(6, 6) covariance of the camera's pose in the sign frame in ROS order (x, y, z in m; rotation about the
    sign frame's x, y, z in rad, the orientation perturbed as exp([δθ]×)·Rᵀ), propagated from the pose's
    covariance over [rotation vector of R, t]; None when the pose has none."""
    if pose.covariance is None:
        return None
    jacobian = ros_jacobian(pose.R, pose.t)
    covariance = jacobian @ np.asarray(pose.covariance, dtype=np.float64) @ jacobian.T
    return 0.5 * (covariance + covariance.T)


def _token(label: str) -> str:
    """`label` in the letters, digits and single underscores ROS names are made of."""
    return re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", label)).strip("_") or "sign"


def ros_name(label: str) -> str:
    """`label` as a ROS topic name token (`_token`), which may not start with a digit: "3f" is sign_3f."""
    token = _token(label)
    return f"sign_{token}" if token[0].isdigit() else token


def sign_frame(label: str) -> str:
    """The TF frame of the sign `label`: sign_<label>, its label in ROS name characters."""
    return f"sign_{_token(label)}"


def pose_topic(label: str, *, filtered: bool = False) -> str:
    """/signpose/<label>/camera_pose, or camera_pose_filtered for the filter's pose."""
    return f"/signpose/{ros_name(label)}/camera_pose{'_filtered' if filtered else ''}"


class FlightOutputError(ValueError):
    """The output file could not be written (a full disk, a file system error); the file is removed."""


class FlightWriter:
    """Writes a flight's records to `path`, a frame at a time; a context manager that closes the file whole.
    `sign_map`: the map the flight was located in, if any.

    The file is made at the first record, or at the end of a run that ended without error: a run that fails
    before its first frame leaves a file already at `path` as it was. One that could not be written
    (FlightOutputError) is removed rather than left cut in the middle of a record."""

    def __init__(self, path: Path, sign_map: SignMap | None = None) -> None:
        self.path, self.sign_map = path, sign_map
        self.opened = self.closed = False

    def write(self, record: dict, *, image: np.ndarray | None = None, stamp_ns: int | None = None) -> None:
        """Write one frame's `record`. `image` (H, W, 3) BGR or (H, W) gray uint8: the input frame, which only the
        MCAP keeps. `stamp_ns`: the frame's time since the epoch (a bag's), else its time_s from 0."""
        with self._writing():
            self._open_once()
            self._write(record, image=image, stamp_ns=stamp_ns)

    def close(self) -> None:
        """Finish the file (once), making it if no record was written."""
        if self.closed:
            return
        self.closed = True
        with self._writing():
            self._open_once()
            self._close()

    def _open_once(self) -> None:
        if not self.opened:
            self._open()
            self.opened = True

    @contextmanager
    def _writing(self) -> Iterator[None]:
        try:
            yield
        except OSError as exc:
            self.closed = True
            if not self.opened:  # nothing was made, and what was there is left
                raise FlightOutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
            with suppress(OSError, ValueError):  # ValueError: the failure was in closing, the file is closed
                self._close()
            self.path.unlink(missing_ok=True)
            raise FlightOutputError(f"cannot write {self.path}: {exc.strerror or exc}; the file is removed") from None

    def _open(self) -> None:
        raise NotImplementedError

    def _write(self, record: dict, *, image: np.ndarray | None, stamp_ns: int | None) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> FlightWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None or self.opened:
            self.close()


def open_flight_output(path: str | Path, *, sign_map: SignMap | None = None) -> FlightWriter:
    """The writer for `path` by its suffix: .jsonl, .csv or .mcap; ValueError for any other. `sign_map`: the map
    the flight was located in (the MCAP's `map` frame and its signs)."""
    path = Path(path)
    writers: dict[str, type[FlightWriter]] = {".jsonl": JsonLinesWriter, ".csv": CsvWriter, ".mcap": McapWriter}
    writer = writers.get(path.suffix.lower())
    if writer is None:
        raise ValueError(f"{path}: unknown output kind {path.suffix or '(no extension)'}; write "
                         f"{', '.join(OUTPUT_SUFFIXES)}")
    return writer(path, sign_map)


class JsonLinesWriter(FlightWriter):
    """One record a line, as `--json` prints it."""

    def _open(self) -> None:
        self.file: IO[str] = self.path.open("w", encoding="utf-8")

    def _write(self, record: dict, *, image: np.ndarray | None, stamp_ns: int | None) -> None:
        self.file.write(json.dumps(record, allow_nan=False) + "\n")
        self.file.flush()

    def _close(self) -> None:
        self.file.close()


def _csv_number(value: float | None) -> str:
    """A number for a CSV cell: empty for None or non-finite, else repr-exact."""
    return "" if value is None or not math.isfinite(value) else repr(float(value))


def csv_row(record: dict, sign: dict) -> list[str]:
    """The CSV_COLUMNS cells of one sign observation of `record`."""
    pose = PoseValues.from_json(sign.get("pose"))
    filtered = PoseValues.from_json(sign.get("filtered_pose"))
    none3: Sequence[float | None] = (None, None, None)
    position = camera_position(pose.R, pose.t) if pose else none3
    quaternion = quaternion_wxyz(pose.R) if pose else (None,) * 4
    filtered_position = camera_position(filtered.R, filtered.t) if filtered else none3
    covariance = ros_covariance(pose) if pose else None
    variances = np.diag(covariance) if covariance is not None else (None,) * 6
    located, filtered_located = record.get("camera_in_map"), record.get("filtered_camera_in_map")
    in_map = [*located["position_m"], *located["orientation_wxyz"]] if located else [None] * 7
    in_map += filtered_located["position_m"] if filtered_located else none3
    map_covariance = located and located["covariance_xyz_rpy"]
    in_map += [map_covariance[i][i] for i in range(6)] if map_covariance else [None] * 6
    cells = [str(record["frame"]), _csv_number(record["time_s"]), sign["label"], str(sign["track_id"]), sign["state"]]
    return cells + [_csv_number(v) for v in (*position, *quaternion, *filtered_position, *variances, *in_map)]


class CsvWriter(FlightWriter):
    """One row per sign observation (CSV_COLUMNS), after a header row; a frame without signs has no row."""

    def _open(self) -> None:
        self.file: IO[str] = self.path.open("w", encoding="utf-8", newline="")
        self.csv = csv.writer(self.file)
        self.csv.writerow(CSV_COLUMNS)
        self.file.flush()

    def _write(self, record: dict, *, image: np.ndarray | None, stamp_ns: int | None) -> None:
        self.csv.writerows(csv_row(record, sign) for sign in record["signs"])
        self.file.flush()

    def _close(self) -> None:
        self.file.close()


def _stamp(stamp_ns: int) -> dict[str, int]:
    """builtin_interfaces/Time of `stamp_ns` ns."""
    return {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}


def _ros_pose(pose: PoseLike) -> dict[str, dict[str, float]]:
    """geometry_msgs/Pose of the camera in the sign frame: position -Rᵀt, orientation Rᵀ."""
    return _pose_message(camera_position(pose.R, pose.t), quaternion_wxyz(np.asarray(pose.R).T))


def _sign_in_camera(pose: PoseLike) -> dict[str, dict[str, float]]:
    """geometry_msgs/Pose of the sign in the camera frame: position t, orientation R."""
    return _pose_message(np.ravel(pose.t), quaternion_wxyz(np.asarray(pose.R)))


def _pose_message(position: Iterable[float], orientation_wxyz: Iterable[float]) -> dict[str, dict[str, float]]:
    """geometry_msgs/Pose of a (3,) position (m) and a (4,) quaternion (w, x, y, z)."""
    w, x, y, z = orientation_wxyz
    return {"position": dict(zip("xyz", map(float, position))),
            "orientation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}}


def _transform(header: dict, child_frame: str, pose: dict[str, dict[str, float]]) -> dict:
    """geometry_msgs/TransformStamped of `child_frame` at `pose` (a geometry_msgs/Pose) in the header's frame."""
    return {"header": header, "child_frame_id": child_frame,
            "transform": {"translation": pose["position"], "rotation": pose["orientation"]}}


def _covariance_message(covariance: np.ndarray | Sequence[Sequence[float]] | None) -> Sequence[float]:
    """A message's 36 covariance numbers, row by row, or UNKNOWN_COVARIANCE for None."""
    return UNKNOWN_COVARIANCE if covariance is None else [float(v) for v in np.ravel(covariance)]


class McapWriter(FlightWriter):
    """A ROS 2 MCAP (profile ros2, CDR messages, message definitions embedded), per frame:
    - per sign with a pose, geometry_msgs/PoseWithCovarianceStamped on /signpose/<label>/camera_pose (and the
      filter's on .../camera_pose_filtered): the camera's pose in `sign_<label>`, covariance by `ros_covariance`;
    - tf2_msgs/TFMessage on /tf: camera_optical -> sign_<label> per sign, from the filtered pose when there is
      one, but for the signs of the sign map, which /tf_static places: every frame keeps one parent, and
      camera_optical none, so the robot's own tree (base_link -> camera_optical) takes these as they are;
    - sensor_msgs/CompressedImage (JPEG) on /signpose/image/compressed, frame camera_optical, when an image is given;
    - with a sign map, geometry_msgs/PoseWithCovarianceStamped on /signpose/camera_in_map (and .../camera_in_map_filtered)
      in the map's frame, covariance in ROS order about the map's axes, on each frame that has it; and once, with
      the first frame, tf2_msgs/TFMessage on /tf_static: map -> sign_<id> for every mapped sign.
    Message times (log, publish and header stamps) are `stamp_ns`, else the record's time_s from 0.
    """

    MESSAGE_TYPES = ("geometry_msgs/msg/PoseWithCovarianceStamped", "tf2_msgs/msg/TFMessage",
                     "sensor_msgs/msg/CompressedImage")

    def _open(self) -> None:
        from mcap_ros2.writer import Writer
        from rosbags.typesys import Stores, get_typestore

        self.map_frame = self.sign_map.frame if self.sign_map is not None else DEFAULT_FRAME
        self.static_sent = self.sign_map is None
        typestore = get_typestore(Stores.ROS2_HUMBLE)
        self.file = self.path.open("wb")
        self.writer = Writer(self.file)
        # mcap_ros2 wants "pkg/msg/Type" names and definitions whose dependencies read "MSG: pkg/Type".
        self.schemas = {name: self.writer.register_msgdef(name, typestore.generate_msgdef(name, ros_version=2)[0])
                        for name in self.MESSAGE_TYPES}
        # As rosbag2 records its distro: its readers take the QoS profiles in that distro's words (Humble's, in
        # numbers, QOS_PROFILE), where without it a Jazzy reader would read them as its own and not understand them.
        self.writer.add_metadata("rosbag2", {"ROS_DISTRO": "humble"})

    def _send(self, topic: str, type_name: str, message: dict, stamp_ns: int) -> None:
        schema = self.schemas[type_name]
        if topic not in self.writer._channel_ids:
            # mcap_ros2's Writer registers a channel without metadata, and takes none: register it first.
            static = topic == TF_STATIC_TOPIC
            qos = QOS_PROFILE.format(depth=1 if static else 10, durability=1 if static else 2)
            self.writer._channel_ids[topic] = self.writer._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema.id, metadata={"offered_qos_profiles": qos})
        self.writer.write_message(topic, schema, message, log_time=stamp_ns, publish_time=stamp_ns)

    def _write(self, record: dict, *, image: np.ndarray | None, stamp_ns: int | None) -> None:
        if stamp_ns is None:
            stamp_ns = round(float(record["time_s"]) * 1e9)
        stamp = _stamp(stamp_ns)
        if not self.static_sent:
            self._send_map(stamp, stamp_ns)
        for key, topic in (("camera_in_map", MAP_POSE_TOPIC), ("filtered_camera_in_map", MAP_POSE_TOPIC + "_filtered")):
            located = record.get(key)
            if located is not None:
                message = {"header": {"stamp": stamp, "frame_id": self.map_frame}, "pose": {
                    "pose": _pose_message(located["position_m"], located["orientation_wxyz"]),
                    "covariance": _covariance_message(located["covariance_xyz_rpy"])}}
                self._send(topic, self.MESSAGE_TYPES[0], message, stamp_ns)
        transforms = []
        mapped = set(self.sign_map.signs) if self.sign_map is not None else set()
        for sign in record["signs"]:
            header = {"stamp": stamp, "frame_id": sign_frame(sign["label"])}
            poses = [(PoseValues.from_json(sign.get("pose")), False),
                     (PoseValues.from_json(sign.get("filtered_pose")), True)]
            for pose, filtered in poses:
                if pose is None:
                    continue
                covariance = ros_covariance(pose)
                message = {"header": header, "pose": {"pose": _ros_pose(pose), "covariance": _covariance_message(covariance)}}
                self._send(pose_topic(sign["label"], filtered=filtered), self.MESSAGE_TYPES[0], message, stamp_ns)
            shown = poses[1][0] or poses[0][0]
            if shown is not None and sign["label"] not in mapped:
                transforms.append(_transform({"stamp": stamp, "frame_id": CAMERA_FRAME}, sign_frame(sign["label"]),
                                             _sign_in_camera(shown)))
        if transforms:
            self._send(TF_TOPIC, self.MESSAGE_TYPES[1], {"transforms": transforms}, stamp_ns)
        if image is not None:
            ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if not ok:
                raise ValueError(f"{self.path}: frame {record['frame']} cannot be encoded as JPEG")
            message = {"header": {"stamp": stamp, "frame_id": CAMERA_FRAME}, "format": "jpeg", "data": jpeg.tobytes()}
            self._send(IMAGE_TOPIC, self.MESSAGE_TYPES[2], message, stamp_ns)

    def _send_map(self, stamp: dict[str, int], stamp_ns: int) -> None:
        """/tf_static: the map frame -> sign_<id> of every mapped sign (its pose in the map), once."""
        assert self.sign_map is not None
        header = {"stamp": stamp, "frame_id": self.map_frame}
        transforms = [_transform(header, sign_frame(sign.sign_id), _pose_message(sign.position_m, quaternion_wxyz(sign.R)))
                      for sign in self.sign_map.signs.values()]
        self._send(TF_STATIC_TOPIC, self.MESSAGE_TYPES[1], {"transforms": transforms}, stamp_ns)
        self.static_sent = True

    def _close(self) -> None:
        """Write the summary and footer, then close the file."""
        try:
            self.writer.finish()
        finally:
            self.file.close()

