"""The hidden-effect sweep (:mod:`multirotor_ros.discrepancy.sweep`) as Dask cases, one flight each."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

from multirotor_ros.campaigns.case import Campaign, Case
from multirotor_ros.campaigns.report import png
from multirotor_ros.discrepancy.sweep import (
    PARAMETER_TOLERANCE,
    case_name,
    gap_ratio,
    judge,
    parameter_errors,
    run_sweep_case,
    sweep_cases,
)


def campaign(only: str | None = None) -> Campaign:
    """The whole sweep, or the cases whose name (``x8-rotor_drag-s1-high``) contains ``only``."""
    cases = tuple(
        Case(case_name(case), case) for case in sweep_cases() if only is None or only in case_name(case)
    )
    if not cases:
        raise ValueError(f"no sweep case name contains {only!r} (names look like x8-rotor_drag-s1-high)")
    return Campaign("sweep", "hidden-effect sweep" + (f" (cases matching {only!r})" if only else ""), cases)


def run_case(description: Mapping[str, Any]) -> dict[str, Any]:
    """Fly, look for the missing effect, judge; the row of the table."""
    report = run_sweep_case(description)
    errors = parameter_errors(description, report)
    continuous = [abs(e) for name, e in errors.items() if name not in ("motor", "t_fault_s")]
    problems = judge(description, report)
    return {
        "airframe": description["airframe"],
        "effect": description["effect"],
        "strength": description["strength"],
        "noise": description["noise"],
        "named": report.missing_effect,
        "passed": not problems,
        "problems": "; ".join(problems),
        "parameter_errors": json.dumps(errors),
        "worst_parameter_error": max(continuous, default=math.nan),
        "gap_ratio": gap_ratio(report),
    }


def summary(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Cases passed, per noise level, and the worst parameter error with its case."""
    lines = [f"passed {sum(row['passed'] for row in rows)}/{len(rows)}"]
    for noise in sorted({row["noise"] for row in rows}):
        mine = [row for row in rows if row["noise"] == noise]
        lines.append(f"  noise {noise}: {sum(row['passed'] for row in mine)}/{len(mine)}")
    measured = [row for row in rows if not math.isnan(row["worst_parameter_error"])]
    if measured:
        worst = max(measured, key=lambda row: row["worst_parameter_error"])
        lines.append(
            f"worst relative parameter error {100 * worst['worst_parameter_error']:.1f} % "
            f"({worst['airframe']}, {worst['effect']}, strength {worst['strength']}, noise {worst['noise']})"
        )
    lines += [
        f"  {row['airframe']} {row['effect']} s{row['strength']} {row['noise']}: {row['problems']}"
        for row in rows
        if not row["passed"]
    ]
    return lines


def figures(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, bytes]]:
    """Per effect: the relative error of every continuous parameter, each case a point, the tolerance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [
        (row["effect"], name, error, row["noise"])
        for row in rows
        for name, error in json.loads(row["parameter_errors"]).items()
        if name not in ("motor", "t_fault_s")
    ]
    if not points:
        return []
    effects = sorted({point[0] for point in points})
    names = {effect: sorted({p[1] for p in points if p[0] == effect}) for effect in effects}
    figure, axes = plt.subplots(figsize=(max(6.0, 0.9 * len(effects) + 2), 4.5))
    for noise, marker in (("low", "o"), ("high", "^"), ("none", "s")):
        mine = [point for point in points if point[3] == noise]
        if mine:
            x = [effects.index(p[0]) + _offset(p[1], names[p[0]]) for p in mine]
            axes.scatter(x, [100 * p[2] for p in mine], marker=marker, s=18, label=f"noise {noise}")
    for bound in (-PARAMETER_TOLERANCE, PARAMETER_TOLERANCE):
        axes.axhline(100 * bound, linestyle="--", linewidth=1, color="0.4")
    axes.set_xticks(range(len(effects)), effects, rotation=30, ha="right")
    axes.set_ylabel("fitted parameter error [% of the truth]")
    axes.legend(fontsize=8)
    figure.tight_layout()
    return [("Parameter error per effect", png(figure))]


def _offset(name: str, names: list[str]) -> float:
    """Parameters of one effect side by side around its tick."""
    return 0.15 * (names.index(name) - (len(names) - 1) / 2)
