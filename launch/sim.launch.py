"""Simulator and controller of one vehicle.

    ros2 launch multirotor_ros sim.launch.py airframe:=x8_octorotor


Arguments: ``airframe`` (config name or YAML path), ``real_time_factor`` (0, the default = lockstep: the
simulator waits for each control period's command, so a flight does not depend on the machine's load;
r > 0 = r x wall time), ``namespace``. Whatever the factor, the simulator publishes ``/clock`` and every
node runs on it (``use_sim_time``), so stamps and timers follow one time. The identifier is started too
(``identifier:=false`` leaves it out).
"""

from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription

PACKAGE = "multirotor_ros"


def generate_launch_description() -> LaunchDescription:
    """Simulator, controller and identifier of one vehicle, with the launch arguments above."""
    airframe = LaunchConfiguration("airframe")
    real_time_factor = LaunchConfiguration("real_time_factor")
    namespace = LaunchConfiguration("namespace")
    # Typed explicitly: `real_time_factor:=1` would otherwise reach the node as an integer.
    rate = ParameterValue(real_time_factor, value_type=float)
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "airframe", default_value="x8_octorotor", description="config name or YAML path"
            ),
            DeclareLaunchArgument(
                "real_time_factor", default_value="0.0", description="0 = lockstep, as fast as possible"
            ),
            DeclareLaunchArgument(
                "namespace", default_value="", description="namespace of the vehicle's nodes"
            ),
            DeclareLaunchArgument(
                "identifier", default_value="true", description="start the identifier node"
            ),
            Node(
                package=PACKAGE,
                executable="simulator",
                name="simulator",
                namespace=namespace,
                output="screen",
                parameters=[{"airframe": airframe, "real_time_factor": rate, "publish_clock": True}],
            ),
            Node(
                package=PACKAGE,
                executable="controller",
                name="controller",
                namespace=namespace,
                output="screen",
                parameters=[{"airframe": airframe, "use_sim_time": True}],
            ),
            Node(
                package=PACKAGE,
                executable="identifier",
                name="identifier",
                namespace=namespace,
                output="screen",
                parameters=[{"airframe": airframe, "use_sim_time": True}],
                condition=IfCondition(LaunchConfiguration("identifier")),
            ),
        ]
    )
