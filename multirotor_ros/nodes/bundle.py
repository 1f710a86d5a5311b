"""Fleet bundles: every vehicle's message of one instant in one message (issue 10's fleet at 250 Hz).

Ten vehicles at 250 Hz exchange 2,500 odometries and 2,500 commands a second each way, and on a 2-core
machine the middleware's work per message (a reliable writer's publish, the executor's dispatch of each
one to Python) sets the limit, not the physics or the control law (README, "Fleet over ROS"). A bundle
carries the same serialised messages, one per vehicle, in one std_msgs/UInt8MultiArray: the simulator
publishes ``fleet/odom`` once per instant after the last vehicle's state (while somebody listens), a
``fleet_controller`` with ``bundles`` on answers on ``fleet/motor_speed_cmd``. Each vehicle's own topics
stay as they are, for everyone else (an identifier, a mission, a visualizer, ``ros2 topic echo``).

Layout of the array's ``data``: entries one after another, each

    uint32 vehicle index (the position in the simulator's ``vehicles``, from 0), little-endian
    uint32 length of the message in bytes
    the message, serialised as on the vehicle's own topic (CDR with its 4-byte encapsulation header)
    zero bytes up to the next multiple of 4

The array's layout (``dim``, ``data_offset``) is empty and unused. A bundle that breaks this layout is
refused with the reason and the byte where it broke; an entry's message is then read and checked as the
vehicle's own topic would read and check it.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Iterable, Sequence
from typing import Any

from rclpy.serialization import deserialize_message
from std_msgs.msg import UInt8MultiArray

from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.nodes.cdr import OdometryWriter
from multirotor_ros.nodes.messages import odometry_values_of_state
from multirotor_ros.refusals import Refusal

BUNDLE_TYPE = UInt8MultiArray
FLEET_ODOM_TOPIC = "fleet/odom"
FLEET_COMMAND_TOPIC = "fleet/motor_speed_cmd"

# Little-endian CDR, then the empty layout (no dims, data_offset 0), then the data's byte count.
_HEAD = struct.Struct("<4sIII")
_LITTLE_ENDIAN_CDR = b"\x00\x01\x00\x00"
_ENTRY = struct.Struct("<II")


def bundle_cdr(entries: Iterable[tuple[int, bytes]]) -> bytes:
    """A serialised UInt8MultiArray carrying ``(vehicle index, serialised message)`` entries."""
    return b"".join(_bundle_parts(entries))


def _bundle_parts(entries: Iterable[tuple[int, bytes]]) -> list[bytes]:
    """:func:`bundle_cdr` in pieces: the array's head, then each entry's head, message and padding."""
    parts = [b""]
    for index, message in entries:
        parts += [_ENTRY.pack(index, len(message)), message, bytes(-len(message) % 4)]
    parts[0] = _HEAD.pack(_LITTLE_ENDIAN_CDR, 0, 0, sum(len(part) for part in parts))
    return parts


class OdometryBundleWriter:
    """The fleet's odometries of one instant as a bundle, each vehicle's written in place.

    One buffer for all of them, laid out once from each vehicle's :class:`OdometryWriter` (its frames
    and covariances): a state costs its stamp, pose and twist written at their offsets, not a message of
    its own and a copy into the bundle.
    """

    def __init__(self, writers: Sequence[OdometryWriter]):
        self._writers = list(writers)
        parts = _bundle_parts(enumerate(writer.serialised for writer in self._writers))
        self._data = bytearray(b"".join(parts))
        # Where each vehicle's message starts: after the array's head and, for each entry, its own head.
        self._starts = list(itertools.accumulate(len(part) for part in parts))[1::3]

    def write(self, stamp: Any, states: Sequence[FloatArray]) -> bytes:
        """The bundle of the vehicles' ``states`` (flat, one per vehicle in order), all stamped ``stamp``."""
        for writer, start, x in zip(self._writers, self._starts, states, strict=True):
            writer.write_into(self._data, start, stamp, odometry_values_of_state(x))
        return bytes(self._data)


def bundle_entries(data: bytes, vehicles: int) -> list[tuple[int, bytes]] | Refusal:
    """The entries of a serialised bundle for ``vehicles`` vehicles, or why it is refused."""
    payload = _payload(data)
    if isinstance(payload, Refusal):
        return payload
    entries: list[tuple[int, bytes]] = []
    offset, end = 0, len(payload)
    while offset < end:
        if end - offset < _ENTRY.size:
            return Refusal("malformed bundle", f"{end - offset} bytes left at byte {offset}, no whole entry")
        index, length = _ENTRY.unpack_from(payload, offset)
        start = offset + _ENTRY.size
        if index >= vehicles:
            return Refusal("malformed bundle", f"vehicle index {index} at byte {offset}; {vehicles} vehicles")
        if length > end - start:
            return Refusal(
                "malformed bundle", f"entry at byte {offset} says {length} bytes, {end - start} are left"
            )
        entries.append((index, bytes(payload[start : start + length])))
        offset = start + length + (-length % 4)
    return entries


def _payload(data: bytes) -> memoryview | Refusal:
    """The array's data, or why it is refused.

    Read in place when plain little-endian CDR with an empty layout (what :func:`bundle_cdr` writes),
    else by rclpy's deserialiser, which reads every encoding the middleware does and raises on bytes that
    are no UInt8MultiArray.
    """
    view = memoryview(data)
    if len(data) >= _HEAD.size:
        encapsulation, dims, _, length = _HEAD.unpack_from(data)
        if encapsulation == _LITTLE_ENDIAN_CDR and dims == 0 and length <= len(data) - _HEAD.size:
            return view[_HEAD.size : _HEAD.size + length]
    try:
        message = deserialize_message(bytes(data), BUNDLE_TYPE)
    except Exception as error:  # noqa: BLE001 - the middleware's reader raises several kinds
        return Refusal("malformed bundle", f"not a UInt8MultiArray ({type(error).__name__}: {error})")
    return memoryview(bytes(message.data))
