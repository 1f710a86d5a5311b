"""How long each lockstep frame took on each side: the bridge's answer, and the flight stack's own turn.

Kept only when a link is asked to (``measure_timing``: benchmarks), one entry per frame, never dropped.
ArduPilot's UDP datagrams carry the kernel's arrival time stamp, so an answer counts from the packet's
arrival, any wait in the socket's queue included; PX4's TCP stream counts from when the loop read it.
The flight stack's turn runs from our answer leaving to its next message arriving: its own work and the
two trips through the kernel. Where the link records it, ``busy`` runs from the arrival to the end of
all this side does with the frame (the answer, then its outputs; answering ahead, the next frame's
integration too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameTimes:
    """Per frame [ns]: our answer (arrival to answer out), the flight stack's turn (answer to next one).

    And, where recorded, how long the frame kept us busy (arrival to done, module docstring).
    """

    answer_ns: list[int] = field(default_factory=list)
    flight_stack_ns: list[int] = field(default_factory=list)
    busy_ns: list[int] = field(default_factory=list)
    _last_answer_ns: int = 0

    def frame(self, arrival_ns: int, answer_ns: int) -> None:
        """One frame that arrived at ``arrival_ns`` and was answered at ``answer_ns`` (CLOCK_REALTIME)."""
        self.answer_ns.append(answer_ns - arrival_ns)
        if self._last_answer_ns:
            self.flight_stack_ns.append(arrival_ns - self._last_answer_ns)
        self._last_answer_ns = answer_ns

    def busy(self, arrival_ns: int, done_ns: int) -> None:
        """A frame that arrived at ``arrival_ns`` needed nothing more from us at ``done_ns``."""
        self.busy_ns.append(done_ns - arrival_ns)

    def summary_ms(self) -> dict[str, float]:
        """Median, p95 and p99 of each [ms], and the frame count."""
        result: dict[str, float] = {"frames": float(len(self.answer_ns))}
        for name, values in (
            ("answer", self.answer_ns),
            ("flight_stack", self.flight_stack_ns),
            ("busy", self.busy_ns),
        ):
            if values:
                p50, p95, p99 = np.percentile(np.asarray(values) * 1e-6, [50, 95, 99])
                result |= {f"{name}_p50_ms": p50, f"{name}_p95_ms": p95, f"{name}_p99_ms": p99}
        return result
