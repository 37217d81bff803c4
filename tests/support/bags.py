"""ROS bags written as ROS tools write them, for tests: bare MCAP files (mcap-ros2-support), rosbag2
folders and ROS 1 bags (rosbags); messages are rosbags' message classes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap_ros2.writer import Writer as McapRos2Writer
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer
from rosbags.typesys import Stores, get_typestore

ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)


def header(store, stamp_ns: int, ros1: bool):
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return Header(seq=0, stamp=stamp, frame_id="cam") if ros1 else Header(stamp=stamp, frame_id="cam")


def plain(value):
    """A rosbags message as the dicts, lists and bytes mcap-ros2-support encodes."""
    if isinstance(value, np.ndarray):
        return value.tobytes() if value.dtype == np.uint8 else value.tolist()
    if hasattr(value, "__dataclass_fields__"):
        return {k: plain(getattr(value, k)) for k in value.__dataclass_fields__ if k != "__msgtype__"}
    return value


def write_mcap(path: Path, messages: list[tuple[str, object]]) -> Path:
    """A bare .mcap file, as mcap-ros2-support writes it: (topic, rosbags ROS 2 message) pairs, CDR, definitions
    embedded; log times from the header stamps."""
    with path.open("wb") as file:
        writer = McapRos2Writer(file)
        schemas: dict[str, object] = {}
        for topic, msg in messages:
            name = msg.__msgtype__
            if name not in schemas:
                schemas[name] = writer.register_msgdef(name, ROS2.generate_msgdef(name, ros_version=2)[0])
            stamp = msg.header.stamp
            ns = stamp.sec * 10**9 + stamp.nanosec
            writer.write_message(topic, schemas[name], plain(msg), log_time=ns, publish_time=ns)
        writer.finish()
    return path


def write_bag2(path: Path, messages: list[tuple[str, object]], log_ns: list[int] | None = None,
                storage: StoragePlugin = StoragePlugin.SQLITE3) -> Path:
    """A rosbag2 folder (metadata.yaml and a .db3 or .mcap), as rosbags writes it."""
    with Bag2Writer(path, version=9, storage_plugin=storage) as writer:
        connections: dict[str, object] = {}
        for n, (topic, msg) in enumerate(messages):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ROS2)
            ns = log_ns[n] if log_ns else msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            writer.write(connections[topic], ns, ROS2.serialize_cdr(msg, msg.__msgtype__))
    return path


def write_bag1(path: Path, messages: list[tuple[str, object]]) -> Path:
    """A ROS 1 .bag, as rosbags writes it."""
    with Bag1Writer(path) as writer:
        connections: dict[str, object] = {}
        for topic, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ROS1)
            ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            writer.write(connections[topic], ns, ROS1.serialize_ros1(msg, msg.__msgtype__))
    return path
