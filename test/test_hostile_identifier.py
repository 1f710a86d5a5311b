"""Hostile input to the identifier: bad messages neither stop it nor move its estimates, and it stays small.

The library tests feed multirotor_ros.diagnosis.monitor.FlightMonitor directly (no ROS, fast): a
simulated flight once clean and once with a seeded flood of bad-but-finite messages mixed in, and a
long stream for the memory bound. The topic-level test floods a running identifier node with the
hostile messages of multirotor_ros.cli.fuzz.
"""

from __future__ import annotations

import math
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from sensor_msgs.msg import JointState
from test_node_identifier import ORIGIN_NS, samples

from multirotor_ros.cli.fuzz import has_non_finite, hostile_messages
from multirotor_ros.diagnosis.campaign import FaultCase, fly_case
from multirotor_ros.diagnosis.monitor import FlightMonitor, StepResult
from multirotor_ros.ident.rls import OnlineSettings
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.nodes.messages import joint_state_from_rotor_speeds, odometry_message, stamp_from_ns

Row = tuple[int, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]


@pytest.fixture(scope="module")
def x8() -> Airframe:
    return load_airframe("x8_octorotor")


@pytest.fixture(scope="module")
def flight(x8: Airframe) -> list[Row]:
    """20 s of X8 flight towards a waypoint and back to hover, no fault."""
    return list(samples(fly_case(x8, FaultCase(0, 1.0, math.inf, seed=8), duration_s=20.0)))


def _bad_rows(row: Row, next_stamp: int, x8: Airframe, rng: np.random.Generator) -> Iterator[tuple[str, Any]]:
    """One bad-but-finite message, sent before the valid ones of ``next_stamp`` (it may take their stamp)."""
    stamp, p, v, q, w, omega = row
    # Half of them steal the stamp of the next valid message, which is then refused as a duplicate.
    bad_stamp = next_stamp if rng.random() < 0.5 else stamp + int(rng.integers(1, next_stamp - stamp))
    kind = int(rng.integers(8))
    top = x8.rotor_speed_max_rad_s
    if kind == 0:  # plausible magnitudes, wrong speeds
        yield "speeds", (bad_stamp, rng.uniform(0.0, top, omega.size))
    elif kind == 1:  # between the maximum and twice it: clamped by a simulator, not a rotor's speed
        yield "speeds", (bad_stamp, np.full(omega.size, rng.uniform(1.05, 1.99) * top))
    elif kind == 2:  # a velocity that is not the vehicle's
        yield "state", (bad_stamp, p, v + rng.uniform(-20.0, 20.0, 3), q, w)
    elif kind == 3:  # a position jump
        yield "state", (bad_stamp, p + rng.uniform(-500.0, 500.0, 3), v, q, w)
    elif kind == 4:  # an attitude that is not the vehicle's
        random_q = rng.normal(size=4)
        yield "state", (bad_stamp, p, v, random_q / np.linalg.norm(random_q), w)
    elif kind == 5:  # body rates that are not the vehicle's
        yield "state", (bad_stamp, p, v, q, rng.uniform(-30.0, 30.0, 3))
    elif kind == 6:  # finite but huge
        yield "state", (bad_stamp, p, v * 1e200, q, w)
    else:  # a stamp in the past
        yield "state", (stamp - int(rng.integers(1, 10**9)), p, v, q, w)


def _fly(x8: Airframe, rows: list[Row], flood_rng: np.random.Generator | None) -> tuple[FlightMonitor, list]:
    """Feed the rows (speeds, then state); with ``flood_rng``, a bad message before about one in three."""
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    results: list[StepResult] = []
    refused = 0
    for index, row in enumerate(rows):
        stamp, p, v, q, w, omega = row
        if flood_rng is not None and index + 1 < len(rows) and flood_rng.random() < 0.35:
            for target, arguments in _bad_rows(row, rows[index + 1][0], x8, flood_rng):
                outcome = (
                    monitor.rotor_speeds(*arguments) if target == "speeds" else monitor.state(*arguments)
                )
                refused += not isinstance(outcome, list)
                results += outcome if isinstance(outcome, list) else []
        for outcome in (monitor.rotor_speeds(stamp, omega), monitor.state(stamp, p, v, q, w)):
            results += outcome if isinstance(outcome, list) else []
    return monitor, results


def test_a_flood_of_bad_but_finite_messages_moves_no_estimate_and_raises_no_alarm(
    x8: Airframe, flight: list[Row]
) -> None:
    clean, clean_results = _fly(x8, flight, None)
    flooded, flooded_results = _fly(x8, flight, np.random.default_rng(11))
    for results in (clean_results, flooded_results):
        assert not any(r.detection is not None and r.detection.alarm[0] for r in results)
    clean_estimates = {e.name: e for e in clean.estimates()}
    flooded_estimates = {e.name: e for e in flooded.estimates()}
    assert clean_estimates["k_f_N_s2"].value == pytest.approx(x8.k_f_N_s2, rel=0.03)
    for name, estimate in clean_estimates.items():
        # Within noise: the flood took the place of some valid samples, so the two differ a little.
        allowed = 3.0 * max(estimate.std, flooded_estimates[name].std) + 0.01 * abs(estimate.value)
        assert abs(flooded_estimates[name].value - estimate.value) <= allowed, (
            name,
            estimate,
            flooded_estimates,
        )
    assert flooded.identifier.n_samples > 0.6 * clean.identifier.n_samples


def test_a_vehicle_lying_on_its_side_with_rotors_running_is_not_learnt_from(x8: Airframe) -> None:
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    on_its_side = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])  # rolled 90 deg
    results = []
    for k in range(300):
        stamp = ORIGIN_NS + k * 10_000_000
        results += monitor.rotor_speeds(stamp, np.full(8, 650.0))
        results += monitor.state(stamp, np.zeros(3), np.zeros(3), on_its_side, np.zeros(3))
    assert all(r.skipped == "resting" for r in results)
    assert "tilted 90 deg" in results[0].events[0]
    assert monitor.identifier.n_samples == 0


def test_retained_structures_stay_bounded_over_a_long_stream(x8: Airframe, flight: list[Row]) -> None:
    """The flight over and over (as long as runs in about 30 s): what the monitor keeps stops growing."""
    monitor = FlightMonitor(x8, ["quadratic_drag"], OnlineSettings(window_s=10.0))
    span = flight[-1][0] - flight[0][0] + 10_000_000
    sizes = []
    tracemalloc.start()
    try:
        for loop in range(4):
            for stamp, p, v, q, w, omega in flight:
                monitor.rotor_speeds(stamp + loop * span, omega)
                monitor.state(stamp + loop * span, p, v, q, w)
            monitor.estimates()
            sizes.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    rate = monitor.settings.sample_rate_hz
    assert len(monitor.identifier.window) <= 10.0 * rate + 1
    assert len(monitor._waiting) <= monitor.settings.max_wait_s * rate + 1
    assert not monitor.diagnoser.detector._state.warm
    # After the first pass (window full), later passes of the same length add next to nothing.
    assert sizes[-1] - sizes[1] < 100_000, sizes


# ------------------------------------------------------------------ over ROS 2


@pytest.mark.ros
def test_the_identifier_node_survives_a_flood_on_every_input(
    tmp_path: Path, ros_probe: RosProbe, x8: Airframe, flight: list[Row]
) -> None:
    """Valid flight data at about real time with a few thousand hostile messages mixed into its inputs."""
    parameters = ros_probe.subscribe("/h1/identified_parameters", DiagnosticArray)
    diagnostics = ros_probe.subscribe("/h1/diagnostics", DiagnosticArray)
    residuals = ros_probe.subscribe("/h1/residuals", Vector3Stamped)
    odom = ros_probe.publisher("/h1/odom", Odometry)
    speeds = ros_probe.publisher("/h1/motor_speeds", JointState)
    hostile = {
        "odometry": (odom, hostile_messages("odometry", 1500, seed=3, airframe=x8)),
        "joint_state": (speeds, hostile_messages("joint_state", 1500, seed=4, airframe=x8)),
    }
    with NodeProcess("identifier", tmp_path / "identifier.log", namespace="/h1") as node:
        ros_probe.wait_for_subscribers(odom, timeout=120.0)
        ros_probe.wait_for_subscribers(speeds, timeout=60.0)
        # Stamped on the node's (wall) clock, so that its stamp gates judge the hostile stamps as they
        # would in flight (an hour ahead of the data is an hour ahead of the node's clock); 30 s behind
        # it, as the 20 s of data may be published faster than real time.
        clock_offset_ns = time.time_ns() - 30_000_000_000 - flight[0][0]
        estimates_before: dict[str, float] = {}
        for index, (data_stamp, p, v, q, w, omega) in enumerate(flight):
            stamp = now_ns = data_stamp + clock_offset_ns
            x = S.make_state(8, position_m=p, velocity_m_s=v, body_rate_rad_s=w)[0]
            x[S.QUATERNION] = q
            speeds.publish(joint_state_from_rotor_speeds(omega, stamp_from_ns(stamp)))
            odom.publish(odometry_message(x, stamp_from_ns(stamp)))
            if index >= 1000:  # after 10 s of clean flight: a hostile message of each kind per sample
                for publisher, items in hostile.values():
                    k = index - 1000
                    if k < len(items):
                        publisher.publish(items[k].stamped(now_ns))
            if index == 20:
                residuals.wait_for(count=1, timeout=120.0)  # the node is up and processing
            if index == 999:
                time.sleep(0.5)
                estimates_before = _estimates(parameters.wait_for(count=1, timeout=30.0)[-1])
            time.sleep(0.005)
        time.sleep(1.5)
        node.assert_running()
        last = parameters.wait_for(count=1, timeout=30.0)[-1]
        assert not has_non_finite(last)
        estimates_after = _estimates(last)
        assert estimates_after["k_f_N_s2"] == pytest.approx(estimates_before["k_f_N_s2"], rel=0.03)
        assert estimates_after["k_f_N_s2"] == pytest.approx(x8.k_f_N_s2, rel=0.05)
        # Every rotor OK all along (the inputs status may say that the flight's data stopped at the end).
        rotors = [
            s for message in diagnostics.messages for s in message.status if s.name.startswith("rotor_")
        ]
        assert rotors and all(s.level == DiagnosticStatus.OK for s in rotors)
    log = node.log_text()
    assert "Traceback" not in log and "internal error" not in log, log[-3000:]
    first_refusals = [line for line in log.splitlines() if "(further refusals of this kind" in line]
    reasons = [
        line.split("refused ", 1)[1].split(" (further")[0].rsplit(":", 1)[0] for line in first_refusals
    ]
    assert len(first_refusals) >= 5
    # Once per reason (per topic), then summaries: bounded, whatever the number of bad messages.
    heads = [line.split("refused ", 1)[1].split(":")[0:2] for line in first_refusals]
    assert len({tuple(h) for h in heads}) == len(heads), reasons
    lines = log.splitlines()
    assert len(lines) <= 2 * len(first_refusals) + 40, (len(lines), log[-3000:])


def _estimates(message: DiagnosticArray) -> dict[str, float]:
    return {
        kv.key: float(kv.value)
        for status in message.status
        for kv in status.values
        if not kv.key.endswith("_std")
    }
