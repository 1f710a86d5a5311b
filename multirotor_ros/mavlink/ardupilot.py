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

Lockstep on the frame count: each new frame advances the physics by exactly 1/frame_rate, as
ArduPilot's own JSON example does (libraries/SITL/examples/JSON); SITL takes its clock from the
differences of our timestamps (SIM_JSON.cpp: ``time_now_us += deltat``, and its frame rate from
1/deltat), so the frame times are counted from the last change of rate, k / frame_rate, and never drift
by the rounding of a frame to nanoseconds. A frame count that repeats is a resend after a lost answer,
which gets the previous answer again without stepping; a count that goes backwards means SITL restarted,
and the vehicle is put back to its initial state at t = 0. A gap (lost servo packets) is counted and
flying continues, one frame's Δt per frame received.

The answer goes out before anything else is done with the frame (the rotor command and the new state
reach ROS after it, :meth:`~multirotor_ros.mavlink.vehicle.Simulation.announce`). With
``measure_timing`` the session keeps, per frame, how long the answer took from the datagram's arrival
(kernel time stamp), how long SITL took from our answer to its next frame, and how long the frame kept
this side busy: :class:`FrameTimes`.

Answering ahead (``answer_ahead``, internal physics only). Exact lockstep integrates a frame's servos
while SITL waits, so a frame costs SITL's turn plus ours, one after the other. Answering ahead, each frame
is answered at once with the state integrated after the previous frame, and its own servos are then
integrated over the next frame while SITL runs its turn: on two cores the two turns overlap. The price is
one frame of actuator delay (1/frame_rate: 0.83 ms at SITL's 1200 Hz, short beside a motor's time
constant of tens of ms), and a change of frame rate takes effect one frame later too. The first frame,
and the first after a restart, have nothing integrated ahead and are answered exactly. The replies to
servos P1, P2, ... are those exact lockstep gives to P1, P1, P2, ...

Faults. Packets of the wrong size or magic, or with a frame rate of 0 or above 10 kHz, are refused and
counted. Packets from a second address while the current peer is active (heard from within
``peer_timeout_s``) are refused, unless their frame count is below the current one: SITL restarted
(from a new port), and takes over at once; after that silence any new address is taken as the peer
reconnecting.
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
from typing import NamedTuple

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.messages import NedView, ned_axes, ned_view
from multirotor_ros.mavlink.timing import FrameTimes
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
MAX_BUSY_WAIT_S = 0.01  # [s] longest poll for SITL's next frame (ArduPilotConfig.busy_wait_s)
# Packet size -> its magic and layout (magic, frame rate, frame count, then the pulses).
_SERVO_LAYOUTS = {
    SERVO_FORMAT_16.size: (SERVO_MAGIC_16, SERVO_FORMAT_16),
    SERVO_FORMAT_32.size: (SERVO_MAGIC_32, SERVO_FORMAT_32),
}


class ServoPacket(NamedTuple):
    """One decoded SITL output packet (a tuple of plain ints: made 1,200 times a second and more)."""

    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple[int, ...]  # 16 or 32 pulses [us], channel 1 first


def encode_servo_packet(frame_rate_hz: int, frame_count: int, pwm_us: list[int]) -> bytes:
    """The bytes SITL sends (16 or 32 channels by the length of ``pwm_us``): for peers and tests."""
    if len(pwm_us) == 16:
        return SERVO_FORMAT_16.pack(SERVO_MAGIC_16, frame_rate_hz, frame_count, *pwm_us)
    if len(pwm_us) == 32:
        return SERVO_FORMAT_32.pack(SERVO_MAGIC_32, frame_rate_hz, frame_count, *pwm_us)
    raise ValueError(f"a servo packet has 16 or 32 channels, not {len(pwm_us)}")


def decode_servo_packet(data: bytes) -> ServoPacket | tuple[str, str]:
    """A servo packet, or (refusal reason, detail)."""
    layout = _SERVO_LAYOUTS.get(len(data))
    if layout is None:
        return (
            "bad servo packet size",
            f"{len(data)} bytes, expected {SERVO_FORMAT_16.size} or {SERVO_FORMAT_32.size}",
        )
    expected, fields = layout
    values = fields.unpack(data)
    magic, frame_rate, frame_count = values[0], values[1], values[2]
    if magic != expected:
        return "bad servo magic", f"magic {magic} in a {len(data)}-byte packet, expected {expected}"
    if not 1 <= frame_rate <= MAX_FRAME_RATE_HZ:
        return "bad frame rate", f"frame rate {frame_rate} Hz outside 1..{MAX_FRAME_RATE_HZ}"
    return ServoPacket(frame_rate, frame_count, values[3:])


# The answer line, keys in SIM_JSON.cpp's spelling; '%.12g' keeps 1e-8 m at 10 km, the timestamp is
# written to the nanosecond. A %-format: json.dumps of the same dict costs ten times as much per frame.
_LINE = (
    '\n{"timestamp":%.9f,"imu":{"gyro":[%.12g,%.12g,%.12g],"accel_body":[%.12g,%.12g,%.12g]},'
    '"position":[%.12g,%.12g,%.12g],"velocity":[%.12g,%.12g,%.12g],"quaternion":[%.12g,%.12g,%.12g,%.12g]}\n'
)


def state_json_line(state: VehicleState) -> bytes:
    """The answer line for one state (see the module docstring)."""
    # ned_view's numbers as plain floats, without its arrays: p 0:3, v 3:6, q 6:10, accel 13:16, gyro 16:19.
    n = ned_axes(state).tolist()
    if math.isfinite(state.t_s + sum(n[0:10]) + sum(n[13:19])):
        if n[6] < 0.0:
            n[6:10] = [-value for value in n[6:10]]  # the same attitude, w >= 0 (ned_view)
        return (_LINE % (state.t_s, *n[16:19], *n[13:16], *n[0:10])).encode("ascii")
    return _json_line(ned_view(state))  # NaN or beyond a float's range: spelt as JSON spells them


class _Answer(NamedTuple):
    """A frame's answer: its JSON line and the simulated time it tells."""

    line: bytes
    t_s: float


def _answer(state: VehicleState) -> _Answer:
    return _Answer(state_json_line(state), state.t_s)


def _json_line(view: NedView) -> bytes:
    document = {
        "timestamp": view.t_s,
        "imu": {"gyro": view.imu_gyro_FRD_rad_s.tolist(), "accel_body": view.imu_accel_FRD_m_s2.tolist()},
        "position": view.p_NED_m.tolist(),
        "velocity": view.v_NED_m_s.tolist(),
        "quaternion": view.q_NED_FRD.tolist(),
    }
    return ("\n" + json.dumps(document, separators=(",", ":")) + "\n").encode("ascii")


@dataclass(frozen=True)
class ArduPilotConfig:
    """Where to listen."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    peer_timeout_s: float = 2.0  # [s] silence after which another address may take over
    measure_timing: bool = False  # keep FrameTimes (benchmarks: one entry per frame, never dropped)
    # [s] after an answer, poll for the next frame this long without sleeping, when SITL's last turn was
    # no longer (ArduPilotSession.wait_for_next_frame); 0 = always sleep in the selector.
    busy_wait_s: float = 0.0003
    # Answer each frame with the state integrated after the previous one (module docstring): SITL's turn
    # and the integration overlap, for one frame of actuator delay.
    answer_ahead: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.busy_wait_s) and 0.0 <= self.busy_wait_s <= MAX_BUSY_WAIT_S):
            raise ValueError(f"busy wait {self.busy_wait_s} s outside 0..{MAX_BUSY_WAIT_S:g} s")


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
        self.endpoint = UdpEndpoint(config.host, config.port, self._on_datagram, config.measure_timing)
        self.peer: tuple[str, int] | None = None
        self.last_heard_s = -math.inf
        self.last_frame: int | None = None
        self.frames = 0
        self.missed_frames = 0
        # SITL sends a frame again when our answer is late (its own timeout): part of its protocol, not
        # bad input, so counted here and not refused.
        self.repeated_frames = 0
        self.restarts = 0
        self.times = FrameTimes() if config.measure_timing else None
        self._last_reply = b""
        self._last_reply_t_s = -math.inf
        self._ahead: _Answer | None = None  # answer_ahead: the next frame's answer, integrated already
        # SITL's last turn (our answer out to its next frame in) [s], and when the last answer went out.
        self.last_turn_s = math.inf
        self._answered_at_s: float | None = None
        self._awaiting_state = False
        # Frame times: base_ns + frames_since_base / rate_hz (see the module docstring).
        self._rate_hz = 0
        self._base_ns = 0
        self._frames_since_base = 0

    @property
    def connected(self) -> bool:
        """Whether a SITL has been heard from within the peer timeout."""
        return self.peer is not None and self.clock() - self.last_heard_s < self.config.peer_timeout_s

    def _on_datagram(self, data: bytes, address: tuple[str, int]) -> None:
        now = self.clock()
        packet = decode_servo_packet(data)
        if self.peer is not None and address != self.peer:
            # A SITL that restarted sends from a new port and counts its frames from 0 again: it takes
            # over at once. Any other second sender is refused while the current one is heard from.
            restarted = isinstance(packet, ServoPacket) and packet.frame_count < (self.last_frame or 0)
            if now - self.last_heard_s < self.config.peer_timeout_s and not restarted:
                self.refusals.refuse(
                    "second peer", f"servo packet from {address[0]}:{address[1]} while {self.peer} is active"
                )
                return
            _LOGGER.warning("ArduPilot SITL now at %s:%d (was %s)", address[0], address[1], self.peer)
        if not isinstance(packet, ServoPacket):
            self.refusals.refuse(*packet)
            return
        if self.peer != address:
            _LOGGER.info("ArduPilot SITL connected from %s:%d", *address)
        self.peer, self.last_heard_s = address, now
        self._on_packet(packet)

    def _on_packet(self, packet: ServoPacket) -> None:
        if self._answered_at_s is not None:
            self.last_turn_s = time.perf_counter() - self._answered_at_s
            self._answered_at_s = None
        last = self.last_frame
        if last is not None and packet.frame_count == last:
            self.repeated_frames += 1
            if self.repeated_frames == 1:
                _LOGGER.info("frame %d again: the last answer is resent (counted from now on)", last)
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
            self._rate_hz = 0  # time starts again from the reset vehicle's 0
            self._last_reply_t_s = -math.inf
            self._ahead = None
            self.on_restart()
        elif last is not None and packet.frame_count > last + 1:
            self.missed_frames += packet.frame_count - last - 1
        self.last_frame = packet.frame_count
        self.frames += 1
        if self._ahead is not None:
            self._send_answer(self._ahead)
            self._hold_command(packet)
            self._ahead = self._integrated(packet.frame_rate_hz)
        else:
            self._hold_command(packet)
            if self.simulation.internal:
                self._send_answer(self._integrated(packet.frame_rate_hz))
                if self.config.answer_ahead:  # from the next frame on, SITL's turn and ours overlap
                    self._ahead = self._integrated(packet.frame_rate_hz)
            elif self.simulation.latest.t_s > self._last_reply_t_s:
                self._send_answer(_answer(self.simulation.latest))
            else:
                self._awaiting_state = True
        self.simulation.announce()
        if self.times is not None:
            self.times.busy(self.endpoint.arrival_ns, time.time_ns())

    def _hold_command(self, packet: ServoPacket) -> None:
        command = self.channels.from_servo_packet(packet.pwm_us)
        for problem in command.problems:
            self.refusals.refuse(problem.reason, f"servo packet {packet.frame_count}: {problem.detail}")
        if command.speeds_rad_s is not None:
            self.simulation.command(command.speeds_rad_s)

    def _integrated(self, rate_hz: int) -> _Answer:
        """The answer at the end of the next frame at ``rate_hz``, integrated with the held command."""
        return _answer(self.simulation.advance_to(self._frame_time_ns(rate_hz)))

    def _frame_time_ns(self, rate_hz: int) -> int:
        """When this frame ends: one more 1/rate_hz after the base (rebased when the rate changes)."""
        if rate_hz != self._rate_hz:
            self._rate_hz, self._base_ns, self._frames_since_base = rate_hz, self.simulation.t_ns, 0
        self._frames_since_base += 1
        return self._base_ns + round(self._frames_since_base * 1_000_000_000 / rate_hz)

    def on_external_state(self, state: VehicleState) -> None:
        """External mode: answer a waiting frame with the simulator's new state."""
        if self._awaiting_state and state.t_s > self._last_reply_t_s:
            self._awaiting_state = False
            self._send_answer(_answer(state))

    def _send_answer(self, answer: _Answer) -> None:
        self._last_reply, self._last_reply_t_s = answer
        self._send(answer.line)

    def _send(self, data: bytes) -> None:
        if self.peer is None:
            return
        if self.times is not None:
            # Taken as the answer leaves: SITL may answer it before sendto returns to us.
            self.times.frame(self.endpoint.arrival_ns, time.time_ns())
        self._answered_at_s = time.perf_counter()
        self.endpoint.send(data, self.peer)

    def busy_wait_left_s(self) -> float:
        """How much longer to poll for SITL's next frame instead of sleeping [s]; 0 = sleep.

        In lockstep at speed SITL's turn is about 0.07-0.1 ms, less than it takes this process to wake
        from the selector's sleep; polling answers the next frame at once. After an answer the poll lasts
        up to ``busy_wait_s`` when SITL's last turn was no longer. SITL running slower (speedup 1: it
        sleeps to keep real time) takes longer than the budget, and then nothing is polled: no core is
        burnt waiting.
        """
        budget_s = self.config.busy_wait_s
        if self._answered_at_s is None or self.last_turn_s > budget_s:
            return 0.0
        return max(budget_s - (time.perf_counter() - self._answered_at_s), 0.0)

    def wait_for_next_frame(self) -> bool:
        """Poll for SITL's next frame for :meth:`busy_wait_left_s`; True if one came and was answered."""
        left_s = self.busy_wait_left_s()
        return left_s > 0.0 and self.endpoint.wait_briefly(left_s)

    def close(self) -> None:
        """Close the socket."""
        self.endpoint.close()
