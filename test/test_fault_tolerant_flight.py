"""Fault-tolerant flight over ROS 2 (issue 15): the identifier's diagnosis reaches the allocation.

Real nodes over DDS, each vehicle in lockstep on the simulator's clock (real_time_factor 0,
publish_clock, a use_sim_time controller), as in test_nodes_sim_control.py, the identifier a lockstep
follower (its ``~/progress``: its verdicts reach the controller at the same simulated time however busy
the machine); times are simulated seconds. The X8 starts hovering at 1 m. The message layout and its
checks are tested without DDS first.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from ros_harness import NodeProcess, RosProbe
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from test_nodes_sim_control import Vehicle, stamp_s, start_vehicle, stop_vehicles

from multirotor_ros.control.fault_tolerance import EffectivenessFilter
from multirotor_ros.nodes.effectiveness_message import effectiveness_from_message, rotor_effectiveness_message
from multirotor_ros.nodes.simulator import parse_faults
from multirotor_ros.refusals import Refusal

HOVER = np.array([0.0, 0.0, 1.0])
SIMULATOR = {"real_time_factor": 0.0, "command_timeout_s": 2.0, "seed": 3, "initial_z": 1.0}

# ------------------------------------------------------------------ the message, without DDS


def test_the_message_round_trips_with_the_agreed_layout() -> None:
    message = rotor_effectiveness_message([1.0, 0.0, 1.0], [0.02, 0.01, 1.0])
    assert [(d.label, d.size, d.stride) for d in message.layout.dim] == [("field", 2, 6), ("rotor", 3, 3)]
    estimate, std = effectiveness_from_message(message, 3)
    np.testing.assert_array_equal(estimate, [1.0, 0.0, 1.0])
    np.testing.assert_array_equal(std, [0.02, 0.01, 1.0])


def _corrupt(change) -> Float64MultiArray:
    message = rotor_effectiveness_message([1.0, 0.5, 1.0], [0.02, 0.02, 0.02])
    change(message)
    return message


@pytest.mark.parametrize(
    ("message", "n_rotors", "reason"),
    [
        (rotor_effectiveness_message([1.0] * 4, [0.1] * 4), 3, "wrong layout"),
        (_corrupt(lambda m: setattr(m.layout.dim[0], "label", "estimate")), 3, "wrong layout"),
        (_corrupt(lambda m: setattr(m.layout, "data_offset", 1)), 3, "wrong layout"),
        (_corrupt(lambda m: setattr(m, "data", [1.0] * 5)), 3, "wrong size"),
        (_corrupt(lambda m: m.data.__setitem__(1, math.nan)), 3, "non-finite value"),
        (_corrupt(lambda m: m.data.__setitem__(1, 1.6)), 3, "effectiveness out of range"),
        (_corrupt(lambda m: m.data.__setitem__(0, -0.1)), 3, "effectiveness out of range"),
        (_corrupt(lambda m: m.data.__setitem__(4, -0.01)), 3, "negative standard deviation"),
    ],
)
def test_a_bad_message_is_refused_with_its_reason(message, n_rotors, reason) -> None:
    refusal = effectiveness_from_message(message, n_rotors)
    assert isinstance(refusal, Refusal) and refusal.reason == reason


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("3", "'3' is not MOTOR:EFFECTIVENESS"),
        ("9:0", "MOTOR in 1..8"),
        ("3:1.5", "EFFECTIVENESS in \\[0, 1\\]"),
        ("3:nan", "'3:nan' is not"),
        ("three:0", "'three:0' is not"),
        ("3:0, 3:0.5", "one fault per motor"),
    ],
)
def test_a_bad_faults_parameter_is_refused_naming_the_entry(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_faults(text, 8)


def test_the_faults_parameter_lists_motor_and_effectiveness() -> None:
    assert parse_faults(" 3:0, 6:0.5 ,", 8) == [(3, 0.0), (6, 0.5)]
    assert parse_faults("", 8) == []


# ------------------------------------------------------------------ over ROS 2


@pytest.fixture
def probe() -> Iterator[RosProbe]:
    probe = RosProbe()
    yield probe
    probe.close()


def hover_error(vehicle: Vehicle, t0: float, t1: float) -> np.ndarray:
    """Distance from the hover point of every odometry in [t0, t1] (simulated seconds)."""
    _, positions = vehicle.between(t0, t1)
    return np.linalg.norm(positions - HOVER, axis=1)


def healthy_and_sure(n_rotors: int) -> Callable[[Float64MultiArray], bool]:
    """Whether a rotor_effectiveness message says every rotor healthy, each with std < 0.1."""

    def check(message: Float64MultiArray) -> bool:
        estimate, std = effectiveness_from_message(message, n_rotors)
        return bool(np.all(estimate == 1.0) and np.all(std < 0.1))

    return check


def publish_diagnosis(probe: RosProbe, namespace: str, estimate: list[float], std: float) -> None:
    """Send a rotor_effectiveness as the identifier would (the controller keeps the latest one)."""
    publisher = probe.publisher(f"{namespace}/rotor_effectiveness", Float64MultiArray)
    probe.wait_for_subscribers(publisher, timeout=120.0)
    publisher.publish(rotor_effectiveness_message(estimate, [std] * len(estimate)))


def one_rotor_at(rotor: int, effectiveness: float, n_rotors: int = 8) -> list[float]:
    """Estimates naming one rotor (1..N) at ``effectiveness``, the others healthy."""
    return [effectiveness if k == rotor else 1.0 for k in range(1, n_rotors + 1)]


def assert_gradual(t_s: np.ndarray, commands: np.ndarray, min_rise_s: float = 0.2) -> None:
    """Check that a rotor's command changed gradually, as a switch of the allocation would not.

    10 % to 90 % of the change in more than ``min_rise_s``, no step above 15 % of it (a switch: all of it
    in one period). Times are the commands' stamps: the probe may miss a command when the loop runs fast.
    """
    change = commands[-1] - commands[0]
    progress = (commands - commands[0]) / change
    rise_s = t_s[np.argmax(progress >= 0.9)] - t_s[np.argmax(progress >= 0.1)]
    largest_step = np.abs(np.diff(commands)).max() / abs(change)
    assert rise_s > min_rise_s and largest_step < 0.15, (rise_s, largest_step)


@pytest.mark.ros
def test_rotor_3_stopped_is_named_reallocated_and_the_x8_is_back_near_its_no_fault_error_within_3_s(
    probe: RosProbe, tmp_path: Path
) -> None:
    diagnostics = probe.subscribe("/ft1/diagnostics", DiagnosticArray)
    effectiveness = probe.subscribe("/ft1/rotor_effectiveness", Float64MultiArray)
    vehicle = start_vehicle(probe, tmp_path, "/ft1", SIMULATOR, {}, sim_time=True)
    try:
        with NodeProcess("identifier", tmp_path / "identifier.log", namespace="/ft1") as identifier:

            def settled(message: DiagnosticArray) -> bool:
                return len(message.status) == 8 and all("no verdict" not in s.message for s in message.status)

            diagnostics.wait_for(settled, timeout=120.0)

            # Before the observer has converged nothing is known (std 1), then every rotor is healthy.
            first_estimate, first_std = effectiveness_from_message(effectiveness.wait_for()[0], 8)
            assert np.all(first_estimate == 1.0) and np.all(first_std == 1.0)
            effectiveness.wait_for(healthy_and_sure(8), timeout=30.0)
            before = stamp_s(vehicle.latest())
            no_fault_level = hover_error(vehicle, before, before + 2.0).max()
            (result,) = probe.set_parameters("/ft1/simulator", {"fault_motor": 3}).values()
            assert result.successful

            def rotor_3_error(message: DiagnosticArray) -> bool:
                return any(s.name == "rotor_3" and s.level == DiagnosticStatus.ERROR for s in message.status)

            named = diagnostics.wait_for(rotor_3_error, timeout=60.0)[-1]
            assert all(s.level == DiagnosticStatus.OK for s in named.status if s.name != "rotor_3")
            faulty = next(s for s in named.status if s.name == "rotor_3")
            detected = float(next(kv.value for kv in faulty.values if kv.key == "detected_at_s"))

            def rotor_3_stopped(message: Float64MultiArray) -> bool:
                estimate, std = effectiveness_from_message(message, 8)
                return bool(estimate[2] < 0.1 and std[2] < 0.1 and np.all(np.delete(estimate, 2) == 1.0))

            effectiveness.wait_for(rotor_3_stopped, timeout=30.0)
            recovered = hover_error(vehicle, detected + 3.0, detected + 5.0)
            identifier.assert_running()
        assert recovered.max() < no_fault_level + 0.15, (no_fault_level, recovered.max())
        assert "reallocating around rotor 3" in vehicle.controller.log_text()
    finally:
        stop_vehicles(vehicle)


@pytest.mark.ros
def test_the_hexarotor_with_a_rotor_stopped_holds_its_hover_and_says_it_gives_up_yaw(
    probe: RosProbe, tmp_path: Path
) -> None:
    hexarotor = {"airframe": "hexarotor_f550"}
    diagnostics = probe.subscribe("/ft4/diagnostics", DiagnosticArray)
    effectiveness = probe.subscribe("/ft4/rotor_effectiveness", Float64MultiArray)
    vehicle = start_vehicle(probe, tmp_path, "/ft4", {**SIMULATOR, **hexarotor}, hexarotor, sim_time=True)
    try:
        with NodeProcess(
            "identifier", tmp_path / "identifier.log", namespace="/ft4", parameters=hexarotor
        ) as identifier:
            effectiveness.wait_for(healthy_and_sure(6), timeout=120.0)
            # The fast stopped-rotor test learns the residual's noise over the identifier's first seconds
            # (a fault before that takes the observer's slower path): hover 3 s more first.
            settled_at = stamp_s(vehicle.latest())
            assert hover_error(vehicle, settled_at, settled_at + 3.0).max() < 0.01
            (result,) = probe.set_parameters("/ft4/simulator", {"fault_motor": 1}).values()
            assert result.successful

            def rotor_1_error(message: DiagnosticArray) -> bool:
                return any(s.name == "rotor_1" and s.level == DiagnosticStatus.ERROR for s in message.status)

            named = diagnostics.wait_for(rotor_1_error, timeout=60.0)[-1]
            faulty = next(s for s in named.status if s.name == "rotor_1")
            detected = float(next(kv.value for kv in faulty.values if kv.key == "detected_at_s"))

            def rotor_1_stopped(message: Float64MultiArray) -> bool:
                estimate, std = effectiveness_from_message(message, 6)
                return bool(estimate[0] < 0.1 and std[0] < 0.1 and np.all(estimate[1:] == 1.0))

            effectiveness.wait_for(rotor_1_stopped, timeout=30.0)
            # From the fault on (the injection comes at most a detection delay before the verdict).
            error = hover_error(vehicle, detected - 0.5, detected + 6.0)
            identifier.assert_running()
        assert error.max() < 0.5, error.max()
        log = vehicle.controller.log_text()
        assert "reallocating around rotor 1" in log and "yaw authority given up" in log
    finally:
        stop_vehicles(vehicle)


@pytest.mark.ros
def test_the_x8_losing_rotor_3_and_then_rotor_6_holds_its_hover(probe: RosProbe, tmp_path: Path) -> None:
    """Two rotors of different coaxial pairs stop 2 s apart (the simulator's ``faults``).

    Both are named stopped and left out of the allocation, and the hover holds within 0.5 m.
    """
    effectiveness = probe.subscribe("/ft5/rotor_effectiveness", Float64MultiArray, qos=100)
    vehicle = start_vehicle(probe, tmp_path, "/ft5", SIMULATOR, {}, sim_time=True)
    try:
        with NodeProcess("identifier", tmp_path / "identifier.log", namespace="/ft5") as identifier:

            def stopped(rotors: list[int]) -> Callable[[Float64MultiArray], bool]:
                def check(message: Float64MultiArray) -> bool:
                    estimate, std = effectiveness_from_message(message, 8)
                    named = [k for k in range(8) if estimate[k] < 0.1 and std[k] < 0.1]
                    return named == [r - 1 for r in rotors]

                return check

            effectiveness.wait_for(healthy_and_sure(8), timeout=120.0)
            settled_at = stamp_s(vehicle.latest())
            assert hover_error(vehicle, settled_at, settled_at + 3.0).max() < 0.02
            (refused,) = probe.set_parameters("/ft5/simulator", {"faults": "3:0, 9:0"}).values()
            assert not refused.successful and "'9:0' is not MOTOR:EFFECTIVENESS" in refused.reason
            first_at = stamp_s(vehicle.latest())
            (result,) = probe.set_parameters("/ft5/simulator", {"faults": "3:0"}).values()
            assert result.successful
            effectiveness.wait_for(stopped([3]), timeout=60.0)
            second_at = stamp_s(vehicle.latest())
            vehicle.until(second_at + 2.0)
            (result,) = probe.set_parameters("/ft5/simulator", {"faults": "3:0, 6:0"}).values()
            assert result.successful
            effectiveness.wait_for(stopped([3, 6]), timeout=60.0)
            named_at = stamp_s(vehicle.latest())
            error = hover_error(vehicle, first_at, named_at + 6.0)
            identifier.assert_running()
        assert error.max() < 0.5, error.max()
        simulator_log = vehicle.simulator.log_text()
        assert "rotor 3 effectiveness 0, rotor 6 effectiveness 0" in simulator_log, simulator_log
    finally:
        stop_vehicles(vehicle)


@pytest.mark.ros
def test_a_healthy_rotor_wrongly_reported_at_half_thrust_does_not_destabilise_the_x8(
    probe: RosProbe, tmp_path: Path
) -> None:
    vehicle = start_vehicle(probe, tmp_path, "/ft2", SIMULATOR, {}, sim_time=True)
    try:
        start = stamp_s(vehicle.latest())
        publish_diagnosis(probe, "/ft2", one_rotor_at(3, 0.5), std=0.01)
        # The position loop has no integral in x and y: the wrong torque it now fights leaves a steady offset.
        error = hover_error(vehicle, start, start + 8.0)
        assert error.max() < 0.5, error.max()
        # It was used: a healthy rotor at 0.5 is above the filter's floor.
        assert "reallocating around rotor 3" in vehicle.controller.log_text()
    finally:
        stop_vehicles(vehicle)


@pytest.mark.ros
def test_with_the_parameter_off_a_diagnosis_changes_nothing_and_reallocation_comes_and_goes_smoothly(
    probe: RosProbe, tmp_path: Path
) -> None:
    commands = probe.subscribe("/ft3/motor_speed_cmd", JointState, qos=1000)
    vehicle = start_vehicle(
        probe, tmp_path, "/ft3", SIMULATOR, {"fault_tolerant_allocation": False}, sim_time=True
    )
    try:
        # The probe's subscription must be matched before the windows below: in lockstep the loop runs
        # seconds of simulated time in a second, and a window flown before discovery would be empty.
        commands.wait_for(timeout=120.0)
        start = stamp_s(vehicle.latest())
        publish_diagnosis(probe, "/ft3", one_rotor_at(3, 0.0), std=0.01)

        def rotor_3(t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
            """Stamps and rotor 3's commanded speeds in [t0, t1] (simulated seconds)."""
            vehicle.until(t1)
            window = [m for m in commands.messages if t0 <= stamp_s(m) <= t1]
            return np.array([stamp_s(m) for m in window]), np.array([m.velocity[2] for m in window])

        # Off: the nominal allocation, as flown without any diagnosis.
        assert hover_error(vehicle, start + 1.0, start + 3.0).max() < 0.02
        _, nominal = rotor_3(start + 1.0, start + 3.0)
        assert "reallocating" not in vehicle.controller.log_text()
        # On: rotor 3 is left out, gradually (the filter's time constant for a stopped rotor, 0.05 s), and
        # the X8 flies on 7.
        # Each window starts before its change: in lockstep simulated time runs on while the change
        # travels, and a window opened after it would miss the start of the transition.
        switched = stamp_s(vehicle.latest())
        (result,) = probe.set_parameters("/ft3/controller", {"fault_tolerant_allocation": True}).values()
        assert result.successful
        t_s, reallocated = rotor_3(switched, switched + 3.0)
        assert reallocated[-1] < 0.5 * nominal.mean()
        assert_gradual(t_s, reallocated, min_rise_s=EffectivenessFilter.DEFAULT_STOP_TIME_CONSTANT_S)
        assert hover_error(vehicle, switched, switched + 3.0).max() < 0.15
        # A message for a quadrotor is refused (counted, logged once) and leaves the diagnosis in force...
        publish_diagnosis(probe, "/ft3", [1.0] * 4, std=0.01)
        # ...then the diagnosis clears: back to the nominal allocation, again without a jump.
        cleared = stamp_s(vehicle.latest())
        publish_diagnosis(probe, "/ft3", [1.0] * 8, std=0.01)
        t_s, restored = rotor_3(cleared, cleared + 3.0)
        assert restored[-1] == pytest.approx(nominal.mean(), rel=0.05)
        assert_gradual(t_s, restored)
        log = vehicle.controller.log_text()
        assert log.count("refused rotor_effectiveness: wrong layout") == 1
        assert log.count("reallocating around rotor 3") == 1
        assert log.count("fault-tolerant allocation ends") == 1
    finally:
        stop_vehicles(vehicle)
