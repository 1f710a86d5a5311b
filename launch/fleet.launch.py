"""N vehicles in one graph: one simulator for all, controller, identifier, mission, visualizer for each.

The vehicles' nodes run under /uav1, /uav2, ...; rviz2 on request.

    ros2 launch multirotor_ros fleet.launch.py vehicles:=3
    ros2 launch multirotor_ros fleet.launch.py vehicles:=4 spacing:=5.0 airframe:=quad_x mission:=none
    ros2 launch multirotor_ros fleet.launch.py fault_vehicle:=uav2 fault_motor:=1 real_time_factor:=1.0

Arguments (``--show-args`` lists them with defaults and meanings): airframe, effects, identifier, noise,
fault_motor, fault_effectiveness, namespace (above the vehicles'), vehicles, spacing (the vehicles stand
in a row along x), fault_vehicle, mission (each vehicle flies it from where it stands), real_time_factor,
visualizer, rviz. A graph has one simulated time, hence one simulator node with its ``vehicles``
parameter (nodes/simulator.py). What starts is computed by multirotor_ros/launch_plan.py (``FLEET``).
"""

from multirotor_ros.launch_actions import launch_description
from multirotor_ros.launch_plan import FLEET


def generate_launch_description():
    """The arguments and nodes of launch_plan.FLEET."""
    return launch_description(FLEET)
