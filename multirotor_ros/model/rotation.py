"""Batched rotations: quaternions (w, x, y, z), ZYX Euler angles and rotation matrices.

Every function takes arrays with any leading batch shape. ``R_WB`` maps body vectors to world
vectors (conventions.md: R = Rz(yaw) Ry(pitch) Rx(roll)); ``q_WB`` is the same rotation as a unit
quaternion, scalar first. ROS messages use (x, y, z, w): convert at the message edge only.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]  # masks: which rows, rotors or samples


def quat_to_matrix(q_WB: ArrayLike) -> FloatArray:
    """Rotation matrix of a unit quaternion (w, x, y, z); shape (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q_WB, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def euler_to_matrix(euler: ArrayLike) -> FloatArray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from (..., 3) = (roll, pitch, yaw) in rad (seed 1 eq. 1)."""
    e = np.asarray(euler, dtype=float)
    cf, sf = np.cos(e[..., 0]), np.sin(e[..., 0])
    ct, st = np.cos(e[..., 1]), np.sin(e[..., 1])
    cp, sp = np.cos(e[..., 2]), np.sin(e[..., 2])
    R = np.empty(e.shape[:-1] + (3, 3))
    R[..., 0, 0] = ct * cp
    R[..., 0, 1] = cp * st * sf - cf * sp
    R[..., 0, 2] = cf * cp * st + sf * sp
    R[..., 1, 0] = ct * sp
    R[..., 1, 1] = sp * st * sf + cf * cp
    R[..., 1, 2] = cf * st * sp - cp * sf
    R[..., 2, 0] = -st
    R[..., 2, 1] = ct * sf
    R[..., 2, 2] = ct * cf
    return R


def euler_to_quat(euler: ArrayLike) -> FloatArray:
    """Unit quaternion (w, x, y, z) of ZYX Euler angles (roll, pitch, yaw)."""
    e = np.asarray(euler, dtype=float)
    cr, sr = np.cos(e[..., 0] / 2), np.sin(e[..., 0] / 2)
    cp, sp = np.cos(e[..., 1] / 2), np.sin(e[..., 1] / 2)
    cy, sy = np.cos(e[..., 2] / 2), np.sin(e[..., 2] / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def quat_to_euler(q_WB: ArrayLike) -> FloatArray:
    """ZYX Euler angles (roll, pitch, yaw) of a unit quaternion; pitch is clipped to [-pi/2, pi/2]."""
    q = np.asarray(q_WB, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def matrix_to_quat(R_WB: ArrayLike) -> FloatArray:
    """Unit quaternion (w, x, y, z) with w >= 0 of rotation matrices (..., 3, 3)."""
    R = np.asarray(R_WB, dtype=float)
    # Shepperd's method, vectorised: pick the largest of (w, x, y, z) for a well-conditioned division.
    trace = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    candidates = np.stack(
        [1 + trace, 1 + 2 * R[..., 0, 0] - trace, 1 + 2 * R[..., 1, 1] - trace, 1 + 2 * R[..., 2, 2] - trace],
        axis=-1,
    )
    best = np.argmax(candidates, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(candidates, best[..., None], -1)[..., 0], 1e-300)) * 2
    r = R
    options = [
        (
            s / 4,
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 1, 0] - r[..., 0, 1]) / s,
        ),
        (
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            s / 4,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
        ),
        (
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            s / 4,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
        ),
        (
            (r[..., 1, 0] - r[..., 0, 1]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
            s / 4,
        ),
    ]
    q = np.zeros(R.shape[:-2] + (4,))
    for index, components in enumerate(options):
        mask = best == index
        q[mask] = np.stack(components, axis=-1)[mask]
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def quat_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product a ⊗ b of quaternions (w, x, y, z)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: ArrayLike) -> FloatArray:
    """Inverse of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def euler_rates_matrix(euler: ArrayLike) -> FloatArray:
    """W(eta) with w_B = W(eta) · d(eta)/dt for ZYX Euler angles; shape (..., 3, 3)."""
    e = np.asarray(euler, dtype=float)
    cf, sf = np.cos(e[..., 0]), np.sin(e[..., 0])
    ct, st = np.cos(e[..., 1]), np.sin(e[..., 1])
    W = np.zeros(e.shape[:-1] + (3, 3))
    W[..., 0, 0] = 1.0
    W[..., 0, 2] = -st
    W[..., 1, 1] = cf
    W[..., 1, 2] = sf * ct
    W[..., 2, 1] = -sf
    W[..., 2, 2] = cf * ct
    return W
