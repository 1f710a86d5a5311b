"""The identifier and the controller as ROS 2 citizens (issue 16): /diagnostics, resets, log lines.

Real nodes over DDS. The identifier is fed a simulated flight by the probe, stamped with the wall clock
as a vehicle without a simulator would stamp it (so that a time printed as a stamp would read as
seconds since 1970); the controller flies a lockstep simulator as in test_nodes_sim_control.py (times
there are simulated seconds). ``simulation_reset`` is published by the probe, as the simulator does
when its ``~/reset`` is called.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from test_node_identifier import rotor_statuses, samples
from test_nodes_sim_control import (
    Vehicle,
    module_probe,
    position,
    setpoint_message,
    stamp_s,
    start_vehicle,
    stop_vehicles,
)

from multirotor_ros.diagnosis.campaign import FaultCase, fly_case
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.messages import joint_state_from_rotor_speeds, odometry_message, stamp_from_ns
from multirotor_ros.nodes.reset import ResetFence, frame_refusal

# A log line as rcutils prints it: [LEVEL] [wall time] [logger]: message.
LOG_LINE = re.compile(r"^\[(DEBUG|INFO|WARN|ERROR|FATAL)\] \[\d+\.\d+\] \[[^\]]+\]: (.*)$")
# A stamp of the wall clock in seconds (1e9 .. 1e10, i.e. 2001 .. 2286) or in nanoseconds.
EPOCH_TIME = re.compile(r"(?<![\d.])(\d{10}(\.\d+)?|\d{19})(?![\d.])")
LONGEST_LINE = 120
NS = 1_000_000_000


def node_log_messages(log: str) -> list[tuple[str, str]]:
    """(level, message) of every line the node logged."""
    return [(m.group(1), m.group(2)) for m in map(LOG_LINE.match, log.splitlines()) if m]


def assert_short_lines_without_stamps(log: str) -> None:
    """One short line per event, no time as a stamp (refusals keep refusals.py's longer form)."""
    messages = node_log_messages(log)
    assert messages, log[-2000:]
    for level, message in messages:
        assert not EPOCH_TIME.search(message), (level, message)
        if not message.startswith("refused "):
            assert len(message) <= LONGEST_LINE, (level, message)


def trigger(probe: RosProbe, service: str) -> Trigger.Response:
    return probe._call(Trigger, service, Trigger.Request(), timeout=60.0)


def simulation_reset(stamp_ns: int, frame_id: str = "odom") -> Header:
    return Header(stamp=stamp_from_ns(stamp_ns), frame_id=frame_id)


# ------------------------------------------------------------------ without DDS


def test_the_reset_fence_drops_state_from_before_the_reset_until_newer_state_or_a_clock_gone_back() -> None:
    fence = ResetFence(clock_back_tolerance_s=0.5)
    assert not fence.stale(1, 0)  # no reset yet
    fence.close(reset_stamp_ns=10 * NS, now_ns=10 * NS)
    assert fence.stale(9 * NS, 10 * NS)  # queued before the reset: the old vehicle's
    assert not fence.stale(10 * NS, 10 * NS) and not fence.stale(9 * NS, 10 * NS)  # open for good
    # The simulator restarted its time with the reset: the clock goes back, every stamp is older.
    fence.close(reset_stamp_ns=10 * NS, now_ns=10 * NS)
    assert fence.stale(3 * NS, 9_600_000_000)  # within the tolerance: a late clock message, not a restart
    assert not fence.stale(3 * NS, 3 * NS)
    fence.close(reset_stamp_ns=10 * NS, now_ns=10 * NS)
    fence.open()  # a reset by the service: nothing to drop
    assert not fence.stale(1, 10 * NS)


def test_a_simulation_reset_for_another_frame_is_refused_and_one_without_a_frame_is_taken() -> None:
    other = frame_refusal(simulation_reset(0, "uav2/odom"), "uav1/odom")
    assert other is not None and other.reason == "wrong frame" and "uav1/odom" in other.detail
    assert frame_refusal(simulation_reset(0, "uav1/odom"), "uav1/odom") is None
    assert frame_refusal(simulation_reset(0, ""), "uav1/odom") is None  # e.g. ros2 topic pub with {}
    assert frame_refusal(simulation_reset(0, "uav2/odom"), "") is None  # no state taken yet


# ------------------------------------------------------------------ the identifier


@pytest.fixture(scope="module")
def faulty_flight():
    """6 s of X8 flight, rotor 2 stops at 4.2 s (as in test_node_identifier.py)."""
    return fly_case(load_airframe("x8_octorotor"), FaultCase(2, 0.0, 4.2, seed=5), duration_s=6.0)


class Feeder:
    """Publishes a flight's rows on ``/uav1`` in about real time, stamped from ``origin_ns``."""

    def __init__(self, probe: RosProbe, flight) -> None:
        self.odom = probe.publisher("/uav1/odom", Odometry)
        self.speeds = probe.publisher("/uav1/motor_speeds", JointState)
        self.rows = list(samples(flight))
        self.last_stamp_ns = 0

    def feed(self, rows: range, origin_ns: int, frame_id: str = "odom") -> None:
        """The rows, the first stamped ``origin_ns``."""
        for index in rows:
            stamp, p, v, q, w, omega = self.rows[index]
            stamp_ns = origin_ns + stamp - self.rows[rows.start][0]
            x = S.make_state(8, position_m=p, velocity_m_s=v, body_rate_rad_s=w)[0]
            x[S.QUATERNION] = q
            self.speeds.publish(joint_state_from_rotor_speeds(omega, stamp_from_ns(stamp_ns)))
            self.odom.publish(odometry_message(x, stamp_from_ns(stamp_ns), frame_id))
            self.last_stamp_ns = stamp_ns
            time.sleep(0.01)  # about real time, as a vehicle would send them


def samples_learnt(message: DiagnosticArray) -> int:
    """The identifier's sample count, from identified_parameters ("running estimate over N samples")."""
    return int(re.search(r"running estimate over (\d+) samples", message.status[0].message).group(1))


def waiting_for_data(statuses: list[DiagnosticStatus]) -> bool:
    return len(statuses) == 8 and all(
        s.message.endswith("no verdict yet, waiting for data") for s in statuses
    )


@pytest.mark.ros
def test_the_identifier_feeds_the_aggregator_and_starts_over_on_reset(
    tmp_path: Path, ros_probe: RosProbe, faulty_flight
) -> None:
    aggregated = ros_probe.subscribe("/diagnostics", DiagnosticArray)
    diagnostics = ros_probe.subscribe("/uav1/diagnostics", DiagnosticArray)
    parameters = ros_probe.subscribe("/uav1/identified_parameters", DiagnosticArray)
    residuals = ros_probe.subscribe("/uav1/residuals", Vector3Stamped)
    resets = ros_probe.publisher("/uav1/simulation_reset", Header)
    feeder = Feeder(ros_probe, faulty_flight)
    with NodeProcess("identifier", tmp_path / "identifier.log", namespace="/uav1") as node:
        ros_probe.wait_for_subscribers(feeder.odom, timeout=120.0)
        ros_probe.wait_for_subscribers(feeder.speeds, timeout=60.0)
        feeder.feed(range(len(feeder.rows)), time.time_ns())

        # The aggregator's topic: every status in one array, named after the node, the vehicle as hardware.
        def rotor_2_error(message: DiagnosticArray) -> bool:
            return any(
                s.name == "uav1/identifier: rotor_2" and s.level == DiagnosticStatus.ERROR
                for s in message.status
            )

        latest = aggregated.wait_for(rotor_2_error, timeout=60.0)[-1]
        assert [s.name for s in latest.status] == ["uav1/identifier: inputs"] + [
            f"uav1/identifier: rotor_{k}" for k in range(1, 9)
        ]
        assert {s.hardware_id for s in latest.status} == {"uav1"}
        # The spec's relative diagnostics is as it was, with the same levels, messages and values.
        time.sleep(1.0)  # no new data: every period now publishes the same rotor statuses
        relative = rotor_statuses(diagnostics.wait_for(rotor_statuses)[-1])
        assert [s.name for s in relative] == [f"rotor_{k}" for k in range(1, 9)]

        def content(statuses: list[DiagnosticStatus]) -> list[tuple]:
            return [(s.level, s.message, [(kv.key, kv.value) for kv in s.values]) for s in statuses]

        assert content(aggregated.messages[-1].status[1:]) == content(relative)
        assert relative[1].level == DiagnosticStatus.ERROR and "rotor 2 stopped" in relative[1].message
        assert samples_learnt(parameters.wait_for()[-1]) > 100

        # ~/reset: the fault finding, the estimates and the window are gone, as at start.
        response = trigger(ros_probe, "/uav1/identifier/reset")
        assert response.success and "starting over" in response.message, response
        diagnostics.clear()
        parameters.clear()
        assert waiting_for_data(rotor_statuses(diagnostics.wait_for(rotor_statuses)[-1]))
        assert samples_learnt(parameters.wait_for()[-1]) == 0
        started_over = aggregated.wait_for(lambda m: waiting_for_data(m.status[1:]), timeout=10.0)[-1]
        assert started_over.status[2].name == "uav1/identifier: rotor_2"

        # It learns again from what comes next; then a simulation reset starts it over too. One for
        # another vehicle (another odometry frame) is refused.
        feeder.feed(range(100), time.time_ns())
        parameters.wait_for(lambda m: samples_learnt(m) > 20, timeout=30.0)
        ros_probe.wait_for_subscribers(resets, timeout=30.0)
        resets.publish(simulation_reset(feeder.last_stamp_ns, "uav2/odom"))
        resets.publish(simulation_reset(feeder.last_stamp_ns))
        parameters.wait_for(lambda m: samples_learnt(m) == 0, timeout=30.0)
        # State still queued from before the reset (stamped before it) is the old vehicle's: dropped.
        residuals.clear()
        feeder.feed(range(100, 150), feeder.last_stamp_ns - 2_000_000_000)
        time.sleep(1.0)
        assert residuals.messages == [] and samples_learnt(parameters.messages[-1]) == 0
        feeder.feed(range(150, 250), time.time_ns())
        residuals.wait_for(count=50, timeout=30.0)
        node.assert_running()
    log = node.log_text()
    assert log.count("rotor fault at t = 4.") == 1, log[-3000:]
    assert log.count("reset by ~/reset: ") == 1 and log.count("reset by simulation_reset: ") == 1
    assert log.count("refused simulation_reset: wrong frame: ") == 1
    assert_short_lines_without_stamps(log)


@pytest.mark.ros
def test_at_the_root_namespace_diagnostics_carries_both_forms(tmp_path: Path, ros_probe: RosProbe) -> None:
    """Both names resolve to /diagnostics: the spec's two arrays and the aggregator's one, all published."""
    diagnostics = ros_probe.subscribe("/diagnostics", DiagnosticArray)
    with NodeProcess("identifier", tmp_path / "identifier.log") as node:
        aggregated = diagnostics.wait_for(lambda m: m.status[0].name == "identifier: inputs", timeout=120.0)
        names = [s.name for s in aggregated[-1].status]
        assert names == ["identifier: inputs"] + [f"identifier: rotor_{k}" for k in range(1, 9)]
        assert {s.hardware_id for s in aggregated[-1].status} == {"x8_octorotor"}  # no namespace to name
        diagnostics.wait_for(lambda m: [s.name for s in m.status] == ["inputs"])
        diagnostics.wait_for(lambda m: [s.name for s in m.status] == [f"rotor_{k}" for k in range(1, 9)])
        node.assert_running()


# ------------------------------------------------------------------ the controller

probe = pytest.fixture(scope="module", name="probe")(module_probe)


@pytest.fixture(scope="module")
def vehicle(probe: RosProbe, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    """An X8 hovering at 1 m in lockstep, as in test_fault_tolerant_flight.py."""
    vehicle = start_vehicle(
        probe,
        tmp_path_factory.mktemp("reset"),
        "/r1",
        simulator={"real_time_factor": 0.0, "command_timeout_s": 2.0, "seed": 3, "initial_z": 1.0},
        controller={},
        sim_time=True,
    )
    yield vehicle
    stop_vehicles(vehicle)


def hold_after_reset(vehicle: Vehicle, reset) -> None:
    """Fly towards x = 3 m with a climb to 2 m scheduled; ``reset()`` on the way: the vehicle stops there."""
    vehicle.settle_at(0.0, 0.0, 1.0)
    scheduled = setpoint_message(0.0, 0.0, 2.0)
    # 4 s ahead: still waiting at the reset when the lockstep loop runs on during the service call (2 s
    # ahead was once flown before the call came through), and inside the 6 s looked at after it.
    scheduled.header.stamp = stamp_from_ns(round((stamp_s(vehicle.latest()) + 4.0) * 1e9))
    vehicle.setpoints.publish(scheduled)
    sent = vehicle.fly_to(3.0, 0.0, 1.0)
    # On its way, not a fixed time after sending: at load 6+ the setpoint reached the controller after
    # the lockstep loop had flown 0.5 s past its sending (clean-clone CI: reset at x = 2 mm).
    vehicle.odom.wait_for(lambda m: stamp_s(m) > sent and position(m)[0] > 0.1, timeout=120.0)
    reset()
    reset_at = stamp_s(vehicle.latest())
    held = position(vehicle.latest())
    assert 0.05 < held[0] < 1.5, held  # on its way
    _, positions = vehicle.between(reset_at, reset_at + 6.0)
    # It brakes and comes back to where it was at the reset: neither on to x = 3 m nor up to 2 m.
    assert positions[:, 0].max() < held[0] + 0.6 and positions[:, 2].max() < 1.3
    assert np.linalg.norm(positions[-1] - held) < 0.15, (positions[-1], held)


@pytest.mark.ros
def test_the_controllers_reset_service_clears_its_setpoints_and_holds_where_it_is(
    vehicle: Vehicle, probe: RosProbe
) -> None:
    def call() -> None:
        response = trigger(probe, "/r1/controller/reset")
        assert response.success and "1 waiting setpoints cleared" in response.message, response

    hold_after_reset(vehicle, call)


@pytest.mark.ros
def test_a_simulation_reset_resets_the_controller_and_one_for_another_vehicle_is_refused(
    vehicle: Vehicle, probe: RosProbe
) -> None:
    resets = probe.publisher("/r1/simulation_reset", Header)
    probe.wait_for_subscribers(resets, timeout=60.0)

    def publish() -> None:
        resets.publish(simulation_reset(round(stamp_s(vehicle.latest()) * 1e9), "uav2/odom"))
        resets.publish(simulation_reset(round(stamp_s(vehicle.latest()) * 1e9)))

    hold_after_reset(vehicle, publish)
    log = vehicle.controller.log_text()
    assert log.count("refused simulation_reset: wrong frame: ") == 1
    assert log.count("reset by simulation_reset: integrals and 1 waiting setpoints cleared") == 1
    assert_short_lines_without_stamps(log)
