"""Control of one multirotor with the law of seed 1 (§II-B, eqs. 8-10); pure numpy, no ROS.

- :mod:`.law`: :class:`SaturationController` (a sum of saturations for x/y through roll and pitch, PID for
  altitude and yaw), :func:`saturate` (eq. 10).
- :mod:`.allocation`: :class:`Allocator`, wrench -> rotor speeds with roll/pitch before thrust before yaw,
  through B diag(e) for a rotor effectiveness e (dead rotors left out).
- :mod:`.fault_tolerance`: :class:`EffectivenessFilter`, the identifier's diagnosis -> the smooth
  effectiveness the allocator uses.
- :mod:`.gains`: :class:`ControllerGains` under the paper's names, read from an airframe YAML.
"""

from multirotor_ros.control.allocation import DEAD_ROTOR_EFFECTIVENESS, AllocationResult, Allocator
from multirotor_ros.control.fault_tolerance import EffectivenessFilter
from multirotor_ros.control.gains import ControllerGains, airframe_gains, gains_from_section
from multirotor_ros.control.law import SaturationController, saturate

__all__ = [
    "DEAD_ROTOR_EFFECTIVENESS",
    "AllocationResult",
    "Allocator",
    "ControllerGains",
    "EffectivenessFilter",
    "SaturationController",
    "airframe_gains",
    "gains_from_section",
    "saturate",
]
