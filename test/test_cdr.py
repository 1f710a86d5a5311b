"""Odometry read from its serialised form (nodes/cdr.py) against rclpy's own reading of the same bytes."""

from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from hypothesis import example, given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from multirotor_ros.nodes import cdr
from multirotor_ros.nodes.cdr import (
    JointStateFields,
    joint_state_fields,
    joint_state_fields_from_cdr,
    odometry_fields,
    odometry_fields_from_cdr,
)
from multirotor_ros.nodes.messages import (
    joint_state_from_rotor_speeds,
    odometry_message,
    odometry_values_of_state,
)
from multirotor_ros.refusals import Refusal

FRAMES = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
VALUES = st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=13, max_size=13)
STAMP = {"sec": st.integers(-(2**31), 2**31 - 1), "nanosec": st.integers(0, 2**32 - 1)}


def _odometry(frame_id: str, child_frame_id: str, values: list[float], sec: int, nanosec: int) -> Odometry:
    message = Odometry()
    message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
    message.header.frame_id, message.child_frame_id = frame_id, child_frame_id
    pose, twist = message.pose.pose, message.twist.twist
    for target, fields, chunk in (
        (pose.position, "xyz", values[0:3]),
        (pose.orientation, "xyzw", values[3:7]),
        (twist.linear, "xyz", values[7:10]),
        (twist.angular, "xyz", values[10:13]),
    ):
        for name, value in zip(fields, chunk, strict=True):
            setattr(target, name, value)
    message.pose.covariance[:] = 1.5  # read past, whatever they hold
    message.twist.covariance[:] = -2.5
    return message


def _same(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


@given(frame_id=FRAMES, child_frame_id=FRAMES, values=VALUES, **STAMP)
@settings(max_examples=300)
def test_the_serialised_odometry_reads_as_rclpys_message_does(
    frame_id: str, child_frame_id: str, values: list[float], sec: int, nanosec: int
) -> None:
    message = _odometry(frame_id, child_frame_id, values, sec, nanosec)
    data = serialize_message(message)
    assert cdr._plain_little_endian(data) is not None  # the fast path, not the fallback
    read, expected = odometry_fields_from_cdr(data), odometry_fields(message)
    assert not isinstance(read, Refusal)
    assert read[:3] == expected[:3] and _same(read.values, expected.values)


def _rclpys_reading(data: bytes) -> cdr.OdometryFields | None:
    try:
        return odometry_fields(deserialize_message(data, Odometry))
    except Exception:  # what rclpy raises for bytes it cannot read
        return None


VALID = serialize_message(_odometry("odom", "base_link", [0.5] * 13, 7, 8))


@given(
    cut=st.integers(0, len(VALID)),
    changes=st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.integers(0, 255)), max_size=4),
)
@settings(max_examples=500)
def test_damaged_bytes_are_refused_with_the_reason_or_read_as_rclpy_reads_them(cut: int, changes) -> None:
    data = bytearray(VALID[:cut])
    for index, value in changes:
        if index < len(data):
            data[index] = value
    read, expected = odometry_fields_from_cdr(bytes(data)), _rclpys_reading(bytes(data))
    if isinstance(read, Refusal):
        assert expected is None
        assert read.reason == "malformed odometry" and f"{len(data)} bytes" in read.detail
    else:
        assert expected is not None and read[:3] == expected[:3] and _same(read.values, expected.values)


def test_a_truncated_or_foreign_encoding_goes_to_rclpys_reader() -> None:
    data = serialize_message(_odometry("odom", "base_link", [0.0] * 6 + [1.0] + [0.0] * 6, 3, 4))
    assert isinstance(odometry_fields_from_cdr(data[:-8]), Refusal)  # cut in the twist's covariance
    assert cdr._plain_little_endian(b"\x00\x00" + data[2:]) is None  # big-endian: not read here
    long_string = data[:12] + (10_000).to_bytes(4, "little") + data[16:]
    assert isinstance(odometry_fields_from_cdr(long_string), Refusal)


@given(
    frame_id=FRAMES,
    child_frame_id=FRAMES,
    state=st.lists(st.floats(-1e6, 1e6), min_size=13, max_size=13),
    sec=st.integers(0, 2**31 - 1),
    nanosec=st.integers(0, 999_999_999),
)
@settings(max_examples=200)
def test_the_writer_gives_the_bytes_rclpy_serialises_for_the_same_message(
    frame_id: str, child_frame_id: str, state: list[float], sec: int, nanosec: int
) -> None:
    template = Odometry()
    template.header.frame_id, template.child_frame_id = frame_id, child_frame_id
    template.pose.covariance[:] = np.arange(36.0)
    template.twist.covariance[:] = -np.arange(36.0)
    writer = cdr.OdometryWriter(template)
    stamp = Time(sec=sec, nanosec=nanosec)
    x = np.array(state)
    # Read back by rclpy (byte for byte would compare the padding, which Fast CDR leaves uninitialised).
    written = deserialize_message(writer.write(stamp, odometry_values_of_state(x)), Odometry)
    expected = odometry_message(x, stamp, frame_id, child_frame_id, out=template)
    assert written == expected and odometry_fields(written) == odometry_fields(expected)


@given(
    speeds=st.lists(st.floats(allow_nan=False), min_size=1, max_size=12),
    sec=st.integers(0, 2**31 - 1),
    nanosec=st.integers(0, 999_999_999),
)
@settings(max_examples=200)
def test_the_command_writer_gives_what_rclpy_serialises_for_the_controllers_joint_state(
    speeds: list[float], sec: int, nanosec: int
) -> None:
    writer = cdr.RotorCommandWriter(len(speeds))
    data = writer.write(sec * 1_000_000_000 + nanosec, speeds)
    expected = joint_state_from_rotor_speeds(speeds, Time(sec=sec, nanosec=nanosec))
    assert deserialize_message(data, JointState) == expected
    assert cdr._plain_little_endian_joint_state(data) == joint_state_fields(expected)  # the simulator's path


DOUBLES = st.lists(st.floats(allow_nan=False), max_size=10)


@given(
    frame_id=FRAMES,
    names=st.lists(FRAMES, max_size=10),
    position=DOUBLES,
    velocity=DOUBLES,
    effort=DOUBLES,
    **STAMP,
)
@settings(max_examples=300)
def test_a_serialised_joint_state_reads_as_rclpys_message_does(
    frame_id: str, names: list[str], position, velocity, effort, sec: int, nanosec: int
) -> None:
    message = JointState(name=names, position=position, velocity=velocity, effort=effort)
    message.header.frame_id = frame_id
    message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
    data = serialize_message(message)
    assert cdr._plain_little_endian_joint_state(data) is not None  # the fast path, not the fallback
    assert joint_state_fields_from_cdr(data) == JointStateFields(
        sec * 1_000_000_000 + nanosec, tuple(names), tuple(velocity)
    )


VALID_COMMAND = serialize_message(JointState(name=[f"rotor_{k}" for k in range(1, 9)], velocity=[300.0] * 8))


@given(
    cut=st.integers(0, len(VALID_COMMAND)),
    changes=st.lists(st.tuples(st.integers(0, len(VALID_COMMAND) - 1), st.integers(0, 255)), max_size=4),
)
@settings(max_examples=500)
# A NUL inside a name (found by hypothesis in CI): rclpy reads the name up to it, as C does.
@example(cut=len(VALID_COMMAND), changes=[(VALID_COMMAND.index(b"rotor_2"), 0)])
def test_a_damaged_joint_state_is_refused_with_the_reason_or_read_as_rclpy_reads_it(
    cut: int, changes
) -> None:
    data = bytearray(VALID_COMMAND[:cut])
    for index, value in changes:
        if index < len(data):
            data[index] = value
    read = joint_state_fields_from_cdr(bytes(data))
    try:
        expected: JointStateFields | None = joint_state_fields(deserialize_message(bytes(data), JointState))
    except Exception:  # what rclpy raises for bytes it cannot read
        expected = None
    if isinstance(read, Refusal):
        assert expected is None and read.reason == "malformed joint state"
    else:
        assert expected is not None and read[:2] == expected[:2] and _same(read.velocity, expected.velocity)
