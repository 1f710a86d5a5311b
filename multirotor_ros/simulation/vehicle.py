"""Simulated vehicles: model + integrator + sensors + command clamp, watchdog and fault injection.

Pure Python and numpy (no ROS): the simulator node and the offline closed loop (flight.py) both drive
a :class:`VehicleSimulator` the same way:

    sim = VehicleSimulator(airframe, rng=np.random.default_rng(1))
    sim.set_command(speeds_rad_s)            # clamped to the airframe's speed range
    for reading in sim.run_until(t_ns):      # physics at physics_rate_hz, readings when they fall due
        ...                                  # reading.kind: odom, imu, pose, range, motor_speeds,
                                             # watchdog, crash
    sim.reset()                              # back to the initial state; time goes on

A fleet is V vehicles of one airframe in one simulator, stepped together: each integrator call advances
all of them (one lane of the compiled kernel per vehicle); one vehicle is the case V = 1 of the same
code. V is the number of generators given, one per vehicle (:func:`vehicle_generators` makes them from
one seed):

    fleet = VehicleSimulator(airframe, rng=vehicle_generators(seed, 3),
                             initial_position_m=[(0, 0, 0), (2, 0, 0), (4, 0, 0)],  # (3,) or (V, 3)
                             initial_yaw_rad=[0.0, 0.0, 1.57])                       # scalar or (V,)
    fleet.set_command(speeds_rad_s, vehicle=2)
    fleet.inject_fault(motor=3, effectiveness=0.0, vehicle=1)
    for reading in fleet.run_until(t_ns):    # reading.vehicle: which vehicle (0..V-1)
        ...

Per vehicle: its state ``x[k]`` (``x`` is (V, 13 + N)), its applied command ``commands_rad_s[k]``, its
watchdog (``last_command_ns[k]``, ``watchdog_tripped[k]``), its crash latch (``crashes.crashed[k]``),
its injected fault, its generator ``rngs[k]`` and its IMU bias. Shared: the airframe, the true effect
list, time (one clock), the sensor configuration and rates (all vehicles' readings fall due together;
within one time the readings come kind by kind, vehicle 0 first). Methods about one vehicle take
``vehicle=k`` (default 0; an index outside 0..V-1 is a ValueError); ``state`` and ``command_rad_s``
name the one vehicle of a simulator of V = 1 and refuse a fleet (use ``x[k]``, ``commands_rad_s[k]``).

A vehicle's readings are the same, bit for bit, whether it flies alone (with the same generator) or in a
fleet: the kernel computes each lane on its own, a vehicle draws its noise from its own generator in the
same order, and the sensor models compute each vehicle with the same arithmetic whatever V is
(sensors.py). The tests hold a fleet to that.

Ground and crashes (multirotor_ros.model.integrator): the ground holds a vehicle resting on it (no
sliding, no turning) until its thrust lifts it. A touchdown faster than ``crash_speed_m_s`` or tilted
more than ``crash_tilt_rad`` is a crash, reported once as a ``crash`` reading: the vehicle then lies
where it hit, its rotors commanded to stop, and commands to it are taken but applied as zero (its
watchdog rests), until :meth:`VehicleSimulator.reset`.

Time is an integer number of nanoseconds (physics steps of ``dt_ns``), so that stamps never drift; a
reset does not turn it back.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import (
    ActuatorFault,
    Effect,
    MotorLag,
    RotorEffectiveness,
    evaluate,
    formula_arguments,
    make_effect,
)
from multirotor_ros.model.integrator import CrashLatch, Integrator
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.simulation import sensors as sens
from multirotor_ros.simulation.sensors import SensorConfig, airframe_sensor_config

NS_PER_S = 1_000_000_000
# A rotor speed above this multiple of the airframe's top speed is taken for a unit mistake (rpm sent as
# rad/s) and refused by whoever reads it; between the top speed and this, set_command clamps it as an
# ESC saturates.
OVERSIZED_SPEED_FACTOR = 2.0
# last_command_ns of a vehicle that was never commanded (its watchdog is not armed).
NEVER = -1
# Default crash limits. Speed: a free fall from about 0.3 m (v = sqrt(2 g h)), what a multirotor's
# landing gear and frame take without damage; a normal landing sinks at 0.5-1 m/s, and this leaves room
# for a firm one. Tilt: a skid or leg gear is about as wide as the centre of mass is high, so touching
# down tilted past about 45 degrees tips the vehicle over its gear onto an arm, and its propellers strike;
# a controlled landing stays within 10-15 degrees of level.
CRASH_SPEED_M_S = 2.5
CRASH_TILT_RAD = math.pi / 4


def _sets_rotor_lag(effect: Effect) -> bool:
    """Whether the effect makes the rotors follow their commands with a time constant (motor_lag)."""
    return "rotor_time_constant_s" in effect.formulas()


def _is_scheduled(effect: Effect) -> bool:
    """Whether the effect acts from a moment of the flight on (its formulas read the time): a fault."""
    return any("t" in formula_arguments(formula) for formula in effect.formulas().values())


def vehicle_generators(seed: int | None, count: int) -> list[np.random.Generator]:
    """``count`` independent generators from one seed (numpy ``SeedSequence.spawn``).

    Vehicle k's generator is the k-th child of the seed whatever ``count`` is, so its noise does not
    depend on the size of its fleet: ``vehicle_generators(s, 1)[0]`` is vehicle 0 of any fleet of seed s.
    """
    if count < 1:
        raise ValueError(f"need at least one vehicle, got {count}")
    return [np.random.default_rng(child) for child in np.random.SeedSequence(seed).spawn(count)]


def _per_lane(lanes: Sequence[Sequence[Effect]], n_rotors: int) -> list[Effect]:
    """Every lane's scheduled effects as one effect per id, its parameters (V,) arrays (row k: lane k).

    The compiled kernel reads one parameter row per lane (``model.compiled.ParameterLayout`` packs a
    (V,) parameter into that lane's row), and the numpy model broadcasts (V,) parameters over the batch,
    so one model steps vehicles with different faults. A lane without the effect gets its neutral
    parameters: for ``actuator_fault`` effectiveness 1, a thrust factor of exactly 1.0, which leaves that
    lane's arithmetic bit for bit as without the effect.
    """
    merged: list[Effect] = []
    for effect_id in dict.fromkeys(effect.id for lane in lanes for effect in lane):
        found = [next((e for e in lane if e.id == effect_id), None) for lane in lanes]
        given = next(e for e in found if e is not None)
        neutral = type(given).neutral_parameters(n_rotors)
        columns = {
            name: np.array([neutral[name] if e is None else float(e[name]) for e in found])
            for name in given.parameters
        }
        merged.append(type(given)(**columns))
    return merged


def _onset_ns(fault: Effect) -> int:
    """An ``actuator_fault``'s onset on the simulator's clock [ns]."""
    return round(float(fault["t_fault_s"]) * NS_PER_S)


def _fold_started_faults(
    faults: Sequence[Effect], t_ns: int, base: RotorEffectiveness | None, n_rotors: int
) -> list[Effect]:
    """A vehicle's several ``actuator_fault`` entries as effects the model takes (one per id).

    The model takes one ``actuator_fault``: the faults already begun at ``t_ns`` become one
    ``rotor_effectiveness`` (their thrust factors multiplied, the airframe's own ``rotor_effectiveness``
    ``base`` included), and the next one to begin stays an ``actuator_fault``, which starts inside the
    integrator at its onset. The simulator rebuilds its model at every onset (run_until stops there).
    """
    started = [f for f in faults if _onset_ns(f) <= t_ns]
    pending = sorted((f for f in faults if _onset_ns(f) > t_ns), key=_onset_ns)
    factors = np.array([1.0 if base is None else float(base[f"e_{i + 1}"]) for i in range(n_rotors)])
    for fault in started:
        factors[int(fault["motor"]) - 1] *= float(fault["effectiveness"])
    folded = RotorEffectiveness(**{f"e_{i + 1}": value for i, value in enumerate(factors)})
    return [folded, *pending[:1]]


class Reading(NamedTuple):
    """Something the simulator produced at time ``t_ns`` for vehicle ``vehicle`` (0 when alone).

    kind and data: ``odom`` the true flat state (13 + N,); ``imu`` an :class:`sensors.ImuReading`;
    ``pose`` (p_WB_W, q_WB); ``range`` distance [m] (+inf: no echo); ``motor_speeds`` measured (N,);
    ``watchdog`` the time [s] since the last command when the rotors were stopped for lack of commands;
    ``crash`` a :class:`Crash`, at the step the vehicle hit the ground.
    A named tuple: immutable, and a fleet makes tens of thousands a second (a tuple is made in a third of
    the time of a frozen dataclass).
    """

    kind: str
    t_ns: int
    data: Any
    vehicle: int = 0


class Crash(NamedTuple):
    """How a vehicle crashed: the data of a ``crash`` reading."""

    touchdown_speed_m_s: float  # downward speed when it hit the ground [m/s]
    tilt_rad: float  # angle between its body z axis and world up as it lies [rad]
    p_WB_W: FloatArray  # (3,) where it lies, world ENU [m]

    def describe(self) -> str:
        """How it hit the ground, for a log line."""
        tilt_deg = math.degrees(self.tilt_rad)
        return f"hit the ground at {self.touchdown_speed_m_s:.1f} m/s, lies tilted {tilt_deg:.0f} deg"


@dataclass
class _Schedule:
    period_ns: int
    next_ns: int = 0


def period_ns(rate_hz: float) -> int:
    """The period of a rate as whole nanoseconds (>= 1)."""
    return max(1, round(NS_PER_S / rate_hz))


class VehicleSimulator:
    """One simulated vehicle, or a fleet of them stepped together; see the module docstring.

    ``rng``: one generator (one vehicle) or a sequence of V generators (V vehicles, one each).
    ``initial_position_m``: (3,) for every vehicle or (V, 3); ``initial_yaw_rad``: one or (V,).
    ``effects``: the true effect list of every vehicle (None = the airframe's own). ``motor_lag``: rotor
    speeds follow their commands with the airframe's ``motor_time_constant_s`` and the ESC reports the
    true rotor speed (when the effect list already holds ``motor_lag``, that hidden lag is kept and the
    report is the speed the ESC was asked for, which is what effects.md's ``motor_lag`` describes).
    ``command_timeout_s`` (0 = no watchdog): a vehicle without a command for that long has its rotors
    commanded to stop. ``odom_rate_hz``: rate of the ``odom`` (truth) readings; the sensors have the
    rates of ``sensors``. ``crash_speed_m_s`` [m/s] and ``crash_tilt_rad`` [rad]: the touchdown that is a
    crash (module docstring; defaults :data:`CRASH_SPEED_M_S`, :data:`CRASH_TILT_RAD`; ``math.inf`` and
    ``math.pi`` turn either test off).
    """

    def __init__(
        self,
        airframe: Airframe,
        effects: Iterable[Effect | Mapping[str, Any]] | None = None,
        *,
        rng: np.random.Generator | Sequence[np.random.Generator],
        physics_rate_hz: float = 1000.0,
        odom_rate_hz: float = 250.0,
        motor_lag: bool = True,
        command_timeout_s: float = 0.5,
        sensors: SensorConfig | None = None,
        noise: bool = True,
        initial_position_m: ArrayLike = (0.0, 0.0, 0.0),
        initial_yaw_rad: ArrayLike = 0.0,
        ground_height_m: float = 0.0,
        crash_speed_m_s: float = CRASH_SPEED_M_S,
        crash_tilt_rad: float = CRASH_TILT_RAD,
    ):
        if not (math.isfinite(physics_rate_hz) and physics_rate_hz > 0):
            raise ValueError(f"physics_rate_hz must be > 0, got {physics_rate_hz}")
        if not (math.isfinite(command_timeout_s) and command_timeout_s >= 0):
            raise ValueError(f"command_timeout_s must be >= 0, got {command_timeout_s}")
        self.rngs: list[np.random.Generator] = [rng] if isinstance(rng, np.random.Generator) else list(rng)
        if not self.rngs:
            raise ValueError("need at least one vehicle: rng is an empty sequence")
        self.vehicles = len(self.rngs)
        positions = self._per_vehicle("initial_position_m", initial_position_m, (3,))
        yaws = self._per_vehicle("initial_yaw_rad", initial_yaw_rad, ())
        self.airframe = airframe
        self.dt_ns = period_ns(physics_rate_hz)
        self._command_shape = (airframe.n_rotors,)
        self._speed_bounds = (
            np.full(airframe.n_rotors, airframe.rotor_speed_min_rad_s),
            np.full(airframe.n_rotors, airframe.rotor_speed_max_rad_s),
        )
        self.ground_height_m = ground_height_m
        self._command_timeout_ns = round(command_timeout_s * NS_PER_S)
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
        # Scheduled effects are kept apart, per vehicle: inject_fault replaces one vehicle's. Several
        # actuator_fault entries (rotors failing one after another) are flown by _fold_started_faults.
        self._base_effects = [e for e in given if not _is_scheduled(e)]
        self._faults = [[e for e in given if _is_scheduled(e)] for _ in range(self.vehicles)]
        self.t_ns = 0
        self._rebuild_model()

        n = airframe.n_rotors
        airborne = positions[:, 2] > ground_height_m
        self.hover_speed_rad_s = self.model.hover_speed_rad_s()
        start_speed = np.where(airborne, self.hover_speed_rad_s, 0.0)
        euler = np.zeros((self.vehicles, 3))
        euler[:, 2] = yaws
        self.x = S.make_state(
            n, self.vehicles, position_m=positions, euler_rad=euler, rotor_speed_rad_s=start_speed[:, None]
        )
        # A vehicle placed in the air starts as if just commanded to hover, so it does not drop at once.
        self.commands_rad_s: FloatArray = np.repeat(start_speed[:, None], n, axis=1)
        self.last_command_ns: NDArray[np.int64] = np.where(airborne, 0, NEVER).astype(np.int64)
        self.watchdog_tripped = np.zeros(self.vehicles, dtype=bool)
        self.crashes = CrashLatch(self.vehicles, crash_speed_m_s, crash_tilt_rad)
        self._initial = (self.x.copy(), self.commands_rad_s.copy(), self.last_command_ns.copy())
        self._deadline_stale = True
        self._deadline_ns: int | None = None
        self._acceleration_W = np.zeros((self.vehicles, 3))
        config = self.sensor_config
        self._imu = sens.Imu(
            config, sens.standard_normals(self.rngs, sens.Imu.INITIAL_DRAWS), self.model.gravity_m_s2
        )
        # Standard normals per vehicle and sample of each kind (sensors.py: the order each model uses them).
        self._draws = {
            "odom": 0,
            "imu": sens.Imu.draws(config),
            "pose": sens.pose_draws(config),
            "range": 0,
            "motor_speeds": sens.rotor_speed_draws(airframe.n_rotors),
        }
        # One throw-away step loads (or compiles) the integrator's kernel now rather than in the first
        # paced step, which would otherwise start a real-time run far behind.
        self.integrator.advance(0.0, self.x.copy(), self.commands_rad_s, 1)
        self._schedules = {
            "odom": _Schedule(period_ns(odom_rate_hz)),
            "imu": _Schedule(period_ns(self.sensor_config.imu_rate_hz)),
            "pose": _Schedule(period_ns(self.sensor_config.pose_rate_hz)),
            "range": _Schedule(period_ns(self.sensor_config.range_rate_hz)),
            "motor_speeds": _Schedule(period_ns(self.sensor_config.rotor_speed_rate_hz)),
        }

    def _per_vehicle(self, name: str, value: ArrayLike, shape: tuple[int, ...]) -> FloatArray:
        """``value`` of one vehicle (``shape``) or of each, as (V, *shape)."""
        array = np.asarray(value, dtype=float)
        if array.shape not in (shape, (self.vehicles, *shape)):
            raise ValueError(
                f"{name}: expected shape {shape} or {(self.vehicles, *shape)} for {self.vehicles} "
                f"vehicle(s) (one generator each), got {array.shape}"
            )
        return np.broadcast_to(array, (self.vehicles, *shape))

    # ------------------------------------------------------------------ model

    def _several_faults(self, k: int) -> bool:
        """Whether vehicle k has more than one ``actuator_fault`` (flown through _fold_started_faults)."""
        return sum(e.id == ActuatorFault.id for e in self._faults[k]) > 1

    def _rebuild_model(self) -> None:
        n = self.airframe.n_rotors
        base = self._base_effects
        lanes = self._faults
        folding = [k for k in range(self.vehicles) if self._several_faults(k)]
        if folding:
            # The airframe's own rotor_effectiveness goes into every lane's (one entry per id).
            own = next((e for e in base if isinstance(e, RotorEffectiveness)), None)
            base = [e for e in base if e is not own]
            lanes = [
                [e for e in lane if e.id != ActuatorFault.id]
                + _fold_started_faults([e for e in lane if e.id == ActuatorFault.id], self.t_ns, own, n)
                if k in folding
                else lane + ([] if own is None else [own])
                for k, lane in enumerate(lanes)
            ]
        # The next onset at which a vehicle with several faults needs its model rebuilt (None: none).
        onsets = [
            _onset_ns(e)
            for k in folding
            for e in self._faults[k]
            if e.id == ActuatorFault.id and _onset_ns(e) > self.t_ns
        ]
        self._next_rebuild_ns = min(onsets, default=None)
        self.model = Model(self.airframe, base + _per_lane(lanes, n))
        self.integrator = Integrator(self.model, self.dt_ns / NS_PER_S, ground_height_m=self.ground_height_m)

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return self.t_ns / NS_PER_S

    def _vehicle(self, vehicle: int) -> int:
        """``vehicle`` checked as an index 0..V-1."""
        if isinstance(vehicle, bool) or not isinstance(vehicle, int | np.integer):
            raise ValueError(f"vehicle must be an integer index 0..{self.vehicles - 1}, got {vehicle!r}")
        if not 0 <= vehicle < self.vehicles:
            raise ValueError(
                f"vehicle {vehicle} does not exist: this simulator has {self.vehicles} "
                f"(indices 0..{self.vehicles - 1})"
            )
        return int(vehicle)

    def _alone(self, name: str, fleet_name: str) -> int:
        """0 for a single vehicle; a fleet has no single ``name``."""
        if self.vehicles != 1:
            raise ValueError(
                f"{name} is a single vehicle's: this fleet has {self.vehicles}, use {fleet_name}"
            )
        return 0

    @property
    def state(self) -> FloatArray:
        """The true flat state (13 + N,) of the single vehicle (a view: do not modify); fleet: ``x[k]``."""
        return self.x[self._alone("state", "x[k]")]

    @property
    def command_rad_s(self) -> FloatArray:
        """The single vehicle's applied command (N,) [rad/s]; fleet: ``commands_rad_s[k]``."""
        return self.commands_rad_s[self._alone("command_rad_s", "commands_rad_s[k]")]

    @property
    def command_timeout_ns(self) -> int:
        """The watchdog's timeout [ns] (0: no watchdog), the same for every vehicle; may be changed."""
        return self._command_timeout_ns

    @command_timeout_ns.setter
    def command_timeout_ns(self, value: int) -> None:
        if value < 0:
            raise ValueError(f"command_timeout_ns must be >= 0, got {value}")
        self._command_timeout_ns = int(value)
        self._deadline_stale = True

    # ------------------------------------------------------------------ inputs

    def set_command(self, speeds_rad_s: ArrayLike, vehicle: int = 0) -> FloatArray:
        """Take a vehicle's rotor speed commands [rad/s], clamped to the airframe's range; returns them.

        Callers validate first (finite, N values): this raises ValueError on anything else. A crashed
        vehicle's command stays zero until a reset.
        """
        k = self._vehicle(vehicle)
        speeds = np.asarray(speeds_rad_s, dtype=float)
        # N plain floats tested one by one: a third of np.isfinite(...).all()'s cost for N <= 8.
        if speeds.shape != self._command_shape or not all(map(math.isfinite, speeds.tolist())):
            raise ValueError(f"need {self.airframe.n_rotors} finite rotor speeds, got {speeds}")
        applied = self.commands_rad_s[k]
        if not self.crashes.crashed[k]:
            # np.clip's own arithmetic, without its Python wrappers, against bounds already arrays (a
            # fleet takes V commands per period, the MAVLink bridge one per flight-stack frame).
            np.maximum(speeds, self._speed_bounds[0], out=applied)
            np.minimum(applied, self._speed_bounds[1], out=applied)
        self.last_command_ns[k] = self.t_ns
        self.watchdog_tripped[k] = False
        self._deadline_stale = True
        return applied

    def inject_fault(self, motor: int, effectiveness: float, vehicle: int = 0) -> None:
        """From now on a vehicle's rotor ``motor`` (1..N) gives ``effectiveness`` (0..1) of its thrust.

        ``motor`` 0 repairs the vehicle. This replaces any earlier fault of that vehicle, a hidden one of
        the effect list (``actuator_fault``) included; the other vehicles keep theirs.
        """
        self.inject_faults([] if motor == 0 else [(motor, effectiveness)], vehicle)

    def inject_faults(self, faults: Sequence[tuple[int, float]], vehicle: int = 0) -> None:
        """A vehicle's faults are now ``faults``: (motor 1..N, effectiveness 0..1) each, one per motor.

        A fault already in force (same motor and effectiveness) keeps its onset; the others begin now
        (rotors failing one after another: list the first, then both). An empty list repairs the vehicle.
        Like :meth:`inject_fault` this replaces every earlier fault of that vehicle.
        """
        k = self._vehicle(vehicle)
        motors = [motor for motor, _ in faults]
        for motor, effectiveness in faults:
            if not 1 <= motor <= self.airframe.n_rotors:
                raise ValueError(f"fault motor must be 1..{self.airframe.n_rotors}, got {motor}")
            if not 0.0 <= effectiveness <= 1.0:
                raise ValueError(f"fault effectiveness must be in [0, 1], got {effectiveness}")
        if len(set(motors)) != len(motors):
            raise ValueError(f"one fault per motor: motors {motors}")
        in_force = {
            (int(f["motor"]), float(f["effectiveness"])): f
            for f in self._faults[k]
            if f.id == ActuatorFault.id
        }
        self._faults[k] = [
            in_force.get((motor, float(effectiveness)))
            or ActuatorFault(motor=motor, effectiveness=float(effectiveness), t_fault_s=self.t_s)
            for motor, effectiveness in faults
        ]
        self._rebuild_model()

    def injected_effectiveness(self, vehicle: int = 0) -> FloatArray:
        """(N,) effectiveness applied to each rotor of a vehicle now: its injected (or hidden) fault."""
        k = self._vehicle(vehicle)
        x = self.x[k : k + 1]
        context = self.model.context(S.StateBatch.from_flat(self.t_s, x, x[:, S.ROTORS_START :]))
        result = np.ones(self.airframe.n_rotors)
        for fault in self._faults[k]:
            if "rotor_thrust_factor" in fault.formulas():
                result = result * evaluate(fault, "rotor_thrust_factor", context)[0]
        return result

    def crashed(self, vehicle: int = 0) -> bool:
        """Whether a vehicle has crashed (since the start or its last reset)."""
        return bool(self.crashes.crashed[self._vehicle(vehicle)])

    def reset(self, vehicle: int | None = None) -> None:
        """A vehicle (None: every vehicle) back to its initial state; simulated time goes on.

        Its initial pose at rest, its rotors and command as at the start (stopped on the ground; at
        hover speed when placed in the air, so that it does not drop), its watchdog restarted from now
        (armed again only if it was at the start), its crash forgotten. Injected faults stay, and the
        sensors' noise and bias continue.
        """
        vehicles = slice(None) if vehicle is None else self._vehicle(vehicle)
        x, commands, last_command_ns = self._initial
        self.x[vehicles] = x[vehicles]
        self.commands_rad_s[vehicles] = commands[vehicles]
        self.last_command_ns[vehicles] = np.where(last_command_ns[vehicles] == NEVER, NEVER, self.t_ns)
        self.watchdog_tripped[vehicles] = False
        self.crashes.clear(vehicles)
        self._acceleration_W[vehicles] = 0.0
        self._deadline_stale = True

    # ------------------------------------------------------------------ stepping

    def run_until(self, t_ns: int) -> list[Reading]:
        """Integrate up to ``t_ns`` (whole physics steps, at least up to it) and return the readings due."""
        readings: list[Reading] = []
        self._sample_due(readings)  # readings due now (at t = 0: the first of each kind)
        while self.t_ns < t_ns:
            if self._next_rebuild_ns is not None and self.t_ns >= self._next_rebuild_ns:
                self._rebuild_model()
            target = min([t_ns, *(s.next_ns for s in self._schedules.values() if s.next_ns > self.t_ns)])
            if self._next_rebuild_ns is not None:
                target = min(target, self._next_rebuild_ns)
            deadline = self._watchdog_deadline()
            if deadline is not None and self.t_ns < deadline < target:
                target = deadline
            steps = max(1, -(-(target - self.t_ns) // self.dt_ns))
            imu_due = self._schedules["imu"].next_ns <= self.t_ns + steps * self.dt_ns
            self._advance(steps, imu_due, readings)
            self._check_watchdog(readings)
            self._sample_due(readings)
        return readings

    def _armed(self) -> NDArray[np.bool_]:
        """(V,) whose watchdog runs: commanded, not tripped since, not crashed, a timeout set."""
        return (
            (self.last_command_ns != NEVER)
            & ~self.watchdog_tripped
            & ~self.crashes.crashed
            & (self._command_timeout_ns > 0)
        )

    def _watchdog_deadline(self) -> int | None:
        """The earliest time a watchdog trips (None: none runs); recomputed only after a change."""
        if self._deadline_stale:
            armed = self._armed()
            self._deadline_ns = (
                int(self.last_command_ns[armed].min()) + self._command_timeout_ns if armed.any() else None
            )
            self._deadline_stale = False
        return self._deadline_ns

    def _check_watchdog(self, readings: list[Reading]) -> None:
        deadline = self._watchdog_deadline()
        if deadline is None or self.t_ns < deadline:
            return
        due = self._armed() & (self.last_command_ns + self._command_timeout_ns <= self.t_ns)
        for k in np.flatnonzero(due).tolist():
            self.watchdog_tripped[k] = True
            self.commands_rad_s[k] = self.airframe.rotor_speed_min_rad_s
            silence_s = (self.t_ns - int(self.last_command_ns[k])) / NS_PER_S
            readings.append(Reading("watchdog", self.t_ns, silence_s, k))
        self._deadline_stale = True

    def _sample_due(self, readings: list[Reading]) -> None:
        t_ns = self.t_ns
        due = [kind for kind, schedule in self._schedules.items() if t_ns >= schedule.next_ns]
        if not due:
            return
        # One draw per vehicle for every kind due now, used kind after kind in the schedules' order: the
        # same numbers, in the same order, as drawing kind by kind.
        z = sens.standard_normals(self.rngs, sum(self._draws[kind] for kind in due))
        column = 0
        for kind in due:
            count = self._draws[kind]
            data = self._sample(kind, z[:, column : column + count])
            column += count
            readings.extend([Reading(kind, t_ns, value, k) for k, value in enumerate(data)])
            # Next due time on the schedule's own grid, skipping any it has missed.
            schedule = self._schedules[kind]
            schedule.next_ns += ((t_ns - schedule.next_ns) // schedule.period_ns + 1) * schedule.period_ns

    def _advance(self, steps: int, imu_due: bool, readings: list[Reading]) -> None:
        if imu_due:
            # The IMU needs the acceleration: the last step is taken alone, and its velocity change over dt
            # is the mean acceleration of that step (exact for RK4's update, ground reaction included).
            if steps > 1:
                self._integrate(steps - 1, readings)
            v_before = self.x[:, S.VELOCITY].copy()
            self._integrate(1, readings)
            self._acceleration_W = (self.x[:, S.VELOCITY] - v_before) / (self.dt_ns / NS_PER_S)
        else:
            self._integrate(steps, readings)

    def _integrate(self, steps: int, readings: list[Reading]) -> None:
        """``steps`` physics steps; a crash among them is reported and stops that vehicle's rotors."""
        start_ns = self.t_ns
        self.x = self.integrator.advance(self.t_s, self.x, self.commands_rad_s, steps, self.crashes)
        self.t_ns += steps * self.dt_ns
        readings += self.take_crashes(start_ns, self.dt_ns)

    def take_crashes(self, start_ns: int, step_ns: int) -> list[Reading]:
        """``crash`` readings of the last advance's crashes (steps of ``step_ns`` from ``start_ns``).

        The crashed vehicles' rotors are commanded to stop. For :meth:`run_until` and for callers that
        step ``self.x`` with an integrator of their own and ``self.crashes`` (the MAVLink bridge's
        physics, whose frames set the step).
        """
        readings: list[Reading] = []
        steps = self.crashes.crash_step
        # The usual case, without flatnonzero's cost; one vehicle (the MAVLink bridge asks every frame) by
        # its entry, which costs a sixth of a reduction.
        if (steps[0] if self.vehicles == 1 else steps.max()) < 0:
            return readings
        for k in np.flatnonzero(self.crashes.crash_step >= 0).tolist():
            self.commands_rad_s[k] = 0.0
            self._deadline_stale = True
            q = self.x[k, S.QUATERNION]
            cos_tilt = 1.0 - 2.0 * (q[1] ** 2 + q[2] ** 2)
            crash = Crash(
                float(self.crashes.touchdown_speed_m_s[k]),
                math.acos(min(1.0, max(-1.0, cos_tilt))),
                self.x[k, S.POSITION].copy(),
            )
            hit_ns = start_ns + (int(self.crashes.crash_step[k]) + 1) * step_ns
            readings.append(Reading("crash", hit_ns, crash, k))
        return readings

    def acceleration_W(self, vehicle: int = 0) -> FloatArray:
        """A vehicle's true acceleration [m/s^2], world ENU (dv/dt, no gravity), over the last IMU step."""
        return self._acceleration_W[self._vehicle(vehicle)].copy()

    def sample(self, kind: str) -> list[Any]:
        """One reading of ``kind`` per vehicle at the current time (draws noise from each one's generator)."""
        if kind not in self._draws:
            raise ValueError(f"unknown reading kind {kind!r}")
        return self._sample(kind, sens.standard_normals(self.rngs, self._draws[kind]))

    def _sample(self, kind: str, z: FloatArray) -> list[Any]:
        """One reading of ``kind`` per vehicle, its noise from the standard normals ``z`` (V, draws)."""
        x = self.x
        config = self.sensor_config
        if kind == "odom":
            return list(x.copy())
        if kind == "imu":
            return self._imu.sample(self.t_s, x[:, S.QUATERNION], self._acceleration_W, x[:, S.BODY_RATE], z)
        if kind == "pose":
            positions, attitudes = sens.pose_readings(config, x[:, S.POSITION], x[:, S.QUATERNION], z)
            return list(zip(positions, attitudes, strict=True))
        if kind == "range":
            distances = sens.range_readings(
                config, x[:, S.POSITION], x[:, S.QUATERNION], self.ground_height_m
            )
            return list(distances.tolist())
        speeds = self.commands_rad_s if self._hidden_lag else x[:, S.ROTORS_START :]
        return list(sens.rotor_speed_readings(config, speeds, z))
