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

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import FloatArray, euler_to_quat

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
