"""The scalar arithmetic of the IMU and pose models (simulation/sensors.py), compiled by numba.

This module imports numba, which takes seconds to start on a loaded machine: sensors.py imports it on
the first sample, not on its own import, so that the nodes that only use the sensor models' types never
pay that. Compiled code goes to numba's disk cache, as model/jit.py's kernels do.

Every function loops over vehicles k; each vehicle is computed by the same scalar code, whatever the
number of vehicles, so one vehicle's reading never depends on how many others share the arrays.
"""

from __future__ import annotations

import math

from numba import njit

from multirotor_ros.model.rotation import FloatArray

_jit = njit(cache=True, error_model="numpy")
_inline = njit(cache=True, error_model="numpy", inline="always")

# Rows of :func:`imu_lanes`' ``out``: the attitude the IMU reports, its specific force, its body rate.
OUT_QUATERNION = slice(0, 4)
OUT_SPECIFIC_FORCE = slice(4, 7)
OUT_RATE = slice(7, 10)
OUT_COLUMNS = 10
# Entries of :func:`imu_lanes`' ``constants``.
ACCEL_BIAS_STEP, GYRO_BIAS_STEP, ACCEL_SIGMA, GYRO_SIGMA, ORIENTATION_SIGMA, GRAVITY = range(6)


@_inline
def _turned(
    aw: float, ax: float, ay: float, az: float, roll: float, pitch: float, yaw: float
) -> tuple[float, float, float, float]:
    """(aw, ax, ay, az) ⊗ q(roll, pitch, yaw), unit norm; q(...) as rotation.euler_to_quat (ZYX)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    bw = cr * cp * cy + sr * sp * sy
    bx = sr * cp * cy - cr * sp * sy
    by = cr * sp * cy + sr * cp * sy
    bz = cr * cp * sy - sr * sp * cy
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    return w / norm, x / norm, y / norm, z / norm


@_jit
def turned_lanes(q_WB: FloatArray, angles_rad: FloatArray, out: FloatArray) -> None:
    """out[k] = q_WB[k] ⊗ q(angles_rad[k]), unit norm: attitudes turned by small ZYX angles."""
    for k in range(q_WB.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = _turned(
            q_WB[k, 0],
            q_WB[k, 1],
            q_WB[k, 2],
            q_WB[k, 3],
            angles_rad[k, 0],
            angles_rad[k, 1],
            angles_rad[k, 2],
        )


@_jit
def imu_lanes(
    q_WB: FloatArray,
    a_WB_W: FloatArray,
    w_WB_B: FloatArray,
    z: FloatArray,
    constants: FloatArray,
    biases: FloatArray,
    out: FloatArray,
) -> None:
    """One IMU sample per vehicle k (sensors.Imu.sample): the biases walk (in place), then the readings.

    ``constants``: the bias walk steps, white-noise sigmas, orientation sigma and gravity, indexed by
    this module's names; ``biases`` (V, 6): accelerometer then gyro. ``z`` (V, 12 or 15): standard
    normals in sensors.Imu.draws' order. The specific force (what an accelerometer measures,
    R(q)^T (a - g_vec) with g_vec = (0, 0, -g); R as rotation.quat_to_matrix) gets bias and noise added;
    the attitude is turned by the orientation noise (ZYX angles, none when its sigma is 0). ``out``
    (V, :data:`OUT_COLUMNS`): attitude, specific force, body rate, in the columns named above.
    """
    accel_step, gyro_step = constants[ACCEL_BIAS_STEP], constants[GYRO_BIAS_STEP]
    accel_sigma, gyro_sigma = constants[ACCEL_SIGMA], constants[GYRO_SIGMA]
    orientation_sigma = constants[ORIENTATION_SIGMA]
    for k in range(q_WB.shape[0]):
        for i in range(3):
            biases[k, i] = biases[k, i] + accel_step * z[k, i]
            biases[k, 3 + i] = biases[k, 3 + i] + gyro_step * z[k, 3 + i]
        w, x, y, zq = q_WB[k, 0], q_WB[k, 1], q_WB[k, 2], q_WB[k, 3]
        a, b, c = a_WB_W[k, 0] + 0.0, a_WB_W[k, 1] + 0.0, a_WB_W[k, 2] + constants[GRAVITY]
        f0 = (1 - 2 * (y * y + zq * zq)) * a + 2 * (x * y + w * zq) * b + 2 * (x * zq - w * y) * c
        f1 = 2 * (x * y - w * zq) * a + (1 - 2 * (x * x + zq * zq)) * b + 2 * (y * zq + w * x) * c
        f2 = 2 * (x * zq + w * y) * a + 2 * (y * zq - w * x) * b + (1 - 2 * (x * x + y * y)) * c
        out[k, 4] = (f0 + biases[k, 0]) + accel_sigma * z[k, 6]
        out[k, 5] = (f1 + biases[k, 1]) + accel_sigma * z[k, 7]
        out[k, 6] = (f2 + biases[k, 2]) + accel_sigma * z[k, 8]
        for i in range(3):
            out[k, 7 + i] = (w_WB_B[k, i] + biases[k, 3 + i]) + gyro_sigma * z[k, 9 + i]
        turn = orientation_sigma > 0
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = _turned(
            w,
            x,
            y,
            zq,
            orientation_sigma * z[k, 12] if turn else 0.0,
            orientation_sigma * z[k, 13] if turn else 0.0,
            orientation_sigma * z[k, 14] if turn else 0.0,
        )
