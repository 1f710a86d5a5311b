"""The vehicle as the MAVLink side sees it: one snapshot type, and the physics the bridge may own.

:class:`VehicleState` is what every outgoing MAVLink message is built from, whichever way the state
arrived: stepped by the bridge's own physics (lockstep), or read from the simulator node's ``odom``,
``imu`` and ``motor_speeds`` topics. World ENU and body FLU, SI units, like the rest of the package.

:class:`Physics` is what the bridge needs from a simulation core to drive it one step per actuator
message; :mod:`multirotor_ros.mavlink.bridge` documents when it owns one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from multirotor_ros.model.rotation import FloatArray


class VehicleState(NamedTuple):
    """One instant of the simulated vehicle.

    A named tuple, immutable like a frozen dataclass: the bridge's own physics makes one per
    flight-stack frame, and a frozen dataclass's ``__init__`` costs five times as much.
    """

    t_s: float  # [s] simulated time
    p_WB_W: FloatArray  # [m] position, world ENU (origin = home)
    v_WB_W: FloatArray  # [m/s] velocity, world ENU
    q_WB: FloatArray  # attitude (w, x, y, z), body FLU -> world ENU
    w_WB_B: FloatArray  # [rad/s] true body rate, FLU
    rotor_speeds_rad_s: FloatArray  # [rad/s] measured rotor speeds, rotor order 1..N
    imu_specific_force_B: FloatArray  # [m/s^2] what the accelerometer reads (a - g), FLU
    imu_w_WB_B: FloatArray  # [rad/s] what the gyroscope reads, FLU

    @staticmethod
    def at_rest(n_rotors: int, gravity_m_s2: float, t_s: float = 0.0) -> VehicleState:
        """Level on the ground at home: the accelerometer reads +g up."""
        zero = np.zeros(3)
        return VehicleState(
            t_s,
            zero,
            zero,
            np.array([1.0, 0.0, 0.0, 0.0]),
            zero,
            np.zeros(n_rotors),
            np.array([0.0, 0.0, gravity_m_s2]),
            zero,
        )


class Physics(Protocol):
    """A simulation core the bridge steps itself (lockstep); see :mod:`multirotor_ros.mavlink.bridge`."""

    @property
    def n_rotors(self) -> int:
        """Rotor count of the simulated airframe."""
        ...

    @property
    def state(self) -> VehicleState:
        """The current state."""
        ...

    @property
    def t_ns(self) -> int:
        """Simulated time [ns]."""
        ...

    def advance_to(self, rotor_speed_cmd_rad_s: FloatArray, t_ns: int) -> VehicleState:
        """Hold the rotor command and advance to exactly ``t_ns``; return the new state."""
        ...

    def reset(self) -> VehicleState:
        """Back to the initial state at t = 0 (a flight stack restarted)."""
        ...


class Simulation:
    """The vehicle the flight-stack links talk to.

    With ``physics`` (internal mode) the links step it themselves. Without (external mode) the state
    is whatever the bridge was last given by :meth:`update` (the node's ``odom``/``imu``/``motor_speeds``
    subscriptions). A link answers its flight stack first and then calls :meth:`announce`, which hands
    the new rotor command to ``on_command`` (the node publishes ``motor_speed_cmd``) and, in internal
    mode, the new state to ``on_state`` (the node publishes what fell due): ROS never delays an answer.
    """

    def __init__(
        self,
        n_rotors: int,
        gravity_m_s2: float,
        physics: Physics | None,
        on_command: Callable[[FloatArray, float], None],
        on_state: Callable[[VehicleState], None],
    ):
        if physics is not None and physics.n_rotors != n_rotors:
            raise ValueError(f"physics has {physics.n_rotors} rotors, the airframe {n_rotors}")
        self.n_rotors = n_rotors
        self.physics = physics
        self._on_command = on_command
        self._on_state = on_state
        self.command_rad_s: FloatArray = np.zeros(n_rotors)
        self.latest: VehicleState = (
            physics.state if physics is not None else VehicleState.at_rest(n_rotors, gravity_m_s2)
        )
        # External mode knows nothing until the simulator node speaks: no telemetry about a guess.
        self.known = physics is not None
        self.steps = 0
        self._new_command = False
        self._new_state = False

    @property
    def internal(self) -> bool:
        """Whether the bridge owns the physics."""
        return self.physics is not None

    @property
    def t_ns(self) -> int:
        """Simulated time of the owned physics [ns]."""
        assert self.physics is not None, "t_ns needs the bridge's own physics"
        return self.physics.t_ns

    def command(self, speeds_rad_s: FloatArray) -> None:
        """Hold a new rotor command (passed on at the next :meth:`announce`)."""
        self.command_rad_s = speeds_rad_s
        self._new_command = True

    def advance_to(self, t_ns: int) -> VehicleState:
        """Advance the owned physics to exactly ``t_ns`` with the held command."""
        assert self.physics is not None, "advance_to() needs the bridge's own physics"
        state = self.physics.advance_to(self.command_rad_s, t_ns)
        self.latest = state
        self.steps += 1
        self._new_state = True
        return state

    def announce(self) -> None:
        """Hand what changed since the last call to the outputs (after the flight stack's answer)."""
        if self._new_command:
            self._new_command = False
            self._on_command(self.command_rad_s, self.latest.t_s)
        if self._new_state:
            self._new_state = False
            self._on_state(self.latest)

    def reset(self) -> VehicleState:
        """Back to the initial state (internal) and no command."""
        self.command_rad_s = np.zeros(self.n_rotors)
        if self.physics is not None:
            self.latest = self.physics.reset()
            self._new_state = True
        return self.latest

    def update(self, state: VehicleState) -> None:
        """A new externally simulated state (external mode)."""
        self.latest = state
        self.known = True
