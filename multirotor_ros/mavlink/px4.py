"""The simulator side of PX4's simulator MAVLink interface (``simulator_mavlink``, TCP 4560).

PX4 connects as a TCP client and sends HEARTBEAT, a COMMAND_LONG SET_MESSAGE_INTERVAL asking for
HIL_STATE_QUATERNION, and then one HIL_ACTUATOR_CONTROLS per control cycle: ``controls[16]``,
``mode`` (bit 128 = armed) and ``flags`` (bit 0 = PX4 runs in lockstep). This side sends:

- HIL_SENSOR at every physics step: specific force and body rates in FRD, the magnetic field in gauss,
  absolute pressure [hPa], pressure altitude [m] and temperature, ``fields_updated`` = every bit of
  the accelerometer, gyroscope, magnetometer and barometer groups (PX4 checks each group as a whole),
  ``time_usec`` = simulated time [us];
- HIL_GPS (degE7, mm, cm/s NED) at 10 Hz, 5-10 Hz on request;
- HIL_STATE_QUATERNION (ground truth, quaternion w, x, y, z body FRD -> NED) at 50 Hz or as requested;
- HEARTBEAT once a second.

Time. PX4 cannot run before it has a clock, and its clock in lockstep is HIL_SENSOR's ``time_usec``:
so once PX4 is connected, the session steps the physics on the wall clock (every ``step_s``, rotors
idle) and sends sensors, until the first actuator message arrives. If that message has the lockstep
flag, the session switches to lockstep and nothing else moves time: an actuator message stamped
``time_usec`` (PX4's clock, which in lockstep is the ``time_usec`` of the HIL_SENSOR it computed on,
SimulatorMavlink.cpp: ``px4_clock_settime`` from HIL_SENSOR, ``hrt_absolute_time()`` into
HIL_ACTUATOR_CONTROLS) holds its command from that instant to one ``step_s`` later: the physics advances
to exactly ``time_usec + step_s`` (sub-steps no longer than the physics step) and answers with the
sensors of that instant. A command computed on an older sensor than the newest one sent (PX4 answering
a sensor the stall rule below sent while it was busy) is held without moving time, since the newest
sensor's answer is on its way; a stamp of 0 (no clock) or ahead of the newest sensor is taken as
answering the newest one, the latter counted as refused. PX4 waits for the sensors of each step before
its next cycle, so the flight is identical however fast either side runs. Without the flag the physics
keeps running on the wall clock with the latest command, ``step_s`` at a time. In external mode (physics
in the simulator node) the session forwards every new state instead of stepping anything.

Faults. A message that cannot be used is counted and ignored; in lockstep an unusable actuator
message still advances one step with the previous command, because PX4's clock would otherwise stop,
and so does ``stall_timeout_s`` (2 s) without any actuator message (one lost in corrupt bytes would
leave each side waiting for the other).
A disconnect freezes the physics where it is; a reconnecting PX4 continues from that state and time.
A second connection while one is open is closed at once and counted.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.messages import (
    MessageSchedule,
    NedView,
    answer_command,
    ned_view,
    time_usec,
)
from multirotor_ros.mavlink.sensors import STANDARD_GRAVITY_M_S2, GpsFix, SensorModel
from multirotor_ros.mavlink.timing import FrameTimes
from multirotor_ros.mavlink.vehicle import Simulation, VehicleState
from multirotor_ros.mavlink.wire import MavlinkCodec, Message, SocketCallbacks, TcpServerEndpoint
from multirotor_ros.refusals import RefusalCounter

_LOGGER = logging.getLogger(__name__)

DEFAULT_PORT = 4560
MODE_FLAG_ARMED = 128
FLAG_LOCKSTEP = 1
# HIL_SENSOR.fields_updated groups (PX4 SimulatorMavlink.hpp SensorSource).
FIELDS_ACCEL = 0b111
FIELDS_GYRO = 0b111000
FIELDS_MAG = 0b111000000
FIELDS_BARO = 0b1101000000000  # abs_pressure, pressure_alt, temperature
FIELDS_ALL = FIELDS_ACCEL | FIELDS_GYRO | FIELDS_MAG | FIELDS_BARO
MSG_HIL_GPS = mavlink2.MAVLINK_MSG_ID_HIL_GPS
MSG_HIL_STATE_QUATERNION = mavlink2.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
MSG_HEARTBEAT = mavlink2.MAVLINK_MSG_ID_HEARTBEAT


@dataclass(frozen=True)
class Px4Config:
    """Where to listen and how often to send what."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    step_s: float = 0.004  # [s] one physics step per actuator message (PX4 SITL's 250 Hz)
    gps_rate_hz: float = 10.0  # [Hz] 5..10
    state_rate_hz: float = 50.0  # [Hz] HIL_STATE_QUATERNION until PX4 asks for another rate
    system_id: int = 1
    component_id: int = 200  # what PX4's Gazebo plugins use for the simulator
    # [s] wall time without an actuator message after which lockstep takes one step on its own (a
    # busy machine can hold PX4 up for a good fraction of a second: keep well above that).
    stall_timeout_s: float = 2.0
    measure_timing: bool = False  # keep FrameTimes of the lockstep steps (benchmarks)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.step_s) and 1e-4 <= self.step_s <= 0.05):
            raise ValueError(f"lockstep step {self.step_s} s outside 0.0001..0.05 s")
        if not 5.0 <= self.gps_rate_hz <= 10.0:
            raise ValueError(f"GPS rate {self.gps_rate_hz} Hz outside 5..10 Hz")
        if not (math.isfinite(self.stall_timeout_s) and self.stall_timeout_s > 0.0):
            raise ValueError(f"lockstep stall timeout {self.stall_timeout_s} s must be > 0")
        if not 0.0 < self.state_rate_hz <= 1000.0:
            raise ValueError(f"HIL_STATE_QUATERNION rate {self.state_rate_hz} Hz outside (0, 1000] Hz")


class Px4Session:
    """One PX4 at a time on a TCP port; see the module docstring."""

    def __init__(
        self,
        config: Px4Config,
        simulation: Simulation,
        channels: RotorChannels,
        sensors: SensorModel,
        refusals: RefusalCounter,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.simulation = simulation
        self.channels = channels
        self.sensors = sensors
        self.refusals = refusals
        self.clock = clock
        self.codec = MavlinkCodec(config.system_id, config.component_id, refusals)
        self.endpoint = TcpServerEndpoint(
            config.host,
            config.port,
            SocketCallbacks(self._on_connect, self._on_data, self._on_disconnect),
            refusals,
        )
        self.schedule = MessageSchedule(
            {MSG_HIL_GPS: config.gps_rate_hz, MSG_HIL_STATE_QUATERNION: config.state_rate_hz},
            {MSG_HIL_GPS: (5.0, 10.0), MSG_HIL_STATE_QUATERNION: (0.1, 1000.0)},
        )
        self.heartbeat_schedule = MessageSchedule({MSG_HEARTBEAT: 1.0})
        self.lockstep = False
        self.armed = False
        self.actuator_messages = 0
        self.late_commands = 0  # computed on an older sensor than the newest: held, time not moved
        self.connections = 0
        self.stalls = 0
        self.times = FrameTimes() if config.measure_timing else None
        self._received_ns = 0
        self._step_ns = round(config.step_s * 1e9)
        self._next_free_step_s = math.inf
        self._last_actuators_s = -math.inf
        self._last_sent_t_s = -math.inf

    @property
    def connected(self) -> bool:
        """Whether a PX4 is connected."""
        return self.endpoint.peer is not None

    # ------------------------------------------------------------------ connection

    def _on_connect(self, address: tuple[str, int]) -> None:
        self.connections += 1
        _LOGGER.info("PX4 connected from %s:%d", *address)
        self.codec.reset()
        self.lockstep = False
        self._send(self._heartbeat())
        self._next_free_step_s = self.clock()

    def _on_disconnect(self, why: str) -> None:
        _LOGGER.warning("PX4 disconnected (%s); the vehicle keeps its state until it reconnects", why)
        self._next_free_step_s = math.inf

    def _send(self, message: Message) -> None:
        self.endpoint.send(self.codec.encode(message))

    # ------------------------------------------------------------------ incoming

    def _on_data(self, data: bytes) -> None:
        if self.times is not None:
            self._received_ns = time.time_ns()
        for message in self.codec.decode(data):
            kind = message.get_type()
            if kind == "HIL_ACTUATOR_CONTROLS":
                self._on_actuators(message)
            elif kind == "COMMAND_LONG":
                self._on_command_long(message)

    def _on_actuators(self, message: Message) -> None:
        self.actuator_messages += 1
        self._last_actuators_s = self.clock()
        self.armed = bool(message.mode & MODE_FLAG_ARMED)
        command = self.channels.from_px4_controls(message.controls, self.armed)
        for problem in command.problems:
            self.refusals.refuse(problem.reason, f"HIL_ACTUATOR_CONTROLS: {problem.detail}")
        if command.speeds_rad_s is not None:
            self.simulation.command(command.speeds_rad_s)
        self.lockstep = bool(message.flags & FLAG_LOCKSTEP)
        if self.simulation.internal:
            if self.lockstep:
                self._next_free_step_s = math.inf
                target_ns = self._computed_on_ns(message.time_usec) + self._step_ns
                if target_ns > self.simulation.t_ns:
                    self.send_state(self.simulation.advance_to(target_ns), answering=True)
                else:
                    self.late_commands += 1
            elif math.isinf(self._next_free_step_s):
                self._next_free_step_s = self.clock()
        self.simulation.announce()

    def _computed_on_ns(self, stamp_usec: int) -> int:
        """The simulated time [ns] of the sensors an actuator message was computed on (module docstring)."""
        newest_ns = self.simulation.t_ns
        newest_usec = time_usec(newest_ns * 1e-9)  # as the newest HIL_SENSOR was stamped
        if stamp_usec == 0 or stamp_usec == newest_usec:
            return newest_ns
        if stamp_usec > newest_usec:
            self.refusals.refuse(
                "actuator stamp ahead",
                f"HIL_ACTUATOR_CONTROLS at {stamp_usec} us, the newest HIL_SENSOR at {newest_usec} us",
            )
            return newest_ns
        return stamp_usec * 1000

    def _on_command_long(self, message: Message) -> None:
        self._send(answer_command(self.codec.mav, message, self.schedule, self.refusals.refuse))

    # ------------------------------------------------------------------ outgoing

    def send_state(self, state: VehicleState, answering: bool = False) -> None:
        """HIL_SENSOR for this state, and HIL_GPS / HIL_STATE_QUATERNION / HEARTBEAT when they are due.

        All of one step goes out in one write: one wake-up of the flight stack per step. ``answering``:
        the answer to the actuator message just read (its time is kept with ``measure_timing``).
        """
        if not self.connected or state.t_s <= self._last_sent_t_s:
            return
        self._last_sent_t_s = state.t_s
        view = ned_view(state)
        stamp = time_usec(state.t_s)
        encode = self.codec.encode
        data = encode(self._hil_sensor(state, view, stamp))
        gps_due = self.schedule.due(MSG_HIL_GPS, state.t_s)
        truth_due = self.schedule.due(MSG_HIL_STATE_QUATERNION, state.t_s)
        if gps_due or truth_due:
            fix = self.sensors.gps(state.p_WB_W, state.v_WB_W)
            if gps_due:
                data += encode(self._hil_gps(fix, stamp))
            if truth_due:
                data += encode(self._hil_state_quaternion(fix, view, stamp))
        if self.heartbeat_schedule.due(MSG_HEARTBEAT, state.t_s):
            data += encode(self._heartbeat())
        if answering and self.times is not None:
            # Taken as the answer leaves: PX4 may answer it before the write returns to us.
            self.times.frame(self._received_ns, time.time_ns())
        self.endpoint.send(data)

    def on_external_state(self, state: VehicleState) -> None:
        """External mode: a new state from the simulator node goes straight out."""
        self.send_state(state)

    def poll(self, now_s: float) -> float:
        """Run wall-clock work that is due; return when to be called next (monotonic seconds)."""
        if not (self.connected and self.simulation.internal):
            return math.inf
        step = self.config.step_s
        if self.lockstep:
            # An actuator message lost in corrupt bytes would stop both sides for good (each waits for
            # the other): after stall_timeout_s of silence, take one step with the held command.
            stall_deadline = self._last_actuators_s + self.config.stall_timeout_s
            if now_s < stall_deadline:
                return stall_deadline
            self.stalls += 1
            if self.stalls == 1:
                _LOGGER.warning(
                    "lockstep stalled for %.1f s: stepping once to wake the flight stack",
                    self.config.stall_timeout_s,
                )
            self._last_actuators_s = now_s
            self.send_state(self.simulation.advance_to(self.simulation.t_ns + self._step_ns))
            self.simulation.announce()
            return now_s + self.config.stall_timeout_s
        while now_s >= self._next_free_step_s:
            self.send_state(self.simulation.advance_to(self.simulation.t_ns + self._step_ns))
            self.simulation.announce()
            self._next_free_step_s += step
            if now_s - self._next_free_step_s > 0.1:
                # Too slow to keep up with the wall clock: skip ahead rather than run a backlog.
                self._next_free_step_s = now_s + step
        return self._next_free_step_s

    def restart_time(self) -> None:
        """The simulated clock went back to zero (the physics was reset)."""
        self._last_sent_t_s = -math.inf
        self.schedule.restart()
        self.heartbeat_schedule.restart()

    def _hil_sensor(self, state: VehicleState, view: NedView, stamp: int) -> Message:
        accel = view.imu_accel_FRD_m_s2
        gyro = view.imu_gyro_FRD_rad_s
        mag = self.sensors.magnetometer_frd_gauss(state.q_WB)
        baro = self.sensors.barometer(state.p_WB_W)
        return self.codec.mav.hil_sensor_encode(
            stamp,
            accel[0],
            accel[1],
            accel[2],
            gyro[0],
            gyro[1],
            gyro[2],
            mag[0],
            mag[1],
            mag[2],
            baro.pressure_hpa,
            0.0,
            baro.pressure_altitude_m,
            baro.temperature_degc,
            FIELDS_ALL,
            0,
        )

    def _hil_gps(self, fix: GpsFix, stamp: int) -> Message:
        vn, ve, vd = fix.v_ned_cm_s
        return self.codec.mav.hil_gps_encode(
            stamp,
            3,
            fix.latitude_e7,
            fix.longitude_e7,
            fix.altitude_mm,
            30,
            40,
            fix.ground_speed_cm_s,
            vn,
            ve,
            vd,
            fix.course_cdeg,
            12,
            0,
            0,
        )

    def _hil_state_quaternion(self, fix: GpsFix, view: NedView, stamp: int) -> Message:
        vn, ve, vd = fix.v_ned_cm_s
        w = view.w_FRD_rad_s
        # Floats in integer fields: the codec rounds them and clamps them to their ranges.
        speed_cm_s = float(np.linalg.norm(view.v_NED_m_s / 1e3)) * 1e5  # scaled: 1e308 m/s must not overflow
        accel_mg = (view.imu_accel_FRD_m_s2 / STANDARD_GRAVITY_M_S2 * 1000.0).tolist()
        return self.codec.mav.hil_state_quaternion_encode(
            stamp,
            view.q_NED_FRD.tolist(),
            w[0],
            w[1],
            w[2],
            fix.latitude_e7,
            fix.longitude_e7,
            fix.altitude_mm,
            vn,
            ve,
            vd,
            speed_cm_s,
            speed_cm_s,
            accel_mg[0],
            accel_mg[1],
            accel_mg[2],
        )

    def _heartbeat(self) -> Message:
        return self.codec.mav.heartbeat_encode(
            mavlink2.MAV_TYPE_GENERIC, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
        )

    def close(self) -> None:
        """Close the sockets."""
        self.endpoint.close()
