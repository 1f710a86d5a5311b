"""Stand-ins for PX4 and ArduPilot SITL: enough of each flight stack's side to fly a hover.

The tests and ``bench/bench_mavlink.py`` use them to exercise the bridge without a real flight stack,
and they are a quick way to check a bridge set-up by hand. Each speaks its interface the way the real
one does (PX4: TCP client, HEARTBEAT, SET_MESSAGE_INTERVAL for HIL_STATE_QUATERNION, one
HIL_ACTUATOR_CONTROLS per HIL_SENSOR with the lockstep flag; ArduPilot: binary servo packets over UDP,
one JSON line back per frame) and flies with its own simple controller, working in NED/FRD on what it
receives, as a flight stack would:

- altitude: PD on the down position and velocity, thrust divided by the tilt's cosine;
- horizontal position: PD giving the tilt that accelerates towards the target;
- attitude: PD on roll and pitch towards that tilt and on the yaw rate towards 0, in body FRD;
- mixing: the airframe's allocation matrix (body FLU) pseudo-inverted, speeds through the motor map.
"""

from __future__ import annotations

import json
import math
import socket
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import encode_servo_packet
from multirotor_ros.mavlink.px4 import FLAG_LOCKSTEP, MODE_FLAG_ARMED
from multirotor_ros.mavlink.sensors import Home
from multirotor_ros.model.airframe import GRAVITY_M_S2
from multirotor_ros.model.rotation import FloatArray, quat_to_euler


@dataclass
class HoverController:
    """Fly to and hold ``target_NED`` [m] (default: ``altitude_m`` above the origin), not turning."""

    channels: RotorChannels
    altitude_m: float = 2.0  # [m] the default target's height
    target_NED: FloatArray | None = None  # [m] from the origin, NED
    k_p_z: float = 4.0  # [1/s^2]
    k_d_z: float = 3.0  # [1/s]
    k_p_xy: float = 1.0  # [1/s^2]
    k_d_xy: float = 1.6  # [1/s]
    max_tilt_rad: float = 0.3  # [rad]
    k_p_att: float = 30.0  # [1/s^2] per rad
    k_d_att: float = 8.0  # [1/s]

    def __post_init__(self) -> None:
        airframe = self.channels.airframe
        if self.target_NED is None:
            self.target_NED = np.array([0.0, 0.0, -self.altitude_m])
        self._mass = airframe.mass_kg
        self._inertia = np.diag(airframe.inertia_kg_m2)
        self._mixer = np.linalg.pinv(airframe.allocation)

    def speeds(
        self, p_NED: FloatArray, v_NED: FloatArray, q_NED_FRD: FloatArray, w_FRD: FloatArray
    ) -> FloatArray:
        """Rotor speeds [rad/s] for the current state."""
        roll, pitch, yaw = quat_to_euler(q_NED_FRD)
        error = np.asarray(self.target_NED) - p_NED
        # NED: thrust pushes up (-z); the needed upward acceleration plus gravity.
        up_accel = GRAVITY_M_S2 - self.k_p_z * error[2] + self.k_d_z * v_NED[2]
        tilt = max(math.cos(roll) * math.cos(pitch), 0.5)
        thrust = self._mass * max(up_accel, 0.0) / tilt
        # Horizontal: the tilt that makes the wanted acceleration (small angles, yaw psi):
        # a_N = -g (theta cos psi + phi sin psi), a_E = -g (theta sin psi - phi cos psi).
        a_N, a_E = self.k_p_xy * error[:2] - self.k_d_xy * v_NED[:2]
        c, s = math.cos(yaw), math.sin(yaw)
        pitch_wanted = np.clip(-(a_N * c + a_E * s) / GRAVITY_M_S2, -self.max_tilt_rad, self.max_tilt_rad)
        roll_wanted = np.clip((-a_N * s + a_E * c) / GRAVITY_M_S2, -self.max_tilt_rad, self.max_tilt_rad)
        torque_FRD = self._inertia * np.array(
            [
                -self.k_p_att * (roll - roll_wanted) - self.k_d_att * w_FRD[0],
                -self.k_p_att * (pitch - pitch_wanted) - self.k_d_att * w_FRD[1],
                -self.k_d_att * w_FRD[2],
            ]
        )
        # The allocation is written in body FLU: torques about y and z change sign.
        wrench_FLU = np.array([thrust, torque_FRD[0], -torque_FRD[1], -torque_FRD[2]])
        omega_squared = np.clip(self._mixer @ wrench_FLU, 0.0, None)
        return np.sqrt(omega_squared)


class _Stream:
    """A file-like sink for pymavlink's MAVLink.send that writes to a TCP socket."""

    def __init__(self, sock: socket.socket):
        self.sock = sock

    def write(self, data: bytes) -> None:
        self.sock.sendall(data)


@dataclass
class Px4Record:
    """What a PX4-like peer received and did."""

    sensors: list[Any] = field(default_factory=list)
    gps: list[Any] = field(default_factory=list)
    states: list[Any] = field(default_factory=list)
    acks: list[Any] = field(default_factory=list)
    heartbeats: int = 0
    actuator_messages: int = 0


class Px4LikePeer:
    """Connects like PX4's ``simulator_mavlink`` and flies a hover in lockstep; see the module docstring."""

    def __init__(
        self,
        port: int,
        controller: HoverController,
        host: str = "127.0.0.1",
        arm_after_s: float = 0.5,
        timeout_s: float = 5.0,
        keep_messages: bool = True,
        origin: Home | None = None,
    ):
        self.controller = controller
        self.arm_after_s = arm_after_s
        self.keep_messages = keep_messages
        self.sock = _connect(host, port, timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.mav = mavlink2.MAVLink(_Stream(self.sock), 1, 1)
        self.record = Px4Record()
        self._state: Any = None
        # Where the altitude is counted from: ``origin`` if given, else the first position received.
        self._origin: tuple[int, int, int] | None = None
        if origin is not None:
            degrees_e7 = (round(origin.latitude_deg * 1e7), round(origin.longitude_deg * 1e7))
            self._origin = (*degrees_e7, round(origin.altitude_m * 1e3))
        self.mav.send(
            self.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, 0, 0, 0)
        )
        self.mav.send(
            self.mav.command_long_encode(
                0,
                0,
                mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                mavlink2.MAVLINK_MSG_ID_HIL_STATE_QUATERNION,
                5000,
                0,
                0,
                0,
                0,
                0,
            )
        )

    def fly(self, duration_s: float) -> Px4Record:
        """Answer every HIL_SENSOR until the simulated time reaches ``duration_s``."""
        t_s = 0.0
        while t_s < duration_s:
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("the bridge closed the connection")
            for message in self.mav.parse_buffer(data) or []:
                kind = message.get_type()
                if kind == "HIL_SENSOR":
                    t_s = message.time_usec * 1e-6
                    if self.keep_messages:
                        self.record.sensors.append(message)
                    self._answer(message, t_s)
                elif kind == "HIL_STATE_QUATERNION":
                    self._state = message
                    if self.keep_messages:
                        self.record.states.append(message)
                elif kind == "HIL_GPS" and self.keep_messages:
                    self.record.gps.append(message)
                elif kind == "COMMAND_ACK":
                    self.record.acks.append(message)
                elif kind == "HEARTBEAT":
                    self.record.heartbeats += 1
        return self.record

    def _answer(self, sensor: Any, t_s: float) -> None:
        armed = t_s >= self.arm_after_s and self._state is not None
        controls = np.zeros(16)
        if armed:
            s = self._state
            speeds = self.controller.speeds(
                p_NED=self._position_ned(s),
                v_NED=np.array([s.vx, s.vy, s.vz]) / 100.0,
                q_NED_FRD=np.array(s.attitude_quaternion),
                w_FRD=np.array([sensor.xgyro, sensor.ygyro, sensor.zgyro]),
            )
            controls = self.controller.channels.px4_controls_for_speeds(speeds)
        mode = 1 | (MODE_FLAG_ARMED if armed else 0)
        self.mav.send(
            self.mav.hil_actuator_controls_encode(sensor.time_usec, controls.tolist(), mode, FLAG_LOCKSTEP)
        )
        self.record.actuator_messages += 1

    def _position_ned(self, state: Any) -> FloatArray:
        # The state message has latitude/longitude/altitude (a sphere is close enough for a controller:
        # PX4's own local projection is one too).
        if self._origin is None:
            self._origin = (state.lat, state.lon, state.alt)
        lat0, lon0, alt0 = self._origin
        north = (state.lat - lat0) * 1e-7 * math.pi / 180.0 * 6371000.0
        east = (
            (state.lon - lon0) * 1e-7 * math.pi / 180.0 * 6371000.0 * math.cos(lat0 * 1e-7 * math.pi / 180.0)
        )
        return np.array([north, east, -(state.alt - alt0) / 1000.0])

    def close(self) -> None:
        """Disconnect."""
        self.sock.close()


@dataclass
class ArduPilotRecord:
    """What an ArduPilot-like peer received."""

    replies: list[dict[str, Any]] = field(default_factory=list)
    frames_sent: int = 0


class ArduPilotLikePeer:
    """Sends servo packets like SITL's JSON backend and flies a hover; see the module docstring."""

    def __init__(
        self,
        port: int,
        controller: HoverController,
        host: str = "127.0.0.1",
        frame_rate_hz: int = 400,
        arm_after_s: float = 0.5,
        channels: int = 16,
        timeout_s: float = 2.0,
        keep_messages: bool = True,
    ):
        self.controller = controller
        self.address = (host, port)
        self.frame_rate_hz = frame_rate_hz
        self.arm_after_s = arm_after_s
        self.channels = channels
        self.keep_messages = keep_messages
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.sock.settimeout(timeout_s)
        self.record = ArduPilotRecord()
        self.frame_count = 0
        self._last: dict[str, Any] | None = None

    def fly(self, duration_s: float) -> ArduPilotRecord:
        """Send a frame, wait for its answer, repeat until the answers' timestamp reaches ``duration_s``."""
        t_s = 0.0
        while t_s < duration_s:
            reply = self.exchange(self._pwm(t_s))
            t_s = float(reply["timestamp"])
        return self.record

    def exchange(self, pwm: list[int], frame_count: int | None = None) -> dict[str, Any]:
        """Send one servo packet (the next frame count unless given) and return the JSON answer."""
        if frame_count is None:
            self.frame_count += 1
            frame_count = self.frame_count
        self.sock.sendto(encode_servo_packet(self.frame_rate_hz, frame_count, pwm), self.address)
        self.record.frames_sent += 1
        data, _ = self.sock.recvfrom(65536)
        if not data.startswith(b"\n") or not data.endswith(b"\n"):
            raise ValueError(f"answer not framed by newlines: {data[:80]!r}")
        reply = json.loads(data)
        self._last = reply
        if self.keep_messages:
            self.record.replies.append(reply)
        return reply

    def _pwm(self, t_s: float) -> list[int]:
        reply = self._last
        if reply is None or t_s < self.arm_after_s:
            return [1000] * self.channels
        speeds = self.controller.speeds(
            p_NED=np.array(reply["position"]),
            v_NED=np.array(reply["velocity"]),
            q_NED_FRD=np.array(reply["quaternion"]),
            w_FRD=np.array(reply["imu"]["gyro"]),
        )
        pwm = self.controller.channels.pwm_for_speeds(speeds, self.channels)
        return [int(round(v)) if v > 0 else 1000 for v in pwm]

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


def _connect(host: str, port: int, timeout_s: float) -> socket.socket:
    """Connect like PX4 does: retry until the simulator listens (or ``timeout_s`` passes)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return socket.create_connection((host, port), timeout=timeout_s)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
