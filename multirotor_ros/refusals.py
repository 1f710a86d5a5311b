"""Refused input: why one message was refused, and the count of refusals that a person reads.

Bad input (a malformed message, a corrupt MAVLink packet) never stops a node: it is refused, counted
per reason, logged once per reason with its detail, and afterwards summarised at most once every
``summary_period_s`` of wall time, so that a flood of bad messages cannot flood the log.
No ROS here: the log is any callable taking one line (a ROS logger's ``warning``, or the Python
logger by default), so the MAVLink code and the nodes share one :class:`RefusalCounter`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

_LOGGER = logging.getLogger(__name__)


@dataclass(frozen=True)
class Refusal:
    """Why a message was refused: ``reason`` is the counting category, ``detail`` the specifics."""

    reason: str
    detail: str


class RefusalCounter:
    """Counts refused input per reason; logs the first of each reason, then throttled summaries.

    Thread-safe: the MAVLink thread and the ROS executor may refuse into one counter.
    """

    def __init__(
        self,
        log: Callable[[str], object] = _LOGGER.warning,
        what: str = "input",
        summary_period_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self._log = log
        self._what = what
        self._summary_period_s = summary_period_s
        self._clock = clock
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._counts_at_summary: dict[str, int] = {}
        self._last_summary = clock()

    @property
    def counts(self) -> dict[str, int]:
        """Refusals per reason so far (a copy)."""
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        """Refusals counted so far, all reasons together."""
        with self._lock:
            return sum(self._counts.values())

    def refuse(self, reason: str, detail: str) -> None:
        """Count one refusal; log it if it is the first of its reason, else maybe a summary."""
        line: str | None = None
        with self._lock:
            first = reason not in self._counts
            self._counts[reason] = self._counts.get(reason, 0) + 1
            now = self._clock()
            if first:
                self._counts_at_summary[reason] = 1
                line = (
                    f"refused {self._what}: {reason}: {detail} (further refusals of this kind are counted "
                    f"and summarised every {self._summary_period_s:g} s)"
                )
            elif now - self._last_summary >= self._summary_period_s:
                line = self._summary(now)
        if line:
            self._log(line)

    def _summary(self, now: float) -> str | None:
        new = {r: c - self._counts_at_summary.get(r, 0) for r, c in self._counts.items()}
        new = {r: c for r, c in new.items() if c > 0}
        elapsed_s = now - self._last_summary
        self._counts_at_summary = dict(self._counts)
        self._last_summary = now
        if not new:
            return None
        parts = ", ".join(f"{reason}: {count}" for reason, count in sorted(new.items()))
        return (
            f"refused {sum(new.values())} more {self._what} in the last {elapsed_s:.0f} s ({parts}); "
            f"total {sum(self._counts.values())}"
        )
