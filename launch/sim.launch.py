"""Simulator, controller and identifier of one vehicle, without a mission: you send the setpoints.

    ros2 launch multirotor_ros sim.launch.py airframe:=x8_octorotor
    ros2 topic pub --once /setpoint geometry_msgs/PoseStamped "{pose: {position: {z: 1.0}}}"

vehicle.launch.py with ``mission:=none visualizer:=false`` as defaults; every argument of that file
applies (``--show-args``): airframe, real_time_factor (0, the default = lockstep: the simulator waits for
each control period's command, so a flight does not depend on the machine's load; r > 0 = r x wall time),
namespace, identifier (``identifier:=false`` leaves it out), effects, noise, fault_motor,
fault_effectiveness, mission, visualizer, rviz. Whatever the factor, the simulator publishes ``/clock``
and every node runs on it (``use_sim_time``). Computed by multirotor_ros/launch_plan.py (``SIM``).
"""

from multirotor_ros.launch_actions import launch_description
from multirotor_ros.launch_plan import SIM


def generate_launch_description():
    """The arguments and nodes of launch_plan.SIM."""
    return launch_description(SIM)
