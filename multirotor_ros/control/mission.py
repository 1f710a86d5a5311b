"""A mission: setpoints flown from the mission's start, and how far the vehicle has got through them.

The file is the setpoints CSV of ``multirotor simulate --setpoints``, read by its parser
(simulation/flight.py ``read_setpoints``): header ``t,x,y,z,yaw`` [s, m, m, m, rad], world ENU in the
odom frame, ``#`` comments; each row holds from its t on. A mission must also fit the controller's
queue of setpoints waiting for their time (control/setpoint_queue.py), since the mission node sends
them all ahead: at most ``SETPOINT_QUEUE_LENGTH`` rows, the last no more than ``SETPOINT_HORIZON_S``
after the start, every position within the controller's ``StateLimits``.

:class:`MissionProgress` is the mission node's bookkeeping, without ROS: each setpoint's stamp (the
mission's start on the odometry's clock plus its t), and from the vehicle's positions over time the
lines the node logs: a setpoint reached (within ``reached_distance_m`` of its position), one replaced
by the next before it was reached (with the closest approach), and the mission done (the last one
reached).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from multirotor_ros.control.setpoint_queue import NS_PER_S, SETPOINT_HORIZON_S, SETPOINT_QUEUE_LENGTH
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.plausibility import StateLimits
from multirotor_ros.simulation.flight import SetpointError, read_setpoints

# A setpoint counts as reached within this distance of its position [m] (the mission node's default).
REACHED_DISTANCE_M = 0.1


@dataclass(frozen=True)
class Mission:
    """The rows of a mission file: (K, 5) t [s], x, y, z [m], yaw [rad]; ``origin`` names the file."""

    table: FloatArray
    origin: str

    def __len__(self) -> int:
        return len(self.table)

    @property
    def duration_s(self) -> float:
        """The t of the last setpoint [s]."""
        return float(self.table[-1, 0])


def read_mission(path: str | Path) -> Mission:
    """The mission in ``path``; SetpointError (a ValueError) naming the file and line or row if unusable."""
    table = read_setpoints(path)
    if len(table) > SETPOINT_QUEUE_LENGTH:
        raise SetpointError(
            f"{path}: {len(table)} setpoints; the controller holds at most {SETPOINT_QUEUE_LENGTH} waiting"
        )
    if table[-1, 0] > SETPOINT_HORIZON_S:
        raise SetpointError(
            f"{path}: the last setpoint is at t = {table[-1, 0]:g} s; the controller accepts setpoints at "
            f"most {SETPOINT_HORIZON_S:g} s ahead"
        )
    limit_m = StateLimits().position_m
    for index, row in enumerate(table, start=1):
        if np.max(np.abs(row[1:4])) > limit_m:
            raise SetpointError(
                f"{path}: setpoint {index} (t = {row[0]:g} s): position beyond the controller's "
                f"{limit_m:g} m limit"
            )
    return Mission(table, str(path))


@dataclass(frozen=True)
class Setpoint:
    """One setpoint as sent: its number (1-based), stamp [ns], position [m] (world ENU) and yaw [rad]."""

    number: int
    stamp_ns: int
    position_m: FloatArray
    yaw_rad: float


class MissionProgress:
    """A mission started at ``start_ns``, offset by ``offset_m`` (added to each position; see module doc)."""

    def __init__(
        self,
        mission: Mission,
        start_ns: int,
        offset_m: FloatArray | None = None,
        reached_distance_m: float = REACHED_DISTANCE_M,
    ):
        self.mission = mission
        self.start_ns = start_ns
        self.reached_distance_m = reached_distance_m
        offset = np.zeros(3) if offset_m is None else np.asarray(offset_m, dtype=float)
        self.setpoints = [
            Setpoint(k + 1, start_ns + round(row[0] * NS_PER_S), row[1:4] + offset, float(row[4]))
            for k, row in enumerate(mission.table)
        ]
        self._stamps = [s.stamp_ns for s in self.setpoints]
        self._watched = -1  # index of the setpoint in force at the last observation, -1 before the first
        self._closest_m = math.inf  # its closest approach so far
        self._reached = False
        self.reached = 0  # setpoints reached so far
        self.done = False

    def in_force(self, now_ns: int) -> int:
        """Index of the setpoint in force at ``now_ns`` (-1 before the first)."""
        return bisect.bisect_right(self._stamps, now_ns) - 1

    def from_in_force(self, now_ns: int) -> list[Setpoint]:
        """The setpoint in force at ``now_ns`` and those to come: what a controller that joins now needs."""
        return self.setpoints[max(self.in_force(now_ns), 0) :]

    def t_s(self, now_ns: int) -> float:
        """Mission time [s] of ``now_ns``."""
        return (now_ns - self.start_ns) / NS_PER_S

    def observe(self, now_ns: int, p_WB_W: FloatArray) -> list[str]:
        """The vehicle at ``p_WB_W`` at ``now_ns``: the lines to log (module docstring), often none."""
        lines = []
        current = self.in_force(now_ns)
        while self._watched < current:
            if self._watched >= 0 and not self._reached:
                replaced = self.setpoints[self._watched]
                closest = min(self._closest_m, self._distance(replaced, p_WB_W))
                lines.append(
                    f"{self._describe(replaced)} not reached before setpoint {replaced.number + 1} took "
                    f"over at t = {self.t_s(self.setpoints[self._watched + 1].stamp_ns):.2f} s "
                    f"(closest {closest:.2f} m)"
                )
            self._watched += 1
            self._closest_m, self._reached = math.inf, False
        if current < 0 or self._reached:
            return lines
        setpoint = self.setpoints[current]
        distance = self._distance(setpoint, p_WB_W)
        self._closest_m = min(self._closest_m, distance)
        if distance <= self.reached_distance_m:
            self._reached = True
            self.reached += 1
            lines.append(
                f"{self._describe(setpoint)} reached at t = {self.t_s(now_ns):.2f} s ({distance:.2f} m away)"
            )
            if setpoint.number == len(self.setpoints):
                self.done = True
                lines.append(
                    f"mission done at t = {self.t_s(now_ns):.2f} s: {self.reached} of {len(self.setpoints)} "
                    f"setpoints reached ({self.mission.origin})"
                )
        return lines

    def _distance(self, setpoint: Setpoint, p_WB_W: FloatArray) -> float:
        return float(np.linalg.norm(np.asarray(p_WB_W, dtype=float) - setpoint.position_m))

    def _describe(self, setpoint: Setpoint) -> str:
        x, y, z = setpoint.position_m
        return (
            f"setpoint {setpoint.number}/{len(self.setpoints)} (t = {self.t_s(setpoint.stamp_ns):g} s: "
            f"x {x:.2f}, y {y:.2f}, z {z:.2f} m, yaw {setpoint.yaw_rad:.2f} rad)"
        )
