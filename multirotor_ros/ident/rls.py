"""Online identification: recursive least squares with forgetting, and the identifier's sliding window.

The model y = Φ θ + e is linear in the parameters θ (the linear parameters of effects.md, whose
regressor rows :class:`multirotor_ros.ident.regressors.ForceRegressor` builds from the model itself).
At every sample the identifier has a few rows (y: (m,), Φ: (m, p));
:meth:`RecursiveLeastSquares.update` folds them in at once (the gain needs the inverse of an m × m
innovation covariance, m = 3), forgetting once per sample.

Forgetting λ < 1 weighs a sample k steps old by λ^k: the estimate follows parameters that drift,
over an effective memory of 1 / (1 - λ) samples. P is the covariance per unit noise variance, and
starts at the prior's diag(initial_std²). During hover most directions of θ are not excited and
plain forgetting lets P grow without bound in those directions ("wind-up"), after which one
manoeuvre throws the estimate far off; so no diagonal entry of P may exceed its starting value, and an
unexcited parameter falls back to being no better known than at the start.

Standard deviations are σ̂ √diag(P), with σ̂² the forgetting-weighted mean of the a-priori residuals'
squares normalised by their own variance (λ eᵀ(λI + ΦPΦᵀ)⁻¹e): the usual RLS noise estimate. With
samples that are correlated in time (a differentiated velocity, a filtered acceleration) these are
optimistic: read them as a lower bound.

:class:`OnlineIdentifier` is what the identifier node runs: an RLS update per sample and, every
``refit_period_s``, a bounded least-squares fit of the samples of the last ``window_s`` from which the
RLS restarts. Updates refuse non-finite rows (they would poison P for good) and say which entry.

A least-squares estimate follows any sample, so a wrong one (a rotor speed that is not the rotor's, a
velocity off by a metre per second) must not reach it: before a sample updates the RLS or enters the
window, :class:`OnlineIdentifier` tests its innovation, the a-priori force residual (its mean square
over x, y, z; not divided by its predicted variance, which a huge regressor, e.g. of a wrong velocity,
would inflate until anything passes), against ``gate_sigma``² times the noise level: the median of the
last ``gate_memory`` samples' innovations (accepted or not), scaled to a mean. A median, because
bad samples would inflate a mean and open the gate for more of them; it stands as long as fewer than
half the samples are bad, and it follows a real change of the vehicle (a payload), which moves every
sample's innovation. A sample beyond the gate is counted (``n_gated``) and dropped; nothing is learnt
before the median rests on ``gate_memory`` / 4 samples.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

# fit imports scipy: loaded with this module, so that a node pays for it at start and not at its
# first refit, while samples pile up.
from multirotor_ros.ident.fit import solve_bounded
from multirotor_ros.ident.parameters import FittedParameter
from multirotor_ros.ident.regressors import ForceRegressor, linear_refs, parameter_value, with_values
from multirotor_ros.ident.settings import FitSettings
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import effect_class
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray
from multirotor_ros.model.state import StateBatch


class RlsError(ValueError):
    """A sample or a saved state that the estimator refuses; the message says which entry."""


class RecursiveLeastSquares:
    """θ̂ of y = Φ θ + e, updated sample by sample with forgetting factor ``forgetting``.

    ``initial`` is the prior estimate (zeros by default) and ``initial_std`` its standard deviation
    (a scalar or one per parameter): P starts at diag(initial_std²) and never exceeds it on the diagonal.
    """

    def __init__(
        self,
        parameter_names: Sequence[str],
        forgetting: float = 0.999,
        initial: ArrayLike | None = None,
        initial_std: ArrayLike = 1e3,
    ):
        names = tuple(parameter_names)
        if not names or len(set(names)) != len(names):
            raise RlsError(f"parameter names must be non-empty and distinct, got {list(names)}")
        if not (0.0 < forgetting <= 1.0):
            raise RlsError(f"forgetting factor must be in (0, 1], got {forgetting}")
        self.parameter_names = names
        self.forgetting = float(forgetting)
        n = len(names)
        prior_std = np.broadcast_to(np.asarray(initial_std, dtype=float), (n,)).copy()
        if np.any(~np.isfinite(prior_std) | (prior_std <= 0)):
            raise RlsError(f"initial_std must be positive and finite, got {prior_std}")
        self.max_covariance: FloatArray = prior_std**2
        self.theta: FloatArray = (
            np.zeros(n) if initial is None else np.array(np.broadcast_to(np.asarray(initial, float), (n,)))
        )
        if not np.all(np.isfinite(self.theta)):
            raise RlsError(f"initial estimate must be finite, got {self.theta}")
        self.covariance: FloatArray = np.diag(self.max_covariance)
        self.noise_variance = 0.0
        # Forgetting-weighted count of rows seen: 1/(1-λ) at most; the noise estimate's weight.
        self.weight = 0.0
        self.n_updates = 0

    @property
    def n_parameters(self) -> int:
        """Number of parameters p."""
        return len(self.parameter_names)

    @property
    def std(self) -> FloatArray:
        """Standard deviation of each parameter estimate (σ̂ √diag P; the prior's before any residual)."""
        scale = self.noise_variance if self.weight > 0 else 1.0
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0) * scale)

    def estimates(self) -> dict[str, tuple[float, float]]:
        """``{name: (value, std)}``."""
        return {
            name: (float(v), float(s))
            for name, v, s in zip(self.parameter_names, self.theta, self.std, strict=True)
        }

    def update(self, y: ArrayLike, phi: ArrayLike) -> FloatArray:
        """Fold in one sample: y (m,) measured, Φ (m, p) regressors; returns the a-priori residuals (m,)."""
        ys, rows = self._rows(y, phi)
        # One reduction catches NaN and infinity anywhere; the slower search below only names the entry.
        if not math.isfinite(float(rows.sum()) + float(ys.sum())):
            self._refuse_non_finite(ys, rows)
        lam = self.forgetting
        P = self.covariance
        P_phi_t = P @ rows.T
        innovation_covariance = rows @ P_phi_t
        innovation_covariance.flat[:: ys.size + 1] += lam
        inverse = _inverse(innovation_covariance)
        residuals = ys - rows @ self.theta
        gain = P_phi_t @ inverse
        self.theta = self.theta + gain @ residuals
        P = (P - gain @ P_phi_t.T) * (1.0 / lam)
        # Normalised innovations: each row's a-priori residual divided by its own variance.
        self.weight = lam * self.weight + ys.size
        self.noise_variance += (
            lam * float(residuals @ inverse @ residuals) - ys.size * self.noise_variance
        ) / self.weight
        self.covariance = self._bounded(P)
        self.n_updates += 1
        return residuals

    def _rows(self, y: ArrayLike, phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """The sample as y (m,) and Φ (m, p); RlsError if their shapes do not fit the parameters."""
        ys = np.asarray(y, dtype=float).reshape(-1)
        rows = np.asarray(phi, dtype=float)
        if rows.shape != (ys.size, self.n_parameters):
            if rows.size != ys.size * self.n_parameters:
                raise RlsError(
                    f"regressor shape {rows.shape} does not match y ({ys.size} rows) "
                    f"and {self.n_parameters} parameters"
                )
            rows = rows.reshape(ys.size, self.n_parameters)
        return ys, rows

    def _bounded(self, P: FloatArray) -> FloatArray:
        """P with no diagonal entry above the prior variance (anti wind-up, see the module docstring)."""
        diagonal = P.diagonal()
        if (diagonal > self.max_covariance).any():
            # Scale rows and columns together so that P stays symmetric positive semi-definite.
            scale = np.sqrt(np.minimum(1.0, self.max_covariance / np.maximum(diagonal, 1e-300)))
            P = P * np.outer(scale, scale)
        return P

    def restart(self, theta: ArrayLike, covariance: ArrayLike, noise_variance: float) -> None:
        """Continue from an estimate made elsewhere (a batch fit): θ, its unit covariance (AᵀA)⁻¹, σ²."""
        theta = np.asarray(theta, dtype=float)
        covariance = np.asarray(covariance, dtype=float)
        n = self.n_parameters
        if theta.shape != (n,) or covariance.shape != (n, n):
            raise RlsError(
                f"restart needs {n} values and a {n}x{n} covariance, got {theta.shape}, {covariance.shape}"
            )
        if not (np.all(np.isfinite(theta)) and math.isfinite(noise_variance)) or np.any(np.isnan(covariance)):
            raise RlsError(
                "restart values must be finite (the covariance may hold +inf for an unseen parameter)"
            )
        # An infinite variance (a parameter the batch never saw) falls back to the prior's, uncorrelated.
        unseen = ~np.isfinite(np.diag(covariance))
        covariance = np.where(np.isfinite(covariance), covariance, 0.0)
        covariance[unseen, :] = 0.0
        covariance[:, unseen] = 0.0
        covariance[unseen, unseen] = self.max_covariance[unseen]
        self.theta = theta.copy()
        self.covariance = self._bounded(0.5 * (covariance + covariance.T))
        self.noise_variance = float(noise_variance)
        self.weight = max(self.weight, 1.0)

    def _refuse_non_finite(self, ys: FloatArray, rows: FloatArray) -> None:
        bad_y = np.flatnonzero(~np.isfinite(ys))
        if bad_y.size:
            raise RlsError(f"measurement row {bad_y[0]} is {ys[bad_y[0]]}; the sample is refused")
        bad = np.argwhere(~np.isfinite(rows))
        if bad.size:
            row, column = bad[0]
            raise RlsError(
                f"regressor row {row}, parameter {self.parameter_names[column]} is {rows[row, column]}; "
                "the sample is refused"
            )
        raise RlsError("the sample's values are too large to be summed in double precision; refused")

    # ------------------------------------------------------------------ persistence

    def state(self) -> dict[str, FloatArray]:
        """Everything needed to resume, as arrays (for ``numpy.savez``)."""
        return {
            "parameter_names": np.array(self.parameter_names),
            "theta": self.theta.copy(),
            "covariance": self.covariance.copy(),
            "max_covariance": self.max_covariance.copy(),
            "scalars": np.array(
                [self.forgetting, self.noise_variance, self.weight, self.n_updates], dtype=float
            ),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, ArrayLike]) -> RecursiveLeastSquares:
        """Rebuild an estimator saved by :meth:`state`; refuses a state that does not fit together."""
        try:
            names = [str(n) for n in np.asarray(state["parameter_names"]).tolist()]
            theta = np.asarray(state["theta"], dtype=float)
            covariance = np.asarray(state["covariance"], dtype=float)
            max_covariance = np.asarray(state["max_covariance"], dtype=float)
            forgetting, noise_variance, weight, n_updates = np.asarray(state["scalars"], dtype=float)
        except (KeyError, ValueError, TypeError) as error:
            raise RlsError(f"saved RLS state is incomplete or malformed: {error}") from error
        n = len(names)
        if theta.shape != (n,) or covariance.shape != (n, n) or max_covariance.shape != (n,):
            raise RlsError(f"saved RLS state has inconsistent shapes for {n} parameters")
        values = np.concatenate(
            [theta, covariance.ravel(), max_covariance, [forgetting, noise_variance, weight]]
        )
        if not np.all(np.isfinite(values)):
            raise RlsError("saved RLS state holds non-finite numbers")
        estimator = cls(names, forgetting, theta, np.sqrt(max_covariance))
        estimator.covariance = covariance
        estimator.noise_variance = float(noise_variance)
        estimator.weight = float(weight)
        estimator.n_updates = int(n_updates)
        return estimator


# ----------------------------------------------------------------------------------------------
# The identifier's online estimator: RLS at every sample, a refit of the sliding window now and then


@dataclass(frozen=True)
class OnlineSettings:
    """How the online identifier remembers: RLS memory and the refit window."""

    window_s: float = 60.0  # [s] samples kept for the refit
    refit_period_s: float = 5.0  # [s] between refits
    forgetting: float = 0.999  # RLS forgetting factor per sample (memory 1/(1-λ) samples)
    min_refit_samples: int = 100  # a refit needs at least this many samples in the window
    gate_sigma: float = 6.0  # a sample whose force residual exceeds this many noise levels is dropped
    gate_memory: int = 200  # samples whose median innovation is the gate's noise level
    # When a refit believes a parameter: the same rule as a fit of a log (identifiable_relative_std).
    fit_settings: FitSettings = field(default_factory=FitSettings)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ValueError(f"window_s must be > 0 s, got {self.window_s}")
        if not (math.isfinite(self.refit_period_s) and self.refit_period_s > 0):
            raise ValueError(f"refit_period_s must be > 0 s, got {self.refit_period_s}")
        if not 0 < self.forgetting <= 1:
            raise ValueError(f"forgetting must be in (0, 1], got {self.forgetting}")
        if self.min_refit_samples < 1:
            raise ValueError(f"min_refit_samples must be >= 1, got {self.min_refit_samples}")
        if not (math.isfinite(self.gate_sigma) and self.gate_sigma > 0):
            raise ValueError(f"gate_sigma must be > 0, got {self.gate_sigma}")
        if self.gate_memory < 4:
            raise ValueError(f"gate_memory must be >= 4, got {self.gate_memory}")


@dataclass(frozen=True)
class Estimate:
    """One identified parameter: where it belongs, value, standard deviation, and whether a bound holds it."""

    effect_id: str  # an effects.md id, or "airframe" for k_f_N_s2
    name: str
    value: float
    std: float
    at_bound: bool = False
    identifiable: bool = True  # False: the data could not tell its value from nothing; the value is held


@dataclass(frozen=True)
class RefitResult:
    """A batch least-squares fit of the window."""

    t: float  # [s] time of the refit (the newest sample's)
    estimates: tuple[Estimate, ...]
    n_samples: int
    rms_residual_N: float  # per axis, world force
    duration_s: float  # wall time the refit took


def _inverse(S: FloatArray) -> FloatArray:
    """Inverse of the small symmetric positive definite innovation covariance.

    The usual sample has three rows (x, y, z); its 3 x 3 inverse by cofactors in plain floats costs
    a fraction of numpy.linalg.inv's call overhead, which would dominate an RLS update.
    """
    if S.shape != (3, 3):
        return np.linalg.inv(S)
    (a, b, c), (_, e, f), (_, _, i) = S.tolist()
    A, B, C = e * i - f * f, c * f - b * i, b * f - c * e
    determinant = a * A + b * B + c * C
    if not determinant > 0:
        return np.linalg.inv(S)  # not positive definite: let numpy raise or do its best
    D, E, F = a * i - c * c, b * c - a * f, a * e - b * b
    return np.array([[A, B, C], [B, D, E], [C, E, F]]) / determinant


def _unit_covariance(A: FloatArray) -> FloatArray:
    """(AᵀA)⁻¹ computed on unit-norm columns: k_f (~1e-5) beside f_x (~1) would fool a plain pseudo-inverse.

    A column that is (numerically) absent gets an infinite variance, which the RLS prior bounds.
    """
    scale = np.linalg.norm(A, axis=0)
    present = scale > 0
    scaled = A[:, present] / scale[present]
    covariance = np.full((A.shape[1], A.shape[1]), 0.0)
    np.fill_diagonal(covariance, np.inf)
    inner = np.linalg.pinv(scaled.T @ scaled, rcond=1e-12, hermitian=True)
    index = np.flatnonzero(present)
    covariance[np.ix_(index, index)] = inner / np.outer(scale[present], scale[present])
    return covariance


def _at_bound(theta: FloatArray, bound: FloatArray) -> BoolArray:
    finite = np.isfinite(bound)
    return finite & (
        np.abs(theta - np.where(finite, bound, 0.0))
        <= 1e-9 * np.maximum(1.0, np.abs(np.where(finite, bound, 0.0)))
    )


# The fields of a sample that the window keeps: all of a StateBatch's, the measured acceleration included.
_STATE_FIELDS = ("t", "p_WB_W", "v_WB_W", "R_WB", "w_WB_B", "omega", "a_WB_W")


class _Window:
    """Rows of the last ``window_s``, in growable arrays (amortised O(1) append, O(1) trim).

    Each row holds a sample (the fields of a :class:`StateBatch`) and its regression rows y (3,),
    Φ (3, P), so a refit stacks what the RLS already computed instead of building the regressors again.
    """

    def __init__(self, n_rotors: int, n_parameters: int, window_s: float):
        self.window_s = window_s
        self._shapes: dict[str, tuple[int, ...]] = {
            "t": (),
            "p_WB_W": (3,),
            "v_WB_W": (3,),
            "R_WB": (3, 3),
            "w_WB_B": (3,),
            "omega": (n_rotors,),
            "a_WB_W": (3,),
            "y": (3,),
            "Phi": (3, n_parameters),
        }
        self._data = {name: np.empty((256, *shape)) for name, shape in self._shapes.items()}
        self._start = 0
        self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    @property
    def last_t(self) -> float | None:
        """Time of the newest row, None when empty."""
        return float(self._data["t"][self._end - 1]) if len(self) else None

    def extend(self, states: StateBatch, y: FloatArray, Phi: FloatArray) -> None:
        """Append states (times increasing, accelerations given) with their rows; trim to the window."""
        rows = {name: getattr(states, name) for name in _STATE_FIELDS} | {"y": y, "Phi": Phi}
        k = states.size
        while self._end + k > self._data["t"].shape[0]:
            self._compact(self._end + k - self._start)
        for name in self._shapes:
            self._data[name][self._end : self._end + k] = rows[name]
        self._end += k
        times = self._data["t"]
        cut = float(times[self._end - 1]) - self.window_s
        self._start += int(np.searchsorted(times[self._start : self._end], cut, side="left"))

    def _compact(self, needed: int) -> None:
        live = len(self)
        capacity = self._data["t"].shape[0]
        while capacity < 2 * needed:
            capacity *= 2
        for name, shape in self._shapes.items():
            grown = np.empty((capacity, *shape))
            grown[:live] = self._data[name][self._start : self._end]
            self._data[name] = grown
        self._start, self._end = 0, live

    def arrays(self) -> dict[str, FloatArray]:
        """Views of the rows in the window, oldest first."""
        return {name: self._data[name][self._start : self._end] for name in self._shapes}

    def states(self) -> StateBatch:
        """The samples in the window, oldest first."""
        data = self.arrays()
        return StateBatch(**{name: data[name] for name in _STATE_FIELDS})

    def clear(self) -> None:
        """Drop every row."""
        self._start = self._end = 0


class OnlineIdentifier:
    """Linear parameters of ``effect_ids`` (and k_f) from flight samples, as they come.

    The model is the airframe with its effect list replaced by ``effect_ids`` (as ``multirotor identify``
    does), each starting at the airframe's own values when it lists the effect, else at the effect's
    neutral values. Every sample updates the RLS estimate (:class:`RecursiveLeastSquares`) with the
    equation-error rows of :class:`multirotor_ros.ident.regressors.ForceRegressor`; :meth:`refit` solves
    the whole window by bounded least squares (the physical bounds of multirotor_ros.ident.parameters)
    and restarts the RLS from that solution, so that the running estimate never drifts far from the
    best fit of the window. Effects without a linear parameter (ground_effect, motor_lag,
    actuator_fault) cannot be fitted this way and are refused.
    """

    def __init__(
        self,
        airframe: Airframe,
        effect_ids: Sequence[str],
        settings: OnlineSettings | None = None,
        include_k_f: bool = True,
    ):
        self.settings = settings or OnlineSettings()
        self.airframe = airframe
        own = {spec["id"]: spec for spec in airframe.effect_specs()}
        specs = []
        for effect_id in effect_ids:
            cls = effect_class(effect_id)
            parameters = cls.parameter_list(airframe.n_rotors)
            if not any(p.linear for p in parameters):
                raise ValueError(
                    f"effect {effect_id!r} has no parameter that enters the force linearly "
                    f"({', '.join(p.name for p in parameters)}): the online identifier cannot fit it; "
                    "use `multirotor identify` on a log"
                )
            specs.append(own.get(effect_id, {"id": effect_id, **cls.neutral_parameters(airframe.n_rotors)}))
        self.effect_ids = tuple(effect_ids)
        self.base_model = Model(airframe, specs)
        self.refs = linear_refs(self.base_model, self.effect_ids, include_k_f)
        if not self.refs:
            raise ValueError("nothing to identify: give at least one effect or include k_f")
        self.regressor = ForceRegressor(self.base_model, self.refs)
        fitted = [FittedParameter.of(r, airframe) for r in self.refs]
        self.lower = np.array([f.lower for f in fitted])
        self.upper = np.array([f.upper for f in fitted])
        self.neutral = np.array([f.neutral for f in fitted])
        self.scale = np.array([f.scale for f in fitted])
        theta0 = np.array([parameter_value(self.base_model, r) for r in self.refs])
        # Prior: the configured value, uncertain by twice the larger of itself and the parameter's
        # "size that matters"; that also bounds how far noise can move a parameter the flight does not excite.
        prior_std = np.array([2.0 * max(f.scale, abs(v)) for f, v in zip(fitted, theta0, strict=True)])
        self.rls = RecursiveLeastSquares(
            [f"{e}.{n}" for e, n in self.refs], self.settings.forgetting, theta0, prior_std
        )
        # The last value of each parameter that a refit could tell (the configured one until then), and
        # whether the last refit could: a parameter the window cannot see is held at its trusted value.
        self.trusted = theta0.copy()
        self.identifiable = np.ones(len(self.refs), dtype=bool)
        self.window = _Window(airframe.n_rotors, len(self.refs), self.settings.window_s)
        self._pending: list[StateBatch] = []
        self._n_pending = 0
        self._last_t: float | None = None
        self.last_refit: RefitResult | None = None
        self._last_refit_t: float | None = None
        self.n_gated = 0  # samples dropped by the innovation gate (module docstring)
        self._innovations: deque[float] = deque(maxlen=self.settings.gate_memory)

    # ------------------------------------------------------------------ samples

    # Regressors are built for this many samples at once: one Model.wrench call costs about the same for
    # 1 or 10 samples, so batching divides the identifier's CPU load; the RLS still updates per sample.
    REGRESSOR_BATCH = 10
    # Median over mean of a chi-square with 3 degrees of freedom (x, y, z) divided by 3: the gate's
    # median noise level, scaled to the mean the gate_sigma threshold speaks of.
    MEDIAN_TO_MEAN = 1.0 / 0.7887

    def add(self, samples: StateBatch) -> None:
        """Queue measured samples of one vehicle (times increasing, ``a_WB_W`` measured, gravity excluded).

        They are folded in by batches of :attr:`REGRESSOR_BATCH`. Raises ValueError for samples not newer
        than the previous one, without an acceleration or not finite: the caller refuses those before (a
        node counts them), so reaching here is a programming error, not bad input.
        """
        self._check(samples)
        self._last_t = float(samples.t[-1])
        self._pending.append(samples)
        self._n_pending += samples.size
        if self._n_pending >= self.REGRESSOR_BATCH:
            self.flush()

    def _check(self, samples: StateBatch) -> None:
        if samples.a_WB_W is None:
            raise ValueError("samples for identification need their measured acceleration (a_WB_W)")
        if samples.omega.shape[1] != self.airframe.n_rotors:
            raise ValueError(
                f"samples have {samples.omega.shape[1]} rotor speeds, the airframe {self.airframe.n_rotors}"
            )
        t = samples.t
        if self._last_t is not None and t[0] <= self._last_t:
            raise ValueError(
                f"sample at t = {t[0]:.6f} s is not newer than the last one ({self._last_t:.6f} s)"
            )
        if np.any(np.diff(t) <= 0):
            raise ValueError(f"sample times from t = {t[0]:.6f} s do not strictly increase")
        values = [getattr(samples, name) for name in _STATE_FIELDS]
        if not all(np.all(np.isfinite(value)) for value in values):
            raise ValueError(f"samples from t = {t[0]:.6f} s hold non-finite values")

    def flush(self) -> None:
        """Fold the queued samples into the RLS (one update each) and the window."""
        if not self._pending:
            return
        samples = StateBatch.concatenate(self._pending)
        self._pending = []
        self._n_pending = 0
        y, Phi = self.regressor.from_states(samples)
        accepted = np.array([self._admit(y[k], Phi[k]) for k in range(samples.size)], dtype=bool)
        if accepted.any():
            self.window.extend(samples.select(accepted), y[accepted], Phi[accepted])

    def _admit(self, y: FloatArray, phi: FloatArray) -> bool:
        """Update the RLS with one sample if it passes the innovation gate (module docstring)."""
        with np.errstate(all="ignore"):
            residual = y - phi @ self.rls.theta
            innovation = float(residual @ residual) / residual.size
        if not math.isfinite(innovation):
            self.n_gated += 1
            return False
        self._innovations.append(innovation)
        if len(self._innovations) < self.settings.gate_memory // 4:
            return False
        level = self.MEDIAN_TO_MEAN * float(np.median(self._innovations))
        if innovation > self.settings.gate_sigma**2 * level:
            self.n_gated += 1
            return False
        self.rls.update(y, phi)
        return True

    def load_window(self, samples: StateBatch) -> None:
        """Fill the window with recorded samples (times increasing, accelerations given).

        For a resumed node: the RLS already holds these samples (its state was saved), so only the
        window learns them, for the next refit.
        """
        self.flush()
        if samples.size == 0:
            return
        self._check(samples)
        y, Phi = self.regressor.from_states(samples)
        self.window.extend(samples, y, Phi)
        self._last_t = float(samples.t[-1])

    @property
    def n_samples(self) -> int:
        """Samples folded in so far (queued ones not counted) since the start or the last :meth:`reset`."""
        return self.rls.n_updates

    def reset_window(self) -> None:
        """Forget the window (e.g. the clock went back): the RLS keeps what it learnt."""
        self._pending = []
        self._n_pending = 0
        self.window.clear()
        self._last_t = None

    def refit_due(self, t: float) -> bool:
        """Whether ``refit_period_s`` has passed since the last refit (or there has been none)."""
        return self._last_refit_t is None or t - self._last_refit_t >= self.settings.refit_period_s

    def refit(self) -> RefitResult | None:
        """Bounded least squares over the window; None (and no change) with too few samples."""
        started = time.perf_counter()
        self.flush()
        data = self.window.arrays()
        n = len(self.window)
        if n == 0:
            return None
        self._last_refit_t = float(data["t"][-1])
        if n < self.settings.min_refit_samples:
            return None
        if self.regressor.bilinear:
            # Rows linearised around an older estimate: rebuild them around the current one.
            self.regressor.relinearise(np.clip(self.rls.theta, self.lower, self.upper))
            y, Phi = self.regressor.from_states(self.window.states())
        else:
            y, Phi = data["y"], data["Phi"]
        A = Phi.reshape(-1, Phi.shape[2])
        b = y.reshape(-1)
        theta = solve_bounded(A, b, self.lower, self.upper)
        covariance_unit = _unit_covariance(A)
        sigma2, inflation = self._noise(b - A @ theta, A.shape[1])
        std = np.sqrt(np.maximum(np.diag(covariance_unit) * sigma2 * inflation, 0.0))
        # A parameter this window cannot tell from nothing keeps its trusted value; the others are
        # solved again with it held (parameters.py's identifiability rule).
        allowed = self.settings.fit_settings.identifiable_relative_std * np.maximum(
            np.abs(theta - self.neutral), self.scale
        )
        identifiable = std <= allowed
        if not identifiable.all():
            held = ~identifiable
            theta[held] = self.trusted[held]
            if identifiable.any():
                theta[identifiable] = solve_bounded(
                    A[:, identifiable],
                    b - A[:, held] @ theta[held],
                    self.lower[identifiable],
                    self.upper[identifiable],
                )
            sigma2, inflation = self._noise(b - A @ theta, int(identifiable.sum()))
        residual = b - A @ theta
        at_bound = _at_bound(theta, self.lower) | _at_bound(theta, self.upper)
        self.trusted[identifiable] = theta[identifiable]
        self.identifiable = identifiable
        # The RLS continues from the window's solution and uncertainty.
        self.rls.restart(theta, covariance_unit, sigma2)
        result = RefitResult(
            t=self._last_refit_t,
            estimates=tuple(
                Estimate(e, name, float(v), float(s_), bool(b_), bool(i))
                for (e, name), v, s_, b_, i in zip(self.refs, theta, std, at_bound, identifiable, strict=True)
            ),
            n_samples=n,
            rms_residual_N=float(np.sqrt(np.mean(residual**2))),
            duration_s=time.perf_counter() - started,
        )
        self.last_refit = result
        return result

    @staticmethod
    def _noise(residual: FloatArray, n_parameters: int) -> tuple[float, float]:
        """Residual variance and the variance inflation of its correlation in time.

        Rows come in threes (x, y, z of one sample); the lag-one autocorrelation ρ of each axis's
        residual gives the AR(1) inflation (1 + ρ)/(1 - ρ) of the parameter variance: samples of a
        smoothed or differentiated signal carry less information than their number says.
        """
        dof = max(residual.size - n_parameters, 1)
        sigma2 = float(residual @ residual) / dof
        per_axis = residual.reshape(-1, 3)
        if per_axis.shape[0] < 3:
            return sigma2, 1.0
        centred = per_axis - per_axis.mean(axis=0)
        denominator = float(np.sum(centred * centred)) or 1.0
        rho = float(np.sum(centred[1:] * centred[:-1])) / denominator
        rho = min(max(rho, 0.0), 0.99)
        return sigma2, (1.0 + rho) / (1.0 - rho)

    # ------------------------------------------------------------------ results

    def estimates(self) -> tuple[Estimate, ...]:
        """The running (RLS) estimates, clipped to their physical bounds (then marked ``at_bound``).

        A parameter the last refit could not tell from nothing is given at its trusted value (marked
        not ``identifiable``): between refits the RLS would let noise move it.
        """
        self.flush()
        theta = np.where(self.identifiable, self.rls.theta, self.trusted)
        clipped = np.clip(theta, self.lower, self.upper)
        return tuple(
            Estimate(e, name, float(c), float(s), bool(c != v), bool(i))
            for (e, name), v, c, s, i in zip(
                self.refs, theta, clipped, self.rls.std, self.identifiable, strict=True
            )
        )

    def state(self) -> dict[str, FloatArray]:
        """What a restarted identifier needs to go on: the RLS state, trusted values, identifiability."""
        state = {f"rls_{key}": value for key, value in self.rls.state().items()}
        state["trusted"] = self.trusted.copy()
        state["identifiable"] = self.identifiable.copy()
        return state

    def resume(self, state: Mapping[str, ArrayLike]) -> None:
        """Go on from :meth:`state` of an earlier run; :class:`RlsError` if it is of other parameters."""
        rls = RecursiveLeastSquares.from_state({k[4:]: v for k, v in state.items() if k.startswith("rls_")})
        if rls.parameter_names != self.rls.parameter_names:
            raise RlsError(
                f"it is of {', '.join(rls.parameter_names)}, "
                f"this identifier fits {', '.join(self.rls.parameter_names)}"
            )
        trusted = np.asarray(state.get("trusted", self.trusted), dtype=float)
        identifiable = np.asarray(state.get("identifiable", self.identifiable), dtype=bool)
        if trusted.shape != self.trusted.shape or identifiable.shape != self.identifiable.shape:
            raise RlsError("its trusted values do not match the parameter list")
        if not np.all(np.isfinite(trusted)):
            raise RlsError("its trusted values are not finite")
        self.rls = rls
        self.trusted = trusted.copy()
        self.identifiable = identifiable.copy()

    def model(self) -> Model:
        """The identified model: the base model with the current estimates (clipped to their bounds)."""
        values = {(e.effect_id, e.name): e.value for e in self.estimates()}
        return with_values(self.base_model, values)
