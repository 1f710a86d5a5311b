"""``multirotor node NAME [--ros-args ...]``: run one of the package's ROS 2 executables."""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND = "node"
HELP = "run a ROS 2 node of this package (simulator, controller, identifier, mavlink_bridge, mission, ...)"

# The executables of `ros2 run multirotor_ros NAME`, each the module multirotor_ros.nodes.NAME; a pip
# install also puts them on PATH as multirotor-NAME (scripts/ament_layout.py console_script_name).
NODE_EXECUTABLES = (
    "simulator",
    "controller",
    "fleet_controller",
    "identifier",
    "mavlink_bridge",
    "mission",
    "visualizer",
)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of the sub-command."""
    parser.add_argument("name", choices=NODE_EXECUTABLES, help="executable name, as for `ros2 run`")
    parser.add_argument("ros_args", nargs=argparse.REMAINDER, help="arguments for rclpy (--ros-args ...)")


def run_node(name: str, ros_args: list[str]) -> int:
    """Run node ``name`` with rclpy arguments; its exit status."""
    if name not in NODE_EXECUTABLES:
        print(
            f"multirotor node: unknown node {name!r}; choose one of {', '.join(NODE_EXECUTABLES)}",
            file=sys.stderr,
        )
        return 2
    module = importlib.import_module(f"multirotor_ros.nodes.{name}")
    return int(module.main([f"multirotor_ros/{name}", *ros_args]) or 0)


def run(args: argparse.Namespace) -> int:
    """Run the node named on the command line."""
    return run_node(args.name, list(args.ros_args))
