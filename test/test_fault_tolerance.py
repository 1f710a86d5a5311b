"""Fault-tolerant flight (issue 15): allocation through B diag(e), the filter, closed-loop flights.

Dead rotors are left out and yaw is given up where it must be; the effectiveness filter stands between
the identifier and the allocator; the closed-loop flights have rotors stopped.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from multirotor_ros.control.allocation import (
    DEAD_ROTOR_EFFECTIVENESS,
    FADE_BAND,
    MAX_EFFECTIVENESS,
    Allocator,
)
from multirotor_ros.control.fault_tolerance import (
    CONFIDENT_STD,
    RECOVERED_EFFECTIVENESS,
    EffectivenessFilter,
)
from multirotor_ros.control.gains import airframe_gains
from multirotor_ros.control.law import SaturationController
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import GRAVITY_M_S2, load_airframe
from multirotor_ros.model.rotation import FloatArray, quat_to_euler
from multirotor_ros.resources import available_airframes
from multirotor_ros.simulation.vehicle import VehicleSimulator, period_ns

AIRFRAMES = available_airframes()


@pytest.fixture(scope="module", params=AIRFRAMES)
def allocator(request) -> Allocator:
    return Allocator.for_airframe(load_airframe(request.param))


def _delivered(allocator: Allocator, omega: FloatArray, effectiveness: FloatArray) -> FloatArray:
    """(thrust, tau_x, tau_y, tau_z) the rotors really give: B diag(e) omega^2."""
    return (allocator.matrix * effectiveness) @ omega**2


def _hover(name: str) -> tuple[Allocator, float]:
    airframe = load_airframe(name)
    return Allocator.for_airframe(airframe), airframe.mass_kg * GRAVITY_M_S2


def _without(n_rotors: int, *stopped: int) -> FloatArray:
    """Effectiveness with the rotors numbered ``stopped`` (1..N) at 0."""
    effectiveness = np.ones(n_rotors)
    effectiveness[[rotor - 1 for rotor in stopped]] = 0.0
    return effectiveness


# ------------------------------------------------------------------ allocation through B diag(e)


@settings(max_examples=30, deadline=None)
@given(thrust_share=st.floats(0.0, 1.0), tau=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3))
def test_all_rotors_healthy_is_the_nominal_allocation(allocator: Allocator, thrust_share: float, tau) -> None:
    thrust = thrust_share * allocator.max_thrust_N
    nominal = allocator.allocate(thrust, tau)
    healthy = allocator.allocate(thrust, tau, np.ones(allocator.n_rotors))
    np.testing.assert_array_equal(healthy.omega_rad_s, nominal.omega_rad_s)
    assert healthy.yaw_fraction == nominal.yaw_fraction


# A rotor is stopped (0), at or below the dead threshold, or anywhere in the accepted range.
_rotor_effectiveness = st.one_of(
    st.just(0.0),
    st.floats(0.0, DEAD_ROTOR_EFFECTIVENESS),
    st.floats(DEAD_ROTOR_EFFECTIVENESS, MAX_EFFECTIVENESS),
)
# Rotors allocated in full, i.e. above the band over which a rotor fades out.
_full_effectiveness = st.floats(DEAD_ROTOR_EFFECTIVENESS + FADE_BAND, MAX_EFFECTIVENESS)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(data=st.data())
def test_a_feasible_wrench_is_delivered_exactly_through_b_diag_e(allocator: Allocator, data) -> None:
    n = allocator.n_rotors
    effectiveness = np.array(data.draw(st.lists(_full_effectiveness, min_size=n, max_size=n)))
    effectiveness[list(data.draw(st.sets(st.integers(0, n - 1), max_size=n - 4)))] = 0.0
    alive = effectiveness > DEAD_ROTOR_EFFECTIVENESS
    top = math.sqrt(allocator.high)
    speeds = np.array(data.draw(st.lists(st.floats(0.3 * top, 0.7 * top), min_size=n, max_size=n)))
    matrix = allocator.matrix[:, alive] * effectiveness[alive]
    wrench = matrix @ speeds[alive] ** 2
    # Feasible in the sense the module docstring promises: all four axes controllable, the least-squares
    # speeds fit the limits with and without the yaw step, and the collective lifts every rotor allocated.
    assume(np.linalg.matrix_rank(matrix) == 4)
    full = np.linalg.pinv(matrix)
    yaw_free = bool(np.all(full[:, 0] > 1e-6 * full[:, 0].max()))  # as Allocator._plan decides
    without_yaw = full @ np.append(wrench[:3], 0.0) if yaw_free else np.linalg.pinv(matrix[:3]) @ wrench[:3]
    assume(yaw_free or np.all(np.linalg.pinv(matrix[:3])[:, 0] > 0))
    for partial in (full @ wrench, without_yaw):
        assume(np.all((partial >= allocator.low) & (partial <= allocator.high)))
    result = allocator.allocate(wrench[0], wrench[1:], effectiveness)
    # The solve's rounding scales with the largest component (the thrust, a few N): a torque of a few mN m
    # was seen 1.4e-9 off, below 1e-9 of the thrust.
    np.testing.assert_allclose(
        _delivered(allocator, result.omega_rad_s, effectiveness),
        wrench,
        rtol=1e-7,
        atol=1e-9 * max(1.0, float(np.max(np.abs(wrench)))),
    )
    assert not result.saturated
    np.testing.assert_array_equal(result.omega_rad_s[~alive], math.sqrt(allocator.low))


@settings(max_examples=80, deadline=None)
@given(
    data=st.data(),
    thrust=st.floats(-100.0, 200.0),
    tau=st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3),
)
def test_dead_rotors_get_the_minimum_speed_and_the_rest_stays_in_range(
    allocator: Allocator, data, thrust: float, tau: list[float]
) -> None:
    n = allocator.n_rotors
    effectiveness = np.array(data.draw(st.lists(_rotor_effectiveness, min_size=n, max_size=n)))
    result = allocator.allocate(thrust, tau, effectiveness)
    omega = result.omega_rad_s
    assert np.all(np.isfinite(omega))
    np.testing.assert_array_equal(omega[effectiveness <= DEAD_ROTOR_EFFECTIVENESS], math.sqrt(allocator.low))
    assert np.all((omega >= math.sqrt(allocator.low) - 1e-9) & (omega <= math.sqrt(allocator.high) + 1e-9))
    assert 0.0 <= result.roll_pitch_fraction <= 1.0 and 0.0 <= result.yaw_fraction <= 1.0
    alive = effectiveness > DEAD_ROTOR_EFFECTIVENESS
    controllable = np.linalg.matrix_rank(allocator.matrix[:, alive] * effectiveness[alive]) == 4
    if controllable and not result.saturated and result.thrust_N == thrust:
        # Whatever the allocation says it delivered in full, the rotors really deliver.
        np.testing.assert_allclose(
            _delivered(allocator, omega, effectiveness), [thrust, *tau], rtol=1e-7, atol=1e-7
        )


def _assert_roll_pitch_authority(allocator: Allocator, hover: float, effectiveness: FloatArray) -> None:
    """Thrust and a roll/pitch torque of 5 % of hover thrust x 0.1 m, in eight directions, delivered whole."""
    size = 0.05 * hover * 0.1
    for angle in np.arange(8) * math.pi / 4:
        roll_pitch = size * np.array([math.cos(angle), math.sin(angle)])
        result = allocator.allocate(hover, (*roll_pitch, 0.0), effectiveness)
        delivered = _delivered(allocator, result.omega_rad_s, effectiveness)
        assert result.roll_pitch_fraction == 1.0
        assert delivered[0] == pytest.approx(hover, rel=1e-9)
        np.testing.assert_allclose(delivered[1:3], roll_pitch, atol=1e-9)


@pytest.mark.parametrize("stopped", range(1, 9))
def test_the_x8_that_lost_a_rotor_hovers_with_full_roll_pitch_authority(stopped: int) -> None:
    allocator, hover = _hover("x8_octorotor")
    effectiveness = _without(8, stopped)
    result = allocator.allocate(hover, (0.0, 0.0, 0.0), effectiveness)
    np.testing.assert_allclose(
        _delivered(allocator, result.omega_rad_s, effectiveness), [hover, 0, 0, 0], atol=1e-9
    )
    assert not result.saturated
    _assert_roll_pitch_authority(allocator, hover, effectiveness)


# Rotors (2k-1, 2k) share an arm (config/x8_octorotor.yaml): every two rotors on different arms.
_DIFFERENT_PAIRS = [(a, b) for a, b in itertools.combinations(range(1, 9), 2) if (a + 1) // 2 != (b + 1) // 2]


@pytest.mark.parametrize("stopped", _DIFFERENT_PAIRS)
def test_the_x8_that_lost_two_rotors_of_different_pairs_hovers_with_full_roll_pitch_authority(
    stopped: tuple[int, int],
) -> None:
    allocator, hover = _hover("x8_octorotor")
    effectiveness = _without(8, *stopped)
    result = allocator.allocate(hover, (0.0, 0.0, 0.0), effectiveness)
    # Two rotors of one spin direction lost: zero yaw needs two others at exactly zero speed, so the
    # yaw step ends on the boundary of the box, up to rounding.
    np.testing.assert_allclose(
        _delivered(allocator, result.omega_rad_s, effectiveness), [hover, 0, 0, 0], atol=1e-9 * hover
    )
    _assert_roll_pitch_authority(allocator, hover, effectiveness)


@pytest.mark.parametrize("stopped", range(1, 7))
def test_the_hexarotor_that_lost_a_rotor_hovers_but_gives_up_yaw(stopped: int) -> None:
    # The X hexarotor keeps thrust and roll/pitch, but zero yaw torque needs the opposite rotor at zero
    # speed, so it has yaw authority in one direction only (allocation.py's docstring).
    allocator, hover = _hover("hexarotor_f550")
    effectiveness = _without(6, stopped)
    result = allocator.allocate(hover, (0.0, 0.0, 0.0), effectiveness)
    np.testing.assert_allclose(
        _delivered(allocator, result.omega_rad_s, effectiveness), [hover, 0, 0, 0], atol=1e-9
    )
    _assert_roll_pitch_authority(allocator, hover, effectiveness)
    yaw_demand = 0.05
    fractions = []
    for sign in (-1.0, 1.0):
        result = allocator.allocate(hover, (0.0, 0.0, sign * yaw_demand), effectiveness)
        delivered = _delivered(allocator, result.omega_rad_s, effectiveness)
        assert delivered[0] == pytest.approx(hover, rel=1e-9)
        np.testing.assert_allclose(delivered[1:3], 0.0, atol=1e-9)
        assert result.roll_pitch_fraction == 1.0
        fractions.append(result.yaw_fraction)
    assert min(fractions) < 1.0 and max(fractions) == 1.0


def test_the_allocator_does_not_rebuild_its_directions_for_a_known_effectiveness() -> None:
    allocator, hover = _hover("x8_octorotor")
    effectiveness = _without(8, 3)
    first = allocator._plan_for(effectiveness)
    assert allocator._plan_for(effectiveness.copy()) is first


@pytest.mark.parametrize(
    ("effectiveness", "reason"),
    [
        (np.ones(7), "one value per rotor"),
        (np.ones((2, 8)), "one value per rotor"),
        (np.array([1.0] * 7 + [math.nan]), "finite"),
        (np.array([1.0] * 7 + [-0.01]), r"\[0, 1.5\]"),
        (np.array([1.0] * 7 + [1.6]), r"\[0, 1.5\]"),
    ],
)
def test_a_bad_effectiveness_is_refused_with_the_reason(effectiveness: FloatArray, reason: str) -> None:
    allocator, hover = _hover("x8_octorotor")
    with pytest.raises(ValueError, match=reason):
        allocator.allocate(hover, (0.0, 0.0, 0.0), effectiveness)


# ------------------------------------------------------------------ the effectiveness filter

CONFIDENT = np.full(8, 0.01)
UNKNOWN = np.ones(8)
RATE_HZ = 250.0


def _run(effectiveness_filter: EffectivenessFilter, diagnoses, start_s: float = 0.0) -> FloatArray:
    """The filter's outputs, one per 1/RATE_HZ, for a list of (estimate, std)."""
    return np.array(
        [
            effectiveness_filter.update(start_s + k / RATE_HZ, estimate, std)
            for k, (estimate, std) in enumerate(diagnoses)
        ]
    )


def test_the_filter_starts_healthy_and_approaches_a_confident_estimate_at_first_order() -> None:
    # A stopped rotor leaves at the stop's own time constant.
    effectiveness_filter = EffectivenessFilter(8, time_constant_s=1.0, stop_time_constant_s=0.2)
    estimate = _without(8, 3)
    outputs = _run(effectiveness_filter, [(estimate, CONFIDENT)] * 251)
    np.testing.assert_array_equal(outputs[0], np.ones(8))
    # After one second, five time constants: e^-5 of the way left.
    assert outputs[-1][2] == pytest.approx(math.exp(-5.0), rel=1e-9)
    np.testing.assert_array_equal(outputs[:, [0, 1, 3, 4, 5, 6, 7]], 1.0)
    assert np.all(np.diff(outputs[:, 2]) < 0)


@pytest.mark.parametrize("stopped", [(3,), (3, 6)])
def test_a_diagnosis_that_appears_and_clears_changes_the_commands_without_a_jump(stopped) -> None:
    # At 250 Hz the commands move by a small share of the full change per step, on the way in and out.
    allocator, hover = _hover("x8_octorotor")
    effectiveness_filter = EffectivenessFilter(8)
    diagnosed = _without(8, *stopped)
    healthy = (np.ones(8), CONFIDENT)
    outputs = _run(effectiveness_filter, [healthy] * 10 + [(diagnosed, CONFIDENT)] * 500 + [healthy] * 500)
    wrench = (hover, 0.01, -0.02, 0.005)
    commands = np.array([allocator.allocate(wrench[0], wrench[1:], e).omega_rad_s for e in outputs])
    full_change = np.abs(
        allocator.allocate(wrench[0], wrench[1:], diagnosed).omega_rad_s
        - allocator.allocate(wrench[0], wrench[1:]).omega_rad_s
    ).max()
    steps = np.abs(np.diff(commands, axis=0)).max(axis=1)
    # The fastest change is a stopped rotor coming back (the filter is then quickest through the fade
    # band): spread over more than 5 control periods, about the motor time constant.
    assert steps.max() < 0.2 * full_change
    np.testing.assert_allclose(outputs[-1], 1.0, atol=1e-3)
    np.testing.assert_allclose(commands[-1], commands[0], rtol=1e-2)


def test_unconfident_or_missing_estimates_hold_and_a_confident_healthy_one_restores() -> None:
    effectiveness_filter = EffectivenessFilter(8)
    estimate = np.ones(8)
    estimate[2] = 0.5
    held = _run(effectiveness_filter, [(estimate, CONFIDENT)] * 500)[-1]
    assert held[2] == pytest.approx(0.5, abs=1e-3)
    std = np.full(8, 0.01)
    std[2] = 2.0 * CONFIDENT_STD
    unconfident_healthy = (np.ones(8), std)
    outputs = _run(effectiveness_filter, [unconfident_healthy] * 100 + [(None, None)] * 100, start_s=2.0)
    np.testing.assert_allclose(outputs, np.tile(held, (200, 1)), atol=1e-3)
    restored = _run(effectiveness_filter, [(np.ones(8), CONFIDENT)] * 500, start_s=3.0)[-1]
    np.testing.assert_allclose(restored, 1.0, atol=1e-3)


def test_a_stopped_verdict_latches_until_a_confident_recovery() -> None:
    effectiveness_filter = EffectivenessFilter(8)
    stopped = (_without(8, 3), CONFIDENT)
    # Once idle, the stopped rotor's estimate drifts above the threshold, unconfident or not.
    drifting = np.ones(8)
    drifting[2] = 0.27
    below_recovery = np.ones(8)
    below_recovery[2] = RECOVERED_EFFECTIVENESS - 0.05
    outputs = _run(
        effectiveness_filter,
        [stopped] * 250 + [(drifting, UNKNOWN)] * 250 + [(below_recovery, CONFIDENT)] * 250,
    )
    assert np.all(outputs[250:, 2] < DEAD_ROTOR_EFFECTIVENESS)
    assert effectiveness_filter.stopped.tolist() == [k == 2 for k in range(8)]
    recovered = _run(effectiveness_filter, [(np.ones(8), CONFIDENT)] * 500, start_s=4.0)[-1]
    np.testing.assert_allclose(recovered, 1.0, atol=1e-3)
    assert not effectiveness_filter.stopped.any()


@settings(max_examples=100, deadline=None)
@given(
    reported=st.floats(-0.2, MAX_EFFECTIVENESS + 0.5),
    std=st.floats(0.0, 2.0),
    floor=st.floats(DEAD_ROTOR_EFFECTIVENESS, 1.0),
)
def test_only_a_rotor_diagnosed_as_stopped_goes_below_the_floor(
    reported: float, std: float, floor: float
) -> None:
    effectiveness_filter = EffectivenessFilter(8, time_constant_s=0.05, floor=floor)
    estimate = np.ones(8)
    estimate[4] = reported
    std_vector = np.full(8, 0.01)
    std_vector[4] = std
    settled = _run(effectiveness_filter, [(estimate, std_vector)] * 250)[-1]
    assert np.all((settled >= 0.0) & (settled <= MAX_EFFECTIVENESS))
    stopped = reported < DEAD_ROTOR_EFFECTIVENESS and std <= CONFIDENT_STD
    if stopped:
        assert settled[4] < DEAD_ROTOR_EFFECTIVENESS
    else:
        assert settled[4] >= floor - 1e-9


@given(
    diagnoses=st.lists(
        st.tuples(
            st.integers(0, 7),
            st.sampled_from([0.0, 0.05, 0.4, 0.7, 1.0, 1.2]),
            st.sampled_from([0.01, CONFIDENT_STD, 0.5]),
            st.integers(1, 400),
        ),
        min_size=1,
        max_size=5,
    )
)
@settings(deadline=None, max_examples=40)
def test_a_diagnosis_given_once_then_none_is_the_same_as_giving_it_every_period(diagnoses) -> None:
    """What a controller does to skip the filter's work between diagnoses (EffectivenessFilter)."""
    every_period, once = EffectivenessFilter(8), EffectivenessFilter(8)
    t_s = 0.0
    for rotor, reported, std, periods in diagnoses:
        estimate, std_vector = np.ones(8), np.full(8, 0.01)
        estimate[rotor], std_vector[rotor] = reported, std
        for period in range(periods):
            t_s += 1.0 / RATE_HZ
            expected = every_period.update(t_s, estimate, std_vector)
            given_once = once.update(t_s, *((estimate, std_vector) if period == 0 else (None, None)))
            np.testing.assert_array_equal(given_once, expected)


def test_the_output_settles_on_its_target_exactly() -> None:
    effectiveness_filter = EffectivenessFilter(8)
    estimate = np.array([1, 1, 0.6, 1, 1, 1, 1, 1.0])
    outputs = _run(effectiveness_filter, [(estimate, CONFIDENT)] + [(None, None)] * 2000)
    assert not np.array_equal(outputs[10], estimate) and effectiveness_filter.settled
    np.testing.assert_array_equal(outputs[-1], estimate)
    assert (np.abs(outputs[1:] - estimate) <= np.abs(outputs[:-1] - estimate)).all()  # no overshoot


def test_a_stopped_rotor_leaves_the_allocation_after_a_few_time_constants() -> None:
    allocator, hover = _hover("x8_octorotor")
    effectiveness_filter = EffectivenessFilter(8, time_constant_s=0.2)
    outputs = _run(effectiveness_filter, [(np.array([1, 1, 0.01, 1, 1, 1, 1, 1.0]), CONFIDENT)] * 250)
    left_out = np.flatnonzero(outputs[:, 2] < DEAD_ROTOR_EFFECTIVENESS)[0] / RATE_HZ
    # A stopped verdict heads for 0, not for the estimate, at the stop's own time constant.
    stop_s = effectiveness_filter.stop_time_constant_s
    assert left_out == pytest.approx(stop_s * math.log(1.0 / DEAD_ROTOR_EFFECTIVENESS), abs=0.01)
    assert allocator.allocate(hover, (0, 0, 0), outputs[-1]).omega_rad_s[2] == 0.0


def test_reset_restores_the_nominal_effectiveness() -> None:
    effectiveness_filter = EffectivenessFilter(8)
    _run(effectiveness_filter, [(_without(8, 1), CONFIDENT)] * 100)
    effectiveness_filter.reset()
    np.testing.assert_array_equal(effectiveness_filter.update(10.0, _without(8, 1), CONFIDENT), 1.0)


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        ((0,), "n_rotors"),
        ((8, 0.0), "time_constant_s"),
        ((8, math.inf), "time_constant_s"),
        ((8, 0.2, 0.05), "floor"),
        ((8, 0.2, 1.2), "floor"),
    ],
)
def test_a_bad_filter_setting_is_refused(arguments, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        EffectivenessFilter(*arguments)


@pytest.mark.parametrize(
    ("estimate", "std", "reason"),
    [
        (np.ones(7), CONFIDENT, "estimate must have one value per rotor"),
        (np.ones(8), np.ones(9), "std must have one value per rotor"),
        (np.array([math.nan] + [1.0] * 7), CONFIDENT, "estimate must be finite"),
        (np.ones(8), np.array([-0.1] + [0.01] * 7), "std must be >= 0"),
    ],
)
def test_a_bad_diagnosis_is_refused(estimate, std, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        EffectivenessFilter(8).update(0.0, estimate, std)


# ------------------------------------------------------------------ closed loop with stopped rotors

FAULT_S = 5.0
HOLD = (0.0, 0.0, 1.0)


def _hover_with_stopped_rotors(
    name: str,
    stopped: tuple[int, ...],
    effectiveness: Callable[[float], FloatArray | None],
    duration_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Hover at HOLD; from FAULT_S the rotors ``stopped`` (1..N) turn at 0 whatever they are commanded.

    The controller is told ``effectiveness(t)``. Returns the control step times [s], the position error
    [m] (world) and the roll/pitch/yaw [rad] at each step.
    """
    airframe = load_airframe(name)
    gains = airframe_gains(airframe)
    sim = VehicleSimulator(
        airframe,
        rng=np.random.default_rng(5),
        odom_rate_hz=gains.rate_hz,
        command_timeout_s=0.0,
        noise=False,
        initial_position_m=HOLD,
    )
    law = SaturationController(airframe, gains, sim.model.gravity_m_s2)
    dead = [rotor - 1 for rotor in stopped]
    control_ns = period_ns(gains.rate_hz)
    times, errors, attitudes = [], [], []
    while sim.t_s < duration_s:
        x = sim.state
        output = law.update(
            sim.t_s,
            x[S.POSITION],
            x[S.VELOCITY],
            x[S.QUATERNION],
            x[S.BODY_RATE],
            HOLD,
            0.0,
            effectiveness=effectiveness(sim.t_s),
        )
        command = output.omega_cmd_rad_s.copy()
        if sim.t_s >= FAULT_S:
            command[dead] = 0.0
        sim.set_command(command)
        times.append(sim.t_s)
        errors.append(x[S.POSITION] - HOLD)
        attitudes.append(quat_to_euler(x[S.QUATERNION]))
        sim.run_until(sim.t_ns + control_ns)
    return np.array(times), np.array(errors), np.array(attitudes)


def _told_from_the_fault(effectiveness: FloatArray) -> Callable[[float], FloatArray | None]:
    return lambda t_s: effectiveness if t_s >= FAULT_S else None


def test_the_x8_holds_position_better_when_the_allocator_knows_rotor_3_stopped() -> None:
    errors = {}
    for label, told in (("blind", lambda t_s: None), ("told", _told_from_the_fault(_without(8, 3)))):
        t, error, _ = _hover_with_stopped_rotors("x8_octorotor", (3,), told, 10.0)
        errors[label] = np.linalg.norm(error[t >= FAULT_S], axis=1)
    assert errors["blind"].max() > 0.5  # the fault matters: seed 1's law alone drifts away
    assert errors["told"].max() < 0.05
    assert np.sqrt(np.mean(errors["told"] ** 2)) < 0.1 * np.sqrt(np.mean(errors["blind"] ** 2))


@pytest.mark.parametrize(
    ("name", "stopped"), [("x8_octorotor", (3, 6)), ("x8_octorotor", (1, 3)), ("hexarotor_f550", (1,))]
)
def test_two_x8_rotors_of_different_pairs_or_one_hexarotor_rotor_lost_still_hover(
    name: str, stopped: tuple[int, ...]
) -> None:
    n_rotors = load_airframe(name).n_rotors
    t, error, attitude = _hover_with_stopped_rotors(
        name, stopped, _told_from_the_fault(_without(n_rotors, *stopped)), 10.0
    )
    after = t >= FAULT_S
    assert np.linalg.norm(error[after], axis=1).max() < 0.1  # issue 15 asks for 0.5 m
    assert np.abs(attitude[after, :2]).max() < 0.1


def test_a_healthy_rotor_wrongly_reported_at_half_thrust_does_not_destabilise_the_x8() -> None:
    effectiveness_filter = EffectivenessFilter(8)
    wrong = np.ones(8)
    wrong[2] = 0.5
    t, error, attitude = _hover_with_stopped_rotors(
        "x8_octorotor",
        (),
        lambda t_s: effectiveness_filter.update(t_s, wrong, CONFIDENT) if t_s >= FAULT_S else None,
        12.0,
    )
    after = t >= FAULT_S
    distance = np.linalg.norm(error, axis=1)
    # A steady offset (the law has no x/y integral), bounded and settled, with a small tilt.
    assert distance[after].max() < 0.3
    assert np.ptp(distance[t >= 10.0]) < 0.01
    assert np.abs(attitude[after, :2]).max() < 0.05


def test_a_rotor_set_that_cannot_balance_says_what_it_delivers() -> None:
    """Hexarotor rotors 1, 2 lost, 6 at half: thrust alone needs a rotor below zero (found by hypothesis)."""
    allocator = Allocator.for_airframe(load_airframe("hexarotor_f550"))
    effectiveness = np.array([0.0, 0.0, 1.0, 1.0, 1.0, 0.5])
    result = allocator.allocate(1.0, (0.0, 0.0, 0.0), effectiveness)
    delivered = _delivered(allocator, result.omega_rad_s, effectiveness)
    assert result.saturated and result.roll_pitch_fraction == 0.0
    assert result.thrust_N == pytest.approx(delivered[0], rel=1e-12)
    assert np.linalg.norm(delivered[1:3]) > 0.01  # the torque the vehicle gets instead of none
    # Balanced sets keep reporting what they deliver: the X8 that lost a coaxial pair hovers.
    x8, hover = _hover("x8_octorotor")
    result = x8.allocate(hover, (0.0, 0.0, 0.0), _without(8, 1, 2))
    assert not result.saturated and result.thrust_N == hover
