"""Odometry and JointState read from their serialised form (CDR), and Odometry written in it.

A subscription with ``raw=True`` gets the bytes the middleware received. rclpy's own reading of an
Odometry (deserialisation to its C struct, then a Python object per nested message and a numpy array per
covariance) costs about 45 us, the controller's largest cost per control period, while it needs 13 numbers,
a stamp and two frame names: :func:`odometry_fields_from_cdr` reads those in about 1 us.

The fast path reads plain little-endian CDR (encapsulation 0x0001, what Fast DDS sends for ROS types):
the header's stamp (int32 sec, uint32 nanosec) and frame_id, child_frame_id, then, aligned to 8 bytes
from the start of the payload, the pose (7 doubles), its covariance (36), the twist (6) and its
covariance (36). Strings are a uint32 length counting their terminating NUL, then the bytes. Anything
else (big-endian, XCDR2, a length that does not fit) goes to rclpy's deserialiser, which reads every
encoding the middleware does and raises on bytes that are no Odometry: those are refused with the reason.

:class:`OdometryWriter` is the other way: a publisher given bytes publishes them as they are (rclpy's
``publish`` of a message object converts it and serialises it, about 10 us for an Odometry), so the
simulator keeps each vehicle's Odometry serialised once, with its frames and covariances, and writes the
stamp, pose and twist of each state into a copy at the offsets this reader finds.

:func:`joint_state_fields_from_cdr` reads a JointState's stamp, names and velocities the same way (the
simulator takes a command per vehicle and control period; rclpy's reading costs 13 us for eight rotors):
after the header, the names (a uint32 count, then each string aligned to 4), then position, velocity and
effort, each a uint32 count aligned to 4 and its doubles aligned to 8. :class:`RotorCommandWriter`
writes the controller's command so: rclpy's ``publish`` of the JointState object cost 3 times the
publish of its bytes (35.6 against 13.1 us for eight rotors, a subscriber in another process).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from multirotor_ros.nodes.messages import odometry_values, rotor_names, stamp_to_ns
from multirotor_ros.refusals import Refusal

_LITTLE_ENDIAN_CDR = b"\x00\x01"
_ENCAPSULATION_BYTES = 4  # alignment counts from the end of the encapsulation header
_STAMP = struct.Struct("<iI")
_LENGTH = struct.Struct("<I")
_POSE = struct.Struct("<7d")  # position (x, y, z), orientation (x, y, z, w)
_TWIST = struct.Struct("<6d")  # linear, angular
_COVARIANCE_BYTES = 36 * 8
_AFTER_FRAMES_BYTES = _POSE.size + _COVARIANCE_BYTES + _TWIST.size + _COVARIANCE_BYTES


class OdometryFields(NamedTuple):
    """What a controller reads of an Odometry."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    # Position, orientation (x, y, z, w), body twist (linear, angular): state_from_odometry_values.
    values: tuple[float, ...]


def odometry_fields(message: Any) -> OdometryFields:
    """The fields of an Odometry message object."""
    return OdometryFields(
        stamp_to_ns(message.header.stamp),
        message.header.frame_id,
        message.child_frame_id,
        odometry_values(message),
    )


def odometry_fields_from_cdr(data: bytes) -> OdometryFields | Refusal:
    """The fields of a serialised Odometry (module docstring), or why it cannot be read."""
    return _read(data, _plain_little_endian, Odometry, odometry_fields, "odometry")


class JointStateFields(NamedTuple):
    """What the simulator reads of a rotor command (nodes/messages.py rotor_speeds_from_parts)."""

    stamp_ns: int
    names: tuple[str, ...]
    velocity: tuple[float, ...]


def joint_state_fields_from_cdr(data: bytes) -> JointStateFields | Refusal:
    """The fields of a serialised JointState (module docstring), or why it cannot be read."""
    return _read(data, _plain_little_endian_joint_state, JointState, joint_state_fields, "joint state")


def joint_state_fields(message: Any) -> JointStateFields:
    """The fields of a JointState message object."""
    return JointStateFields(stamp_to_ns(message.header.stamp), tuple(message.name), tuple(message.velocity))


def _read[Fields](
    data: bytes,
    plain: Callable[[bytes], Fields | None],
    message_type: Any,
    fields_of: Callable[[Any], Fields],
    what: str,
) -> Fields | Refusal:
    """``plain`` of the bytes, else the fields of rclpy's reading of them, else why neither can read them."""
    fields = plain(data)
    if fields is not None:
        return fields
    try:
        message = deserialize_message(data, message_type)
    except Exception as error:  # whatever rclpy's deserialiser says of bytes it cannot read
        return Refusal(f"malformed {what}", f"{len(data)} bytes that are no {message_type.__name__}: {error}")
    return fields_of(message)


class OdometryWriter:
    """Serialised Odometry messages of one template (frames, covariances) with a new stamp, pose and twist."""

    def __init__(self, template: Odometry):
        self._data = bytearray(serialize_message(template))
        frames = _frames(bytes(self._data))
        if frames is None:  # Fast DDS serialises ROS types as plain little-endian CDR
            raise ValueError("rclpy did not serialise the Odometry as plain little-endian CDR")
        self._pose_offset = frames[3]
        self._twist_offset = self._pose_offset + _POSE.size + _COVARIANCE_BYTES

    @property
    def serialised(self) -> bytes:
        """The message last written (the template before any): its length and layout are every one's."""
        return bytes(self._data)

    def write(self, stamp: Any, values: tuple[float, ...]) -> bytes:
        """The template stamped ``stamp`` (builtin_interfaces/Time) with the 13 values of odometry_values."""
        self.write_into(self._data, 0, stamp, values)
        return bytes(self._data)

    def write_into(self, buffer: bytearray, start: int, stamp: Any, values: tuple[float, ...]) -> None:
        """:meth:`write` into a copy of :attr:`serialised` that begins at ``start`` of ``buffer``."""
        _STAMP.pack_into(buffer, start + _ENCAPSULATION_BYTES, stamp.sec, stamp.nanosec)
        _POSE.pack_into(buffer, start + self._pose_offset, *values[:7])
        _TWIST.pack_into(buffer, start + self._twist_offset, *values[7:])


class RotorCommandWriter:
    """Serialised JointState rotor commands (rotor_1..rotor_N, the speeds as ``velocity``), newly stamped.

    What nodes/messages.py ``joint_state_from_rotor_speeds`` makes, serialised once; each command is a copy
    with the stamp and the velocities written at the offsets the reader finds.
    """

    def __init__(self, n_rotors: int):
        self._data = bytearray(
            serialize_message(JointState(name=rotor_names(n_rotors), velocity=[0.0] * n_rotors))
        )
        self._speeds = struct.Struct(f"<{n_rotors}d")
        layout = _joint_state_layout(bytes(self._data))
        if layout is None:
            raise ValueError("rclpy did not serialise the JointState as plain little-endian CDR")
        self._speeds_offset = layout[2][1][1]  # velocity's first double

    def write(self, stamp_ns: int, speeds_rad_s: Sequence[float]) -> bytes:
        """The command stamped ``stamp_ns`` with the rotors' speeds [rad/s], in rotor order."""
        _STAMP.pack_into(self._data, _ENCAPSULATION_BYTES, *divmod(stamp_ns, 1_000_000_000))
        self._speeds.pack_into(self._data, self._speeds_offset, *speeds_rad_s)
        return bytes(self._data)


def _plain_little_endian(data: bytes) -> OdometryFields | None:
    frames = _frames(data)
    if frames is None or len(data) < frames[3] + _AFTER_FRAMES_BYTES:
        return None
    stamp_ns, frame_id, child_frame_id, offset = frames
    pose = _POSE.unpack_from(data, offset)
    twist = _TWIST.unpack_from(data, offset + _POSE.size + _COVARIANCE_BYTES)
    return OdometryFields(stamp_ns, frame_id, child_frame_id, pose + twist)


def _plain_little_endian_joint_state(data: bytes) -> JointStateFields | None:
    layout = _joint_state_layout(data)
    if layout is None:
        return None
    stamp_ns, names, (_, (count, offset), _) = layout
    return JointStateFields(stamp_ns, names, struct.unpack_from(f"<{count}d", data, offset))


def _joint_state_layout(data: bytes) -> tuple[int, tuple[str, ...], list[tuple[int, int]]] | None:
    """A JointState's stamp [ns], names, and the length and offset of position, velocity and effort."""
    header = _header(data)
    if header is None:
        return None
    stamp_ns, _, offset = header
    read = _NAMES.read(data, offset)
    if read is None:
        return None
    names, offset = read
    sequences = []
    for _ in range(3):  # position, velocity, effort
        count, offset = _count(data, offset)
        if count is None:
            return None
        if count:
            offset += _padding(offset, 8)
        end = offset + 8 * count
        if end > len(data):
            return None
        sequences.append((count, offset))
        offset = end
    return stamp_ns, names, sequences


class _LastNames:
    """A JointState's names, read again only when their bytes differ from the last ones read.

    A rotor command names the same rotors every time, and reading eight strings was half of the reading
    of a command. The names read depend only on their bytes and where they start (the alignment).
    """

    def __init__(self) -> None:
        self._last: tuple[int, bytes, tuple[str, ...]] | None = None  # (start, their bytes, names)

    def read(self, data: bytes, start: int) -> tuple[tuple[str, ...], int] | None:
        """The names (a count, then the strings) at ``start``, and the offset after them; None: unreadable."""
        last = self._last
        if last is not None and last[0] == start and data.startswith(last[1], start):
            return last[2], start + len(last[1])
        count, offset = _count(data, start)
        if count is None:
            return None
        names = []
        for _ in range(count):
            name, offset = _string(data, offset + _padding(offset, 4))
            if name is None:
                return None
            names.append(name)
        self._last = (start, data[start:offset], tuple(names))
        return self._last[2], offset


_NAMES = _LastNames()


def _count(data: bytes, offset: int) -> tuple[int | None, int]:
    """A sequence's length at ``offset`` (aligned to 4 first) and the offset after it."""
    offset += _padding(offset, 4)
    if len(data) < offset + _LENGTH.size:
        return None, offset
    return _LENGTH.unpack_from(data, offset)[0], offset + _LENGTH.size


def _header(data: bytes) -> tuple[int, str, int] | None:
    """The std_msgs/Header of plain little-endian CDR: stamp [ns], frame_id and the offset after them."""
    if data[:2] != _LITTLE_ENDIAN_CDR or len(data) < _ENCAPSULATION_BYTES + _STAMP.size:
        return None
    sec, nanosec = _STAMP.unpack_from(data, _ENCAPSULATION_BYTES)
    frame_id, offset = _string(data, _ENCAPSULATION_BYTES + _STAMP.size)
    return None if frame_id is None else (sec * 1_000_000_000 + nanosec, frame_id, offset)


def _frames(data: bytes) -> tuple[int, str, str, int] | None:
    """An Odometry's stamp [ns], frame_id, child_frame_id and the offset of the pose after them."""
    header = _header(data)
    if header is None:
        return None
    stamp_ns, frame_id, offset = header
    child_frame_id, offset = _string(data, offset + _padding(offset, 4))
    if child_frame_id is None:
        return None
    return stamp_ns, frame_id, child_frame_id, offset + _padding(offset, 8)


def _padding(offset: int, alignment: int) -> int:
    return -(offset - _ENCAPSULATION_BYTES) % alignment


def _string(data: bytes, offset: int) -> tuple[str | None, int]:
    """A CDR string at ``offset`` and the offset after it; None where the bytes are no such string."""
    if len(data) < offset + _LENGTH.size:
        return None, offset
    (length,) = _LENGTH.unpack_from(data, offset)
    end = offset + _LENGTH.size + length
    if length == 0 or end > len(data) or data[end - 1] != 0:
        return None, offset
    # rclpy reads a string as C does, up to its first NUL: b"a\0b" is "a", as any ROS node sees it.
    text, _, _ = data[offset + _LENGTH.size : end - 1].partition(b"\0")
    try:
        return text.decode(), end
    except UnicodeDecodeError:
        return None, offset
