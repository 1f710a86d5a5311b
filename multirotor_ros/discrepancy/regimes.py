"""Where a model and a log disagree: per axis, per time window and per flight regime.

A regime is a range of one quantity the effects of effects.md depend on: horizontal speed (drags),
climb rate (inflow), height (ground effect), mean rotor speed (thrust coefficient against mass),
rate of change of rotor speed (motor lag), the split of thrust between upper and lower coaxial rotors,
and time (a fault starts at a moment). Each quantity's samples are cut into five bins of equal count
(quintiles of this log), so that "high speed" means "the fastest fifth of this flight".

The same binning says where a candidate effect explains the error (its improvement per bin), and
where one candidate beats a look-alike: the regime in which they differ is the evidence for naming one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from multirotor_ros.ident.metrics import AXES
from multirotor_ros.ident.samples import FlightSamples
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import BoolArray, FloatArray

N_BINS = 5
BIN_NAMES = ("lowest fifth", "low", "middle", "high", "highest fifth")


@dataclass(frozen=True)
class RegimeVariable:
    """One quantity per sample, with its unit and how to say it."""

    key: str
    label: str
    unit: str
    values: FloatArray


def regime_variables(samples: FlightSamples, airframe: Airframe) -> list[RegimeVariable]:
    """The regime quantities of this log (height only when measured, coaxial split for coaxial rotors)."""
    v = samples.v_WB_W
    mean_speed = samples.omega.mean(axis=1)
    speed_rate = np.zeros_like(mean_speed)
    speed_rate[1:] = np.abs(np.diff(mean_speed)) / np.maximum(np.diff(samples.t), 1e-9)
    variables = [
        RegimeVariable("horizontal_speed", "horizontal speed", "m/s", np.linalg.norm(v[:, :2], axis=1)),
        RegimeVariable("climb_rate", "climb rate", "m/s", v[:, 2]),
    ]
    if samples.height_known:
        variables.append(RegimeVariable("height", "height", "m", samples.p_WB_W[:, 2]))
    variables += [
        RegimeVariable("rotor_speed", "mean rotor speed", "rad/s", mean_speed),
        RegimeVariable("rotor_speed_rate", "rate of change of rotor speed", "rad/s^2", speed_rate),
    ]
    lower = airframe.lower_rotor_mask
    if lower.any():
        squares = samples.omega**2
        share = squares[:, lower].sum(axis=1) / np.maximum(squares.sum(axis=1), 1e-9)
        variables.append(RegimeVariable("lower_share", "lower rotors' share of thrust", "", share))
    variables.append(RegimeVariable("time", "time", "s", samples.t))
    return variables


def _bins(values: FloatArray, rows: BoolArray) -> tuple[FloatArray, FloatArray]:
    """Bin index per sample (-1 outside rows) and the N_BINS + 1 quantile edges over rows."""
    edges = np.quantile(values[rows], np.linspace(0, 1, N_BINS + 1))
    index = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, N_BINS - 1)
    return np.where(rows, index, -1), edges


def _varies(values: FloatArray, rows: BoolArray) -> bool:
    """Whether a regime variable takes more than one value over the rows (a constant has no regimes)."""
    used = values[rows]
    return used.size > 1 and bool(np.ptp(used) > 1e-9 * max(float(np.max(np.abs(used))), 1e-300))


def describe_bin(variable: RegimeVariable, edges: FloatArray, b: int) -> str:
    """'horizontal speed 2.1-2.9 m/s (highest fifth of this log)'."""
    unit = f" {variable.unit}" if variable.unit else ""
    return f"{variable.label} {edges[b]:.3g} to {edges[b + 1]:.3g}{unit} ({BIN_NAMES[b]} of this log)"


@dataclass(frozen=True)
class Concentration:
    """Where a per-sample quantity (an error, an improvement) gathers most."""

    variable: str
    text: str
    bin_index: int
    ratio: float  # bin mean / overall mean
    share: float  # the bin's share of the total


def concentration(
    per_sample: FloatArray, rows: BoolArray, variables: list[RegimeVariable], exclude: tuple[str, ...] = ()
) -> list[Concentration]:
    """For each regime variable, the bin with the highest mean of ``per_sample``; sorted by that ratio."""
    total = float(np.sum(per_sample[rows]))
    mean = total / max(int(np.count_nonzero(rows)), 1)
    found: list[Concentration] = []
    if mean <= 0:
        return found
    for variable in variables:
        if variable.key in exclude or not _varies(variable.values, rows):
            continue
        index, edges = _bins(variable.values, rows)
        sums = np.array([per_sample[index == b].sum() for b in range(N_BINS)])
        counts = np.array([np.count_nonzero(index == b) for b in range(N_BINS)])
        means = sums / np.maximum(counts, 1)
        b = int(np.argmax(means))
        if f"{edges[b]:.3g}" == f"{edges[b + 1]:.3g}":
            continue  # a bin of one value (most samples share it): "0.5 to 0.5" says nothing
        found.append(
            Concentration(
                variable.key,
                describe_bin(variable, edges, b),
                b,
                float(means[b] / mean),
                float(sums[b] / total),
            )
        )
    return sorted(found, key=lambda c: -c.ratio)


def window_conditions(samples: FlightSamples, variables: list[RegimeVariable], start: int, stop: int) -> str:
    """The regime a time window is in, relative to the whole log: 'horizontal speed high (2.3 m/s), ...'."""
    parts = []
    rows = samples.valid
    for variable in variables:
        if variable.key == "time" or not _varies(variable.values, rows):
            continue
        window_rows = rows[start:stop]
        if not np.any(window_rows):
            continue
        value = float(np.mean(variable.values[start:stop][window_rows]))
        index, edges = _bins(variable.values, rows)
        b = int(np.clip(np.searchsorted(edges, value, side="right") - 1, 0, N_BINS - 1))
        if b in (0, N_BINS - 1):
            unit = f" {variable.unit}" if variable.unit else ""
            parts.append(f"{variable.label} {'low' if b == 0 else 'high'} ({value:.3g}{unit})")
    return ", ".join(parts) if parts else "ordinary flight for this log (no quantity at its extremes)"


def error_windows(
    samples: FlightSamples,
    residual: FloatArray,
    variables: list[RegimeVariable],
    window_s: float,
    limit: int = 6,
) -> list[dict[str, object]]:
    """The time windows holding the most squared error, per axis, with their share and their regime."""
    rows = samples.valid
    squared = np.where(rows[:, None], np.nan_to_num(residual) ** 2, 0.0)
    totals = squared.sum(axis=0)
    t = samples.t
    edges = np.arange(t[0], t[-1] + window_s, window_s)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 1)
    entries = []
    n_windows = len(edges)
    for a, axis in enumerate(AXES):
        if totals[a] <= 0:
            continue
        sums = np.bincount(index, weights=squared[:, a], minlength=n_windows)
        for w in np.argsort(sums)[::-1][:limit]:
            share = float(sums[w] / totals[a])
            # Only windows holding clearly more than an even share of the error are "where".
            if share < 2.0 / n_windows:
                break
            members = np.flatnonzero(index == w)
            start, stop = int(members[0]), int(members[-1]) + 1
            entries.append(
                {
                    "axis": axis,
                    "t_start": float(t[start]),
                    "t_end": float(t[stop - 1]),
                    "share_of_error": share,
                    "regime": window_conditions(samples, variables, start, stop),
                }
            )
    # Across axes, the windows that hold the most of the total error come first.
    weight = (
        {axis: float(totals[a] / totals.sum()) for a, axis in enumerate(AXES)} if totals.sum() > 0 else {}
    )
    entries.sort(key=lambda e: -cast(float, e["share_of_error"]) * weight.get(str(e["axis"]), 0.0))
    return entries[:limit]
