"""The ground-station link: telemetry out over UDP, position setpoints in.

Out (to the ground stations, see "Peers" below), on the wall clock, as system ``system_id`` /
component 1 (an autopilot, so that ground stations show it as a vehicle):

| message | rate | content |
|---|---|---|
| HEARTBEAT | 1 Hz | MAV_TYPE from the rotor count, armed while a rotor turns faster than idle |
| SYS_STATUS | 1 Hz | IMU, magnetometer, barometer, GPS present and healthy; ``errors_comm``: refusals |
| ATTITUDE | 50 Hz | roll, pitch, yaw (NED/FRD), body rates FRD |
| LOCAL_POSITION_NED | 50 Hz | position and velocity NED from home |
| GLOBAL_POSITION_INT | 10 Hz | latitude, longitude, altitude, height above home, velocity, heading |
| ACTUATOR_OUTPUT_STATUS | 10 Hz | rotor speeds [rad/s], one per rotor, ``active`` bit per rotor |
| ESC_TELEMETRY_1_TO_4 (5_TO_8, ...) | 10 Hz | rotor speeds [rpm], what ground stations display |

``time_boot_ms`` is the simulated time. SET_MESSAGE_INTERVAL changes any of these rates within
0.05..50 Hz (interval 20,000..20,000,000 us; -1 stops a message, 0 restores its default); a request
outside is answered DENIED with ``result_param2 = 2`` and counted (:class:`.messages.MessageSchedule`).
Every value is fitted to its field's range before packing (:func:`.messages.fit_to_wire`). With PX4 or
ArduPilot SITL also reporting to the same ground station, give the bridge another ``system_id`` (the
flight stack's is 1 too), or the ground station mixes the two vehicles up.

In: TIMESYNC requests (tc1 = 0) are answered with this side's time in ns. SET_POSITION_TARGET_LOCAL_NED
addressed to this system (or to all, target 0) becomes a setpoint: world ENU position and ENU yaw.
Frames: LOCAL_NED (1) and BODY_NED (8, whose positions MAVLink defines as LOCAL_NED's) are absolute;
LOCAL_OFFSET_NED (7) is an offset from the current position; BODY_OFFSET_NED (9) and BODY_FRD (12) an
offset along the vehicle's heading, and their yaw is relative to the current heading. Setpoints that
ignore the position (velocity or acceleration only) or use another frame are refused: the controller
behind ``setpoint`` flies to positions. An ignored yaw keeps the current heading.

Signing: with a key, outgoing packets are signed and incoming ones go through
:class:`~multirotor_ros.mavlink.signing.SigningPolicy`; refused ones never reach the handlers. Commands
that change rates (COMMAND_LONG) are commands like setpoints: unsigned ones are refused with a key.

Peers: telemetry and replies go only to known ground stations, so that a spoofed source address cannot
turn the link into an amplifier aimed at somebody else:

- the configured address ``host:port`` always (the operator chose it);
- besides it, at most ``max_peers`` (3) other addresses, each learnt from a datagram carrying a message
  that passed the signing policy and, with a key, was signed with it (an unsigned HEARTBEAT, which the
  policy lets through, does not make a peer). A peer is forgotten 10 s after its last such message.

A datagram from any other address is refused as a whole ("ground station not admitted", counted):
its commands are not handled and nothing is sent back. Without a key anybody can become a peer, so the
bound is what limits the traffic one spoofer can direct: at most ``max_peers`` destinations besides
the configured one, at the configured rates. With a key only holders of the key become peers.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.frames import ned_to_enu, yaw_ned_to_enu
from multirotor_ros.mavlink.messages import (
    MessageSchedule,
    NedView,
    answer_command,
    as_float_list,
    heading_cdeg,
    ned_view,
    time_usec,
)
from multirotor_ros.mavlink.sensors import SensorModel
from multirotor_ros.mavlink.signing import SigningPolicy, is_signed
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.mavlink.wire import MavlinkCodec, Message, UdpEndpoint
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.refusals import RefusalCounter

DEFAULT_PORT = 14550
GCS_PEER_MEMORY_S = 10.0
MAX_PEERS_LIMIT = 16
SETPOINT_RANGE_M = 10000.0  # [m] from home: anything farther is a mistake, not a destination
RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)

TYPE_MASK_POSITION_IGNORE = 0b111  # bits of x, y, z
TYPE_MASK_YAW_IGNORE = 1 << 10
ABSOLUTE_FRAMES = {mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_NED}
OFFSET_FRAMES = {mavlink2.MAV_FRAME_LOCAL_OFFSET_NED}
HEADING_OFFSET_FRAMES = {mavlink2.MAV_FRAME_BODY_OFFSET_NED, mavlink2.MAV_FRAME_BODY_FRD}

SENSORS = (
    mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink2.MAV_SYS_STATUS_SENSOR_GPS
)
MAV_TYPE_BY_ROTORS = {
    4: mavlink2.MAV_TYPE_QUADROTOR,
    6: mavlink2.MAV_TYPE_HEXAROTOR,
    8: mavlink2.MAV_TYPE_OCTOROTOR,
}

MSG_HEARTBEAT = mavlink2.MAVLINK_MSG_ID_HEARTBEAT
MSG_SYS_STATUS = mavlink2.MAVLINK_MSG_ID_SYS_STATUS
MSG_ATTITUDE = mavlink2.MAVLINK_MSG_ID_ATTITUDE
MSG_LOCAL_POSITION_NED = mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED
MSG_GLOBAL_POSITION_INT = mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
MSG_ACTUATOR_OUTPUT_STATUS = mavlink2.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS
MSG_ESC_TELEMETRY = mavlink2.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4
ESC_TELEMETRY_ENCODERS = (
    "esc_telemetry_1_to_4_encode",
    "esc_telemetry_5_to_8_encode",
    "esc_telemetry_9_to_12_encode",
)


@dataclass(frozen=True)
class GroundStationConfig:
    """Where the ground station is and how fast the attitude and position go out."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    bind_host: str = "127.0.0.1"
    bind_port: int = 0  # 0 = any free port; ground stations answer to where packets come from
    system_id: int = 1
    telemetry_rate_hz: float = 50.0  # [Hz] ATTITUDE and LOCAL_POSITION_NED
    max_peers: int = 3  # ground stations learnt from their messages, besides host:port

    def __post_init__(self) -> None:
        if not 0 <= self.max_peers <= MAX_PEERS_LIMIT:
            raise ValueError(f"max_peers {self.max_peers} outside 0..{MAX_PEERS_LIMIT}")
        if not 0.0 < self.telemetry_rate_hz <= 500.0:
            raise ValueError(f"ground-station telemetry rate {self.telemetry_rate_hz} Hz outside (0, 500] Hz")
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"MAVLink system id {self.system_id} outside 1..255")


@dataclass(frozen=True)
class Setpoint:
    """A position setpoint in the package's frames."""

    p_W_m: FloatArray  # world ENU
    yaw_W_rad: float  # ENU yaw: from east, counter-clockwise


class GroundStationLink:
    """Telemetry out and setpoints in; see the module docstring."""

    def __init__(
        self,
        config: GroundStationConfig,
        sensors: SensorModel,
        n_rotors: int,
        signing: SigningPolicy,
        refusals: RefusalCounter,
        on_setpoint: Callable[[Setpoint], None],
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.sensors = sensors
        self.n_rotors = n_rotors
        self.refusals = refusals
        self.on_setpoint = on_setpoint
        self.clock = clock
        self.codec = MavlinkCodec(config.system_id, mavlink2.MAV_COMP_ID_AUTOPILOT1, refusals, signing)
        self.endpoint = UdpEndpoint(config.bind_host, config.bind_port, self._on_datagram)
        rate = config.telemetry_rate_hz
        self.schedule = MessageSchedule(
            {
                MSG_HEARTBEAT: 1.0,
                MSG_SYS_STATUS: 1.0,
                MSG_ATTITUDE: rate,
                MSG_LOCAL_POSITION_NED: rate,
                MSG_GLOBAL_POSITION_INT: 10.0,
                MSG_ACTUATOR_OUTPUT_STATUS: 10.0,
                MSG_ESC_TELEMETRY: 10.0,
            }
        )
        self._peers: dict[tuple[str, int], float] = {}
        self.setpoints = 0
        self.timesync_answers = 0
        self.state: VehicleState | None = None
        self._armed_above_rad_s = 0.0

    @property
    def local_port(self) -> int:
        """The UDP port telemetry goes out from and commands come in to."""
        return self.endpoint.port

    def set_armed_speed(self, speed_rad_s: float) -> None:
        """Rotor speed above which (any rotor) the vehicle is reported armed."""
        self._armed_above_rad_s = speed_rad_s

    # ------------------------------------------------------------------ outgoing

    @property
    def configured_address(self) -> tuple[str, int]:
        """The ground station's configured address (always a destination)."""
        return (self.config.host, self.config.port)

    def _destinations(self, now_s: float) -> list[tuple[str, int]]:
        self._forget_silent_peers(now_s)
        return list({self.configured_address, *self._peers})

    def _forget_silent_peers(self, now_s: float) -> None:
        self._peers = {a: t for a, t in self._peers.items() if now_s - t < GCS_PEER_MEMORY_S}

    def _send(self, message: Message, now_s: float) -> None:
        data = self.codec.encode(message)
        for address in self._destinations(now_s):
            self.endpoint.send(data, address)

    def poll(self, now_s: float, state: VehicleState) -> float:
        """Send whatever telemetry is due for this state; return when the next is due."""
        self.state = state
        due = [m for m in self.schedule_ids() if self.schedule.due(m, now_s)]
        if due:
            view = ned_view(state)
            for message_id in due:
                for message in self._build(message_id, state, view):
                    self._send(message, now_s)
        return self.schedule.next_due_s()

    @staticmethod
    def schedule_ids() -> tuple[int, ...]:
        """Every periodic message, in sending order."""
        return (
            MSG_HEARTBEAT,
            MSG_SYS_STATUS,
            MSG_ATTITUDE,
            MSG_LOCAL_POSITION_NED,
            MSG_GLOBAL_POSITION_INT,
            MSG_ACTUATOR_OUTPUT_STATUS,
            MSG_ESC_TELEMETRY,
        )

    def _build(self, message_id: int, state: VehicleState, view: NedView) -> list[Message]:
        mav = self.codec.mav
        t_ms = int(state.t_s * 1000.0) & 0xFFFFFFFF
        speeds = np.asarray(state.rotor_speeds_rad_s, dtype=float)
        if message_id == MSG_HEARTBEAT:
            armed = bool(np.any(speeds > self._armed_above_rad_s))
            base_mode = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
            )
            status = mavlink2.MAV_STATE_ACTIVE if armed else mavlink2.MAV_STATE_STANDBY
            kind = MAV_TYPE_BY_ROTORS.get(self.n_rotors, mavlink2.MAV_TYPE_GENERIC)
            return [mav.heartbeat_encode(kind, mavlink2.MAV_AUTOPILOT_GENERIC, base_mode, 0, status)]
        if message_id == MSG_SYS_STATUS:
            errors = min(self.refusals.total, 65535)
            return [mav.sys_status_encode(SENSORS, SENSORS, SENSORS, 0, 65535, -1, -1, 0, errors, 0, 0, 0, 0)]
        if message_id == MSG_ATTITUDE:
            roll, pitch, yaw = view.euler_NED_rad.tolist()
            w = view.w_FRD_rad_s
            return [mav.attitude_encode(t_ms, roll, pitch, yaw, w[0], w[1], w[2])]
        if message_id == MSG_LOCAL_POSITION_NED:
            p, v = view.p_NED_m, view.v_NED_m_s
            return [mav.local_position_ned_encode(t_ms, p[0], p[1], p[2], v[0], v[1], v[2])]
        if message_id == MSG_GLOBAL_POSITION_INT:
            fix = self.sensors.gps(state.p_WB_W, state.v_WB_W)
            relative_mm = float(state.p_WB_W[2]) * 1000.0  # the codec fits it to int32
            hdg = heading_cdeg(float(view.euler_NED_rad[2]))
            return [
                mav.global_position_int_encode(
                    t_ms,
                    fix.latitude_e7,
                    fix.longitude_e7,
                    fix.altitude_mm,
                    relative_mm,
                    *fix.v_ned_cm_s,
                    hdg,
                )
            ]
        if message_id == MSG_ACTUATOR_OUTPUT_STATUS:
            active = (1 << min(self.n_rotors, 32)) - 1
            return [
                mav.actuator_output_status_encode(time_usec(state.t_s), active, as_float_list(speeds, 32))
            ]
        # ESC telemetry, four rotors per message; the codec rounds the rpm into its uint16 field.
        rpm = (speeds * RAD_S_TO_RPM).tolist()
        messages = []
        for group, encoder in enumerate(ESC_TELEMETRY_ENCODERS):
            chunk = rpm[4 * group : 4 * group + 4]
            if not chunk:
                break
            padded = [*chunk, *[0] * (4 - len(chunk))]
            messages.append(getattr(mav, encoder)([0] * 4, [0] * 4, [0] * 4, [0] * 4, padded, [0] * 4))
        return messages

    # ------------------------------------------------------------------ incoming

    def _on_datagram(self, data: bytes, address: tuple[str, int]) -> None:
        messages = self.codec.decode(data, whole_datagram=True)
        if not messages or not self._admitted(address, messages):
            return
        for message in messages:
            kind = message.get_type()
            if kind == "TIMESYNC":
                self._on_timesync(message, address)
            elif kind == "SET_POSITION_TARGET_LOCAL_NED":
                self._on_position_target(message)
            elif kind == "COMMAND_LONG":
                self._on_command_long(message, address)

    def _admitted(self, address: tuple[str, int], messages: list[Message]) -> bool:
        """Whether this datagram's sender is a peer (becoming one if it may); see "Peers" above."""
        if address == self.configured_address:
            return True
        now_s = self.clock()
        vouched = not self.codec.signing.enabled or any(is_signed(m.get_msgbuf()) for m in messages)
        self._forget_silent_peers(now_s)
        known = address in self._peers
        if not known and not vouched:
            self.refusals.refuse(
                "ground station not admitted", f"{address[0]}:{address[1]} sent nothing signed with the key"
            )
            return False
        if not known and len(self._peers) >= self.config.max_peers:
            self.refusals.refuse(
                "ground station not admitted",
                f"{address[0]}:{address[1]}: already {len(self._peers)} ground stations (max_peers)",
            )
            return False
        if vouched:
            self._peers[address] = now_s
        return True

    def _for_us(self, target_system: int) -> bool:
        return target_system in (0, self.config.system_id)

    def _on_timesync(self, message: Message, address: tuple[str, int]) -> None:
        if message.tc1 != 0:
            return  # an answer to somebody's request, not a request
        self.timesync_answers += 1
        self.endpoint.send(
            self.codec.encode(self.codec.mav.timesync_encode(time.monotonic_ns(), message.ts1)), address
        )

    def _on_command_long(self, message: Message, address: tuple[str, int]) -> None:
        if not self._for_us(message.target_system):
            return
        ack = answer_command(self.codec.mav, message, self.schedule, self.refusals.refuse)
        self.endpoint.send(self.codec.encode(ack), address)

    def _on_position_target(self, message: Message) -> None:
        if not self._for_us(message.target_system):
            return
        setpoint = self.setpoint_from_message(message)
        if isinstance(setpoint, Setpoint):
            self.setpoints += 1
            self.on_setpoint(setpoint)
        else:
            self.refusals.refuse(*setpoint)

    def setpoint_from_message(self, message: Message) -> Setpoint | tuple[str, str]:
        """A SET_POSITION_TARGET_LOCAL_NED as a setpoint, or (refusal reason, detail)."""
        mask, frame = int(message.type_mask), int(message.coordinate_frame)
        if mask & TYPE_MASK_POSITION_IGNORE:
            return (
                "unsupported setpoint",
                f"type_mask {mask:#06x} ignores the position; only positions are flown",
            )
        values = np.array([message.x, message.y, message.z, message.yaw], dtype=float)
        use_yaw = not mask & TYPE_MASK_YAW_IGNORE
        if not np.all(np.isfinite(values[:3])) or (use_yaw and not math.isfinite(values[3])):
            return "non-finite setpoint", f"x, y, z, yaw = {values.tolist()}"
        state = self.state
        current_ned = ned_view(state) if state is not None else None
        yaw_now_ned = float(current_ned.euler_NED_rad[2]) if current_ned is not None else 0.0
        p_now_ned = current_ned.p_NED_m if current_ned is not None else np.zeros(3)
        offset = values[:3]
        if frame in ABSOLUTE_FRAMES:
            p_ned, yaw_ned = offset, values[3]
        elif frame in OFFSET_FRAMES:
            p_ned, yaw_ned = p_now_ned + offset, values[3]
        elif frame in HEADING_OFFSET_FRAMES:
            c, s = math.cos(yaw_now_ned), math.sin(yaw_now_ned)
            rotated = np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1], offset[2]])
            p_ned, yaw_ned = p_now_ned + rotated, yaw_now_ned + values[3]
        else:
            return "unsupported frame", f"coordinate_frame {frame}; supported: 1, 7, 8, 9, 12"
        if not use_yaw:
            yaw_ned = yaw_now_ned
        if float(np.linalg.norm(p_ned)) > SETPOINT_RANGE_M:
            return (
                "setpoint out of range",
                f"{np.linalg.norm(p_ned):.0f} m from home (limit {SETPOINT_RANGE_M:.0f} m)",
            )
        return Setpoint(ned_to_enu(p_ned), float(yaw_ned_to_enu(yaw_ned)))

    def close(self) -> None:
        """Close the socket."""
        self.endpoint.close()
