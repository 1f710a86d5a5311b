"""A campaign's results for people: the summary on the terminal and one self-contained HTML page.

The page carries its plots as base64 PNGs (it can be mailed or archived alone); only the per-log reports
of a logs campaign are separate files, linked relative to the page.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from multirotor_ros.campaigns.case import Campaign, kind_module

# Columns shown first in the table, and those not shown (too long: the failure list has them).
_FIRST = ("key", "status")
_HIDDEN = ("traceback", "error")


def png(figure: Any) -> bytes:
    """A matplotlib figure as PNG bytes; the figure is closed."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    plt.close(figure)
    return buffer.getvalue()


def summary_lines(campaign: Campaign, rows: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Counts, the kind's own summary over the cases that ran, and every failure with its error."""
    table = campaign.table(rows)
    ok = [row for row in table if row["status"] == "ok"]
    failed = [row for row in table if row["status"] != "ok"]
    missing = len(campaign.cases) - len(table)
    lines = [
        f"{campaign.title}: {len(campaign.cases)} cases, {len(ok)} ran, {len(failed)} failed"
        + (f", {missing} not run yet" if missing else "")
    ]
    lines += kind_module(campaign.kind).summary(ok) if ok else []
    lines += [f"FAILED {row['key']}: {row['error']}" for row in failed]
    return lines


def _cell(name: str, value: Any) -> str:
    if name == "report" and isinstance(value, str):
        return f'<a href="{html.escape(value)}">{html.escape(value)}</a>'
    if isinstance(value, float):
        return "-" if math.isnan(value) else f"{value:.4g}"
    return html.escape(str(value))


def _table(rows: Sequence[Mapping[str, Any]]) -> str:
    names = list(_FIRST)
    for row in rows:
        names += [name for name in row if name not in names and name not in _HIDDEN]
    head = "".join(f"<th>{html.escape(name)}</th>" for name in names)
    body = "".join(
        f'<tr class="{row["status"]}">'
        + "".join(f"<td>{_cell(n, row.get(n, ''))}</td>" for n in names)
        + "</tr>"
        for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_html(campaign: Campaign, rows: Mapping[str, Mapping[str, Any]], path: Path) -> Path:
    """The page: summary, plots, failures with their errors, every case's row."""
    table = campaign.table(rows)
    ok = [row for row in table if row["status"] == "ok"]
    failed = [row for row in table if row["status"] != "ok"]
    figures = kind_module(campaign.kind).figures(ok) if ok else []
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(campaign.title)}</title>",
        "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;font-size:12px}"
        "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}tr.failed{background:#fdd}"
        "pre{background:#f6f6f6;padding:1em}img{max-width:100%}</style></head><body>",
        f"<h1>{html.escape(campaign.title)}</h1>",
        "<pre>" + html.escape("\n".join(summary_lines(campaign, rows))) + "</pre>",
    ]
    for title, data in figures:
        encoded = base64.b64encode(data).decode("ascii")
        parts += [
            f"<h2>{html.escape(title)}</h2>",
            f'<img alt="{html.escape(title)}" src="data:image/png;base64,{encoded}">',
        ]
    if failed:
        parts.append("<h2>Failed cases</h2><table><tr><th>key</th><th>error</th><th>traceback</th></tr>")
        parts += [
            f"<tr><td>{html.escape(row['key'])}</td><td>{html.escape(row['error'])}</td>"
            f"<td><pre>{html.escape(rows[row['key']].get('traceback', ''))}</pre></td></tr>"
            for row in failed
        ]
        parts.append("</table>")
    parts += ["<h2>Every case</h2>", _table(table), "</body></html>"]
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
