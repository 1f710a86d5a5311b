"""Fault-tolerant flight (issue 15) offline: the diagnosis in the loop feeds the allocation.

A few cases of the campaign in bench/bench_fault_tolerance.py (multirotor_ros.diagnosis.recovery), each
flown without fault and with the fault, reallocation off and on, on a trajectory of random waypoints;
and hover cases, among them the X8 losing two rotors of different coaxial pairs one after the other.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from multirotor_ros.diagnosis.campaign import HOVER_HEIGHT_M, FaultCase
from multirotor_ros.diagnosis.recovery import (
    HOVER_HOLD_M,
    HoverCase,
    fault_effects,
    fly_case_three_times,
    fly_hover,
    recovery_case,
)
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.simulation.flight import ReportedFault
from multirotor_ros.simulation.vehicle import NS_PER_S, VehicleSimulator

pytestmark = pytest.mark.slow

DURATION_S = 8.0


@pytest.mark.parametrize(
    "case",
    [FaultCase(3, 0.0, 3.0, 7), FaultCase(6, 0.3, 3.0, 9)],
    ids=["rotor-3-stopped", "rotor-6-at-30-percent"],
)
def test_x8_recovers_from_a_rotor_fault_on_a_trajectory(case: FaultCase) -> None:
    outcome = fly_case_three_times((load_airframe("x8_octorotor"), case, DURATION_S))
    assert outcome.on.detected_motor == case.motor
    assert outcome.on.meets_issue, outcome
    # Without reallocation the same fault does not meet the numbers: the campaign compares something.
    assert not outcome.off.meets_issue, outcome


def test_hexarotor_with_a_rotor_stopped_holds_its_hover() -> None:
    outcome = fly_hover(HoverCase("hexarotor_f550", (1,), duration_s=DURATION_S))
    assert outcome.detected_motor == 1
    assert outcome.holds, outcome.describe()


def test_x8_with_a_rotor_stopped_holds_its_hover_only_with_reallocation() -> None:
    on = fly_hover(HoverCase("x8_octorotor", (3,), duration_s=DURATION_S))
    off = fly_hover(HoverCase("x8_octorotor", (3,), duration_s=DURATION_S, reallocation=False))
    assert on.holds, on.describe()
    assert not off.holds, off.describe()


def test_the_simulator_stops_each_of_two_rotors_at_its_own_onset() -> None:
    # Constant commands, no noise: the vertical acceleration drops by one rotor's share of the thrust at
    # each onset (the start speed holds the vehicle with one rotor lost: simulator's hover speed), over
    # stretches too short for the torques left to tilt it much.
    airframe = load_airframe("x8_octorotor")
    effects = fault_effects(airframe, [(6, 0.0, 0.2), (3, 0.0, 0.1)])
    sim = VehicleSimulator(
        airframe, effects, rng=np.random.default_rng(0), noise=False, initial_position_m=(0, 0, 2)
    )

    def vertical_acceleration(start_s: float, end_s: float) -> float:
        sim.run_until(round(start_s * NS_PER_S))
        v_start = sim.state[S.VELOCITY][2]
        sim.run_until(round(end_s * NS_PER_S))
        return float((sim.state[S.VELOCITY][2] - v_start) / (end_s - start_s))

    accelerations = [vertical_acceleration(t, t + 0.04) for t in (0.05, 0.15, 0.25)]
    one_rotor = sim.model.gravity_m_s2 / 7  # hover thrust shared by seven rotors
    assert np.diff(accelerations) == pytest.approx([-one_rotor, -one_rotor], rel=0.15)
    assert sim.injected_effectiveness().tolist() == [1, 1, 0, 1, 1, 0, 1, 1]


def test_faults_injected_one_after_another_keep_their_onsets() -> None:
    # As the simulator node's ``faults`` parameter sets them: the first alone, later both.
    airframe = load_airframe("x8_octorotor")
    sim = VehicleSimulator(airframe, rng=np.random.default_rng(0), noise=False, initial_position_m=(0, 0, 2))
    sim.run_until(round(0.1 * NS_PER_S))
    sim.inject_faults([(3, 0.0)])
    sim.run_until(round(0.3 * NS_PER_S))
    sim.inject_faults([(3, 0.0), (6, 0.5)])
    onsets = {int(f["motor"]): float(f["t_fault_s"]) for f in sim._faults[0]}
    assert onsets == pytest.approx({3: 0.1, 6: 0.3})
    assert sim.injected_effectiveness().tolist() == [1, 1, 0, 1, 1, 0.5, 1, 1]
    sim.inject_faults([(6, 0.5)])  # rotor 3 repaired, rotor 6 as it was
    assert float(sim._faults[0][0]["t_fault_s"]) == pytest.approx(0.3)
    with pytest.raises(ValueError, match="one fault per motor"):
        sim.inject_faults([(6, 0.5), (6, 0.0)])
    with pytest.raises(ValueError, match="fault motor must be 1..8"):
        sim.inject_faults([(9, 0.0)])


def test_x8_with_two_rotors_of_different_pairs_stopped_holds_its_hover() -> None:
    # Rotor 3 (pair 2) stops at 3 s, rotor 6 (pair 3) at 5 s: the second stop is kept beside the alarm.
    case = HoverCase("x8_octorotor", (3, 6), duration_s=DURATION_S, stop_interval_s=2.0)
    outcome = fly_hover(case)
    assert outcome.named_faulty == (3, 6), outcome.describe()
    assert outcome.effectiveness[[2, 5]] == pytest.approx([0.0, 0.0], abs=1e-3)
    healthy = np.delete(outcome.effectiveness, [2, 5])
    assert healthy == pytest.approx(np.ones(6), abs=0.05)
    assert outcome.holds, outcome.describe()
    assert outcome.min_height_m > HOVER_HEIGHT_M - HOVER_HOLD_M, outcome.describe()
    off = fly_hover(dataclasses.replace(case, reallocation=False))
    assert not off.holds, off.describe()


@pytest.mark.parametrize("airframe", ["x8_octorotor", "hexarotor_f550"])
def test_a_healthy_rotor_wrongly_reported_at_half_thrust_does_not_destabilise(airframe: str) -> None:
    case = HoverCase(airframe, (), duration_s=DURATION_S, reported=ReportedFault(1, 0.5, 3.0))
    outcome = fly_hover(case)
    assert math.isnan(outcome.detection_t_s)  # the diagnoser itself saw nothing
    assert outcome.effectiveness[0] == pytest.approx(0.5, abs=0.01)  # the filter's floor
    assert outcome.holds, outcome.describe()
    assert outcome.final_error_m < HOVER_HOLD_M


def test_a_case_is_a_pure_function_of_its_seed() -> None:
    assert recovery_case(8, 42) == recovery_case(8, 42)
    cases = {recovery_case(8, seed) for seed in range(40)}
    assert len(cases) == 40
    assert {case.effectiveness == 0.0 for case in cases} == {True, False}
    assert all(0.3 <= case.effectiveness <= 0.8 for case in cases if case.effectiveness)
