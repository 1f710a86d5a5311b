"""The MAVLink bridge flying with PX4 or ArduPilot SITL, with the identifier and visualizer (and rviz2).

    ros2 launch multirotor_ros mavlink.launch.py flight_stack:=px4
    ros2 launch multirotor_ros mavlink.launch.py flight_stack:=ardupilot airframe:=x8_octorotor
    ros2 launch multirotor_ros mavlink.launch.py flight_stack:=px4 fault_motor:=2 noise:=false gcs_port:=14550

Then start the flight stack's SITL, which connects to the bridge (PX4: TCP 4560; ArduPilot:
``sim_vehicle.py -f JSON``, UDP 9002), and fly it from a ground station on UDP 14550. The bridge steps
its own physics in lockstep with the flight stack and publishes /clock; the flight stack sets the pace
(PX4_SIM_SPEED_FACTOR, ArduPilot's --speedup), so there is no real_time_factor here. Arguments
(``--show-args``): flight_stack, airframe (default quad_x), effects, identifier, noise, fault_motor,
fault_effectiveness, namespace, flight_stack_port, gcs_port, visualizer, rviz. What starts is computed
by multirotor_ros/launch_plan.py (``MAVLINK``).
"""

from multirotor_ros.launch_actions import launch_description
from multirotor_ros.launch_plan import MAVLINK


def generate_launch_description():
    """The arguments and nodes of launch_plan.MAVLINK."""
    return launch_description(MAVLINK)
