"""The seed 1 control law: saturation (eq. 10), signs in ENU/FLU, allocation, gains, closed-loop flights.

Every shipped airframe flies the closed loop offline (simulate_flight).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from multirotor_ros.control import law as law_module
from multirotor_ros.control.allocation import Allocator
from multirotor_ros.control.gains import (
    GAIN_UNITS,
    SEED1_GAINS,
    GainError,
    airframe_gains,
    gains_from_section,
)
from multirotor_ros.control.law import SaturationController, saturate
from multirotor_ros.model.airframe import GRAVITY_M_S2, AirframeError, airframe_from_dict, load_airframe
from multirotor_ros.model.rotation import euler_to_quat
from multirotor_ros.plausibility import StateLimits
from multirotor_ros.resources import available_airframes
from multirotor_ros.simulation.flight import simulate_flight

AIRFRAMES = available_airframes()
finite = st.floats(-1e6, 1e6, allow_nan=False)


# ------------------------------------------------------------------ eq. 10


@given(s=finite, b=st.floats(1e-6, 1e6))
def test_saturation_is_bounded_identity_inside_and_odd(s: float, b: float) -> None:
    value = float(saturate(s, b))
    assert abs(value) <= b
    if abs(s) < b:
        assert value == s
    else:
        assert value == math.copysign(b, s)
    assert float(saturate(-s, b)) == -value


@given(a=finite, c=finite, b=st.floats(1e-6, 1e6))
def test_saturation_is_monotone(a: float, c: float, b: float) -> None:
    low, high = sorted((a, c))
    assert saturate(low, b) <= saturate(high, b)


@pytest.fixture(scope="module")
def x8():
    return load_airframe("x8_octorotor")


@pytest.fixture(scope="module")
def x8_law(x8) -> SaturationController:
    return SaturationController(x8, airframe_gains(x8))


@settings(deadline=None)
@given(yaw=st.floats(-math.pi, math.pi), error=st.floats(-3.1, 3.1), turns=st.integers(-5, 5))
def test_the_yaw_error_is_taken_the_short_way_round(
    x8_law: SaturationController, yaw: float, error: float, turns: int
) -> None:
    # Whole turns in the wanted yaw change nothing; the torque turns the vehicle towards the nearer side.
    def yaw_torque(wanted: float) -> float:
        x8_law.reset()
        q = euler_to_quat([0.0, 0.0, yaw])
        output = x8_law.update(
            0.0, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), q, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), wanted
        )
        return float(output.torque_B[2])

    torque = yaw_torque(yaw + error)
    assert yaw_torque(yaw + error + 2.0 * math.pi * turns) == pytest.approx(torque, rel=1e-6, abs=1e-9)
    assume(abs(error) > 1e-6)
    assert math.copysign(1.0, torque) == math.copysign(1.0, error)


def test_the_compiled_law_reads_every_gain_but_the_rate() -> None:
    # _law unpacks its array in _LAW_GAINS's order: a gain added to ControllerGains must be named there too.
    assert sorted(law_module._LAW_GAINS) == sorted(set(GAIN_UNITS) - {"rate_hz"})


# ------------------------------------------------------------------ signs of eq. 9 in ENU / FLU


def _torque(airframe, position, yaw=0.0, velocity=(0.0, 0.0, 0.0)):
    law = SaturationController(airframe, airframe_gains(airframe))
    q = euler_to_quat([0.0, 0.0, yaw])
    output = law.update(0.0, position, velocity, q, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), yaw)
    return output.torque_B


def test_vehicle_east_of_the_target_pitches_nose_up_to_fly_west(x8) -> None:
    # +theta accelerates towards +x (seed 1 eq. 7); the vehicle is at +x, so it must pitch negative.
    assert _torque(x8, (0.5, 0.0, 1.0))[1] < 0


def test_vehicle_north_of_the_target_rolls_right_to_fly_south(x8) -> None:
    # +phi accelerates towards -y (seed 1 eq. 7, -C_psi S_phi): at +y the vehicle must roll positive.
    assert _torque(x8, (0.0, 0.5, 1.0))[0] > 0


def test_errors_are_taken_in_the_heading_frame(x8) -> None:
    # Facing north (yaw +90 deg), a target to the east is on the vehicle's right (body -y): it must roll
    # positive, and not pitch at all.
    torque = _torque(x8, (-0.5, 0.0, 1.0), yaw=math.pi / 2)
    assert torque[0] > 0
    assert abs(torque[1]) < 1e-12


def test_velocity_terms_damp_the_motion(x8) -> None:
    # Moving east at the target: decelerate, i.e. pitch negative as for a position east of the target.
    assert _torque(x8, (0.0, 0.0, 1.0), velocity=(1.0, 0.0, 0.0))[1] < 0


# ------------------------------------------------------------------ extreme but plausible input

LIMITS = StateLimits()


def _bounded_vectors(limit: float) -> st.SearchStrategy[np.ndarray]:
    """Vectors of norm up to ``limit`` (less a rounding error), the limit itself and zero included."""
    largest = limit * (1.0 - 1e-9)
    direction = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
        lambda v: np.linalg.norm(v) > 1e-3
    )
    size = st.one_of(st.just(largest), st.just(0.0), st.floats(0.0, largest))
    return st.builds(lambda d, s: np.array(d) / np.linalg.norm(d) * s, direction, size)


# Any attitude, and pitch at and near +-90 deg, where the Euler rates divide by cos(pitch).
_attitudes = st.one_of(
    st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)
    .filter(lambda q: np.linalg.norm(q) > 1e-3)
    .map(lambda q: np.array(q) / np.linalg.norm(q)),
    st.builds(
        lambda pitch, yaw: euler_to_quat([0.0, pitch, yaw]),
        st.sampled_from([math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, 1.5]),
        st.floats(-math.pi, math.pi),
    ),
)
_plausible_states = st.tuples(
    st.floats(0.0, 1.0),  # time since the previous update [s]
    _bounded_vectors(LIMITS.position_m),
    _bounded_vectors(LIMITS.speed_m_s),
    _attitudes,
    _bounded_vectors(LIMITS.body_rate_rad_s),
    _bounded_vectors(LIMITS.position_m),  # setpoint
    st.floats(-math.pi, math.pi),
)


@pytest.mark.parametrize("name", AIRFRAMES)
@settings(max_examples=80, deadline=None)
@given(states=st.lists(_plausible_states, min_size=1, max_size=6))
def test_plausible_extremes_give_finite_speeds_in_range(name: str, states: list) -> None:
    # Whatever the nodes accept (StateLimits: 10 km, 100 m/s, 35 rad/s, any unit quaternion), the law
    # answers with finite speeds in the rotor range, and is fit for the next update: nothing poisons it.
    airframe = load_airframe(name)
    law = SaturationController(airframe, airframe_gains(airframe))
    t = 0.0
    for dt, p, v, q, w, p_desired, yaw_desired in states:
        t += dt
        assert LIMITS.check(p_WB_W=p, v_WB_W=v, w_WB_B=w) is None
        output = law.update(t, p, v, q, w, p_desired, yaw_desired)
        omega = output.omega_cmd_rad_s
        assert np.all(np.isfinite(omega)) and np.isfinite(output.thrust_N)
        assert np.all(np.isfinite(output.torque_B))
        assert np.all(omega >= airframe.rotor_speed_min_rad_s - 1e-9)
        assert np.all(omega <= airframe.rotor_speed_max_rad_s + 1e-9)
    hover = law.update(
        t + 0.004, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, (0.0, 0.0, 1.0), 0.0
    )
    assert np.all(np.isfinite(hover.omega_cmd_rad_s))


# ------------------------------------------------------------------ allocation


@pytest.fixture(scope="module", params=AIRFRAMES)
def allocator(request):
    return Allocator.for_airframe(load_airframe(request.param))


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_wrench_whose_least_squares_speeds_fit_is_allocated_exactly(allocator: Allocator, data) -> None:
    n = allocator.matrix.shape[1]
    top = math.sqrt(allocator.high)
    speeds = np.array(data.draw(st.lists(st.floats(0.2 * top, 0.8 * top), min_size=n, max_size=n)))
    wrench = allocator.matrix @ speeds**2
    pinv = np.linalg.pinv(allocator.matrix)
    # The priorities add yaw last: exactness is promised when the pseudo-inverse solution fits with and
    # without its yaw part (for a square matrix, whenever the wrench is feasible at all).
    for partial in (pinv @ wrench, pinv @ np.append(wrench[:3], 0.0)):
        assume(np.all((partial >= allocator.low) & (partial <= allocator.high)))
    result = allocator.allocate(wrench[0], wrench[1:])
    np.testing.assert_allclose(allocator.matrix @ result.omega_rad_s**2, wrench, rtol=1e-9, atol=1e-9)
    assert not result.saturated


@settings(max_examples=100, deadline=None)
@given(thrust=st.floats(-100.0, 200.0), tau=st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3))
def test_allocated_speeds_stay_in_range(allocator: Allocator, thrust: float, tau: list[float]) -> None:
    result = allocator.allocate(thrust, tau)
    assert np.all(result.omega_rad_s >= math.sqrt(allocator.low) - 1e-9)
    assert np.all(result.omega_rad_s <= math.sqrt(allocator.high) + 1e-9)
    assert 0.0 <= result.roll_pitch_fraction <= 1.0
    assert 0.0 <= result.yaw_fraction <= 1.0


@settings(max_examples=60, deadline=None)
@given(yaw_torque=st.floats(1.0, 50.0), sign=st.sampled_from([-1.0, 1.0]))
def test_yaw_gives_way_before_thrust_and_attitude(
    allocator: Allocator, yaw_torque: float, sign: float
) -> None:
    hover = 0.4 * allocator.max_thrust_N
    roll_pitch = (0.05 * hover * 0.1, -0.05 * hover * 0.1)
    result = allocator.allocate(hover, (*roll_pitch, sign * yaw_torque))
    delivered = allocator.matrix @ result.omega_rad_s**2
    assert result.roll_pitch_fraction == 1.0
    assert delivered[0] == pytest.approx(hover, rel=1e-9)
    np.testing.assert_allclose(delivered[1:3], roll_pitch, atol=1e-9)
    assert result.yaw_fraction < 1.0
    assert np.sign(delivered[3]) in (0.0, sign)


def test_attitude_is_kept_before_thrust(allocator: Allocator) -> None:
    # Near full thrust a large roll torque cannot be had with the collective asked: thrust gives way. The
    # torque is 0.2 of the thrust at 0.1 m, or at the rotors' distance from the roll axis where that is
    # shorter (the Crazyflie's 33 mm), so that the airframe can give it at a lower collective.
    hover = 0.95 * allocator.max_thrust_N
    lever_m = min(0.1, float(np.max(np.abs(allocator.matrix[1] / allocator.matrix[0]))))
    roll = 0.2 * hover * lever_m
    result = allocator.allocate(hover, (roll, 0.0, 0.0))
    delivered = allocator.matrix @ result.omega_rad_s**2
    assert result.roll_pitch_fraction == 1.0
    assert delivered[1] == pytest.approx(roll, rel=1e-9)
    assert delivered[0] < hover


# ------------------------------------------------------------------ gains from the YAML


def _document(airframe_name: str) -> dict:
    path = load_airframe(airframe_name).source_path
    return yaml.safe_load(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", AIRFRAMES)
def test_every_airframe_has_every_gain(name: str) -> None:
    gains = airframe_gains(load_airframe(name)).as_dict()
    assert list(gains) == list(GAIN_UNITS)
    assert all(value > 0 for value in gains.values())


def test_an_airframe_overrides_only_the_gains_it_names() -> None:
    document = _document("quad_x")
    document["controller"] = {"k_dphi": 100.0}
    airframe = airframe_from_dict(document, origin="quad_x.yaml", source_path=Path("quad_x.yaml"))
    assert airframe_gains(airframe) == SEED1_GAINS.replace(k_dphi=100.0)


def test_an_airframe_without_a_controller_section_gets_the_seed_1_gains() -> None:
    document = _document("quad_x")
    del document["controller"]
    assert airframe_gains(airframe_from_dict(document, origin="quad_x.yaml")) == SEED1_GAINS


def test_the_seed_1_gains_follow_their_stated_derivation() -> None:
    # gains.py derives each loop gain from a natural frequency and a damping; the values are rounded.
    g = SEED1_GAINS
    attitude_frequency, attitude_damping = 8.0, 0.8
    position_frequency, position_damping = 1.6, 0.9
    for k_p, k_d in ((g.k_ptheta, g.k_dtheta), (g.k_pphi, g.k_dphi)):
        assert k_p == pytest.approx(attitude_frequency**2 * GRAVITY_M_S2, rel=0.01)
        assert k_d == pytest.approx(2 * attitude_damping * attitude_frequency * GRAVITY_M_S2, rel=0.01)
    for k_p, k_d, k_attitude in ((g.k_px, g.k_dx, g.k_ptheta), (g.k_py, g.k_dy, g.k_pphi)):
        assert k_p == pytest.approx(position_frequency**2 * k_attitude / GRAVITY_M_S2, rel=0.01)
        assert k_d == pytest.approx(
            2 * position_damping * position_frequency * k_attitude / GRAVITY_M_S2, rel=0.01
        )
    assert g.b_ptheta > g.b_px + g.b_dx and g.b_pphi > g.b_py + g.b_dy


@pytest.mark.parametrize("name", AIRFRAMES)
def test_every_airframe_s_rotors_are_fast_enough_for_the_shared_attitude_loop(name: str) -> None:
    # The one set of gains holds where the rotor lag's bandwidth is at least 4 times the attitude loop's.
    gains = airframe_gains(load_airframe(name))
    attitude_frequency = math.sqrt(max(gains.k_pphi, gains.k_ptheta) / GRAVITY_M_S2)
    assert 1.0 / load_airframe(name).motor_time_constant_s >= 4.0 * attitude_frequency


def test_an_unknown_gain_key_is_refused() -> None:
    section = dict(_document("quad_x")["controller"], k_pxx=1.0)
    with pytest.raises(GainError, match=r"q\.yaml: controller\.k_pxx: unknown key"):
        gains_from_section(section, "q.yaml")


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), "fast", True])
def test_a_gain_must_be_a_positive_number(value) -> None:
    section = dict(_document("quad_x")["controller"], b_py=value)
    with pytest.raises(GainError, match=r"controller\.b_py"):
        gains_from_section(section, "q.yaml")


def test_a_controller_section_that_is_not_a_mapping_is_refused() -> None:
    document = _document("quad_x")
    document["controller"] = [1, 2]
    with pytest.raises(AirframeError, match="controller: expected a mapping"):
        airframe_from_dict(document, origin="quad_x.yaml")


# ------------------------------------------------------------------ closed loop, offline


def _fly(airframe, setpoints, duration, **options):
    return simulate_flight(
        airframe, setpoints=setpoints, duration_s=duration, rng=np.random.default_rng(3), **options
    )


@pytest.mark.parametrize("name", AIRFRAMES)
def test_every_airframe_takes_off_and_hovers_within_2_cm(name: str) -> None:
    log = _fly(load_airframe(name), [(0.0, 0.0, 0.0, 1.0, 0.0)], 8.0, noise=False)
    hold = log.t >= 6.0
    error = np.sqrt(log.columns["x"] ** 2 + log.columns["y"] ** 2 + (log.columns["z"] - 1.0) ** 2)
    assert error[hold].max() < 0.02


@pytest.mark.parametrize("name", AIRFRAMES)
@pytest.mark.parametrize("yaw", [0.0, 2.0])
def test_every_airframe_settles_a_1_m_step_within_5_s(name: str, yaw: float) -> None:
    # The step is along world x whatever the heading: the law works in the heading frame.
    setpoints = [(0.0, 0.0, 0.0, 1.0, yaw), (4.0, 1.0, 0.0, 1.0, yaw)]
    log = _fly(load_airframe(name), setpoints, 10.0, initial_position_m=(0.0, 0.0, 1.0), initial_yaw_rad=yaw)
    after = log.t >= 4.0
    x = log.columns["x"][after]
    t = log.t[after] - 4.0
    assert x.max() - 1.0 < 0.20
    outside = np.nonzero(np.abs(x - 1.0) > 0.05)[0]
    assert t[outside[-1]] < 5.0
    assert np.abs(log.columns["y"][after]).max() < 0.05


def test_the_x8_keeps_flying_when_rotor_3_stops(x8) -> None:
    fault = {"id": "actuator_fault", "motor": 3, "effectiveness": 0.0, "t_fault_s": 3.0}
    log = simulate_flight(
        x8,
        [*x8.effect_specs(), fault],
        setpoints=[(0.0, 0.0, 0.0, 1.0, 0.0)],
        duration_s=12.0,
        rng=np.random.default_rng(4),
        initial_position_m=(0.0, 0.0, 1.0),
    )
    after = log.t >= 3.0
    assert log.columns["z"][after].min() > 0.6
    assert np.hypot(log.columns["x"], log.columns["y"])[after].max() < 1.5
    assert np.abs(log.columns["z"][log.t >= 10.0] - 1.0).max() < 0.05
    assert np.abs(log.columns["roll"][after]).max() < 0.4


def test_the_closed_loop_is_deterministic_given_the_generator(x8) -> None:
    setpoints = [(0.0, 0.0, 0.0, 1.0, 0.0), (1.0, 0.5, 0.0, 1.0, 0.0)]
    first = _fly(x8, setpoints, 2.0)
    second = _fly(x8, setpoints, 2.0)
    for name, column in first.columns.items():
        np.testing.assert_array_equal(column, second.columns[name], err_msg=name)
