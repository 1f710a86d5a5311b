"""The bridge's own physics: the package's :class:`~multirotor_ros.simulation.VehicleSimulator`.

The same simulation core as the simulator node (model, integrator, sensor noise, command clamp), so a
flight stack in lockstep flies exactly the vehicle the rest of the package simulates. Choices that
differ from the simulator node, and why:

- no command watchdog: the flight stack drives every step, and a silent one freezes the physics;
- the IMU samples once per flight-stack step (``imu_rate_hz`` = the lockstep rate), so HIL_SENSOR and
  the JSON answer carry a fresh reading each step and the noise has that rate's discrete-time sigma;
- a reset builds a new simulator from the same factory (ArduPilot SITL restarted).

The readings the simulator produces (``odom``, ``imu``, ``motor_speeds``, ...) are kept for the node
to publish: :meth:`SimulatorPhysics.take_readings`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.simulation import Reading, VehicleSimulator
from multirotor_ros.simulation.sensors import SensorConfig, airframe_sensor_config
from multirotor_ros.simulation.vehicle import NS_PER_S


class SimulatorPhysics:
    """:class:`~multirotor_ros.mavlink.vehicle.Physics` backed by a VehicleSimulator."""

    def __init__(self, factory: Callable[[], VehicleSimulator]):
        self._factory = factory
        self._readings: list[Reading] = []
        self._start()
        # One step now, so that compiling the integrator does not stall the flight stack's first step.
        self.step(self.simulator.command_rad_s, 2 * self.simulator.dt_ns / NS_PER_S)
        self.reset()

    def _start(self) -> None:
        self.simulator = self._factory()
        self._target_ns = self.simulator.t_ns
        self._imu = None
        self._rotor_speeds: FloatArray = self.simulator.state[S.ROTORS_START :].copy()
        self._absorb(self.simulator.run_until(self.simulator.t_ns))
        self.state = self._snapshot()

    @classmethod
    def for_airframe(
        cls,
        airframe: Airframe,
        step_s: float,
        *,
        seed: int = 0,
        noise: bool = True,
        physics_rate_hz: float = 1000.0,
        odom_rate_hz: float = 250.0,
    ) -> SimulatorPhysics:
        """The bridge's usual core: the airframe's sensors with the IMU at the flight-stack rate 1/step_s.

        Motion capture and the range finder are sampled once a second only: the bridge publishes
        neither, and sampling them costs time at every step.
        """
        sensors = dataclasses.replace(
            airframe_sensor_config(airframe), imu_rate_hz=1.0 / step_s, pose_rate_hz=1.0, range_rate_hz=1.0
        )

        def factory() -> VehicleSimulator:
            return VehicleSimulator(
                airframe,
                rng=np.random.default_rng(seed),
                physics_rate_hz=physics_rate_hz,
                odom_rate_hz=odom_rate_hz,
                command_timeout_s=0.0,
                sensors=sensors,
                noise=noise,
            )

        return cls(factory)

    @property
    def sensor_config(self) -> SensorConfig:
        """The sensor noise and rates in use (zero noise when built without noise)."""
        return self.simulator.sensor_config

    @property
    def n_rotors(self) -> int:
        """Rotor count of the airframe."""
        return self.simulator.airframe.n_rotors

    @property
    def gravity_m_s2(self) -> float:
        """The model's gravity."""
        return float(self.simulator.model.gravity_m_s2)

    def step(self, rotor_speed_cmd_rad_s: FloatArray, dt_s: float) -> VehicleState:
        """Advance by ``dt_s`` (to the physics step grid: the error never accumulates)."""
        self.simulator.set_command(rotor_speed_cmd_rad_s)
        self._target_ns += round(dt_s * NS_PER_S)
        self._absorb(self.simulator.run_until(self._target_ns))
        self.state = self._snapshot()
        return self.state

    def reset(self) -> VehicleState:
        """A fresh vehicle at t = 0."""
        self._readings.clear()
        self._start()
        return self.state

    def take_readings(self) -> list[Reading]:
        """The readings produced since the last call (oldest first)."""
        readings, self._readings = self._readings, []
        return readings

    def _absorb(self, readings: list[Reading]) -> None:
        for reading in readings:
            if reading.kind == "imu":
                self._imu = reading.data
            elif reading.kind == "motor_speeds":
                self._rotor_speeds = np.asarray(reading.data, dtype=float)
        self._readings.extend(readings)

    def _snapshot(self) -> VehicleState:
        x = self.simulator.state
        imu = self._imu
        assert imu is not None, "the simulator produces an IMU reading at t = 0"
        return VehicleState(
            t_s=self.simulator.t_s,
            p_WB_W=x[S.POSITION].copy(),
            v_WB_W=x[S.VELOCITY].copy(),
            q_WB=x[S.QUATERNION].copy(),
            w_WB_B=x[S.BODY_RATE].copy(),
            rotor_speeds_rad_s=self._rotor_speeds,
            imu_specific_force_B=np.asarray(imu.specific_force_B, dtype=float),
            imu_w_WB_B=np.asarray(imu.w_WB_B, dtype=float),
        )
