"""Setpoints scheduled ahead: a mission sent at once, each setpoint taking effect at its stamp.

A setpoint stamped later than the controller's clock waits in the queue until that time; one stamped at
or before it (0 included: ``ros2 topic pub`` leaves the stamp 0) takes effect at once. Stamping with
simulated time, a script sends a whole sequence ahead and the flight is the same however late each
message arrives: what ``multirotor simulate --setpoints`` does offline. The queue is bounded in length
and in how far ahead it looks, so that a sender cannot make it grow or hide a setpoint in the far future.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.refusals import Refusal

NS_PER_S = 1_000_000_000
# A setpoint more than this far ahead of the controller's clock is refused (a wall-clock stamp sent to a
# controller on simulated time is 1.7e9 s ahead) [s].
SETPOINT_HORIZON_S = 3600.0
# Setpoints waiting at most: a mission of a few hundred waypoints fits.
SETPOINT_QUEUE_LENGTH = 1000

Target = tuple[FloatArray, float]  # (p_W [m] ENU, yaw [rad])


@dataclass
class SetpointQueue:
    """Targets waiting for their time, in stamp order (see the module docstring)."""

    horizon_s: float = SETPOINT_HORIZON_S
    max_length: int = SETPOINT_QUEUE_LENGTH
    _stamps: list[int] = field(default_factory=list)
    _targets: list[Target] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self._stamps)

    def schedule(self, stamp_ns: int, target: Target, now_ns: int) -> Refusal | None:
        """Queue ``target`` for ``stamp_ns`` (> ``now_ns``), or say why not (nothing kept)."""
        ahead_s = (stamp_ns - now_ns) / NS_PER_S
        if ahead_s > self.horizon_s:
            return Refusal(
                "stamp too far ahead",
                f"setpoint stamped {ahead_s:.3f} s ahead of this node's clock (at most {self.horizon_s:g} "
                "s): "
                "stamp setpoints with the controller's clock (simulated time under use_sim_time), or 0 "
                "for at once",
            )
        if len(self._stamps) >= self.max_length:
            return Refusal("setpoint queue full", f"{self.max_length} setpoints already wait for their time")
        index = bisect.bisect_right(self._stamps, stamp_ns)
        self._stamps.insert(index, stamp_ns)
        self._targets.insert(index, target)
        return None

    def due(self, now_ns: int) -> Target | None:
        """The latest target whose time has come (removing every due one), or None."""
        count = bisect.bisect_right(self._stamps, now_ns)
        if count == 0:
            return None
        target = self._targets[count - 1]
        del self._stamps[:count], self._targets[:count]
        return target

    def clear(self) -> None:
        """Forget every waiting setpoint (the clock went back: their stamps mean nothing now)."""
        self._stamps.clear()
        self._targets.clear()
