"""Control allocation: a wanted (thrust, torque) -> rotor speeds, through the airframe's 4xN matrix.

The allocation matrix A maps squared rotor speeds to (thrust, tau_x, tau_y, tau_z) in body FLU
(airframe.py). Its pseudo-inverse splits the wrench into three rotor-space directions: collective
(thrust), roll/pitch, yaw. When the rotors cannot deliver everything, the priority is
1. roll/pitch torque: kept whole if some collective fits it, otherwise scaled down as little as possible;
2. thrust: the collective closest to the wanted one that keeps the roll/pitch part inside the limits;
3. yaw torque: the largest fraction of it that still fits (yaw is the weakest axis of a multirotor and
   the one whose loss is least dangerous).
Everything is linear in omega^2, so each step is a small closed-form interval computation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import FloatArray


@dataclass(frozen=True)
class AllocationResult:
    """Rotor speeds [rad/s] and how much of the wanted wrench they give."""

    omega_rad_s: FloatArray  # (N,)
    thrust_N: float  # thrust actually allocated
    roll_pitch_fraction: float  # share of the wanted roll/pitch torque kept, 0..1
    yaw_fraction: float  # share of the wanted yaw torque kept, 0..1

    @property
    def saturated(self) -> bool:
        """Whether anything wanted was not delivered in full."""
        return self.roll_pitch_fraction < 1.0 or self.yaw_fraction < 1.0


class Allocator:
    """Allocates wrenches for one airframe between squared-speed limits [omega_min^2, omega_max^2]."""

    def __init__(self, allocation: ArrayLike, speed_min_rad_s: float, speed_max_rad_s: float):
        matrix = np.asarray(allocation, dtype=float)
        if matrix.ndim != 2 or matrix.shape[0] != 4:
            raise ValueError(f"allocation matrix must be 4xN, got shape {matrix.shape}")
        if not 0.0 <= speed_min_rad_s < speed_max_rad_s:
            raise ValueError(f"need 0 <= speed_min < speed_max, got {speed_min_rad_s}, {speed_max_rad_s}")
        pinv = np.linalg.pinv(matrix)  # (N, 4)
        self.matrix = matrix
        self._collective = pinv[:, 0]  # omega^2 per newton of thrust
        self._roll_pitch = pinv[:, 1:3]
        self._yaw = pinv[:, 3]
        if np.any(self._collective <= 0):
            raise ValueError("every rotor must contribute to thrust (pseudo-inverse collective column > 0)")
        self.low = speed_min_rad_s**2
        self.high = speed_max_rad_s**2
        # r_ij = hi/a_j - lo/a_i of step 1 in allocate(): constant for the airframe.
        self._pair_room = self.high / self._collective[None, :] - self.low / self._collective[:, None]

    @classmethod
    def for_airframe(cls, airframe: Airframe) -> Allocator:
        """The allocator of an Airframe, with its rotor speed range."""
        return cls(airframe.allocation, airframe.rotor_speed_min_rad_s, airframe.rotor_speed_max_rad_s)

    @property
    def max_thrust_N(self) -> float:
        """Largest thrust with no torque."""
        return float(self.high / self._collective.max())

    def allocate(self, thrust_N: float, torque_B: ArrayLike) -> AllocationResult:
        """Rotor speeds for a wanted thrust [N] and body torque (tau_x, tau_y, tau_z) [N m]."""
        tau = np.asarray(torque_B, dtype=float)
        a = self._collective
        b = self._roll_pitch @ tau[:2]
        # Step 1: the largest k in [0, 1] such that some collective c gives lo <= c a + k b <= hi: for every
        # pair (i, j), (lo - k b_i)/a_i <= (hi - k b_j)/a_j, i.e. k d_ij <= r_ij, d_ij = b_j/a_j - b_i/a_i.
        ratio = b / a
        d = ratio[None, :] - ratio[:, None]
        binding = d > 1e-12
        k = min(1.0, float((self._pair_room[binding] / d[binding]).min())) if binding.any() else 1.0
        k = max(k, 0.0)
        rp = k * b
        # Step 2: the collective range that keeps every rotor inside the limits, and the thrust nearest.
        c_low = float(((self.low - rp) / a).max())
        c_high = max(c_low, float(((self.high - rp) / a).min()))
        c = min(max(float(thrust_N), c_low), c_high)
        base = c * a + rp
        # Step 3: the largest yaw fraction s in [0, 1] that keeps base + s y inside the limits.
        y = self._yaw * float(tau[2])
        s = 1.0
        # Rotors the yaw part barely moves cannot limit it (and would overflow the division).
        negligible = 1e-12 * self.high
        up, down = y > negligible, y < -negligible
        if up.any():
            s = min(s, float(((self.high - base[up]) / y[up]).min()))
        if down.any():
            s = min(s, float(((self.low - base[down]) / y[down]).min()))
        s = max(s, 0.0)
        omega_sq = np.clip(base + s * y, self.low, self.high)
        return AllocationResult(np.sqrt(omega_sq), c, k, s)
