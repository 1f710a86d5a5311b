"""The identifier: its ROS-free core (FlightMonitor, record) on simulated flights, then the node over ROS 2.

The monitor tests feed flights of multirotor_ros.simulation.simulate_flight (sensor noise, rotor lag,
seed 1 controller) sample by sample, as the node would from ``odom`` and ``motor_speeds``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from sensor_msgs.msg import JointState

from multirotor_ros.diagnosis.campaign import FaultCase, fly_case
from multirotor_ros.diagnosis.monitor import FlightMonitor, Refused, StepResult
from multirotor_ros.diagnosis.record import FlightRecord
from multirotor_ros.io.flight_log import read_flight_log, rotor_columns
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import euler_to_quat
from multirotor_ros.nodes.messages import (
    joint_state_from_rotor_speeds,
    odometry_message,
    stamp_from_ns,
    stamp_to_ns,
)

ORIGIN_NS = 1_000_000_000_000  # stamps of a node started long after the epoch of its clock


@pytest.fixture(scope="module")
def x8():
    return load_airframe("x8_octorotor")


@pytest.fixture(scope="module")
def faulty_flight(x8):
    """6 s of X8 flight, rotor 2 stops at 4.2 s."""
    return fly_case(x8, FaultCase(2, 0.0, 4.2, seed=5), duration_s=6.0)


@pytest.fixture(scope="module")
def nominal_flight(x8):
    return fly_case(x8, FaultCase(0, 1.0, math.inf, seed=6), duration_s=6.0)


def samples(log):
    """Per row: stamp [ns], p, v, q (w, x, y, z), body rates (gyro), rotor speeds."""
    q = euler_to_quat(log.euler())
    omega = np.column_stack([log.column(c) for c in rotor_columns("omega", log.n_rotors)])
    for k in range(len(log)):
        yield (
            ORIGIN_NS + round(log.t[k] * 1e9),
            np.array([log.column(c)[k] for c in "xyz"]),
            np.array([log.column(c)[k] for c in ("vx", "vy", "vz")]),
            q[k],
            np.array([log.column(c)[k] for c in "pqr"]),
            omega[k],
        )


def feed(monitor, rows, accelerations=None):
    """Each row's rotor speeds, then its state (with the IMU's acceleration if given); all results."""
    results = []
    for index, (stamp, p, v, q, w, omega) in enumerate(rows):
        results += monitor.rotor_speeds(stamp, omega)
        results += monitor.state(stamp, p, v, q, w, None if accelerations is None else accelerations[index])
    return results


def test_monitor_names_the_stopped_rotor_and_stops_learning_from_the_faulty_flight(x8, faulty_flight):
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    rows = list(samples(faulty_flight))
    feed(monitor, rows[:415])
    learnt_before = monitor.identifier.n_samples
    k_f = {e.name: e for e in monitor.estimates()}["k_f_N_s2"]
    assert k_f.value == pytest.approx(x8.k_f_N_s2, rel=0.05)
    results = feed(monitor, rows[415:])
    alarms = [r for r in results if r.detection is not None and r.detection.alarm[0]]
    assert alarms and alarms[0].t - 4.2 <= 0.2
    reports = monitor.reports()
    assert reports[1].name == "rotor_2" and reports[1].level == "ERROR"
    assert "rotor 2 stopped or lost its propeller" in reports[1].message
    assert all(r.level == "OK" for k, r in enumerate(reports) if k != 1)
    # Learning stops at the suspicion: the fault is not absorbed into the thrust constant.
    assert monitor.identifier.n_samples <= learnt_before + 25


def test_monitor_with_imu_acceleration_identifies_and_names_the_rotor(x8, faulty_flight):
    """Pose + imu input: the acceleration is measured, the identifier needs no velocity difference."""
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    accelerations = np.column_stack([faulty_flight.column(c) for c in ("ax", "ay", "az")])
    results = feed(monitor, list(samples(faulty_flight)), accelerations)
    first = next(r for r in results if r.detection is not None and r.detection.alarm[0])
    assert 0 < first.t - 4.2 <= 0.2 and int(first.detection.rotor[0]) == 1
    k_f = {e.name: e for e in monitor.estimates()}["k_f_N_s2"]
    assert k_f.value == pytest.approx(x8.k_f_N_s2, rel=0.05)


def test_nothing_is_learnt_or_diagnosed_while_resting_on_the_ground(x8):
    from multirotor_ros.simulation import simulate_flight

    # On the ground until 1.5 s (the controller holds hover thrust there), then a climb to 1.5 m.
    log = simulate_flight(
        x8, setpoints=[(1.5, 0.0, 0.0, 1.5, 0.0)], duration_s=4.0, rng=np.random.default_rng(7)
    )
    rows = list(samples(log))
    # Until 1.4 s the rotors idle at half speed instead: the ground carries most of the weight. Then
    # they hold hover thrust on the ground, which is still resting, until the climb lifts the vehicle.
    rows = [(s, p, v, q, w, omega * (0.5 if s < ORIGIN_NS + 1.4e9 else 1.0)) for s, p, v, q, w, omega in rows]
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    results = feed(monitor, rows)
    resting = [r for r in results if r.skipped == "resting"]
    assert resting[0].t < 0.1 and 1.5 <= resting[-1].t < 1.6
    assert all(r.skipped == "resting" for r in results if r.t <= resting[-1].t)
    # Times in words are seconds since the first sample (stamps start at 1000 s), not the stamps.
    assert any(e.startswith("resting at t = 0.00 s (on the ground") for r in results for e in r.events)
    assert any(e.startswith("flying from t = 1.5") for r in results for e in r.events)
    assert not any(r.detection is not None and r.detection.alarm[0] for r in results)
    assert monitor.identifier.n_samples <= len(results) - len(resting)


def test_a_state_waits_for_the_rotor_speeds_of_its_time(x8, nominal_flight):
    monitor = FlightMonitor(x8, [])
    rows = list(samples(nominal_flight))
    feed(monitor, rows[:100])
    stamp, p, v, q, w, omega = rows[100]
    assert monitor.state(stamp, p, v, q, w) == []  # the speeds of its time are not there yet
    (result,) = monitor.rotor_speeds(stamp, omega)
    assert result.stamp_ns == stamp and result.skipped is None and result.accel_residual_W is not None


def test_states_before_the_first_rotor_speeds_are_skipped_as_expected_then_paired(x8, nominal_flight):
    """An identifier joining a running simulator hears odometry (250 Hz) before rotor speeds (100 Hz)."""
    rows = list(samples(nominal_flight))
    for restarted in (False, True):
        monitor = FlightMonitor(x8, [])
        if restarted:  # a new time line forgets the old one's first report
            feed(monitor, rows[:50])
            monitor.restart()
        early = [monitor.state(*row[:5]) for row in rows[50:53]]
        assert early == [[], [], []]  # they wait for rotor speeds of their time
        results = feed(monitor, rows[53:60])
        first = [r for r in results if r.stamp_ns < rows[53][0]]
        assert [r.skipped for r in first] == ["before the first motor_speeds"] * 3
        assert all(
            r.skipped_as_expected and "came before any rotor speeds" in r.skipped_detail for r in first
        )
        assert not any(r.skipped_as_expected for r in results if r.stamp_ns >= rows[53][0])
    # Speeds that stop later are a fault of the input, and said so (test below).
    assert not StepResult(0.0, 0, skipped="no recent motor_speeds").skipped_as_expected


def test_monitor_refuses_repeated_and_older_stamps_and_non_finite_states(x8, nominal_flight):
    monitor = FlightMonitor(x8, [])
    rows = list(samples(nominal_flight))
    feed(monitor, rows[:10])
    stamp, p, v, q, w, omega = rows[9]
    assert monitor.state(stamp, p, v, q, w) == Refused(
        "duplicated stamp", monitor.state(stamp, p, v, q, w).detail
    )
    assert monitor.state(stamp - 1, p, v, q, w).reason == "stamp out of order"
    assert monitor.rotor_speeds(stamp, omega).reason == "duplicated stamp"
    assert monitor.rotor_speeds(stamp - 5, omega).reason == "stamp out of order"
    bad = v.copy()
    bad[1] = math.nan
    assert monitor.state(stamp + 10_000_000, p, bad, q, w).reason == "non-finite velocity"
    # Finite is not yet plausible: a position 1e308 m away, a jump of 50 m in 10 ms, rotor speeds
    # above the airframe's maximum (the simulator clamps up to twice that, the identifier must not learn).
    assert monitor.state(stamp + 10_000_000, p + 1e308, v, q, w).reason == "implausible position"
    assert monitor.state(stamp + 10_000_000, p + 50.0, v, q, w).reason == "implausible position jump"
    fast = np.full(8, 1.1 * x8.rotor_speed_max_rad_s)
    assert monitor.rotor_speeds(stamp + 10_000_000, fast).reason == "rotor speed outside the airframe's range"
    # None of them was kept: the next valid speeds and state are taken.
    assert not isinstance(monitor.rotor_speeds(stamp + 10_000_000, omega), Refused)
    assert not isinstance(monitor.state(stamp + 10_000_000, p, v, q, w), Refused)


def test_monitor_skips_samples_without_rotor_speeds_and_warns_of_gaps(x8, nominal_flight):
    monitor = FlightMonitor(x8, [])
    rows = list(samples(nominal_flight))
    feed(monitor, rows[:150])
    stamp, p, v, q, w, _ = rows[150]
    # The rotor speeds stopped coming: the state waits for them...
    assert monitor.state(stamp + 100_000_000, p, v, q, w) == []
    # ...and 0.4 s later, when both come back, it is found without rotor speeds of its time; then a gap,
    # said in words, and no alarm from the observer's restart.
    results = feed(monitor, rows[200:])
    assert results[0].skipped == "no recent motor_speeds" and results[0].t == pytest.approx(1.6)
    assert any("gap of 0.5" in warning for r in results for warning in r.warnings)
    assert not any(r.detection is not None and r.detection.alarm[0] for r in results)


def test_record_resumes_estimate_window_and_noise_and_survives_a_torn_line(x8, nominal_flight, tmp_path):
    rows = list(samples(nominal_flight))
    first = FlightMonitor(x8, ["quadratic_drag"], record=FlightRecord(tmp_path, x8.name, 8))
    feed(first, rows[:400])
    first.flush_record()
    saved_updates = first.identifier.rls.n_updates
    saved_theta = first.identifier.rls.theta.copy()
    segment = tmp_path / "segment_0001.csv"
    log = read_flight_log(segment, 8)  # any offline tool can read the record
    assert len(log) >= 390 and log.metadata["airframe"] == "x8_octorotor"
    # A crash in the middle of a write: half a line at the end.
    with open(segment, "a", encoding="utf-8") as handle:
        handle.write("4.01,0.1,0.2")
    second = FlightMonitor(x8, ["quadratic_drag"], record=FlightRecord(tmp_path, x8.name, 8))
    assert any("torn last line" in note for note in second.notes)
    assert second.identifier.rls.n_updates == saved_updates
    np.testing.assert_array_equal(second.identifier.rls.theta, saved_theta)
    assert len(second.identifier.window) == len(log)
    assert second.diagnoser.detector.warmed_up
    # It goes on where the first stopped, in the same segment and time base.
    results = feed(second, rows[400:])
    assert results[0].t == pytest.approx(nominal_flight.t[400])
    assert not any(r.detection is not None and r.detection.alarm[0] for r in results)
    second.flush_record()
    assert len(read_flight_log(segment, 8)) > len(log)
    # A third start whose clock restarted from zero: a new segment and a warning, the estimate kept.
    third = FlightMonitor(x8, ["quadratic_drag"], record=FlightRecord(tmp_path, x8.name, 8))
    # A second of it: after the restart the detector settles and learns the noise again, and until it
    # can judge, the identifier learns (and records) nothing.
    restarted = [(s - ORIGIN_NS + 1, *rest) for s, *rest in rows[:100]]
    results = feed(third, restarted)
    assert any("clock went back" in warning for warning in results[0].warnings)
    third.flush_record()
    assert (tmp_path / "segment_0002.csv").exists()
    assert third.identifier.rls.n_updates >= saved_updates


# ------------------------------------------------------------------ over ROS 2


def diagnostics_naming(rotor: str, level: int):
    def matches(message: DiagnosticArray) -> bool:
        return any(s.name == rotor and s.level == level for s in message.status)

    return matches


def rotor_statuses(message: DiagnosticArray) -> list[DiagnosticStatus]:
    """The rotors' statuses of a diagnostics message (the ``inputs`` status comes in one of its own)."""
    return [s for s in message.status if s.name.startswith("rotor_")]


@pytest.mark.ros
def test_identifier_refuses_bad_messages_logs_them_once_and_keeps_publishing(
    tmp_path: Path, ros_probe: RosProbe, x8, nominal_flight
) -> None:
    residuals = ros_probe.subscribe("/i1/residuals", Vector3Stamped)
    parameters = ros_probe.subscribe("/i1/identified_parameters", DiagnosticArray)
    diagnostics = ros_probe.subscribe("/i1/diagnostics", DiagnosticArray)
    odom = ros_probe.publisher("/i1/odom", Odometry)
    speeds = ros_probe.publisher("/i1/motor_speeds", JointState)
    with NodeProcess(
        "identifier",
        tmp_path / "identifier.log",
        namespace="/i1",
        parameters={"record_path": str(tmp_path / "record")},
    ) as node:
        ros_probe.wait_for_subscribers(odom, timeout=120.0)
        ros_probe.wait_for_subscribers(speeds, timeout=60.0)
        rows = list(samples(nominal_flight))
        for index, (stamp, p, v, q, w, omega) in enumerate(rows[:300]):
            x = S.make_state(8, position_m=p, velocity_m_s=v, body_rate_rad_s=w)[0]
            x[S.QUATERNION] = q
            speeds.publish(joint_state_from_rotor_speeds(omega, stamp_from_ns(stamp)))
            odom.publish(odometry_message(x, stamp_from_ns(stamp)))
            if index % 50 == 25:
                bad_count = joint_state_from_rotor_speeds(omega[:4], stamp_from_ns(stamp + 1))
                bad_value = joint_state_from_rotor_speeds(
                    np.where(np.arange(8) == 3, math.nan, omega), stamp_from_ns(stamp + 2)
                )
                speeds.publish(bad_count)
                speeds.publish(bad_value)
                # The same message again is a resend (a lockstep simulator's), ignored without a word;
                # another state with the same stamp is refused.
                odom.publish(odometry_message(x, stamp_from_ns(stamp)))
                moved = x.copy()
                moved[S.POSITION] += 0.001
                odom.publish(odometry_message(moved, stamp_from_ns(stamp)))
                stale = odometry_message(x, stamp_from_ns(stamp - 5_000_000))
                odom.publish(stale)
            time.sleep(0.01)  # about real time, as a vehicle would send them
            if index == 20:
                residuals.wait_for(count=1, timeout=120.0)  # the node is up and processing
        residuals.wait_for(count=50, timeout=120.0)
        published = parameters.wait_for(count=1, timeout=60.0)[-1]
        names = {s.name for s in published.status}
        assert names == {"airframe", "quadratic_drag"}
        keys = {kv.key for s in published.status for kv in s.values}
        assert {"k_f_N_s2", "k_f_N_s2_std", "c_x", "c_x_std"} <= keys
        statuses = diagnostics.wait_for(rotor_statuses, timeout=60.0)[-1].status
        assert [s.name for s in statuses] == [f"rotor_{k}" for k in range(1, 9)]
        assert all(s.level == DiagnosticStatus.OK for s in statuses)
        (inputs,) = diagnostics.wait_for(lambda m: m.status[0].name == "inputs", timeout=60.0)[-1].status
        assert inputs.level == DiagnosticStatus.OK and inputs.message == "receiving motor_speeds, odom"
        assert {kv.key: kv.value for kv in inputs.values}["odom_resent"] == "6"
        # Thresholds change at run time within their range; the rest is read-only.
        results = ros_probe.set_parameters("/i1/identifier", {"detection.k_sigma": 6.0}, timeout=60.0)
        assert results["detection.k_sigma"].successful
        results = ros_probe.set_parameters("/i1/identifier", {"detection.min_loss": 1.5}, timeout=60.0)
        assert not results["detection.min_loss"].successful
        assert "min_loss must be in (0, 1)" in results["detection.min_loss"].reason
        results = ros_probe.set_parameters("/i1/identifier", {"window_s": 10.0}, timeout=60.0)
        assert "read-only" in results["window_s"].reason
        node.assert_running()
    log = node.log_text()
    for reason in ("wrong rotor count", "non-finite speed", "duplicated stamp", "stamp out of order"):
        assert log.count(f": {reason}:") == 1, (reason, log[-3000:])
    assert (tmp_path / "record" / "state.npz").exists()
    assert (tmp_path / "record" / "segment_0001.csv").exists()


@pytest.mark.ros
@pytest.mark.parametrize("source", ["odom", "pose_imu"])
def test_a_fault_set_with_ros2_param_set_is_named_on_diagnostics(
    tmp_path: Path, ros_probe: RosProbe, source: str
) -> None:
    """Simulator + controller + identifier over topics; the fault is injected by setting parameters.

    In lockstep, the default: in real time a loaded host delayed the pose or the IMU by a few periods
    around the injection (the simulator late, a burst), and the identifier, rightly, learnt its noise
    again after that gap before it named the fault: 0.79 s instead of 0.1-0.25 s, twice in full runs.
    """
    diagnostics = ros_probe.subscribe("/e2e/diagnostics", DiagnosticArray)
    residuals = ros_probe.subscribe("/e2e/residuals", Vector3Stamped)
    truth = ros_probe.subscribe("/e2e/injected_faults", DiagnosticArray)
    common = {"namespace": "/e2e"}
    # The controller starts first and the simulator's watchdog is lenient: on a loaded machine a
    # controller that starts late would otherwise find the vehicle already fallen to the ground.
    with (
        NodeProcess(
            "controller",
            tmp_path / "controller.log",
            **common,
            # The nominal allocation: this test is about naming the fault, test_fault_tolerant_flight.py
            # about flying with it (reallocation takes the stopped rotor's signature out of the residual).
            parameters={"use_sim_time": True, "fault_tolerant_allocation": False},
        ),
        NodeProcess(
            "identifier",
            tmp_path / "identifier.log",
            **common,
            parameters={"input": source, "use_sim_time": True},
        ) as identifier,
        NodeProcess(
            "simulator",
            tmp_path / "simulator.log",
            **common,
            parameters={
                "real_time_factor": 0.0,
                "publish_clock": True,
                "initial_z": 2.0,
                "seed": 4,
                "command_timeout_s": 30.0,
            },
        ),
    ):
        # The identifier has learnt the residual noise once it has a verdict for every rotor.
        def settled(message: DiagnosticArray) -> bool:
            return len(message.status) == 8 and all("no verdict yet" not in s.message for s in message.status)

        diagnostics.wait_for(settled, timeout=180.0)
        residuals.wait_for(count=20, timeout=60.0)
        assert not any(
            s.level != DiagnosticStatus.OK for m in diagnostics.messages for s in rotor_statuses(m)
        )
        results = ros_probe.set_parameters(
            "/e2e/simulator", {"fault_effectiveness": 0.0, "fault_motor": 3}, timeout=60.0
        )
        assert all(r.successful for r in results.values()), results
        named = diagnostics.wait_for(diagnostics_naming("rotor_3", DiagnosticStatus.ERROR), timeout=60.0)[-1]
        faulty = next(s for s in named.status if s.name == "rotor_3")
        assert "rotor 3" in faulty.message and "thrust left" in faulty.message
        others = [s for s in named.status if s.name != "rotor_3"]
        assert all(s.level == DiagnosticStatus.OK for s in others)

        # Detected after the injection, on the same (simulated) clock, and soon after it.
        def injected(message: DiagnosticArray) -> bool:
            return any(s.name == "rotor_3" and s.level == DiagnosticStatus.ERROR for s in message.status)

        injected_at = stamp_to_ns(truth.wait_for(injected, timeout=30.0)[0].header.stamp) * 1e-9
        detected_at = float(next(kv.value for kv in faulty.values if kv.key == "detected_at_s"))
        assert 0.0 < detected_at - injected_at <= 0.5, (injected_at, detected_at)
        identifier.assert_running()


@pytest.fixture(scope="module")
def longer_nominal_flight(x8):
    return fly_case(x8, FaultCase(0, 1.0, math.inf, seed=9), duration_s=10.0)


@pytest.mark.ros
def test_identifier_names_a_silent_input_and_takes_gaps_for_missing_data(
    tmp_path: Path, ros_probe: RosProbe, longer_nominal_flight
) -> None:
    """A fault-free flight with a gap in both inputs, then motor_speeds silent for 2 s while odom goes on."""
    residuals = ros_probe.subscribe("/i2/residuals", Vector3Stamped)
    diagnostics = ros_probe.subscribe("/i2/diagnostics", DiagnosticArray)
    odom = ros_probe.publisher("/i2/odom", Odometry)
    speeds = ros_probe.publisher("/i2/motor_speeds", JointState)
    both_lost = range(300, 330)
    speeds_silent = range(500, 700)
    with NodeProcess(
        "identifier", tmp_path / "identifier.log", namespace="/i2", parameters={"input_timeout_s": 0.5}
    ) as node:
        ros_probe.wait_for_subscribers(odom, timeout=120.0)
        ros_probe.wait_for_subscribers(speeds, timeout=60.0)
        for index, (stamp, p, v, q, w, omega) in enumerate(samples(longer_nominal_flight)):
            x = S.make_state(8, position_m=p, velocity_m_s=v, body_rate_rad_s=w)[0]
            x[S.QUATERNION] = q
            if index not in both_lost and index not in speeds_silent:
                speeds.publish(joint_state_from_rotor_speeds(omega, stamp_from_ns(stamp)))
            if index not in both_lost:
                odom.publish(odometry_message(x, stamp_from_ns(stamp)))
            time.sleep(0.01)  # about real time, as a vehicle would send them
            if index == 20:
                residuals.wait_for(count=1, timeout=120.0)  # the node is up and processing

        def silent_motor_speeds(message: DiagnosticArray) -> bool:
            return message.status[0].name == "inputs" and message.status[0].level == DiagnosticStatus.WARN

        warned = diagnostics.wait_for(silent_motor_speeds, timeout=30.0)[0].status[0]
        assert warned.message.startswith("silent: motor_speeds for ")
        assert "(odom still coming)" in warned.message
        assert {kv.key: kv.value for kv in warned.values}["silent"] == "motor_speeds"
        node.assert_running()
    rotor_levels = {s.level for m in diagnostics.messages for s in rotor_statuses(m)}
    assert rotor_levels == {DiagnosticStatus.OK}
    log = node.log_text()
    assert log.count("while odom keep coming") == 1  # once per episode
    assert "motor_speeds is back after 2." in log
    assert "gap of 0.3" in log and "rotor fault" not in log
