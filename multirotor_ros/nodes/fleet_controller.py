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

``bundles`` (read-only, default false; fleet.launch.py sets it): the fleet takes every vehicle's odometry
of one instant from the simulator's ``fleet/odom`` bundle and answers with one ``fleet/motor_speed_cmd``
bundle of the commands computed from it (nodes/bundle.py; the commands of one ``/clock`` likewise), in
place of each controller's ``odom`` subscription and ``motor_speed_cmd`` publisher: two messages a
control period instead of two per vehicle, for a simulator whose ``vehicles`` are this node's, in that
order. Each controller still checks its own odometry and keeps its setpoints, parameters and services;
the vehicles' own topics stay for every other node. Ten vehicles at 250 Hz: each process about half a
core instead of 80 % (bench/bench_fleet_ros.py).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from functools import partial
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

from multirotor_ros.nodes.bundle import (
    BUNDLE_TYPE,
    FLEET_COMMAND_TOPIC,
    FLEET_ODOM_TOPIC,
    bundle_cdr,
    bundle_entries,
)
from multirotor_ros.nodes.clock import SharedClock
from multirotor_ros.nodes.controller import ControllerNode
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.nodes.vehicles import parse_vehicles
from multirotor_ros.refusals import Refusal, RefusalCounter


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
        bundles = self.declare_parameter(
            "bundles",
            False,
            ParameterDescriptor(
                description="exchange the fleet's odometries and commands as bundles with the simulator "
                f"({FLEET_ODOM_TOPIC}, {FLEET_COMMAND_TOPIC}; nodes/bundle.py) instead of each vehicle's "
                "odom and motor_speed_cmd",
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
        # While a bundle of odometries is handed out: the commands its members compute, sent as one bundle.
        self._commands: list[tuple[int, bytes]] | None = None
        try:
            for index, vehicle in enumerate(vehicles):
                # The member's own remap of its namespace: a node's local arguments come before the
                # process's, so a process-wide -r __ns:=/NS (what ros2 launch gives a namespaced
                # process) moves this node to /NS and each member to /NS/NAME, not all onto /NS.
                own = f"{namespace}/{vehicle.name}"
                remap = ["--ros-args", "-r", f"__ns:={own}"]
                member = ControllerNode(
                    **kwargs,
                    namespace=own,
                    cli_args=remap,
                    clock_subscription=False,
                    bundled=partial(self._command, index) if bundles else None,
                )
                self.members.append(member)
        except Exception:
            for built in self.members:
                built.destroy_node()
            raise
        if bundles:
            self._command_pub = self.create_publisher(BUNDLE_TYPE, FLEET_COMMAND_TOPIC, 10)
            self._odometry_refusals = RefusalCounter(self.get_logger().warning, FLEET_ODOM_TOPIC)
            subscribe(self, BUNDLE_TYPE, FLEET_ODOM_TOPIC, self._on_odometries, 1, raw=True)
        self.get_logger().info(
            f"{len(vehicles)} controllers: "
            + ", ".join(m.get_fully_qualified_name() for m in self.members)
            + (
                f"; odometry and commands in bundles on {self.resolve_topic_name(FLEET_ODOM_TOPIC)} and "
                f"{self.resolve_topic_name(FLEET_COMMAND_TOPIC)}"
                if bundles
                else ""
            )
        )
        # Last, just before the spin (nodes/clock.py NodeTime): one /clock subscription for all of them.
        self._shared_clock = SharedClock(
            self, [member.time for member in self.members], self._gathering if bundles else nullcontext
        )

    def _on_odometries(self, data: bytes) -> None:
        """A bundle of odometries: each to its vehicle's controller; their commands back in one bundle."""
        entries = bundle_entries(data, len(self.members))
        if isinstance(entries, Refusal):
            self._odometry_refusals.refuse(entries.reason, entries.detail)
            return
        with self._gathering():
            for index, odometry in entries:
                self.members[index].on_odometry(odometry)

    @contextmanager
    def _gathering(self) -> Iterator[None]:
        """The commands the members compute inside go out as one bundle at the end."""
        self._commands = []
        try:
            yield
        finally:
            commands, self._commands = self._commands, None
            if commands:
                self._command_pub.publish(bundle_cdr(commands))

    def _command(self, index: int, command: bytes) -> None:
        """A member's serialised command: gathered (an odometry bundle, a clock), else sent at once."""
        if self._commands is not None:
            self._commands.append((index, command))
        else:
            self._command_pub.publish(bundle_cdr([(index, command)]))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros fleet_controller`` (``multirotor node fleet_controller``)."""
    return run_node(FleetControllerNode, args)
