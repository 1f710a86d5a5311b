"""Super-twisting sliding-mode observer: estimate the unknown part of a measured rate's derivative.

For each channel c (batched over vehicles B) a measured quantity y (a velocity or a body rate) obeys
ẏ = f(t) + d(t), where f is what the model predicts and d what it does not: after a rotor fault,
d is the fault's force (or torque) per unit mass (or inertia). The observer of seed 1's reference [16]
(Saied et al., ECC 2015), after Davila, Fridman and Levant (2005), is

    e = y - ŷ
    dŷ/dt = f + λ |e|^½ sign(e) + z
    dz/dt = α sign(e)

With |ḋ| ≤ L and the usual choice λ = 1.5 √L, α = 1.1 L, e reaches 0 in finite time and stays there
(a second-order sliding mode), and then z = d exactly: z is the equivalent output injection, a
continuous estimate of the disturbance obtained without differentiating the noisy measurement.

A rotor fault is a step in d, for which no L bounds ḋ; z then ramps towards the new d at the rate α
(so α sets the convergence time to a step of size D, about D/α) and sliding is re-established. With
sampled, noisy measurements sign(e) chatters: z moves by α·dt each sample. ``filter_time_constant_s``
low-passes z into the reported estimate to take that ripple out (a first-order filter, exact
discretisation); 0 reports z as it is.

The observer is discretised at the measurement instants: over the interval between two samples the
model rate is the mean of its values at both ends and the injection of the first is held.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import FloatArray


def levant_gains(lipschitz: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(λ, α) = (1.5 √L, 1.1 L): Levant's gains for a disturbance with |ḋ| ≤ L, per channel."""
    bound = np.asarray(lipschitz, dtype=float)
    if np.any(~np.isfinite(bound) | (bound <= 0)):
        raise ValueError(f"the disturbance-rate bound L must be positive and finite per channel, got {bound}")
    return 1.5 * np.sqrt(bound), 1.1 * bound


class SuperTwistingObserver:
    """Batched super-twisting observer over C channels: :meth:`update` returns the estimate of d (B, C)."""

    def __init__(self, lambda_gain: ArrayLike, alpha_gain: ArrayLike, filter_time_constant_s: float = 0.0):
        self.lambda_gain = np.asarray(lambda_gain, dtype=float)
        self.alpha_gain = np.asarray(alpha_gain, dtype=float)
        if self.lambda_gain.ndim != 1 or self.lambda_gain.shape != self.alpha_gain.shape:
            raise ValueError(
                f"gains must be two vectors of one value per channel, got shapes {self.lambda_gain.shape} "
                f"and {self.alpha_gain.shape}"
            )
        if np.any(self.lambda_gain <= 0) or np.any(self.alpha_gain <= 0):
            raise ValueError("super-twisting gains must be positive")
        if not (np.isfinite(filter_time_constant_s) and filter_time_constant_s >= 0):
            raise ValueError(f"filter time constant must be >= 0 s, got {filter_time_constant_s}")
        self.filter_time_constant_s = float(filter_time_constant_s)
        self.y_hat: FloatArray | None = None
        self.z: FloatArray = np.zeros(0)
        self.estimate: FloatArray = np.zeros(0)
        self._f = np.zeros(0)  # model rate at the last sample
        self._injection = np.zeros(0)  # output injection at the last sample, held over the next interval

    @property
    def n_channels(self) -> int:
        """Number of channels C."""
        return self.lambda_gain.size

    @property
    def started(self) -> bool:
        """Whether the observer has had its first measurement."""
        return self.y_hat is not None

    def reset(self, y: ArrayLike, f: ArrayLike = 0.0, disturbance: ArrayLike = 0.0) -> None:
        """Start at the measurement y (B, C), model rate f, with a disturbance guess (0 by default)."""
        measured = np.array(y, dtype=float, ndmin=2)
        if measured.shape[1] != self.n_channels:
            raise ValueError(f"measurement has {measured.shape[1]} channels, the observer {self.n_channels}")
        self.y_hat = measured.copy()
        self.z = np.broadcast_to(np.asarray(disturbance, dtype=float), measured.shape).copy()
        self.estimate = self.z.copy()
        self._f = np.broadcast_to(np.asarray(f, dtype=float), measured.shape).copy()
        self._injection = np.zeros_like(measured)

    def update(self, dt_s: float, y: FloatArray, f: FloatArray) -> FloatArray:
        """Advance by ``dt_s`` to the measurement y (B, C); f (B, C) is the model's dy/dt at this sample.

        The first call only starts the observer (estimate 0). ŷ is propagated over the elapsed interval
        with the mean model rate of its two ends and the injection of the previous sample; z integrates
        the sign of the new error at once, which saves a sample of delay.
        """
        if self.y_hat is None:
            self.reset(y, f)
            return self.estimate
        self.y_hat = self._predicted(dt_s, f)
        error = y - self.y_hat
        sign = np.sign(error)
        self.z = self.z + dt_s * self.alpha_gain * sign
        self._f = np.array(f, dtype=float)
        self._injection = self.lambda_gain * np.sqrt(np.abs(error)) * sign
        if self.filter_time_constant_s > 0:
            blend = 1.0 - np.exp(-dt_s / self.filter_time_constant_s)
            self.estimate = self.estimate + blend * (self.z - self.estimate)
        else:
            self.estimate = self.z.copy()
        return self.estimate

    def prediction_error(self, dt_s: float, y: FloatArray, f: FloatArray) -> FloatArray:
        """(B, C) how far the measurement y lies from where the observer expected it, per ``dt_s``.

        What :meth:`update` would see, without updating: a measurement that agrees with the model and
        the current estimate gives noise, a bad one (or the first sample of a fault) a step.
        """
        return (y - self._predicted(dt_s, f)) / dt_s

    def _predicted(self, dt_s: float, f: FloatArray) -> FloatArray:
        """ŷ propagated by ``dt_s`` to a sample whose model rate is f."""
        if self.y_hat is None:
            raise ValueError("the observer has not started: no prediction")
        if not dt_s > 0:
            raise ValueError(f"observer step must be positive, got {dt_s} s")
        # The model rate enters as the mean of its values at both ends of the interval (trapezoid):
        # rotor speeds ramp between samples during manoeuvres, and holding the old value would leave
        # half an interval's change as a residual that looks like a fault.
        return self.y_hat + dt_s * (0.5 * (self._f + f) + self._injection + self.z)

    def shift_model(self, shift: FloatArray) -> None:
        """The model rate f became f - ``shift`` (B, C): move z and the held f so that f + z stays."""
        self.z = self.z + shift
        self.estimate = self.estimate + shift
        self._f = self._f - shift
