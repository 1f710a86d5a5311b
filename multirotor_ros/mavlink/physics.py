"""The bridge's own physics: the package's vehicle, advanced by exactly each flight-stack frame's Δt.

The vehicle is a :class:`~multirotor_ros.simulation.VehicleSimulator` (model and effects, command
clamp, injected faults, sensor configuration), so a flight stack flies exactly the vehicle the rest of
the package simulates. The stepping is done here, not by its ``run_until``: that integrates whole steps
of one fixed ``dt_ns`` up to at least the target, which turns ArduPilot's 1200 Hz frames into 1 ms steps
(1001 Hz, one frame in about 1,000 advancing by zero) and 400 Hz frames into steps of 2 and 3 ms. Here
a frame of Δt is integrated in n = ceil(Δt / physics step) equal RK4 sub-steps of Δt / n, one compiled
call, so time advances by exactly the flight stack's Δt whatever its rate, and never by more than the
airframe's physics step at once. The compiled RK4 stepper of :mod:`multirotor_ros.model.compiled`
takes the sub-step length with each call (the numpy integrator is the fallback for a model it cannot
compile); the command is checked and clamped once, by the simulator's ``set_command``.

Per frame, what the flight stack's sensors read: the IMU of the airframe's sensor model
(:class:`~multirotor_ros.simulation.sensors.Imu`), sampled at the frame rate, so its white noise has the
discrete-time sigma of that rate (noise density x root of the rate, :attr:`imu_config`); its specific
force is the mean acceleration over the frame (Δv / Δt, what a delta-velocity IMU reports; exact for
RK4, ground reaction included) and its rate the body rate at the frame's end.

For the node, :meth:`SimulatorPhysics.take_readings` returns what falls due on simulated time at the
rates the rest of the graph expects, not at the frame rate: ``odom`` at ``odom_rate_hz``, ``imu`` at
the airframe's ``sensors.imu_rate_hz`` (readings the flight stack got, one in every so many), and
``motor_speeds`` at the ESC report rate. Publishing 1,200 messages a second of each would cost the
bridge more than the physics.

No command watchdog: the flight stack drives every step, and a silent one freezes the physics.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.simulation import Reading, VehicleSimulator
from multirotor_ros.simulation import sensors as sens
from multirotor_ros.simulation.sensors import SensorConfig
from multirotor_ros.simulation.vehicle import NS_PER_S, period_ns

if TYPE_CHECKING:
    from multirotor_ros.model.compiled import CompiledStepper

NOISE_BLOCK = 4096  # IMU samples whose standard normals are drawn in one call (the same stream)


class _Rate:
    """When a reading is next due on simulated time: a grid of ``period_ns``, missed points skipped."""

    def __init__(self, rate_hz: float):
        self.period_ns = period_ns(rate_hz)
        self.next_ns = 0

    def due(self, t_ns: int) -> bool:
        if t_ns < self.next_ns:
            return False
        self.next_ns += ((t_ns - self.next_ns) // self.period_ns + 1) * self.period_ns
        return True


class SimulatorPhysics:
    """:class:`~multirotor_ros.mavlink.vehicle.Physics` of a VehicleSimulator; see the module docstring."""

    def __init__(self, factory: Callable[[], VehicleSimulator], odom_rate_hz: float = 250.0):
        self._factory = factory
        self._odom_rate_hz = odom_rate_hz
        self._start()
        # Compile (or load) the kernel now, not in the flight stack's first frame.
        self.advance_to(self.simulator.command_rad_s, self.simulator.dt_ns)
        self.reset()

    @classmethod
    def for_airframe(
        cls,
        airframe: Airframe,
        *,
        seed: int = 0,
        noise: bool = True,
        physics_rate_hz: float = 1000.0,
        odom_rate_hz: float = 250.0,
    ) -> SimulatorPhysics:
        """The usual core: the airframe's own effects, sensors and motor lag; ``seed`` for the noise."""

        def factory() -> VehicleSimulator:
            return VehicleSimulator(
                airframe,
                rng=np.random.default_rng(seed),
                physics_rate_hz=physics_rate_hz,
                command_timeout_s=0.0,
                noise=noise,
            )

        return cls(factory, odom_rate_hz)

    def _start(self) -> None:
        self.simulator = simulator = self._factory()
        self._rng = simulator.rngs[0]
        config = simulator.sensor_config
        self._imu = sens.Imu(
            config, self._rng.standard_normal((1, sens.Imu.INITIAL_DRAWS)), self.gravity_m_s2
        )
        self._imu_draws = sens.Imu.draws(config)
        self._imu_rate_hz = config.imu_rate_hz
        self._normals = np.empty((0, self._imu_draws))
        self._next_normal = 0
        self._stepper = self._compiled_stepper()
        self._odom_due = _Rate(self._odom_rate_hz)
        self._imu_due = _Rate(config.imu_rate_hz)
        self._motor_speeds_due = _Rate(config.rotor_speed_rate_hz)
        self._readings: list[Reading] = []
        self._mean_acceleration = np.zeros((1, 3))
        self.state = self._snapshot(self._mean_acceleration)
        self._collect_due()

    @property
    def t_ns(self) -> int:
        """Simulated time [ns]."""
        return self.simulator.t_ns

    @property
    def imu_config(self) -> SensorConfig:
        """The IMU's noise and rate now: the frame rate's (zero noise when built without noise)."""
        return self._imu.config

    @property
    def n_rotors(self) -> int:
        """Rotor count of the airframe."""
        return self.simulator.airframe.n_rotors

    @property
    def gravity_m_s2(self) -> float:
        """The model's gravity."""
        return float(self.simulator.model.gravity_m_s2)

    @property
    def max_step_ns(self) -> int:
        """The longest integration sub-step [ns]: the airframe's physics step."""
        return self.simulator.dt_ns

    def advance_to(self, rotor_speed_cmd_rad_s: FloatArray, t_ns: int) -> VehicleState:
        """Hold the command (clamped to the airframe's range) and integrate to exactly ``t_ns``."""
        simulator = self.simulator
        simulator.set_command(rotor_speed_cmd_rad_s)
        dt_ns = t_ns - simulator.t_ns
        if dt_ns <= 0:
            return self.state
        substeps = -(-dt_ns // simulator.dt_ns)  # ceil: no sub-step longer than the physics step
        substep_s = dt_ns / substeps / NS_PER_S
        # Both integrators return a new state and leave this one as it was: its velocity is the one
        # before the frame.
        x_before = simulator.x
        u = simulator.commands_rad_s
        ground = simulator.ground_height_m
        # The simulator's crash latch: a crashed vehicle stays down here too, whatever the flight stack sends.
        crashes = simulator.crashes if ground is not None else None
        if self._stepper is not None:
            x = self._stepper.advance(simulator.t_s, x_before, u, substep_s, substeps, ground, crashes)
        else:
            x = Integrator(simulator.model, substep_s, ground, backend="numpy").advance(
                simulator.t_s, x_before, u, substeps, crashes
            )
        start_ns = simulator.t_ns
        simulator.x, simulator.t_ns = x, t_ns
        self._readings += simulator.take_crashes(start_ns, dt_ns // substeps)
        frame_rate_hz = round(NS_PER_S / dt_ns)  # 1200 for frames of 833,333 and 833,334 ns alike
        if frame_rate_hz != self._imu_rate_hz:
            self._imu_rate_hz = frame_rate_hz
            self._imu.config = dataclasses.replace(self._imu.config, imu_rate_hz=frame_rate_hz)
        mean_acceleration = self._mean_acceleration  # the IMU reads it and keeps nothing of it
        np.subtract(x[:, S.VELOCITY], x_before[:, S.VELOCITY], out=mean_acceleration)
        mean_acceleration *= NS_PER_S / dt_ns
        self.state = self._snapshot(mean_acceleration)
        self._collect_due()
        return self.state

    def _compiled_stepper(self) -> CompiledStepper | None:
        """The compiled stepper of the simulator's model, None if it cannot be compiled."""
        # Imported here: importing numba takes seconds on a loaded machine, and a bridge without its
        # own physics (flight_stack none, or external physics) never needs it.
        from multirotor_ros.model import compiled

        model = self.simulator.model
        return compiled.CompiledStepper(model, 1) if compiled.supports(model) else None

    def _snapshot(self, a_WB_W: FloatArray) -> VehicleState:
        """The state now, with an IMU reading of the acceleration ``a_WB_W`` (1, 3) and the body rate."""
        simulator = self.simulator
        t_s = simulator.t_s
        x = simulator.x
        if self._next_normal == len(self._normals):
            self._normals = self._rng.standard_normal((NOISE_BLOCK, self._imu_draws))
            self._next_normal = 0
        z = self._normals[self._next_normal : self._next_normal + 1]
        self._next_normal += 1
        self.imu = imu = self._imu.sample(t_s, x[:, S.QUATERNION], a_WB_W, x[:, S.BODY_RATE], z)[0]
        # Views of x: each step makes a new x, so a state handed out never changes afterwards.
        x0 = x[0]
        return VehicleState(
            t_s,
            x0[S.POSITION],
            x0[S.VELOCITY],
            x0[S.QUATERNION],
            x0[S.BODY_RATE],
            x0[S.ROTORS_START :],
            imu.specific_force_B,
            imu.w_WB_B,
        )

    def _collect_due(self) -> None:
        simulator = self.simulator
        t_ns = simulator.t_ns
        if self._odom_due.due(t_ns):
            self._readings.append(Reading("odom", t_ns, simulator.x[0].copy()))
        if self._imu_due.due(t_ns):
            self._readings.append(Reading("imu", t_ns, self.imu))
        if self._motor_speeds_due.due(t_ns):
            # The ESC reports the rotor speed; without a simulated lag the rotor is at its command.
            lagged = simulator.motor_lag_s is not None
            speeds = simulator.x[:, S.ROTORS_START :] if lagged else simulator.commands_rad_s
            z = self._rng.standard_normal((1, sens.rotor_speed_draws(self.n_rotors)))
            self._readings.append(
                Reading(
                    "motor_speeds", t_ns, sens.rotor_speed_readings(simulator.sensor_config, speeds, z)[0]
                )
            )

    def reset(self) -> VehicleState:
        """A fresh vehicle at t = 0 (the same noise stream as at the start)."""
        self._start()
        return self.state

    def inject_fault(self, motor: int, effectiveness: float) -> None:
        """From now on rotor ``motor`` (1..N; 0 repairs) gives ``effectiveness`` (0..1) of its thrust."""
        self.simulator.inject_fault(motor, effectiveness)
        self._stepper = self._compiled_stepper()  # for the model with the fault

    def take_readings(self) -> list[Reading]:
        """The readings due since the last call (oldest first)."""
        readings, self._readings = self._readings, []
        return readings

    @property
    def hover_speed_rad_s(self) -> float:
        """The rotor speed that holds the vehicle in hover (all rotors alike)."""
        return float(self.simulator.hover_speed_rad_s)
