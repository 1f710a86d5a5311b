"""From the identifier's rotor diagnosis to the effectiveness the allocator uses; pure numpy, no ROS.

The identifier publishes, per rotor, an effectiveness estimate (share of the nominal thrust left, 1 =
healthy) and its standard deviation (1.0 when nothing is known). :class:`EffectivenessFilter` turns
that stream into the vector given to ``Allocator.allocate(..., effectiveness)``:

- only confident estimates (std <= CONFIDENT_STD) move the output; an unconfident estimate, or none at
  all, holds the current target. A rotor commanded to its minimum speed gives the identifier almost no
  information, so its estimate loses confidence exactly when it is left out: taking that as "healthy"
  would bring a stopped rotor back. A confident healthy estimate (the identifier publishes 1 with a
  small std once converged on a healthy rotor) restores the nominal allocation;
- a rotor is "stopped" once a confident estimate puts it below DEAD_ROTOR_EFFECTIVENESS: the verdict
  latches (target 0, the rotor out of the allocation) until a confident estimate of at least
  RECOVERED_EFFECTIVENESS arrives, so a noisy estimate of the idle rotor drifting above the threshold
  does not put it back;
- the output moves towards its target with first-order dynamics (time constant ``time_constant_s``), so
  a diagnosis that appears or clears changes the commands smoothly, never in one step. A rotor latched
  as stopped leaves faster (``stop_time_constant_s``): it gives nothing whatever it is asked, and every
  moment it is still counted on leaves its share of the wrench undone. A hexarotor whose rotor stopped
  in hover, declared 0.03 s after, swings by 4 m when the rotor leaves with 0.2 s, 0.9 m with 0.1 s,
  0.18 m with 0.05 s and 0.11 m with 0.03 s (test_recovery.py's hover case);
- only a stopped rotor may go below ``floor``, down to 0 (the allocator leaves it out below
  DEAD_ROTOR_EFFECTIVENESS). Any other rotor is never taken as weaker than ``floor``: a healthy rotor
  wrongly reported at 15 % is allocated as if at ``floor``, which the feedback law absorbs.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.control.allocation import DEAD_ROTOR_EFFECTIVENESS, MAX_EFFECTIVENESS
from multirotor_ros.model.rotation import BoolArray, FloatArray

# Largest std [1, effectiveness] of an estimate the filter acts on: +-0.2 (2 sigma) separates a rotor
# at half its thrust from a healthy one and a stopped rotor (< 0.1) from one at the floor, and
# is well above the std of a converged diagnosis (a few 0.01), well below the "nothing known" 1.0.
CONFIDENT_STD = 0.1
# Smallest confident estimate that takes a rotor latched as stopped back into the allocation. Half the
# nominal thrust: well above what the identifier estimates for a stopped rotor idling at its minimum
# speed (up to about 0.3 in the X8 campaign, bench/bench_fault_tolerance.py), and a rotor that gives at
# least half its thrust is worth allocating.
RECOVERED_EFFECTIVENESS = 0.5
# Within this of its target the output is taken as there (set to it): the first-order approach would
# otherwise stop a few rounding steps short and never settle. 1e-12 of a rotor's thrust is nothing.
SETTLED_TOLERANCE = 1e-12


class EffectivenessFilter:
    """Confident estimates -> a smooth effectiveness vector per rotor (module docstring).

    ``update(t_s, estimate, std)`` with the identifier's (N,) estimate and std (either None: nothing
    known) returns the (N,) effectiveness for the allocator, starting from all 1 (healthy). Giving the same
    diagnosis again does what giving None does (the stopped latch is idempotent): a caller that runs the
    filter every control period gives a diagnosis when it is new and None in between, which costs almost
    nothing once the output has settled on its target (:attr:`settled`).
    """

    # Time constant [s] of the approach to a new target. Several times the motor time constant (0.03 s
    # on the shipped airframes) so that the commands change no faster than the rotors can follow, and
    # short beside the 3 s the vehicle has to recover after a detection: 3 time constants = 95 % in 0.6 s.
    DEFAULT_TIME_CONSTANT_S: ClassVar[float] = 0.2
    # Smallest effectiveness assumed for a rotor not diagnosed as stopped: a weak, noisy estimate cannot
    # take a rotor out of the allocation (the others would carry its share, a hexarotor would lose yaw).
    # 0.3 is the deepest partial loss issue 15 asks to compensate in full. The floor is no bound on the
    # harm of a wrong diagnosis of a healthy rotor: the allocation gives rotor i a share of omega^2
    # proportional to e_i (pseudo-inverse of B diag(e)), so the mismatch e_i (1 - e_i) is largest at
    # e_i = 0.5, about 40 % of the wrench error of a stopped rotor left uncompensated, which the law
    # holds (test_fault_tolerance.py flies a healthy rotor reported at 50 %).
    DEFAULT_FLOOR: ClassVar[float] = 0.3
    # Time constant [s] of a stopped rotor's way out (module docstring): fast enough for a hexarotor to
    # hold its hover, and slow enough that the commands change by no more per period than when a rotor
    # comes back at DEFAULT_TIME_CONSTANT_S (the fade band makes that the fastest change otherwise).
    DEFAULT_STOP_TIME_CONSTANT_S: ClassVar[float] = 0.05

    def __init__(
        self,
        n_rotors: int,
        time_constant_s: float = DEFAULT_TIME_CONSTANT_S,
        floor: float = DEFAULT_FLOOR,
        stop_time_constant_s: float = DEFAULT_STOP_TIME_CONSTANT_S,
    ):
        if n_rotors < 1:
            raise ValueError(f"n_rotors must be >= 1, got {n_rotors}")
        for name, value in (
            ("time_constant_s", time_constant_s),
            ("stop_time_constant_s", stop_time_constant_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if not DEAD_ROTOR_EFFECTIVENESS <= floor <= 1.0:
            raise ValueError(f"floor must lie in [{DEAD_ROTOR_EFFECTIVENESS}, 1], got {floor}")
        self.n_rotors = n_rotors
        self.time_constant_s = time_constant_s
        self.floor = floor
        self.stop_time_constant_s = stop_time_constant_s
        self.reset()

    def reset(self) -> None:
        """Back to all rotors healthy, no time seen, no rotor stopped."""
        self._effectiveness = np.ones(self.n_rotors)
        self._target = np.ones(self.n_rotors)
        self._stopped = np.zeros(self.n_rotors, dtype=bool)
        self._last_t: float | None = None
        self._settled = True

    @property
    def settled(self) -> bool:
        """Whether the output is at its target: updates without a new diagnosis leave it as it is."""
        return self._settled

    @property
    def effectiveness(self) -> FloatArray:
        """The current output (a copy)."""
        return self._effectiveness.copy()

    @property
    def stopped(self) -> BoolArray:
        """(N,) rotors latched as stopped (a copy)."""
        return self._stopped.copy()

    def target(self, estimate: ArrayLike | None, std: ArrayLike | None) -> FloatArray:
        """Where the output heads after this diagnosis (module docstring); updates the stopped latch."""
        if estimate is None or std is None:
            return self._target.copy()
        e = self._vector(estimate, "estimate")
        sigma = self._vector(std, "std")
        if np.any(sigma < 0):
            raise ValueError(f"std must be >= 0, got {sigma.tolist()}")
        confident = sigma <= CONFIDENT_STD
        self._stopped = np.where(
            confident,
            (e < DEAD_ROTOR_EFFECTIVENESS) | (self._stopped & (e < RECOVERED_EFFECTIVENESS)),
            self._stopped,
        )
        # An estimate of a healthy rotor may come out above 1.
        wanted = np.clip(e, self.floor, MAX_EFFECTIVENESS)
        self._target = np.where(self._stopped, 0.0, np.where(confident, wanted, self._target))
        return self._target.copy()

    def update(self, t_s: float, estimate: ArrayLike | None, std: ArrayLike | None) -> FloatArray:
        """The effectiveness for the allocator at time ``t_s`` [s], given the latest diagnosis."""
        if not math.isfinite(t_s):
            raise ValueError(f"t_s must be finite, got {t_s}")
        if estimate is None and std is None and self._settled:
            self._last_t = t_s
            return self._effectiveness.copy()
        target = self.target(estimate, std)
        dt = 0.0 if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        time_constant = np.where(self._stopped, self.stop_time_constant_s, self.time_constant_s)
        self._effectiveness += (target - self._effectiveness) * -np.expm1(-dt / time_constant)
        self._settled = bool(np.all(np.abs(target - self._effectiveness) <= SETTLED_TOLERANCE))
        if self._settled:
            self._effectiveness[:] = target
        return self._effectiveness.copy()

    def _vector(self, values: ArrayLike, name: str) -> FloatArray:
        vector = np.asarray(values, dtype=float)
        if vector.shape != (self.n_rotors,):
            raise ValueError(f"{name} must have one value per rotor ({self.n_rotors}), got {vector.shape}")
        if not np.all(np.isfinite(vector)):
            raise ValueError(f"{name} must be finite, got {vector.tolist()}")
        return vector
