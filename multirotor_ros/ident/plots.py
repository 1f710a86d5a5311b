"""PNG plots of measured against modelled motion (matplotlib, Agg backend: no display needed).

Every function takes the samples, the series to draw and a path, writes one PNG and returns the path.
Long logs are thinned to at most ``MAX_POINTS`` points per line (the eye cannot see more).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from multirotor_ros.ident.metrics import AXES
from multirotor_ros.ident.samples import FlightSamples
from multirotor_ros.model.rotation import BoolArray, FloatArray

MAX_POINTS = 2000
DPI = 80


def _pyplot():  # noqa: ANN202 - matplotlib.pyplot, imported lazily (slow import, optional for the library)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _thin(samples: FlightSamples) -> slice:
    return slice(None, None, max(1, samples.t.size // MAX_POINTS))


def plot_axes(
    samples: FlightSamples,
    measured: FloatArray | None,
    modelled: Mapping[str, FloatArray],
    path: Path,
    title: str,
    unit: str,
    rows: BoolArray | None = None,
) -> Path:
    """Three stacked panels (x, y, z): the measured series and each modelled one against time."""
    plt = _pyplot()
    keep = samples.valid if rows is None else rows
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    thin = _thin(samples)
    t = samples.t[thin]
    for a, ax in enumerate(axes):
        if measured is not None:
            ax.plot(t, np.where(keep, measured[:, a], np.nan)[thin], color="black", lw=0.8, label="measured")
        for (label, series), color in zip(
            modelled.items(), ("tab:red", "tab:blue", "tab:green", "tab:orange"), strict=False
        ):
            ax.plot(
                t, np.where(keep, series[:, a], np.nan)[thin], color=color, lw=0.8, label=label, alpha=0.85
            )
        ax.set_ylabel(f"{AXES[a]} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[0].set_title(title)
    axes[-1].set_xlabel("t [s]")
    # Fixed margins: tight_layout measures every text and costs more than the plot itself.
    fig.subplots_adjust(left=0.08, right=0.98, top=0.94, bottom=0.07, hspace=0.12)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_bars(
    labels: Sequence[str],
    values: Sequence[float],
    highlight: Sequence[bool],
    path: Path,
    title: str,
    xlabel: str,
) -> Path:
    """Horizontal bars, highlighted ones in colour (e.g. candidate scores, significant ones)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 0.4 * len(labels) + 1.2))
    colors = ["tab:red" if h else "tab:gray" for h in highlight]
    ax.barh(range(len(labels)), values, color=colors)
    ax.set_yticks(range(len(labels)), labels)
    ax.invert_yaxis()
    ax.axvline(0.0, color="black", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_title(title)
    ax.grid(alpha=0.3, axis="x")
    fig.subplots_adjust(left=0.3, right=0.97, top=0.9, bottom=0.5 / (0.4 * len(labels) + 1.2) + 0.05)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_binned(
    x: FloatArray,
    series: Mapping[str, FloatArray],
    rows: BoolArray,
    path: Path,
    title: str,
    xlabel: str,
    ylabel: str,
    bins: int = 12,
    equal_width: bool = False,
) -> Path:
    """Mean of each series in bins of ``x`` (a regime quantity), one line per series.

    Bins of equal count, or of equal width over x's 2nd to 98th percentile; bins with fewer than 20
    samples are left out.
    """
    plt = _pyplot()
    if equal_width:
        lo, hi = np.percentile(x[rows], [2, 98])
        edges = np.linspace(lo, hi, bins + 1)
        rows = rows & (x >= lo) & (x <= hi)
    else:
        edges = np.unique(np.quantile(x[rows], np.linspace(0, 1, bins + 1)))
    index = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centres = 0.5 * (edges[1:] + edges[:-1])
    fig, ax = plt.subplots(figsize=(7, 4))
    for (label, values), color in zip(series.items(), ("tab:red", "tab:blue", "tab:green"), strict=False):
        means = [
            np.mean(values[rows & (index == b)]) if np.count_nonzero(rows & (index == b)) >= 20 else np.nan
            for b in range(len(centres))
        ]
        ax.plot(centres, means, "o-", color=color, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.9, bottom=0.14)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
