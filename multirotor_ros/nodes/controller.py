"""The ``controller`` node: the seed 1 saturation law flying one vehicle (shared/spec/interfaces.md).

Wiring::

    odom (Odometry) --------> validate -> latest state --+
    setpoint (PoseStamped) -> validate -> latest target -+-> SaturationController (control/), every
                                                             1/rate_hz of the node's clock -> motor_speed_cmd

The timer runs on the node's clock, so with ``use_sim_time`` the law runs at ``rate_hz`` of simulated
time and each command is stamped with the simulated time it was computed at. Until the first setpoint
the vehicle holds the pose of the first odometry it received. With no odometry for ``odom_timeout_s``
the node stops sending commands (warning logged once) and the simulator's watchdog stops the rotors.
Gains: parameters under the paper's names, defaults from the airframe YAML's ``controller`` section,
settable at run time (validated; the integrals are rescaled so the output does not jump).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import JointState

from multirotor_ros.control.gains import GAIN_UNITS, airframe_gains
from multirotor_ros.control.law import SaturationController
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import quat_to_euler
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import (
    joint_state_from_rotor_speeds,
    setpoint_from_pose,
    stamp_to_ns,
    state_from_odometry,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.refusals import Refusal, RefusalCounter


def controller_parameters(gains: dict[str, float]) -> list[NodeParameter]:
    """Gains (defaults from the airframe YAML) and the node's own settings."""
    specs = [
        NodeParameter(name, value, meaning, unit, 0.0, 1e6, low_exclusive=True, read_only=name == "rate_hz")
        for name, value in gains.items()
        for unit, meaning in [GAIN_UNITS[name]]
    ]
    specs.append(
        NodeParameter(
            "odom_timeout_s",
            0.5,
            "stop commanding when odometry is older than this",
            "s",
            0.0,
            60.0,
            low_exclusive=True,
        )
    )
    return specs


class ControllerNode(Node):
    """Position and yaw control of one vehicle; see the module docstring."""

    def __init__(self, **kwargs: Any):
        super().__init__("controller", **kwargs)
        name = self.declare_parameter(
            "airframe",
            "x8_octorotor",
            NodeParameter(
                "airframe",
                "",
                "airframe config name or YAML path (its controller section gives the gains)",
                read_only=True,
            ).descriptor(),
        ).value
        self.airframe = load_airframe(name)
        gains = airframe_gains(self.airframe)
        specs = controller_parameters(gains.as_dict())
        self._specs = {spec.name: spec for spec in specs}
        values = declare_parameters(self, specs)
        self.law = SaturationController(self.airframe, gains.replace(**{k: values[k] for k in GAIN_UNITS}))
        self._odom_timeout_ns = round(values["odom_timeout_s"] * 1e9)
        self._state: tuple[Any, ...] | None = None
        self._state_stamp_ns = 0
        self._state_received_ns = 0
        self._target: tuple[np.ndarray, float] | None = None
        self._odom_frame = ""
        self._stale = False
        self._odom_refusals = RefusalCounter(self.get_logger().warning, "odom")
        self._setpoint_refusals = RefusalCounter(self.get_logger().warning, "setpoint")

        self._command_pub = self.create_publisher(JointState, "motor_speed_cmd", 10)
        self.create_subscription(Odometry, "odom", self._on_odom, 10)
        self.create_subscription(PoseStamped, "setpoint", self._on_setpoint, 10)
        self.add_on_set_parameters_callback(lambda params: check_parameters(self._specs, params))
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(1.0 / self.law.gains.rate_hz, self._on_timer)
        self.get_logger().info(
            f"{self.airframe.name}: seed 1 saturation law at {self.law.gains.rate_hz:g} Hz"
        )

    def _on_odom(self, message: Odometry) -> None:
        state = state_from_odometry(message)
        stamp_ns = stamp_to_ns(message.header.stamp)
        if isinstance(state, Refusal):
            self._odom_refusals.refuse(state.reason, state.detail)
            return
        if stamp_ns < self._state_stamp_ns:
            self._odom_refusals.refuse(
                "out-of-order stamp", f"{stamp_ns} ns is older than {self._state_stamp_ns} ns"
            )
            return
        self._state, self._state_stamp_ns = state, stamp_ns
        self._state_received_ns = self.get_clock().now().nanoseconds
        self._odom_frame = message.header.frame_id
        if self._target is None:
            self._target = (state[0].copy(), float(quat_to_euler(state[2])[2]))

    def _on_setpoint(self, message: PoseStamped) -> None:
        frame = message.header.frame_id
        if frame and self._odom_frame and frame != self._odom_frame:
            self._setpoint_refusals.refuse(
                "wrong frame", f"frame_id {frame!r}, odometry is in {self._odom_frame!r}"
            )
            return
        target = setpoint_from_pose(message)
        if isinstance(target, Refusal):
            self._setpoint_refusals.refuse(target.reason, target.detail)
            return
        self._target = target

    def _on_timer(self) -> None:
        if self._state is None or self._target is None:
            return
        now = self.get_clock().now()
        if now.nanoseconds - self._state_received_ns > self._odom_timeout_ns:
            if not self._stale:
                self.get_logger().warning("odometry is stale: no motor commands until it returns")
            self._stale = True
            return
        self._stale = False
        p, v, q, w = self._state
        output = self.law.update(now.nanoseconds * 1e-9, p, v, q, w, *self._target)
        self._command_pub.publish(joint_state_from_rotor_speeds(output.omega_cmd_rad_s, now.to_msg()))

    def _apply_parameters(self, parameters: list[Any]) -> None:
        changes = {p.name: float(p.value) for p in parameters if p.name in GAIN_UNITS}
        if changes:
            self.law.set_gains(self.law.gains.replace(**changes))
        for parameter in parameters:
            if parameter.name == "odom_timeout_s":
                self._odom_timeout_ns = round(float(parameter.value) * 1e9)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros controller`` and ``multirotor node controller``."""
    return run_node(ControllerNode, args)
