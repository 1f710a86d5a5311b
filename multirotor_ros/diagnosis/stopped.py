"""A fast test for "rotor k stopped": a generalised likelihood ratio over a short window of raw residuals.

The detector (:mod:`multirotor_ros.diagnosis.detection`) works on the observer's residual, which reaches
a step in about the observer's convergence time and reports a fraction of the fault on the way: its
first estimate of a stopped rotor is a partial loss. A fault-tolerant allocation that believes a stopped
rotor still gives half its thrust keeps asking it for half the work, and a hexarotor swings by a metre
before the estimate settles. This test answers one question early and decisively: did one rotor stop?

It works on the raw wrench residual (``ResidualSample.raw_wrench``: the last interval alone, unfiltered),
centred on the detector's baseline (the model's steady error) and weighted by its own noise W = diag(1/σ_c²)
(σ_c learnt like the detector's, while the detector is calm; a sample teaches it only ``learn_after_s``
after it came, the detector calm all along: a fault's first samples, before the detector suspects
anything, would otherwise teach the test that a stop is noise). Over the last ``window_s``, for each onset
candidate j (a sample of the window) and each rotor i, the samples k >= j fitted as r_k ≈ -δ s_ik give

    δ̂ = -Σ s_ikᵀ W r_k / Σ s_ikᵀ W s_ik,   std(δ̂) = (Σ s_ikᵀ W s_ik)^-½

and the misfit of "rotor i stopped since j" (δ = 1) is compared with the best misfit of every other
rotor (with its own best loss). Rotor i is declared stopped when, for some j with at least
``min_samples`` samples since:

- the stop explains the samples: |δ̂ - 1| <= ``k_sigma`` std(δ̂);
- the stop is told from a partial loss: the k-sigma intervals about 1 and about ``partial_loss`` (the
  deepest partial loss issue 15 asks to compensate as such, 70 %) do not overlap, i.e.
  std(δ̂) <= (1 - partial_loss) / (2 k_sigma);
- no other rotor explains them nearly as well: its best misfit exceeds the stop's by ``rotor_margin_chi2``
  (a chi-square in units of the noise). A coaxial partner shares the rotor's position: in thrust, roll
  and pitch the two differ only by their speeds, and a model error of a tenth of a rotor during the
  fault's first samples (when the controller changes every speed at once) weighs more there than that
  difference where the thrust is measured precisely (an IMU's specific force): the stop of rotor 4
  "fitted" rotor 3's on such a flight. So the partner is judged on the yaw drag torque alone: the stop
  of the rotor must fit the yaw residual better than the stop of its partner by ``rotor_margin_chi2``,
  which takes half a dozen samples or more on the X8 (the verdict then comes later, or not at all, and
  the detector's alarm stands alone).

A rotor left to idle by the allocation has almost no signature: the test then says nothing about it.
Nor does it speak before ``learn_samples`` calm samples have taught it the noise (at 100 Hz, 0.45 s after
the detector's warm-up, about 1.9 s into a flight): a fault before that is left to the detector.
Pure numpy, batched over B vehicles.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.rotation import BoolArray, FloatArray

# Mean absolute deviation of a Gaussian is σ √(2/π).
_MAD_TO_SIGMA = math.sqrt(math.pi / 2)


@dataclass(frozen=True)
class StopTestSettings:
    """Thresholds of the stopped-rotor test (module docstring)."""

    window_s: float = 0.1  # [s] onset candidates within this window
    min_samples: int = 2  # samples since the onset candidate, at least
    k_sigma: float = 4.0  # width of the intervals about a stop and about the deepest partial loss
    partial_loss: float = 0.7  # deepest partial loss (30 % left) the verdict must tell from a stop
    rotor_margin_chi2: float = 9.0  # how much better the stop must fit than any other rotor's best loss
    noise_time_constant_s: float = 5.0  # [s] memory of the raw residual's noise estimate
    learn_after_s: float = 0.2  # [s] age at which a sample of a calm vehicle teaches the noise
    learn_samples: int = 25  # calm samples learnt before any verdict
    noise_floor_fraction: float = 0.01  # noise floor, as a fraction of a stopped rotor's residual

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"stop test setting {name} must be a finite number > 0, got {value!r}")
        if not self.partial_loss < 1:
            raise ValueError(f"partial_loss must be in (0, 1), got {self.partial_loss}")
        if self.min_samples != int(self.min_samples) or self.learn_samples != int(self.learn_samples):
            raise ValueError("min_samples and learn_samples must be whole numbers")

    @property
    def max_loss_std(self) -> float:
        """Largest std(δ̂) that still tells a stop from the deepest partial loss (module docstring)."""
        return (1.0 - self.partial_loss) / (2.0 * self.k_sigma)


@dataclass(frozen=True)
class StopVerdict:
    """The test's answer after one sample, batched over B (rotor indices are 0-based)."""

    stopped: BoolArray  # (B,) a rotor is declared stopped
    rotor: FloatArray  # (B,) int: which (0 where none)
    loss_std: FloatArray  # (B,) std of its loss estimate over the samples since the onset (nan where none)


class StoppedRotorTest:
    """Windowed stopped-rotor test for B vehicles with N rotors (module docstring)."""

    def __init__(
        self,
        wrench_scale: ArrayLike,
        partners: ArrayLike,
        batch: int = 1,
        settings: StopTestSettings | None = None,
    ):
        self.settings = settings or StopTestSettings()
        scale = np.asarray(wrench_scale, dtype=float)
        if scale.shape != (4,) or np.any(scale <= 0):
            raise ValueError(f"wrench_scale must be 4 positive numbers, got {scale}")
        partner_of = np.asarray(partners, dtype=int)
        n = partner_of.size
        if partner_of.ndim != 1 or n < 1 or np.any((partner_of < -1) | (partner_of >= n)):
            raise ValueError(
                f"partners must give each rotor's coaxial partner (0..N-1) or -1, got {partner_of.tolist()}"
            )
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.batch = int(batch)
        self.partners = partner_of
        # rival[i, m]: rotor m's best loss competes with rotor i's stop in every channel (not i, not its
        # coaxial partner, which is judged on the yaw torque alone: module docstring)
        rotors = np.arange(n)
        self._rival = (rotors[None, :] != rotors[:, None]) & (rotors[None, :] != partner_of[:, None])
        self._has_partner = partner_of >= 0
        self._noise_floor = self.settings.noise_floor_fraction * scale
        self._mad = np.zeros((self.batch, 4))
        self._learnt = np.zeros(self.batch, dtype=int)
        self._unsettled_t = np.full(self.batch, -np.inf)  # (B,) last time the vehicle was not calm
        self._window: deque[tuple[float, FloatArray, FloatArray]] = deque()
        self._to_learn: deque[tuple[float, FloatArray]] = deque()  # samples too young to teach the noise

    def clear(self) -> None:
        """Forget the window (a break in the data: its samples do not follow on from the next ones)."""
        self._window.clear()

    @property
    def noise_std(self) -> FloatArray:
        """(B, 4) the raw residual's noise per wrench channel (floored)."""
        return np.maximum(self._mad * _MAD_TO_SIGMA, self._noise_floor)

    def update(
        self,
        t: float,
        dt_s: float,
        raw_wrench: FloatArray,
        signatures: FloatArray,
        baseline: FloatArray,
        calm: BoolArray,
        may_judge: BoolArray,
    ) -> StopVerdict:
        """One sample: ``raw_wrench`` (B, 4), ``signatures`` (B, 4, N), ``baseline`` (B, 4) the bias.

        ``calm`` (B,): nothing suspected, the sample teaches the noise; ``may_judge`` (B,): a verdict may
        be given (the detector knows the noise and its bias).
        """
        s = self.settings
        centred = raw_wrench - baseline
        self._unsettled_t = np.where(calm, self._unsettled_t, t)
        self._to_learn.append((t, centred))
        while self._to_learn and self._to_learn[0][0] <= t - s.learn_after_s + 1e-9:
            sample_t, sample = self._to_learn.popleft()
            self._learn(sample_t, sample, dt_s)
        self._window.append((t, centred, signatures))
        while self._window and self._window[0][0] <= t - s.window_s + 1e-9:
            self._window.popleft()
        b = self.batch
        verdict = StopVerdict(np.zeros(b, dtype=bool), np.zeros(b), np.full(b, np.nan))
        judged = may_judge & (self._learnt >= s.learn_samples)
        if len(self._window) < s.min_samples or not judged.any():
            return verdict
        residuals = np.stack([sample[1] for sample in self._window])  # (K, B, 4)
        rotor_signatures = np.stack([sample[2] for sample in self._window])  # (K, B, 4, N)
        weight = 1.0 / self.noise_std**2  # (B, 4)
        weighted = rotor_signatures * weight[None, :, :, None]
        # Sums over the samples since each onset candidate j (reverse cumulative sums over k): (K, B, N).
        projection = np.cumsum(np.einsum("kbci,kbc->kbi", weighted, residuals)[::-1], axis=0)[::-1]
        information = np.maximum(
            np.cumsum(np.einsum("kbci,kbci->kbi", weighted, rotor_signatures)[::-1], axis=0)[::-1], 1e-300
        )
        loss = -projection / information
        loss_std = 1.0 / np.sqrt(information)
        # Misfits relative to "all healthy": the stop of rotor i, and rotor i's best loss (positive only).
        stop_misfit = 2.0 * projection + information
        best_misfit = -np.where(loss > 0, projection**2 / information, 0.0)
        rivals_best = np.where(self._rival, best_misfit[..., None, :], np.inf).min(axis=-1)  # (K, B, N)
        # The yaw part of the stop's misfit, to compare a rotor's stop with its partner's.
        yaw = weighted[:, :, 3, :]  # (K, B, N)
        yaw_stop_misfit = np.cumsum(
            (yaw * (2.0 * residuals[:, :, 3, None] + rotor_signatures[:, :, 3, :]))[::-1], axis=0
        )[::-1]
        partner_yaw_margin = np.where(
            self._has_partner, yaw_stop_misfit[..., np.maximum(self.partners, 0)] - yaw_stop_misfit, np.inf
        )
        since = np.arange(len(self._window), 0, -1)[:, None, None]
        margin = np.minimum(rivals_best - stop_misfit, partner_yaw_margin)
        declared = (
            (since >= s.min_samples)
            & (np.abs(loss - 1.0) <= s.k_sigma * loss_std)
            & (loss_std <= s.max_loss_std)
            & (margin >= s.rotor_margin_chi2)
            & judged[None, :, None]
        )
        best_margin = np.where(declared, margin, -np.inf).max(axis=0)  # (B, N)
        stopped = np.isfinite(best_margin).any(axis=1)
        rotor = np.argmax(best_margin, axis=1)
        vehicles = np.arange(b)
        # The surest of the onsets that declare it (the most samples since).
        rotor_std = np.where(declared[:, vehicles, rotor], loss_std[:, vehicles, rotor], np.inf).min(axis=0)
        return StopVerdict(stopped, np.where(stopped, rotor, 0), np.where(stopped, rotor_std, np.nan))

    def _learn(self, sample_t: float, centred: FloatArray, dt_s: float) -> None:
        """Teach the noise a (B, 4) sample of ``sample_t`` for the vehicles calm since then."""
        calm = self._unsettled_t < sample_t
        if not calm.any():
            return
        self._learnt[calm] += 1
        blend = np.maximum(1.0 / self._learnt[calm], -math.expm1(-dt_s / self.settings.noise_time_constant_s))
        self._mad[calm] += blend[:, None] * (np.abs(centred[calm]) - self._mad[calm])
