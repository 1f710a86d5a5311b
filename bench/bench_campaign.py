"""Cases per second of the fault-diagnosis campaign: Dask local cluster against the spawned-process pool.

    .venv/bin/python bench/bench_campaign.py                    # 48 X8 faults, each way, twice
    .venv/bin/python bench/bench_campaign.py --cases 104 --airframe hexarotor_f550

The same cases (multirotor_ros.campaigns.fault: fly one fault, replay the diagnosis) go through
1. the pool the diagnosis code used before issue 17 (diagnosis.campaign.map_in_processes: a
   ProcessPoolExecutor of spawned interpreters, started for the call), with --workers processes;
2. run_campaign on a LocalCluster of --workers single-threaded worker processes (results streamed to
   Parquet, progress counted), and
3. the same on a LocalCluster of one worker: how the campaign scales from 1 to --workers.
Figures are wall-clock cases/s, with and without starting the pool or cluster (best of --rounds, each
round's in brackets, the order alternating between rounds), the CPU time of every process per case
(start-up included: what other jobs on the machine change least), and the load average before and after
(the machine may be shared: quote it). The rows of every run must be identical.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

from multirotor_ros.campaigns import fault
from multirotor_ros.campaigns.engine import dask_client, run_campaign


def _cpu_s() -> float:
    """CPU time of this process and its ended children (pool processes, Dask nannies and their workers)."""
    return sum(
        usage.ru_utime + usage.ru_stime
        for usage in (resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN))
    )


def _measured(run) -> tuple[list, float, float, float]:
    """What ``run`` returns, and the CPU seconds of every process it started, start-up included."""
    cpu = _cpu_s()
    rows, total_s, work_s = run()
    return rows, total_s, work_s, _cpu_s() - cpu


def _pool(descriptions: list, workers: int) -> tuple[list, float, float]:
    """Rows, seconds with the pool's start, seconds of the work alone (from the first submission)."""
    started = time.perf_counter()
    # As map_in_processes did: fresh interpreters, started for this call.
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        pool.submit(int).result()  # the pool is up once one worker answers
        ready = time.perf_counter()
        rows = list(pool.map(fault.run_case, descriptions))
    return rows, time.perf_counter() - started, time.perf_counter() - ready


def _dask(campaign, workers: int) -> tuple[list, float, float]:
    started = time.perf_counter()
    with dask_client(workers=workers) as client, tempfile.TemporaryDirectory() as out:
        client.wait_for_workers(workers)
        ready = time.perf_counter()
        table = run_campaign(campaign, out, client).table()
        finished = time.perf_counter()
    rows = [{k: v for k, v in row.items() if k not in ("key", "status", "error")} for row in table]
    failed = [row for row in table if row["status"] != "ok"]
    if failed:
        raise RuntimeError(f"cases failed: {failed}")
    return rows, finished - started, finished - ready


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="x8_octorotor")
    parser.add_argument("--cases", type=int, default=48)
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    parser.add_argument(
        "--rounds", type=int, default=2, help="rounds of the three runs, in alternating order"
    )
    args = parser.parse_args(argv)
    campaign = fault.campaign([args.airframe], args.cases, args.seed)
    descriptions = [dict(case.description) for case in campaign.cases]
    n = len(descriptions)
    variants = {
        f"spawned pool, {args.workers} processes": lambda: _measured(
            lambda: _pool(descriptions, args.workers)
        ),
        f"Dask LocalCluster, {args.workers} workers": lambda: _measured(
            lambda: _dask(campaign, args.workers)
        ),
        "Dask LocalCluster, 1 worker": lambda: _measured(lambda: _dask(campaign, 1)),
    }
    load_before = os.getloadavg()
    # Other jobs on a shared machine come and go: alternating the order spreads them over the variants.
    runs: dict[str, list[tuple[list, float, float, float]]] = {label: [] for label in variants}
    for round_ in range(args.rounds):
        for label in list(variants)[:: 1 if round_ % 2 == 0 else -1]:
            runs[label].append(variants[label]())
    load_after = os.getloadavg()
    print(
        f"{n} {args.airframe} fault cases (seed {args.seed}), {args.rounds} round(s); load average before "
        f"{load_before[0]:.2f}, after {load_after[0]:.2f} ({os.cpu_count()} cores)"
    )
    print(f"{'cases/s, best (each round)':<36} {'incl. start':>24} {'work only':>24} {'CPU ms/case':>20}")
    best = {}
    for label, results in runs.items():
        total = [n / total_s for _, total_s, _, _ in results]
        work = [n / work_s for _, _, work_s, _ in results]
        cpu = [1000 * cpu_s / n for _, _, _, cpu_s in results]
        best[label] = (max(total), max(work))
        each = [", ".join(f"{r:.2f}" for r in rates) for rates in (total, work)]
        each_cpu = ", ".join(f"{c:.0f}" for c in cpu)
        print(
            f"{label:<36} {max(total):>6.2f} ({each[0]:>14}) {max(work):>6.2f} ({each[1]:>14}) "
            f"{min(cpu):>5.0f} ({each_cpu:>10})"
        )
    pool, dask_n, dask_1 = best.values()
    print(
        f"Dask / pool: {dask_n[0] / pool[0]:.2f} incl. start, {dask_n[1] / pool[1]:.2f} work only; "
        f"{args.workers} workers / 1 worker: {dask_n[1] / dask_1[1]:.2f} work only"
    )
    tables = {json.dumps(rows, sort_keys=True) for results in runs.values() for rows, *_ in results}
    print(f"identical rows in every run: {'yes' if len(tables) == 1 else 'NO'}")
    return 0 if len(tables) == 1 else 1


if __name__ == "__main__":
    sys.exit(main())
