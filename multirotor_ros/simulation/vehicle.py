"""One simulated vehicle: model + integrator + sensors + command clamp, watchdog and fault injection.

Pure Python and numpy (no ROS): the simulator node and the offline closed loop (flight.py) both drive
a :class:`VehicleSimulator` the same way:

    sim = VehicleSimulator(airframe, rng=np.random.default_rng(1))
    sim.set_command(speeds_rad_s)            # clamped to the airframe's speed range
    for reading in sim.run_until(t_ns):      # physics at physics_rate_hz, readings when they fall due
        ...                                  # reading.kind: odom, imu, pose, range, motor_speeds, watchdog

Time is an integer number of nanoseconds (physics steps of ``dt_ns``), so that stamps never drift.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import (
    ActuatorFault,
    Effect,
    MotorLag,
    evaluate,
    formula_arguments,
    make_effect,
)
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray, quat_to_matrix
from multirotor_ros.simulation import sensors as sens
from multirotor_ros.simulation.sensors import SensorConfig, airframe_sensor_config

NS_PER_S = 1_000_000_000
# A rotor speed above this multiple of the airframe's top speed is taken for a unit mistake (rpm sent as
# rad/s) and refused by whoever reads it; between the top speed and this, set_command clamps it as an
# ESC saturates.
OVERSIZED_SPEED_FACTOR = 2.0


def _sets_rotor_lag(effect: Effect) -> bool:
    """Whether the effect makes the rotors follow their commands with a time constant (motor_lag)."""
    return "rotor_time_constant_s" in effect.formulas()


def _is_scheduled(effect: Effect) -> bool:
    """Whether the effect acts from a moment of the flight on (its formulas read the time): a fault."""
    return any("t" in formula_arguments(formula) for formula in effect.formulas().values())


@dataclass(frozen=True)
class Reading:
    """Something the simulator produced at time ``t_ns``.

    kind and data: ``odom`` the true flat state (13 + N,); ``imu`` an :class:`sensors.ImuReading`;
    ``pose`` (p_WB_W, q_WB); ``range`` distance [m] (+inf: no echo); ``motor_speeds`` measured (N,);
    ``watchdog`` the time [s] since the last command when the rotors were stopped for lack of commands.
    """

    kind: str
    t_ns: int
    data: Any


@dataclass
class _Schedule:
    period_ns: int
    next_ns: int = 0


def period_ns(rate_hz: float) -> int:
    """The period of a rate as whole nanoseconds (>= 1)."""
    return max(1, round(NS_PER_S / rate_hz))


class VehicleSimulator:
    """The simulated vehicle; see the module docstring.

    ``effects``: the true effect list (None = the airframe's own). ``motor_lag``: rotor speeds follow
    their commands with the airframe's ``motor_time_constant_s`` and the ESC reports the true rotor speed
    (when the effect list already holds ``motor_lag``, that hidden lag is kept and the report is the
    speed the ESC was asked for, which is what effects.md's ``motor_lag`` describes). ``command_timeout_s``
    (0 = no watchdog): without a command for that long the rotors are commanded to stop.
    ``odom_rate_hz``: rate of the ``odom`` (truth) readings; the sensors have the rates of ``sensors``.
    """

    def __init__(
        self,
        airframe: Airframe,
        effects: Iterable[Effect | Mapping[str, Any]] | None = None,
        *,
        rng: np.random.Generator,
        physics_rate_hz: float = 1000.0,
        odom_rate_hz: float = 250.0,
        motor_lag: bool = True,
        command_timeout_s: float = 0.5,
        sensors: SensorConfig | None = None,
        noise: bool = True,
        initial_position_m: ArrayLike = (0.0, 0.0, 0.0),
        initial_yaw_rad: float = 0.0,
        ground_height_m: float = 0.0,
    ):
        if not (math.isfinite(physics_rate_hz) and physics_rate_hz > 0):
            raise ValueError(f"physics_rate_hz must be > 0, got {physics_rate_hz}")
        if not (math.isfinite(command_timeout_s) and command_timeout_s >= 0):
            raise ValueError(f"command_timeout_s must be >= 0, got {command_timeout_s}")
        self.airframe = airframe
        self.rng = rng
        self.dt_ns = period_ns(physics_rate_hz)
        self.ground_height_m = ground_height_m
        self.command_timeout_ns = round(command_timeout_s * NS_PER_S)
        config = sensors if sensors is not None else airframe_sensor_config(airframe)
        self.sensor_config = config if noise else config.without_noise()

        given = [make_effect(e) for e in (airframe.effect_specs() if effects is None else effects)]
        # The true effects as given (what a log's metadata reports); the simulator's own motor lag is not
        # one of them, since the ESC reports the lagged speed and no log can see it.
        self.true_effects: tuple[Effect, ...] = tuple(given)
        self._hidden_lag = any(_sets_rotor_lag(e) for e in given)
        self.motor_lag_s: float | None = None
        if motor_lag and not self._hidden_lag:
            self.motor_lag_s = airframe.motor_time_constant_s
            given.append(MotorLag(tau_s=airframe.motor_time_constant_s))
        # Scheduled effects are kept apart: inject_fault replaces them.
        self._base_effects = [e for e in given if not _is_scheduled(e)]
        self._faults = [e for e in given if _is_scheduled(e)]
        self._rebuild_model()

        self.t_ns = 0
        position = np.asarray(initial_position_m, dtype=float)
        airborne = position[2] > ground_height_m
        self.hover_speed_rad_s = self.model.hover_speed_rad_s()
        start_speed = self.hover_speed_rad_s if airborne else 0.0
        self.x = S.make_state(
            airframe.n_rotors,
            position_m=position,
            euler_rad=(0.0, 0.0, initial_yaw_rad),
            rotor_speed_rad_s=start_speed,
        )
        # A vehicle placed in the air starts as if just commanded to hover, so it does not drop at once.
        self.command_rad_s = np.full(airframe.n_rotors, start_speed)
        self._last_command_ns: int | None = 0 if airborne else None
        self.watchdog_tripped = False
        self._acceleration_W = np.zeros(3)
        self._imu = sens.Imu(self.sensor_config, rng, self.model.gravity_m_s2)
        # One throw-away step loads (or compiles) the integrator's kernel now rather than in the first
        # paced step, which would otherwise start a real-time run far behind.
        self.integrator.advance(0.0, self.x.copy(), self.command_rad_s[None, :], 1)
        self._schedules = {
            "odom": _Schedule(period_ns(odom_rate_hz)),
            "imu": _Schedule(period_ns(self.sensor_config.imu_rate_hz)),
            "pose": _Schedule(period_ns(self.sensor_config.pose_rate_hz)),
            "range": _Schedule(period_ns(self.sensor_config.range_rate_hz)),
            "motor_speeds": _Schedule(period_ns(self.sensor_config.rotor_speed_rate_hz)),
        }

    # ------------------------------------------------------------------ model

    def _rebuild_model(self) -> None:
        self.model = Model(self.airframe, self._base_effects + self._faults)
        self.integrator = Integrator(self.model, self.dt_ns / NS_PER_S, ground_height_m=self.ground_height_m)

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return self.t_ns / NS_PER_S

    @property
    def state(self) -> FloatArray:
        """The true flat state (13 + N,) (a view: do not modify)."""
        return self.x[0]

    # ------------------------------------------------------------------ inputs

    def set_command(self, speeds_rad_s: ArrayLike) -> FloatArray:
        """Take rotor speed commands [rad/s], clamped to the airframe's range; returns what was applied.

        Callers validate first (finite, N values): this raises ValueError on anything else.
        """
        speeds = np.asarray(speeds_rad_s, dtype=float)
        if speeds.shape != (self.airframe.n_rotors,) or not np.all(np.isfinite(speeds)):
            raise ValueError(f"need {self.airframe.n_rotors} finite rotor speeds, got {speeds}")
        self.command_rad_s = np.clip(
            speeds, self.airframe.rotor_speed_min_rad_s, self.airframe.rotor_speed_max_rad_s
        )
        self._last_command_ns = self.t_ns
        self.watchdog_tripped = False
        return self.command_rad_s

    def inject_fault(self, motor: int, effectiveness: float) -> None:
        """From now on rotor ``motor`` (1..N) gives ``effectiveness`` (0..1) of its thrust; 0 = repaired.

        This replaces any earlier fault, a hidden one of the effect list (``actuator_fault``) included.
        """
        if not 0 <= motor <= self.airframe.n_rotors:
            raise ValueError(f"fault motor must be 0 (none) or 1..{self.airframe.n_rotors}, got {motor}")
        if not 0.0 <= effectiveness <= 1.0:
            raise ValueError(f"fault effectiveness must be in [0, 1], got {effectiveness}")
        self._faults = (
            []
            if motor == 0
            else [ActuatorFault(motor=motor, effectiveness=effectiveness, t_fault_s=self.t_s)]
        )
        self._rebuild_model()

    def injected_effectiveness(self) -> FloatArray:
        """(N,) effectiveness applied to each rotor now: the truth of the injected (or hidden) fault."""
        context = self.model.context(S.StateBatch.from_flat(self.t_s, self.x, self.x[:, S.ROTORS_START :]))
        result = np.ones(self.airframe.n_rotors)
        for fault in self._faults:
            if "rotor_thrust_factor" in fault.formulas():
                result = result * evaluate(fault, "rotor_thrust_factor", context)[0]
        return result

    # ------------------------------------------------------------------ stepping

    def run_until(self, t_ns: int) -> list[Reading]:
        """Integrate up to ``t_ns`` (whole physics steps, at least up to it) and return the readings due."""
        readings: list[Reading] = []
        self._sample_due(readings)  # readings due now (at t = 0: the first of each kind)
        while self.t_ns < t_ns:
            target = min([t_ns, *(s.next_ns for s in self._schedules.values() if s.next_ns > self.t_ns)])
            deadline = self._watchdog_deadline()
            if deadline is not None and self.t_ns < deadline < target:
                target = deadline
            steps = max(1, -(-(target - self.t_ns) // self.dt_ns))
            self._advance(steps, imu_due=self._schedules["imu"].next_ns <= self.t_ns + steps * self.dt_ns)
            self._check_watchdog(readings)
            self._sample_due(readings)
        return readings

    def _watchdog_deadline(self) -> int | None:
        if self.command_timeout_ns == 0 or self._last_command_ns is None or self.watchdog_tripped:
            return None
        return self._last_command_ns + self.command_timeout_ns

    def _check_watchdog(self, readings: list[Reading]) -> None:
        deadline = self._watchdog_deadline()
        if deadline is not None and self.t_ns >= deadline:
            self.watchdog_tripped = True
            self.command_rad_s = np.full(self.airframe.n_rotors, self.airframe.rotor_speed_min_rad_s)
            last_command_ns = deadline - self.command_timeout_ns
            readings.append(Reading("watchdog", self.t_ns, (self.t_ns - last_command_ns) / NS_PER_S))

    def _sample_due(self, readings: list[Reading]) -> None:
        for kind, schedule in self._schedules.items():
            if self.t_ns >= schedule.next_ns:
                readings.append(Reading(kind, self.t_ns, self.sample(kind)))
                # Next due time on the schedule's own grid, skipping any it has missed.
                missed = (self.t_ns - schedule.next_ns) // schedule.period_ns
                schedule.next_ns += (missed + 1) * schedule.period_ns

    def _advance(self, steps: int, imu_due: bool) -> None:
        command = self.command_rad_s[None, :]
        if imu_due:
            # The IMU needs the acceleration: the last step is taken alone, and its velocity change over dt
            # is the mean acceleration of that step (exact for RK4's update, ground reaction included).
            if steps > 1:
                self.x = self.integrator.advance(self.t_s, self.x, command, steps - 1)
                self.t_ns += (steps - 1) * self.dt_ns
            v_before = self.x[0, S.VELOCITY].copy()
            self.x = self.integrator.advance(self.t_s, self.x, command, 1)
            self.t_ns += self.dt_ns
            self._acceleration_W = (self.x[0, S.VELOCITY] - v_before) / (self.dt_ns / NS_PER_S)
        else:
            self.x = self.integrator.advance(self.t_s, self.x, command, steps)
            self.t_ns += steps * self.dt_ns

    def acceleration_W(self) -> FloatArray:
        """True acceleration [m/s^2] in world ENU (dv/dt, gravity not included) over the last IMU step."""
        return self._acceleration_W.copy()

    def sample(self, kind: str) -> Any:
        """A reading of one kind at the current time (draws noise from the generator)."""
        state = self.x[0]
        config = self.sensor_config
        if kind == "odom":
            return state.copy()
        if kind == "imu":
            return self._imu.sample(self.t_s, state[S.QUATERNION], self.acceleration_W(), state[S.BODY_RATE])
        if kind == "pose":
            return sens.pose_reading(config, self.rng, state[S.POSITION], state[S.QUATERNION])
        if kind == "range":
            R = quat_to_matrix(state[S.QUATERNION])
            return sens.range_reading(config, self.rng, state[S.POSITION], R, self.ground_height_m)
        if kind == "motor_speeds":
            speeds = self.command_rad_s if self._hidden_lag else state[S.ROTORS_START :]
            return sens.rotor_speed_reading(config, self.rng, np.asarray(speeds, dtype=float))
        raise ValueError(f"unknown reading kind {kind!r}")
