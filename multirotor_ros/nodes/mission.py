"""The ``mission`` node: flies a mission file by sending its setpoints to the controller.

Wiring::

    odom (Odometry) ----> the mission's start, progress (control/mission.py) -> log lines
    mission_file -------> setpoints, each stamped start + t ------------------> setpoint (PoseStamped)

Parameters: ``mission_file``, the setpoints CSV of ``multirotor simulate --setpoints`` (header
``t,x,y,z,yaw`` [s, m, m, m, rad], world ENU; config/missions/square.csv is an example), read with its
parser; ``frame_id``, the odometry's frame, which the controller requires of a setpoint (``odom``;
``uav1/odom`` for a vehicle whose frames carry the prefix ``uav1/``); ``relative_to_start``, x and y
as offsets from where the vehicle stands at the start (one mission for every vehicle of a fleet; z stays
the height above the ground); ``reached_distance_m``.

Time: the mission's t = 0 is the stamp of the first odometry it receives, and each setpoint is stamped
that plus its t. Odometry stamps are on the controller's clock (the simulator's ``/clock`` under
``use_sim_time``, else the wall clock), so the mission needs no clock of its own and works on either.

Sent ahead, not when due: once the first odometry is in and the ``setpoint`` topic has a subscriber,
every setpoint goes out at once, stamped with its time; the controller keeps the future ones in its
queue until then (control/setpoint_queue.py). In lockstep, simulated time runs as fast as the loop can
go, so a setpoint sent when due would take effect whenever this process happened to be scheduled, later
on a loaded machine; stamped ahead, each takes effect at its time exactly and the flight is the same on
any machine, as ``multirotor simulate`` flies it offline. The price is the controller's queue bounds: a
mission longer than ``SETPOINT_HORIZON_S`` or of more than ``SETPOINT_QUEUE_LENGTH`` rows is refused at
start. A subscriber that appears later (a controller started after the mission, or restarted) gets the
setpoint in force and those to come again: a restarted controller has lost its queue, and to the one
that has not, the same setpoints again change nothing.

Log: one line when the setpoints are sent (with the odometry's time then), one per setpoint reached
(within ``reached_distance_m``) or replaced by the next before it was reached, one when the mission is
done (the last setpoint reached). A warning when the first setpoints could only go out more than
``LATE_SEND_WARNING_S`` after they were due: nobody subscribed to ``setpoint`` until then (a controller
started late, or discovery slow on a loaded host), so the flight starts that much later than the mission
says; in lockstep simulated time does not wait for the mission.
The node keeps running after that, for a controller that restarts.

A mission file that cannot be flown stops the node at start with one line naming the file and the line
(or setpoint) and exit status 2 (nodes/entry.py). Odometry that is not finite, in another frame than
``frame_id``, or stamped before the newest one is refused, counted and logged once per reason
(refusals.py); the node goes on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from multirotor_ros.control.mission import REACHED_DISTANCE_M, MissionProgress, read_mission
from multirotor_ros.control.setpoint_queue import SETPOINT_QUEUE_LENGTH
from multirotor_ros.model.rotation import euler_to_quat
from multirotor_ros.nodes.clock import steady_clock
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import pose_message, stamp_from_ns, stamp_to_ns, state_from_odometry
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.refusals import Refusal, RefusalCounter

# How often the node looks for a new subscriber of its setpoints (wall time) [s].
SUBSCRIBER_CHECK_PERIOD_S = 0.25
# The first setpoints sent this much after they were due (on the odometry's clock) are said to be late [s]:
# two looks for a subscriber, so that a controller a moment behind the mission in real time is no news.
LATE_SEND_WARNING_S = 2 * SUBSCRIBER_CHECK_PERIOD_S

PARAMETERS = (
    NodeParameter(
        "mission_file", "", "setpoints CSV: header t,x,y,z,yaw [s, m, m, m, rad], world ENU", read_only=True
    ),
    NodeParameter("frame_id", "odom", "frame of the setpoints: the odometry's frame", read_only=True),
    NodeParameter(
        "relative_to_start",
        False,
        "x and y are offsets from the vehicle's position at the mission's start (z is still the height)",
        read_only=True,
    ),
    NodeParameter(
        "reached_distance_m",
        REACHED_DISTANCE_M,
        "a setpoint counts as reached this close to its position",
        "m",
        0.0,
        100.0,
        low_exclusive=True,
        read_only=True,
    ),
)


class MissionNode(Node):
    """Sends a mission's setpoints ahead and logs the vehicle's progress; see the module docstring."""

    # Its time is the odometry's stamps and its only timer is on the wall clock: it may spin on the
    # EventsExecutor under use_sim_time (nodes/entry.py make_executor).
    KEEPS_ITS_OWN_SIMULATED_TIME = True

    def __init__(self, **kwargs: Any):
        super().__init__("mission", **kwargs)
        p = declare_parameters(self, PARAMETERS)
        if not p["mission_file"]:
            raise ValueError(
                "parameter mission_file is required: the path of a setpoints CSV "
                "(share/multirotor_ros/config/missions/square.csv is an example)"
            )
        self.mission = read_mission(Path(p["mission_file"]).expanduser())
        self.add_on_set_parameters_callback(
            lambda parameters: check_parameters({row.name: row for row in PARAMETERS}, parameters)
        )
        self._frame_id = p["frame_id"]
        self._relative = bool(p["relative_to_start"])
        self._reached_distance_m = p["reached_distance_m"]
        self.progress: MissionProgress | None = None
        self._newest_ns = -1
        self._subscribers = 0
        self._sent_once = False
        self._refusals = RefusalCounter(self.get_logger().warning, "odom")
        self._publisher = self.create_publisher(PoseStamped, "setpoint", SETPOINT_QUEUE_LENGTH)
        subscribe(self, Odometry, "odom", self._on_odom, 10)
        self.create_timer(SUBSCRIBER_CHECK_PERIOD_S, self._offer, clock=steady_clock())
        self.get_logger().info(
            f"{self.mission.origin}: {len(self.mission)} setpoints over {self.mission.duration_s:g} s, "
            f"in {self._frame_id}{' relative to the start' if self._relative else ''}; waiting for odom"
        )

    def _on_odom(self, message: Odometry) -> None:
        state = state_from_odometry(message)
        stamp_ns = stamp_to_ns(message.header.stamp)
        if not isinstance(state, Refusal) and message.header.frame_id != self._frame_id:
            state = Refusal(
                "wrong frame",
                f"odometry in {message.header.frame_id[:40]!r}, setpoints in {self._frame_id!r} (parameter "
                "frame_id): the controller would refuse them",
            )
        if not isinstance(state, Refusal) and stamp_ns < self._newest_ns:
            state = Refusal(
                "stamp went back",
                f"odometry stamped {stamp_ns / 1e9:.3f} s after {self._newest_ns / 1e9:.3f} s (a restarted "
                "simulator: restart the mission too)",
            )
        if isinstance(state, Refusal):
            self._refusals.refuse(state.reason, state.detail)
            return
        self._newest_ns = stamp_ns
        p_WB_W = state[0]
        if self.progress is None:
            offset = np.array([p_WB_W[0], p_WB_W[1], 0.0]) if self._relative else None
            self.progress = MissionProgress(self.mission, stamp_ns, offset, self._reached_distance_m)
            self._offer()
        for line in self.progress.observe(stamp_ns, p_WB_W):
            self.get_logger().info(line)

    def _offer(self) -> None:
        """Send the setpoints to a subscriber that has appeared since the last look (module docstring)."""
        if self.progress is None:
            return
        count = self._publisher.get_subscription_count()
        if count > self._subscribers:
            self._send(self.progress, count)
        self._subscribers = count

    def _send(self, progress: MissionProgress, subscribers: int) -> None:
        setpoints = progress.from_in_force(self._newest_ns)
        for setpoint in setpoints:
            q_WB = euler_to_quat([0.0, 0.0, setpoint.yaw_rad])
            self._publisher.publish(
                pose_message(stamp_from_ns(setpoint.stamp_ns), self._frame_id, setpoint.position_m, q_WB)
            )
        self.get_logger().info(
            f"sent setpoints {setpoints[0].number}..{setpoints[-1].number} of {len(progress.setpoints)} to "
            f"{self._publisher.topic_name} (subscribers: {subscribers}), stamped t = "
            f"{progress.t_s(setpoints[0].stamp_ns):g}..{progress.t_s(setpoints[-1].stamp_ns):g} s of the "
            f"mission, which started at {progress.start_ns / 1e9:.3f} s on the odometry's clock; sent at "
            f"{self._newest_ns / 1e9:.3f} s"
        )
        late_s = (self._newest_ns - setpoints[0].stamp_ns) / 1e9
        if not self._sent_once and late_s > LATE_SEND_WARNING_S:
            self.get_logger().warning(
                f"setpoint {setpoints[0].number} went out {late_s:.3f} s after it was due: nobody subscribed "
                f"to {self._publisher.topic_name} until then, and the flight starts that much late"
            )
        self._sent_once = True


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros mission`` and ``multirotor node mission``."""
    return run_node(MissionNode, args)
