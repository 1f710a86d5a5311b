"""Hostile input to the controller (issue 11): its odometry check without DDS, then floods over ROS 2.

The ROS tests fly a simulator and a controller in lockstep (as test_nodes_sim_control.py does), flood
the controller's inputs with the seeded mix of multirotor_ros.cli.fuzz and check that the controller
runs on, never commands a non-finite or negative speed, logs each refusal reason once, and afterwards
still flies to a setpoint. Stamps of the flood are relative to the simulated time of the newest
simulated time the simulator publishes on its clock, the controller's clock. The flood goes to the
topic the probe's odometry recorder listens to as well: the recorder is cleared after each flood, so
that the checks that follow see only the simulator's odometry.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import serialize_message
from ros_harness import RosProbe
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from test_nodes_sim_control import (
    STARTUP_TIMEOUT_S,
    Vehicle,
    lockstep_vehicle,
    module_probe,
    setpoint_message,
    stamp_s,
)

from multirotor_ros.cli.fuzz import default_valid_message, flood, has_non_finite, hostile_messages
from multirotor_ros.nodes.cdr import OdometryFields, odometry_fields_from_cdr
from multirotor_ros.nodes.controller import OdometryCheck
from multirotor_ros.nodes.messages import stamp_from_ns, stamp_to_ns
from multirotor_ros.plausibility import NS_PER_S, StateLimits
from multirotor_ros.refusals import Refusal

NOW_NS = 100 * NS_PER_S
FORGET_AFTER_NS = NS_PER_S // 2


def odometry(stamp_ns: int, x: float = 0.0, **twist: float) -> Odometry:
    """Hover at (x, 0, 1) in frame odom, stamped; ``twist`` sets e.g. angular_z=1e308."""
    message = default_valid_message("odometry")
    message.header.stamp = stamp_from_ns(stamp_ns)
    message.pose.pose.position.x = x
    for name, value in twist.items():
        part, axis = name.split("_")
        setattr(getattr(message.twist.twist, part), axis, value)
    return message


def received(message: Odometry) -> OdometryFields:
    """What the controller reads of an Odometry it receives (serialised, read by nodes/cdr.py)."""
    fields = odometry_fields_from_cdr(serialize_message(message))
    assert not isinstance(fields, Refusal)
    return fields


def refused(result: object) -> str:
    assert isinstance(result, Refusal), result
    return result.reason


# ------------------------------------------------------------------ the odometry check, no DDS


def test_a_huge_body_rate_is_refused_and_the_next_odometry_accepted() -> None:
    check = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    assert not isinstance(check.accept(received(odometry(NOW_NS)), NOW_NS), Refusal)
    assert refused(check.accept(received(odometry(NOW_NS + 1000, angular_z=1e308)), NOW_NS + 1000)) == (
        "implausible body rate"
    )
    assert refused(check.accept(received(odometry(NOW_NS + 2000, linear_x=1e39)), NOW_NS + 2000)) == (
        "implausible velocity"
    )
    assert not isinstance(check.accept(received(odometry(NOW_NS + 3000)), NOW_NS + 3000), Refusal)


@pytest.mark.parametrize("stamp_ns", [NOW_NS + 3600 * NS_PER_S, (2**31 - 1) * NS_PER_S])
def test_a_future_stamp_is_refused_alone(stamp_ns: int) -> None:
    check = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    assert not isinstance(check.accept(received(odometry(NOW_NS)), NOW_NS), Refusal)
    assert refused(check.accept(received(odometry(stamp_ns)), NOW_NS + 1000)) == "stamp in the future"
    # It was not kept as the newest: the next valid odometry is accepted, and the one after it.
    for later_ns in (NOW_NS + 4_000_000, NOW_NS + 8_000_000):
        assert not isinstance(check.accept(received(odometry(later_ns)), later_ns), Refusal)


def test_a_zero_stamp_is_unstamped_except_when_simulated_time_has_just_started() -> None:
    just_started = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    assert not isinstance(just_started.accept(received(odometry(0)), 0), Refusal)
    check = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    assert refused(check.accept(received(odometry(0)), NOW_NS)) == "unstamped odometry"
    assert not isinstance(check.accept(received(odometry(NOW_NS)), NOW_NS), Refusal)


def test_a_jump_or_a_new_frame_is_refused_until_the_odometry_would_be_stale() -> None:
    check = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    assert not isinstance(check.accept(received(odometry(NOW_NS)), NOW_NS), Refusal)
    later_ns = NOW_NS + 10_000_000
    jumped = check.accept(received(odometry(later_ns, x=100.0)), later_ns)
    assert refused(jumped) == "implausible odometry position jump"
    moved = odometry(later_ns)
    moved.header.frame_id = "map"
    assert refused(check.accept(received(moved), later_ns)) == "wrong frame"
    # After odom_timeout_s without accepted odometry, a re-localised source is taken as it is.
    stale_ns = NOW_NS + FORGET_AFTER_NS + 1
    assert not isinstance(check.accept(received(odometry(stale_ns, x=100.0)), stale_ns), Refusal)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_whatever_the_check_accepts_is_plausible(seed: int) -> None:
    check = OdometryCheck(forget_after_ns=FORGET_AFTER_NS)
    limits = StateLimits()
    now_ns = NOW_NS
    # The first odometry has nothing to be compared with: a valid one, as from a running estimator.
    assert not isinstance(check.accept(received(odometry(now_ns)), now_ns), Refusal)
    for item in hostile_messages("odometry", 200, seed):
        now_ns += 4_000_000
        result = check.accept(received(item.stamped(now_ns)), now_ns)
        if isinstance(result, Refusal):
            assert result.reason and "np." not in result.detail
            continue
        p_WB_W, v_WB_W, q_WB, w_WB_B = result
        assert limits.check(p_WB_W=p_WB_W, v_WB_W=v_WB_W, w_WB_B=w_WB_B) is None
        assert math.isclose(float(np.linalg.norm(q_WB)), 1.0, rel_tol=1e-9)
        assert np.linalg.norm(p_WB_W - (0.0, 0.0, 1.0)) < 1.0  # every accepted one is near the hover


# ------------------------------------------------------------------ floods over ROS 2

FLOOD_COUNT = 3000
FLOOD_RATE_HZ = 1000.0


probe = pytest.fixture(scope="module", name="probe")(module_probe)


@pytest.fixture(scope="module")
def vehicle(probe: RosProbe, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    yield from lockstep_vehicle(probe, tmp_path_factory.mktemp("hostile_controller"), "/hc", seed=7)


@pytest.fixture(scope="module")
def simulated_now_ns(vehicle: Vehicle, probe: RosProbe) -> Callable[[], int]:
    """The newest simulated time the simulator published (only it publishes its clock)."""
    clock = probe.subscribe("/clock", Clock, qos_profile_sensor_data)
    clock.wait_for(count=1, timeout=STARTUP_TIMEOUT_S)
    return lambda: stamp_to_ns(clock.messages[-1].clock)


def forget_the_flood(vehicle: Vehicle) -> None:
    """Let the flood's last messages arrive, then keep only odometry the simulator publishes from now on."""
    time.sleep(1.0)
    vehicle.odom.clear()


def assert_refusals_logged_once_per_reason(log: str, what: str) -> None:
    firsts = [line for line in log.splitlines() if f"refused {what}: " in line]
    reasons = [line.split(f"refused {what}: ", 1)[1].split(":", 1)[0] for line in firsts]
    assert len(reasons) == len(set(reasons)), reasons
    summaries = [line for line in log.splitlines() if f"more {what} in the last" in line]
    # Summaries at most every 10 s of wall time: a flood of a few seconds gives a handful.
    assert len(summaries) <= 6, summaries


@pytest.mark.ros
def test_an_odometry_flood_moves_no_command_out_of_range_and_the_vehicle_flies_on(
    vehicle: Vehicle, probe: RosProbe, simulated_now_ns: Callable[[], int]
) -> None:
    vehicle.settle_at(0.0, 0.0, 1.0)
    commands = probe.subscribe("/hc/motor_speed_cmd", JointState)
    publisher = probe.publisher("/hc/odom", Odometry)
    probe.wait_for_subscribers(
        publisher, count=2, timeout=STARTUP_TIMEOUT_S
    )  # controller and probe... or more
    # The reproductions of issue 11 first, then the seeded mix.
    now_ns = simulated_now_ns()
    publisher.publish(odometry(now_ns, angular_z=1e308))
    publisher.publish(odometry(now_ns + 3600 * NS_PER_S))
    publisher.publish(odometry((2**31 - 1) * NS_PER_S))
    flood(
        hostile_messages("odometry", FLOOD_COUNT, seed=11),
        publisher.publish,
        simulated_now_ns,
        FLOOD_RATE_HZ,
    )
    forget_the_flood(vehicle)
    vehicle.controller.assert_running()
    settled = vehicle.settle_at(0.5, 0.0, 1.2, tolerance=0.05)
    received = commands.messages
    assert len(received) > 100
    assert not any(has_non_finite(m) or min(m.velocity) < 0.0 for m in received)
    assert stamp_s(received[-1]) > settled - 1.0  # still commanding after the flood
    log = vehicle.controller.log_text()
    assert "refused odom: implausible body rate:" in log
    assert "refused odom: stamp in the future:" in log
    assert "odometry is stale" not in log
    assert_refusals_logged_once_per_reason(log, "odom")


@pytest.mark.ros
def test_a_setpoint_flood_leaves_the_vehicle_at_its_valid_setpoint(vehicle: Vehicle, probe: RosProbe) -> None:
    vehicle.settle_at(0.0, 0.0, 1.0)
    publisher = probe.publisher("/hc/setpoint", type(setpoint_message(0.0, 0.0, 1.0)))
    probe.wait_for_subscribers(publisher, timeout=STARTUP_TIMEOUT_S)
    start = stamp_s(vehicle.latest())
    for target in [(0.0, 0.0, 1e5), (1e308, 0.0, 1.0)]:
        publisher.publish(setpoint_message(*target))
    # Every setpoint of the mix that is accepted is the hover at (0, 0, 1): far, huge and non-finite ones,
    # wrong frames and invalid quaternions are refused, and the vehicle keeps its setpoint.
    flood(hostile_messages("setpoint", FLOOD_COUNT, seed=12), publisher.publish, lambda: 0, FLOOD_RATE_HZ)
    end = stamp_s(vehicle.latest())
    _, positions = vehicle.between(start, end + 2.0)
    assert np.linalg.norm(positions - (0.0, 0.0, 1.0), axis=1).max() < 0.05
    vehicle.controller.assert_running()
    log = vehicle.controller.log_text()
    assert "refused setpoint: implausible position: setpoint position of magnitude 100000 m" in log
    assert_refusals_logged_once_per_reason(log, "setpoint")
    vehicle.settle_at(-0.5, 0.5, 1.0, tolerance=0.05)
