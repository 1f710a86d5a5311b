"""State samples from a measured pose (motion capture) and an IMU, one IMU message at a time.

The identifier's ``pose_imu`` input: a pose gives position and attitude, the IMU body rates and
specific force. What the identifier also needs comes from them:

- velocity: the difference of consecutive positions, low-passed with ``velocity_time_constant_s``
  (first order, exact for the interval between the two poses); it restarts at zero after a gap
  longer than ``max_gap_s``;
- acceleration in world ENU from the specific force and the pose's attitude (the better one):
  f_B = R_WB^T (a_W - g_W) with g_W = (0, 0, -g), so a_W = R_WB f_B + g_W.

Each IMU message makes one :class:`StateSample` with the newest pose, if that pose is at most
``max_pose_age_s`` away from it in stamps; otherwise it is :class:`Unpaired` (not bad input, but no
sample). Refused, and forgotten as if never sent: a pose whose stamp repeats or goes back, a position
beyond :class:`~multirotor_ros.plausibility.StateLimits` or farther from the last accepted one than
the speed limit allows (one pose at 1e308 m would otherwise make the velocity infinite for good), an
IMU reading beyond the limits of body rate and acceleration. Inputs are finite unit quaternions:
:mod:`multirotor_ros.nodes.messages` reads and checks the messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import FloatArray, quat_to_matrix
from multirotor_ros.plausibility import StateLimits, jump_refusal
from multirotor_ros.refusals import Refusal

# Velocity from pose differences is low-passed with this time constant [s].
VELOCITY_TIME_CONSTANT_S = 0.05


@dataclass(frozen=True)
class StateSample:
    """The vehicle's state at ``stamp_ns``; ``a_WB_W`` is None when the source has no acceleration."""

    stamp_ns: int
    p_WB_W: FloatArray  # position, world ENU [m]
    v_WB_W: FloatArray  # velocity, world ENU [m/s]
    q_WB: FloatArray  # attitude (w, x, y, z), body FLU in world ENU
    w_WB_B: FloatArray  # body rates, body FLU [rad/s]
    a_WB_W: FloatArray | None = None  # acceleration, world ENU [m/s^2]


@dataclass(frozen=True)
class Unpaired(Refusal):
    """An IMU message without a pose close enough in time: no sample, but not bad input either."""


@dataclass(frozen=True)
class _Pose:
    stamp_ns: int
    p_WB_W: FloatArray
    q_WB: FloatArray
    v_WB_W: FloatArray


class PoseImuFusion:
    """Pose + IMU messages -> state samples with velocity and acceleration; see the module docstring."""

    def __init__(
        self,
        gravity_m_s2: float,
        max_gap_s: float,
        max_pose_age_s: float,
        velocity_time_constant_s: float = VELOCITY_TIME_CONSTANT_S,
        limits: StateLimits | None = None,
    ):
        for name, value in [
            ("gravity_m_s2", gravity_m_s2),
            ("max_gap_s", max_gap_s),
            ("max_pose_age_s", max_pose_age_s),
            ("velocity_time_constant_s", velocity_time_constant_s),
        ]:
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"PoseImuFusion: {name} must be finite and > 0, got {value}")
        self.gravity_m_s2 = gravity_m_s2
        self.max_gap_s = max_gap_s
        self.max_pose_age_s = max_pose_age_s
        self.velocity_time_constant_s = velocity_time_constant_s
        self.limits = limits or StateLimits()
        self._pose: _Pose | None = None

    def pose(self, stamp_ns: int, p_WB_W: ArrayLike, q_WB: ArrayLike) -> Refusal | None:
        """Take a pose (position world ENU [m], unit quaternion); a Refusal if it is not new or plausible."""
        p = np.asarray(p_WB_W, dtype=float)
        refusal = self.limits.check(p_WB_W=p, what="pose")
        if refusal is not None:
            return refusal
        velocity = np.zeros(3)
        last = self._pose
        if last is not None:
            if stamp_ns <= last.stamp_ns:
                return Refusal(
                    "duplicated stamp" if stamp_ns == last.stamp_ns else "stamp out of order",
                    f"pose stamp {stamp_ns} ns, previous {last.stamp_ns} ns",
                )
            dt_s = (stamp_ns - last.stamp_ns) * 1e-9
            refusal = jump_refusal(last.p_WB_W, p, dt_s, self.limits, "pose position")
            if refusal is not None:
                return refusal
            if dt_s <= self.max_gap_s:
                blend = 1.0 - math.exp(-dt_s / self.velocity_time_constant_s)
                velocity = last.v_WB_W + blend * ((p - last.p_WB_W) / dt_s - last.v_WB_W)
        self._pose = _Pose(stamp_ns, p, np.asarray(q_WB, dtype=float), velocity)
        return None

    def imu(
        self, stamp_ns: int, w_WB_B: ArrayLike, specific_force_B: ArrayLike
    ) -> StateSample | Unpaired | Refusal:
        """The state sample of an IMU message (body rates [rad/s], specific force [m/s^2], body FLU)."""
        refusal = self.limits.check(w_WB_B=w_WB_B, a_WB_W=specific_force_B, what="imu")
        if refusal is not None:
            return refusal
        pose = self._pose
        if pose is None:
            return Unpaired("no pose yet", "imu arrived before the first pose")
        if abs(stamp_ns - pose.stamp_ns) * 1e-9 > self.max_pose_age_s:
            return Unpaired("no recent pose", f"imu at {stamp_ns} ns, newest pose at {pose.stamp_ns} ns")
        a_W = quat_to_matrix(pose.q_WB) @ np.asarray(specific_force_B, dtype=float)
        a_W[2] -= self.gravity_m_s2
        return StateSample(
            stamp_ns, pose.p_WB_W, pose.v_WB_W, pose.q_WB, np.asarray(w_WB_B, dtype=float), a_W
        )
