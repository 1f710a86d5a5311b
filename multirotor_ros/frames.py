"""The one place where ENU/FLU (inside) and NED/FRD (MAVLink, PX4, ArduPilot logs) meet.

Inside the package: world ENU (x east, y north, z up), body FLU (x forward, y left, z up).
Flight stacks: world NED (x north, y east, z down), body FRD (x forward, y right, z down).

Both changes of axes are involutions (applying one twice is the identity):
- world vector: ENU (e, n, u) <-> NED (n, e, -d)      — a swap of x and y and a flip of z;
- body vector:  FLU (f, l, u) <-> FRD (f, -l, -u)     — a flip of y and z.
An attitude R_WB (body FLU -> world ENU) becomes R_NED_FRD = T_W · R_WB · T_B with T_W, T_B the two
(symmetric, orthogonal) axis changes. Quaternions here are (w, x, y, z); ROS messages use (x, y, z, w).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import FloatArray

ENU_TO_NED: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD: FloatArray = np.diag([1.0, -1.0, -1.0])
_HALF_SQRT2 = float(np.sqrt(0.5))


def enu_to_ned(vector_enu: ArrayLike) -> FloatArray:
    """World vector(s) (..., 3) from ENU to NED."""
    return np.asarray(vector_enu, dtype=float) @ ENU_TO_NED.T


def ned_to_enu(vector_ned: ArrayLike) -> FloatArray:
    """World vector(s) (..., 3) from NED to ENU."""
    return np.asarray(vector_ned, dtype=float) @ ENU_TO_NED.T


def flu_to_frd(vector_flu: ArrayLike) -> FloatArray:
    """Body vector(s) (..., 3) from FLU to FRD."""
    return np.asarray(vector_flu, dtype=float) @ FLU_TO_FRD.T


def frd_to_flu(vector_frd: ArrayLike) -> FloatArray:
    """Body vector(s) (..., 3) from FRD to FLU."""
    return np.asarray(vector_frd, dtype=float) @ FLU_TO_FRD.T


def rotation_enu_flu_to_ned_frd(R_WB: ArrayLike) -> FloatArray:
    """Attitude matrix (body FLU -> world ENU) as (body FRD -> world NED)."""
    return ENU_TO_NED @ np.asarray(R_WB, dtype=float) @ FLU_TO_FRD


def rotation_ned_frd_to_enu_flu(R_NED_FRD: ArrayLike) -> FloatArray:
    """Attitude matrix (body FRD -> world NED) as (body FLU -> world ENU)."""
    return ENU_TO_NED @ np.asarray(R_NED_FRD, dtype=float) @ FLU_TO_FRD


def quat_enu_flu_to_ned_frd(q_WB: ArrayLike) -> FloatArray:
    """Attitude quaternion(s) (..., 4) (w, x, y, z), body FLU -> world ENU, as body FRD -> world NED (w >= 0).

    q_NED_FRD = q(T_W) * q_WB * q(T_B) with q(T_W) = (0, 1/sqrt2, 1/sqrt2, 0) (half a turn about the
    east-north diagonal) and q(T_B) = (0, 1, 0, 0) (half a turn about x). Multiplied out this is
    (w + z, x + y, x - y, w - z) / sqrt2, up to the sign fixed by w >= 0; the same as
    :func:`rotation_enu_flu_to_ned_frd` on matrices, without building them (it runs at every physics
    step of the MAVLink bridge). The map is its own inverse.
    """
    q = np.asarray(q_WB, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.stack([w + z, x + y, x - y, w - z], axis=-1) * _HALF_SQRT2
    return out * np.where(out[..., :1] < 0, -1.0, 1.0)


def quat_ned_frd_to_enu_flu(q_NED_FRD: ArrayLike) -> FloatArray:
    """Attitude quaternion(s) (w, x, y, z), body FRD -> world NED, as body FLU -> world ENU (w >= 0)."""
    return quat_enu_flu_to_ned_frd(q_NED_FRD)


def yaw_enu_to_ned(yaw_enu_rad: ArrayLike) -> FloatArray:
    """Heading: ENU yaw (from east, counter-clockwise) -> NED yaw (from north, clockwise), in (-pi, pi]."""
    return np.angle(np.exp(1j * (np.pi / 2 - np.asarray(yaw_enu_rad, dtype=float))))


def yaw_ned_to_enu(yaw_ned_rad: ArrayLike) -> FloatArray:
    """Heading: NED yaw -> ENU yaw (the same formula: the map is its own inverse)."""
    return yaw_enu_to_ned(yaw_ned_rad)


def ros_quat_to_wxyz(x: float, y: float, z: float, w: float) -> FloatArray:
    """A ROS geometry_msgs/Quaternion's fields as our (w, x, y, z)."""
    return np.array([w, x, y, z], dtype=float)


def wxyz_to_ros_quat(q: ArrayLike) -> tuple[float, float, float, float]:
    """Our (w, x, y, z) as ROS field order (x, y, z, w)."""
    w, x, y, z = (float(v) for v in np.asarray(q, dtype=float))
    return x, y, z, w
