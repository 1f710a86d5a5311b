"""Rotor fault campaign (issue 4) and the identifier node's path on a loaded machine (issue 10).

The campaign: >= 100 simulated faults per airframe, the table, a long fault-free flight.

    .venv/bin/python bench/bench_diagnosis.py     # X8 and hexarotor, 104/102 faults, 600 s nominal each
    .venv/bin/python bench/bench_diagnosis.py --airframe x8_octorotor --faults 16 --nominal-s 60
    .venv/bin/python bench/bench_diagnosis.py --no-campaign   # only the loaded-machine part

Flights are simulated with multirotor_ros.simulation.simulate_flight (seed 1 controller, sensor noise,
rotor lag) on one Dask cluster for the whole run (a local one of --processes workers, or --scheduler's),
the diagnosis replays them batched (multirotor_ros.diagnosis.campaign). The loaded-machine
part replays flights message by message through the identifier's FlightMonitor, with runs of lost
messages on each input stream (campaign.Load, loaded_check): fault-free flights from the ground with
take-off and landing, and faults with and without losses. Exit status 1 when a requirement is missed: a
fault of the campaign not detected in time, isolation below 95 %, or any false alarm.
"""

from __future__ import annotations

import argparse
import sys
import time

from multirotor_ros.campaigns.engine import dask_client
from multirotor_ros.diagnosis.campaign import Load, loaded_check, nominal_check, run_campaign
from multirotor_ros.model.airframe import load_airframe


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
    parser.add_argument(
        "--no-campaign", action="store_true", help="skip the batched campaign and the nominal flight"
    )
    parser.add_argument(
        "--loaded-flights", type=int, default=10, help="fault-free flights through the monitor (0: skip)"
    )
    parser.add_argument("--loaded-flight-s", type=float, default=60.0, help="their duration [s]")
    parser.add_argument(
        "--loaded-faults", type=int, default=0, help="faults through the monitor (default: 4 per rotor)"
    )
    parser.add_argument(
        "--loss-rate", type=float, default=0.005, help="share of messages that start a run of lost ones"
    )
    parser.add_argument("--loss-run", type=int, default=10, help="longest run of lost messages")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--processes", type=int, default=2, help="local Dask workers for the flights")
    parser.add_argument("--scheduler", help="fly on an existing Dask cluster instead (tcp://HOST:PORT)")
    parser.add_argument(
        "--velocity-noise", type=float, default=0.02, help="state-estimator velocity noise [m/s]"
    )
    args = parser.parse_args(argv)
    # One cluster for every batch of flights below (they find it as the current Dask client).
    with dask_client(args.scheduler, None if args.scheduler else args.processes):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    airframes = args.airframe or ["x8_octorotor", "hexarotor_f550"]
    failed = False
    for name in airframes:
        started = time.perf_counter()
        n_rotors = load_airframe(name).n_rotors
        if not args.no_campaign:
            n_faults = args.faults or n_rotors * -(-100 // n_rotors)
            result = run_campaign(
                name, n_faults, args.seed, args.processes, velocity_noise_m_s=args.velocity_noise
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
        if args.loaded_flights > 0:
            loaded = loaded_check(
                name,
                Load(args.loss_rate, args.loss_run),
                args.loaded_flights,
                args.loaded_flight_s,
                args.loaded_faults or 4 * n_rotors,
                seed=args.seed + 2,
                processes=args.processes,
                velocity_noise_m_s=args.velocity_noise,
            )
            print(loaded.describe())
            failed |= any(trace.alarms for trace in loaded.nominal)
            failed |= any(
                trace.alarms_before(case.onset_s)
                for traces in (loaded.intact, loaded.loaded)
                for case, trace in zip(loaded.cases, traces, strict=True)
            )
        print(f"({name}: {time.perf_counter() - started:.0f} s wall in all)\n", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
