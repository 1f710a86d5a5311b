"""Fault diagnosis on simulated closed-loop flights with sensor noise: the issue's requirements, scaled down.

The full campaign (>= 100 faults per airframe, 10 minutes of nominal flight) is bench/bench_diagnosis.py;
these run the same code and thresholds on fewer flights.
"""

from __future__ import annotations

import math

import pytest

from multirotor_ros.diagnosis.campaign import nominal_check, required_delay_s, run_campaign

pytestmark = pytest.mark.slow


def test_every_x8_rotor_stopped_and_at_half_thrust_is_detected_in_time_and_isolated():
    result = run_campaign("x8_octorotor", 16, seed=11, processes=2)
    summary = result.summary()
    assert [o.case.effectiveness for o in result.outcomes] == [0.0] * 8 + [0.5] * 8
    late = [o for o in result.outcomes if not o.in_time]
    assert not late, result.table()
    assert summary["isolation_rate"] >= 0.95, result.table()
    assert summary["false_alarms_before_onset"] == 0, result.table()
    for outcome in result.outcomes:
        assert outcome.delay_s <= required_delay_s(outcome.case.effectiveness)
        assert abs(outcome.final_effectiveness - outcome.case.effectiveness) < 0.1


def test_hexarotor_faults_of_random_size_are_detected_and_isolated():
    result = run_campaign("hexarotor_f550", 18, seed=12, processes=2)
    summary = result.summary()
    assert summary["in_time"] == 18, result.table()
    assert summary["isolation_rate"] >= 0.95, result.table()
    assert summary["false_alarms_before_onset"] == 0, result.table()


def test_a_minute_of_nominal_flight_raises_no_alarm():
    result = nominal_check("x8_octorotor", 15.0, flights=4, seed=13, processes=2)
    assert result.false_alarms == 0, result.describe()
    assert math.isnan(result.first_false_alarm_s)
    # Margin: the loss estimates stay well below the alarm threshold.
    assert result.max_loss_ratio < 0.8, result.describe()
