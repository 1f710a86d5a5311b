"""The state in NED/FRD, message schedules and SET_MESSAGE_INTERVAL answers, on a clock the test controls."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.messages import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_UNSUPPORTED,
    REQUEST_RATE_BOUNDS_HZ,
    MessageSchedule,
    heading_cdeg,
    ned_view,
    time_usec,
    wire_value,
)
from multirotor_ros.mavlink.vehicle import VehicleState

GPS = 113
HEARTBEAT = 0


def due_times(
    schedule: MessageSchedule, message_id: int, until_s: float, tick_s: float = 0.001
) -> list[float]:
    return [k * tick_s for k in range(round(until_s / tick_s)) if schedule.due(message_id, k * tick_s)]


def test_due_keeps_the_phase_and_the_rate():
    schedule = MessageSchedule({GPS: 10.0})
    times = due_times(schedule, GPS, 1.0)
    assert len(times) == 10 and times[0] == 0.0
    assert all(math.isclose(b - a, 0.1, abs_tol=1.5e-3) for a, b in zip(times, times[1:], strict=False))


def test_after_a_gap_the_schedule_restarts_from_now_instead_of_bursting():
    schedule = MessageSchedule({GPS: 10.0})
    assert schedule.due(GPS, 0.0)
    assert schedule.due(GPS, 5.0)  # long gap: one message, not fifty
    assert not schedule.due(GPS, 5.05)
    assert schedule.due(GPS, 5.1)


def test_set_message_interval_answers():
    schedule = MessageSchedule({GPS: 10.0}, {GPS: (5.0, 10.0)})
    assert schedule.request(GPS, 200_000).result == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 5.0
    assert schedule.request(GPS, 50_000).result == MAV_RESULT_DENIED  # 20 Hz: outside what is allowed
    assert schedule.request(GPS, -1).result == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 0.0
    assert not schedule.due(GPS, 100.0)  # stopped
    assert schedule.request(GPS, 0).result == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 10.0  # default
    assert schedule.request(30, 10_000).result == MAV_RESULT_UNSUPPORTED
    assert schedule.request(float("nan"), 10_000).result == MAV_RESULT_DENIED
    assert schedule.request(GPS + 0.5, 10_000).result == MAV_RESULT_DENIED
    assert schedule.request(GPS, float("inf")).result == MAV_RESULT_DENIED


@pytest.mark.parametrize("interval_us", [1, 19_999, 20_000_001, 1e300, -2, float("nan"), float("-inf")])
def test_requested_rates_outside_the_bounds_are_denied_and_say_which_parameter(interval_us):
    # HEARTBEAT at 1 us went out 3,187 times a second before: at most 50 Hz, at least every 20 s.
    schedule = MessageSchedule({HEARTBEAT: 1.0})
    answer = schedule.request(HEARTBEAT, interval_us)
    assert answer.result == MAV_RESULT_DENIED and answer.refused_param == 2
    assert "50 Hz" in answer.detail and schedule.rate_hz(HEARTBEAT) == 1.0


def test_requested_rates_within_the_bounds_are_taken():
    low_hz, high_hz = REQUEST_RATE_BOUNDS_HZ
    schedule = MessageSchedule({HEARTBEAT: 1.0})
    assert schedule.request(HEARTBEAT, 1e6 / high_hz).result == MAV_RESULT_ACCEPTED
    assert schedule.rate_hz(HEARTBEAT) == pytest.approx(high_hz)
    assert schedule.request(HEARTBEAT, 1e6 / low_hz).result == MAV_RESULT_ACCEPTED
    assert schedule.rate_hz(HEARTBEAT) == pytest.approx(low_hz)


def test_wire_units():
    assert heading_cdeg(-math.pi / 2) == 27000 and heading_cdeg(2 * math.pi) == 0
    assert time_usec(0.0) == 1 and time_usec(1.25) == 1_250_000
    assert heading_cdeg(math.nan) == 65535 and time_usec(math.inf) == 2**64 - 1  # unknown; the largest


@pytest.mark.parametrize(
    ("value", "wire_type", "expected"),
    [
        (1e308, "int16_t", 32767),
        (-1e308, "int32_t", -(2**31)),
        (math.nan, "int32_t", 0),
        (math.inf, "uint16_t", 65535),
        (-5, "uint8_t", 0),
        (2.6, "int16_t", 3),
        (1e39, "float", 3.4028234663852886e38),
        (-math.inf, "float", -3.4028234663852886e38),
        (1e308, "double", 1e308),
    ],
)
def test_wire_value_fits_every_field_type(value, wire_type, expected):
    assert wire_value(value, wire_type) == expected


def vectors(size: int, finite: bool = True):
    return st.lists(
        # Not finite: NaN and infinities among values that do not overflow on their own (a value near the
        # float's maximum overflows in one of two equivalent sums and not in the other).
        st.floats(-1e6, 1e6)
        if finite
        else st.one_of(st.floats(-1e300, 1e300), st.sampled_from([np.nan, np.inf, -np.inf])),
        min_size=size,
        max_size=size,
    ).map(np.array)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on infinities (inf * 0 in a product): expected
@settings(max_examples=60)
@given(st.data())
def test_ned_view_is_frames_py_applied_to_each_vector(data):
    finite = data.draw(st.booleans())
    q = (
        data.draw(vectors(4).filter(lambda q: np.linalg.norm(q) > 1e-3))
        if finite
        else data.draw(vectors(4, False))
    )
    state = VehicleState(
        1.5, data.draw(vectors(3, finite)), data.draw(vectors(3)), q / np.linalg.norm(q) if finite else q,
        data.draw(vectors(3)), np.zeros(4), data.draw(vectors(3)), data.draw(vectors(3)),
    )  # fmt: skip
    view = ned_view(state)
    np.testing.assert_allclose(view.p_NED_m, enu_to_ned(state.p_WB_W), rtol=1e-15, atol=1e-9)
    np.testing.assert_allclose(view.v_NED_m_s, enu_to_ned(state.v_WB_W), rtol=1e-15, atol=1e-9)
    # One product instead of a sum then a product: the last bit may differ.
    np.testing.assert_allclose(view.q_NED_FRD, quat_enu_flu_to_ned_frd(state.q_WB), rtol=1e-14, atol=1e-12)
    for ours, theirs in [
        (view.w_FRD_rad_s, state.w_WB_B),
        (view.imu_accel_FRD_m_s2, state.imu_specific_force_B),
        (view.imu_gyro_FRD_rad_s, state.imu_w_WB_B),
    ]:
        np.testing.assert_allclose(ours, flu_to_frd(theirs), rtol=1e-15, atol=1e-9)
