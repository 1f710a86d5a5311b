"""Model-discrepancy workflow timing (issue 5): a 90 s log at 100 Hz in under 10 s, plots included.

    .venv/bin/python bench/bench_discrepancy.py [--runs 3] [--effect rotor_drag]

A 90 s closed-loop flight of the X8 (multirotor_ros.simulation, 9000 samples) with one effect hidden is
written as a flight-log CSV; then the whole of `multirotor discrepancy --effects none` is timed as the
command runs it: read the CSV, find_discrepancy (baseline, where, every candidate fitted and
cross-validated, look-alikes separated, refit) and report.write (report.json, PNG plots, report.html).
Medians of several runs in CPU time of this process and wall time (the machine is shared: the limit is
judged on CPU time; the CPU time of a single-threaded run is what an idle machine's wall time would be).
The named effect and the phases' times are printed. Exit status 1 if the median misses 10 s.
"""

from __future__ import annotations

import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from multirotor_ros.discrepancy.workflow import find_discrepancy  # noqa: E402
from multirotor_ros.ident.excitation import excitation_setpoints  # noqa: E402
from multirotor_ros.io.flight_log import write_flight_log  # noqa: E402
from multirotor_ros.model.airframe import load_airframe  # noqa: E402
from multirotor_ros.simulation.flight import simulate_flight  # noqa: E402

LIMIT_S = 10.0
HIDDEN = {
    "rotor_drag": {"k_h": 1.5e-4},
    "actuator_fault": {"motor": 3, "effectiveness": 0.7, "t_fault_s": 40.0},
    "ground_effect": {"rotor_radius_m": 0.127},
    "motor_lag": {"tau_s": 0.04},
    "mass_offset": {"dm_kg": 0.15},
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--effect", default="rotor_drag", choices=sorted(HIDDEN))
    args = parser.parse_args()
    airframe = load_airframe("x8_octorotor")
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    log = simulate_flight(
        airframe,
        [{"id": args.effect, **HIDDEN[args.effect]}],
        setpoints=excitation_setpoints(90.0, np.random.default_rng(1)),
        duration_s=90.0,
        rng=np.random.default_rng(2),
        physics_rate_hz=500.0,
    )
    cpu, wall = [], []
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "flight.csv"
        write_flight_log(path, log)
        print(
            f"log: {log.t.size} samples, {log.t[-1]:.1f} s, hidden {args.effect} {HIDDEN[args.effect]}",
            flush=True,
        )
        for run in range(args.runs):
            c0, w0 = time.process_time(), time.perf_counter()
            report = find_discrepancy(airframe, path, [])
            report.write(Path(directory) / f"out{run}")
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
            phases = ", ".join(f"{k} {v:.2f}" for k, v in report.timings_s.items())
            print(
                f"run {run + 1}: named {report.missing_effect} {report.parameters}; CPU {cpu[-1]:.2f} s, "
                "wall "
                f"{wall[-1]:.2f} s (workflow phases, wall: {phases})",
                flush=True,
            )
    median = statistics.median(cpu)
    print(
        f"discrepancy, 90 s at 100 Hz, plots included: CPU median {median:.2f} s (best {min(cpu):.2f}, worst "
        f"{max(cpu):.2f}); wall median {statistics.median(wall):.2f} s; limit {LIMIT_S:g} s: "
        f"{'met' if median < LIMIT_S else 'MISSED'}"
    )
    return 0 if median < LIMIT_S else 1


if __name__ == "__main__":
    sys.exit(main())
