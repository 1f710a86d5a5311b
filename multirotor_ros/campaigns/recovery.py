"""The fault-tolerant flight campaign (:mod:`multirotor_ros.diagnosis.recovery`, issue 15) as Dask cases.

A case is :func:`~multirotor_ros.diagnosis.recovery.recovery_case` of its seed, flown three times by
:func:`~multirotor_ros.diagnosis.recovery.fly_case_three_times` (no fault, reallocation off, on) and scored
against the issue's numbers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from multirotor_ros.campaigns.case import Campaign, Case, keyed
from multirotor_ros.campaigns.report import png
from multirotor_ros.diagnosis.recovery import (
    FLIGHT_AFTER_ONSET_S,
    ONSET_RANGE_S,
    RECOVER_WITHIN_S,
    RMS_RATIO_MAX,
    fly_case_three_times,
    recovery_case,
)
from multirotor_ros.model.airframe import load_airframe

MODES = ("off", "on")  # reallocation


def campaign(airframes: Sequence[str], cases: int, seed: int = 0) -> Campaign:
    """``cases`` cases per airframe, of the seeds ``seed``, ``seed + 1``, ... (as run_recovery_campaign)."""
    all_cases: list[Case] = []
    for name in airframes:
        load_airframe(name)  # an unknown airframe is refused here, not in every case
        all_cases += keyed(name, [{"airframe": name, "seed": seed + index} for index in range(cases)])
    return Campaign("recovery", f"fault-tolerant flight campaign, seeds from {seed}", tuple(all_cases))


def run_case(description: Mapping[str, Any]) -> dict[str, Any]:
    """Fly the case three times; the row: the fault, then each fault run's scores."""
    airframe = load_airframe(description["airframe"])
    case = recovery_case(airframe.n_rotors, int(description["seed"]))
    outcome = fly_case_three_times((airframe, case, ONSET_RANGE_S[1] + FLIGHT_AFTER_ONSET_S))
    row: dict[str, Any] = {
        "airframe": airframe.name,
        "motor": case.motor,
        "effectiveness": case.effectiveness,
        "onset_s": case.onset_s,
    }
    for mode, score in zip(MODES, (outcome.off, outcome.on), strict=True):
        row |= {
            f"{mode}_detection_delay_s": score.detection_delay_s,
            f"{mode}_recovery_s": score.recovery_s,
            f"{mode}_rms_ratio": score.rms_ratio,
            f"{mode}_max_deviation_m": score.max_deviation_m,
            f"{mode}_meets_issue": score.meets_issue,
        }
    return row


def summary(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per airframe and reallocation mode: cases meeting the issue (and of them stopped rotors), delays."""
    lines = []
    for name in sorted({row["airframe"] for row in rows}):
        mine = [row for row in rows if row["airframe"] == name]
        stopped = [row for row in mine if row["effectiveness"] == 0.0]
        for mode in MODES:
            delays = np.array([r[f"{mode}_detection_delay_s"] for r in mine])
            delays = delays[~np.isnan(delays)]
            lines.append(
                f"{name}, reallocation {mode}: back within 0.15 m within {RECOVER_WITHIN_S:g} s and RMS "
                f"ratio <= {RMS_RATIO_MAX:g} in {sum(r[f'{mode}_meets_issue'] for r in mine)}/{len(mine)} "
                f"(stopped rotors {sum(r[f'{mode}_meets_issue'] for r in stopped)}/{len(stopped)}); detected "
                f"{delays.size}/{len(mine)}, delay median "
                f"{np.median(delays) if delays.size else math.nan:.2f} s"
            )
    return lines


def figures(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, bytes]]:
    """Time to recover and RMS ratio, reallocation off against on, each case a point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (recovery, rms) = plt.subplots(1, 2, figsize=(11, 4.5))
    # A run that never comes back is drawn at the edge: inf has no place on an axis.
    never = 2 * FLIGHT_AFTER_ONSET_S
    for axes, column, limit, label in (
        (recovery, "recovery_s", RECOVER_WITHIN_S, "time to recover [s] (never: at the edge)"),
        (rms, "rms_ratio", RMS_RATIO_MAX, "RMS position error ratio"),
    ):
        off = [min(r[f"off_{column}"], never) for r in rows]
        on = [min(r[f"on_{column}"], never) for r in rows]
        colours = ["tab:red" if r["effectiveness"] == 0.0 else "tab:blue" for r in rows]
        axes.scatter(off, on, c=colours, s=14)
        axes.axvline(limit, linestyle="--", color="0.4", linewidth=1)
        axes.axhline(limit, linestyle="--", color="0.4", linewidth=1)
        axes.set_xlabel(f"reallocation off: {label}")
        axes.set_ylabel(f"reallocation on: {label}")
    recovery.set_title("red: stopped rotor, blue: partial loss", fontsize=9)
    figure.tight_layout()
    return [("Fault-tolerant flight: reallocation off against on", png(figure))]
