"""A fleet's flight logs as Dask cases: ``identify`` or ``discrepancy`` on every log of a folder or glob.

Each case is one log: converted first when it is a rosbag2, ULog, dataflash or data-driven-dynamics file
(:func:`multirotor_ros.io.convert.convert`, with the airframe's motor map), used as it is when it is a
flight-log CSV. Its report goes to ``OUT/reports/<log>/`` (``report.json``, ``report.html`` and plots for
``discrepancy``; ``identified.json``, the fitted airframe YAML and plots for ``identify``), and its row holds
what it found and the link to that report. On a remote cluster the logs and ``OUT`` must be at the same
paths on every worker (a shared filesystem).
"""

from __future__ import annotations

import glob
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from multirotor_ros.campaigns.case import Campaign, Case

ANALYSES = ("discrepancy", "identify")
# Files of a folder that are not logs: what our own reports and converters leave beside them.
_NOT_LOGS = {".json", ".html", ".png", ".yaml", ".md", ".txt"}


def find_logs(source: str) -> list[Path]:
    """The logs of ``source``: a glob, or a folder (its files, and rosbag2 folders, recursively)."""
    path = Path(source)
    if path.is_dir():
        found = []
        for root, folders, files in os.walk(path):
            if "metadata.yaml" in files:  # a rosbag2 is one log, the folder
                found.append(Path(root))
                folders.clear()
                continue
            found += [Path(root, name) for name in files if Path(name).suffix.lower() not in _NOT_LOGS]
        return sorted(found)
    return sorted(Path(match) for match in glob.glob(source, recursive=True))


def campaign(
    source: str,
    airframe: str,
    analysis: str,
    out_dir: Path,
    effects: Sequence[str] | None = None,
    max_effects: int = 1,
    plots: bool = True,
) -> Campaign:
    """One case per log of ``source``; ``effects``: the model for identify, the baseline for discrepancy."""
    if analysis not in ANALYSES:
        raise ValueError(f"analysis must be one of {', '.join(ANALYSES)}, got {analysis!r}")
    if analysis == "identify" and effects is None:
        raise ValueError("identify needs the effects to fit (--effects: comma-separated ids, or none)")
    logs = find_logs(source)
    if not logs:
        raise ValueError(f"no logs in {source!r}")
    root = Path(os.path.commonpath([log.parent for log in logs]))
    cases = []
    for log in logs:
        name = re.sub(r"[^A-Za-z0-9._-]+", "_", str(log.relative_to(root)))
        cases.append(
            Case(
                name,
                {
                    "log": str(log.resolve()),
                    "airframe": airframe,
                    "analysis": analysis,
                    "effects": None if effects is None else list(effects),
                    "max_effects": max_effects,
                    "plots": plots,
                    "report_dir": str((out_dir / "reports" / name).resolve()),
                    "report_link": f"reports/{name}/"
                    + ("report.html" if analysis == "discrepancy" else "identified.json"),
                },
            )
        )
    return Campaign("logs", f"{analysis} over {len(logs)} log(s) of {source}", tuple(cases))


def _flight_log(path: Path, airframe: Any) -> tuple[Any, str]:
    """The log to analyse and the format it came from."""
    from multirotor_ros.io.convert import ConversionError, convert, detect_format

    try:
        kind = detect_format(path)
    except ConversionError:
        # A flight-log CSV, or nothing readable: reading it as a flight log says which.
        return path, "flight-log"
    return convert(path, airframe, kind).log, kind


def run_case(description: Mapping[str, Any]) -> dict[str, Any]:
    """Analyse one log, write its report, return what it found."""
    from multirotor_ros.model.airframe import load_airframe

    airframe = load_airframe(description["airframe"])
    log, kind = _flight_log(Path(description["log"]), airframe)
    out = Path(description["report_dir"])
    row: dict[str, Any] = {"log": description["log"], "format": kind, "report": description["report_link"]}
    if description["analysis"] == "discrepancy":
        from multirotor_ros.discrepancy.workflow import find_discrepancy

        report = find_discrepancy(
            airframe, log, description["effects"], max_effects=description["max_effects"]
        )
        report.write(out, plots=description["plots"])
        before, after = sum(report.mse_before.values()), sum(report.mse_after.values())
        row |= {
            "finding": ", ".join(report.missing_effects) or "none",
            "parameters": json.dumps(report.parameters),
            "warnings": "; ".join(report.warnings),
        }
    else:
        from multirotor_ros.ident.identify import identify

        result = identify(airframe, log, description["effects"])
        result.write(out, plots=description["plots"])
        before, after = sum(result.mse_before.values()), sum(result.mse_after.values())
        row |= {
            "finding": ", ".join(f"{name} not identifiable" for name in result.not_identifiable) or "fitted",
            "parameters": json.dumps(result.parameters),
            "warnings": "; ".join(result.warnings),
        }
    return row | {
        "mse_before": before,
        "mse_after": after,
        "gap_ratio": after / before if before else math.nan,
    }


def summary(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """How many logs gave each finding."""
    findings: dict[str, int] = {}
    for row in rows:
        findings[row["finding"]] = findings.get(row["finding"], 0) + 1
    return [f"{count} log(s): {finding}" for finding, count in sorted(findings.items(), key=lambda i: -i[1])]


def figures(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, bytes]]:
    """Per log, the model's acceleration error before and after, labelled with the finding."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from multirotor_ros.campaigns.report import png

    if not rows:
        return []
    figure, axes = plt.subplots(figsize=(9, 1.2 + 0.32 * len(rows)))
    positions = range(len(rows))
    axes.barh([p + 0.2 for p in positions], [row["mse_before"] for row in rows], height=0.4, label="before")
    axes.barh([p - 0.2 for p in positions], [row["mse_after"] for row in rows], height=0.4, label="after")
    axes.set_yticks(
        list(positions), [f"{Path(row['log']).name}: {row['finding']}" for row in rows], fontsize=8
    )
    axes.set_xscale("log")
    axes.set_xlabel("acceleration mse, sum over axes [(m/s^2)^2]")
    axes.invert_yaxis()
    axes.legend(fontsize=8)
    figure.tight_layout()
    return [("Model error per log, before and after", png(figure))]
