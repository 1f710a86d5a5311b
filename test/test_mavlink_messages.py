"""Message schedules and SET_MESSAGE_INTERVAL answers, on a clock the test controls."""

from __future__ import annotations

import math

from multirotor_ros.mavlink.messages import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_UNSUPPORTED,
    MessageSchedule,
    heading_cdeg,
    time_usec,
)

GPS = 113


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
    assert schedule.request(GPS, 200_000) == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 5.0
    assert schedule.request(GPS, 50_000) == MAV_RESULT_DENIED  # 20 Hz: outside what is allowed
    assert schedule.request(GPS, -1) == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 0.0
    assert not schedule.due(GPS, 100.0)  # stopped
    assert schedule.request(GPS, 0) == MAV_RESULT_ACCEPTED and schedule.rate_hz(GPS) == 10.0  # default
    assert schedule.request(30, 10_000) == MAV_RESULT_UNSUPPORTED
    assert schedule.request(float("nan"), 10_000) == MAV_RESULT_DENIED
    assert schedule.request(GPS + 0.5, 10_000) == MAV_RESULT_DENIED
    assert schedule.request(GPS, float("inf")) == MAV_RESULT_DENIED


def test_wire_units():
    assert heading_cdeg(-math.pi / 2) == 27000 and heading_cdeg(2 * math.pi) == 0
    assert time_usec(0.0) == 1 and time_usec(1.25) == 1_250_000
