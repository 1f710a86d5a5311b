"""Rotor fault campaign (issue 4): >= 100 simulated faults per airframe, the table, a long fault-free flight.

    .venv/bin/python bench/bench_diagnosis.py     # X8 and hexarotor, 104/102 faults, 600 s nominal each
    .venv/bin/python bench/bench_diagnosis.py --airframe x8_octorotor --faults 16 --nominal-s 60

Flights are simulated with multirotor_ros.simulation.simulate_flight (seed 1 controller, sensor noise,
rotor lag), the diagnosis replays them batched (multirotor_ros.diagnosis.campaign). Exit status 1 when a
requirement is missed: a fault not detected in time, isolation below 95 %, or any false alarm.
"""

from __future__ import annotations

import argparse
import sys
import time

from multirotor_ros.diagnosis.campaign import nominal_check, run_campaign


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--airframe", action="append", help="airframe config name (repeatable); default: X8 and hexarotor"
    )
    parser.add_argument(
        "--faults", type=int, default=0, help="faults per airframe (default: 13 per rotor, >= 100)"
    )
    parser.add_argument(
        "--nominal-s", type=float, default=600.0, help="fault-free flight per airframe [s] (0: skip)"
    )
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--processes", type=int, default=2, help="worker processes for the flights")
    parser.add_argument(
        "--velocity-noise", type=float, default=0.02, help="state-estimator velocity noise [m/s]"
    )
    args = parser.parse_args(argv)
    airframes = args.airframe or ["x8_octorotor", "hexarotor_f550"]
    failed = False
    for name in airframes:
        started = time.perf_counter()
        from multirotor_ros.model.airframe import load_airframe

        n_rotors = load_airframe(name).n_rotors
        n_faults = args.faults or n_rotors * -(-100 // n_rotors)
        result = run_campaign(
            name, n_faults, seed=args.seed, processes=args.processes, velocity_noise_m_s=args.velocity_noise
        )
        print(result.table())
        summary = result.summary()
        failed |= summary["in_time"] < summary["faults"] or summary["isolation_rate"] < 0.95
        failed |= summary["false_alarms_before_onset"] > 0
        if args.nominal_s > 0:
            nominal = nominal_check(
                name, args.nominal_s, seed=args.seed + 1, velocity_noise_m_s=args.velocity_noise
            )
            print(nominal.describe())
            failed |= nominal.false_alarms > 0
        print(f"({name}: {time.perf_counter() - started:.0f} s wall in all)\n", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
