"""Vehicle simulation without ROS: the physics model with sensors, command clamp, watchdog and faults.

- :mod:`.vehicle`: :class:`VehicleSimulator`, one vehicle or a fleet of one airframe stepped together in
  integer nanoseconds (one lane of the batched kernel each).
- :mod:`.sensors`: IMU (3DM-GX3-25), SRF08 range, motion capture, ESC speed reports.
- :mod:`.flight`: :func:`simulate_flight`, the closed loop with the seed 1 controller, as a flight log.
- :mod:`.pacing`: real-time factor, lockstep and late-period rules of the simulator and controller nodes.
"""

from multirotor_ros.simulation.flight import read_setpoints, simulate_flight
from multirotor_ros.simulation.vehicle import Reading, VehicleSimulator, vehicle_generators

__all__ = ["Reading", "VehicleSimulator", "read_setpoints", "simulate_flight", "vehicle_generators"]
