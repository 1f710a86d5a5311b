"""How simulated time runs against the wall clock and the controllers, as pure rules (no ROS).

- ``real_time_factor`` r > 0 (:class:`RealTimePacer`): simulated time follows r x wall time from an
  anchor. When the physics cannot keep up for longer than ``max_lag_s`` of simulated time, the anchor
  moves (the simulation slows down rather than catching up in a burst) and the pacer counts it.
- Lockstep at ``real_time_factor`` 0 (:class:`Lockstep`): simulated time runs at most one control period
  past the stamp of the newest motor command, so that every control period is integrated with the
  command computed for it, however slow the machine, the simulator or the controller: the same commands
  give the same flight. There is no wall-time escape: a controller that stops stops simulated time, and
  the simulator says so (:meth:`Lockstep.waiting_s`) instead of flying on with a stale command.
  Followers (an identifier whose verdict a controller allocates from) may join: each says up to which
  stamp it has handled its inputs, and simulated time also runs at most ``follower_slack`` past the
  slowest follower's word, so that what it concludes from the state of t reaches the controllers at the
  same simulated time in every run. A follower counts from the first word heard; one silent for
  ``release_s`` of wall time while simulated time waits for it is released (the simulator says so) and
  joins again when heard: a stopped identifier must not stop the flight. A follower that must see the
  flight from its first instant (a recorder) is expected instead (:meth:`Lockstep.expect`): simulated
  time stays at 0 until its first word, for as long as its own patience; a subscription that discovery
  matches late then misses nothing (a probe that only counted from its first word lost the first 0.64 s
  of a flight on a loaded machine).
- :class:`ControlTiming`: in real time, whether each control period got its command in time (the command
  for the period starting at t, stamped t, is in force before the physics passes t + one period), and the
  achieved real-time factor: what the simulator reports on its ``pacing`` topic.
- :class:`ClockTicks`: the ticks of a controller on simulated time, read from the clock's messages: every
  ``period`` of simulated time, at the multiples of the period, as a timer on the simulated clock would.
- :class:`StateForTick`: the controller's side of lockstep. Its timer fires on the simulated clock, and the
  clock and the odometry for the same instant arrive on two topics in either order; waiting for the
  odometry of the tick (when the stream says one is due) makes the command the same in every run.
"""

from __future__ import annotations

from dataclasses import dataclass

NS_PER_S = 1_000_000_000


class RealTimePacer:
    """Target simulated time for a wall time, at a fixed real-time factor (> 0)."""

    def __init__(self, real_time_factor: float, max_lag_s: float = 0.25):
        if not real_time_factor > 0:
            raise ValueError(f"real_time_factor must be > 0 for pacing, got {real_time_factor}")
        self.real_time_factor = real_time_factor
        self.max_lag_ns = round(max_lag_s * NS_PER_S)
        self._anchor: tuple[int, int] | None = None  # (wall ns, sim ns)
        self.fell_behind = 0  # episodes where the physics could not keep up

    def anchor(self, wall_ns: int, sim_ns: int) -> None:
        """Start (or restart) pacing: ``sim_ns`` corresponds to ``wall_ns``."""
        self._anchor = (wall_ns, sim_ns)

    def now_ns(self, wall_ns: int) -> int | None:
        """Simulated time [ns] that ``wall_ns`` stands for, without re-anchoring; None before the start."""
        if self._anchor is None:
            return None
        wall0, sim0 = self._anchor
        return sim0 + round((wall_ns - wall0) * self.real_time_factor)

    def target(self, wall_ns: int, sim_ns: int) -> int:
        """Simulated time [ns] to reach now; re-anchors (and counts) when ``sim_ns`` lags too far behind."""
        if self._anchor is None:
            self.anchor(wall_ns, sim_ns)
        wall0, sim0 = self._anchor  # type: ignore[misc]
        wanted = sim0 + round((wall_ns - wall0) * self.real_time_factor)
        if wanted - sim_ns > self.max_lag_ns:
            self.fell_behind += 1
            self.anchor(wall_ns, sim_ns + self.max_lag_ns)
            return sim_ns + self.max_lag_ns
        return wanted


@dataclass
class _Follower:
    """A node that lockstep waits for besides the controllers: its word and when it was last heard."""

    handled_ns: int  # it has handled every input stamped up to this
    heard_wall_s: float  # when it was last heard, or expected
    patience_s: float  # wall time it may be silent while simulated time waits for it
    released: bool = False
    heard: bool = True  # False for one expected that has not spoken yet


class Lockstep:
    """Lockstep rule at real_time_factor 0 (see the module docstring), for one or several vehicles.

    ``period_ns``: the controllers' period; the physics may run that far past the newest command's stamp
    (so up to the next tick of a controller whose first tick is one period after 0). With several
    vehicles in one simulator it is the newest command of the vehicle whose controller is furthest behind:
    one time for all. ``follower_slack_ns``: how far past a follower's word the physics may run; at least
    the period of the slowest state topic a follower waits for (its next input must get published, or it
    could never say more). ``release_s``: wall time after which a silent follower is no longer waited for.
    """

    def __init__(self, period_ns: int, vehicles: int = 1, follower_slack_ns: int = 0, release_s: float = 1.0):
        self.period_ns = period_ns
        self.newest_command_ns = [0] * vehicles  # stamp of each vehicle's newest command; they start at 0
        self.commands = 0
        self.follower_slack_ns = max(follower_slack_ns, period_ns)
        self.release_s = release_s
        self._followers: dict[str, _Follower] = {}
        # (simulated time, wall time) of the start of the current wait at the limit, None while it runs.
        self._wait: tuple[int, float] | None = None

    def limit_ns(self) -> int:
        """Simulated time the physics may run up to now."""
        limit = min(self.newest_command_ns) + self.period_ns
        waited_for = [f.handled_ns for f in self._followers.values() if not f.released]
        return min(limit, min(waited_for) + self.follower_slack_ns) if waited_for else limit

    def follower(self, name: str, handled_ns: int, wall_s: float) -> bool:
        """``name`` has handled its inputs up to ``handled_ns``; True when it joins (or joins again)."""
        known = self._followers.get(name)
        if known is None or known.released:
            self._followers[name] = _Follower(handled_ns, wall_s, self.release_s)
            return True
        joins = not known.heard
        known.handled_ns = max(known.handled_ns, handled_ns)
        known.heard_wall_s = wall_s
        known.patience_s = self.release_s
        known.heard = True
        return joins

    def expect(self, name: str, wall_s: float, patience_s: float) -> None:
        """Wait for ``name`` from simulated time 0, before its first word: for ``patience_s`` of wall time.

        Simulated time stays at 0 until it is heard; silent that long, it is released as any follower is.
        """
        self._followers[name] = _Follower(-self.follower_slack_ns, wall_s, patience_s, heard=False)

    def release_silent(self, wall_s: float) -> list[tuple[str, int | None]]:
        """The followers simulated time waits for that were silent for their patience while it did: let go.

        Returns each one's name and last word [ns] (None: expected, never heard).

        Silent since they were last heard or since the wait began, whichever is later: a follower has
        nothing to say while simulated time stands still for a controller.
        """
        if self._wait is None:
            return []
        at_ns, since_s = self._wait
        released = []
        for name, known in self._followers.items():
            holding = known.handled_ns + self.follower_slack_ns <= at_ns
            silent_s = wall_s - max(known.heard_wall_s, since_s)
            if not known.released and holding and silent_s >= known.patience_s:
                known.released = True
                released.append((name, known.handled_ns if known.heard else None))
        return released

    def command(self, stamp_ns: int, vehicle: int = 0) -> None:
        """A stamped command arrived (unstamped ones do not count: they belong to no period)."""
        self.newest_command_ns[vehicle] = max(self.newest_command_ns[vehicle], stamp_ns)
        self.commands += 1

    def behind(self) -> list[int]:
        """The vehicles whose commands hold simulated time back (the newest command is the oldest)."""
        oldest = min(self.newest_command_ns)
        return [k for k, stamp in enumerate(self.newest_command_ns) if stamp == oldest]

    def reached(self, sim_ns: int, wall_s: float) -> None:
        """The physics is at ``sim_ns`` at wall time ``wall_s``: a wait starts when it gets to the limit."""
        if sim_ns < self.limit_ns():
            self._wait = None
        elif self._wait is None or self._wait[0] != sim_ns:
            self._wait = (sim_ns, wall_s)

    def waiting_for_commands(self) -> bool:
        """Whether simulated time stands because of a controller (not only because of a follower)."""
        return self._wait is not None and min(self.newest_command_ns) + self.period_ns <= self._wait[0]

    def waiting_s(self, wall_s: float) -> float:
        """Wall time [s] simulated time has stood still for a command or a follower (0 while it runs)."""
        return 0.0 if self._wait is None else wall_s - self._wait[1]


class ControlTiming:
    """Real-time bookkeeping: control periods on time or late, and the achieved real-time factor.

    A control period [t, t + period) is on time when a command stamped t or later is in force before the
    physics passes t + period; late otherwise (the physics ran that period on an older command). Periods
    before the first command are not counted: no controller is there yet.
    """

    def __init__(self, period_ns: int):
        self.period_ns = period_ns
        self.newest_command_ns: int | None = None
        self.on_time = 0
        self.late = 0
        self._next_check_ns: int | None = None

    def command(self, stamp_ns: int) -> None:
        if self.newest_command_ns is None:
            self._next_check_ns = stamp_ns + self.period_ns
        self.newest_command_ns = (
            stamp_ns if self.newest_command_ns is None else max(self.newest_command_ns, stamp_ns)
        )

    def physics_at(self, sim_ns: int) -> None:
        """The physics reached ``sim_ns``: judge every control period that ended by then."""
        if self.newest_command_ns is None or self._next_check_ns is None:
            return
        while self._next_check_ns <= sim_ns:
            period_start = self._next_check_ns - self.period_ns
            if self.newest_command_ns >= period_start:
                self.on_time += 1
            else:
                self.late += 1
            self._next_check_ns += self.period_ns


class AchievedRate:
    """Simulated seconds per wall second since the last call of :meth:`take` (and over the whole run)."""

    def __init__(self, wall_s: float, sim_ns: int):
        self._start = self._last = (wall_s, sim_ns)

    def take(self, wall_s: float, sim_ns: int) -> tuple[float, float]:
        """(factor since the last call, factor since the start); 0 when no wall time has passed."""
        recent = _factor(self._last, (wall_s, sim_ns))
        self._last = (wall_s, sim_ns)
        return recent, _factor(self._start, self._last)


def _factor(start: tuple[float, int], end: tuple[float, int]) -> float:
    wall = end[0] - start[0]
    return (end[1] - start[1]) / NS_PER_S / wall if wall > 0 else 0.0


class ClockTicks:
    """Ticks at the multiples of ``period_ns`` of a simulated clock, told each time it reads.

    What a timer on the simulated clock does, without one (nodes/controller.py says why): :meth:`clock`
    with each time the clock gives; True when that time reached the next tick. The first tick is one
    period after 0 (where :class:`Lockstep` lets the physics run to before any command); a clock that
    jumps past several ticks gives one, and the next is the first multiple after it; a clock that goes
    back (a restarted simulator) starts the ticks again from there.
    """

    def __init__(self, period_ns: int):
        if period_ns <= 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        self.period_ns = period_ns
        self._next_ns = period_ns
        self._newest_ns: int | None = None

    @property
    def next_ns(self) -> int:
        """When the next tick is due [ns]."""
        return self._next_ns

    def clock(self, now_ns: int) -> bool:
        """The clock reads ``now_ns``: True when a tick is due (then the next one is scheduled)."""
        if self._newest_ns is not None and now_ns < self._newest_ns:
            self._next_ns = self._after(now_ns)
        self._newest_ns = now_ns
        if now_ns < self._next_ns:
            return False
        self._next_ns = self._after(now_ns)
        return True

    def _after(self, now_ns: int) -> int:
        return (now_ns // self.period_ns + 1) * self.period_ns


class StateForTick:
    """Whether the controller has the state for a tick of its timer, or must wait for it (module docstring).

    The state stream's period is learnt from its stamps. A tick at t waits when the newest state is older
    than t and the next one is due by t (or, before the period is known, whenever the newest is older): the
    simulator publishes the state for t before the clock reaches t, so it is on its way. A tick that waits
    is computed when the next state arrives, whatever its stamp; a new tick replaces a tick still waiting
    (in real time the physics went on without it: a late period, counted by the simulator).
    """

    def __init__(self) -> None:
        self.newest_ns: int | None = None
        self.period_ns: int | None = None
        self.waiting_tick_ns: int | None = None

    def state(self, stamp_ns: int) -> int | None:
        """A state stamped ``stamp_ns`` arrived; returns the tick that waited for it, if any."""
        if self.newest_ns is not None and stamp_ns < self.newest_ns:
            self.newest_ns = self.period_ns = None  # simulated time went back: a restarted simulator
        if self.newest_ns is not None and stamp_ns > self.newest_ns:
            self.period_ns = stamp_ns - self.newest_ns
        if self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns
        tick, self.waiting_tick_ns = self.waiting_tick_ns, None
        return tick

    def tick(self, tick_ns: int) -> bool:
        """The timer fired at ``tick_ns``: True to compute now, False to wait for the state due."""
        due = (
            self.newest_ns is None
            or (self.period_ns is None and self.newest_ns < tick_ns)
            or (self.period_ns is not None and self.newest_ns + self.period_ns <= tick_ns)
        )
        self.waiting_tick_ns = tick_ns if due else None
        return not due
