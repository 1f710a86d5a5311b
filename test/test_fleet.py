"""Several vehicles in one simulator node, one clock, a controller each, over real ROS 2 (issue 10).

The controllers run as a process each or as the nodes of one ``fleet_controller`` process, on each
vehicle's topics or on the simulator's fleet bundles (nodes/bundle.py).

The simulator steps every vehicle of its ``vehicles`` list in one batched kernel call and publishes one
``/clock``; each vehicle has its own topics and frames under its name, and its own fault parameters.
"""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from std_msgs.msg import UInt8MultiArray
from test_nodes_sim_control import STARTUP_TIMEOUT_S, setpoint_message

from multirotor_ros.nodes.cdr import odometry_fields_from_cdr
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.fleet_controller import FleetControllerNode
from multirotor_ros.nodes.messages import stamp_from_ns
from multirotor_ros.nodes.vehicles import VehicleSpec, parse_vehicles
from multirotor_ros.simulation.pacing import NS_PER_S

# name, initial pose, target (x, y, z) reached at t = 1 s
PUBLISH_PERIOD_NS = NS_PER_S // 250  # the simulator's default publish_rate_hz
PROBE_PROGRESS = "probe/progress"  # the probe's word as a lockstep follower, under each vehicle's namespace
FLEET = {
    "uav1": ("uav1", (0.0, 0.5, 1.0)),
    "uav2": ("uav2 3 0 0", (3.0, 0.0, 1.5)),
    "uav3": ("uav3 0 3 0 1.57", (-1.0, 3.0, 1.2)),
}


def test_vehicle_entries_are_parsed_and_bad_ones_named() -> None:
    assert parse_vehicles(["uav1", "uav2 3 0 0", "b 1 2 0.5 0.3"]) == [
        VehicleSpec("uav1"),
        VehicleSpec("uav2", (3.0, 0.0, 0.0)),
        VehicleSpec("b", (1.0, 2.0, 0.5), 0.3),
    ]
    for entries, reason in [
        (["1uav"], "must start with a name"),
        (["uav1 1 2"], "got 3 fields"),
        (["uav1 1 2 x"], "must be numbers"),
        (["uav1 1 2 nan"], "must be finite"),
        (["uav1 0 0 -1"], "z >= 0"),
        (["uav1", "uav1 1 0 0"], "already a vehicle"),
        ([""], "must start with a name"),
    ]:
        with pytest.raises(ValueError, match=reason) as error:
            parse_vehicles(entries)
        assert f"vehicles[{len(entries) - 1}]" in str(error.value)


@pytest.mark.ros
def test_a_fleet_controller_without_vehicles_or_with_a_bad_one_ends_with_status_2_and_the_reason(
    capsys,
) -> None:
    def run(*parameters: str) -> int:
        ros_args = [a for p in parameters for a in ("-p", p)]
        return run_node(FleetControllerNode, ["fleet_controller", "--ros-args", *ros_args])

    assert run() == 2
    assert "parameter vehicles: name at least one vehicle" in capsys.readouterr().err
    assert run("vehicles:=['uav1', '2uav']") == 2
    assert "vehicles[1] '2uav': must start with a name" in capsys.readouterr().err
    assert run("vehicles:=['uav1']", "airframe:=no_such_frame") == 2  # a controller's own check
    assert "unknown airframe 'no_such_frame'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "way",
    ["separate", "composed", "bundled"],
    ids=["a-controller-process-each", "one-fleet-controller", "one-fleet-controller-on-bundles"],
)
def test_three_vehicles_in_one_simulator_fly_with_a_controller_each(tmp_path, way: str) -> None:
    """Three controllers, as three processes or as the nodes of one ``fleet_controller`` process.

    Bundled, the fleet takes every vehicle's odometry in one message and answers in one; the vehicles'
    own topics still carry theirs to everyone else (the probe here), and fly the same.
    """
    probe = RosProbe()
    # Read serialised (nodes/cdr.py) and followed in lockstep: a probe that only listened lost 1.2 % and
    # 11.5 % of a lockstep fleet's states in two clean-clone CI runs, the simulator's bounded history
    # dropping them while the probe fell behind; as a follower it holds simulated time back instead.
    odom = {
        name: probe.subscribe(
            f"/{name}/odom",
            Odometry,
            qos=1000,
            read=odometry_fields_from_cdr,
            lockstep_progress=f"/{name}/{PROBE_PROGRESS}",
        )
        for name in FLEET
    }
    faults = probe.subscribe("/uav2/injected_faults", DiagnosticArray)
    simulator = NodeProcess(
        "simulator",
        tmp_path / "simulator.log",
        parameters={
            "real_time_factor": 0.0,
            "publish_clock": True,
            "vehicles": [entry for entry, _ in FLEET.values()],
            "lockstep_followers": PROBE_PROGRESS,
        },
    )
    controllers = (
        [
            NodeProcess(
                "fleet_controller",
                tmp_path / "fleet_controller.log",
                parameters={"use_sim_time": True, "vehicles": list(FLEET), "bundles": way == "bundled"},
            )
        ]
        if way != "separate"
        else [
            NodeProcess(
                "controller",
                tmp_path / f"{name}.log",
                namespace=f"/{name}",
                parameters={"use_sim_time": True},
            )
            for name in FLEET
        ]
    )
    try:
        for name, (_, target) in FLEET.items():
            setpoints = probe.publisher(f"/{name}/setpoint", type(setpoint_message(0, 0, 0)))
            probe.wait_for_subscribers(setpoints, timeout=STARTUP_TIMEOUT_S)
            message = setpoint_message(*target)
            message.header.frame_id = f"{name}/odom"  # the vehicle's own frame, as its odometry says
            message.header.stamp = stamp_from_ns(NS_PER_S)
            setpoints.publish(message)
        for name, (_, target) in FLEET.items():
            arrived = odom[name].wait_for(lambda m: m.stamp_ns >= 8 * NS_PER_S, timeout=300.0)
            final = arrived[-1]
            assert final.frame_id == f"{name}/odom" and final.child_frame_id == f"{name}/base_link"
            assert np.linalg.norm(np.array(final.values[:3]) - target) < 0.05, name
        # One time line: every vehicle's odometry on the same grid of publish periods (250 Hz), none missing.
        window = range(2 * NS_PER_S, 6 * NS_PER_S + 1, PUBLISH_PERIOD_NS)
        for name in FLEET:
            stamps = {m.stamp_ns for m in odom[name].messages if window.start <= m.stamp_ns < window.stop}
            assert stamps == set(window), (name, sorted(set(window) ^ stamps)[:10])
        (outcome,) = probe.set_parameters("/simulator", {"uav2.fault_motor": 3}).values()
        assert outcome.successful
        truth = faults.wait_for(lambda m: m.status[2].values[0].value == "0", timeout=30.0)[-1]
        assert [s.values[0].value for s in truth.status] == ["1", "1", "0", "1", "1", "1", "1", "1"]
        log = simulator.log_text()
        assert "3 vehicles (uav1, uav2, uav3)" in log and "uav2/rotor 3 effectiveness 0" in log
        if way != "separate":
            log = controllers[0].log_text()
            assert "3 controllers: /uav1/controller, /uav2/controller, /uav3/controller" in log, log
            # The same node as a process of its own: its parameters, under its own name.
            (outcome,) = probe.set_parameters("/uav2/controller", {"k_px": -1.0}).values()
            assert not outcome.successful and "k_px" in outcome.reason, outcome.reason
        if way == "bundled":
            assert "in bundles on /fleet/odom and /fleet/motor_speed_cmd" in log, log
            # The vehicles' own command topics carried nothing: every command went in the bundles.
            for name in FLEET:
                assert not probe.node.get_publishers_info_by_topic(f"/{name}/motor_speed_cmd"), name
            assert "refused" not in simulator.log_text()
            # A careless user's bundles: refused with the reason, counted, and both nodes fly on.
            for topic in ("/fleet/motor_speed_cmd", "/fleet/odom"):
                garbage = probe.publisher(topic, UInt8MultiArray)
                probe.wait_for_subscribers(garbage, timeout=STARTUP_TIMEOUT_S)
                garbage.publish(UInt8MultiArray(data=b"\x05\x00"))
            said = "malformed bundle: 2 bytes left at byte 0, no whole entry"
            simulator.wait_for_log(f"refused fleet/motor_speed_cmd: {said}", STARTUP_TIMEOUT_S)
            controllers[0].wait_for_log(f"refused fleet/odom: {said}", STARTUP_TIMEOUT_S)
            newest = odom["uav1"].messages[-1].stamp_ns
            odom["uav1"].wait_for(lambda m: m.stamp_ns > newest + NS_PER_S, timeout=60.0)
            for process in [*controllers, simulator]:
                process.assert_running()
    finally:
        for process in [*controllers, simulator]:
            process.stop()
        probe.close()


@pytest.mark.ros
def test_a_fleet_controller_moved_by_a_process_wide_namespace_keeps_each_controller_under_its_vehicle(
    tmp_path,
) -> None:
    """``-r __ns:=/team``, what ros2 launch gives a namespaced process, moves the fleet, not onto one name."""
    probe = RosProbe()
    controllers = NodeProcess(
        "fleet_controller",
        tmp_path / "fleet_controller.log",
        namespace="/team",
        parameters={"vehicles": ["uav1", "uav2"]},
    )
    try:
        for name in ("/team/fleet_controller", "/team/uav1/controller", "/team/uav2/controller"):
            probe.wait_for_node(name, timeout=STARTUP_TIMEOUT_S)
        said = "2 controllers: /team/uav1/controller, /team/uav2/controller"
        assert said in controllers.wait_for_log(said, STARTUP_TIMEOUT_S), controllers.log_text()
        (outcome,) = probe.set_parameters("/team/uav2/controller", {"k_px": -1.0}).values()
        assert not outcome.successful and "k_px" in outcome.reason, outcome.reason
    finally:
        controllers.stop()
        probe.close()
