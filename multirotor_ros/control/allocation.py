"""Control allocation: a wanted (thrust, torque) -> rotor speeds, through the airframe's 4xN matrix.

The allocation matrix A maps squared rotor speeds to (thrust, tau_x, tau_y, tau_z) in body FLU
(airframe.py). With a rotor effectiveness e (rotor i gives e_i of its nominal thrust and drag torque,
e.g. as diagnosed by the identifier), the matrix the rotors really obey is A diag(e): rotors with
e_i <= DEAD_ROTOR_EFFECTIVENESS are left out (commanded to the minimum speed) and the others are
allocated through their scaled columns M = A[:, alive] diag(e[alive]); a rotor within FADE_BAND above
the threshold fades out of the allocation continuously, so that dropping it is no jump in the commands.

The allocation splits the wrench into rotor-space directions from the pseudo-inverse of M: collective
(thrust), roll/pitch, yaw. Where the collective would not turn every rotor (zero yaw torque needs some
rotor stopped), collective and roll/pitch come instead from the pseudo-inverse of the first three rows of
M (thrust, roll, pitch), and yaw from what is left. When the rotors cannot deliver everything, the
priority is
1. roll/pitch torque: kept whole if some collective fits it, otherwise scaled down as little as possible;
2. thrust: the collective closest to the wanted one that keeps the roll/pitch part inside the limits;
3. yaw torque: steps 1-2 may bring some yaw torque with them (none for a symmetric airframe whose
   rotors are all healthy; some once a rotor is lost); the largest fraction of the way from it to the
   wanted yaw torque that still fits is taken (yaw is the weakest axis of a multirotor and the one whose
   loss is least dangerous).
Everything is linear in omega^2, so each step is a small closed-form interval computation. Whenever the
least-squares speeds pinv(M) w (weighted, for a rotor fading out) and the part of them without the yaw
step fit the limits, the result is exactly pinv(M) w (the yaw step moves along a segment of a box).

Losing yaw. An X hexarotor that lost a rotor (rotor 1 here, ccw) keeps full rank, but balancing roll
and pitch with zero yaw torque needs the opposite rotor (4) at exactly zero thrust: roll, pitch and
thrust for hover are still there, and the yaw torque is whatever the lowest speed of rotor 4 leaves,
one direction only. The yaw step then reports yaw_fraction < 1 and the vehicle's heading drifts while
its position holds. An X8 that lost one rotor, or two of different coaxial pairs, keeps everything.
A set of rotors that cannot balance roll and pitch with every rotor at or above its minimum (a
quadrotor with a rotor lost, an X8 with a whole arm lost) cannot hover; the allocation stays finite and
within the limits, but cannot hold the attitude, and says so: whenever its collective would need a
rotor below zero thrust, the torque delivered is not the one wanted (roll_pitch_fraction 0) and the
thrust reported is the one the rotors give.

Cost: the directions depend on e, so they are computed once per effectiveness vector (two 4xN
pseudo-inverses) and cached, the rank of each rotor set once; the three steps of allocate are one
compiled scalar kernel (model/jit.py): as numpy operations on arrays of N they cost 30-40 us per call,
almost all of it call overhead, where the controller has 4 ms per period for everything and a fleet
controller runs it for every vehicle.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.jit import kernel
from multirotor_ros.model.rotation import FloatArray

IndexArray = NDArray[np.intp]

# Below this effectiveness a rotor is treated as stopped and left out of the allocation. The
# identifier's "stopped" verdicts are around 1 % of thrust left, and 10 % leaves room for its estimation
# error. Dropping such a rotor barely changes the other commands: the pseudo-inverse of B diag(e) gives
# rotor i a share of omega^2 proportional to e_i, i.e. of thrust proportional to e_i^2 (1 % at 0.1).
DEAD_ROTOR_EFFECTIVENESS = 0.1
# Largest effectiveness accepted: an identified rotor may be stronger than the nominal one (a stiffer
# propeller, a wrong k_f in the YAML), but 1.5x the nominal thrust is beyond any plausible error.
MAX_EFFECTIVENESS = 1.5
# Width of the band above DEAD_ROTOR_EFFECTIVENESS over which a rotor fades out of the allocation
# (_plan): narrow, so that rotors worth using are allocated in full.
FADE_BAND = 0.1
# Effectiveness vectors whose directions are kept (a filter converging on a diagnosis produces a
# new vector per update, a converged one the same vector every time).
_CACHE_SIZE = 32
# Singular values of the row-normalised matrix below this mean "rank deficient" (as in airframe.py).
_RANK_TOLERANCE = 1e-9


@dataclass(frozen=True)
class AllocationResult:
    """Rotor speeds [rad/s] and how much of the wanted wrench they give."""

    omega_rad_s: FloatArray  # (N,)
    thrust_N: float  # thrust actually allocated
    roll_pitch_fraction: float  # share of the wanted roll/pitch torque kept, 0..1
    # Share of the way from the yaw torque that thrust and roll/pitch bring with them (none with all
    # rotors healthy on a symmetric airframe) to the wanted yaw torque, 0..1; 1 = the wanted yaw torque.
    yaw_fraction: float

    @property
    def saturated(self) -> bool:
        """Whether anything wanted was not delivered in full."""
        return self.roll_pitch_fraction < 1.0 or self.yaw_fraction < 1.0


@dataclass(frozen=True)
class _Plan:
    """The rotor-space directions of one effectiveness vector (see the module docstring)."""

    alive: IndexArray  # (n,) indices of the rotors allocated
    collective: FloatArray  # (n,) omega^2 per newton of thrust, no roll/pitch torque
    roll_pitch: FloatArray  # (n, 2) omega^2 per N m of roll and pitch torque
    yaw: FloatArray  # (n,) omega^2 per N m of pure yaw torque (zeros where has_yaw is false)
    has_yaw: bool  # False: no yaw authority at all (the rotor set's matrix is not of full rank)
    collective_yaw: float  # yaw torque [N m] per newton of collective thrust
    roll_pitch_yaw: FloatArray  # (2,) yaw torque per N m of roll and pitch torque
    pair_room: FloatArray  # (n, n) r_ij = hi/a_j - lo/a_i of step 1 in allocate()
    balanced: bool  # whether thrust alone needs no rotor below zero (see the module docstring)
    lift: FloatArray  # (n,) thrust [N] per omega^2 of each rotor allocated


class Allocator:
    """Allocates wrenches for one airframe between squared-speed limits [omega_min^2, omega_max^2]."""

    def __init__(self, allocation: ArrayLike, speed_min_rad_s: float, speed_max_rad_s: float):
        matrix = np.asarray(allocation, dtype=float)
        if matrix.ndim != 2 or matrix.shape[0] != 4:
            raise ValueError(f"allocation matrix must be 4xN, got shape {matrix.shape}")
        if not 0.0 <= speed_min_rad_s < speed_max_rad_s:
            raise ValueError(f"need 0 <= speed_min < speed_max, got {speed_min_rad_s}, {speed_max_rad_s}")
        if np.any(np.linalg.pinv(matrix[:3])[:, 0] <= 0):
            raise ValueError("every rotor must contribute to thrust (pseudo-inverse collective column > 0)")
        self.matrix = matrix
        self.n_rotors = matrix.shape[1]
        self.low = speed_min_rad_s**2
        self.high = speed_max_rad_s**2
        self._ranks: dict[bytes, int] = {}
        self._plans: OrderedDict[bytes, _Plan] = OrderedDict()
        self._nominal = self._plan(np.ones(self.n_rotors))
        # The kernel compiled (or loaded from numba's cache: about 0.5 s) now, not in a first control period.
        self.allocate(0.0, (0.0, 0.0, 0.0))

    @classmethod
    def for_airframe(cls, airframe: Airframe) -> Allocator:
        """The allocator of an Airframe, with its rotor speed range."""
        return cls(airframe.allocation, airframe.rotor_speed_min_rad_s, airframe.rotor_speed_max_rad_s)

    @property
    def max_thrust_N(self) -> float:
        """Largest thrust with no torque, all rotors healthy."""
        return float(self.high / self._nominal.collective.max())

    def allocate(
        self, thrust_N: float, torque_B: Sequence[float] | FloatArray, effectiveness: ArrayLike | None = None
    ) -> AllocationResult:
        """Rotor speeds for a wanted thrust [N] and body torque (tau_x, tau_y, tau_z) [N m].

        ``effectiveness``: (N,) share of its nominal thrust and torque each rotor gives, in
        [0, MAX_EFFECTIVENESS]; None = all healthy. Rotors below DEAD_ROTOR_EFFECTIVENESS get the
        minimum speed.
        """
        plan = self._nominal if effectiveness is None else self._plan_for(effectiveness)
        if plan.alive.size == 0:
            return AllocationResult(np.full(self.n_rotors, np.sqrt(self.low)), 0.0, 0.0, 0.0)
        tau_x, tau_y, tau_z = (float(value) for value in torque_B)
        omega_sq = np.empty(plan.alive.size)
        omega = np.empty(plan.alive.size)
        c, k, s = kernel(_allocate_lanes)(
            float(thrust_N), tau_x, tau_y, tau_z, plan.collective, plan.roll_pitch, plan.yaw, plan.has_yaw,
            plan.collective_yaw, plan.roll_pitch_yaw, plan.pair_room, self.low, self.high, omega_sq, omega,
        )  # fmt: skip
        if plan.alive.size != self.n_rotors:
            allocated = omega
            omega = np.full(self.n_rotors, np.sqrt(self.low))
            omega[plan.alive] = allocated
        if not plan.balanced:
            # The collective direction was lifted off a negative rotor: what the rotors give is not c.
            return AllocationResult(omega, float(plan.lift @ omega_sq), 0.0, s)
        return AllocationResult(omega, c, k, s)

    def _plan_for(self, effectiveness: ArrayLike) -> _Plan:
        """The cached plan of an effectiveness vector, after checking it."""
        e = np.asarray(effectiveness, dtype=float)
        key = e.tobytes()
        plan = self._plans.get(key)
        if plan is not None:
            return plan
        if e.shape != (self.n_rotors,):
            raise ValueError(f"effectiveness must have one value per rotor ({self.n_rotors}), got {e.shape}")
        if not np.all(np.isfinite(e)):
            raise ValueError(f"effectiveness must be finite, got {e.tolist()}")
        if np.any(e < 0.0) or np.any(e > MAX_EFFECTIVENESS):
            raise ValueError(f"effectiveness must lie in [0, {MAX_EFFECTIVENESS}], got {e.tolist()}")
        plan = self._plan(e)
        self._plans[key] = plan
        if len(self._plans) > _CACHE_SIZE:
            self._plans.popitem(last=False)
        return plan

    def _plan(self, effectiveness: FloatArray) -> _Plan:
        alive = np.flatnonzero(effectiveness > DEAD_ROTOR_EFFECTIVENESS)
        matrix = self.matrix[:, alive] * effectiveness[alive]
        # Weighted pseudo-inverses D pinv(M D), D = fade: a rotor fading out of the allocation gets a
        # share of omega^2 in fade^2 that goes to 0 as its effectiveness reaches DEAD_ROTOR_EFFECTIVENESS,
        # so that leaving it out is no jump in its command (quadratic, as its speed is a square root).
        fade = np.clip((effectiveness[alive] - DEAD_ROTOR_EFFECTIVENESS) / FADE_BAND, 0.0, 1.0)
        full = fade[:, None] * np.linalg.pinv(matrix * fade)  # (n, 4)
        has_yaw = self._rank(alive, matrix) == 4
        # Hover with no yaw torque at all, if every rotor then turns (a healthy airframe; the X8 that lost
        # one rotor); else yaw is left to step 3 (the hexarotor that lost one).
        yaw_free = has_yaw and bool(np.all(full[:, 0] > 1e-6 * full[:, 0].max(initial=0.0)))
        directions = full[:, :3] if yaw_free else fade[:, None] * np.linalg.pinv(matrix[:3] * fade)
        collective = directions[:, 0]
        # A rotor the collective does not lift cannot be balanced with the others at hover (module
        # docstring): a small positive floor keeps the interval computations finite for such sets.
        floor = 1e-9 * float(collective.max(initial=0.0))
        # Exactly zero is balanced (the X8 that lost a coaxial pair: its partners' diagonal idles);
        # materially below zero, the floor lifts that rotor and the collective tilts the vehicle.
        balanced = bool(collective.min(initial=0.0) >= -1e-6 * collective.max(initial=0.0))
        collective = np.maximum(collective, max(floor, np.finfo(float).tiny))
        return _Plan(
            alive=alive,
            collective=collective,
            roll_pitch=np.ascontiguousarray(directions[:, 1:3]),
            yaw=full[:, 3].copy() if has_yaw else np.zeros(alive.size),
            has_yaw=has_yaw,
            collective_yaw=float(matrix[3] @ collective),
            roll_pitch_yaw=matrix[3] @ directions[:, 1:3],
            pair_room=self.high / collective[None, :] - self.low / collective[:, None],
            balanced=balanced,
            lift=matrix[0],
        )

    def _rank(self, alive: IndexArray, matrix: FloatArray) -> int:
        """Rank of the allocation matrix of a rotor set: positive column scaling does not change it."""
        key = alive.tobytes()
        if alive.size == 0:
            return 0
        if key not in self._ranks:
            scale = np.abs(matrix).max(axis=1)
            scale[scale == 0.0] = 1.0
            singular = np.linalg.svd(matrix / scale[:, None], compute_uv=False)
            self._ranks[key] = int(np.sum(singular > _RANK_TOLERANCE * singular.max(initial=1.0)))
        return self._ranks[key]


def _allocate_lanes(
    thrust: float,
    tau_x: float,
    tau_y: float,
    tau_z: float,
    a: FloatArray,
    roll_pitch: FloatArray,
    yaw: FloatArray,
    has_yaw: bool,
    collective_yaw: float,
    roll_pitch_yaw: FloatArray,
    pair_room: FloatArray,
    low: float,
    high: float,
    omega_sq: FloatArray,
    omega: FloatArray,
) -> tuple[float, float, float]:
    """Steps 1-3 of :meth:`Allocator.allocate` on a plan's directions: returns (c, k, s).

    Writes omega^2 and omega of the allocated rotors. Compiled (model/jit.py): plain loops over them.
    """
    n = a.shape[0]
    b = np.empty(n)  # omega^2 of the wanted roll/pitch torque
    ratio = np.empty(n)
    for i in range(n):
        b[i] = roll_pitch[i, 0] * tau_x + roll_pitch[i, 1] * tau_y
        ratio[i] = b[i] / a[i]
    # Step 1: the largest k in [0, 1] such that some collective c gives lo <= c a + k b <= hi: for every
    # pair (i, j), (lo - k b_i)/a_i <= (hi - k b_j)/a_j, i.e. k d_ij <= r_ij, d_ij = b_j/a_j - b_i/a_i.
    k = 1.0
    for i in range(n):
        for j in range(n):
            d = ratio[j] - ratio[i]
            if d > 1e-12:
                k = min(k, pair_room[i, j] / d)
    k = max(k, 0.0)
    # Step 2: the collective range that keeps every rotor inside the limits, and the thrust nearest.
    c_low = -np.inf
    c_high = np.inf
    for i in range(n):
        c_low = max(c_low, (low - k * b[i]) / a[i])
        c_high = min(c_high, (high - k * b[i]) / a[i])
    c_high = max(c_low, c_high)
    c = min(max(thrust, c_low), c_high)
    for i in range(n):
        omega_sq[i] = c * a[i] + k * b[i]
    # Step 3: the largest fraction s in [0, 1] of the way from the yaw torque of base to the wanted one.
    missing_yaw = tau_z - c * collective_yaw - k * (roll_pitch_yaw[0] * tau_x + roll_pitch_yaw[1] * tau_y)
    s = 1.0
    if not has_yaw:
        s = 0.0 if abs(missing_yaw) > 1e-12 else 1.0
    else:
        # Rotors the yaw part barely moves cannot limit it (and would overflow the division).
        negligible = 1e-12 * high
        for i in range(n):
            y = yaw[i] * missing_yaw
            if y > negligible:
                s = min(s, (high - omega_sq[i]) / y)
            elif y < -negligible:
                s = min(s, (low - omega_sq[i]) / y)
        s = max(s, 0.0)
        for i in range(n):
            omega_sq[i] += s * yaw[i] * missing_yaw
    for i in range(n):
        omega_sq[i] = min(max(omega_sq[i], low), high)
        omega[i] = np.sqrt(omega_sq[i])
    return c, k, s
