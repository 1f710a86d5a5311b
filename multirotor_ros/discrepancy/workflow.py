"""Find where a model and a log disagree, name the missing effect, add it, and show the gap shrink.

:func:`find_discrepancy` does, for any log and airframe (seed 1's story made automatic):

1. Runs the baseline model (the airframe with ``baseline_effects``, parameters as configured) on the
   log's measured attitude, rotor speeds, velocity and height, and compares its acceleration with the
   measured one, and its position over short re-initialised horizons (:mod:`multirotor_ros.ident.metrics`).
2. Locates the disagreement per axis, per time window and per regime (:mod:`.regimes`).
3. Fits every translational effect of effects.md that the baseline lacks (its own parameters; the
   baseline stays as configured, k_f included) and scores it on data it was not fitted on: 5-fold
   cross-validation over interleaved blocks of about 2 s (each block is predicted by the fit on the
   other four folds). The score is the held-out share of the acceleration error it removes.
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
   does not. If that is not conclusive either, the report says the log cannot separate them
   (``ambiguous_with``) and names the higher score.
5. The named effect is added and fitted on the whole log; the gap before and after is reported.
   ``max_effects`` > 1 repeats 3-5 with the named effects in the model (their linear parameters refitted
   with each linear candidate, all of them together after each round).

``none`` is named when no candidate is significant; effects that this log could not reveal (their
parameters not identifiable, e.g. drag in a hover) are listed with the reason.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from multirotor_ros.discrepancy.regimes import RegimeVariable, concentration, error_windows, regime_variables
from multirotor_ros.ident.fit import FitResult, Fitter, acceleration_residual, fit_parameters, torque_residual
from multirotor_ros.ident.metrics import horizon_position_error, model_acceleration, per_axis
from multirotor_ros.ident.parameters import ParameterRef, neutral_effect_spec
from multirotor_ros.ident.regressors import parameter_value
from multirotor_ros.ident.samples import FlightSamples, NotEnoughData, load_samples
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.effects import EFFECTS, TRANSLATIONAL_EFFECTS, Effect, make_effect
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

Progress = Callable[[str], None]
Z_CRITICAL = 3.0
NEGLIGIBLE_ACCELERATION_M_S2 = 0.05
FOLDS = 5
MIN_BLOCKS = 10
MAX_BLOCK_S = 2.0
MIN_BLOCK_S = 0.5
LOOKALIKE_SCORE_RATIO = 0.5
# Effects smaller than this must explain more than a constant accelerometer bias could (a few mg, 0.05 m/s^2,
# is what good IMUs leave after calibration; three times that is beyond any bias one would fly with).
BIAS_CHECK_BELOW_M_S2 = 0.15
MAX_LOOKALIKES = 2


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
    return {k: (int(round(v)) if k == "motor" else float(v)) for k, v in values.items()}


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
        }

    def write(self, out_dir: str | Path, plots: bool = True) -> list[Path]:
        """report.json, the PNG plots and report.html in ``out_dir`` (created); returns the files."""
        from multirotor_ros.discrepancy.report import write_report

        return write_report(self, Path(out_dir), plots=plots)


# ----------------------------------------------------------------------------------------------
# folds and statistics


@dataclass(frozen=True)
class Folds:
    """Interleaved blocks: block b of ``block_s`` seconds belongs to fold b mod k."""

    block: FloatArray  # (T,) block index of each sample
    n_blocks: int
    k: int
    block_s: float

    def test_rows(self, fold: int, valid: FloatArray) -> FloatArray:
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


def make_folds(samples: FlightSamples, k: int = FOLDS) -> Folds:
    """Blocks of about 2 s (shorter for short logs, so that there are at least MIN_BLOCKS)."""
    duration = samples.duration_s
    block_s = float(np.clip(duration / (4 * MIN_BLOCKS), MIN_BLOCK_S, MAX_BLOCK_S))
    block = np.floor((samples.t - samples.t[0]) / block_s).astype(int)
    used = np.unique(block[samples.valid])
    if used.size < MIN_BLOCKS:
        raise NotEnoughData(
            f"{samples.source}: {duration:.1f} s of usable flight; the discrepancy workflow needs at least "
            f"{MIN_BLOCKS * MIN_BLOCK_S:g} s ({MIN_BLOCKS} blocks) to fit candidates on one part of the log "
            "and "
            "test them on another"
        )
    return Folds(block, int(block.max()) + 1, k, block_s)


def block_sse(residual: FloatArray, rows: FloatArray, folds: Folds) -> FloatArray:
    """(n_blocks,) sum over samples and axes of squared residuals, per block."""
    squared = np.where(rows, np.sum(np.nan_to_num(residual) ** 2, axis=1), 0.0)
    return np.bincount(folds.block, weights=squared, minlength=folds.n_blocks)


def improvement_z(before: FloatArray, after: FloatArray, rows: FloatArray, folds: Folds) -> float:
    """How many standard deviations of noise the held-out improvement SSE(before) - SSE(after) stands at.

    With e = after (what is left) and c = before - after (what the added effect takes away), the
    improvement is sum(c^2 + 2 e.c). If the effect only fitted noise, e.c is noise times a fixed
    column, whose sum's variance is estimated block by block (sum over blocks of (sum_b e.c)^2), so
    residuals correlated within a block are accounted for. Unlike a t-test on block improvements, an
    effect acting strongly in a few blocks only (near the ground, after a fault) is not penalised for
    the blocks where it does nothing.
    """
    e = np.where(rows[:, None], np.nan_to_num(after), 0.0)
    b = np.where(rows[:, None], np.nan_to_num(before), 0.0)
    c = b - e
    gain = float(np.sum(b * b) - np.sum(e * e))
    cross = np.bincount(folds.block, weights=np.sum(e * c, axis=1), minlength=folds.n_blocks)
    spread = 2.0 * math.sqrt(float(np.sum(cross**2)))
    if spread == 0.0:
        return 0.0 if gain <= 0 else math.inf
    return gain / spread


def _without_body_bias(samples: FlightSamples, *residuals: FloatArray) -> list[FloatArray]:
    """Each residual minus its least-squares fit by a constant body-frame acceleration (an IMU bias)."""
    rows = samples.valid
    # A body-frame bias b shows in world as R b: stacked over samples, the rows of each R.
    basis = samples.R_WB[rows].reshape(-1, 3)
    out = []
    for residual in residuals:
        values = np.nan_to_num(residual[rows]).reshape(-1)
        bias = np.linalg.lstsq(basis, values, rcond=None)[0]
        corrected = np.array(residual, copy=True)
        corrected[rows] = (values - basis @ bias).reshape(-1, 3)
        out.append(corrected)
    return out


def peak_window_rms(
    contribution: FloatArray, samples: FlightSamples, rows: FloatArray, window_s: float = 1.0
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
    """The state shared by the steps of :func:`find_discrepancy`."""

    def __init__(self, samples: FlightSamples, baseline: Model, folds: Folds, progress: Progress | None):
        self.samples = samples
        self.baseline = baseline
        self.folds = folds
        self.progress = progress
        self.trials: dict[tuple[str, ...], Trial] = {}
        self.valid = samples.valid

    def _say(self, message: str) -> None:
        if self.progress is not None:
            self.progress(message)

    def model_with(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> Model:
        """The baseline plus ``effects`` at their ``start`` values."""
        specs = list(self.baseline.effects) + [make_effect({"id": e, **start[e]}) for e in effects]
        return Model(self.baseline.airframe, specs, self.baseline.gravity_m_s2)

    def residual_with(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> FloatArray:
        """Acceleration residual of :meth:`model_with`."""
        return acceleration_residual(self.samples, self.model_with(effects, start))

    def joint_fit(self, effects: Sequence[str], start: Mapping[str, Mapping[str, float]]) -> FitResult:
        """All parameters of ``effects`` fitted together on the whole log (no cross-validation)."""
        free = [(e, n) for e in effects for n in EFFECTS[e].parameter_units]
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
        airframe = self.baseline.airframe
        specs: list[Effect] = list(self.baseline.effects)
        specs += [make_effect({"id": effect_id, **start[effect_id]}) for effect_id in fixed]
        free: list[ParameterRef] = []
        for effect_id in effects:
            values = dict(start.get(effect_id) or neutral_effect_spec(effect_id, airframe))
            specs.append(make_effect({"id": effect_id, **values}))
            free += [(effect_id, name) for name in EFFECTS[effect_id].parameter_units]
        candidates_free = list(free)
        named_held: dict[ParameterRef, float] = {}
        if all(not EFFECTS[e].nonlinear_parameters for e in effects):
            for effect_id in fixed:
                for name in EFFECTS[effect_id].parameter_units:
                    free.append((effect_id, name))
                    if name in EFFECTS[effect_id].nonlinear_parameters:
                        named_held[(effect_id, name)] = float(start[effect_id][name])
        model = Model(airframe, specs, self.baseline.gravity_m_s2)
        self._say(f"fitting {' + '.join(effects)}")
        full = fit_parameters(self.samples, model, free, held=named_held)
        held = {**named_held, **{ref: parameter_value(model, ref) for ref in full.not_identifiable}}
        if ("actuator_fault", "effectiveness") in held:
            held.update({(e, n): parameter_value(model, (e, n)) for e, n in free if e == "actuator_fault"})
        heldout = np.full((self.samples.t.size, 3), np.nan)
        all_held = all(ref in held for ref in candidates_free)
        in_sample = acceleration_residual(self.samples, full.model)
        if all_held:
            heldout[:] = in_sample
        else:
            for fold in range(self.folds.k):
                test = self.folds.test_rows(fold, self.valid)
                if not np.any(test):
                    continue
                # Folds start from the whole-log fit and search its non-linear parameters nearby: the same
                # optimum when the training data agree, at a fraction of the cost of a full search.
                fitter = Fitter(
                    self.samples, full.model, free, rows=self.valid & ~test, held=held, weights=full.weights
                )
                fitted = fitter.run(refine=False, local=True)
                heldout[test] = acceleration_residual(self.samples, fitted)[test]
        trial = Trial(tuple(effects), full, heldout, in_sample)
        self.trials[key] = trial
        return trial


def _verdict_params(trial: Trial, effect_id: str) -> tuple[dict[str, float | None], dict[str, str]]:
    std = {name: trial.fit.std.get((effect_id, name)) for name in EFFECTS[effect_id].parameter_units}
    reasons = {name: why for (e, name), why in trial.fit.not_identifiable.items() if e == effect_id}
    return std, reasons


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
                effects.append(make_effect({"id": entry, **neutral_effect_spec(entry, airframe)}))
                unconfigured.append(entry)
        else:
            effects.append(make_effect(entry))
    return effects, unconfigured


def find_discrepancy(
    airframe: Airframe | str | Path,
    log: FlightLog | str | Path,
    baseline_effects: Sequence[str | Mapping[str, Any] | Effect] | None = None,
    max_effects: int = 1,
    progress: Progress | None = None,
    candidates: Sequence[str] | None = None,
    accelerometer_bias: bool = True,
) -> DiscrepancyReport:
    """Run the workflow of the module docstring; ``baseline_effects`` None = the airframe's own list.

    ``candidates`` restricts the effects tried (default: every translational effect the baseline lacks).
    ``accelerometer_bias``: when the log measures acceleration, a constant bias along body x and y is
    removed from every comparison as a nuisance (:meth:`FlightSamples.estimate_accelerometer_bias`), so
    that an IMU's few mg are not taken for a steady horizontal force.
    Raises FlightLogError, LogMismatch or NotEnoughData (all ValueError) with a message naming what is wrong.
    """
    clock = time.perf_counter()
    timings: dict[str, float] = {}
    if not isinstance(airframe, Airframe):
        airframe = load_airframe(airframe)
    if max_effects < 1:
        raise ValueError(f"max_effects must be >= 1, got {max_effects}")
    samples = load_samples(log, airframe)
    if accelerometer_bias:
        samples.estimate_accelerometer_bias(airframe.mass_kg)
    timings["load"] = time.perf_counter() - clock
    effects, unconfigured = _resolve_baseline(airframe, baseline_effects)
    baseline = Model(airframe, effects)
    notes = list(samples.notes)
    warnings = list(samples.warnings)
    if samples.nuisance is not None:
        notes.append(
            "a constant accelerometer bias along body x and y is fitted alongside every model (a nuisance, "
            "not an effect): a steady horizontal force is told from it by the vehicle's changes of heading"
        )
    if unconfigured:
        free = [(e, n) for e in unconfigured for n in EFFECTS[e].parameter_units]
        baseline = fit_parameters(samples, baseline, free, progress=progress).model
        notes.append(
            f"baseline effect(s) {', '.join(unconfigured)} have no values in {airframe.name}'s "
            "configuration: "
            "they were fitted to this log first"
        )
    folds = make_folds(samples)
    valid = samples.valid
    used_blocks = np.bincount(folds.block[valid], minlength=folds.n_blocks) > 0
    variables = regime_variables(samples, airframe)
    residual_before = acceleration_residual(samples, baseline)
    mse_before = np.mean(residual_before[valid] ** 2, axis=0)
    position_before, _ = horizon_position_error(samples, model_acceleration(samples, baseline))
    where = error_windows(
        samples, residual_before, variables, window_s=max(folds.block_s, samples.duration_s / 30)
    )
    squared_before = np.sum(residual_before**2, axis=1)
    regimes = [
        {"regime": c.text, "variable": c.variable, "error_ratio": c.ratio, "share_of_error": c.share}
        for c in concentration(squared_before, valid, variables)[:4]
    ]
    timings["baseline"] = time.perf_counter() - clock

    baseline_ids = [e.id for e in baseline.effects]
    pool = [e for e in (candidates or TRANSLATIONAL_EFFECTS) if e not in baseline_ids]
    not_testable: dict[str, str] = {}
    if "coaxial_loss" in pool and not airframe.lower_rotor_mask.any():
        pool.remove("coaxial_loss")
        not_testable["coaxial_loss"] = f"{airframe.name} has no coaxial rotors"
    if "ground_effect" in pool and not samples.height_known:
        pool.remove("ground_effect")
        not_testable["ground_effect"] = "the log has no measured height (no position, no range column)"
    if "motor_lag" in pool and baseline.rotor_time_constant_s is not None:
        pool.remove("motor_lag")

    workflow = Workflow(samples, baseline, folds, progress)
    named: list[str] = []
    start: dict[str, dict[str, float]] = {}
    all_candidates: list[Candidate] = []
    explanation: list[str] = []
    round_residual = residual_before
    round_in_sample = residual_before
    for round_number in range(1, max_effects + 1):
        before_blocks = block_sse(round_residual, valid, folds)
        round_total = float(before_blocks[used_blocks].sum())
        scored: list[tuple[Candidate, Trial]] = []
        for effect_id in pool:
            if effect_id in named:
                continue
            # Later rounds keep the named effects at their fitted values while candidates are screened (the
            # named ones are refitted jointly with the winner at the end).
            trial = workflow.trial([effect_id], start, fixed=named)
            after_blocks = block_sse(trial.heldout, valid, folds)
            score = 1.0 - float(after_blocks[used_blocks].sum()) / round_total if round_total > 0 else 0.0
            z_stat = improvement_z(round_residual, trial.heldout, valid, folds)
            contribution = round_in_sample - trial.in_sample
            peak = peak_window_rms(contribution, samples, valid)
            std, reasons = _verdict_params(trial, effect_id)
            fitted_any = any(
                (effect_id, n) not in trial.fit.not_identifiable for n in EFFECTS[effect_id].parameter_units
            )
            significant = bool(
                fitted_any and z_stat >= Z_CRITICAL and score > 0 and peak >= NEGLIGIBLE_ACCELERATION_M_S2
            )
            bias_like = False
            if significant and peak < BIAS_CHECK_BELOW_M_S2:
                # A small effect must also explain something an accelerometer bias cannot.
                z_unbiased = improvement_z(
                    *_without_body_bias(samples, round_residual, trial.heldout), valid, folds
                )
                bias_like = z_unbiased < Z_CRITICAL
                significant = not bias_like
            gain = np.sum(np.nan_to_num(round_residual) ** 2 - np.nan_to_num(trial.heldout) ** 2, axis=1)
            where_gain = concentration(np.maximum(gain, 0.0), valid, variables)
            regime = (
                f"explains most where {where_gain[0].text}"
                if where_gain and score > 0
                else "explains nothing"
            )
            candidate = Candidate(
                effect=effect_id,
                round=round_number,
                parameters=trial.parameters(effect_id),
                std=std,
                mse_after=per_axis(np.mean(trial.heldout[valid] ** 2, axis=0)),
                score=score,
                z_statistic=z_stat,
                peak_contribution_m_s2=peak,
                significant=significant,
                regime=regime,
                not_identifiable=reasons,
            )
            candidate.verdict = _verdict(candidate, fitted_any, bias_like)
            if not fitted_any and round_number == 1:
                not_testable[effect_id] = "; ".join(reasons.values())
            scored.append((candidate, trial))
        scored.sort(key=lambda item: -item[0].score)
        significant = [item for item in scored if item[0].significant]
        if not significant:
            all_candidates += [c for c, _ in scored]
            if round_number == 1:
                explanation.append(
                    "No candidate effect explains a significant part of the disagreement beyond noise on "
                    "held-out data "
                    f"(needs z >= {Z_CRITICAL:g} and a force reaching {NEGLIGIBLE_ACCELERATION_M_S2} m/s^2): "
                    "missing effect: none."
                )
            else:
                explanation.append(f"Round {round_number}: no further effect is significant; stopping.")
            break
        best, best_trial = significant[0]
        best, best_trial, lookalike_words = _separate_lookalikes(
            workflow, best, best_trial, significant, named, start, round_residual, variables
        )
        all_candidates += [c for c, _ in scored]
        named.append(best.effect)
        start[best.effect] = best_trial.parameters(best.effect)
        if len(named) > 1:
            # The named effects refitted together: an earlier one fitted alone absorbed part of the later one.
            joint = workflow.joint_fit(named, start)
            start.update(
                {e: {n: float(v) for n, v in joint.model.effect(e).parameters.items()} for e in named}
            )
        explanation.append(
            f"Round {round_number}: {best.effect} removes {100 * best.score:.1f} % of the acceleration error "
            "on held-out "
            f"data (z = {best.z_statistic:.1f}; its force reaches {best.peak_contribution_m_s2:.3g} m/s^2); "
            f"it {best.regime}."
        )
        explanation += lookalike_words
        # The next round's reference: the model with the named effects at their fitted values (nothing is
        # fitted in it, so held-out and in-sample residuals are the same).
        round_residual = round_in_sample = workflow.residual_with(named, start)
        pool = [e for e in pool if e != best.effect]
    timings["candidates"] = time.perf_counter() - clock

    if named:
        final_trial = workflow.trial(named, start)
        final_model = final_trial.fit.model
        parameters = {name: float(v) for e in named for name, v in final_trial.parameters(e).items()}
        std = {name: final_trial.fit.std.get((e, name)) for e in named for name in EFFECTS[e].parameter_units}
        for e in named:
            for name in EFFECTS[e].parameter_units:
                why = final_trial.fit.not_identifiable.get((e, name))
                if why:
                    warnings.append(f"{e}.{name}: {why}")
        residual_after = final_trial.in_sample
    else:
        final_model = baseline
        parameters, std = {}, {}
        residual_after = residual_before
    mse_after = np.mean(residual_after[valid] ** 2, axis=0)
    position_after, _ = horizon_position_error(samples, model_acceleration(samples, final_model))
    if named:
        reduction = 1.0 - float(mse_after.sum() / mse_before.sum())
        explanation.append(
            f"With {' + '.join(named)} added and fitted on the whole log, the acceleration error falls from "
            f"{mse_before.sum():.4g} to {mse_after.sum():.4g} (m/s^2)^2 summed over the axes "
            f"({100 * reduction:.1f} % less)."
        )
    if not_testable:
        explanation.append(
            "Not testable on this log: " + "; ".join(f"{e} ({why})" for e, why in not_testable.items()) + "."
        )
    explanation.append(
        "Rotational effects (gyroscopic, cg_offset) are not candidates: the workflow compares translational "
        "motion."
    )
    metric = (
        "mse_before / mse_after: mean square error per world axis of the acceleration [(m/s^2)^2], measured "
        "minus "
        "modelled over every usable sample of the log, the model driven by the log's attitude, rotor speeds, "
        "velocity "
        f"and height ({samples.chain.describe()}). mse_after: the model with the named effect(s) fitted on "
        "the whole "
        "log. candidates[].mse_after and score: held-out values ("
        + folds.describe()
        + "); score = share of the "
        "round's acceleration error removed on held-out data. position_mse_*: mean square position error "
        "[m^2] over "
        "1 s horizons re-initialised on the measured position and velocity."
    )
    timings["total"] = time.perf_counter() - clock
    return DiscrepancyReport(
        log=Path(str(samples.source)).name,
        airframe=airframe.name,
        baseline_effects=baseline_ids,
        metric=metric,
        mse_before=per_axis(mse_before),
        where=where,
        regimes=regimes,
        candidates=all_candidates,
        missing_effect=named[0] if named else "none",
        missing_effects=named,
        parameters=parameters,
        std=std,
        mse_after=per_axis(mse_after),
        position_mse_before=None if position_before is None else per_axis(position_before),
        position_mse_after=None if position_after is None else per_axis(position_after),
        explanation=explanation,
        not_testable=not_testable,
        split=folds.describe(),
        notes=notes,
        warnings=warnings,
        timings_s=timings,
        samples=samples,
        baseline_model=baseline,
        final_model=final_model,
        residual_before=residual_before,
        residual_after=residual_after,
    )


def _verdict(candidate: Candidate, fitted_any: bool, bias_like: bool = False) -> str:
    if not fitted_any:
        return "not identifiable on this log"
    if bias_like:
        return (
            f"not significant: small (at most {candidate.peak_contribution_m_s2:.3g} m/s^2) and what it "
            "explains a constant "
            f"accelerometer bias explains as well"
        )
    if candidate.significant:
        return "significant"
    reasons = []
    if candidate.score <= 0:
        reasons.append("no held-out improvement")
    elif candidate.z_statistic < Z_CRITICAL:
        reasons.append(
            f"held-out improvement within noise (z = {candidate.z_statistic:.1f} < {Z_CRITICAL:g})"
        )
    if candidate.peak_contribution_m_s2 < NEGLIGIBLE_ACCELERATION_M_S2:
        reasons.append(
            f"negligible force (at most {candidate.peak_contribution_m_s2:.3g} m/s^2, below "
            f"{NEGLIGIBLE_ACCELERATION_M_S2})"
        )
    return "not significant: " + "; ".join(reasons)


def _separate_lookalikes(
    workflow: Workflow,
    best: Candidate,
    best_trial: Trial,
    significant: list[tuple[Candidate, Trial]],
    named: list[str],
    start: dict[str, dict[str, float]],
    round_residual: FloatArray,
    variables: list[RegimeVariable],
) -> tuple[Candidate, Trial, list[str]]:
    """Fit the best with each close competitor; keep the one the other does not add to (module docstring)."""
    samples = workflow.samples
    valid = samples.valid
    folds = workflow.folds
    words: list[str] = []
    rivals = [item for item in significant[1:] if item[0].score >= LOOKALIKE_SCORE_RATIO * best.score][
        :MAX_LOOKALIKES
    ]
    for rival, rival_trial in rivals:
        pair = workflow.trial(
            [best.effect, rival.effect],
            {
                **start,
                best.effect: best.parameters,
                rival.effect: rival.parameters,
            },
            fixed=named,
        )
        rival_adds = improvement_z(best_trial.heldout, pair.heldout, valid, folds) >= Z_CRITICAL
        best_adds = improvement_z(rival_trial.heldout, pair.heldout, valid, folds) >= Z_CRITICAL
        if best_adds and rival_adds:
            words.append(
                f"{best.effect} and {rival.effect} each explain a part the other does not: both seem present "
                "(a further round names the other when --max-effects allows it)."
            )
            continue
        # The torques are a channel neither fit has seen: when they are conclusive they decide, because a
        # one-sided translational verdict between look-alikes can come from noise in one regressor.
        rotation = _torque_evidence(samples, folds, best_trial, rival_trial)
        if rotation is not None:
            favoured, z_rot = rotation
            if favoured is rival_trial:
                best, best_trial, rival, rival_trial = rival, rival_trial, best, best_trial
            words.append(
                f"{best.effect} and {rival.effect} explain the same part of the translational error; the "
                "torque "
                f"balance (roll and pitch, which neither was fitted to) agrees with {best.effect} "
                f"(z = {z_rot:.1f}): "
                f"{_TORQUE_SIGNATURE.get(best.effect, best.effect + ' changes the torques')}; "
                f"{_TORQUE_SIGNATURE.get(rival.effect, rival.effect + ' changes them otherwise')}."
            )
            rival.verdict = f"explained away by {best.effect} (torque balance)"
            continue
        if rival_adds:
            # The rival holds what the best explains and more: it is the better explanation.
            best, best_trial, rival, rival_trial = rival, rival_trial, best, best_trial
            best_adds = True
        if best_adds:
            diff = np.nan_to_num(rival_trial.heldout) ** 2 - np.nan_to_num(best_trial.heldout) ** 2
            found = concentration(np.maximum(np.sum(diff, axis=1), 0.0), valid, variables)
            place = found[0].text if found else "no particular regime"
            words.append(
                f"{best.effect} and {rival.effect} both explain part of the error, but together they do no "
                f"better than {best.effect} alone on held-out data, while {best.effect} adds to "
                f"{rival.effect}: "
                f"{best.effect} is the better explanation; it fits better where {place}."
            )
            rival.verdict = f"explained away by {best.effect}"
        else:
            best.ambiguous_with.append(rival.effect)
            rival.ambiguous_with.append(best.effect)
            words.append(
                f"{best.effect} and {rival.effect} explain the same part of the error and this log cannot "
                f"separate them (neither adds to the other on held-out data, and the torques do not decide); "
                f"{best.effect} is named for its higher score ({best.score:.3f} against {rival.score:.3f}). "
                f"A flight covering more of {_separating_regime(best.effect, rival.effect)} would tell them "
                "apart."
            )
    return best, best_trial, words


def _torque_evidence(samples: FlightSamples, folds: Folds, a: Trial, b: Trial) -> tuple[Trial, float] | None:
    """Which of two translational fits predicts the roll and pitch torques better, if clearly (|z| >= 3).

    The fits never saw the torques, so this is out-of-sample evidence: a mass offset or a steady force
    leaves the torques as modelled, while a thrust change per rotor (coaxial loss, a speed-dependent
    thrust coefficient, a fault) scales the torques the rotors make.
    """
    rows = samples.valid & np.all(np.isfinite(samples.w_dot_B), axis=1)
    if np.count_nonzero(rows) < 100:
        return None
    r_a = torque_residual(samples, a.fit.model)[:, :2]
    r_b = torque_residual(samples, b.fit.model)[:, :2]
    z_a = improvement_z(r_b, r_a, rows, folds)
    if z_a >= Z_CRITICAL:
        return a, z_a
    z_b = improvement_z(r_a, r_b, rows, folds)
    if z_b >= Z_CRITICAL:
        return b, z_b
    return None


_TORQUE_SIGNATURE = {
    "mass_offset": "a mass offset leaves the rotors' torques as modelled",
    "constant_force": "a steady force leaves the rotors' torques as modelled",
    "coaxial_loss": "a weaker lower rotor in every pair scales the roll and pitch torques by (1 + eta)/2",
    "thrust_speed_dependence": "a thrust coefficient growing with speed makes fast rotors' torques larger",
    "inflow_thrust_loss": "inflow changes each rotor's thrust with its speed, and so the torques",
    "ground_effect": "ground effect scales every rotor's thrust, and so the torques",
    "actuator_fault": "a weak rotor leaves a torque the others must balance",
    "motor_lag": "lagging rotors delay the torques too",
}


_REGIME_OF = {
    "quadratic_drag": "horizontal and vertical speeds (drag quadratic in speed)",
    "rotor_drag": "horizontal speeds at different rotor speeds (drag linear in speed)",
    "thrust_speed_dependence": "rotor speeds (thrust growing faster than omega^2)",
    "mass_offset": "accelerations (a mass scales the whole force need)",
    "coaxial_loss": "changes of the lower rotors' share of the thrust (on an X8, yaw with diagonal tilt)",
    "ground_effect": "heights within a few rotor radii of the ground",
    "inflow_thrust_loss": "climbs and descents",
    "motor_lag": "fast changes of rotor speed",
    "constant_force": "headings and attitudes (a steady force does not turn with the vehicle)",
    "actuator_fault": "flight before and after the fault with manoeuvres",
}


def _separating_regime(a: str, b: str) -> str:
    return f"{_REGIME_OF.get(a, a)} and {_REGIME_OF.get(b, b)}"
