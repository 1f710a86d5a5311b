"""Missions: the file, the bookkeeping of control/mission.py, and the mission node flying one over ROS 2.

The ROS tests start the processes the launch plans describe (multirotor_ros/launch_plan.py), with the
same executables and parameters, as ``ros2 launch`` would; ``launch`` itself is not installable here
(test/test_launch_plan.py says why).
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from ros_harness import Recorder

from multirotor_ros.control.mission import MissionProgress, read_mission
from multirotor_ros.control.setpoint_queue import SETPOINT_HORIZON_S, SETPOINT_QUEUE_LENGTH
from multirotor_ros.launch_plan import FLEET, VEHICLE, NodePlan
from multirotor_ros.nodes.messages import stamp_from_ns, stamp_to_ns
from multirotor_ros.nodes.mission import LATE_SEND_WARNING_S
from multirotor_ros.simulation.flight import SetpointError

REPOSITORY = Path(__file__).resolve().parent.parent
EXAMPLE = REPOSITORY / "config" / "missions" / "square.csv"
NS = 1_000_000_000
# Take off to 1 m, move 1 m along x, land: short enough for a loaded machine, every kind of move.
HOP = "t,x,y,z,yaw\n0,0,0,1,0\n4,1,0,1,0\n8,1,0,0,0\n"
HOP_TARGETS = [(0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
FLIGHT_TIMEOUT_S = 240.0


def _write(tmp_path: Path, text: str, name: str = "mission.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------- the file


def test_the_example_mission_takes_off_flies_a_square_and_lands_with_units_in_its_header() -> None:
    mission = read_mission(EXAMPLE)
    header = [line for line in EXAMPLE.read_text().splitlines() if line.startswith("#")]
    assert all(unit in "\n".join(header) for unit in ("t [s]", "x y z [m]", "yaw [rad]", "ENU"))
    positions = mission.table[:, 1:4]
    assert positions[0].tolist() == [0.0, 0.0, 2.0] and positions[-1].tolist() == [0.0, 0.0, 0.0]
    corners = {tuple(p[:2]) for p in positions[1:-1]}
    assert corners == {(2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)}
    assert set(positions[1:-1, 2]) == {2.0}


def test_a_mission_must_fit_the_controllers_queue(tmp_path) -> None:
    too_many = "t,x,y,z,yaw\n" + "".join(f"{k},0,0,1,0\n" for k in range(SETPOINT_QUEUE_LENGTH + 1))
    too_far = f"t,x,y,z,yaw\n0,0,0,1,0\n{SETPOINT_HORIZON_S + 1:g},0,0,1,0\n"
    outside = "t,x,y,z,yaw\n0,0,0,1,0\n5,20000,0,1,0\n"
    for text, message in [
        (
            too_many,
            f"{SETPOINT_QUEUE_LENGTH + 1} setpoints; the controller holds at most {SETPOINT_QUEUE_LENGTH}",
        ),
        (too_far, f"the last setpoint is at t = {SETPOINT_HORIZON_S + 1:g} s"),
        (outside, "setpoint 2 (t = 5 s): position beyond the controller's 10000 m limit"),
    ]:
        path = _write(tmp_path, text)
        with pytest.raises(SetpointError) as error:
            read_mission(path)
        assert str(error.value).startswith(f"{path}: ") and message in str(error.value)


# ---------------------------------------------------------------------------------------------- progress


def test_setpoints_are_stamped_from_the_start_and_offset_for_a_fleet(tmp_path) -> None:
    mission = read_mission(_write(tmp_path, HOP))
    progress = MissionProgress(mission, start_ns=7 * NS, offset_m=np.array([4.0, -2.0, 0.0]))
    assert [s.stamp_ns for s in progress.setpoints] == [7 * NS, 11 * NS, 15 * NS]
    assert [s.position_m.tolist() for s in progress.setpoints] == [[4, -2, 1], [5, -2, 1], [5, -2, 0]]
    assert [s.number for s in progress.from_in_force(12 * NS)] == [2, 3]
    assert [s.number for s in progress.from_in_force(6 * NS)] == [1, 2, 3]


def test_progress_says_what_was_reached_what_was_not_and_when_the_mission_is_done(tmp_path) -> None:
    progress = MissionProgress(read_mission(_write(tmp_path, HOP)), start_ns=0, reached_distance_m=0.1)
    assert progress.observe(0, np.array([0.0, 0.0, 0.0])) == []
    (reached,) = progress.observe(2 * NS, np.array([0.0, 0.05, 0.98]))
    assert reached.startswith(
        "setpoint 1/3 (t = 0 s: x 0.00, y 0.00, z 1.00 m, yaw 0.00 rad) reached at t = 2.00 s"
    )
    assert progress.observe(3 * NS, np.array([0.0, 0.0, 1.0])) == []  # said once
    assert progress.observe(5 * NS, np.array([0.5, 0.0, 1.0])) == []
    assert progress.observe(7 * NS, np.array([0.7, 0.0, 1.0])) == []
    (missed,) = progress.observe(9 * NS, np.array([0.9, 0.0, 0.9]))
    assert missed.startswith("setpoint 2/3 (t = 4 s: x 1.00, y 0.00, z 1.00 m, yaw 0.00 rad) not reached")
    assert "before setpoint 3 took over at t = 8.00 s (closest 0.14 m)" in missed
    assert not progress.done
    landed, done = progress.observe(12 * NS, np.array([1.0, 0.0, 0.02]))
    assert "setpoint 3/3" in landed and "reached at t = 12.00 s" in landed
    assert done.startswith("mission done at t = 12.00 s: 2 of 3 setpoints reached")
    assert progress.done and progress.observe(13 * NS, np.array([1.0, 0.0, 0.0])) == []


# ---------------------------------------------------------------------------------------------- the node


def _run_mission_node(*parameters: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "multirotor_ros.cli", "node", "mission", "--ros-args"]
    for parameter in parameters:
        command += ["-p", parameter]
    return subprocess.run(command, capture_output=True, text=True, timeout=60)


@pytest.mark.ros
def test_a_bad_mission_file_stops_the_node_with_file_and_line_and_status_2(tmp_path) -> None:
    bad = _write(tmp_path, "# units: s, m, rad\nt,x,y,z,yaw\n0,0,0,1,0\n3,1,0\n")
    result = _run_mission_node(f"mission_file:={bad}")
    assert result.returncode == 2
    assert f"mission: {bad}:4: expected 5 cells, got 3" in result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    missing = _run_mission_node()
    assert missing.returncode == 2 and "parameter mission_file is required" in missing.stderr


def _odometry(frame_id: str, position: tuple[float, float, float], stamp_s: float) -> Odometry:
    message = Odometry()
    message.header.frame_id = frame_id
    message.header.stamp = stamp_from_ns(round(stamp_s * NS))
    message.child_frame_id = "base_link"
    message.pose.pose.position.x, message.pose.pose.position.y, message.pose.pose.position.z = position
    message.pose.pose.orientation.w = 1.0
    return message


@pytest.mark.ros
def test_the_node_refuses_bad_odometry_and_sends_the_setpoints_ahead_stamped_from_its_start(
    tmp_path, start_node, ros_probe
) -> None:
    setpoints = ros_probe.subscribe("/m/setpoint", PoseStamped, qos=100)
    odom = ros_probe.publisher("/m/odom", Odometry)
    mission = start_node(
        "mission",
        namespace="/m",
        parameters={
            "mission_file": str(_write(tmp_path, HOP)),
            "frame_id": "m/odom",
            "relative_to_start": True,
        },
    )
    ros_probe.wait_for_subscribers(odom, timeout=30.0)
    odom.publish(_odometry("m/odom", (math.nan, 0.0, 0.0), 5.0))
    odom.publish(_odometry("odom", (2.0, 3.0, 0.0), 5.0))
    log = mission.wait_for_log("refused odom: wrong frame", 10.0)
    assert "refused odom: non-finite odometry" in log and "refused odom: wrong frame" in log, log
    assert "setpoints in 'm/odom' (parameter frame_id)" in log
    mission.assert_running()
    assert setpoints.messages == []
    odom.publish(_odometry("m/odom", (2.0, 3.0, 0.0), 5.0))  # the start: t = 0 is 5 s, (2, 3) the origin
    received = setpoints.wait_for(count=3, timeout=10.0)
    assert [stamp_to_ns(m.header.stamp) for m in received] == [5 * NS, 9 * NS, 13 * NS]
    assert {m.header.frame_id for m in received} == {"m/odom"}
    positions = [(m.pose.position.x, m.pose.position.y, m.pose.position.z) for m in received]
    assert positions == [(2.0, 3.0, 1.0), (3.0, 3.0, 1.0), (3.0, 3.0, 0.0)]
    odom.publish(_odometry("m/odom", (2.0, 3.0, 0.0), 4.0))
    assert "refused odom: stamp went back" in mission.wait_for_log("stamp went back", 10.0)
    mission.assert_running()


@pytest.mark.ros
def test_setpoints_that_can_only_go_out_after_they_were_due_are_said_to_be_late(
    tmp_path, start_node, ros_probe
) -> None:
    odom = ros_probe.publisher("/late/odom", Odometry)
    mission = start_node(
        "mission",
        namespace="/late",
        parameters={"mission_file": str(_write(tmp_path, HOP)), "frame_id": "late/odom"},
    )
    ros_probe.wait_for_subscribers(odom, timeout=30.0)
    odom.publish(_odometry("late/odom", (0.0, 0.0, 0.0), 5.0))  # the start, with nobody to send to
    odom.publish(_odometry("late/odom", (0.0, 0.0, 0.0), 8.0))
    # Refused for its stamp, and so proof that the mission has taken the two before it, in their order.
    odom.publish(_odometry("late/odom", (0.0, 0.0, 0.0), 7.0))
    assert "refused odom: stamp went back" in mission.wait_for_log("stamp went back", 10.0)
    setpoints = ros_probe.subscribe("/late/setpoint", PoseStamped, qos=100)
    received = setpoints.wait_for(count=3, timeout=10.0)  # the one in force (t = 0) and those to come
    assert [stamp_to_ns(m.header.stamp) for m in received] == [5 * NS, 9 * NS, 13 * NS]
    log = mission.wait_for_log("went out", 10.0)
    assert "which started at 5.000 s on the odometry's clock; sent at 8.000 s" in log, log
    assert "setpoint 1 went out 3.000 s after it was due: nobody subscribed to /late/setpoint" in log, log


def _start(start_node, plan: NodePlan):
    return start_node(plan.executable, namespace=plan.namespace, parameters=plan.parameters)


# [s] for the probe to catch up with the nodes: on a slow host its subscription ran behind them, and the
# mission was done before the probe had the odometry that shows the last target reached (CI, 2026-11-29).
PROBE_CATCH_UP_S = 30.0


def _wait_until_reached_in_order(
    odom: Recorder, targets: list[tuple[float, float, float]], within_m: float
) -> None:
    """Wait until the positions come within ``within_m`` of each target, one after the other."""
    remaining = list(targets)

    def completes(message: Odometry) -> bool:
        p = message.pose.pose.position
        if remaining and np.linalg.norm(np.subtract((p.x, p.y, p.z), remaining[0])) <= within_m:
            remaining.pop(0)
        return not remaining

    try:
        odom.wait_for(completes, timeout=PROBE_CATCH_UP_S)
    except AssertionError as error:
        raise AssertionError(f"not reached in order, from {remaining[0]} on: {error}") from None


@pytest.mark.ros
@pytest.mark.slow
def test_the_one_vehicle_plan_takes_off_and_flies_its_mission_over_ros(
    tmp_path, start_node, ros_probe
) -> None:
    plan = VEHICLE.nodes(
        {
            "namespace": "uav1",
            "mission": str(_write(tmp_path, HOP)),
            "identifier": "false",  # not needed to fly; spares a loaded machine
            "visualizer": "false",  # written by another helper; not part of this test
        }
    )
    assert [n.executable for n in plan] == ["simulator", "controller", "mission"]
    odom = ros_probe.subscribe("/uav1/odom", Odometry, qos=1000)
    processes = {node.executable: _start(start_node, node) for node in plan}
    mission = processes["mission"]
    log = mission.wait_for_log("mission done", FLIGHT_TIMEOUT_S)
    for process in processes.values():
        process.assert_running()
    assert "mission done" in log, mission.log_tail()
    assert "sent setpoints 1..3 of 3 to /uav1/setpoint" in log
    assert log.count(" reached at t = ") == 3, log
    assert "not reached" not in log
    # The vehicle itself, as the simulator reports it: off the ground, over, and down again, in this order
    # (a little wider than the mission's 0.1 m: the probe may miss odometry the lockstep loop outruns).
    _wait_until_reached_in_order(odom, HOP_TARGETS, within_m=0.15)
    messages = odom.messages
    assert messages[0].header.frame_id == "uav1/odom"
    # Took off as soon as its setpoints went out, not after a wait: at the mission's start (its first
    # odometry), or later when the controller's subscription was matched late (CI once: 2.08 s, loaded), which
    # the mission then says.
    sent = re.search(r"which started at ([0-9.]+) s on the odometry's clock; sent at ([0-9.]+) s", log)
    start_s, sent_s = float(sent.group(1)), float(sent.group(2))
    assert ("went out" in log) == (sent_s - start_s > LATE_SEND_WARNING_S), log
    lift_off_ns = next(stamp_to_ns(m.header.stamp) for m in messages if m.pose.pose.position.z > 0.05)
    assert 0.0 < lift_off_ns / NS - sent_s < 2.0


@pytest.mark.ros
@pytest.mark.slow
def test_a_controller_started_after_the_mission_gets_its_setpoints(tmp_path, start_node) -> None:
    plan = VEHICLE.nodes(
        {"mission": str(_write(tmp_path, "t,x,y,z,yaw\n0,0,0,0.5,0\n")), "identifier": "0", "visualizer": "0"}
    )
    by_name = {node.executable: node for node in plan}
    _start(start_node, by_name["simulator"])
    mission = _start(start_node, by_name["mission"])
    # The lockstep simulator resends its first state while it waits for a controller: the mission starts.
    assert "waiting for odom" in mission.wait_for_log("waiting for odom", 60.0)
    time.sleep(3.0)
    assert "sent setpoints" not in mission.log_text()
    _start(start_node, by_name["controller"])
    log = mission.wait_for_log("mission done", FLIGHT_TIMEOUT_S)
    assert "sent setpoints 1..1 of 1" in log and "mission done" in log, mission.log_tail()
    # Simulated time waited at 0 for the controller, so the setpoint went out when it was due.
    assert "went out" not in log, log


@pytest.mark.ros
@pytest.mark.slow
def test_the_fleet_plan_flies_one_mission_file_from_where_each_vehicle_stands(
    tmp_path, start_node, ros_probe
) -> None:
    plan = FLEET.nodes(
        {
            "vehicles": "2",
            "spacing": "3",
            "mission": str(_write(tmp_path, "t,x,y,z,yaw\n0,0,0,1,0\n4,0,1,1,0\n")),
            "identifier": "false",
            "visualizer": "false",
        }
    )
    odom = {k: ros_probe.subscribe(f"/uav{k}/odom", Odometry, qos=1000) for k in (1, 2)}
    processes = [_start(start_node, node) for node in plan]
    for mission in [p for p in processes if p.name == "mission"]:
        assert "mission done" in mission.wait_for_log("mission done", FLIGHT_TIMEOUT_S), mission.log_tail()
    for k, x in ((1, 0.0), (2, 3.0)):
        _wait_until_reached_in_order(odom[k], [(x, 0.0, 1.0), (x, 1.0, 1.0)], within_m=0.15)
        assert odom[k].messages[0].header.frame_id == f"uav{k}/odom"
