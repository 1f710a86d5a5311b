"""Write a discrepancy report: report.json (interfaces.md), PNG plots and one self-contained report.html.

The HTML embeds its plots as base64 PNG, so the one file can be mailed or archived and still shows
everything: the verdict first, then where the disagreement is, the candidates and why one was named,
the gap before and after, and the notes on how the log was read.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from multirotor_ros.discrepancy.regimes import regime_variables
from multirotor_ros.ident.identify import json_safe
from multirotor_ros.ident.metrics import AXES, horizon_position_error, model_acceleration
from multirotor_ros.ident.plots import plot_axes, plot_bars, plot_binned

if TYPE_CHECKING:
    from multirotor_ros.discrepancy.workflow import DiscrepancyReport


def _json_default(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def dumps(document: dict[str, Any]) -> str:
    """JSON text of a report dict (NaN as null)."""
    return json.dumps(json_safe(document), indent=2, default=_json_default)


# What each plot of :func:`make_plots` shows and what to look at, by file stem (report.html's captions).
CAPTIONS = {
    "acceleration": "Measured acceleration against the baseline model and the model with the named effect, "
    "per world axis: where the baseline departs from the measurement, the named effect should follow it.",
    "residual": "Acceleration error (measured minus modelled) before and after the named effect: the gap "
    "should shrink to noise, with no structure left in time.",
    "position": "Position over 1 s horizons re-initialised on the measurement: a model that drifts away "
    "within the second is missing force; the named effect should stay on the measured track.",
    "candidates": "Every candidate's held-out share of the error removed (red: significant; the named "
    "effect and any effect this log cannot tell from it are marked in their labels).",
    "regime": "Squared acceleration error along the quantity where it gathers most: the named effect "
    "should flatten the rise.",
}


def make_plots(report: DiscrepancyReport, out_dir: Path) -> list[Path]:
    """The report's PNG files."""
    samples = report.samples
    named = " + ".join(report.missing_effects) or "nothing named"
    paths = []
    before = samples.a_W - report.residual_before
    after = samples.a_W - report.residual_after
    modelled = {"baseline": before}
    if report.missing_effects:
        modelled[f"with {named}"] = after
    paths.append(
        plot_axes(
            samples,
            samples.a_W,
            modelled,
            out_dir / "acceleration.png",
            "Measured and modelled acceleration (world ENU)",
            "m/s^2",
        )
    )
    residuals = {"baseline": report.residual_before}
    if report.missing_effects:
        residuals[f"with {named}"] = report.residual_after
    paths.append(
        plot_axes(
            samples,
            None,
            residuals,
            out_dir / "residual.png",
            "Acceleration error: measured minus modelled",
            "m/s^2",
        )
    )
    if samples.position_measured:
        _, p_before = horizon_position_error(samples, model_acceleration(samples, report.baseline_model))
        positions = {"baseline, 1 s horizons": p_before}
        if report.missing_effects:
            _, p_after = horizon_position_error(samples, model_acceleration(samples, report.final_model))
            positions[f"with {named}, 1 s horizons"] = p_after
        paths.append(
            plot_axes(
                samples,
                samples.p_WB_W,
                positions,
                out_dir / "position.png",
                "Position: measured and modelled over 1 s horizons re-initialised on the measurement",
                "m",
            )
        )
    first_round = [c for c in report.candidates if c.round == 1]
    if first_round:
        paths.append(
            plot_bars(
                [_candidate_label(c.effect, report) for c in first_round],
                [c.score for c in first_round],
                [c.significant for c in first_round],
                out_dir / "candidates.png",
                "Candidates: held-out share of the error removed (red: significant)",
                "score",
            )
        )
    if report.regimes:
        variables = {v.key: v for v in regime_variables(samples, samples_airframe(report))}
        variable = variables.get(report.regimes[0]["variable"])
        if variable is not None:
            series = {"baseline": np.sum(np.nan_to_num(report.residual_before) ** 2, axis=1)}
            if report.missing_effects:
                series[f"with {named}"] = np.sum(np.nan_to_num(report.residual_after) ** 2, axis=1)
            unit = f" [{variable.unit}]" if variable.unit else ""
            paths.append(
                plot_binned(
                    variable.values,
                    series,
                    samples.valid,
                    out_dir / "regime.png",
                    f"Squared acceleration error along {variable.label}",
                    f"{variable.label}{unit}",
                    "mean |error|^2 [(m/s^2)^2]",
                )
            )
    return paths


def _candidate_label(effect: str, report: DiscrepancyReport) -> str:
    """The candidate's name, marked when it is the named effect or a look-alike of it."""
    if effect in report.missing_effects:
        return f"{effect} (named)"
    if any(entry["effect"] == effect for entry in report.ambiguous_with):
        return f"{effect} (cannot tell apart)"
    return effect


def samples_airframe(report: DiscrepancyReport):  # noqa: ANN201 - Airframe
    """The airframe the report's models use."""
    return report.baseline_model.airframe


def _table(headers: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(value: Any) -> str:
    if value is None:
        return "&ndash;"
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


def render_html(report: DiscrepancyReport, images: list[Path]) -> str:
    """The self-contained report page."""
    e = html.escape
    document = report.to_json()
    verdict = (
        f"Missing effect: <b>{e(report.verdict())}</b>"
        if report.missing_effects
        else "Missing effect: <b>none</b> (no candidate explains a significant part of the disagreement)"
    )
    proposal = report.proposed_experiment
    experiment = (
        f"<br>To tell them apart, fly <code>{e(proposal['setpoint_file'])}</code> "
        f"({e(proposal['manoeuvre'])}, {proposal['duration_s']:g} s): worst expected separation "
        f"z = {proposal['worst_z']:.1f}"
        if proposal
        else ""
    )
    params = ", ".join(
        f"{e(k)} = {_fmt(v)}"
        + (f" &plusmn; {_fmt(report.std.get(k))}" if report.std.get(k) is not None else "")
        for k, v in document["parameters"].items()
    )
    gap = _table(
        ["", *AXES, "sum"],
        [
            [
                "mse before [(m/s²)²]",
                *(_fmt(report.mse_before[a]) for a in AXES),
                _fmt(sum(report.mse_before.values())),
            ],
            [
                "mse after [(m/s²)²]",
                *(_fmt(report.mse_after[a]) for a in AXES),
                _fmt(sum(report.mse_after.values())),
            ],
        ]
        + (
            [
                [
                    "position mse before, 1 s horizons [m²]",
                    *(_fmt(report.position_mse_before[a]) for a in AXES),
                    "",
                ],
                ["position mse after [m²]", *(_fmt(report.position_mse_after[a]) for a in AXES), ""],
            ]
            if report.position_mse_before and report.position_mse_after
            else []
        ),
    )
    where = (
        _table(
            ["axis", "from [s]", "to [s]", "share of the axis' error", "regime"],
            [
                [
                    e(w["axis"]),
                    _fmt(w["t_start"]),
                    _fmt(w["t_end"]),
                    f"{100 * w['share_of_error']:.1f} %",
                    e(w["regime"]),
                ]
                for w in report.where
            ],
        )
        if report.where
        else "<p>The error is spread evenly over time (no window holds clearly more).</p>"
    )
    regimes = _table(
        ["regime", "error there / average", "share of the error"],
        [
            [e(r["regime"]), f"{r['error_ratio']:.2f}", f"{100 * r['share_of_error']:.1f} %"]
            for r in report.regimes
        ],
    )
    candidates = _table(
        [
            "round",
            "effect",
            "score",
            "z",
            "peak force [m/s²]",
            "parameters",
            "verdict",
            "where it helps",
        ],
        [
            [
                str(c.round),
                f"<b>{e(c.effect)}</b>" if c.effect in report.missing_effects else e(c.effect),
                f"{c.score:.3f}",
                f"{c.z_statistic:.1f}",
                f"{c.peak_contribution_m_s2:.3g}",
                e(", ".join(f"{k}={v:.4g}" for k, v in c.parameters.items())),
                e(
                    c.verdict
                    + (f"; ambiguous with {', '.join(c.ambiguous_with)}" if c.ambiguous_with else "")
                    + ("; " + "; ".join(c.not_identifiable.values()) if c.not_identifiable else "")
                ),
                e(c.regime),
            ]
            for c in report.candidates
        ],
    )
    figures = "".join(
        f'<figure><img alt="{e(p.stem)}" src="data:image/png;base64,'
        f'{base64.b64encode(p.read_bytes()).decode()}">'
        f"<figcaption>{e(CAPTIONS.get(p.stem, p.name))}</figcaption></figure>"
        for p in images
    )
    listing = "".join(f"<li>{e(x)}</li>" for x in report.explanation)
    notes = "".join(f"<li>{e(x)}</li>" for x in report.notes)
    warnings = "".join(f"<li>{e(x)}</li>" for x in report.warnings) or "<li>none</li>"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Model discrepancy: {e(report.log)}</title>
<style>
body {{ font-family: sans-serif; max-width: 1100px; margin: 2em auto; line-height: 1.4; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }}
td, th {{ border: 1px solid #ccc; padding: 0.25em 0.6em; vertical-align: top; }}
th {{ background: #f0f0f0; }} figure {{ margin: 1em 0; }} img {{ max-width: 100%; }}
.verdict {{ font-size: 1.3em; padding: 0.6em; background: #f6f6ff; border-left: 5px solid #55f; }}
</style></head><body>
<h1>Model discrepancy report</h1>
<p>Log <code>{e(report.log)}</code>, airframe <code>{e(report.airframe)}</code>, baseline effects:
<code>{e(", ".join(report.baseline_effects) or "none (thrust and gravity only)")}</code>.</p>
<p class="verdict">{verdict}{("<br>Parameters: " + params) if params else ""}{experiment}</p>
<h2>Why</h2><ul>{listing}</ul>
<h2>The gap, before and after</h2>{gap}
<h2>Where the baseline disagrees with the log</h2>
<h3>Time windows</h3>{where}
<h3>Regimes</h3>{regimes}
<h2>Candidate effects</h2>{candidates}
<h2>Plots</h2>{figures}
<h2>What the numbers mean</h2><p>{e(report.metric)}</p>
<h2>Warnings</h2><ul>{warnings}</ul>
<h2>How the log was read</h2><ul>{notes}</ul>
<p>Timings [s]: {e(", ".join(f"{k} {v:.2f}" for k, v in report.timings_s.items()))}</p>
</body></html>
"""


def write_report(report: DiscrepancyReport, out_dir: Path, plots: bool = True) -> list[Path]:
    """report.json, plots and report.html; returns the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    images = make_plots(report, out_dir) if plots else []
    json_path = out_dir / "report.json"
    json_path.write_text(dumps(report.to_json()) + "\n", encoding="utf-8")
    html_path = out_dir / "report.html"
    html_path.write_text(render_html(report, images), encoding="utf-8")
    return [json_path, *images, html_path]
