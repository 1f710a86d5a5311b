"""rosbag2 recording of this package's topics (interfaces.md) -> flight log, read with ``rosbags``.

Both storage formats (sqlite3 ``.db3`` and ``.mcap``) are read; the bag is the directory holding
``metadata.yaml``. Topics are looked up under a namespace (``--namespace /uav1`` for
``/uav1/odom``); without one, the root namespace is used, or the only namespace that has ``odom``
or ``pose``.

- ``odom`` (nav_msgs/Odometry) is the time base: pose in world ENU -> x, y, z and roll, pitch,
  yaw; twist in body FLU (REP-105) -> world velocity v_W = R_WB·v_B (vx, vy, vz) and p, q, r.
  Without ``odom``, ``pose`` (geometry_msgs/PoseStamped) is the time base (x, y, z, attitude) and
  p, q, r come from ``imu``.
- ``motor_speeds`` (sensor_msgs/JointState, ``rotor_k`` names, rad/s) -> omega_k, linear
  interpolation; ``motor_speed_cmd`` -> omega_cmd_k, zero-order hold (commands are piecewise constant).
- ``imu`` (sensor_msgs/Imu) -> imu_fx, imu_fy, imu_fz (specific force) and imu_p, imu_q, imu_r
  (gyro), body FLU, linear interpolation.
- ``range`` (sensor_msgs/Range) -> range, linear interpolation.

Stamps are the messages' header stamps; a topic whose header stamps are all zero uses the bag's
receive times instead (the metadata says so). Messages that do not fit (wrong rotor names or count)
are skipped and counted in a warning, never guessed.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from multirotor_ros.io.flight_log import FlightLog, rotor_columns
from multirotor_ros.io.log_builder import ConversionError, LogBuilder
from multirotor_ros.io.resample import sort_unique
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import quat_to_matrix

TOPIC_TYPES = {
    "odom": "nav_msgs/msg/Odometry",
    "pose": "geometry_msgs/msg/PoseStamped",
    "motor_speeds": "sensor_msgs/msg/JointState",
    "motor_speed_cmd": "sensor_msgs/msg/JointState",
    "imu": "sensor_msgs/msg/Imu",
    "range": "sensor_msgs/msg/Range",
}


def bag_directory(path: Path) -> Path:
    """The rosbag2 directory: ``path`` itself, or the directory of a .mcap/.db3 file inside one."""
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    if path.is_file() and (path.parent / "metadata.yaml").is_file():
        return path.parent
    raise ConversionError(f"{path}: not a rosbag2 directory (no metadata.yaml beside the recording)")


def resolve_namespace(topics: set[str], namespace: str | None) -> str:
    """'' or '/ns': where this package's topics are in the bag."""
    if namespace is not None:
        stripped = namespace.strip("/")
        return f"/{stripped}" if stripped else ""
    bases = sorted(
        {topic.rsplit("/", 1)[0] for topic in topics if topic.rsplit("/", 1)[-1] in ("odom", "pose")}
    )
    if "" in bases or not bases:
        return ""
    if len(bases) == 1:
        return bases[0]
    raise ConversionError(f"several vehicles in the bag ({', '.join(bases)}): choose one with --namespace")


def _stamp(message: Any) -> float:
    stamp = message.header.stamp
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


class _Topic:
    """One topic's samples: stamps [s] and rows of values."""

    def __init__(self, name: str):
        self.name = name
        self.header_stamps: list[float] = []
        self.bag_stamps: list[float] = []
        self.rows: list[list[float]] = []
        self.skipped = 0

    def arrays(self) -> tuple[np.ndarray, np.ndarray, str]:
        header = np.array(self.header_stamps)
        use_bag = header.size > 0 and not np.any(header)
        stamps = np.array(self.bag_stamps) if use_bag else header
        ts, values, _ = sort_unique(stamps, np.array(self.rows, dtype=float))
        return ts, values, "bag receive time (header stamps are zero)" if use_bag else "header stamps"


def _joint_row(message: Any, n_rotors: int) -> list[float] | None:
    expected = rotor_columns("rotor", n_rotors)
    if sorted(message.name) != sorted(expected) or len(message.velocity) != len(message.name):
        return None
    by_name = dict(zip(message.name, message.velocity, strict=True))
    return [float(by_name[name]) for name in expected]


def _read_topics(bag: Path, namespace: str | None, n_rotors: int) -> tuple[dict[str, _Topic], str]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    extractors: dict[str, Callable[[Any], list[float] | None]] = {
        "odom": lambda m: [
            m.pose.pose.position.x,
            m.pose.pose.position.y,
            m.pose.pose.position.z,
            m.pose.pose.orientation.w,
            m.pose.pose.orientation.x,
            m.pose.pose.orientation.y,
            m.pose.pose.orientation.z,
            m.twist.twist.linear.x,
            m.twist.twist.linear.y,
            m.twist.twist.linear.z,
            m.twist.twist.angular.x,
            m.twist.twist.angular.y,
            m.twist.twist.angular.z,
        ],  # fmt: skip
        "pose": lambda m: [
            m.pose.position.x,
            m.pose.position.y,
            m.pose.position.z,
            m.pose.orientation.w,
            m.pose.orientation.x,
            m.pose.orientation.y,
            m.pose.orientation.z,
        ],  # fmt: skip
        "motor_speeds": lambda m: _joint_row(m, n_rotors),
        "motor_speed_cmd": lambda m: _joint_row(m, n_rotors),
        "imu": lambda m: [
            m.linear_acceleration.x,
            m.linear_acceleration.y,
            m.linear_acceleration.z,
            m.angular_velocity.x,
            m.angular_velocity.y,
            m.angular_velocity.z,
        ],  # fmt: skip
        "range": lambda m: [m.range],
    }
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as error:  # rosbags raises its own errors for unreadable or unknown storage
        raise ConversionError(f"{bag}: cannot open the rosbag2: {error}") from None
    try:
        all_topics = {connection.topic for connection in reader.connections}
        prefix = resolve_namespace(all_topics, namespace)
        wanted = {f"{prefix}/{name}": name for name in TOPIC_TYPES}
        connections = []
        for connection in reader.connections:
            name = wanted.get(connection.topic)
            if name is None:
                continue
            if connection.msgtype != TOPIC_TYPES[name]:
                raise ConversionError(
                    f"{bag}: topic {connection.topic} has type {connection.msgtype}, "
                    f"expected {TOPIC_TYPES[name]}"
                )
            connections.append(connection)
        topics = {name: _Topic(name) for name in TOPIC_TYPES}
        # rosbags reads every connection when given none: an empty selection must read nothing.
        messages = reader.messages(connections=connections) if connections else iter(())
        for connection, bag_time_ns, raw in messages:
            topic = topics[wanted[connection.topic]]
            message = reader.deserialize(raw, connection.msgtype)
            row = extractors[topic.name](message)
            if row is None:
                topic.skipped += 1
                continue
            topic.header_stamps.append(_stamp(message))
            topic.bag_stamps.append(bag_time_ns * 1e-9)
            topic.rows.append(row)
    finally:
        reader.close()
    return {name: topic for name, topic in topics.items() if topic.rows or topic.skipped}, prefix


def convert_rosbag2(
    path: str | Path, airframe: Airframe, namespace: str | None = None
) -> tuple[FlightLog, list[str]]:
    """Convert a rosbag2 of this package's topics; returns the log and warnings for the user."""
    bag = bag_directory(Path(path))
    n = airframe.n_rotors
    topics, prefix = _read_topics(bag, namespace, n)
    warnings = [
        f"{prefix}/{t.name}: {t.skipped} messages skipped "
        f"(names must be rotor_1..rotor_{n}, one velocity each)"
        for t in topics.values()
        if t.skipped
    ]
    found = ", ".join(f"{prefix}/{name}" for name in topics) or "none"
    stamp_sources: dict[str, str] = {}

    def arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
        ts, values, source = topics[name].arrays()
        stamp_sources[name] = source
        return ts, values

    base_name = "odom" if "odom" in topics else "pose" if "pose" in topics else None
    if base_name is None or not topics[base_name].rows:
        raise ConversionError(f"{bag}: no {prefix}/odom or {prefix}/pose messages (topics found: {found})")
    if "motor_speeds" not in topics or not topics["motor_speeds"].rows:
        raise ConversionError(
            f"{bag}: no usable {prefix}/motor_speeds messages, so no rotor group (topics found: {found})"
        )
    t, base = arrays(base_name)
    builder = LogBuilder(t, f"{prefix}/{base_name} stamps")
    builder.put(["x", "y", "z"], base[:, 0:3])
    q_WB = base[:, 3:7] / np.linalg.norm(base[:, 3:7], axis=1, keepdims=True)
    builder.put_attitude(t, q_WB, f"{prefix}/{base_name} orientation")
    if base_name == "odom":
        builder.put(["vx", "vy", "vz"], np.einsum("nij,nj->ni", quat_to_matrix(q_WB), base[:, 7:10]))
        builder.put(["p", "q", "r"], base[:, 10:13])
        builder.metadata["derived"] = (
            "vx,vy,vz = R_WB * odom twist.linear (body FLU -> world ENU); p,q,r = twist.angular"
        )

    ts, speeds = arrays("motor_speeds")
    builder.put_stream(rotor_columns("omega", n), ts, speeds, "linear", f"{prefix}/motor_speeds")
    builder.metadata["omega_source"] = "measured (motor_speeds topic)"
    if "motor_speed_cmd" in topics and topics["motor_speed_cmd"].rows:
        ts, commands = arrays("motor_speed_cmd")
        builder.put_stream(rotor_columns("omega_cmd", n), ts, commands, "hold", f"{prefix}/motor_speed_cmd")
    if "imu" in topics:
        ts, imu = arrays("imu")
        builder.put_stream(
            ["imu_fx", "imu_fy", "imu_fz"], ts, imu[:, :3], "linear", f"{prefix}/imu linear_acceleration"
        )
        rate_names = ["imu_p", "imu_q", "imu_r"] if base_name == "odom" else ["p", "q", "r"]
        builder.put_stream(rate_names, ts, imu[:, 3:], "linear", f"{prefix}/imu angular_velocity")
        builder.metadata["imu_columns"] = (
            f"imu_fx..imu_fz: specific force, {', '.join(rate_names)}: gyro; "
            "body FLU, with the sensor's noise"
        )
    if "range" in topics:
        ts, ranges = arrays("range")
        builder.put_stream(["range"], ts, ranges, "linear", f"{prefix}/range")
    first = {
        "source": "rosbag2",
        "converted_from": f"{bag.name} (rosbag2; topics {found})",
        "airframe": airframe.name,
        "namespace": prefix or "/",
        "stamps": "; ".join(f"{name}: {source}" for name, source in stamp_sources.items()),
    }
    return builder.build(first), warnings
