"""Offline identification: fit the base model's k_f and the parameters of chosen effects to a flight log.

:func:`identify` is what ``multirotor identify`` runs. The model is the airframe's rigid body and thrust
plus exactly the effects asked for (the airframe's own effect list is replaced); k_f and every parameter
of those effects are fitted (:mod:`multirotor_ros.ident.fit`), ``actuator_fault``'s rotor and onset by
search. Effects the airframe configures start from its values, the others from "no effect".

The result says, per parameter, the value and its standard deviation, or that it is not identifiable on
this log and why (then its value is ``None`` in :attr:`IdentificationResult.parameters`, never a number
the data do not support), and the acceleration error per axis before (the model at its starting values)
and after the fit, on the identification log and, if given, on a separate validation log (seed 1 §III-C
uses one experiment to identify and another to validate).

Several logs of the vehicle (``--log`` repeated) are fitted together
(:func:`~multirotor_ros.ident.samples.concatenate_samples`: each keeps its segments and accelerometer bias).
From the same logs comes the vehicle's rotor balance (:mod:`multirotor_ros.ident.rotor_balance`): what
each rotor carries in steady flight, the weight, the centre of gravity and the yaw balance, with the
flight-to-flight scatter that the discrepancy workflow later measures a suspect flight against.

Writes (:meth:`IdentificationResult.write`): ``identified.json``, ``<airframe>_identified.yaml`` (an
airframe YAML with the fitted values and the ``rotor_balance`` section, which
:func:`~multirotor_ros.model.airframe.load_airframe` reads) and PNG plots of measured against modelled
acceleration and position.
"""

from __future__ import annotations

import datetime
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from multirotor_ros.ident.fit import FitResult, acceleration_residual, fit_parameters, nuisance_estimate
from multirotor_ros.ident.metrics import AXES, horizon_position_error, model_acceleration, per_axis
from multirotor_ros.ident.parameters import AIRFRAME, K_F, FittedParameter, ParameterRef, parameter_facts
from multirotor_ros.ident.rotor_balance import (
    BaselineState,
    RotorBalanceError,
    RotorBaseline,
    baseline_state_std,
    flight_balance,
    rotor_baseline,
)
from multirotor_ros.ident.samples import FlightSamples, concatenate_samples, load_samples
from multirotor_ros.io.flight_log import FlightLog, read_flight_log
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.effects import EFFECTS, effect_class, make_effect
from multirotor_ros.model.model import Model

Progress = Callable[[str], None]


@dataclass
class LogFit:
    """Errors of the model before and after on one log."""

    log: str
    mse_before: dict[str, float]
    mse_after: dict[str, float]
    position_mse_before: dict[str, float] | None
    position_mse_after: dict[str, float] | None

    def to_json(self) -> dict[str, Any]:
        """Plain dict."""
        return dict(self.__dict__)


@dataclass
class IdentificationResult:
    """What :func:`identify` found (module docstring)."""

    airframe: Airframe
    effects: list[str]
    parameters: dict[str, float | None]
    std: dict[str, float | None]
    not_identifiable: dict[str, str]
    held_at: dict[str, float]
    identification: LogFit
    validation: LogFit | None
    fit: FitResult
    model_before: Model
    model_after: Model
    samples: FlightSamples
    validation_samples: FlightSamples | None
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    nuisance: dict[str, float] = field(default_factory=dict)
    rotor_balance: RotorBaseline | None = None

    @property
    def mse_before(self) -> dict[str, float]:
        """Acceleration mse per axis [(m/s^2)^2] of the starting model on the identification log."""
        return self.identification.mse_before

    @property
    def mse_after(self) -> dict[str, float]:
        """Acceleration mse per axis [(m/s^2)^2] of the fitted model on the identification log."""
        return self.identification.mse_after

    def to_json(self) -> dict[str, Any]:
        """identified.json as a dict (interfaces.md: parameters, std, mse_before, mse_after first)."""
        discrete = {ref[1] for ref in self.fit.free if parameter_facts(ref).discrete}
        return {
            "parameters": {
                k: (int(round(v)) if k in discrete and v is not None else v)
                for k, v in self.parameters.items()
            },
            "std": self.std,
            "mse_before": self.mse_before,
            "mse_after": self.mse_after,
            "airframe": self.airframe.name,
            "log": self.identification.log,
            "effects": self.effects,
            "not_identifiable": self.not_identifiable,
            "held_at": self.held_at,
            "nuisance": self.nuisance,
            "metric": (
                "mse_*: mean square error per world axis of the acceleration [(m/s^2)^2], measured minus "
                "modelled over "
                "the log's usable samples, the model driven by the log's attitude, rotor speeds, velocity "
                "and height; "
                "before = the model at its starting values (airframe configuration, or no effect), after = "
                "fitted. "
                "position_mse_*: mean square position error [m^2] over 1 s horizons re-initialised on the "
                "measurement."
            ),
            "position_mse_before": self.identification.position_mse_before,
            "position_mse_after": self.identification.position_mse_after,
            "validation": None if self.validation is None else self.validation.to_json(),
            "rotor_balance": self._rotor_balance_json(),
            "warnings": self.warnings,
            "notes": self.notes,
        }

    def _rotor_balance_json(self) -> dict[str, Any] | None:
        if self.rotor_balance is None:
            return None
        airframe = self.model_after.airframe
        state = BaselineState.of(airframe, self.rotor_balance.thrust_N)
        std = baseline_state_std(airframe, self.rotor_balance)
        return {
            **self.rotor_balance.to_section(),
            "weight_carried_kg": state.mass_kg,
            "cg_offset_m": {"r_x": state.cg_m[0], "r_y": state.cg_m[1]},
            "cw_over_ccw_drag_ratio": state.cw_drag_ratio,
            "std": {
                "weight_carried_kg": float(std[0]),
                "r_x": float(std[1]),
                "r_y": float(std[2]),
                "cw_over_ccw_drag_ratio": float(std[3]),
            },
            "not_identifiable": (
                "each rotor's own effectiveness in the normal state: steady flight gives four balances "
                "(weight, two moments, yaw) and they trade off against the centre of gravity; the rotors "
                "are judged against this balance instead"
            ),
        }

    def summary(self) -> str:
        """A few lines for a terminal."""
        lines = [
            f"identified {', '.join(['k_f', *self.effects])} on {self.identification.log} "
            f"({self.airframe.name}):"
        ]
        for name, value in self.parameters.items():
            if value is None:
                lines.append(f"  {name:16s} not identifiable (held at {self.held_at[name]:.6g})")
            else:
                sd = self.std.get(name)
                lines.append(f"  {name:16s} {value:.6g}" + ("" if sd is None else f" +/- {sd:.2g}"))
        balance = self._rotor_balance_json()
        if balance is not None:
            thrusts = ", ".join(f"{f * 1e3:.2f}" for f in balance["thrust_N"])
            lines.append(
                f"  rotor balance over {balance['flights']} flight(s): rotor thrusts [mN] {thrusts}; weight "
                f"carried {balance['weight_carried_kg'] * 1e3:.1f} g; centre of gravity "
                f"({balance['cg_offset_m']['r_x'] * 1e3:+.2f} +/- {balance['std']['r_x'] * 1e3:.2f}, "
                f"{balance['cg_offset_m']['r_y'] * 1e3:+.2f} +/- {balance['std']['r_y'] * 1e3:.2f}) mm; "
                f"cw/ccw drag ratio {balance['cw_over_ccw_drag_ratio']:.3f} "
                f"+/- {balance['std']['cw_over_ccw_drag_ratio']:.3f}"
            )
        before = ", ".join(f"{a} {self.mse_before[a]:.4g}" for a in AXES)
        after = ", ".join(f"{a} {self.mse_after[a]:.4g}" for a in AXES)
        lines.append(f"  acceleration mse [(m/s^2)^2] before: {before}; after: {after}")
        if self.validation is not None:
            vb = ", ".join(f"{a} {self.validation.mse_before[a]:.4g}" for a in AXES)
            va = ", ".join(f"{a} {self.validation.mse_after[a]:.4g}" for a in AXES)
            lines.append(f"  validation log {self.validation.log}: before {vb}; after {va}")
        return "\n".join(lines)

    def airframe_document(self) -> dict[str, Any]:
        """The airframe YAML with the fitted values (unidentified parameters keep their starting values)."""
        source = self.airframe.source_path
        document: dict[str, Any] = yaml.safe_load(source.read_text(encoding="utf-8")) if source else {}
        document = dict(document or {})
        document["name"] = f"{self.airframe.name}_identified"
        document["description"] = (
            f"{self.airframe.description or self.airframe.name}; k_f and effects identified from "
            f"{self.identification.log} by multirotor identify"
        ).strip()
        document["k_f_N_s2"] = float(self.model_after.airframe.k_f_N_s2)
        effects = []
        for effect in self.model_after.effects:
            values: dict[str, float | int] = {name: float(v) for name, v in effect.parameters.items()}
            neutral = effect.neutral_parameters(self.airframe.n_rotors)
            if all(self.parameters.get(name) is None for name in values) and values == neutral:
                continue  # nothing identified: an effect at "does nothing" only confuses a reader
            for name, value in values.items():
                if effect.parameter(name).discrete:
                    values[name] = int(round(value))
            effects.append({"id": effect.id, **values})
        document["effects"] = effects
        if self.rotor_balance is not None:
            document["rotor_balance"] = self.rotor_balance.to_section()
        return document

    def write(self, out_dir: str | Path, plots: bool = True) -> list[Path]:
        """identified.json, <airframe>_identified.yaml and plots in ``out_dir`` (created)."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        json_path = out / "identified.json"
        json_path.write_text(json.dumps(json_safe(self.to_json()), indent=2) + "\n", encoding="utf-8")
        written.append(json_path)
        yaml_path = out / f"{self.airframe.name}_identified.yaml"
        header = [
            f"# Airframe {self.airframe.name} with k_f and effect parameters identified by `multirotor "
            "identify`",
            f"# from {self.identification.log} on {datetime.date.today().isoformat()}; see identified.json "
            "for",
            "# standard deviations and the acceleration error before and after.",
        ]
        header += [
            f"# NOT identified (starting value kept): {name}: {why}"
            for name, why in self.not_identifiable.items()
        ]
        body = yaml.safe_dump(self.airframe_document(), sort_keys=False, default_flow_style=None, width=110)
        yaml_path.write_text("\n".join(header) + "\n" + body, encoding="utf-8")
        written.append(yaml_path)
        if plots:
            written += self._plots(out)
        return written

    def _plots(self, out: Path) -> list[Path]:
        from multirotor_ros.ident.plots import plot_axes

        paths = [self._thrust_coefficient_plot(out)]
        for label, samples in (("identification", self.samples), ("validation", self.validation_samples)):
            if samples is None:
                continue
            before = samples.a_W - acceleration_residual(samples, self.model_before)
            after = samples.a_W - acceleration_residual(samples, self.model_after)
            paths.append(
                plot_axes(
                    samples,
                    samples.a_W,
                    {"before": before, "identified": after},
                    out / f"{label}_acceleration.png",
                    f"{label.capitalize()} log {Path(samples.source).name}: acceleration (world ENU)",
                    "m/s^2",
                )
            )
            if samples.position_measured:
                _, p_before = horizon_position_error(samples, model_acceleration(samples, self.model_before))
                _, p_after = horizon_position_error(samples, model_acceleration(samples, self.model_after))
                paths.append(
                    plot_axes(
                        samples,
                        samples.p_WB_W,
                        {"before, 1 s horizons": p_before, "identified, 1 s horizons": p_after},
                        out / f"{label}_position.png",
                        f"{label.capitalize()} log: position over 1 s horizons re-initialised on the "
                        "measurement",
                        "m",
                    )
                )
        return paths

    def _thrust_coefficient_plot(self, out: Path) -> Path:
        """Seed 1 Fig. 4: the thrust coefficient the log shows against rotor speed, and the identified one.

        Per sample, the force along the thrust axis that the measured motion needs, minus the identified
        model's other forces, divided by sum(omega^2); binned by mean rotor speed (12 bins of equal width).
        """
        from multirotor_ros.ident.plots import plot_binned

        samples, model = self.samples, self.model_after
        ctx = samples.model_context(model)
        omega = ctx.omega
        force, _, thrust = model.wrench(ctx)
        e_z = ctx.e_z_W
        needed = np.asarray(model.mass_kg, dtype=float) * (
            samples.a_W + np.array([0.0, 0.0, model.gravity_m_s2])
        )
        other = force - thrust.sum(axis=1)[:, None] * e_z
        squares = np.sum(omega**2, axis=1)
        rows = samples.valid & (squares > 0)
        shown = np.where(
            rows, np.einsum("ti,ti->t", needed - other, e_z) / np.where(squares > 0, squares, 1.0), np.nan
        )
        fitted = np.where(rows, thrust.sum(axis=1) / np.where(squares > 0, squares, 1.0), np.nan)
        return plot_binned(
            omega.mean(axis=1),
            {"from the measured motion": shown, "identified model": fitted},
            rows,
            out / "thrust_coefficient.png",
            "Thrust coefficient against rotor speed (seed 1 Fig. 4)",
            "mean rotor speed [rad/s]",
            "thrust / sum(omega^2) [N s^2/rad^2]",
            equal_width=True,
        )


def json_safe(value: Any) -> Any:
    """A JSON-ready copy of nested dicts and lists: NaN and infinities (not JSON) become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value


def _log_fit(samples: FlightSamples, before: Model, after: Model) -> LogFit:
    valid = samples.valid
    r_before = acceleration_residual(samples, before)
    r_after = acceleration_residual(samples, after)
    p_before, _ = horizon_position_error(samples, model_acceleration(samples, before))
    p_after, _ = horizon_position_error(samples, model_acceleration(samples, after))
    return LogFit(
        log=Path(samples.source).name,
        mse_before=per_axis(np.mean(r_before[valid] ** 2, axis=0)),
        mse_after=per_axis(np.mean(r_after[valid] ** 2, axis=0)),
        position_mse_before=None if p_before is None else per_axis(p_before),
        position_mse_after=None if p_after is None else per_axis(p_after),
    )


def identify(
    airframe: Airframe | str | Path,
    log: FlightLog | str | Path | Sequence[FlightLog | str | Path],
    effects: Sequence[str],
    validation_log: FlightLog | str | Path | None = None,
    progress: Progress | None = None,
    fit_k_f: bool = True,
    accelerometer_bias: bool = True,
) -> IdentificationResult:
    """Fit k_f (unless ``fit_k_f`` is False) and the parameters of ``effects`` to ``log`` (module docstring).

    ``log``: one log, or several of the same vehicle fitted together.

    ``accelerometer_bias``: when the log's accelerations are measured, a constant bias along body x and y
    is fitted alongside as a nuisance (:meth:`FlightSamples.estimate_accelerometer_bias`) and reported.

    Raises FlightLogError, LogMismatch or NotEnoughData (ValueError) when the log cannot be used.
    """
    if not isinstance(airframe, Airframe):
        airframe = load_airframe(airframe)
    effects = list(effects)
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECTS)}")
    duplicated = sorted({e for e in effects if effects.count(e) > 1})
    if duplicated:
        raise ValueError(f"effect(s) listed twice: {', '.join(duplicated)}")
    rotational = [e for e in effects if EFFECTS[e].rotational]
    if rotational:
        raise ValueError(
            f"{', '.join(rotational)}: rotational effects are not identified from translational motion "
            "(their torques need the angular accelerations, which this identifier does not fit)"
        )
    flights = [
        entry if isinstance(entry, FlightLog) else read_flight_log(entry)
        for entry in ([log] if isinstance(log, (FlightLog, str, Path)) else log)
    ]
    parts = [load_samples(flight, airframe) for flight in flights]
    if accelerometer_bias:
        for part in parts:
            part.estimate_accelerometer_bias(airframe.mass_kg)
    samples = concatenate_samples(parts)
    if progress is not None:
        progress(f"{samples.source}: {np.count_nonzero(samples.valid)} usable samples of {samples.t.size}")
    configured = {spec["id"]: spec for spec in airframe.effect_specs()}
    start = [
        make_effect(configured.get(e) or {"id": e, **effect_class(e).neutral_parameters(airframe.n_rotors)})
        for e in effects
    ]
    model_before = Model(airframe, start)
    free: list[ParameterRef] = [(AIRFRAME, K_F)] if fit_k_f else []
    free += [(e, p.name) for e in effects for p in effect_class(e).parameter_list(airframe.n_rotors)]
    fit = fit_parameters(samples, model_before, free, progress=progress)
    model_after = fit.model

    parameters: dict[str, float | None] = {}
    std: dict[str, float | None] = {}
    not_identifiable: dict[str, str] = {}
    held_at: dict[str, float] = {}
    for ref in free:
        name = ref[1]
        value = fit.values[ref]
        why = fit.not_identifiable.get(ref)
        fitted = FittedParameter.of(ref, airframe)
        if why is not None:
            parameters[name] = None
            std[name] = None
            not_identifiable[name] = why
            held_at[name] = value
        else:
            parameters[name] = value
            bound = fitted.bound_reached(value)
            std[name] = None if bound else fit.std.get(ref)
            if bound:
                fit.notes.append(f"{name} = {value:.6g} is at its {bound}: the fit's limit, not an estimate")
            sd = std[name]
            if (
                sd is not None
                and not fitted.facts.discrete
                and abs(value - fitted.neutral) < 2 * sd
                and name != K_F
            ):
                fit.notes.append(
                    f"{name} = {value:.4g} +/- {sd:.2g} is not significantly different from "
                    f"{fitted.neutral:g} (no effect)"
                )
    warnings = list(samples.warnings) + [f"{name}: {why}" for name, why in not_identifiable.items()]
    nuisance = _nuisance_values(samples, model_after)
    if nuisance:
        fit.notes.append(
            "accelerometer bias fitted as a nuisance (body frame): "
            + ", ".join(f"{name} = {value:.4g}" for name, value in nuisance.items())
        )
    balance, balance_warnings = _rotor_balance(flights, model_after.airframe)
    warnings += balance_warnings
    validation_samples = None
    validation = None
    if validation_log is not None:
        validation_samples = load_samples(validation_log, airframe)
        warnings += [f"validation log: {w}" for w in validation_samples.warnings]
        validation = _log_fit(validation_samples, model_before, model_after)
    return IdentificationResult(
        airframe=airframe,
        effects=effects,
        parameters=parameters,
        std=std,
        not_identifiable=not_identifiable,
        held_at=held_at,
        identification=_log_fit(samples, model_before, model_after),
        validation=validation,
        fit=fit,
        model_before=model_before,
        model_after=model_after,
        samples=samples,
        validation_samples=validation_samples,
        warnings=warnings,
        notes=list(samples.notes) + fit.notes,
        nuisance=nuisance,
        rotor_balance=balance,
    )


def _rotor_balance(
    flights: Sequence[FlightLog], airframe: Airframe
) -> tuple[RotorBaseline | None, list[str]]:
    """The vehicle's rotor balance over the logs (with the identified k_f), or None and the reason."""
    try:
        return rotor_baseline([flight_balance(flight, airframe) for flight in flights])
    except RotorBalanceError as error:
        return None, [f"no rotor balance: {error}"]


def _nuisance_values(samples: FlightSamples, model: Model) -> dict[str, float]:
    """The nuisance parameters (accelerometer bias) that go with ``model`` on ``samples``."""
    if samples.nuisance is None:
        return {}
    columns = samples.nuisance
    samples.nuisance = None
    samples.design_cache.clear()
    try:
        force = acceleration_residual(samples, model) * float(np.asarray(model.mass_kg))
    finally:
        samples.nuisance = columns
        samples.design_cache.clear()
    return dict(zip(samples.nuisance_names, nuisance_estimate(samples, force).tolist(), strict=True))
