"""The simulator's ``vehicles`` parameter: several vehicles in one simulator node (issue 10).

Each entry is ``"NAME [X Y Z [YAW]]"``: a name that becomes the vehicle's namespace under the node's
(its topics ``NAME/odom``, ``NAME/motor_speed_cmd``, ... and frames ``NAME/odom``, ``NAME/base_link``)
and its initial position [m] (world ENU, z = 0 on the ground) and yaw [rad], 0 when left out. Example::

    ros2 run multirotor_ros simulator --ros-args -p vehicles:="['uav1', 'uav2 3 0 0', 'uav3 0 3 0 1.57']"

Pure parsing, no ROS: a bad entry is a ValueError that quotes it and says what is wrong.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

# A ROS name token: what a namespace segment may be.
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
# At most this many vehicles in one node: a typo (a list of thousands) is refused, not simulated.
MAX_VEHICLES = 256
POSITION_LIMIT_M = 1e4


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle of a simulator node: its name ("" for the one unnamed vehicle) and initial pose."""

    name: str
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float = 0.0

    @property
    def prefix(self) -> str:
        """What goes before its topic and frame names: ``NAME/``, or nothing for the unnamed vehicle."""
        return f"{self.name}/" if self.name else ""


def parse_vehicles(entries: Sequence[str]) -> list[VehicleSpec]:
    """The vehicles of ``entries`` (see the module docstring); ValueError naming the bad entry."""
    if len(entries) > MAX_VEHICLES:
        raise ValueError(f"vehicles: {len(entries)} entries, at most {MAX_VEHICLES}")
    specs: list[VehicleSpec] = []
    for index, entry in enumerate(entries):
        where = f"vehicles[{index}] {entry[:60]!r}"
        fields = entry.split()
        if not fields or not _NAME.fullmatch(fields[0]):
            raise ValueError(f"{where}: must start with a name (a letter, then letters, digits or _)")
        if len(fields) not in (1, 4, 5):
            raise ValueError(f"{where}: expected 'NAME' or 'NAME X Y Z [YAW]', got {len(fields)} fields")
        try:
            numbers = [float(v) for v in fields[1:]]
        except ValueError:
            raise ValueError(f"{where}: X Y Z YAW must be numbers") from None
        if not all(math.isfinite(v) for v in numbers):
            raise ValueError(f"{where}: X Y Z YAW must be finite")
        position = tuple(numbers[:3]) if numbers else (0.0, 0.0, 0.0)
        if any(abs(v) > POSITION_LIMIT_M for v in position) or (numbers and numbers[2] < 0.0):
            raise ValueError(f"{where}: the position must be within {POSITION_LIMIT_M:g} m and z >= 0")
        if fields[0] in (s.name for s in specs):
            raise ValueError(f"{where}: the name {fields[0]!r} is already a vehicle")
        yaw = numbers[3] if len(numbers) == 4 else 0.0
        specs.append(VehicleSpec(fields[0], position, yaw))  # type: ignore[arg-type]
    return specs
