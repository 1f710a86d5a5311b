"""The ``fleet_controller`` executable: the controllers of several vehicles in one process (issue 10).

Each vehicle of ``vehicles`` (the simulator's list: ``"NAME [X Y Z [YAW]]"``, the pose ignored here,
nodes/vehicles.py) gets a ``controller`` node of its own (nodes/controller.py) in the namespace
``NAME`` under this node's: the same topics, parameters, services and logs as a controller process per
vehicle, ``ros2 param set /uav2/controller ...`` included. They share one process and one executor, as
ROS 2 composes nodes in a component container, which rclpy does not offer: a controller process costs
its interpreter, its DDS participant and its own ``/clock`` traffic (here one ``/clock`` subscription,
nodes/clock.py SharedClock, tells every controller), and with one process per vehicle a
2-core machine kept the control periods of 4 vehicles on time only 23 % of the time
(bench/bench_fleet_ros.py). Parameters given with ``-p`` apply to every controller; a parameters file
sets one vehicle's under ``/NAME/controller``. Under ``-r __ns:=/NS`` for the whole process (as ``ros2
launch`` starts a namespaced node) this node is ``/NS/fleet_controller`` and each controller
``/NS/NAME/controller``. fleet.launch.py starts the controllers so. Example::

    ros2 run multirotor_ros fleet_controller --ros-args -p vehicles:="['uav1', 'uav2']" -p use_sim_time:=true
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

from multirotor_ros.nodes.clock import SharedClock
from multirotor_ros.nodes.controller import ControllerNode
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.vehicles import parse_vehicles


class FleetControllerNode(Node):
    """Holds one ``ControllerNode`` per vehicle (``members``, spun beside it by ``run_node``)."""

    # No timer and no time of its own; its members keep theirs (nodes/entry.py make_executor).
    KEEPS_ITS_OWN_SIMULATED_TIME = True

    def __init__(self, **kwargs: Any):
        super().__init__("fleet_controller", **kwargs)
        listed = self.declare_parameter(
            "vehicles",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY,
                description="the vehicles to control, as the simulator's vehicles list: 'NAME [X Y Z [YAW]]'",
                read_only=True,
            ),
        ).value
        vehicles = parse_vehicles(listed or [])
        if not vehicles:
            raise ValueError(
                "parameter vehicles: name at least one vehicle, e.g. vehicles:=\"['uav1', 'uav2']\""
            )
        namespace = self.get_namespace().rstrip("/")
        self.members: list[ControllerNode] = []
        try:
            for vehicle in vehicles:
                # The member's own remap of its namespace: a node's local arguments come before the
                # process's, so a process-wide -r __ns:=/NS (what ros2 launch gives a namespaced
                # process) moves this node to /NS and each member to /NS/NAME, not all onto /NS.
                own = f"{namespace}/{vehicle.name}"
                remap = ["--ros-args", "-r", f"__ns:={own}"]
                member = ControllerNode(**kwargs, namespace=own, cli_args=remap, clock_subscription=False)
                self.members.append(member)
        except Exception:
            for built in self.members:
                built.destroy_node()
            raise
        self.get_logger().info(
            f"{len(vehicles)} controllers: " + ", ".join(m.get_fully_qualified_name() for m in self.members)
        )
        # Last, just before the spin (nodes/clock.py NodeTime): one /clock subscription for all of them.
        self._shared_clock = SharedClock(self, [member.time for member in self.members])


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros fleet_controller`` (``multirotor node fleet_controller``)."""
    return run_node(FleetControllerNode, args)
