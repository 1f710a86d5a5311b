"""How fast simulated time runs against the wall clock: real-time factor and lockstep, as pure rules.

- ``real_time_factor`` r > 0: simulated time follows r x wall time from an anchor. When the physics
  cannot keep up for longer than ``max_lag_s`` of simulated time, the anchor moves (the simulation
  slows down rather than trying to catch up in a burst) and the pacer says so once per episode.
- ``real_time_factor`` 0 with lockstep: simulated time may run at most ``lead_ns`` past the stamp of the
  newest motor command, so that a controller on ``use_sim_time`` gets every state it needs before the
  physics goes on, however slow either side is. Without any command for ``fallback_after_s`` of wall time
  (no controller yet, or one that stopped) the simulation runs on in real time until commands return.
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
class Lockstep:
    """Lockstep rule at real_time_factor 0 (see the module docstring)."""

    lead_ns: int
    fallback_after_s: float
    newest_command_ns: int = 0  # stamp of the newest command (sim time); commands start at 0
    last_command_wall_s: float = 0.0

    def limit_ns(self) -> int:
        """Simulated time the physics may run up to now."""
        return self.newest_command_ns + self.lead_ns

    def command(self, stamp_ns: int, wall_s: float) -> None:
        """A stamped command arrived at wall time ``wall_s`` (unstamped messages do not count)."""
        self.newest_command_ns = max(self.newest_command_ns, stamp_ns)
        self.last_command_wall_s = wall_s

    def stalled(self, wall_s: float) -> bool:
        """Whether no command came for so long that the simulator should run on in real time."""
        return wall_s - self.last_command_wall_s > self.fallback_after_s
