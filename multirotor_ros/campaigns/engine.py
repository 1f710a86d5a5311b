"""Running a campaign on Dask: the cluster, the cases as tasks, streaming results, progress, resuming.

Every case is one Dask task (:func:`execute_case`). A case that raises becomes a ``failed`` row with its
error and the others go on; a worker that dies takes no case with it, because the scheduler gives the
tasks it held to the other workers (a case that kills every worker it lands on fails, after
``distributed.scheduler.allowed-failures`` tries, as ``KilledWorker``). Finished rows are flushed to the
:class:`~multirotor_ros.campaigns.store.ResultStore` every ``flush_s`` seconds, and a new run of the same
campaign into the same directory runs only the cases not stored yet.

The cluster is a ``LocalCluster`` of one single-threaded process per core (the cases are numpy and Python
loops that hold the GIL: processes, not threads, are what run them side by side), or the existing cluster
whose scheduler address is given; its workers must be able to import this package and, for the logs
campaign, read the logs and write the reports at the paths given.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import time
import traceback
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from distributed import Client, LocalCluster, as_completed, default_client

from multirotor_ros.campaigns.case import Campaign, kind_module
from multirotor_ros.campaigns.store import ResultStore

Row = dict[str, Any]


def execute_case(kind: str, key: str, description: Mapping[str, Any]) -> Row:
    """Run one case where it lands; an exception is the case's result, not the campaign's end."""
    started = time.perf_counter()
    try:
        row: Row = {"key": key, "status": "ok", "error": "", **kind_module(kind).run_case(description)}
    except Exception as error:
        # Any error is the case's own, and the campaign goes on. Its text is part of the table a rerun must
        # reproduce; the traceback is not (it names paths).
        row = {"key": key, "status": "failed", "error": f"{type(error).__name__}: {error}"}
        row["traceback"] = "".join(traceback.format_exception(error)[-6:])
    row["elapsed_s"] = time.perf_counter() - started
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return row


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A client of the cluster at ``scheduler`` (``tcp://HOST:PORT``), else of a new local cluster.

    The local cluster has ``workers`` single-threaded worker processes (default: one per core) and listens
    on 127.0.0.1 only, its HTTP server (the dashboard, with bokeh) on a free port.
    """
    if scheduler is not None:
        with Client(scheduler, timeout=30) as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            # Its warnings (a worker slow to close on a loaded machine) would clutter the progress line;
            # what matters to a campaign, a failed or lost case, is in its table.
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


class ProgressBar:
    """``[#####-----] done/total, failed, rate, ETA`` on ``stream``.

    Redrawn in place on a terminal, else a line every ``every_s`` seconds and at the end (a log file
    should not get a line per case).
    """

    def __init__(self, title: str, total: int, stream: TextIO = sys.stderr, every_s: float = 10.0) -> None:
        self.title = title
        self.total = total
        self.stream = stream
        self.every_s = every_s
        self.done = 0
        self.failed = 0
        self._already = 0
        self._started = time.monotonic()
        self._last_line = -float("inf")

    def start(self, already_done: int, already_failed: int) -> None:
        """Cases found in the store: counted as done, left out of the rate."""
        self.done = self._already = already_done
        self.failed = already_failed
        self._started = time.monotonic()
        self._draw(final=False)

    def __call__(self, row: Mapping[str, Any]) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        self._draw(final=self.done == self.total)

    def line(self) -> str:
        """The current state as one line."""
        width = 30
        filled = round(width * self.done / self.total) if self.total else width
        elapsed = time.monotonic() - self._started
        computed = self.done - self._already
        rate = computed / elapsed if elapsed > 0 else 0.0
        remaining = self.total - self.done
        eta = _clock(remaining / rate) if rate > 0 else "?" if remaining else _clock(0.0)
        return (
            f"{self.title}: [{'#' * filled}{'-' * (width - filled)}] {self.done}/{self.total} done, "
            f"{self.failed} failed, {rate:.2f} cases/s, elapsed {_clock(elapsed)}, ETA {eta}"
        )

    def _draw(self, final: bool) -> None:
        if self.stream.isatty():
            self.stream.write("\r" + self.line() + ("\n" if final else ""))
        elif final or time.monotonic() - self._last_line >= self.every_s:
            self._last_line = time.monotonic()
            self.stream.write(self.line() + "\n")
        self.stream.flush()


def _clock(seconds: float) -> str:
    whole = round(seconds)
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


@dataclass(frozen=True)
class CampaignRun:
    """What :func:`run_campaign` did: every stored row by key, and how many cases this run computed."""

    campaign: Campaign
    rows: dict[str, Row]
    computed: int
    resumed: int

    def table(self) -> list[Row]:
        """The result table in case order (:meth:`Campaign.table`)."""
        return self.campaign.table(self.rows)

    @property
    def failed(self) -> list[Row]:
        """Rows of the failed cases."""
        return [row for row in self.table() if row["status"] != "ok"]


def run_campaign(
    campaign: Campaign,
    out_dir: str | Path,
    client: Client,
    progress: ProgressBar | None = None,
    retry_failed: bool = False,
    flush_s: float = 2.0,
) -> CampaignRun:
    """Run the cases of ``campaign`` not yet in ``out_dir`` on ``client``'s cluster (module docstring).

    ``progress`` is told of the stored cases, then of each finished row; if anything interrupts the run
    (Ctrl-C, an exception of ``progress``), the finished rows are stored before the exception goes on.
    ``retry_failed`` runs the stored failures again.
    """
    store = ResultStore(out_dir, campaign)
    stored = store.rows()
    pending = [
        case
        for case in campaign.cases
        if case.key not in stored or (retry_failed and stored[case.key]["status"] != "ok")
    ]
    if progress is not None:
        pending_keys = {case.key for case in pending}
        kept = [
            stored[case.key] for case in campaign.cases if case.key in stored and case.key not in pending_keys
        ]
        progress.start(len(kept), sum(row["status"] != "ok" for row in kept))
    run_id = uuid.uuid4().hex[:8]
    futures = {
        client.submit(
            execute_case, campaign.kind, case.key, case.description, key=f"{case.key}-{run_id}", pure=False
        ): case.key
        for case in pending
    }
    buffer: list[Row] = []
    last_flush = time.monotonic()
    try:
        for future in as_completed(futures):
            if future.status == "error":
                # The task never returned: a case that killed its workers (KilledWorker), or a worker
                # that could not unpickle it.
                error = future.exception()
                row: Row = {
                    "key": futures[future],
                    "status": "failed",
                    "error": f"{type(error).__name__}: {error}",
                }
            else:
                row = future.result()
            future.release()
            stored[row["key"]] = row
            buffer.append(row)
            if progress is not None:
                progress(row)
            if time.monotonic() - last_flush >= flush_s:
                store.append(buffer)
                buffer, last_flush = [], time.monotonic()
    finally:
        store.append(buffer)
        client.cancel(list(futures))
    return CampaignRun(campaign, stored, len(pending), len(campaign.cases) - len(pending))


def map_on_dask[Job, Result](
    function: Callable[[Job], Result], jobs: Sequence[Job], processes: int = 1
) -> list[Result]:
    """``[function(job) for job in jobs]`` as Dask tasks.

    On the cluster of the current Dask client when there is one (``multirotor campaign --scheduler`` and
    the tests set it), else on a local cluster of ``processes`` workers when > 1, else in this process.
    ``function`` must be importable by the workers (a module-level function).
    """
    try:
        client = default_client()
    except ValueError:
        if processes <= 1:
            return [function(job) for job in jobs]
        with dask_client(workers=processes) as local:
            return _gather(local, function, jobs)
    return _gather(client, function, jobs)


def _gather[Job, Result](
    client: Client, function: Callable[[Job], Result], jobs: Sequence[Job]
) -> list[Result]:
    return list(client.gather(client.map(function, list(jobs), pure=False)))
