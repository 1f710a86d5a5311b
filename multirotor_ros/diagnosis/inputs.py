"""Which input went silent: the identifier's inputs watched for a stalled peer (pure, no ROS).

A peer can stall without dying: a controller once deadlocked inside its middleware and had to be
killed, and all its peers saw was silence. :class:`InputWatch` says which input went silent and for how
long, so that a person reading the identifier's log or ``diagnostics`` knows whom to look at.

An input is silent when no message of it has arrived for longer than ``timeout_s``, counted in the
node's clock (simulated time under ``use_sim_time``) or in wall time, whichever is longer: when the
simulator stalls it stops the clock too, and silence would never grow in a clock that stands still.
Arrival times are when the node took the message, whether it used it or refused it: a peer sending
bad messages is alive (the refusal counters say what is wrong with them). A resend (the same message
again: a lockstep simulator resends its newest odometry while it waits for a command) brings no data and
does not end a silence; it is counted, and a silence with resends says so: that publisher is alive and
waiting, the one it waits for is the one to look at. Before any input has been
heard nothing is judged (the node is waiting for its peers to start); from the first message of any
input on, an input never heard is as silent as one that stopped.

A node that did not run cannot tell silence from its own stall: on a loaded machine its executor may
not run for a second, and messages wait in its queues. A check that comes more than half the timeout
after the previous one judges nothing; the next one, after the queues have been read, does.

:meth:`InputWatch.check` returns a line to log (WARN) for each input that went silent, once per
episode, naming the inputs still coming; :meth:`InputWatch.heard` returns a line (INFO) when a silent
input is back; :meth:`InputWatch.status` is the state of every input as of the last check, for the
node's ``diagnostics`` (a status named ``inputs``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

NS = 1_000_000_000


@dataclass(frozen=True)
class InputsStatus:
    """The ``inputs`` status: OK while every input comes, WARN while one is silent."""

    level: Literal["OK", "WARN"]
    message: str
    values: dict[str, str]


@dataclass
class _Input:
    name: str
    clock_ns: int | None = None  # when last heard, on the node's clock
    wall_ns: int | None = None  # when last heard, wall time
    silent_s: float = 0.0  # as of the last check
    silent: bool = False  # in a silence episode (said once)
    resent: int = 0  # resends received in all
    resent_since_heard: int = 0


class InputWatch:
    """Silence of the named inputs, in the node's clock and wall time (module docstring)."""

    def __init__(self, names: Sequence[str], timeout_s: float):
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be > 0, got {timeout_s!r}")
        self.timeout_s = timeout_s
        self._inputs = {name: _Input(name) for name in names}
        self._first_heard: tuple[int, int] | None = None  # (clock, wall) of the first message of any input
        self._last_check_wall_ns: int | None = None
        self._clock_seen_ns: int | None = None
        self._clock_moved_wall_ns: int | None = None  # wall time when the node's clock last moved

    def heard(self, name: str, clock_ns: int, wall_ns: int) -> str | None:
        """A message of input ``name`` arrived; a line to log when it ends a silence."""
        watched = self._inputs[name]
        self._see_clock(clock_ns, wall_ns)
        if self._first_heard is None:
            self._first_heard = (clock_ns, wall_ns)
        silence_s = self._silence_s(watched, clock_ns, wall_ns)
        watched.clock_ns, watched.wall_ns = clock_ns, wall_ns
        watched.resent_since_heard = 0
        if not watched.silent:
            return None
        watched.silent = False
        return f"{name} is back after {silence_s:.1f} s of silence"

    def resent(self, name: str) -> None:
        """Input ``name`` sent its last message again (module docstring)."""
        watched = self._inputs[name]
        watched.resent += 1
        watched.resent_since_heard += 1

    def check(self, clock_ns: int, wall_ns: int) -> list[str]:
        """Judge every input now; a line to log (WARN) for each that went silent since the last check."""
        stalled_self = (
            self._last_check_wall_ns is not None
            and (wall_ns - self._last_check_wall_ns) / NS > 0.5 * self.timeout_s
        )
        self._last_check_wall_ns = wall_ns
        self._see_clock(clock_ns, wall_ns)
        if stalled_self or self._first_heard is None:
            return []
        newly = []
        for watched in self._inputs.values():
            watched.silent_s = self._silence_s(watched, clock_ns, wall_ns)
            if watched.silent_s > self.timeout_s and not watched.silent:
                watched.silent = True
                newly.append(watched)
        return [self._went_silent(watched) for watched in newly]

    def _see_clock(self, clock_ns: int, wall_ns: int) -> None:
        if clock_ns != self._clock_seen_ns:
            self._clock_seen_ns, self._clock_moved_wall_ns = clock_ns, wall_ns

    def _silence_s(self, watched: _Input, clock_ns: int, wall_ns: int) -> float:
        assert self._first_heard is not None
        since_clock = watched.clock_ns if watched.clock_ns is not None else self._first_heard[0]
        since_wall = watched.wall_ns if watched.wall_ns is not None else self._first_heard[1]
        # A clock that went back (a restarted simulator) starts the count again.
        return max(clock_ns - since_clock, wall_ns - since_wall, 0) / NS

    def _clock_note(self) -> str:
        """Words for a node's clock that stood still as long as the timeout, as of the last check, or ''."""
        if self._clock_moved_wall_ns is None or self._last_check_wall_ns is None:
            return ""
        stopped_s = (self._last_check_wall_ns - self._clock_moved_wall_ns) / NS
        return f"the clock has not moved for {stopped_s:.1f} s" if stopped_s > self.timeout_s else ""

    def _went_silent(self, watched: _Input) -> str:
        coming = [w.name for w in self._inputs.values() if not w.silent]
        what = f"no {watched.name} for {watched.silent_s:.1f} s"
        if coming:
            what += f" while {' and '.join(coming)} keep coming"
        else:
            clock = self._clock_note()
            what += f", nor any other input{', and ' + clock if clock else ''}"
        if watched.resent_since_heard:
            # As a lockstep simulator waits for motor_speed_cmd: look at the one it waits for.
            return (
                f"{what}; only its last message came again ({watched.resent_since_heard} times): its "
                "publisher is alive and waits"
            )
        if coming:
            return f"{what}: its publisher may be stalled; no diagnosis until it is back"
        return f"{what}: their publishers may be stalled"

    def status(self) -> InputsStatus:
        """Every input as of the last check (module docstring)."""
        names = list(self._inputs)
        if self._first_heard is None:
            return InputsStatus("OK", f"waiting for the first message on {', '.join(names)}", {})
        values = {f"{w.name}_silent_s": f"{w.silent_s:.2f}" for w in self._inputs.values()}
        values |= {f"{w.name}_resent": str(w.resent) for w in self._inputs.values()}
        silent = [w for w in self._inputs.values() if w.silent]
        if not silent:
            return InputsStatus("OK", f"receiving {', '.join(names)}", values)
        values["silent"] = ",".join(w.name for w in silent)
        coming = [w.name for w in self._inputs.values() if not w.silent]
        message = "silent: " + ", ".join(f"{w.name} for {w.silent_s:.1f} s" for w in silent)
        note = f"{', '.join(coming)} still coming" if coming else self._clock_note()
        if note:
            message += f" ({note})"
        return InputsStatus("WARN", message + ": no identification or diagnosis meanwhile", values)
