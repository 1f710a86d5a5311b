"""The ``visualizer`` node: what RViz shows of one vehicle (nodes/visual_messages.py draws it).

Wiring::

    odom (Odometry) ------------------------> frames, path flown --+
    motor_speed_cmd (JointState) -----------> commanded speeds ----+--> markers (MarkerArray, rate_hz)
    rotor_effectiveness (Float64MultiArray) -> diagnosed share ----+--> path (nav_msgs/Path, rate_hz)
    setpoint (PoseStamped) -----------------> target --------------+

The frames are the odometry's (so a simulator's or bridge's ``frame_prefix`` carries over); until the
first odometry they are ``frame_prefix`` + ``odom`` / ``base_link``. The tf the markers hang on comes from
the simulator (``/tf``, ``/tf_static``). The path keeps the last ``path_duration_s`` of positions, one
per update. Every input is checked as the controller checks it; refused ones are counted and logged once
per reason (refusals.py), and the node runs on. With ``use_sim_time`` the updates follow simulated time.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import MarkerArray

from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.effectiveness_message import effectiveness_from_message
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import (
    pose_message,
    rotor_speeds_from_joint_state,
    setpoint_from_pose,
    state_from_odometry,
)
from multirotor_ros.nodes.parameters import NodeParameter, declare_parameters
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.nodes.visual_messages import BASE_FRAME, VehicleView, vehicle_markers
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation.vehicle import OVERSIZED_SPEED_FACTOR

# The path's poses carry positions only: each is given the identity attitude (w, x, y, z).
UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])
UPRIGHT.flags.writeable = False

PARAMETERS = [
    NodeParameter("airframe", "x8_octorotor", "airframe config name or YAML path", read_only=True),
    NodeParameter("rate_hz", 10.0, "rate of markers and path", "Hz", 0.1, 100.0, read_only=True),
    NodeParameter(
        "path_duration_s", 60.0, "how much of the path flown is drawn", "s", 0.0, 3600.0, read_only=True
    ),
    NodeParameter(
        "frame_prefix", "", "prefix of the frame ids until the first odometry (e.g. uav1/)", read_only=True
    ),
]


class VisualizerNode(Node):
    """Markers and path of one vehicle; see the module docstring."""

    def __init__(self, **kwargs: Any):
        super().__init__("visualizer", **kwargs)
        p = declare_parameters(self, PARAMETERS)
        airframe = load_airframe(p["airframe"])
        self._n_rotors = airframe.n_rotors
        self._speed_limit = OVERSIZED_SPEED_FACTOR * airframe.rotor_speed_max_rad_s
        self._path: deque[tuple[float, float, float]] = deque(
            maxlen=max(2, round(p["path_duration_s"] * p["rate_hz"]))
        )
        self.view = VehicleView(
            world_frame=p["frame_prefix"] + "odom",
            base_frame=p["frame_prefix"] + BASE_FRAME,
            rotor_positions_m=airframe.rotor_positions_m,
            rotor_radius_m=airframe.rotor_radius_m,
            speed_range_rad_s=(airframe.rotor_speed_min_rad_s, airframe.rotor_speed_max_rad_s),
            path_m=self._path,  # the markers draw the path as it grows
        )
        self._position: tuple[float, float, float] | None = None
        self._refusals = {
            topic: RefusalCounter(self.get_logger().warning, topic)
            for topic in ("odom", "motor_speed_cmd", "rotor_effectiveness", "setpoint")
        }
        self._markers_pub = self.create_publisher(MarkerArray, "markers", 10)
        self._path_pub = self.create_publisher(Path, "path", 10)
        subscribe(self, Odometry, "odom", self._on_odom, 10)
        subscribe(self, JointState, "motor_speed_cmd", self._on_command, 10)
        subscribe(self, Float64MultiArray, "rotor_effectiveness", self._on_effectiveness, 10)
        subscribe(self, PoseStamped, "setpoint", self._on_setpoint, 10)
        self.create_timer(1.0 / p["rate_hz"], self._update)
        self.get_logger().info(f"{airframe.name}: markers and path at {p['rate_hz']:g} Hz")

    def _refused(self, topic: str, result: Any) -> bool:
        if isinstance(result, Refusal):
            self._refusals[topic].refuse(result.reason, result.detail)
            return True
        return False

    def _on_odom(self, message: Odometry) -> None:
        state = state_from_odometry(message)
        if self._refused("odom", state):
            return
        assert not isinstance(state, Refusal)
        self.view.world_frame = message.header.frame_id or self.view.world_frame
        self.view.base_frame = message.child_frame_id or self.view.base_frame
        x, y, z = state[0].tolist()
        self._position = (x, y, z)

    def _on_command(self, message: JointState) -> None:
        speeds = rotor_speeds_from_joint_state(message, self._n_rotors, self._speed_limit)
        if not self._refused("motor_speed_cmd", speeds):
            assert not isinstance(speeds, Refusal)
            self.view.commanded_speeds_rad_s = speeds.speeds_rad_s

    def _on_effectiveness(self, message: Float64MultiArray) -> None:
        result = effectiveness_from_message(message, self._n_rotors)
        if not self._refused("rotor_effectiveness", result):
            assert not isinstance(result, Refusal)
            self.view.effectiveness = np.asarray(result[0])

    def _on_setpoint(self, message: PoseStamped) -> None:
        target = setpoint_from_pose(message)
        if not self._refused("setpoint", target):
            assert not isinstance(target, Refusal)
            self.view.setpoint = target

    def _update(self) -> None:
        stamp = self.get_clock().now().to_msg()
        if self._position is not None:
            self._path.append(self._position)
        self._markers_pub.publish(vehicle_markers(self.view, stamp))
        path = Path()
        path.header.stamp = stamp
        path.header.frame_id = self.view.world_frame
        path.poses = [
            pose_message(stamp, self.view.world_frame, position, UPRIGHT) for position in self._path
        ]
        self._path_pub.publish(path)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros visualizer`` and ``multirotor node visualizer``."""
    return run_node(VisualizerNode, args)
