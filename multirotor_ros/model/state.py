"""Layout of the flat Newton-Euler state vector, batched as (B, 13 + N).

| slice | name | frame, unit |
|---|---|---|
| 0:3 | p_WB_W | position of the body origin, world ENU [m] |
| 3:6 | v_WB_W | velocity, world ENU [m/s] |
| 6:10 | q_WB | attitude quaternion (w, x, y, z), body FLU -> world ENU |
| 10:13 | w_WB_B | body rate, FLU [rad/s] |
| 13:13+N | omega | rotor speeds [rad/s] |
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import FloatArray, euler_to_matrix, euler_to_quat, quat_to_matrix

if TYPE_CHECKING:
    from multirotor_ros.io.flight_log import FlightLog

POSITION = slice(0, 3)
VELOCITY = slice(3, 6)
QUATERNION = slice(6, 10)
BODY_RATE = slice(10, 13)
ROTORS_START = 13


def state_size(n_rotors: int) -> int:
    """Length of the state vector for an airframe with ``n_rotors`` rotors."""
    return ROTORS_START + n_rotors


def make_state(
    n_rotors: int,
    batch: int = 1,
    position_m: ArrayLike = (0.0, 0.0, 0.0),
    velocity_m_s: ArrayLike = (0.0, 0.0, 0.0),
    euler_rad: ArrayLike = (0.0, 0.0, 0.0),
    body_rate_rad_s: ArrayLike = (0.0, 0.0, 0.0),
    rotor_speed_rad_s: ArrayLike = 0.0,
) -> FloatArray:
    """A (batch, 13 + N) state; every argument broadcasts over the batch."""
    x = np.zeros((batch, state_size(n_rotors)))
    x[:, POSITION] = position_m
    x[:, VELOCITY] = velocity_m_s
    x[:, QUATERNION] = euler_to_quat(np.broadcast_to(np.asarray(euler_rad, dtype=float), (batch, 3)))
    x[:, BODY_RATE] = body_rate_rad_s
    x[:, ROTORS_START:] = rotor_speed_rad_s
    return x


@dataclass(frozen=True)
class StateBatch:
    """Measured or simulated states of B vehicles (or B samples of one log), frames in the names.

    The one value the model, the identifier and the observers pass around instead of seven arrays.
    """

    t: FloatArray  # (B,) time [s]
    p_WB_W: FloatArray  # (B, 3) position of the body origin in world ENU [m]
    v_WB_W: FloatArray  # (B, 3) velocity in world ENU [m/s]
    R_WB: FloatArray  # (B, 3, 3) attitude, body FLU -> world ENU
    w_WB_B: FloatArray  # (B, 3) body rate in FLU [rad/s]
    omega: FloatArray  # (B, N) rotor speeds that make thrust [rad/s]
    a_WB_W: FloatArray | None = None  # (B, 3) measured acceleration, world ENU, gravity excluded [m/s^2]

    def __post_init__(self) -> None:
        batch = self.p_WB_W.shape[0]
        object.__setattr__(self, "t", np.broadcast_to(np.asarray(self.t, dtype=float), (batch,)))

    @classmethod
    def from_flat(cls, t: ArrayLike, x: FloatArray, omega: FloatArray) -> StateBatch:
        """From flat states (B, 13 + N) and the rotor speeds that make thrust (B, N)."""
        return cls(
            t=np.asarray(t, dtype=float),
            p_WB_W=x[:, POSITION],
            v_WB_W=x[:, VELOCITY],
            R_WB=quat_to_matrix(x[:, QUATERNION]),
            w_WB_B=x[:, BODY_RATE],
            omega=omega,
        )

    @classmethod
    def from_flight_log(cls, log: FlightLog) -> StateBatch:
        """The rows of a flight log with position, velocity, body rates ``p, q, r`` and rotor speeds.

        Its ``ax, ay, az``, when present, become the measured acceleration (shared/spec/flight_log.md).
        """

        def columns(names: Sequence[str]) -> FloatArray:
            return np.column_stack([log.column(name) for name in names])

        acceleration = log.group_columns("acceleration")
        return cls(
            t=log.t,
            p_WB_W=columns(log.group_columns("position")),
            v_WB_W=columns(log.group_columns("velocity")),
            R_WB=euler_to_matrix(log.euler()),
            w_WB_B=columns(("p", "q", "r")),
            omega=columns(log.group_columns("rotor_speeds")),
            a_WB_W=columns(acceleration) if all(name in log.columns for name in acceleration) else None,
        )

    @classmethod
    def concatenate(cls, batches: Sequence[StateBatch]) -> StateBatch:
        """The states of ``batches`` one after the other; the acceleration is kept if every batch has it."""
        accelerations = [batch.a_WB_W for batch in batches if batch.a_WB_W is not None]
        return cls(
            t=np.concatenate([batch.t for batch in batches]),
            p_WB_W=np.concatenate([batch.p_WB_W for batch in batches]),
            v_WB_W=np.concatenate([batch.v_WB_W for batch in batches]),
            R_WB=np.concatenate([batch.R_WB for batch in batches]),
            w_WB_B=np.concatenate([batch.w_WB_B for batch in batches]),
            omega=np.concatenate([batch.omega for batch in batches]),
            a_WB_W=np.concatenate(accelerations) if len(accelerations) == len(batches) else None,
        )

    @property
    def size(self) -> int:
        """B, the number of states."""
        return int(self.p_WB_W.shape[0])

    @property
    def e_z_W(self) -> FloatArray:
        """Body z axis in world, (B, 3): the thrust direction."""
        return self.R_WB[:, :, 2]

    def select(self, rows: ArrayLike) -> StateBatch:
        """The states at ``rows`` (an index array, a slice or a boolean mask)."""
        index = rows if isinstance(rows, slice) else np.asarray(rows)
        return StateBatch(
            t=self.t[index],
            p_WB_W=self.p_WB_W[index],
            v_WB_W=self.v_WB_W[index],
            R_WB=self.R_WB[index],
            w_WB_B=self.w_WB_B[index],
            omega=self.omega[index],
            a_WB_W=None if self.a_WB_W is None else self.a_WB_W[index],
        )

    def with_omega(self, omega: FloatArray) -> StateBatch:
        """The same states with other rotor speeds (the lagged ones of a motor_lag model, say)."""
        return dataclasses.replace(self, omega=omega)
