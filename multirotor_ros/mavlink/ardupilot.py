"""ArduPilot's JSON external-physics interface (SITL ``--model JSON``, UDP 9002).

ArduPilot SITL sends a binary servo packet to UDP 9002 and waits for the answer before its next
frame (libraries/SITL/SIM_JSON.cpp, examples/JSON/readme.md). Little-endian:

    uint16 magic = 18458, uint16 frame_rate [Hz], uint32 frame_count, uint16 pwm[16] [us]   (40 bytes)
    uint16 magic = 29569, uint16 frame_rate [Hz], uint32 frame_count, uint16 pwm[32] [us]   (72 bytes)

The answer, sent back to the address the packet came from, is one line of JSON preceded and followed by
a newline. SITL's parser reads each value right after ``"key":``, so the JSON is written without
spaces. Fields: ``timestamp`` (simulated s), ``imu.gyro`` (rad/s, body FRD), ``imu.accel_body``
(specific force, m/s^2, FRD), ``position`` and ``velocity`` (NED, m and m/s, from home) and
``quaternion`` (w, x, y, z, body FRD -> NED).

Lockstep on the frame count: each new frame is one physics step of 1/frame_rate (in sub-steps when
that is long); a frame count that repeats is a resend after a lost answer, which gets the previous
answer again without stepping; a count that goes backwards means SITL restarted, and the vehicle is put
back to its initial state at t = 0. A gap (lost servo packets) is noted and flying continues.

Faults. Packets of the wrong size or magic, or with a frame rate of 0 or above 10 kHz, are refused and
counted. Packets from a second address while the current peer is active (heard from within
``peer_timeout_s``) are refused; after that silence the new address is taken as the peer reconnecting.
In external mode (physics in the simulator node) the answer to a frame is sent when the simulator
publishes a state newer than the one last sent.
"""

from __future__ import annotations

import json
import logging
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.messages import ned_view
from multirotor_ros.mavlink.vehicle import Simulation, VehicleState
from multirotor_ros.mavlink.wire import UdpEndpoint
from multirotor_ros.refusals import RefusalCounter

_LOGGER = logging.getLogger(__name__)

DEFAULT_PORT = 9002
SERVO_MAGIC_16 = 18458
SERVO_MAGIC_32 = 29569
SERVO_FORMAT_16 = struct.Struct("<HHI16H")
SERVO_FORMAT_32 = struct.Struct("<HHI32H")
MAX_FRAME_RATE_HZ = 10000


@dataclass(frozen=True)
class ServoPacket:
    """One decoded SITL output packet."""

    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple[int, ...]


def encode_servo_packet(frame_rate_hz: int, frame_count: int, pwm_us: list[int]) -> bytes:
    """The bytes SITL sends (16 or 32 channels by the length of ``pwm_us``): for peers and tests."""
    if len(pwm_us) == 16:
        return SERVO_FORMAT_16.pack(SERVO_MAGIC_16, frame_rate_hz, frame_count, *pwm_us)
    if len(pwm_us) == 32:
        return SERVO_FORMAT_32.pack(SERVO_MAGIC_32, frame_rate_hz, frame_count, *pwm_us)
    raise ValueError(f"a servo packet has 16 or 32 channels, not {len(pwm_us)}")


def decode_servo_packet(data: bytes) -> ServoPacket | tuple[str, str]:
    """A servo packet, or (refusal reason, detail)."""
    if len(data) == SERVO_FORMAT_16.size:
        values = SERVO_FORMAT_16.unpack(data)
        expected = SERVO_MAGIC_16
    elif len(data) == SERVO_FORMAT_32.size:
        values = SERVO_FORMAT_32.unpack(data)
        expected = SERVO_MAGIC_32
    else:
        return (
            "bad servo packet size",
            f"{len(data)} bytes, expected {SERVO_FORMAT_16.size} or {SERVO_FORMAT_32.size}",
        )
    magic, frame_rate, frame_count = values[:3]
    if magic != expected:
        return "bad servo magic", f"magic {magic} in a {len(data)}-byte packet, expected {expected}"
    if not 1 <= frame_rate <= MAX_FRAME_RATE_HZ:
        return "bad frame rate", f"frame rate {frame_rate} Hz outside 1..{MAX_FRAME_RATE_HZ}"
    return ServoPacket(frame_rate, frame_count, tuple(values[3:]))


def state_json_line(state: VehicleState) -> bytes:
    """The answer line for one state (see the module docstring)."""
    view = ned_view(state)
    document = {
        "timestamp": round(state.t_s, 9),
        "imu": {"gyro": _rounded(view.imu_gyro_FRD_rad_s), "accel_body": _rounded(view.imu_accel_FRD_m_s2)},
        "position": _rounded(view.p_NED_m),
        "velocity": _rounded(view.v_NED_m_s),
        "quaternion": _rounded(view.q_NED_FRD),
    }
    return ("\n" + json.dumps(document, separators=(",", ":")) + "\n").encode("ascii")


def _rounded(values: object) -> list[float]:
    return [round(float(v), 9) for v in values]  # type: ignore[attr-defined]


@dataclass(frozen=True)
class ArduPilotConfig:
    """Where to listen."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    peer_timeout_s: float = 2.0  # [s] silence after which another address may take over


class ArduPilotSession:
    """One ArduPilot SITL at a time on a UDP port; see the module docstring."""

    def __init__(
        self,
        config: ArduPilotConfig,
        simulation: Simulation,
        channels: RotorChannels,
        refusals: RefusalCounter,
        on_restart: Callable[[], None],
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.simulation = simulation
        self.channels = channels
        self.refusals = refusals
        self.on_restart = on_restart
        self.clock = clock
        self.endpoint = UdpEndpoint(config.host, config.port, self._on_datagram)
        self.peer: tuple[str, int] | None = None
        self.last_heard_s = -math.inf
        self.last_frame: int | None = None
        self.frames = 0
        self.missed_frames = 0
        self.restarts = 0
        self._last_reply = b""
        self._last_reply_t_s = -math.inf
        self._awaiting_state = False

    @property
    def connected(self) -> bool:
        """Whether a SITL has been heard from within the peer timeout."""
        return self.peer is not None and self.clock() - self.last_heard_s < self.config.peer_timeout_s

    def _on_datagram(self, data: bytes, address: tuple[str, int]) -> None:
        now = self.clock()
        if self.peer is not None and address != self.peer:
            if now - self.last_heard_s < self.config.peer_timeout_s:
                self.refusals.refuse(
                    "second peer", f"servo packet from {address[0]}:{address[1]} while {self.peer} is active"
                )
                return
            _LOGGER.warning("ArduPilot SITL now at %s:%d (was %s)", address[0], address[1], self.peer)
        packet = decode_servo_packet(data)
        if not isinstance(packet, ServoPacket):
            self.refusals.refuse(*packet)
            return
        if self.peer != address:
            _LOGGER.info("ArduPilot SITL connected from %s:%d", *address)
        self.peer, self.last_heard_s = address, now
        self._on_packet(packet)

    def _on_packet(self, packet: ServoPacket) -> None:
        last = self.last_frame
        if last is not None and packet.frame_count == last:
            self.refusals.refuse(
                "duplicate frame", f"frame {packet.frame_count} again: the last answer is resent"
            )
            if self._last_reply:
                self._send(self._last_reply)
            return
        if last is not None and packet.frame_count < last:
            self.restarts += 1
            _LOGGER.warning(
                "ArduPilot frame count went from %d to %d: SITL restarted, vehicle reset",
                last,
                packet.frame_count,
            )
            self.simulation.reset()
            self._last_reply_t_s = -math.inf
            self.on_restart()
        elif last is not None and packet.frame_count > last + 1:
            self.missed_frames += packet.frame_count - last - 1
        self.last_frame = packet.frame_count
        self.frames += 1
        command = self.channels.from_pwm(packet.pwm_us)
        for problem in command.problems:
            self.refusals.refuse(problem.reason, f"servo packet {packet.frame_count}: {problem.detail}")
        if command.speeds_rad_s is not None:
            self.simulation.command(command.speeds_rad_s)
        if self.simulation.internal:
            self._reply(self.simulation.step(1.0 / packet.frame_rate_hz))
        elif self.simulation.latest.t_s > self._last_reply_t_s:
            self._reply(self.simulation.latest)
        else:
            self._awaiting_state = True

    def on_external_state(self, state: VehicleState) -> None:
        """External mode: answer a waiting frame with the simulator's new state."""
        if self._awaiting_state and state.t_s > self._last_reply_t_s:
            self._awaiting_state = False
            self._reply(state)

    def _reply(self, state: VehicleState) -> None:
        self._last_reply = state_json_line(state)
        self._last_reply_t_s = state.t_s
        self._send(self._last_reply)

    def _send(self, data: bytes) -> None:
        if self.peer is not None:
            self.endpoint.send(data, self.peer)

    def close(self) -> None:
        """Close the socket."""
        self.endpoint.close()
