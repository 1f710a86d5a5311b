"""Malformed MAVLink input, seeded: what the fuzz tests and ``bench/bench_mavlink.py`` send to every port.

:func:`malformed_frames` gives ``count`` frames (one datagram, or one write on a stream), each with the
kind of damage it carries, drawn evenly from :data:`MALFORMED_KINDS`:

- ``random bytes``: 1..300 random bytes, half of them starting with the MAVLink 2 marker;
- ``truncated``: a valid packet cut short;
- ``bad CRC``: a valid packet with one byte after the header changed;
- ``unknown id``: a packet with a message id no dialect defines;
- ``oversized``: 1..4 kB (a MAVLink packet has at most 280 bytes) of valid packets run together with
  garbage between them;
- ``hostile fields``: well-formed packets addressed to the vehicle whose values are NaN, +-inf, 3.4e38
  or out of every range: setpoints, SET_MESSAGE_INTERVAL at 1 us, actuator controls.

Every frame except ``hostile fields`` is refused by the codec; hostile fields are refused by the
handler that reads them (a setpoint, an interval), or ignored when the message is not for the link.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.wire import Message

MALFORMED_KINDS = ("random bytes", "truncated", "bad CRC", "unknown id", "oversized", "hostile fields")
# What a float32 field can carry at its worst (1e39 does not fit: senders cannot pack it).
HOSTILE_NUMBERS = (math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e30)
HEADER_LEN = 10  # MAVLink 2 header up to and including the message id
UNKNOWN_MESSAGE_ID = 60000  # no dialect defines it
VALID_POOL_SIZE = 32


class _Collector:
    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data = bytes(data)


class _Sender:
    """A ground station / flight stack that packs what it is given (pymavlink packs NaN and inf)."""

    def __init__(self, target_system: int):
        self.target = target_system
        self.mav = mavlink2.MAVLink(_Collector(), 255, 190)

    def pack(self, message: Message) -> bytes:
        self.mav.send(message)
        return bytes(self.mav.file.data)

    def valid(self, rng: np.random.Generator) -> bytes:
        mav = self.mav
        choices = (
            lambda: mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0),
            lambda: mav.timesync_encode(0, int(rng.integers(1, 2**62))),
            lambda: mav.set_position_target_local_ned_encode(
                0, self.target, 1, 1, 0b1101_1111_1000, 1.0, 2.0, -3.0, 0, 0, 0, 0, 0, 0, 0, 0
            ),
        )
        return self.pack(choices[int(rng.integers(len(choices)))]())

    def hostile(self, rng: np.random.Generator) -> bytes:
        mav = self.mav

        def number() -> float:
            return float(HOSTILE_NUMBERS[int(rng.integers(len(HOSTILE_NUMBERS)))])

        choices = (
            lambda: mav.set_position_target_local_ned_encode(
                0,
                self.target,
                1,
                1,
                0b1001_1111_1000,
                number(),
                number(),
                number(),
                0,
                0,
                0,
                0,
                0,
                0,
                number(),
                0,
            ),
            lambda: mav.command_long_encode(
                self.target, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0, 1, 0, 0, 0, 0, 0
            ),
            lambda: mav.command_long_encode(
                self.target, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, number(), number(), 0, 0, 0, 0, 0
            ),
            lambda: mav.hil_actuator_controls_encode(1, [number()] * 16, 128, 1),
        )
        return self.pack(choices[int(rng.integers(len(choices)))]())


def malformed_frames(count: int, seed: int, target_system: int = 1) -> list[tuple[str, bytes]]:
    """``count`` (kind, frame) pairs, the same for the same arguments (see the module docstring)."""
    rng = np.random.default_rng(seed)
    sender = _Sender(target_system)
    valid = [sender.valid(rng) for _ in range(VALID_POOL_SIZE)]  # packing is the slow part: reuse

    def any_valid() -> bytes:
        return valid[int(rng.integers(VALID_POOL_SIZE))]

    frames = []
    for index in range(count):
        kind = MALFORMED_KINDS[index % len(MALFORMED_KINDS)]
        if kind == "random bytes":
            frame = rng.bytes(int(rng.integers(1, 301)))
            if rng.random() < 0.5:
                frame = bytes([mavlink2.PROTOCOL_MARKER_V2]) + frame
        elif kind == "truncated":
            packet = any_valid()
            frame = packet[: int(rng.integers(1, len(packet)))]
        elif kind == "bad CRC":
            damaged = bytearray(any_valid())
            position = int(rng.integers(HEADER_LEN, len(damaged)))
            damaged[position] ^= int(rng.integers(1, 256))
            frame = bytes(damaged)
        elif kind == "unknown id":
            damaged = bytearray(any_valid())
            damaged[7:10] = UNKNOWN_MESSAGE_ID.to_bytes(3, "little")
            frame = bytes(damaged)
        elif kind == "oversized":
            run = bytearray()
            size = int(rng.integers(1024, 4097))
            while len(run) < size:
                run += any_valid() + rng.bytes(int(rng.integers(1, 40)))
            frame = bytes(run)
        else:
            frame = sender.hostile(rng)
        frames.append((kind, frame))
    return frames
