"""The launch files' side of :mod:`multirotor_ros.launch_plan`: a plan's rows as launch_ros actions.

Only the files in ``launch/`` import this module, under ``ros2 launch``, which brings ``launch`` and
``launch_ros``; everything they start is computed by launch_plan, which needs neither (its docstring
says why). The arguments are declared with their defaults and descriptions, so ``ros2 launch
multirotor_ros vehicle.launch.py --show-args`` lists them; their values are read in an
``OpaqueFunction`` when the launch runs, and a bad one ends the launch with launch_plan's message before
any process starts.

The imports carry ``type: ignore`` because launch and launch_ros are absent where the mypy gate runs
(test/test_typing.py) and untyped where they are installed.
"""

from __future__ import annotations

import typing
from typing import Any

# launch's submodules, not its top level: mypy, run from the repository, takes its launch/ directory for
# the package.
from launch.actions import (  # type: ignore[import-not-found,import-untyped,unused-ignore]
    DeclareLaunchArgument,
    OpaqueFunction,
)
from launch.launch_context import LaunchContext  # type: ignore[import-not-found,import-untyped,unused-ignore]
from launch.launch_description import (  # type: ignore[import-not-found,import-untyped,unused-ignore]
    LaunchDescription,
)
from launch.substitutions import LaunchConfiguration  # type: ignore[import-not-found,import-untyped,unused-ignore]
from launch_ros.actions import Node  # type: ignore[import-not-found,import-untyped,unused-ignore]
from launch_ros.parameter_descriptions import (  # type: ignore[import-not-found,import-untyped,unused-ignore]
    ParameterValue,
)

from multirotor_ros.launch_plan import LaunchFile, NodePlan


def launch_description(launch_file: LaunchFile) -> Any:
    """The LaunchDescription of a launch file of launch_plan: its arguments, then its nodes."""
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(a.name, default_value=a.default, description=a.description)
                for a in launch_file.arguments
            ),
            OpaqueFunction(function=_node_actions, args=[launch_file]),
        ]
    )


def _node_actions(context: LaunchContext, launch_file: LaunchFile) -> list[Any]:
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in launch_file.arguments}
    return [node_action(plan) for plan in launch_file.nodes(values)]


def node_action(plan: NodePlan) -> Any:
    """A launch_ros Node for one row, each parameter typed as the plan made it.

    Typed explicitly: launch would otherwise read each string as YAML, and the identifier's empty
    ``effects`` (its airframe's own) would arrive as null, a file named ``1.5`` as a number.
    """
    return Node(
        package=plan.package,
        executable=plan.executable,
        namespace=plan.namespace,
        arguments=list(plan.arguments),
        parameters=[{name: _typed(value) for name, value in plan.parameters.items()}],
        output="screen",
    )


def _typed(value: Any) -> Any:
    if isinstance(value, list):
        # typing.List, not list[str]: launch recognises a list type by identity with List[...].
        return ParameterValue(value, value_type=typing.List[str])  # noqa: UP006
    return ParameterValue(value, value_type=type(value))
