"""Find where a model and a log disagree, name the missing effect, add it, and show the gap shrink.

:func:`find_discrepancy` does, for any log and airframe (seed 1's story made automatic), in stages that
read top to bottom in its body; the thresholds are :class:`~.settings.DiscrepancySettings` (defaults
quoted here):

1. Runs the baseline model (the airframe with ``baseline_effects``, parameters as configured) on the
   log's measured attitude, rotor speeds, velocity and height, and compares its acceleration with the
   measured one, and its position over short re-initialised horizons (:mod:`multirotor_ros.ident.metrics`).
2. Locates the disagreement per axis, per time window and per regime (:mod:`.regimes`).
3. Fits every translational effect of effects.md that the baseline lacks and this log and airframe can
   test (its own parameters; the baseline stays as configured, k_f included) and scores it on data it was
   not fitted on: 5-fold cross-validation over interleaved blocks of about 2 s (each block is predicted by
   the fit on the other four folds). The score is the held-out share of the acceleration error it removes.
   An effect is *significant* when its held-out improvement stands beyond noise (z >= 3, the noise's
   variance estimated block by block so that residuals correlated within a block count once,
   :func:`improvement_z`) and its force is not negligible: it reaches 0.05 m/s^2 RMS over some second of
   flight, and below 0.15 m/s^2 it must also explain something a constant accelerometer bias (a few mg)
   cannot.
4. Look-alikes (a mass offset and a thrust coefficient growing with speed; quadratic and rotor drag;
   a mass offset and a weaker lower coaxial rotor) are told apart by fitting the best candidate together
   with each close competitor: if the pair does not beat the best alone on held-out data, the competitor
   only explained what the best explains, and the regime where the best fits better (e.g. the slow
   part of the flight, where drag linear in speed departs from drag quadratic in speed) is the evidence.
   If neither adds to the other in the translational data, the torques decide: the fits never saw the
   roll and pitch torque balance, and a mass offset leaves it as modelled while a thrust change per rotor
   does not (each effect's ``torque_signature`` says how). If that is not conclusive either, the report
   says the log cannot tell them apart: the answer is "X or Y" (``ambiguous_with`` lists Y with its
   parameters; X, the higher score, is listed first, not chosen), with the regimes (each effect's
   ``regime``) a flight should cover to tell them apart.
5. The named effect is added and fitted on the whole log; the gap before and after is reported.
   ``max_effects`` > 1 repeats 3-5 with the named effects in the model (their linear parameters refitted
   with each linear candidate, all of them together after each round).

``none`` is named when no candidate is significant. Effects that this log could not reveal (their
parameters not identifiable, e.g. drag in a hover), that the airframe cannot have (``not_applicable``) or
that need what the log lacks (``log_needs``) are listed with the reason, and so are effects with one
parameter per rotor (``rotor_effectiveness``): the translational motion shows only the rotors' combined
thrust.

6. The rotors' balance: when the airframe carries a ``rotor_balance`` (``multirotor identify`` writes it
   from the vehicle's normal flights), the log's mean rotor commands in steady flight are compared with
   it (:mod:`multirotor_ros.ident.rotor_balance`): a weakened rotor (``rotor_effectiveness``, e_k per
   rotor with standard deviations), a payload (``mass_offset`` with ``cg_offset``) or nothing. What it
   names joins the translational answer; where a weakened rotor and a payload both explain the commands,
   ``ambiguous_with`` says so.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from multirotor_ros.discrepancy.regimes import concentration, error_windows, regime_variables
from multirotor_ros.discrepancy.settings import DiscrepancySettings
from multirotor_ros.ident.fit import FitResult, Fitter, acceleration_residual, fit_parameters, torque_residual
from multirotor_ros.ident.metrics import horizon_position_error, model_acceleration, per_axis
from multirotor_ros.ident.parameters import FittedParameter, ParameterRef
from multirotor_ros.ident.regressors import parameter_value
from multirotor_ros.ident.rotor_balance import (
    RotorBalanceError,
    RotorBaseline,
    RotorDiagnosis,
    diagnose,
    flight_balance,
)
from multirotor_ros.ident.samples import FlightSamples, NotEnoughData, load_samples
from multirotor_ros.io.flight_log import FlightLog, read_flight_log
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.effects import EFFECTS, TRANSLATIONAL_EFFECTS, Effect, effect_class, make_effect
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray

Progress = Callable[[str], None]

# What an effect's ``log_needs`` may ask of a log: whether it has it, and how the report says it does not.
_LOG_PROVISIONS: dict[str, tuple[Callable[[FlightSamples], bool], str]] = {
    "height": (
        lambda samples: samples.height_known,
        "the log has no measured height (no position, no range column)",
    ),
}


@dataclass
class Candidate:
    """One effect tried on top of the model of its round."""

    effect: str
    round: int
    parameters: dict[str, float]
    std: dict[str, float | None]
    mse_after: dict[str, float]  # held-out, per axis
    score: float  # held-out share of the round's acceleration error removed
    z_statistic: float
    peak_contribution_m_s2: float
    significant: bool
    regime: str
    not_identifiable: dict[str, str] = field(default_factory=dict)
    verdict: str = ""
    ambiguous_with: list[str] = field(default_factory=list)

    @property
    def fitted_any(self) -> bool:
        """Whether the log identified at least one of the effect's parameters."""
        return len(self.not_identifiable) < len(self.parameters)

    def to_json(self) -> dict[str, Any]:
        """The report.json entry (interfaces.md keys first)."""
        return {
            "effect": self.effect,
            "parameters": _json_parameters(self.parameters),
            "mse_after": self.mse_after,
            "score": self.score,
            "round": self.round,
            "significant": self.significant,
            "z_statistic": self.z_statistic,
            "peak_contribution_m_s2": self.peak_contribution_m_s2,
            "std": self.std,
            "regime": self.regime,
            "not_identifiable": self.not_identifiable,
            "ambiguous_with": self.ambiguous_with,
            "verdict": self.verdict,
        }


def _json_parameters(values: Mapping[str, float]) -> dict[str, float | int]:
    """Parameter values for report.json: a discrete one (a rotor's number) as an integer."""
    return {name: (int(round(v)) if _is_discrete(name) else float(v)) for name, v in values.items()}


def _is_discrete(name: str) -> bool:
    # Parameter names are unique across effects.md: report.json lists the named effects' ones flat.
    return any(p.discrete and p.name == name for cls in EFFECTS.values() for p in cls.PARAMETERS)


@dataclass
class DiscrepancyReport:
    """Everything :func:`find_discrepancy` found; :meth:`to_json` is report.json (interfaces.md)."""

    log: str
    airframe: str
    baseline_effects: list[str]
    metric: str
    mse_before: dict[str, float]
    where: list[dict[str, Any]]
    regimes: list[dict[str, Any]]
    candidates: list[Candidate]
    missing_effect: str
    missing_effects: list[str]
    parameters: dict[str, float]
    std: dict[str, float | None]
    mse_after: dict[str, float]
    position_mse_before: dict[str, float] | None
    position_mse_after: dict[str, float] | None
    explanation: list[str]
    not_testable: dict[str, str]
    split: str
    notes: list[str]
    warnings: list[str]
    timings_s: dict[str, float]
    samples: FlightSamples
    baseline_model: Model
    final_model: Model
    residual_before: FloatArray
    residual_after: FloatArray
    # Look-alikes of the first named effect that this log cannot tell from it: effect, parameters, std.
    ambiguous_with: list[dict[str, Any]] = field(default_factory=list)
    rotor_balance: dict[str, Any] | None = None
    # The flight that would tell the look-alikes apart (:mod:`.experiment`), when one was asked for.
    proposed_experiment: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """report.json as a dict: interfaces.md's keys, then what this implementation adds."""
        return {
            "log": self.log,
            "airframe": self.airframe,
            "baseline_effects": self.baseline_effects,
            "metric": self.metric,
            "mse_before": self.mse_before,
            "where": self.where,
            "candidates": [c.to_json() for c in self.candidates],
            "missing_effect": self.missing_effect,
            "parameters": _json_parameters(self.parameters),
            "mse_after": self.mse_after,
            "missing_effects": self.missing_effects,
            "ambiguous_with": self.ambiguous_with,
            "std": self.std,
            "position_mse_before": self.position_mse_before,
            "position_mse_after": self.position_mse_after,
            "regimes": self.regimes,
            "explanation": self.explanation,
            "not_testable": self.not_testable,
            "split": self.split,
            "notes": self.notes,
            "warnings": self.warnings,
            "timings_s": self.timings_s,
            "rotor_balance": self.rotor_balance,
            "proposed_experiment": self.proposed_experiment,
        }

    def verdict(self) -> str:
        """The named effect(s) in words, with the look-alikes this log cannot tell from them."""
        if not self.ambiguous_with:
            return " + ".join(self.missing_effects) or "none"
        first, *also = self.missing_effects
        others = " or ".join(entry["effect"] for entry in self.ambiguous_with)
        verdict = f"{first} or {others}: this log cannot tell them apart"
        return verdict + (f"; and {' + '.join(also)}" if also else "")

    def write(self, out_dir: str | Path, plots: bool = True) -> list[Path]:
        """report.json, the PNG plots and report.html in ``out_dir`` (created); returns the files."""
        from multirotor_ros.discrepancy.report import write_report

        return write_report(self, Path(out_dir), plots=plots)


# ----------------------------------------------------------------------------------------------
# folds and statistics


@dataclass(frozen=True)
class Folds:
    """Interleaved blocks: block b of ``block_s`` seconds belongs to fold b mod k."""

    block: NDArray[np.intp]  # (T,) block index of each sample
    n_blocks: int
    k: int
    block_s: float

    def test_rows(self, fold: int, valid: BoolArray) -> BoolArray:
        """Samples of one fold (usable ones)."""
        return valid & (self.block % self.k == fold)

    def describe(self) -> str:
        """Words for the report."""
        return (
            f"{self.k}-fold cross-validation over {self.n_blocks} interleaved blocks of {self.block_s:.3g} "
            "s: "
            f"block b is predicted by the model fitted on the blocks of the other folds (b mod {self.k} "
            "differs)"
        )


def make_folds(samples: FlightSamples, settings: DiscrepancySettings) -> Folds:
    """Blocks of ``max_block_s`` (shorter for short logs, so that there are at least ``min_blocks``)."""
    duration = samples.duration_s
    min_blocks = settings.min_blocks
    block_s = float(np.clip(duration / (4 * min_blocks), settings.min_block_s, settings.max_block_s))
    block = np.floor((samples.t - samples.t[0]) / block_s).astype(int)
    used = np.unique(block[samples.valid])
    if used.size < min_blocks:
        raise NotEnoughData(
            f"{samples.source}: {duration:.1f} s of usable flight; the discrepancy workflow needs at least "
            f"{min_blocks * settings.min_block_s:g} s ({min_blocks} blocks) to fit candidates on one part of "
            "the log and test them on another"
        )
    return Folds(block, int(block.max()) + 1, settings.folds, block_s)


def block_sse(residual: FloatArray, rows: BoolArray, folds: Folds) -> FloatArray:
    """(n_blocks,) sum over samples and axes of squared residuals, per block."""
    squared = np.where(rows, np.sum(np.nan_to_num(residual) ** 2, axis=1), 0.0)
    return np.bincount(folds.block, weights=squared, minlength=folds.n_blocks)


def improvement_z(
    before: FloatArray, after: FloatArray, rows: BoolArray, folds: Folds, noise_gain: float = 0.0
) -> float:
    """How many standard deviations of noise the held-out improvement SSE(before) - SSE(after) stands at.

    With e = after (what is left) and c = before - after (what the added effect takes away), the
    improvement is sum(c^2 + 2 e.c). If the effect only fitted noise, e.c is noise times a fixed
    column, whose sum's variance is estimated block by block (sum over blocks of (sum_b e.c)^2), so
    residuals correlated within a block are accounted for. Unlike a t-test on block improvements, an
    effect acting strongly in a few blocks only (near the ground, after a fault) is not penalised for
    the blocks where it does nothing.

    ``noise_gain``: the part of SSE(before) - SSE(after) that noise in the models' own inputs makes by
    itself (:func:`regressor_noise_sse`), taken off the improvement.
    """
    e = np.where(rows[:, None], np.nan_to_num(after), 0.0)
    b = np.where(rows[:, None], np.nan_to_num(before), 0.0)
    c = b - e
    gain = float(np.sum(b * b) - np.sum(e * e)) - noise_gain
    cross = np.bincount(folds.block, weights=np.sum(e * c, axis=1), minlength=folds.n_blocks)
    spread = 2.0 * math.sqrt(float(np.sum(cross**2)))
    if spread == 0.0:
        return 0.0 if gain <= 0 else math.inf
    return gain / spread


def _without_body_bias(
    samples: FlightSamples, before: FloatArray, after: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Both residuals minus their least-squares fits by a constant body-frame acceleration (an IMU bias)."""
    rows = samples.valid
    # A body-frame bias b shows in world as R b: stacked over samples, the rows of each R.
    basis = samples.R_WB[rows].reshape(-1, 3)

    def unbiased(residual: FloatArray) -> FloatArray:
        values = np.nan_to_num(residual[rows]).reshape(-1)
        bias = np.linalg.lstsq(basis, values, rcond=None)[0]
        corrected = np.array(residual, copy=True)
        corrected[rows] = (values - basis @ bias).reshape(-1, 3)
        return corrected

    return unbiased(before), unbiased(after)


def peak_window_rms(
    contribution: FloatArray, samples: FlightSamples, rows: BoolArray, window_s: float
) -> float:
    """Largest RMS over windows of ``window_s`` of a per-sample vector (T, 3) on ``rows``."""
    index = np.floor((samples.t - samples.t[0]) / window_s).astype(int)
    squared = np.where(rows, np.sum(np.nan_to_num(contribution) ** 2, axis=1), 0.0)
    sums = np.bincount(index, weights=squared)
    counts = np.bincount(index, weights=rows.astype(float))
    full = counts >= 0.5 * window_s / samples.dt
    if not np.any(full):
        return 0.0
    return float(np.sqrt(np.max(sums[full] / counts[full])))


# ----------------------------------------------------------------------------------------------
# trials


@dataclass
class Trial:
    """Effects added to the baseline, fitted on the whole log and cross-validated."""

    effects: tuple[str, ...]
    fit: FitResult
    heldout: FloatArray  # (T, 3) held-out acceleration residual
    in_sample: FloatArray  # (T, 3) residual of the whole-log fit

    def parameters(self, effect_id: str) -> dict[str, float]:
        """Fitted parameters of one of the trial's effects."""
        effect = self.fit.model.effect(effect_id)
        assert effect is not None
        return {name: float(value) for name, value in effect.parameters.items()}


class Workflow:
    """The state shared by the stages of :func:`find_discrepancy`: the log, the baseline, the folds."""

    def __init__(
        self,
        samples: FlightSamples,
        baseline: Model,
        settings: DiscrepancySettings,
        progress: Progress | None,
        notes: list[str],
    ):
        self.samples = samples
        self.baseline = baseline
        self.airframe = baseline.airframe
        self.settings = settings
        self.progress = progress
        self.notes = notes
        self.valid = samples.valid
        self.folds = make_folds(samples, settings)
        self.used_blocks = np.bincount(self.folds.block[self.valid], minlength=self.folds.n_blocks) > 0
        self.variables = regime_variables(samples, self.airframe)
        self.trials: dict[tuple[tuple[str, ...], tuple[str, ...]], Trial] = {}
        self._vertical_bias: Workflow | None = None

    def with_vertical_accelerometer_bias(self) -> Workflow | None:
        """This workflow with a constant accelerometer bias along body z as one more nuisance (cached).

        Left out of the fits because in flight it is collinear with thrust (a few mg is a few tenths of a
        per cent of k_f), it is also what remains between look-alikes that scale the thrust alike (a
        payload, a weaker lower coaxial rotor, a speed-dependent thrust coefficient in a hover): a verdict
        between them that such a bias can undo is no verdict. None when the log's acceleration is not
        measured (a differentiated position has no bias).
        """
        samples = self.samples
        if samples.chain.order != 0:
            return None
        if self._vertical_bias is None:
            along_z = self.airframe.mass_kg * samples.R_WB[:, :, 2:]
            nuisance = along_z if samples.nuisance is None else np.concatenate([samples.nuisance, along_z], 2)
            biased = dataclasses.replace(
                samples,
                nuisance=nuisance,
                nuisance_names=(*samples.nuisance_names, "accelerometer_bias_z_m_s2"),
                design_cache={},
            )
            self._vertical_bias = Workflow(biased, self.baseline, self.settings, None, [])
        return self._vertical_bias

    def _say(self, message: str) -> None:
        if self.progress is not None:
            self.progress(message)

    def parameter_names(self, effect_id: str) -> list[str]:
        """The names of an effect's parameters on this airframe."""
        return [p.name for p in effect_class(effect_id).parameter_list(self.airframe.n_rotors)]

    def model_with(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> Model:
        """The baseline plus ``effects`` at their ``start`` values."""
        specs = list(self.baseline.effects) + [make_effect({"id": e, **start[e]}) for e in effects]
        return Model(self.airframe, specs, self.baseline.gravity_m_s2)

    def residual_with(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> FloatArray:
        """Acceleration residual of :meth:`model_with`."""
        return acceleration_residual(self.samples, self.model_with(effects, start))

    def joint_fit(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> FitResult:
        """All parameters of ``effects`` fitted together on the whole log (no cross-validation)."""
        free = [(e, n) for e in effects for n in self.parameter_names(e)]
        return fit_parameters(self.samples, self.model_with(effects, start), free)

    def trial(
        self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]], fixed: Sequence[str] = ()
    ) -> Trial:
        """Fit ``effects`` (ids, in order) on top of the baseline and the already named ``fixed`` effects.

        The named effects start from their ``start`` values; when the candidates enter linearly, the named
        effects' linear parameters are refitted with them (cheap, and an earlier effect fitted alone has often
        absorbed part of a later one); before a search (ground effect, lag, fault) they stay fixed.
        Cached by the sets of ids.
        """
        key = (tuple(sorted(effects)), tuple(sorted(fixed)))
        if key in self.trials:
            return self.trials[key]
        n_rotors = self.airframe.n_rotors
        specs: list[Effect] = list(self.baseline.effects)
        specs += [make_effect({"id": effect_id, **start[effect_id]}) for effect_id in fixed]
        free: list[ParameterRef] = []
        for effect_id in effects:
            values = dict(start.get(effect_id) or effect_class(effect_id).neutral_parameters(n_rotors))
            specs.append(make_effect({"id": effect_id, **values}))
            free += [(effect_id, name) for name in self.parameter_names(effect_id)]
        candidates_free = list(free)
        named_held: dict[ParameterRef, float] = {}
        if all(p.linear for e in effects for p in effect_class(e).parameter_list(n_rotors)):
            for effect_id in fixed:
                for name in self.parameter_names(effect_id):
                    free.append((effect_id, name))
                    if not effect_class(effect_id).parameter(name).linear:
                        named_held[(effect_id, name)] = float(start[effect_id][name])
        model = Model(self.airframe, specs, self.baseline.gravity_m_s2)
        self._say(f"fitting {' + '.join(effects)}")
        full = fit_parameters(self.samples, model, free, held=named_held)
        held = {**named_held, **{ref: parameter_value(model, ref) for ref in full.not_identifiable}}
        for effect_id, name in list(held):
            # A parameter that is linear only once its effect's others are chosen (a fault's effectiveness),
            # held at its start, leaves those others nothing to choose: the folds hold them too.
            if effect_class(effect_id).parameter(name).linear_given_others:
                held.update({ref: parameter_value(model, ref) for ref in free if ref[0] == effect_id})
        heldout = np.full((self.samples.t.size, 3), np.nan)
        in_sample = acceleration_residual(self.samples, full.model)
        if all(ref in held for ref in candidates_free):
            heldout[:] = in_sample
        else:
            for fold in range(self.folds.k):
                test = self.folds.test_rows(fold, self.valid)
                if not np.any(test):
                    continue
                # Folds start from the whole-log fit and search its non-linear parameters nearby: the same
                # optimum when the training data agree, at a fraction of the cost of a full search.
                fitter = Fitter(
                    self.samples,
                    full.model,
                    free,
                    rows=self.valid & ~test,
                    held=held,
                    weights=full.weights,
                )
                fitted = fitter.run(refine=False, local=True)
                heldout[test] = acceleration_residual(self.samples, fitted)[test]
        trial = Trial(tuple(effects), full, heldout, in_sample)
        self.trials[key] = trial
        return trial


# ----------------------------------------------------------------------------------------------
# the stages of find_discrepancy


@dataclass
class Disagreement:
    """How the baseline misses the log: where, and the reference the candidates are scored against."""

    residual: FloatArray  # (T, 3) measured minus modelled acceleration [m/s^2]
    mse: FloatArray  # (3,) mean square per world axis [(m/s^2)^2]
    position_mse: FloatArray | None  # (3,) over 1 s horizons [m^2]; None without a measured position
    where: list[dict[str, Any]]
    regimes: list[dict[str, Any]]


@dataclass
class Naming:
    """What the rounds of candidate fits found."""

    not_testable: dict[str, str]
    named: list[str] = field(default_factory=list)
    start: dict[str, dict[str, float]] = field(default_factory=dict)  # the named effects' fitted values
    candidates: list[Candidate] = field(default_factory=list)
    explanation: list[str] = field(default_factory=list)
    # Pairs that each explained a part the other did not: (line in explanation, round, best, rival). Their
    # sentence is written once the rounds are over, when it is known whether a later round named the rival.
    both_present: list[tuple[int, int, str, str]] = field(default_factory=list)


@dataclass
class FinalFit:
    """The named effects fitted together on the whole log (the baseline when none is named)."""

    model: Model
    parameters: dict[str, float]
    std: dict[str, float | None]
    residual: FloatArray  # (T, 3) [m/s^2]
    warnings: list[str]


def find_discrepancy(
    airframe: Airframe | str | Path,
    log: FlightLog | str | Path,
    baseline_effects: Sequence[str | Mapping[str, Any] | Effect] | None = None,
    max_effects: int = 1,
    progress: Progress | None = None,
    candidates: Sequence[str] | None = None,
    accelerometer_bias: bool = True,
    settings: DiscrepancySettings | None = None,
) -> DiscrepancyReport:
    """Run the workflow of the module docstring; ``baseline_effects`` None = the airframe's own list.

    ``candidates`` restricts the effects tried (default: every translational effect the baseline lacks).
    ``accelerometer_bias``: when the log measures acceleration, a constant bias along body x and y is
    removed from every comparison as a nuisance (:meth:`FlightSamples.estimate_accelerometer_bias`), so
    that an IMU's few mg are not taken for a steady horizontal force.
    ``settings``: the thresholds (default :class:`DiscrepancySettings`).
    Raises FlightLogError, LogMismatch or NotEnoughData (all ValueError) with a message naming what is wrong.
    """
    started = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(phase: str) -> None:
        timings[phase] = time.perf_counter() - started

    settings = DiscrepancySettings() if settings is None else settings
    if not isinstance(airframe, Airframe):
        airframe = load_airframe(airframe)
    if max_effects < 1:
        raise ValueError(f"max_effects must be >= 1, got {max_effects}")
    flight = log if isinstance(log, FlightLog) else read_flight_log(log)
    samples = load_samples(flight, airframe, settings=settings.fit)
    if accelerometer_bias:
        samples.estimate_accelerometer_bias(airframe.mass_kg)
    rotor_stage = _rotor_balance_stage(airframe, flight)
    found = rotor_stage.baseline_effects()
    if found:
        baseline_effects = [
            *(airframe.effect_specs() if baseline_effects is None else baseline_effects),
            *found,
        ]
    lap("load")
    workflow = _baseline_workflow(samples, airframe, baseline_effects, settings, progress)
    disagreement = _where_the_model_disagrees(workflow)
    lap("baseline")
    pool, not_testable = _candidate_pool(workflow, candidates)
    naming = _name_effects(workflow, pool, Naming(not_testable), disagreement.residual, max_effects)
    lap("candidates")
    final = _fit_named(workflow, naming, disagreement)
    report = _report(workflow, disagreement, naming, final)
    _add_rotor_balance(report, rotor_stage)
    lap("total")
    report.timings_s = timings
    return report


def _baseline_workflow(
    samples: FlightSamples,
    airframe: Airframe,
    baseline_effects: Sequence[str | Mapping[str, Any] | Effect] | None,
    settings: DiscrepancySettings,
    progress: Progress | None,
) -> Workflow:
    """The baseline model, its effects without configured values fitted to the log first."""
    effects, unconfigured = _resolve_baseline(airframe, baseline_effects)
    baseline = Model(airframe, effects)
    notes = list(samples.notes)
    if samples.nuisance is not None:
        notes.append(
            "a constant accelerometer bias along body x and y is fitted alongside every model (a nuisance, "
            "not an effect): a steady horizontal force is told from it by the vehicle's changes of heading"
        )
    if unconfigured:
        free = [(e, p.name) for e in unconfigured for p in effect_class(e).parameter_list(airframe.n_rotors)]
        baseline = fit_parameters(samples, baseline, free, progress=progress).model
        notes.append(
            f"baseline effect(s) {', '.join(unconfigured)} have no values in {airframe.name}'s "
            "configuration: they were fitted to this log first"
        )
    return Workflow(samples, baseline, settings, progress, notes)


def _resolve_baseline(
    airframe: Airframe, baseline_effects: Sequence[str | Mapping[str, Any] | Effect] | None
) -> tuple[list[Effect], list[str]]:
    """Baseline effects (configured values) and the ids that have no configured values (to be fitted)."""
    if baseline_effects is None:
        return [make_effect(spec) for spec in airframe.effect_specs()], []
    configured = {spec["id"]: spec for spec in airframe.effect_specs()}
    effects: list[Effect] = []
    unconfigured: list[str] = []
    for entry in baseline_effects:
        if isinstance(entry, str):
            if entry not in EFFECTS:
                raise ValueError(f"unknown effect {entry!r}; known: {', '.join(EFFECTS)} or 'none'")
            if entry in configured:
                effects.append(make_effect(configured[entry]))
            else:
                neutral = EFFECTS[entry].neutral_parameters(airframe.n_rotors)
                effects.append(make_effect({"id": entry, **neutral}))
                unconfigured.append(entry)
        else:
            effects.append(make_effect(entry))
    return effects, unconfigured


def _where_the_model_disagrees(workflow: Workflow) -> Disagreement:
    """The baseline's error per axis, over 1 s horizons of position, per time window and per regime."""
    samples, valid, settings = workflow.samples, workflow.valid, workflow.settings
    residual = acceleration_residual(samples, workflow.baseline)
    position_mse, _ = horizon_position_error(samples, model_acceleration(samples, workflow.baseline))
    window_s = max(workflow.folds.block_s, samples.duration_s / settings.where_windows_per_log)
    where = error_windows(
        samples, residual, workflow.variables, window_s=window_s, limit=settings.where_limit
    )
    worst_regimes = concentration(np.sum(residual**2, axis=1), valid, workflow.variables)
    regimes = [
        {"regime": c.text, "variable": c.variable, "error_ratio": c.ratio, "share_of_error": c.share}
        for c in worst_regimes[: settings.regimes_listed]
    ]
    return Disagreement(residual, np.mean(residual[valid] ** 2, axis=0), position_mse, where, regimes)


def _candidate_pool(workflow: Workflow, candidates: Sequence[str] | None) -> tuple[list[str], dict[str, str]]:
    """The effects to try (not already in the baseline), and why the others cannot be tested here."""
    in_baseline = workflow.baseline.effect_ids
    pool: list[str] = []
    not_testable: dict[str, str] = {}
    for effect_id in candidates or TRANSLATIONAL_EFFECTS:
        if effect_id in in_baseline:
            continue
        reason = _why_untestable(effect_class(effect_id), workflow)
        if reason is None:
            pool.append(effect_id)
        else:
            not_testable[effect_id] = reason
    return pool, not_testable


def untestable_by_design(cls: type[Effect]) -> str | None:
    """Why this workflow cannot fit an effect on any log, or None."""
    per_rotor = cls.PER_ROTOR_PARAMETER
    if per_rotor is None:
        return None
    return (
        f"one {per_rotor.name}_i per rotor: the translational motion shows only the rotors' combined "
        "thrust, and the torque balance that tells the rotors apart is not fitted by this workflow"
    )


def _why_untestable(cls: type[Effect], workflow: Workflow) -> str | None:
    """Why an effect cannot be a candidate on this airframe and log, or None."""
    by_design = untestable_by_design(cls)
    if by_design is not None:
        return by_design
    inapplicable = cls.not_applicable(workflow.airframe)
    if inapplicable is not None:
        return inapplicable
    lacking = [
        missing
        for has, missing in (_LOG_PROVISIONS[need] for need in cls.log_needs)
        if not has(workflow.samples)
    ]
    return "; ".join(lacking) if lacking else None


def _name_effects(
    workflow: Workflow, pool: list[str], naming: Naming, reference: FloatArray, max_effects: int
) -> Naming:
    """Rounds of candidate fits; each names the best significant candidate or stops (module docstring 3-5).

    ``reference``: the acceleration residual the round's candidates are scored against (the baseline's,
    then the model with the named effects at their fitted values, where nothing is fitted, so held-out and
    in-sample residuals are the same).
    """
    settings = workflow.settings
    for round_number in range(1, max_effects + 1):
        remaining = [e for e in pool if e not in naming.named]
        scored = _screen(workflow, remaining, naming, reference, round_number)
        significant = [item for item in scored if item[0].significant]
        naming.candidates += [candidate for candidate, _ in scored]
        if not significant:
            if round_number == 1:
                naming.explanation.append(
                    "No candidate effect explains a significant part of the disagreement beyond noise on "
                    f"held-out data (needs z >= {settings.z_critical:g} and a force reaching "
                    f"{settings.negligible_acceleration_m_s2} m/s^2): missing effect: none."
                )
            else:
                naming.explanation.append(
                    f"Round {round_number}: no further effect is significant; stopping."
                )
            break
        best, best_trial, lookalike_words = _separate_lookalikes(workflow, significant, naming)
        _add_named(workflow, naming, best.effect, best_trial)
        naming.explanation.append(
            f"Round {round_number}: {best.effect} removes {100 * best.score:.1f} % of the acceleration error "
            f"on held-out data (z = {best.z_statistic:.1f}; its force reaches "
            f"{best.peak_contribution_m_s2:.3g} m/s^2); it {best.regime}."
        )
        for line in lookalike_words:
            if isinstance(line, tuple):
                naming.both_present.append((len(naming.explanation), round_number, *line))
                line = ""
            naming.explanation.append(line)
        reference = workflow.residual_with(naming.named, naming.start)
    for index, round_number, best_effect, rival in naming.both_present:
        naming.explanation[index] = _both_present_sentence(
            round_number, best_effect, rival, naming, max_effects
        )
    return naming


def _both_present_sentence(round_number: int, best: str, rival: str, naming: Naming, max_effects: int) -> str:
    """What two effects that each add to the other mean, given what the later rounds named."""
    pair = f"{best} and {rival} each explain a part of the error the other does not (held-out data)"
    if rival in naming.named:
        later = naming.named.index(rival) + 1
        return f"{pair}: both are present, and round {later} names {rival}."
    if max_effects > round_number:
        return (
            f"{pair}, but with {best} in the model {rival} is no longer significant in round "
            f"{round_number + 1}: only {best} is named."
        )
    return (
        f"{pair}: {rival} may be present too; --max-effects {round_number + 1} tests it in a further round."
    )


def _screen(
    workflow: Workflow, pool: list[str], naming: Naming, reference: FloatArray, round_number: int
) -> list[tuple[Candidate, Trial]]:
    """Each candidate fitted on top of the round's model and scored on held-out data, best score first."""
    scored = []
    for effect_id in pool:
        # Later rounds keep the named effects at their fitted values while candidates are screened (the
        # named ones are refitted jointly with the winner at the end).
        trial = workflow.trial([effect_id], naming.start, fixed=naming.named)
        candidate = _score(workflow, effect_id, trial, reference, round_number)
        if not candidate.fitted_any and round_number == 1:
            naming.not_testable[effect_id] = "; ".join(candidate.not_identifiable.values())
        scored.append((candidate, trial))
    scored.sort(key=lambda item: -item[0].score)
    return scored


def _score(
    workflow: Workflow, effect_id: str, trial: Trial, reference: FloatArray, round_number: int
) -> Candidate:
    """The candidate's held-out score, significance, size, and where it explains the error."""
    samples, valid, folds, settings = workflow.samples, workflow.valid, workflow.folds, workflow.settings
    before = float(block_sse(reference, valid, folds)[workflow.used_blocks].sum())
    after = float(block_sse(trial.heldout, valid, folds)[workflow.used_blocks].sum())
    score = 1.0 - after / before if before > 0 else 0.0
    z_stat = improvement_z(reference, trial.heldout, valid, folds)
    peak = peak_window_rms(reference - trial.in_sample, samples, valid, settings.peak_window_s)
    names = workflow.parameter_names(effect_id)
    not_identifiable = {name: why for (e, name), why in trial.fit.not_identifiable.items() if e == effect_id}
    fitted_any = len(not_identifiable) < len(names)
    significant = bool(
        fitted_any
        and z_stat >= settings.z_critical
        and score > 0
        and peak >= settings.negligible_acceleration_m_s2
    )
    parameters = trial.parameters(effect_id)
    early_onset = _onset_without_flight_before(parameters, samples, settings)
    significant = significant and early_onset is None
    bias_like = False
    if significant and peak < settings.bias_check_below_m_s2:
        # A small effect must also explain something an accelerometer bias cannot.
        reference_unbiased, heldout_unbiased = _without_body_bias(samples, reference, trial.heldout)
        z_unbiased = improvement_z(reference_unbiased, heldout_unbiased, valid, folds)
        bias_like = z_unbiased < settings.z_critical
        significant = not bias_like
    gain = np.sum(np.nan_to_num(reference) ** 2 - np.nan_to_num(trial.heldout) ** 2, axis=1)
    where_gain = concentration(np.maximum(gain, 0.0), valid, workflow.variables)
    candidate = Candidate(
        effect=effect_id,
        round=round_number,
        parameters=parameters,
        std=_std_unless_at_bound(
            workflow.airframe, [(effect_id, name) for name in names], parameters, trial.fit.std
        )[0],
        mse_after=per_axis(np.mean(trial.heldout[valid] ** 2, axis=0)),
        score=score,
        z_statistic=z_stat,
        peak_contribution_m_s2=peak,
        significant=significant,
        regime=_regime_text(parameters, where_gain if score > 0 else []),
        not_identifiable=not_identifiable,
    )
    candidate.verdict = early_onset or _verdict(candidate, bias_like, settings)
    return candidate


def _onset_without_flight_before(
    parameters: Mapping[str, float], samples: FlightSamples, settings: DiscrepancySettings
) -> str | None:
    """Why a fault onset with too little usable flight before it is not significant, or None."""
    onset = parameters.get("t_fault_s")
    usable = samples.t[samples.valid]
    if onset is None or not math.isfinite(onset) or usable.size == 0:
        return None
    before_s = float(np.count_nonzero(usable < onset)) * samples.dt
    if before_s >= settings.min_flight_before_fault_s:
        return None
    return (
        f"not significant: its onset (t = {onset:.2f} s) has {before_s:.2f} s of usable flight before it "
        f"(at least {settings.min_flight_before_fault_s:g} s needed): a rotor weak from the start is "
        "rotor_effectiveness, not a fault"
    )


def _regime_text(parameters: Mapping[str, float], where: Sequence[Any]) -> str:
    """Where the candidate explains most; an effect with an onset says when it began first."""
    if not where:
        return "explains nothing"
    text = f"explains most where {where[0].text}"
    onset = parameters.get("t_fault_s")
    if onset is not None and math.isfinite(onset):
        return f"starts at t = {onset:.2f} s and {text}"
    return text


def _verdict(candidate: Candidate, bias_like: bool, settings: DiscrepancySettings) -> str:
    if not candidate.fitted_any:
        return "not identifiable on this log"
    if bias_like:
        return (
            f"not significant: small (at most {candidate.peak_contribution_m_s2:.3g} m/s^2) and what it "
            "explains a constant accelerometer bias explains as well"
        )
    if candidate.significant:
        return "significant"
    reasons = []
    if candidate.score <= 0:
        reasons.append("no held-out improvement")
    elif candidate.z_statistic < settings.z_critical:
        reasons.append(
            f"held-out improvement within noise (z = {candidate.z_statistic:.1f} < {settings.z_critical:g})"
        )
    if candidate.peak_contribution_m_s2 < settings.negligible_acceleration_m_s2:
        reasons.append(
            f"negligible force (at most {candidate.peak_contribution_m_s2:.3g} m/s^2, below "
            f"{settings.negligible_acceleration_m_s2})"
        )
    return "not significant: " + "; ".join(reasons)


def _add_named(workflow: Workflow, naming: Naming, effect_id: str, trial: Trial) -> None:
    """Name an effect at its fitted values; with earlier ones, refit them all together."""
    naming.named.append(effect_id)
    naming.start[effect_id] = trial.parameters(effect_id)
    if len(naming.named) > 1:
        # An earlier effect fitted alone absorbed part of the later one.
        joint = workflow.joint_fit(naming.named, naming.start)
        naming.start.update(
            {e: {name: v for (owner, name), v in joint.values.items() if owner == e} for e in naming.named}
        )


def _fit_named(workflow: Workflow, naming: Naming, disagreement: Disagreement) -> FinalFit:
    """The named effects fitted together on the whole log, with a warning per parameter it cannot tell."""
    if not naming.named:
        return FinalFit(workflow.baseline, {}, {}, disagreement.residual, [])
    trial = workflow.trial(naming.named, naming.start)
    refs = [(e, name) for e in naming.named for name in workflow.parameter_names(e)]
    parameters = {name: float(v) for e in naming.named for name, v in trial.parameters(e).items()}
    std, at_bounds = _std_unless_at_bound(workflow.airframe, refs, parameters, trial.fit.std)
    return FinalFit(
        model=trial.fit.model,
        parameters=parameters,
        std=std,
        residual=trial.in_sample,
        warnings=[
            f"{e}.{name}: {why}" for e, name in refs if (why := trial.fit.not_identifiable.get((e, name)))
        ]
        + at_bounds,
    )


def _std_unless_at_bound(
    airframe: Airframe,
    refs: Sequence[ParameterRef],
    values: Mapping[str, float],
    fitted_std: Mapping[ParameterRef, float | None],
) -> tuple[dict[str, float | None], list[str]]:
    """The fit's std per parameter, None for one on a bound (a limit of the fit, not an estimate), and why."""
    std: dict[str, float | None] = {}
    words = []
    for ref in refs:
        name = ref[1]
        bound = FittedParameter.of(ref, airframe).bound_reached(values[name])
        std[name] = None if bound else fitted_std.get(ref)
        if bound:
            words.append(
                f"{ref[0]}.{name} = {values[name]:.6g} is at its {bound}: the fit's limit, not an estimate "
                "(no standard deviation)"
            )
    return std, words


def _report(
    workflow: Workflow,
    disagreement: Disagreement,
    naming: Naming,
    final: FinalFit,
) -> DiscrepancyReport:
    """The gap before and after, in numbers and words."""
    samples, valid, named = workflow.samples, workflow.valid, naming.named
    mse_before = disagreement.mse
    mse_after = np.mean(final.residual[valid] ** 2, axis=0)
    position_after, _ = horizon_position_error(samples, model_acceleration(samples, final.model))
    explanation = list(naming.explanation)
    if named:
        reduction = 1.0 - float(mse_after.sum() / mse_before.sum())
        explanation.append(
            f"With {' + '.join(named)} added and fitted on the whole log, the acceleration error falls from "
            f"{mse_before.sum():.4g} to {mse_after.sum():.4g} (m/s^2)^2 summed over the axes "
            f"({100 * reduction:.1f} % less)."
        )
    if naming.not_testable:
        reasons = "; ".join(f"{e} ({why})" for e, why in naming.not_testable.items())
        explanation.append(f"Not testable on this log: {reasons}.")
    metric = (
        "mse_before / mse_after: mean square error per world axis of the acceleration [(m/s^2)^2], measured "
        "minus modelled over every usable sample of the log, the model driven by the log's attitude, rotor "
        f"speeds, velocity and height ({samples.chain.describe()}). mse_after: the model with the named "
        "effect(s) fitted on the whole log. candidates[].mse_after and score: held-out values ("
        + workflow.folds.describe()
        + "); score = share of the round's acceleration error removed on held-out data. position_mse_*: mean "
        "square position error [m^2] over 1 s horizons re-initialised on the measured position and velocity."
    )
    position_before = disagreement.position_mse
    first = next((c for c in naming.candidates if named and c.effect == named[0]), None)
    ambiguous_with = [
        {"effect": c.effect, "parameters": _json_parameters(c.parameters), "std": c.std}
        for c in naming.candidates
        if first is not None and c.round == first.round and c.effect in first.ambiguous_with
    ]
    return DiscrepancyReport(
        log=Path(str(samples.source)).name,
        airframe=workflow.airframe.name,
        baseline_effects=workflow.baseline.effect_ids,
        metric=metric,
        mse_before=per_axis(mse_before),
        where=disagreement.where,
        regimes=disagreement.regimes,
        candidates=naming.candidates,
        missing_effect=named[0] if named else "none",
        missing_effects=named,
        parameters=final.parameters,
        std=final.std,
        mse_after=per_axis(mse_after),
        position_mse_before=None if position_before is None else per_axis(position_before),
        position_mse_after=None if position_after is None else per_axis(position_after),
        explanation=explanation,
        not_testable=naming.not_testable,
        split=workflow.folds.describe(),
        notes=workflow.notes,
        warnings=list(samples.warnings) + final.warnings,
        timings_s={},
        samples=samples,
        baseline_model=workflow.baseline,
        final_model=final.model,
        residual_before=disagreement.residual,
        residual_after=final.residual,
        ambiguous_with=ambiguous_with,
    )


@dataclass
class RotorBalanceStage:
    """Stage 6's outcome before the translational stages: what to add to the baseline, what to report."""

    diagnosis: RotorDiagnosis | None
    explanation: str
    warnings: list[str]

    def baseline_effects(self) -> list[dict[str, Any]]:
        """The named finding as effect specs, so that the translational comparison starts from it."""
        if self.diagnosis is None or self.diagnosis.named == "none":
            return []
        fitted = self.diagnosis.explanations[self.diagnosis.named].parameters
        if self.diagnosis.named == "rotor_effectiveness":
            return [{"id": "rotor_effectiveness", **fitted}]
        return [
            {"id": "mass_offset", "dm_kg": fitted["dm_kg"]},
            {"id": "cg_offset", "r_x": fitted["r_x"], "r_y": fitted["r_y"]},
        ]


def _rotor_balance_stage(airframe: Airframe, flight: FlightLog) -> RotorBalanceStage:
    """The log's rotor balance against the airframe's, if the airframe has one."""
    baseline = RotorBaseline.of_airframe(airframe)
    if baseline is None:
        return RotorBalanceStage(
            None,
            "The rotors' balance (rotor_effectiveness per rotor, cg_offset) is not compared: "
            f"{airframe.name} has no rotor_balance; `multirotor identify` with the vehicle's normal flights "
            "(--log repeated) writes an airframe that has one.",
            [],
        )
    try:
        diagnosis = diagnose(airframe, baseline, flight_balance(flight, airframe))
    except RotorBalanceError as error:
        return RotorBalanceStage(None, f"The rotors' balance is not compared: {error}.", [str(error)])
    line = f"Compared with {airframe.name}'s rotor balance: {diagnosis.headline()}."
    if diagnosis.named != "none":
        line += " The translational comparison above starts from a baseline with this finding in it."
    return RotorBalanceStage(diagnosis, line, [])


def _add_rotor_balance(report: DiscrepancyReport, stage: RotorBalanceStage) -> None:
    """What the rotor balance named joins the report's answer."""
    report.explanation.append(stage.explanation)
    report.warnings += stage.warnings
    diagnosis = stage.diagnosis
    if diagnosis is None:
        return
    report.rotor_balance = diagnosis.to_json()
    report.notes += diagnosis.notes
    if diagnosis.named == "none":
        return
    effects = diagnosis.named.split("+")
    fitted = diagnosis.explanations[diagnosis.named]
    report.missing_effect = effects[0]
    report.missing_effects = effects + [e for e in report.missing_effects if e not in effects]
    report.parameters = {**fitted.parameters, **report.parameters}
    report.std = {**fitted.std, **report.std}
    report.ambiguous_with = [
        {
            "effect": name,
            "parameters": diagnosis.explanations[name].parameters,
            "std": diagnosis.explanations[name].std,
        }
        for name in diagnosis.ambiguous_with
    ]


# ----------------------------------------------------------------------------------------------
# look-alikes


def _separate_lookalikes(
    workflow: Workflow, significant: list[tuple[Candidate, Trial]], naming: Naming
) -> tuple[Candidate, Trial, list[str | tuple[str, str]]]:
    """Fit the best with each close competitor; keep the one the other does not add to (module docstring).

    The words are explanation lines; a pair (best, rival) marks a rival that adds to the best as the best
    adds to it, whose sentence depends on the later rounds (:func:`_both_present_sentence`).
    """
    valid, folds, settings = workflow.valid, workflow.folds, workflow.settings
    z_critical = settings.z_critical
    best, best_trial = significant[0]
    words: list[str | tuple[str, str]] = []
    close = [item for item in significant[1:] if item[0].score >= settings.lookalike_score_ratio * best.score]
    for rival, rival_trial in close[: settings.max_lookalikes]:
        pair = workflow.trial(
            [best.effect, rival.effect],
            {**naming.start, best.effect: best.parameters, rival.effect: rival.parameters},
            fixed=naming.named,
        )
        rival_adds = improvement_z(best_trial.heldout, pair.heldout, valid, folds) >= z_critical
        best_adds = improvement_z(rival_trial.heldout, pair.heldout, valid, folds) >= z_critical
        if best_adds and rival_adds:
            words.append((best.effect, rival.effect))
            continue
        # The torques are a channel neither fit has seen: when they are conclusive they decide, because a
        # one-sided translational verdict between look-alikes can come from noise in one regressor.
        rotation = _torque_evidence(workflow, best_trial, rival_trial)
        if rotation is not None:
            favoured, z_rot = rotation
            if favoured is rival_trial:
                best, best_trial, rival, rival_trial = rival, rival_trial, best, best_trial
            best_signature = (
                effect_class(best.effect).torque_signature or f"{best.effect} changes the torques"
            )
            rival_signature = (
                effect_class(rival.effect).torque_signature or f"{rival.effect} changes them otherwise"
            )
            words.append(
                f"{best.effect} and {rival.effect} explain the same part of the translational error; the "
                "torque balance (roll and pitch, which neither was fitted to) agrees with "
                f"{best.effect} (z = {z_rot:.1f}): {best_signature}; {rival_signature}."
            )
            rival.verdict = f"explained away by {best.effect} (torque balance)"
            continue
        if rival_adds != best_adds and not _one_sided_survives_vertical_bias(
            workflow, best, rival, naming, rival_adds
        ):
            rival_adds = best_adds = False
        if rival_adds:
            # The rival holds what the best explains and more: it is the better explanation.
            best, best_trial, rival, rival_trial = rival, rival_trial, best, best_trial
            best_adds = True
        if best_adds:
            diff = np.nan_to_num(rival_trial.heldout) ** 2 - np.nan_to_num(best_trial.heldout) ** 2
            found = concentration(np.maximum(np.sum(diff, axis=1), 0.0), valid, workflow.variables)
            place = found[0].text if found else "no particular regime"
            words.append(
                f"{best.effect} and {rival.effect} both explain part of the error, but together they do no "
                f"better than {best.effect} alone on held-out data, while {best.effect} adds to "
                f"{rival.effect}: {best.effect} is the better explanation; it fits better where {place}."
            )
            rival.verdict = f"explained away by {best.effect}"
        else:
            best.ambiguous_with.append(rival.effect)
            rival.ambiguous_with.append(best.effect)
            words.append(
                f"{best.effect} and {rival.effect} explain the same part of the error and this log cannot "
                "tell them apart (neither adds to the other on held-out data once a few mg of accelerometer "
                "bias along body z is allowed for, and the torques do not decide): "
                f"the answer is {best.effect} or {rival.effect} (scores {best.score:.3f} and "
                f"{rival.score:.3f}; {best.effect} is listed first, not chosen). A flight covering more of "
                f"{_regime(best.effect)} and {_regime(rival.effect)} would tell them apart."
            )
    return best, best_trial, words


def _one_sided_survives_vertical_bias(
    workflow: Workflow, best: Candidate, rival: Candidate, naming: Naming, rival_is_better: bool
) -> bool:
    """Whether the better of two look-alikes still adds to the other with a body-z accelerometer bias.

    The bias is fitted as well (:meth:`Workflow.with_vertical_accelerometer_bias`). Measured without this
    check: a 30 s X8 hover with a weaker lower rotor had the true effect explained away by a payload at
    z = 4.2.
    """
    biased = workflow.with_vertical_accelerometer_bias()
    if biased is None:
        return True
    start = {**naming.start, best.effect: best.parameters, rival.effect: rival.parameters}
    worse = best if rival_is_better else rival
    alone = biased.trial([worse.effect], start, fixed=naming.named)
    pair = biased.trial([best.effect, rival.effect], start, fixed=naming.named)
    z = improvement_z(alone.heldout, pair.heldout, biased.valid, biased.folds)
    return z >= workflow.settings.z_critical


def _regime(effect_id: str) -> str:
    return effect_class(effect_id).regime or effect_id


def _torque_evidence(workflow: Workflow, a: Trial, b: Trial) -> tuple[Trial, float] | None:
    """Which of two translational fits predicts the roll and pitch torques better, if clearly.

    The fits never saw the torques, so this is out-of-sample evidence: a mass offset or a steady force
    leaves the torques as modelled, while a thrust change per rotor (coaxial loss, a speed-dependent
    thrust coefficient, a fault) scales the torques the rotors make. The modelled torques are made from
    the logged rotor speeds, whose noise a model that scales the torques down predicts less of: in a
    hover, where the rotors' torques are that noise and little else, that alone would favour it (z = 7
    for a weaker lower rotor against the true payload, measured on a 30 s X8 hover). The share of each
    residual that the speed noise makes is taken off before the two are compared.
    """
    samples, settings = workflow.samples, workflow.settings
    rows = samples.valid & np.all(np.isfinite(samples.w_dot_B), axis=1)
    if np.count_nonzero(rows) < settings.min_torque_samples:
        return None
    sigma = rotor_speed_noise(samples.omega[rows])
    r_a = torque_residual(samples, a.fit.model)[:, :2]
    r_b = torque_residual(samples, b.fit.model)[:, :2]
    noise_a = regressor_noise_sse(samples, a.fit.model, sigma, rows)
    noise_b = regressor_noise_sse(samples, b.fit.model, sigma, rows)
    z_a = improvement_z(r_b, r_a, rows, workflow.folds, noise_gain=noise_b - noise_a)
    if z_a >= settings.z_critical:
        return a, z_a
    z_b = improvement_z(r_a, r_b, rows, workflow.folds, noise_gain=noise_a - noise_b)
    if z_b >= settings.z_critical:
        return b, z_b
    return None


def rotor_speed_noise(omega: FloatArray) -> FloatArray:
    """(N,) standard deviation of each rotor's white speed noise [rad/s], robustly from a log's speeds.

    The second difference of white noise of std s has std s * sqrt(6), while a rotor's own speed (its
    motor a low-pass filter) changes little from one sample to the next; the median absolute deviation
    keeps the manoeuvres' fast changes out. Where a log holds commands rather than measured speeds, the
    controller's own jitter counts as noise too: the torque tie-breaker then decides less often, never
    more.
    """
    second = np.diff(omega, n=2, axis=0)
    deviation = np.nanmedian(np.abs(second - np.nanmedian(second, axis=0)), axis=0)
    return np.nan_to_num(1.4826 * deviation / math.sqrt(6.0))


def regressor_noise_sse(
    samples: FlightSamples, model: Model, sigma: FloatArray, rows: BoolArray, draws: int = 8
) -> float:
    """Expected sum over ``rows`` of the squared roll and pitch torque error rotor-speed noise makes.

    ``sigma``: the noise's std per rotor. Averaged over ``draws`` noisy copies of the logged speeds put
    through ``model`` (a fixed seed, so that a report is reproducible).
    """
    if not np.any(sigma > 0):
        return 0.0
    clean = torque_residual(samples, model)[:, :2]
    rng = np.random.default_rng(0)
    total = 0.0
    for _ in range(draws):
        noisy_speeds = samples.omega + sigma * rng.standard_normal(samples.omega.shape)
        noisy = dataclasses.replace(samples, omega=noisy_speeds, design_cache={})
        error = np.nan_to_num(torque_residual(noisy, model)[:, :2] - clean)
        total += float(np.sum(error[rows] ** 2))
    return total / draws
