"""Fault-tolerant flight (issue 15) offline: the diagnosis in the loop feeds the allocation.

A few cases of the campaign in bench/bench_fault_tolerance.py (multirotor_ros.diagnosis.recovery), each
flown without fault and with the fault, reallocation off and on, on a trajectory of random waypoints;
and hover cases. The X8 with two rotors of different coaxial pairs stopped is not here: the simulator
flies one hidden fault (``actuator_fault``) per flight.
"""

from __future__ import annotations

import math

import pytest

from multirotor_ros.diagnosis.campaign import FaultCase
from multirotor_ros.diagnosis.recovery import (
    HOVER_HOLD_M,
    HoverCase,
    fly_case_three_times,
    fly_hover,
    recovery_case,
)
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.simulation.flight import ReportedFault

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
