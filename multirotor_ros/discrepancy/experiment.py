"""The flight that would tell look-alikes apart (issue 14): a setpoint file and its expected separation.

When :func:`~.workflow.find_discrepancy` answers "X or Y: this log cannot tell them apart", both fitted
models explain the log. :func:`propose_experiment` flies each of them, noise-free, through every manoeuvre
of :data:`MANOEUVRES` (the closed loop of ``multirotor simulate``: the controller knows only the airframe),
fits every other look-alike to that flight as the workflow would, and measures what the fit cannot
explain against the noise of the original log. For white noise of std s per sample, a model that misses
the truth by d_t stands at sum(d_t^2) / (2 s sqrt(sum(d_t^2))) = |d| / (2 s) standard deviations in the
workflow's held-out test (:func:`~.workflow.improvement_z`), so that is the expected separation, in the
translational acceleration and in the roll and pitch torques (the workflow's tie-breaker) alike; the
larger of the two decides. The manoeuvre proposed is the one whose worst pair (either model being the
truth) separates most.
"""

from __future__ import annotations

import itertools
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from multirotor_ros.discrepancy.settings import DiscrepancySettings
from multirotor_ros.discrepancy.workflow import DiscrepancyReport, make_folds
from multirotor_ros.ident.fit import fit_parameters, torque_residual
from multirotor_ros.ident.samples import FlightSamples, load_samples
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import effect_class, make_effect
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray
from multirotor_ros.simulation.flight import SETPOINT_COLUMNS, simulate_flight

PHYSICS_RATE_HZ = 500.0  # as the hidden-effect sweep: the fits' errors, not the integrator's, must show
TAKE_OFF_S = 5.0  # every manoeuvre starts on the ground and climbs to HOLD_HEIGHT_M first
HOLD_HEIGHT_M = 2.0


@dataclass(frozen=True)
class Manoeuvre:
    """A short flight from the ground: what it excites, and its setpoints (t, x, y, z, yaw)."""

    name: str
    excites: str
    setpoints: tuple[tuple[float, float, float, float, float], ...]
    duration_s: float


def _alternating(
    name: str, excites: str, values: Sequence[tuple[float, float, float, float]], hold_s: float, repeats: int
) -> Manoeuvre:
    """Take off, then hold each of ``values`` (x, y, z, yaw) for ``hold_s`` in turn, ``repeats`` times."""
    rows = [(0.0, 0.0, 0.0, HOLD_HEIGHT_M, 0.0)]
    t = TAKE_OFF_S
    for value in itertools.islice(itertools.cycle(values), repeats * len(values)):
        rows.append((t, *value))
        t += hold_s
    rows.append((t, 0.0, 0.0, HOLD_HEIGHT_M, 0.0))
    return Manoeuvre(name, excites, tuple(rows), t + hold_s)


MANOEUVRES = (
    _alternating(
        "climbs and descents",
        "rotor speed and vertical speed over a wide range (a thrust coefficient growing with speed, "
        "inflow, a mass against a thrust change)",
        [(0.0, 0.0, 6.0, 0.0), (0.0, 0.0, 1.5, 0.0)],
        hold_s=4.0,
        repeats=3,
    ),
    _alternating(
        "lateral dashes",
        "roll and pitch torques and body-horizontal speed (a thrust change per rotor scales the torques, "
        "a mass does not; drag)",
        [(3.0, 0.0, HOLD_HEIGHT_M, 0.0), (-3.0, 0.0, HOLD_HEIGHT_M, 0.0), (0.0, 3.0, HOLD_HEIGHT_M, 0.0)],
        hold_s=3.0,
        repeats=3,
    ),
    _alternating(
        "yaw turns",
        "headings and the rotors' speed spread (a steady force does not turn with the vehicle)",
        [(0.0, 0.0, HOLD_HEIGHT_M, math.pi / 2), (0.0, 0.0, HOLD_HEIGHT_M, -math.pi / 2)],
        hold_s=3.0,
        repeats=3,
    ),
    _alternating(
        "low passes",
        "height above the ground (ground effect)",
        [(0.0, 0.0, 0.4, 0.0), (0.0, 0.0, HOLD_HEIGHT_M, 0.0)],
        hold_s=4.0,
        repeats=3,
    ),
)


@dataclass(frozen=True)
class Separation:
    """How far a flight of ``manoeuvre`` with ``truth`` lands from the best fit of ``rival``, in noise std."""

    truth: str
    rival: str
    translational_z: float
    torque_z: float

    @property
    def z(self) -> float:
        """The workflow decides on the translational fit first and the torques otherwise: the larger."""
        return max(self.translational_z, self.torque_z)


@dataclass
class Proposal:
    """The manoeuvre proposed, each pair's expected separation on it, and every manoeuvre's worst pair."""

    manoeuvre: Manoeuvre
    separations: list[Separation]
    worst_per_manoeuvre: dict[str, float]
    lookalikes: list[str]
    airframe: str
    z_needed: float

    @property
    def worst(self) -> Separation:
        return min(self.separations, key=lambda s: s.z)

    @property
    def separates(self) -> bool:
        return self.worst.z >= self.z_needed

    def summary(self) -> str:
        """One sentence for the report's explanation and the command line."""
        pairs = "; ".join(
            f"{s.truth} against {s.rival}: z = {s.z:.1f}"
            + (" (roll and pitch torques)" if s.torque_z > s.translational_z else "")
            for s in self.separations
        )
        outcome = (
            "enough to tell them apart"
            if self.separates
            else f"short of the z = {self.z_needed:g} needed: no manoeuvre tried separates them at this noise"
        )
        return (
            f"Proposed experiment to tell {' and '.join(self.lookalikes)} apart: {self.manoeuvre.name} "
            f"({self.manoeuvre.duration_s:g} s; it excites {self.manoeuvre.excites}); expected separation "
            f"in standard deviations of this log's noise, if the first were true: {pairs}: {outcome}."
        )

    def to_json(self, setpoint_file: str | Path) -> dict[str, Any]:
        """report.json's ``proposed_experiment``, the setpoint file as written."""
        return {
            "setpoint_file": str(setpoint_file),
            "manoeuvre": self.manoeuvre.name,
            "duration_s": self.manoeuvre.duration_s,
            "excites": self.manoeuvre.excites,
            "lookalikes": self.lookalikes,
            "separations": [
                {
                    "truth": s.truth,
                    "rival": s.rival,
                    "z": s.z,
                    "translational_z": s.translational_z,
                    "torque_z": s.torque_z,
                }
                for s in self.separations
            ],
            "worst_z": self.worst.z,
            "z_needed": self.z_needed,
            "separates": self.separates,
            "worst_z_per_manoeuvre": self.worst_per_manoeuvre,
        }

    def write_setpoints(self, path: str | Path) -> Path:
        """The setpoint file ``multirotor simulate --setpoints`` reads, its reasons in comment lines."""
        path = Path(path)
        lines = [
            f"# {line}"
            for line in (
                *textwrap.wrap(f"multirotor discrepancy ({self.airframe}): {self.summary()}", 100),
                "One row per setpoint, held from its t on: t [s] from take-off, x y z [m] world ENU from the",
                "start point (z up, 0 on the ground), yaw [rad]. Fly it, or simulate it with",
                f"  multirotor simulate --airframe {self.airframe} --setpoints {path.name} "
                f"--duration {self.manoeuvre.duration_s:g} --out flight.csv",
            )
        ]
        lines.append(",".join(SETPOINT_COLUMNS))
        lines += [",".join(f"{v:.6g}" for v in row) for row in self.manoeuvre.setpoints]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path


def lookalike_models(report: DiscrepancyReport) -> dict[str, Model]:
    """The named effect and each look-alike the report could not tell from it, as fitted models."""
    if not report.ambiguous_with:
        return {}
    baseline = report.baseline_model
    named = report.missing_effects[0]
    specs = [(named, _parameters_of(named, report.parameters))]
    specs += [(entry["effect"], dict(entry["parameters"])) for entry in report.ambiguous_with]
    return {
        effect_id: Model(
            baseline.airframe,
            [*baseline.effects, make_effect({"id": effect_id, **parameters})],
            baseline.gravity_m_s2,
        )
        for effect_id, parameters in specs
    }


def _parameters_of(effect_id: str, parameters: Mapping[str, float]) -> dict[str, float]:
    names = [p.name for p in effect_class(effect_id).PARAMETERS]
    return {name: float(parameters[name]) for name in names if name in parameters}


@dataclass(frozen=True)
class LogNoise:
    """Per-axis noise of the original log's residuals: acceleration [m/s^2], roll and pitch torque [N m].

    Each is the residual's std times the root of its long-run variance ratio (the variance of block sums
    over the sum of variances, blocks of the workflow's cross-validation): a residual correlated from
    sample to sample (a filtered derivative) counts fewer independent samples, as the workflow's block
    estimate of the noise does.
    """

    acceleration: FloatArray  # (3,)
    torque: FloatArray  # (2,)

    @classmethod
    def of(cls, report: DiscrepancyReport) -> LogNoise:
        """What the named model leaves of the log: the noise a proposed flight will be read against."""
        samples = report.samples
        folds = make_folds(samples, DiscrepancySettings())
        torque = torque_residual(samples, report.final_model)[:, :2]
        torque_rows = samples.valid & np.all(np.isfinite(torque), axis=1)
        return cls(
            _effective_std(report.residual_after, samples.valid, folds.block),
            _effective_std(torque, torque_rows, folds.block),
        )


def _effective_std(residual: FloatArray, rows: BoolArray, block: NDArray[np.intp]) -> FloatArray:
    values = np.where(rows[:, None], np.nan_to_num(residual), 0.0)
    squares = np.sum(values**2, axis=0)
    block_sums = np.stack([np.bincount(block, weights=column) for column in values.T], axis=1)
    ratio = np.maximum(np.sum(block_sums**2, axis=0) / squares, 1.0)
    return np.sqrt(squares / np.count_nonzero(rows) * ratio)


def separation(
    truth_log_samples: FlightSamples, truth: str, rival: str, rival_model: Model, noise: LogNoise
) -> Separation:
    """Fit ``rival``'s parameters (starting at its fitted values) to a flight of the truth; what is left."""
    free = [(rival, p.name) for p in effect_class(rival).parameter_list(rival_model.n_rotors)]
    fit = fit_parameters(truth_log_samples, rival_model, free)
    rows = fit.rows
    miss = np.nan_to_num(fit.residual[rows]) / noise.acceleration
    torque = torque_residual(truth_log_samples, fit.model)[:, :2]
    torque_rows = rows & np.all(np.isfinite(torque), axis=1)
    torque_miss = torque[torque_rows] / noise.torque
    return Separation(
        truth,
        rival,
        float(np.sqrt(np.sum(miss**2))) / 2.0,
        float(np.sqrt(np.sum(torque_miss**2))) / 2.0 if torque_miss.size else 0.0,
    )


def propose_experiment(
    report: DiscrepancyReport,
    manoeuvres: Sequence[Manoeuvre] = MANOEUVRES,
    z_needed: float | None = None,
) -> Proposal | None:
    """The manoeuvre that best separates the report's look-alikes (None when the report names no tie).

    ``z_needed``: the separation the proposal must reach to say it tells them apart (default: the
    workflow's z_critical plus one, a margin for the noise of the flight itself).
    """
    models = lookalike_models(report)
    if not models:
        return None
    noise = LogNoise.of(report)
    airframe: Airframe = report.baseline_model.airframe
    needed = DiscrepancySettings().z_critical + 1.0 if z_needed is None else z_needed
    best: tuple[float, Manoeuvre, list[Separation]] | None = None
    worst_per_manoeuvre: dict[str, float] = {}
    for manoeuvre in manoeuvres:
        separations = []
        for truth, truth_model in models.items():
            samples = load_samples(_noise_free_flight(truth_model, manoeuvre), airframe)
            for rival, rival_model in models.items():
                if rival != truth:
                    separations.append(separation(samples, truth, rival, rival_model, noise))
        worst = min(s.z for s in separations)
        worst_per_manoeuvre[manoeuvre.name] = worst
        if best is None or worst > best[0]:
            best = (worst, manoeuvre, separations)
    assert best is not None
    _, manoeuvre, separations = best
    return Proposal(manoeuvre, separations, worst_per_manoeuvre, list(models), airframe.name, needed)


def _noise_free_flight(model: Model, manoeuvre: Manoeuvre) -> FlightLog:
    return simulate_flight(
        model,
        setpoints=np.array(manoeuvre.setpoints),
        duration_s=manoeuvre.duration_s,
        rng=np.random.default_rng(0),
        physics_rate_hz=PHYSICS_RATE_HZ,
        noise=False,
    )
