"""Plausibility checks: limits, stamps and jumps, with hypothesis over hostile values."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from multirotor_ros.plausibility import NS_PER_S, StampGate, StateLimits, format_vector, jump_refusal

LIMITS = StateLimits()
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)


def test_a_hard_manoeuvre_is_plausible() -> None:
    assert (
        LIMITS.check(p_WB_W=(120.0, -40.0, 35.0), v_WB_W=(30.0, 5.0, -8.0), w_WB_B=(10.0, -12.0, 6.0)) is None
    )


@given(st.lists(ANY_FLOAT, min_size=3, max_size=3), st.sampled_from(["p_WB_W", "v_WB_W", "w_WB_B", "a_WB_W"]))
def test_every_value_is_either_plausible_or_refused_with_a_reason(values: list[float], field: str) -> None:
    refusal = LIMITS.check(**{field: values})
    finite = all(math.isfinite(v) for v in values)
    limit = {
        "p_WB_W": LIMITS.position_m,
        "v_WB_W": LIMITS.speed_m_s,
        "w_WB_B": LIMITS.body_rate_rad_s,
        "a_WB_W": LIMITS.acceleration_m_s2,
    }[field]
    plausible = finite and float(np.linalg.norm(values)) <= limit
    assert (refusal is None) == plausible
    if refusal is not None:
        assert refusal.reason and "np." not in refusal.detail and "array(" not in refusal.detail


def test_messages_carry_no_numpy_repr() -> None:
    assert format_vector(np.array([1.0, np.float64(2.5), np.nan])) == "(1, 2.5, nan)"


def test_a_future_stamp_is_refused_alone_and_never_remembered() -> None:
    gate = StampGate(future_tolerance_s=0.5)
    now = 100 * NS_PER_S
    assert gate.check(now - 1000, now) is None
    refusal = gate.check(now + 3600 * NS_PER_S, now)
    assert refusal is not None and refusal.reason == "stamp in the future"
    # The next valid message is accepted: the future stamp was not kept as the newest.
    assert gate.check(now + 1000, now + 2000) is None


def test_out_of_order_stamps_and_a_restarted_clock() -> None:
    gate = StampGate(future_tolerance_s=0.5, reordering_tolerance_s=0.01)
    assert gate.check(10 * NS_PER_S, 10 * NS_PER_S) is None
    assert gate.check(10 * NS_PER_S - 5_000_000, 10 * NS_PER_S) is None  # 5 ms late: transports reorder
    late = gate.check(9 * NS_PER_S, 10 * NS_PER_S)
    assert late is not None and late.reason == "stamp out of order"
    # Simulated time restarted at 0: the gate follows the clock back instead of refusing forever.
    assert gate.check(0, 0) is None


@given(st.integers(-(2**63), 2**63 - 1), st.integers(0, 2**62))
def test_the_gate_never_refuses_a_stamp_equal_to_its_clock(stamp_offset: int, now: int) -> None:
    gate = StampGate()
    gate.check(min(stamp_offset, now), now)
    assert gate.check(now, now) is None


def test_position_jumps() -> None:
    assert jump_refusal((0, 0, 1), (0.5, 0, 1), 0.01, LIMITS) is None
    refusal = jump_refusal((0, 0, 1), (1e200, 0, 1), 0.01, LIMITS)
    assert refusal is not None and refusal.reason == "implausible position jump"
    assert jump_refusal((0, 0, 1), (math.nan, 0, 1), 0.01, LIMITS) is not None
