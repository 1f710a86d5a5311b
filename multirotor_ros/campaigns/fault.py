"""Fault-diagnosis campaign as Dask cases: one simulated rotor fault per case, diagnosed on its own.

The cases are those of :func:`multirotor_ros.diagnosis.campaign.campaign_cases` (same airframe, count and
seed, same faults) and each is flown by :func:`~multirotor_ros.diagnosis.campaign.fly_case` and replayed
by :func:`~multirotor_ros.diagnosis.campaign.replay`, scored by the same requirements. One difference from
``run_campaign``, which replays all flights as one batch sharing one generator: here the state
estimator's velocity noise of a case comes from the case's own seed, so that a case gives the same row
wherever and with whatever neighbours it runs.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from multirotor_ros.campaigns.case import Campaign, Case, keyed
from multirotor_ros.campaigns.report import png
from multirotor_ros.diagnosis.campaign import (
    CaseOutcome,
    FaultCase,
    campaign_cases,
    fly_case,
    measurements_from_logs,
    replay,
    required_delay_s,
)
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.model import Model

# Second entry of the velocity-noise generator's seed: the flight's own generator is seeded by the seed alone.
_VELOCITY_NOISE_STREAM = 1


def campaign(
    airframes: Sequence[str],
    faults: int,
    seed: int = 0,
    duration_s: float = 3.5,
    velocity_noise_m_s: float = 0.02,
) -> Campaign:
    """``faults`` cases per airframe (0: 13 per rotor, >= 100, as bench/bench_diagnosis.py)."""
    cases: list[Case] = []
    for name in airframes:
        n_rotors = load_airframe(name).n_rotors
        n_faults = faults or n_rotors * -(-100 // n_rotors)
        descriptions = [
            {
                "airframe": name,
                "motor": case.motor,
                "effectiveness": case.effectiveness,
                "onset_s": case.onset_s,
                "seed": case.seed,
                "duration_s": duration_s,
                "velocity_noise_m_s": velocity_noise_m_s,
            }
            for case in campaign_cases(n_rotors, n_faults, np.random.default_rng(seed))
        ]
        cases += keyed(name, descriptions)
    return Campaign("fault", f"fault-diagnosis campaign, seed {seed}", tuple(cases))


@functools.cache
def _airframe(name: str) -> Airframe:
    return load_airframe(name)


def run_case(description: Mapping[str, Any]) -> dict[str, Any]:
    """Fly and diagnose one fault; the row of the table."""
    airframe = _airframe(description["airframe"])
    case = FaultCase(
        int(description["motor"]),
        float(description["effectiveness"]),
        float(description["onset_s"]),
        int(description["seed"]),
    )
    log = fly_case(airframe, case, float(description["duration_s"]))
    noise = np.random.default_rng([case.seed, _VELOCITY_NOISE_STREAM])
    data = measurements_from_logs([log], float(description["velocity_noise_m_s"]), noise)
    trace = replay(Model(airframe), data, np.array([case.onset_s]))
    outcome = CaseOutcome(
        case=case,
        delay_s=float(trace.first_alarm_t[0] - case.onset_s),
        isolated=int(trace.first_rotor[0]),
        final_rotor=int(trace.final_rotor[0]),
        final_effectiveness=float(trace.final_effectiveness[0]),
        ambiguous=bool(trace.first_ambiguous[0]),
        false_alarm_s=float(trace.alarm_before[0]),
    )
    return {
        "airframe": airframe.name,
        "motor": case.motor,
        "effectiveness": case.effectiveness,
        "onset_s": case.onset_s,
        "delay_s": outcome.delay_s,
        "limit_s": required_delay_s(case.effectiveness),
        "in_time": outcome.in_time,
        "isolated": outcome.isolated,
        "isolated_right": outcome.isolated_right,
        "ambiguous": outcome.ambiguous,
        "final_effectiveness": outcome.final_effectiveness,
        "false_alarm_s": outcome.false_alarm_s,
    }


def summary(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per airframe, over the cases that ran: detected, in time (by requirement), isolated, false alarms."""
    lines = []
    for name in sorted({row["airframe"] for row in rows}):
        ok = [row for row in rows if row["airframe"] == name]
        n = len(ok)
        delays = np.array([row["delay_s"] for row in ok if not math.isnan(row["delay_s"])])
        stopped = [row for row in ok if row["limit_s"] == required_delay_s(0.0)]
        half = [row for row in ok if row["limit_s"] == required_delay_s(0.5)]
        lines += [
            f"{name}: {n} faults, detected {delays.size}/{n}, in time {sum(r['in_time'] for r in ok)}/{n} "
            f"(stopped rotor within 0.2 s: {sum(r['in_time'] for r in stopped)}/{len(stopped)}; loss down "
            f"to 50 % within 0.5 s: {sum(r['in_time'] for r in half)}/{len(half)})",
            f"  right rotor isolated {sum(r['isolated_right'] for r in ok)}/{n}, coaxial partner also named "
            f"{sum(r['ambiguous'] for r in ok)}, false alarms before the onset "
            f"{sum(not math.isnan(r['false_alarm_s']) for r in ok)}; delay median "
            f"{np.median(delays) if delays.size else math.nan:.3f} s, max "
            f"{np.max(delays) if delays.size else math.nan:.3f} s",
        ]
    return lines


def figures(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, bytes]]:
    """The detection-delay distribution per requirement class, and delay against remaining effectiveness."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    detected = [row for row in rows if not math.isnan(row["delay_s"])]
    if not detected:
        return []
    figure, (histogram, scatter) = plt.subplots(1, 2, figsize=(11, 4))
    classes = sorted({row["limit_s"] for row in detected})
    bins = np.linspace(0.0, max(max(row["delay_s"] for row in detected), max(classes)) * 1.05, 30)
    for limit in classes:
        delays = [row["delay_s"] for row in detected if row["limit_s"] == limit]
        histogram.hist(delays, bins=bins, alpha=0.6, label=f"required <= {limit:g} s ({len(delays)})")
        histogram.axvline(limit, linestyle="--", linewidth=1, color="0.3")
    histogram.set_xlabel("detection delay [s]")
    histogram.set_ylabel("faults")
    histogram.legend(fontsize=8)
    for name in sorted({row["airframe"] for row in detected}):
        mine = [row for row in detected if row["airframe"] == name]
        scatter.scatter([r["effectiveness"] for r in mine], [r["delay_s"] for r in mine], s=12, label=name)
    scatter.set_xlabel("remaining effectiveness of the faulty rotor")
    scatter.set_ylabel("detection delay [s]")
    scatter.legend(fontsize=8)
    figure.tight_layout()
    return [("Detection delay", png(figure))]
