"""Fit effect parameters to a log: exact least squares where they enter linearly, searches for the rest.

The criterion is seed 1's mean square error (eq. 11) of the model's output, the world acceleration,
over the log's usable samples, in equation-error form m (a + g e_z) = F(theta) (:mod:`.regressors`).
The three axes are stacked and weighted by the inverse of their residual variance (a first unweighted
fit estimates it): an axis with noisy accelerations does not drown the others, as seed 1 fits per axis.

- Linear parameters (k_f, drag coefficients, k_h, k_f1, eta_lower, k_v, dm_kg, f_*, and the fault's
  effectiveness once its rotor and onset are fixed) are solved exactly, within their physical bounds
  (:mod:`.parameters`); the bilinear pair k_f x eta_lower by Gauss–Newton iterations of that solve.
- Non-linear parameters are searched with the linear ones solved inside each evaluation (variable
  projection): a continuous one (``rotor_radius_m``, ``tau_s``) over its effect's search grid, then
  bounded Brent refinement; an effect with a discrete parameter (``actuator_fault``'s rotor number) by an
  exhaustive search over rotor x onset sample (:class:`RotorOnsetSearch`), exact for the linear
  parameters through suffix sums, helped by the torque balance when the log allows it (a rotor that lost
  thrust unbalances the torques the most clearly); its factor on that rotor is then linear.
- Standard deviations: the sandwich (Newey–West) covariance with a bandwidth taken from the residuals'
  autocorrelation, because closed-loop flight residuals are not white; the white-noise formula would
  give smaller, overconfident values (the inflation is reported in the notes). Added in quadrature: the
  shift an accelerometer bias along body z would cause (:func:`bias_sensitivity`). That bias is constant
  over a log, so no resampling of the log's residuals sees it, and it is nearly collinear with the
  thrust, so it cannot be fitted; it moves k_f, a mass, a vertical force or a thrust factor by about
  bias/g (0.2 % for the 2 mg of seed 1's IMU), many times their noise standard deviation.
- A parameter whose standard deviation exceeds half of max(|value - neutral|, scale) is not identifiable
  on this log (:mod:`.parameters`; the thresholds are :class:`~multirotor_ros.ident.settings.FitSettings`):
  it is held (at its starting value), the others are refitted, and the reason is reported: nearly
  collinear with another parameter, or the regime that would excite it absent.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear, minimize_scalar

from multirotor_ros.ident.parameters import AIRFRAME, K_F, FittedParameter, ParameterRef, parameter_facts
from multirotor_ros.ident.regressors import (
    ForceRegressor,
    is_bilinear,
    is_regressed,
    parameter_value,
    with_values,
)
from multirotor_ros.ident.samples import FlightSamples, MeasurementChain, describe_range
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import EFFECTS, EffectContext, effect_class, formula_arguments
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray
from multirotor_ros.model.rotors import rotor_signatures

Progress = Callable[[str], None]


@dataclass(frozen=True)
class RotorOnsetSearch:
    """The parameters of an effect that acts on one rotor from an onset on, searched together.

    An effect with a discrete parameter (a rotor number) and an onset time is searched exhaustively over
    rotor x onset sample; its parameter that is linear once both are fixed is its factor on that rotor's
    thrust, which the search solves exactly through suffix sums.
    """

    rotor: ParameterRef
    onset: ParameterRef
    factor: ParameterRef

    @classmethod
    def of(cls, effect_id: str) -> RotorOnsetSearch | None:
        """The search for ``effect_id``, or None if it has no discrete parameter."""
        parameters = effect_class(effect_id).PARAMETERS
        rotors = [p.name for p in parameters if p.discrete]
        if not rotors:
            return None
        onsets = [p.name for p in parameters if p.onset_time]
        factors = [p.name for p in parameters if p.linear_given_others]
        if len(rotors) != 1 or len(onsets) != 1 or len(factors) != 1:
            raise ValueError(
                f"effect {effect_id!r}: a discrete parameter is searched as a rotor number, which needs one "
                "onset time and one conditionally linear factor beside it; it has "
                f"{', '.join(p.name for p in parameters)}"
            )
        return cls((effect_id, rotors[0]), (effect_id, onsets[0]), (effect_id, factors[0]))


def _is_rotor_time_constant(ref: ParameterRef) -> bool:
    """Whether the parameter sets the rotors' time constant (motor_lag's tau_s)."""
    formula = effect_class(ref[0]).formulas().get("rotor_time_constant_s") if ref[0] != AIRFRAME else None
    return formula is not None and ref[1] in formula_arguments(formula)


@dataclass
class Design:
    """y (T, 3), Phi (T, 3, P) over all rows of a log for one set of non-linear values (chained)."""

    y: FloatArray
    Phi: FloatArray
    regressor: ForceRegressor
    model: Model
    ctx: EffectContext


@dataclass
class FitResult:
    """A fitted model and what is known about its parameters."""

    model: Model
    free: list[ParameterRef]
    values: dict[ParameterRef, float]
    std: dict[ParameterRef, float | None]
    not_identifiable: dict[ParameterRef, str]
    residual: FloatArray  # (T, 3) measured - modelled acceleration [m/s^2]; NaN outside the fitted rows
    rows: BoolArray  # (T,) the samples fitted
    weights: FloatArray  # (3,) per-axis weights used
    notes: list[str] = field(default_factory=list)
    fault_candidates: list[tuple[int, float, float]] = field(default_factory=list)  # (motor, onset, score)

    def mse(self, rows: BoolArray | None = None) -> FloatArray:
        """(3,) mean square acceleration error per axis over ``rows`` (default: the fitted ones)."""
        use = self.rows if rows is None else rows
        return np.mean(self.residual[use] ** 2, axis=0)

    def named_values(self) -> dict[str, float]:
        """Fitted values by parameter name (effects.md names; k_f as ``k_f_N_s2``)."""
        return {name: value for (_, name), value in self.values.items()}


# ----------------------------------------------------------------------------------------------
# designs and linear solves


def _model_key(model: Model, skip: Sequence[ParameterRef]) -> tuple:
    """Hashable identity of a model's structure and parameter values, without the ``skip`` ones."""
    skipped = set(skip)
    values: list[object] = [model.airframe.name, model.gravity_m_s2]
    if (AIRFRAME, K_F) not in skipped:
        values.append(model.airframe.k_f_N_s2)
    for effect in model.effects:
        values.append(effect.id)
        values += [
            (name, float(v)) for name, v in effect.parameters.items() if (effect.id, name) not in skipped
        ]
    return tuple(values)


def build_design(samples: FlightSamples, model: Model, linear: Sequence[ParameterRef]) -> Design:
    """The chained regression of ``linear`` parameters for ``model`` over every row of ``samples``.

    Designs are cached on the samples: a search revisits grid values, cross-validation folds share
    their designs, and a linear parameter's value does not change its design (y = Phi theta holds for any).
    """
    key = (_model_key(model, () if is_bilinear(linear) else linear), tuple(linear))
    cache = samples.design_cache
    if key in cache:
        return cache[key]
    regressor = ForceRegressor(model, linear)
    ctx = samples.model_context(model)
    s, F0, dF = regressor.parts(ctx, samples.a_W)
    if samples.chain.order > 0:
        F0 = samples.through_chain(F0)
        dF = samples.through_chain(dF)
    y, Phi = regressor.assemble(s, F0, dF)
    if samples.nuisance is not None:
        y, Phi = _without_nuisance(samples, samples.nuisance, y, Phi)
    design = Design(y, Phi, regressor, model, ctx)
    if len(cache) >= samples.settings.design_cache_size:
        cache.pop(next(iter(cache)))
    cache[key] = design
    return design


def _without_nuisance(
    samples: FlightSamples, nuisance: FloatArray, y: FloatArray, Phi: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The y and Phi minus their least-squares projection on the nuisance columns (Frisch-Waugh-Lovell).

    Fitting theta to the projected problem gives the same theta and residual as fitting theta together with
    the nuisance parameters, so every later step (bounds, searches, covariance) need not know about them.
    """
    return _project_out(samples, nuisance, y), _project_out(samples, nuisance, Phi)


def _project_out(samples: FlightSamples, nuisance: FloatArray, values: FloatArray) -> FloatArray:
    """``values`` (T, 3, ...) minus their least-squares projection on the nuisance columns (T, 3, K)."""
    key = ("nuisance basis",)
    if key not in samples.design_cache:
        # Zero outside the usable rows, so that projecting every row leaves the unusable ones as they are.
        masked = np.where(samples.valid[:, None, None], nuisance, 0.0)
        samples.design_cache[key] = np.linalg.qr(masked.reshape(-1, masked.shape[2]))[0]
    q = samples.design_cache[key]
    flat = values.reshape(q.shape[0], -1)
    # Unusable rows may hold NaN (filter ends); their basis rows are zero, so they stay as they are.
    return (flat - q @ (q.T @ np.nan_to_num(flat))).reshape(values.shape)


def nuisance_estimate(samples: FlightSamples, residual_before_projection: FloatArray) -> FloatArray:
    """Least-squares nuisance parameters explaining a (force) residual over the usable rows."""
    N = samples.nuisance
    if N is None:
        return np.zeros(0)
    rows = samples.valid
    return np.linalg.lstsq(
        N[rows].reshape(-1, N.shape[2]), residual_before_projection[rows].reshape(-1), rcond=None
    )[0]


def _weighted_system(design: Design, rows: BoolArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    sw = np.sqrt(weights)
    y = design.y[rows] * sw[None, :]
    A = (design.Phi[rows] * sw[None, :, None]).reshape(y.size, design.Phi.shape[2])
    b = y.reshape(-1)
    return A, b


def solve_bounded(A: FloatArray, b: FloatArray, lower: FloatArray, upper: FloatArray) -> FloatArray:
    """Argmin |A theta - b| within bounds; columns are scaled first (k_f ~ 1e-5 beside f_x ~ 1).

    Normal equations on the scaled columns (a few parameters, well scaled: their condition number squared
    stays far from double precision's limit); a bound that the free solution crosses is enforced by BVLS
    on the Cholesky factor, which has the same minimiser.
    """
    n_par = A.shape[1]
    if n_par == 0:
        return np.zeros(0)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    G = As.T @ As
    h = As.T @ b
    try:
        L = np.linalg.cholesky(G)
        theta_s = np.linalg.solve(L.T, np.linalg.solve(L, h))
        R, c = L.T, np.linalg.solve(L, h)
    except np.linalg.LinAlgError:
        theta_s = np.linalg.lstsq(As, b, rcond=1e-10)[0]
        Q, R = np.linalg.qr(As)
        c = Q.T @ b
    theta = theta_s / scale
    if np.all(theta >= lower) and np.all(theta <= upper):
        return theta
    lo = np.where(np.isfinite(lower), lower * scale, -np.inf)
    hi = np.where(np.isfinite(upper), upper * scale, np.inf)
    result = lsq_linear(R, c, bounds=(lo, hi), method="bvls" if n_par <= 10 else "trf")
    # Unscaling can put a value at a bound a rounding error outside it, where an effect refuses it.
    return np.clip(result.x / scale, lower, upper)


class LinearSolver:
    """Solves the linear parameters of designs on a set of rows, with bounds and per-axis weights."""

    def __init__(self, refs: Sequence[ParameterRef], airframe: Airframe, held: dict[ParameterRef, float]):
        self.refs = list(refs)
        fitted = [FittedParameter.of(r, airframe) for r in self.refs]
        self.lower = np.array([f.lower for f in fitted])
        self.upper = np.array([f.upper for f in fitted])
        self.held = held

    def solve(self, design: Design, rows: BoolArray, weights: FloatArray) -> FloatArray:
        """Fitted theta for the design's parameter list (held ones fixed)."""
        free = [j for j, r in enumerate(self.refs) if r not in self.held]
        theta = design.regressor.theta0.copy()
        for j, r in enumerate(self.refs):
            if r in self.held:
                theta[j] = self.held[r]
        A, b = _weighted_system(design, rows, weights)
        fixed = [j for j in range(len(self.refs)) if j not in free]
        if fixed:
            b = b - A[:, fixed] @ theta[fixed]
        theta[free] = solve_bounded(A[:, free], b, self.lower[free], self.upper[free])
        return theta


def residual_force(design: Design, theta: FloatArray) -> FloatArray:
    """(T, 3) y - Phi theta [N]."""
    return design.y - design.Phi @ theta


def sse(design: Design, theta: FloatArray, rows: BoolArray, weights: FloatArray) -> float:
    """Weighted sum of squared force residuals over ``rows``."""
    r = residual_force(design, theta)[rows]
    return float(np.sum(r * r * weights[None, :]))


# ----------------------------------------------------------------------------------------------
# the fitter


class Fitter:
    """Fits ``free`` parameters of ``model`` to ``samples`` (see the module docstring)."""

    def __init__(
        self,
        samples: FlightSamples,
        model: Model,
        free: Sequence[ParameterRef],
        rows: BoolArray | None = None,
        weights: FloatArray | None = None,
        progress: Progress | None = None,
        held: dict[ParameterRef, float] | None = None,
    ):
        self.samples = samples
        self.start_model = model
        # Lists (from YAML or JSON) become tuples: refs are compared and used as keys.
        self.free: list[ParameterRef] = [(effect_id, name) for effect_id, name in free]
        for ref in self.free:
            parameter_value(model, ref)  # names the missing effect or parameter
        self.rows = samples.valid.copy() if rows is None else (samples.valid & rows)
        self.progress = progress
        self.held: dict[ParameterRef, float] = dict(held or {})
        self.linear = [r for r in self.free if is_regressed(r)]
        self.searched = [r for r in self.free if not is_regressed(r)]
        searched_effects = dict.fromkeys(effect_id for effect_id, _ in self.searched)
        self.rotor_onset_searches = [
            search
            for effect_id in searched_effects
            if (search := RotorOnsetSearch.of(effect_id)) is not None and search.rotor in self.searched
        ]
        # Continuous searches in registry order, so that the order of the effects asked for changes nothing.
        registry_order = list(EFFECTS)
        self.scalar_searches = sorted(
            (r for r in self.searched if parameter_facts(r).search_grid),
            key=lambda r: registry_order.index(r[0]),
        )
        covered = {r for search in self.rotor_onset_searches for r in (search.rotor, search.onset)}
        unsearchable = [r for r in self.searched if r not in covered and r not in self.scalar_searches]
        if unsearchable:
            raise ValueError(
                f"{', '.join(f'{e}.{n}' for e, n in unsearchable)}: neither linear nor searchable on its own "
                "(free it with the rest of its effect)"
            )
        self.solver = LinearSolver(self.linear, model.airframe, self.held)
        self.weights = np.ones(3) if weights is None else np.asarray(weights, dtype=float)
        self._given_weights = weights is not None
        self.fault_candidates: list[tuple[int, float, float]] = []
        self.fault_profile: FloatArray | None = None  # (T,) score of each onset on the rotor found

    def _say(self, message: str) -> None:
        if self.progress is not None:
            self.progress(message)

    # -- linear part --------------------------------------------------------------------------

    def solve_linear(self, model: Model, rows: BoolArray | None = None) -> tuple[Design, FloatArray, float]:
        """Design and fitted linear parameters for the non-linear values in ``model``."""
        use = self.rows if rows is None else rows
        design = build_design(self.samples, model, self.linear)
        theta = self.solver.solve(design, use, self.weights)
        if design.regressor.bilinear:
            for _ in range(30):
                previous = theta
                model = with_values(model, dict(zip(self.linear, theta.tolist(), strict=True)))
                design = build_design(self.samples, model, self.linear)
                theta = self.solver.solve(design, use, self.weights)
                if np.allclose(theta, previous, rtol=1e-9, atol=0.0):
                    break
        return design, theta, sse(design, theta, use, self.weights)

    def estimate_weights(self, model: Model) -> None:
        """Per-axis weights 1/variance from an unweighted fit of ``model`` (normalised to mean 1)."""
        if self._given_weights:
            return
        self.weights = np.ones(3)
        design, theta, _ = self.solve_linear(model)
        variance = np.mean(residual_force(design, theta)[self.rows] ** 2, axis=0)
        variance = np.maximum(variance, 1e-12 * max(variance.max(), 1e-300))
        w = 1.0 / variance
        self.weights = w / w.mean()

    # -- searches ------------------------------------------------------------------------------

    def _scalar_search(self, model: Model, ref: ParameterRef, local: bool = False) -> Model:
        """Grid then bounded Brent search of one continuous non-linear parameter (linear ones inside)."""
        if ref in self.held:
            return with_values(model, {ref: self.held[ref]})
        label = f"{ref[0]}.{ref[1]}"

        def cost(value: float) -> float:
            return self.solve_linear(with_values(model, {ref: value}))[2]

        facts = parameter_facts(ref)
        grid = np.asarray(facts.search_grid, dtype=float)
        if _is_rotor_time_constant(ref):
            # A lag shorter than half a sample interval cannot be told from smoothing the speed sensor's noise
            # (which also lowers the error): the search starts there.
            grid = np.geomspace(max(grid[0], 0.5 * self.samples.dt), grid[-1], grid.size)
        values = [facts.start, *grid.tolist()]
        if local:
            start = parameter_value(model, ref)
            if start > 2 * facts.start:
                values = [facts.start, *np.geomspace(max(start / 2, grid[0]), start * 2, 5).tolist()]
        costs = []
        for i, value in enumerate(values):
            costs.append(cost(value))
            if i % 5 == 4:
                self._say(f"{label}: grid {i + 1}/{len(values)}")
        best = int(np.argmin(costs))
        if best == 0:
            return with_values(model, {ref: values[0]})
        # Between the neighbours of the best grid value, never below the first grid value (see above).
        lo = math.log(values[max(best - 1, 1)])
        hi = math.log(values[min(best + 1, len(values) - 1)])
        result = minimize_scalar(
            lambda x: cost(math.exp(x)),
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 2e-3, "maxiter": 14},
        )
        value = math.exp(result.x) if result.fun <= costs[best] else values[best]
        self._say(f"{label} = {value:.4g}")
        return with_values(model, {ref: value})

    def _rotor_onset_search(self, model: Model, search: RotorOnsetSearch) -> Model:
        """Exhaustive rotor x onset search (:class:`RotorOnsetSearch`, module docstring)."""
        if search.rotor in self.held:
            return model
        samples = self.samples
        healthy = with_values(model, {search.factor: parameter_facts(search.factor).neutral})
        others = [r for r in self.linear if r != search.factor]
        design = build_design(samples, healthy, others)
        solver = LinearSolver(others, healthy.airframe, self.held)
        theta = solver.solve(design, self.rows, self.weights)
        healthy = with_values(healthy, dict(zip(others, theta.tolist(), strict=True)))
        design = build_design(samples, healthy, others)
        rows = self.rows
        n_rows = int(np.count_nonzero(rows))
        thrust, drag_torque = healthy.rotor_loads(design.ctx)
        e_z = design.ctx.e_z_W
        airframe = healthy.airframe
        # Per-rotor columns of delta = 1 - effectiveness: the lost thrust and the lost rotor torque.
        force_cols = -thrust[:, :, None] * e_z[:, None, :]  # (T, N, 3)
        torque_cols = -rotor_signatures(airframe, thrust, drag_torque)[:, 1:, :].swapaxes(1, 2)  # (T, N, 3)
        if samples.chain.order > 0:
            force_cols = samples.through_chain(force_cols)
        sw = np.sqrt(self.weights)
        Y = np.where(rows[:, None], design.y * sw, 0.0)
        Phi = np.where(rows[:, None, None], design.Phi * sw[None, :, None], 0.0)
        C = np.where(rows[:, None, None], force_cols * sw[None, None, :], 0.0)
        P = Phi.shape[2]
        A = Phi.reshape(Y.size, P)
        G = A.T @ A
        G_inv = np.linalg.pinv(G) if P else np.zeros((0, 0))
        r0 = Y - Phi @ (G_inv @ (A.T @ Y.reshape(-1))) if P else Y
        noise = max(float(np.mean(r0[rows] ** 2)), 1e-300)
        rot = self._torque_residual(healthy, design.ctx)
        eligible = rows.copy()
        after = np.cumsum(rows[::-1])[::-1]
        eligible &= after * samples.dt >= samples.settings.min_fault_duration_s
        best_score = np.zeros(airframe.n_rotors)
        best_index = np.zeros(airframe.n_rotors, dtype=int)
        profiles = []
        for m in range(airframe.n_rotors):
            c = C[:, m, :]
            R_k = _suffix(np.sum(c * r0, axis=1))
            H_k = _suffix(np.sum(c * c, axis=1))
            if P:
                g_k = _suffix(np.einsum("tap,ta->tp", Phi, c))
                H_k = H_k - np.einsum("tp,pq,tq->t", g_k, G_inv, g_k)
            H_k = np.maximum(H_k, 1e-300)
            delta = R_k / H_k
            score = np.where(delta > 0, np.where(delta <= 1, R_k**2 / H_k, 2 * R_k - H_k), 0.0) / noise
            if rot is not None:
                residual_tau, scale_tau = rot
                ct = torque_cols[:, m, :] / scale_tau
                ct = np.where(rows[:, None], ct, 0.0)
                Rt = _suffix(np.sum(ct * residual_tau, axis=1))
                Ht = np.maximum(_suffix(np.sum(ct * ct, axis=1)), 1e-300)
                dt_ = Rt / Ht
                score = score + np.where(dt_ > 0, np.where(dt_ <= 1, Rt**2 / Ht, 2 * Rt - Ht), 0.0)
            score = np.where(eligible, score, -np.inf)
            profiles.append(score)
            best_index[m] = int(np.argmax(score))
            best_score[m] = score[best_index[m]]
        motor = int(np.argmax(best_score))
        k = best_index[motor]
        ranking = np.argsort(best_score)[::-1]
        self.fault_candidates = [
            (int(m) + 1, float(samples.t[best_index[m]]), float(best_score[m])) for m in ranking[:3]
        ]
        self.fault_profile = profiles[motor]
        self._say(
            f"{search.rotor[0]}: rotor {motor + 1} from t = {samples.t[k]:.2f} s (searched "
            f"{airframe.n_rotors} rotors x {int(np.count_nonzero(eligible))} onsets over {n_rows} samples)"
        )
        return with_values(model, {search.rotor: motor + 1.0, search.onset: float(samples.t[k])})

    def _torque_residual(self, model: Model, ctx: EffectContext) -> tuple[FloatArray, FloatArray] | None:
        """The torque balance residual (:func:`torque_residual`) scaled per axis, zero off the fitted rows."""
        rows = self.rows & np.all(np.isfinite(self.samples.w_dot_B), axis=1)
        if np.count_nonzero(rows) < 20:
            return None
        residual = torque_residual(self.samples, model)
        median = np.median(residual[rows], axis=0)
        scale = 1.4826 * np.median(np.abs(residual[rows] - median), axis=0)
        scale = np.maximum(scale, 1e-9)
        return np.where(rows[:, None], residual / scale, 0.0), scale

    def _refine_onset(self, model: Model, search: RotorOnsetSearch) -> Model:
        """Exact designs around the onset found by the search (the filter blurs a step by its window)."""
        samples = self.samples
        onset = parameter_value(model, search.onset)
        k = int(np.searchsorted(samples.t, onset))
        reach = max(samples.chain.half_window + 2, 3)
        best = (self.solve_linear(model)[2], onset)
        for j in range(max(k - reach, 0), min(k + reach + 1, samples.t.size)):
            candidate = float(samples.t[j])
            if candidate == onset:
                continue
            cost = self.solve_linear(with_values(model, {search.onset: candidate}))[2]
            if cost < best[0]:
                best = (cost, candidate)
        return with_values(model, {search.onset: best[1]})

    # -- the whole fit -------------------------------------------------------------------------

    def run(self, refine: bool = True, local: bool = False) -> Model:
        """The model with every free parameter fitted (held ones at their held values).

        ``local``: search the continuous non-linear parameters only near their starting values (a factor
        of 2 either way), for refits that start from a fit of the same log (cross-validation folds).
        """
        model = with_values(self.start_model, {r: v for r, v in self.held.items()})
        self.estimate_weights(model)
        n_searches = len(self.rotor_onset_searches) + len(self.scalar_searches)
        for _ in range(2 if n_searches > 1 else 1):
            for search in self.rotor_onset_searches:
                model = self._rotor_onset_search(model, search)
                if refine and samples_blur(self.samples):
                    model = self._refine_onset(model, search)
            for ref in self.scalar_searches:
                model = self._scalar_search(model, ref, local)
        design, theta, _ = self.solve_linear(model)
        return with_values(model, dict(zip(self.linear, theta.tolist(), strict=True)))


def samples_blur(samples: FlightSamples) -> bool:
    """Whether the log's acceleration was filtered (a step in force then spreads over the filter window)."""
    return samples.chain.order > 0


def _suffix(values: FloatArray) -> FloatArray:
    """Sum from each index to the end along axis 0."""
    return np.cumsum(values[::-1], axis=0)[::-1]


# ----------------------------------------------------------------------------------------------
# covariance and identifiability


def newey_west(
    X: FloatArray, residual: FloatArray, weights: FloatArray
) -> tuple[FloatArray, FloatArray, int]:
    """Sandwich covariance of theta for y = X theta + e over time-ordered rows.

    X (n, 3, P) and residual (n, 3), weighted per axis. Returns (covariance, white-noise covariance,
    bandwidth in samples). The bandwidth is where the residual's autocorrelation falls below 0.1 (at least
    the Newey–West rule 4 (n/100)^(2/9)), capped at n/4.
    """
    n, _, P = X.shape
    sw = np.sqrt(weights)
    Xw = X * sw[None, :, None]
    ew = residual * sw[None, :]
    A = Xw.reshape(-1, P)
    bread = np.linalg.pinv(A.T @ A)
    dof = max(A.shape[0] - P, 1)
    white = bread * float(np.sum(ew**2)) / dof
    scores = np.einsum("tap,ta->tp", Xw, ew)
    e = ew.sum(axis=1)
    e = e - e.mean()
    denominator = float(e @ e) or 1.0
    rule = int(math.ceil(4 * (n / 100) ** (2 / 9)))
    max_lag = max(1, min(n // 4, 400))
    bandwidth = max_lag
    for lag in range(1, max_lag + 1):
        if float(e[lag:] @ e[:-lag]) / denominator < 0.1:
            bandwidth = lag
            break
    bandwidth = min(max(bandwidth * 2, rule), max(n // 4, 1))
    # Bartlett weights 1 - lag/(L+1) are what the covariance of sums of L+1 consecutive scores gives:
    # one product instead of one per lag (the ends, L samples out of n, are left out and rescaled).
    span = bandwidth + 1
    if n > 2 * span:
        cumulative = np.vstack([np.zeros((1, P)), np.cumsum(scores, axis=0)])
        sums = cumulative[span:] - cumulative[:-span]
        meat = (sums.T @ sums) / span * (n / sums.shape[0])
    else:
        meat = scores.T @ scores
        for lag in range(1, bandwidth + 1):
            gamma = scores[lag:].T @ scores[:-lag]
            meat += (1.0 - lag / (bandwidth + 1)) * (gamma + gamma.T)
    meat *= n / max(n - P, 1)
    return bread @ meat @ bread, white, bandwidth


def excitation_evidence(ref: ParameterRef, samples: FlightSamples, model: Model, rows: BoolArray) -> str:
    """What this log shows of the regime that makes ``ref`` visible, in words."""
    effect = model.effect(ref[0])
    if effect is None:
        return f"{np.count_nonzero(rows)} usable samples"
    why_not = effect.not_applicable(model.airframe)
    if why_not is not None:
        return why_not
    if "height" in effect.log_needs and not samples.height_known:
        return "the log has no measured height"
    what, values, unit = effect.excitation(ref[1], samples.states(rows), model.airframe)
    return f"{what} is {describe_range(values, unit)}"


@dataclass
class Uncertainty:
    """Standard deviations and identifiability verdicts of a fit."""

    std: dict[ParameterRef, float | None]
    not_identifiable: dict[ParameterRef, str]
    worst: ParameterRef | None
    notes: list[str]


def assess(fitter: Fitter, model: Model) -> tuple[Uncertainty, FloatArray]:
    """Covariance of the continuous free parameters of a fitted ``model`` and the identifiability verdicts.

    Also returns the force residual (T, 3) [N] at the fitted values. In stages: the residual at the fit,
    each continuous parameter's column, the standard deviations of the free ones, the verdicts.
    """
    design, theta, residual = _residual_at_fit(fitter, model)
    sensitivity = _sensitivity(fitter, model, design, theta)
    std: dict[ParameterRef, float | None] = {ref: None for ref in fitter.free}
    notes: list[str] = []
    not_identifiable: dict[ParameterRef, str] = {}
    worst: ParameterRef | None = None
    free = [j for j, ref in enumerate(sensitivity.refs) if ref not in fitter.held]
    if free:
        refs = [sensitivity.refs[j] for j in free]
        X = sensitivity.columns[fitter.rows][:, :, free]
        systematic = np.hypot(bias_sensitivity(fitter, model, X), command_timing_std(fitter.samples, refs))
        sd, covariance_note = _standard_deviations(
            X, residual[fitter.rows], fitter.weights, fitter.samples.dt, systematic
        )
        std.update(zip(refs, sd.tolist(), strict=True))
        notes.append(covariance_note)
        notes += [
            f"{ref[1]}: the best fit is no {ref[0]}; its std is the resolution the log would give near "
            f"{value:g}"
            for ref, value in sensitivity.probes.items()
        ]
        not_identifiable, worst = _identifiability(fitter, model, refs, X, sd, sensitivity.probes, residual)
    for ref in fitter.held:
        std[ref] = None
    return Uncertainty(std, not_identifiable, worst, notes), residual


def _residual_at_fit(fitter: Fitter, model: Model) -> tuple[Design, FloatArray, FloatArray]:
    """The design of the fitted ``model``, the values of its linear parameters and the force residual [N]."""
    design = build_design(fitter.samples, model, fitter.linear)
    theta = np.array([parameter_value(model, ref) for ref in fitter.linear])
    return design, theta, residual_force(design, theta)


@dataclass
class _Sensitivity:
    """How the modelled force moves with each continuous parameter at a fit: one column per parameter."""

    columns: FloatArray  # (T, 3, P) d(force)/d(parameter) [N per unit of the parameter]
    refs: list[ParameterRef]  # the P parameters: the linear ones, then the searched continuous ones
    # Searched parameters fitted at "no effect": their columns are taken at this typical value instead.
    probes: dict[ParameterRef, float]


def _sensitivity(fitter: Fitter, model: Model, design: Design, theta: FloatArray) -> _Sensitivity:
    """The design's columns and, by central differences, those of the searched continuous parameters."""
    samples = fitter.samples
    columns = [design.Phi]
    refs = list(fitter.linear)
    probes: dict[ParameterRef, float] = {}
    for ref in fitter.scalar_searches:
        if ref in fitter.held:
            continue
        value = parameter_value(model, ref)
        if value <= 2 * parameter_facts(ref).start:
            # At "no effect" the force does not change to first order (the ground factor is quadratic in
            # the radius): whether the log could show the effect is judged at a typical value instead.
            value = FittedParameter.of(ref, model.airframe).scale
            probes[ref] = value
        step = max(1e-4, 1e-3 * value)
        lo, hi = max(value - step, 1e-6), value + step
        r_hi = residual_force(build_design(samples, with_values(model, {ref: hi}), fitter.linear), theta)
        r_lo = residual_force(build_design(samples, with_values(model, {ref: lo}), fitter.linear), theta)
        # The prediction's derivative is minus the residual's.
        columns.append(((r_lo - r_hi) / (hi - lo))[:, :, None])
        refs.append(ref)
    return _Sensitivity(np.concatenate(columns, axis=2), refs, probes)


def _standard_deviations(
    X: FloatArray, residual: FloatArray, weights: FloatArray, dt: float, systematic: FloatArray
) -> tuple[FloatArray, str]:
    """Standard deviations of the parameters of the columns X (n, 3, P), and a note on them.

    Newey-West for the noise, and in quadrature ``systematic`` (P,): what the log's errors that are
    constant over it (an accelerometer bias, the timing of the rotor commands) leave uncertain, which
    no resampling of the residuals can see (:func:`bias_sensitivity`, :func:`command_timing_std`).
    """
    covariance, white, bandwidth = newey_west(X, residual, weights)
    sd_noise = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    sd = np.hypot(sd_noise, systematic)
    sd_white = np.sqrt(np.maximum(np.diag(white), 0.0))
    inflation = float(np.median(sd_noise / np.maximum(sd_white, 1e-300)))
    note = (
        f"standard deviations: Newey-West (bandwidth {bandwidth} samples = {bandwidth * dt:.3g} s) for "
        f"autocorrelated residuals; the white-noise formula gives {inflation:.2g} times smaller values"
    )
    if np.any(systematic > 0):
        share = float(np.median(systematic / np.maximum(sd, 1e-300)))
        note += (
            "; with, in quadrature, the accelerometer's bias along the thrust (body z), which no fit can "
            "tell from a thrust or mass change, and for a rotor time constant the timing of the logged "
            f"commands (median share of the std {share:.2g})"
        )
    return sd, note


def command_timing_std(samples: FlightSamples, refs: Sequence[ParameterRef]) -> FloatArray:
    """(P,) For a rotor time constant: the uncertainty of the logged commands' timing, 0 for the rest.

    With motor_lag the log's rotor speeds are the commands the ESCs were given, samples of a staircase
    that steps every command period at times the log does not show: the command in force may have been
    set up to a period before or after the logged value suggests. A delay of the thrust is, to first
    order, a change of the time constant by as much, so the time constant is known no better than that
    timing: the standard deviation of a uniform offset over one command period, period / sqrt(12).
    """
    timing_std_s = samples.rotor_command_period_s / math.sqrt(12.0)
    return np.array([timing_std_s if _is_rotor_time_constant(ref) else 0.0 for ref in refs])


def bias_sensitivity(fitter: Fitter, model: Model, X: FloatArray) -> FloatArray:
    """(P,) How far one standard deviation of accelerometer bias the fit does not model moves each parameter.

    A bias b along body axis j adds m R_WB e_j b to the measured force m (a_W + g e_z). Along body z it is
    nearly collinear with the thrust, so it is not fitted (FlightSamples.unfitted_bias_axes): the
    least-squares parameters of the columns X (n, 3, P) on the fitted rows move by (A^T A)^-1 A^T (m R e_j)
    b (weighted as the fit, with the fitted nuisance projected out as in the fit). The bias is a draw of
    the IMU (std ``accelerometer_bias_std_m_s2``), independent per axis: the shifts add in quadrature.
    """
    samples = fitter.samples
    axes = samples.unfitted_bias_axes()
    n_parameters = X.shape[2]
    if not axes or n_parameters == 0:
        return np.zeros(n_parameters)
    columns = float(np.asarray(model.mass_kg)) * samples.R_WB[:, :, axes]
    if samples.nuisance is not None:
        columns = _project_out(samples, samples.nuisance, columns)
    sw = np.sqrt(fitter.weights)[None, :, None]
    A = (X * sw).reshape(-1, n_parameters)
    B = (columns[fitter.rows] * sw).reshape(-1, len(axes))
    shift = np.linalg.lstsq(A, B, rcond=None)[0]  # (P, axes): parameter change per m/s^2 of bias
    return samples.accelerometer_bias_std_m_s2 * np.sqrt(np.sum(shift**2, axis=1))


def _identifiability(
    fitter: Fitter,
    model: Model,
    refs: list[ParameterRef],
    X: FloatArray,
    sd: FloatArray,
    probes: dict[ParameterRef, float],
    residual: FloatArray,
) -> tuple[dict[ParameterRef, str], ParameterRef | None]:
    """The free parameters ``refs`` this log cannot identify, why, and the one to hold first (or None).

    A parameter is not identifiable when its column is one with another's, when its std exceeds
    ``identifiable_relative_std`` of max(|value - neutral|, scale) (at the probe value, if probed), or
    when the log does not move it at all.
    """
    samples = fitter.samples
    settings = samples.settings
    A = (X * np.sqrt(fitter.weights)[None, :, None]).reshape(-1, len(refs))
    norms = np.linalg.norm(A, axis=0)
    norms[norms == 0] = 1.0
    corr = (A / norms).T @ (A / norms)
    fitted = [FittedParameter.of(ref, model.airframe) for ref in refs]
    allowed = [
        settings.identifiable_relative_std
        * max(abs(probes.get(ref, parameter_value(model, ref)) - facts.neutral), facts.scale)
        for ref, facts in zip(refs, fitted, strict=True)
    ]
    ratios = [float(s) / a if a > 0 else math.inf for s, a in zip(sd, allowed, strict=True)]
    collinear = _exactly_collinear(refs, corr, ratios, settings.exactly_collinear)
    residual_rms = float(np.sqrt(np.mean(np.sum(residual[fitter.rows] ** 2, axis=1)))) / float(
        np.asarray(model.mass_kg)
    )
    not_identifiable: dict[ParameterRef, str] = {}
    worst: tuple[tuple[int, int, float], ParameterRef] | None = None
    for i, ref in enumerate(refs):
        unmoved = norms[i] == 1.0 and np.allclose(A[:, i], 0)
        if i not in collinear and sd[i] <= allowed[i] and not unmoved:
            continue
        partner: ParameterRef | None
        if i in collinear:
            correlation, partner = collinear[i][1], refs[collinear[i][0]]
        else:
            others = [(abs(corr[i, j]), refs[j]) for j in range(len(refs)) if j != i]
            correlation, partner = max(others, default=(0.0, None))
        if partner is not None and correlation >= settings.collinear_correlation:
            why = (
                f"nearly collinear with {partner[1]} (correlation {correlation:.5f}): this log determines "
                "only a combination of the two"
            )
        else:
            why = (
                "too little excitation for the noise and unexplained error of this log "
                f"({residual_rms:.2g} m/s^2 RMS): it shows in {fitted[i].facts.excited_by}, and "
                f"{excitation_evidence(ref, samples, model, fitter.rows)}"
            )
        not_identifiable[ref] = (
            f"{ref[1]} is not identifiable ({why})"
            if i in collinear
            else f"{ref[1]} = {parameter_value(model, ref):.4g} +/- {sd[i]:.2g} is not identifiable ({why}); "
            f"the std must stay below {allowed[i]:.2g} to tell a relevant value from none"
        )
        # Exact collinearity first, and k_f (the airframe's own, known value) before an effect's parameter.
        key = (2 if i in collinear else 1, 1 if ref == (AIRFRAME, K_F) else 0, ratios[i])
        if worst is None or key > worst[0]:
            worst = (key, ref)
    return not_identifiable, None if worst is None else worst[1]


def _exactly_collinear(
    refs: list[ParameterRef], corr: FloatArray, ratios: list[float], threshold: float
) -> dict[int, tuple[int, float]]:
    """The parameters whose column is one with another's: index -> (the other's index, |correlation|).

    Columns this close are one column: the data give only a combination, and noise in the inputs (errors
    in variables) makes the std of each meaningless, so the verdict does not wait for the std. Of a pair,
    k_f is the one named (the airframe's own, known value), otherwise the one with the larger std ratio.
    """
    collinear: dict[int, tuple[int, float]] = {}
    for i in range(len(refs)):
        for j in range(i + 1, len(refs)):
            if abs(corr[i, j]) >= threshold:
                k_f_index = next((k for k in (i, j) if refs[k] == (AIRFRAME, K_F)), None)
                victim = k_f_index if k_f_index is not None else (i if ratios[i] >= ratios[j] else j)
                collinear[victim] = (j if victim == i else i, abs(float(corr[i, j])))
    return collinear


def torque_residual(samples: FlightSamples, model: Model) -> FloatArray:
    """(T, 3) I dw/dt + w x I w - tau_model [N m], body FLU; NaN where the angular acceleration is unknown.

    The log's angular acceleration is a filtered derivative of its body rates, so the model's torque goes
    through the same derivative-of-integral filter (:class:`MeasurementChain` of order 1), twice when the
    rates were themselves derived from Euler angles. Cached per model.
    """
    key = ("torque residual", _model_key(model, ()))
    if key not in samples.design_cache:
        _, tau, _ = model.wrench(samples.model_context(model))
        inertia = model.inertia_kg_m2
        w = samples.w_WB_B
        gyro = np.cross(w, w @ inertia.T)
        # Rates from a gyro are differentiated once; rates from Euler angles were themselves a filtered
        # derivative, so the angular acceleration went through the filter twice.
        chain = MeasurementChain(1, samples.chain.flt, samples.chain.dt)
        modelled = tau - gyro
        for _ in range(samples.rate_chain.order):
            modelled = chain.apply(samples.t, modelled, samples.segments)
        samples.design_cache[key] = samples.w_dot_B @ inertia.T - modelled
    return samples.design_cache[key]


def acceleration_residual(samples: FlightSamples, model: Model) -> FloatArray:
    """(T, 3) measured minus modelled acceleration [m/s^2] (model output through the log's chain)."""
    design = build_design(samples, model, [])
    return design.y / np.asarray(model.mass_kg, dtype=float)


def rotor_shares_unseen(free: Sequence[ParameterRef], n_rotors: int) -> dict[ParameterRef, str]:
    """The free parameters the force equation cannot tell apart, each with the reason.

    A thrust factor given per rotor (rotor_effectiveness's e_1 ... e_N) changes the force only through the
    sum of the rotors' thrusts, sum e_i k_f omega_i^2, along one axis: in closed-loop flight the rotor
    speeds move together, so the log tells the rotors' shares apart only by their small differences, and
    a fit returns confident values that are wrong (a weak rotor's loss spread over its neighbours). Each
    rotor's share shows in the torque balance, which this equation-error fit does not use: such factors
    are held at their starting values and named.
    """
    unseen: dict[ParameterRef, str] = {}
    for effect_id in dict.fromkeys(effect_id for effect_id, _ in free if effect_id != AIRFRAME):
        cls = effect_class(effect_id)
        per_rotor = cls.PER_ROTOR_PARAMETER
        if per_rotor is None or "rotor_thrust_factor" not in cls.formulas():
            continue
        for i in range(1, n_rotors + 1):
            ref = (effect_id, f"{per_rotor.name}_{i}")
            if ref in free:
                unseen[ref] = (
                    f"{ref[1]} is not identifiable from the translational motion (a thrust factor per rotor "
                    "changes the force only through the sum of the rotors' thrusts; each rotor's share shows "
                    "in the torque balance, which this fit does not use)"
                )
    return unseen


def fit_parameters(
    samples: FlightSamples,
    model: Model,
    free: Sequence[ParameterRef],
    rows: BoolArray | None = None,
    progress: Progress | None = None,
    hold_unidentifiable: bool = True,
    held: dict[ParameterRef, float] | None = None,
    weights: FloatArray | None = None,
) -> FitResult:
    """Fit ``free`` parameters of ``model`` (its values are the start) on ``rows`` of ``samples``.

    With ``hold_unidentifiable`` a parameter found not identifiable is held at its starting value and the
    rest refitted, one at a time, until every free parameter is identifiable; each verdict is kept.
    """
    held = dict(held or {})
    verdicts: dict[ParameterRef, str] = {}
    for ref, why in rotor_shares_unseen(free, model.n_rotors).items():
        if ref not in held:
            held[ref] = parameter_value(model, ref)
            verdicts[ref] = why
    notes: list[str] = []
    while True:
        fitter = Fitter(samples, model, free, rows=rows, progress=progress, held=held, weights=weights)
        fitted = fitter.run()
        uncertainty, residual = assess(fitter, fitted)
        if hold_unidentifiable and uncertainty.worst is not None:
            ref = uncertainty.worst
            verdicts[ref] = uncertainty.not_identifiable[ref]
            held[ref] = parameter_value(model, ref)
            for search in fitter.rotor_onset_searches:
                if ref == search.factor:
                    # Without its factor the rotor and onset have nothing to choose between.
                    held.update({r: parameter_value(model, r) for r in (search.rotor, search.onset)})
            if progress is not None:
                progress(f"holding {ref[1]} at {held[ref]:.4g}: not identifiable")
            continue
        verdicts.update(uncertainty.not_identifiable)
        notes += uncertainty.notes
        break
    std = dict(uncertainty.std)
    for search in fitter.rotor_onset_searches:
        profile = fitter.fault_profile
        if search.onset in held or profile is None:
            continue
        finite = np.isfinite(profile)
        near = finite & (profile >= np.max(profile[finite]) - 1.0)
        spread = samples.t[near]
        # A fault between two samples first shows, partly, in the later one: the onset found is a sample
        # time within one interval of the true one either way, a uniform spread of dt / sqrt(3) at least.
        std[search.onset] = float(max((spread.max() - spread.min()) / 2, samples.dt / math.sqrt(3.0)))
        notes.append(
            f"{search.onset[1]} std: half the span of onsets whose fit is within one (whitened) unit of the "
            f"best, at least the resolution of the sample interval; {search.rotor[1]} is a discrete choice "
            "(no std)"
        )
    mass = np.asarray(fitted.mass_kg, dtype=float)
    acc_residual = np.where(fitter.rows[:, None], residual / mass, np.nan)
    values = {r: parameter_value(fitted, r) for r in free}
    return FitResult(
        model=fitted,
        free=list(fitter.free),
        values=values,
        std=std,
        not_identifiable=verdicts,
        residual=acc_residual,
        rows=fitter.rows,
        weights=fitter.weights,
        notes=notes,
        fault_candidates=fitter.fault_candidates,
    )
