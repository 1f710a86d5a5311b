"""One vehicle flying a mission: simulator, controller, identifier, mission, visualizer (and rviz2).

    ros2 launch multirotor_ros vehicle.launch.py
    ros2 launch multirotor_ros vehicle.launch.py airframe:=quad_x namespace:=uav1 mission:=my_mission.csv
    ros2 launch multirotor_ros vehicle.launch.py fault_motor:=3 fault_effectiveness:=0.5 effects:=rotor_drag
    ros2 launch multirotor_ros vehicle.launch.py noise:=false real_time_factor:=1.0 rviz:=true

Arguments (``--show-args`` lists them with defaults and meanings): airframe, effects, identifier, noise,
fault_motor, fault_effectiveness, namespace, mission (default ``square``: config/missions/square.csv,
take off to 2 m, a square, land; ``none``: no mission), real_time_factor (0, the default: lockstep),
visualizer, rviz. The vehicle takes off and flies the mission from its first odometry on. What starts,
with which parameters, is computed by multirotor_ros/launch_plan.py (``VEHICLE``), tested without
``launch``, which the test machines cannot install (see that module).
"""

from multirotor_ros.launch_actions import launch_description
from multirotor_ros.launch_plan import VEHICLE


def generate_launch_description():
    """The arguments and nodes of launch_plan.VEHICLE."""
    return launch_description(VEHICLE)
