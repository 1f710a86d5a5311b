"""State samples from a measured pose (motion capture) and an IMU, one IMU message at a time.

The identifier's ``pose_imu`` input: a pose gives position and attitude, the IMU body rates and
specific force. What the identifier also needs comes from them:

- velocity: the difference of consecutive positions, low-passed with ``velocity_time_constant_s``
  (first order, exact for the interval between the two poses); it restarts at zero after a gap
  longer than ``max_gap_s``;
- acceleration in world ENU from the specific force and the pose's attitude (the better one):
  f_B = R_WB^T (a_W - g_W) with g_W = (0, 0, -g), so a_W = R_WB f_B + g_W.

Each IMU message makes one :class:`StateSample` with the pose nearest to it in stamps, if that pose is
at most ``max_pose_age_s`` away; otherwise it is :class:`Unpaired` (not bad input, but no sample). The
two topics need not arrive in the order of their stamps (a loaded machine, a publisher catching up in a
burst): an IMU message waits for a pose stamped at or after it, for at most ``max_gap_s`` of IMU
stamps (longer would be a gap in the data anyway), so that a pose that comes late is still its pose and
a sample is never lost to the order of arrival. :meth:`PoseImuFusion.decided` hands out the IMU
messages decided so far, in the order of their stamps.

Refused, and forgotten as if never sent: a pose whose stamp repeats or goes back, a position beyond
:class:`~multirotor_ros.plausibility.StateLimits` or farther from the last accepted one than the speed
limit allows (one pose at 1e308 m would otherwise make the velocity infinite for good), an IMU reading
beyond the limits of body rate and acceleration. Inputs are finite unit quaternions:
:mod:`multirotor_ros.nodes.messages` reads and checks the messages.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
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
        # Accepted poses, oldest first, as far back as a waiting IMU message may need (pose()).
        self._poses: deque[_Pose] = deque()
        # IMU messages not yet decided (stamp, body rates, specific force), oldest first; then the decided
        # ones until decided() hands them out.
        self._waiting: deque[tuple[int, FloatArray, FloatArray]] = deque()
        self._decided: list[StateSample | Unpaired] = []

    def pose(self, stamp_ns: int, p_WB_W: ArrayLike, q_WB: ArrayLike) -> Refusal | None:
        """Take a pose (position world ENU [m], unit quaternion); a Refusal if it is not new or plausible."""
        p = np.asarray(p_WB_W, dtype=float)
        refusal = self.limits.check(p_WB_W=p, what="pose")
        if refusal is not None:
            return refusal
        velocity = np.zeros(3)
        last = self._poses[-1] if self._poses else None
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
        self._poses.append(_Pose(stamp_ns, p, np.asarray(q_WB, dtype=float), velocity))
        # A waiting IMU message is at most max_gap_s older than the newest, and its pose at most
        # max_pose_age_s older than it.
        oldest_needed_ns = stamp_ns - round((self.max_gap_s + self.max_pose_age_s) * 1e9)
        while len(self._poses) > 2 and self._poses[1].stamp_ns <= oldest_needed_ns:
            self._poses.popleft()
        self._decide()
        return None

    def imu(self, stamp_ns: int, w_WB_B: ArrayLike, specific_force_B: ArrayLike) -> Refusal | None:
        """Take an IMU message (body rates [rad/s], specific force [m/s^2], body FLU); Refusal if implausible.

        Its sample (or why there is none) comes out of :meth:`decided` once its pose is known.
        """
        refusal = self.limits.check(w_WB_B=w_WB_B, a_WB_W=specific_force_B, what="imu")
        if refusal is not None:
            return refusal
        self._waiting.append(
            (stamp_ns, np.asarray(w_WB_B, dtype=float), np.asarray(specific_force_B, dtype=float))
        )
        self._decide()
        return None

    def decided(self) -> list[StateSample | Unpaired]:
        """The IMU messages decided since the last call, in the order of their stamps."""
        decided, self._decided = self._decided, []
        return decided

    def _decide(self) -> None:
        """Pair the waiting IMU messages whose pose is known, or that waited ``max_gap_s`` of stamps."""
        waiting = self._waiting
        newest_pose_ns = self._poses[-1].stamp_ns if self._poses else None
        patience_ns = round(self.max_gap_s * 1e9)
        while waiting:
            stamp_ns, w_WB_B, specific_force_B = waiting[0]
            pose_known = newest_pose_ns is not None and newest_pose_ns >= stamp_ns
            if not pose_known and waiting[-1][0] - stamp_ns <= patience_ns:
                return
            waiting.popleft()
            self._decided.append(self._pair(stamp_ns, w_WB_B, specific_force_B))

    def _pair(
        self, stamp_ns: int, w_WB_B: FloatArray, specific_force_B: FloatArray
    ) -> StateSample | Unpaired:
        poses = self._poses
        if not poses:
            return Unpaired("no pose yet", "imu arrived before the first pose")
        after = bisect.bisect_left(poses, stamp_ns, key=lambda pose: pose.stamp_ns)
        nearby = [poses[k] for k in (after - 1, after) if 0 <= k < len(poses)]
        pose = min(nearby, key=lambda candidate: abs(candidate.stamp_ns - stamp_ns))
        if abs(stamp_ns - pose.stamp_ns) * 1e-9 > self.max_pose_age_s:
            return Unpaired("no recent pose", f"imu at {stamp_ns} ns, nearest pose at {pose.stamp_ns} ns")
        a_W = quat_to_matrix(pose.q_WB) @ specific_force_B
        a_W[2] -= self.gravity_m_s2
        return StateSample(stamp_ns, pose.p_WB_W, pose.v_WB_W, pose.q_WB, w_WB_B, a_W)
