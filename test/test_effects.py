"""Every effect of effects.md: one contract test over all of them, and each formula on hand-computed cases."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe, load_airframe
from multirotor_ros.model.compiled import CompiledStepper
from multirotor_ros.model.effects import (
    EFFECTS,
    Effect,
    Parameter,
    ReferenceCondition,
    check_formulas,
    make_effect,
    parse_effect_list,
)
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import euler_to_matrix
from multirotor_ros.model.state import StateBatch
from multirotor_ros.resources import config_directory

X8 = load_airframe("x8_octorotor")
AIRFRAMES = [load_airframe(path.stem) for path in sorted(config_directory().glob("*.yaml"))]
SAMPLE_PARAMETERS = {
    "quadratic_drag": {"c_x": 0.47, "c_y": 0.4, "c_z": 0.2},
    "rotor_drag": {"k_h": 2e-4},
    "thrust_speed_dependence": {"k_f1": 2e-9},
    "coaxial_loss": {"eta_lower": 0.8},
    "ground_effect": {"rotor_radius_m": 0.127},
    "inflow_thrust_loss": {"k_v": 1e-4},
    "motor_lag": {"tau_s": 0.03},
    "mass_offset": {"dm_kg": 0.3},
    "constant_force": {"f_x": 1.0, "f_y": -0.5, "f_z": 0.2},
    "actuator_fault": {"motor": 3, "effectiveness": 0.4, "t_fault_s": 1.0},
    "gyroscopic": {"j_r": 1e-4},
    "cg_offset": {"r_x": 0.01, "r_y": -0.02},
    "yaw_drag_torque": {"dk_t": 5e-8},
}
SPEC = Path(__file__).resolve().parents[2] / "shared" / "spec" / "effects.md"


def sample_parameters(effect_id: str, n_rotors: int = 8) -> dict[str, float]:
    """Parameters that make the effect act; per-rotor ones differ from rotor to rotor."""
    per_rotor = EFFECTS[effect_id].PER_ROTOR_PARAMETER
    if per_rotor is not None:
        return {f"{per_rotor.name}_{i}": 1.0 - 0.05 * i for i in range(1, n_rotors + 1)}
    return SAMPLE_PARAMETERS[effect_id]


def spec_parameters() -> dict[str, list[str]]:
    """Effect ids and parameter names as effects.md writes them (e_1 ... e_N read as the per-rotor e_i)."""
    table = {}
    for line in SPEC.read_text().splitlines():
        cells = [c.strip() for c in line.split("|")]
        if len(cells) > 3 and re.fullmatch(r"`[a-z_]+`", cells[1]):
            names = re.findall(r"`([a-z_0-9N]+)`", cells[2])
            if names and names[-1].endswith("_N"):
                names = [names[0].rsplit("_", 1)[0] + "_i"]
            table[cells[1].strip("`")] = names
    return table


README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.skipif(not SPEC.exists(), reason="the project's shared/spec is not beside this checkout")
def test_registry_matches_the_spec() -> None:
    """The ids and parameter names of effects.md, verbatim; an effect beyond them is in the README."""
    ours = {k: [p.name for p in cls.parameter_list(None)] for k, cls in EFFECTS.items()}
    spec = spec_parameters()
    assert {k: ours.get(k) for k in spec} == spec
    additions = README.read_text().split("## Interfaces beyond the spec")[1].split("\n## ")[0]
    for effect_id in ours.keys() - spec.keys():
        assert f"`{effect_id}`" in additions, (
            f"{effect_id} is not in effects.md nor in the README's additions"
        )
        for name in ours[effect_id]:
            assert f"`{name}`" in additions


@pytest.mark.parametrize("airframe", AIRFRAMES, ids=lambda a: a.name)
@pytest.mark.parametrize("effect_id", sorted(EFFECTS))
def test_effect_contract(effect_id: str, airframe: Airframe) -> None:
    """The contract every effect keeps on every airframe: names itself, refuses bad parameters, acts finitely.

    Like PySINDy's one test over every feature library: a new effect class is held to it without a new test.
    """
    cls = EFFECTS[effect_id]
    n = airframe.n_rotors
    parameters = sample_parameters(effect_id, n)
    effect = make_effect({"id": effect_id, **parameters})
    assert isinstance(effect, Effect) and effect.id == effect_id and effect_id in repr(effect)
    assert cls.description() and cls.regime, "an effect says what it adds and where a flight shows it"
    assert make_effect(effect.spec()).parameters.keys() == effect.parameters.keys()
    with pytest.raises(ValueError, match="unknown parameter"):
        make_effect({"id": effect_id, **parameters, "bogus": 1.0})
    with pytest.raises(ValueError, match="missing parameter"):
        make_effect({"id": effect_id, **{k: v for k, v in parameters.items() if k != next(iter(parameters))}})
    first = next(iter(parameters))
    with pytest.raises(ValueError, match=first):
        make_effect({"id": effect_id, **parameters, first: math.nan})
    for parameter in cls.parameter_list(n):
        assert parameter.unit and parameter.excited_by
        reference = ReferenceCondition.of(airframe)
        assert math.isfinite(parameter.scale(reference)) and parameter.scale(reference) > 0
        lower, upper = parameter.bounds(reference)
        assert lower <= parameter.start <= upper, f"{parameter.name} starts outside its bounds"
        searched_elsewhere = parameter.linear_given_others or parameter.discrete or parameter.onset_time
        if not parameter.linear and not searched_elsewhere:
            assert parameter.search_grid, f"{parameter.name} is searched, so it needs a grid"
    # The neutral parameters make no difference to the physics.
    model = Model(airframe, [effect])
    neutral = Model(airframe, [{"id": effect_id, **cls.neutral_parameters(n)}])
    base = Model(airframe, [])
    x = S.make_state(
        n,
        batch=4,
        position_m=(0, 0, 5.0),
        velocity_m_s=(2, -1, 0.5),
        euler_rad=(0.1, -0.2, 0.5),
        body_rate_rad_s=(0.3, 0.2, -0.1),
        rotor_speed_rad_s=330,
    )
    u = np.full((4, n), 340.0)
    # Compared with the rotors at their command: a stand-in for "no lag" still moves a rotor that is not.
    at_command = x.copy()
    at_command[:, S.ROTORS_START :] = u
    np.testing.assert_allclose(
        neutral.derivative(2.0, at_command, u)[:, : S.ROTORS_START],
        base.derivative(2.0, at_command, u)[:, : S.ROTORS_START],
        rtol=1e-6,
        atol=1e-6,
    )
    acting = model.derivative(2.0, x, u)
    assert np.all(np.isfinite(acting))
    if (
        cls.not_applicable(airframe) is None
        and cls.rotational is False
        and not cls.formulas().keys() <= {"rotor_time_constant_s"}
    ):
        assert not np.allclose(acting, base.derivative(2.0, x, u)), (
            f"{effect_id} does nothing on {airframe.name}"
        )
    assert set(effect.linear_parameters) <= set(parameters)
    # The compiled kernel, generated from the same formulas, gives the same derivative.
    np.testing.assert_allclose(
        CompiledStepper(model, 4).derivative(2.0, x, u), acting, rtol=1e-11, atol=1e-11
    )


def test_a_formula_reading_an_unknown_name_is_refused_at_definition() -> None:
    class Misspelt(Effect):
        """A force that reads a quantity that does not exist."""

        id = "misspelt"
        PARAMETERS = (Parameter("k", "N", 0.0, lambda r: 1.0, "any flight"),)

        @staticmethod
        def force_W(k, velocity_x):  # noqa: ANN001, ANN205 - the point is the wrong name
            return k * velocity_x, 0.0, 0.0

    with pytest.raises(TypeError, match="velocity_x"):
        check_formulas(Misspelt)


@pytest.mark.parametrize("effect_id", sorted(EFFECTS))
def test_compiled_kernel_matches_the_reference_model(effect_id: str) -> None:
    """The compiled fast path evaluates the same formula as the numpy effect, effect by effect."""
    model = Model(X8, [{"id": effect_id, **sample_parameters(effect_id)}])
    rng = np.random.default_rng(7)
    x = S.make_state(8, batch=16, position_m=(0, 0, 0.0), rotor_speed_rad_s=0.0)
    x[:, S.POSITION] = rng.uniform([-5, -5, 0.0], [5, 5, 3.0], (16, 3))
    x[:, S.VELOCITY] = rng.normal(0, 3, (16, 3))
    q = rng.normal(size=(16, 4))
    x[:, S.QUATERNION] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x[:, S.BODY_RATE] = rng.normal(0, 1, (16, 3))
    x[:, S.ROTORS_START :] = rng.uniform(200, 500, (16, 8))
    u = rng.uniform(200, 500, (16, 8))
    for t in (0.5, 1.5):
        reference = model.derivative(t, x, u)
        compiled = CompiledStepper(model, 16).derivative(t, x, u)
        np.testing.assert_allclose(compiled, reference, rtol=1e-11, atol=1e-11)


def _level_context(model: Model, v=(0.0, 0.0, 0.0), z=10.0, omega=340.0, t=0.0, euler=(0.0, 0.0, 0.0)):
    R = euler_to_matrix(np.array([euler]))
    return model.context(
        StateBatch(
            t,
            np.array([[0.0, 0.0, z]]),
            np.array([v], float),
            R,
            np.zeros((1, 3)),
            np.broadcast_to(np.asarray(omega, float), (1, 8)).copy(),
        )
    )


def _force(effect_spec: dict, **kwargs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    model = Model(X8, [effect_spec])
    base = Model(X8, [])
    ctx = _level_context(model, **kwargs)
    F, tau, thrust = model.wrench(ctx)
    F0, tau0, thrust0 = base.wrench(ctx)
    return F[0] - F0[0], tau[0] - tau0[0], thrust[0]


def test_quadratic_drag_by_hand() -> None:
    dF, dtau, _ = _force({"id": "quadratic_drag", "c_x": 0.4688, "c_y": 0.3, "c_z": 0.1}, v=(2.0, -1.0, 0.5))
    np.testing.assert_allclose(dF, [-0.4688 * 4, 0.3 * 1, -0.1 * 0.25])
    np.testing.assert_allclose(dtau, 0.0)


def test_rotor_drag_by_hand() -> None:
    # Level: R P R^T v keeps the horizontal part of v, grows with the rotor speed sum.
    dF, _, _ = _force({"id": "rotor_drag", "k_h": 1e-4}, v=(2.0, -1.0, 3.0), omega=300.0)
    np.testing.assert_allclose(dF, [-1e-4 * 2400 * 2, 1e-4 * 2400, 0.0], atol=1e-12)
    # Pitched 90 degrees (nose down), the body-horizontal plane is world y-z: world x velocity makes no drag.
    dF, _, _ = _force(
        {"id": "rotor_drag", "k_h": 1e-4}, v=(2.0, 0.0, 0.0), omega=300.0, euler=(0, math.pi / 2, 0)
    )
    np.testing.assert_allclose(dF, 0.0, atol=1e-12)


def test_thrust_speed_dependence_by_hand() -> None:
    _, _, thrust = _force({"id": "thrust_speed_dependence", "k_f1": 2e-9}, omega=400.0)
    np.testing.assert_allclose(thrust, (1.7e-5 + 2e-9 * 400) * 400**2)


def test_coaxial_loss_by_hand() -> None:
    _, _, thrust = _force({"id": "coaxial_loss", "eta_lower": 0.8}, omega=340.0)
    single = 1.7e-5 * 340**2
    np.testing.assert_allclose(thrust, [single, 0.8 * single] * 4)


def test_ground_effect_by_hand() -> None:
    radius = 0.127
    _, _, thrust = _force({"id": "ground_effect", "rotor_radius_m": radius}, z=0.5, omega=340.0)
    np.testing.assert_allclose(thrust, 1.7e-5 * 340**2 / (1 - (radius / (4 * 0.5)) ** 2))
    # Far above the ground the effect vanishes.
    _, _, far = _force({"id": "ground_effect", "rotor_radius_m": radius}, z=100.0, omega=340.0)
    np.testing.assert_allclose(far, 1.7e-5 * 340**2, rtol=1e-6)


def test_inflow_thrust_loss_by_hand() -> None:
    _, _, climbing = _force({"id": "inflow_thrust_loss", "k_v": 1e-4}, v=(0.0, 0.0, 2.0), omega=340.0)
    np.testing.assert_allclose(climbing, 1.7e-5 * 340**2 - 1e-4 * 340 * 2.0)
    _, _, descending = _force({"id": "inflow_thrust_loss", "k_v": 1e-4}, v=(0.0, 0.0, -2.0), omega=340.0)
    assert np.all(descending > 1.7e-5 * 340**2)


def test_motor_lag_follows_a_first_order_response() -> None:
    model = Model(X8, [{"id": "motor_lag", "tau_s": 0.05}])
    from multirotor_ros.model.integrator import Integrator

    x = S.make_state(8, position_m=(0, 0, 50), rotor_speed_rad_s=300.0)
    x = Integrator(model, 1e-3, backend="numpy").advance(0.0, x, np.full(8, 400.0), 50)
    np.testing.assert_allclose(x[0, S.ROTORS_START :], 400 - 100 * math.exp(-1), rtol=1e-9)


def test_mass_offset_by_hand() -> None:
    model = Model(X8, [{"id": "mass_offset", "dm_kg": 0.4}])
    hover = Model(X8, []).hover_speed_rad_s()
    a_W, _ = model.accelerations(_level_context(model, omega=hover))
    np.testing.assert_allclose(a_W[0], [0, 0, 1.6 * GRAVITY_M_S2 / 2.0 - GRAVITY_M_S2], atol=1e-12)


def test_constant_force_by_hand() -> None:
    dF, _, _ = _force({"id": "constant_force", "f_x": 1.0, "f_y": -2.0, "f_z": 0.5})
    np.testing.assert_allclose(dF, [1.0, -2.0, 0.5])


def test_actuator_fault_by_hand() -> None:
    spec = {"id": "actuator_fault", "motor": 3, "effectiveness": 0.25, "t_fault_s": 1.0}
    _, _, before = _force(spec, t=0.5)
    _, dtau_after, after = _force(spec, t=1.5)
    single = 1.7e-5 * 340**2
    np.testing.assert_allclose(before, single)
    np.testing.assert_allclose(after, [single, single, 0.25 * single, single, single, single, single, single])
    # Rotor 3 (rear-right, cw) lost 75 % of its thrust and of its drag torque.
    position = X8.rotor_positions_m[2]
    lost = -0.75 * single
    np.testing.assert_allclose(dtau_after, [lost * position[1], -lost * position[0], -0.75 * 2.5e-7 * 340**2])


def test_gyroscopic_torque_by_hand() -> None:
    model = Model(X8, [{"id": "gyroscopic", "j_r": 1e-4}])
    omega = np.array([[300.0, 310, 320, 330, 340, 350, 360, 370]])
    ctx = model.context(
        StateBatch(
            0.0, np.zeros((1, 3)), np.zeros((1, 3)), np.eye(3)[None], np.array([[0.5, -0.2, 0.0]]), omega
        )
    )
    _, tau, _ = model.wrench(ctx)
    _, tau0, _ = Model(X8, []).wrench(ctx)
    # Seed 1 eq. 3: Omega_r = w2 + w3 + w6 + w7 - w1 - w4 - w5 - w8 (cw minus ccw).
    w = omega[0]
    omega_r = w[1] + w[2] + w[5] + w[6] - w[0] - w[3] - w[4] - w[7]
    # Roll: +J_r q Omega_r as in seed 1 eq. 7; pitch: -J_r p Omega_r (seed 1 prints +, a known sign slip:
    # the torque is -w x h, and Bouabdallah's thesis, seed 1's ref. [1], has the minus sign).
    np.testing.assert_allclose(tau[0] - tau0[0], [1e-4 * -0.2 * omega_r, -1e-4 * 0.5 * omega_r, 0.0])


def test_cg_offset_by_hand() -> None:
    _, dtau, thrust = _force({"id": "cg_offset", "r_x": 0.01, "r_y": -0.02})
    total = thrust.sum()
    np.testing.assert_allclose(dtau, [0.02 * total, 0.01 * total, 0.0])


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.sampled_from(sorted(EFFECTS)), unique=True, max_size=4),
    st.floats(-3, 3),
    st.floats(0, 3),
)
def test_any_effect_combination_keeps_the_state_finite(
    effect_ids: list[str], speed: float, height: float
) -> None:
    model = Model(X8, [{"id": i, **sample_parameters(i)} for i in effect_ids])
    x = S.make_state(
        8, position_m=(0, 0, height), velocity_m_s=(speed, -speed, speed / 2), rotor_speed_rad_s=340
    )
    assert np.all(np.isfinite(model.derivative(1.0, x, np.full(8, 340.0))))


def test_effect_list_parsing() -> None:
    assert parse_effect_list("none") == []
    assert parse_effect_list("quadratic_drag, rotor_drag") == ["quadratic_drag", "rotor_drag"]
    with pytest.raises(ValueError, match="warp"):
        parse_effect_list("quadratic_drag,warp")


def test_gyroscopic_yaw_term_from_rotor_acceleration() -> None:
    """Seed 1 eq. 7's J_r dOmega_r/dt: rotors speeding up twist the body the other way about z."""
    tau_s, j_r = 0.05, 1e-4
    lagging = Model(X8, [{"id": "motor_lag", "tau_s": tau_s}])
    with_gyro = Model(X8, [{"id": "motor_lag", "tau_s": tau_s}, {"id": "gyroscopic", "j_r": j_r}])
    x = S.make_state(8, position_m=(0, 0, 10), rotor_speed_rad_s=300.0)
    command = np.array([[300.0, 340, 340, 300, 300, 340, 340, 300]])  # the cw rotors (2, 3, 6, 7) speed up
    yaw_acceleration = (
        with_gyro.derivative(0.0, x, command)[0, 12] - lagging.derivative(0.0, x, command)[0, 12]
    )
    omega_dot = (command[0] - 300.0) / tau_s
    # Body torque -dh_r/dt with h_r = J_r sum(-s_i omega_i): J_r sum(s_i domega_i/dt) about +z.
    expected_torque = j_r * float(X8.spin_signs @ omega_dot)
    np.testing.assert_allclose(yaw_acceleration * X8.inertia_kg_m2[2, 2], expected_torque, rtol=1e-9)
    assert expected_torque > 0
