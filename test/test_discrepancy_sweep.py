"""Hidden-effect sweep (issue 5): every translational effect the workflow can fit hidden from the baseline.

Each at two strengths and two noise levels, on the X8 and the hexarotor (coaxial_loss on the X8 only, the
hexarotor has no coaxial rotors). The workflow, baseline `--effects none`, must name the effect, recover
its parameters within 15 % and cut the gap. About 80 simulated flights (7-10 minutes on the 2-core
machine); `make test` runs it, `-m "not slow"` leaves it out while iterating.
"""

import pytest
from test_ident_flights import effect, flight

from multirotor_ros.discrepancy.workflow import find_discrepancy, untestable_by_design
from multirotor_ros.model.effects import TRANSLATIONAL_EFFECTS, effect_class

STRENGTHS = {
    "quadratic_drag": [dict(c_x=0.15, c_y=0.15, c_z=0.1), dict(c_x=0.4, c_y=0.4, c_z=0.2)],
    "rotor_drag": [dict(k_h=7e-5), dict(k_h=2e-4)],
    "thrust_speed_dependence": [dict(k_f1=2e-9), dict(k_f1=5e-9)],
    "coaxial_loss": [dict(eta_lower=0.9), dict(eta_lower=0.75)],
    "ground_effect": [dict(rotor_radius_m=0.1), dict(rotor_radius_m=0.127)],
    "inflow_thrust_loss": [dict(k_v=2e-4), dict(k_v=5e-4)],
    "motor_lag": [dict(tau_s=0.02), dict(tau_s=0.05)],
    "mass_offset": [dict(dm_kg=0.05), dict(dm_kg=0.15)],
    "constant_force": [dict(f_x=0.3, f_y=-0.2, f_z=0.3), dict(f_x=0.5, f_y=-0.3, f_z=0.5)],
    "actuator_fault": [
        dict(motor=3, effectiveness=0.8, t_fault_s=15.0),
        dict(motor=5, effectiveness=0.6, t_fault_s=22.0),
    ],
}
CASES = [
    pytest.param(
        airframe, effect_id, strength, noise, id=f"{airframe.split('_')[0]}-{effect_id}-s{strength}-{noise}"
    )
    for airframe in ("x8_octorotor", "hexarotor_f550")
    for effect_id in STRENGTHS
    for strength in (0, 1)
    for noise in ("low", "high")
    if not (effect_id == "coaxial_loss" and airframe != "x8_octorotor")
]


def test_the_sweep_covers_every_translational_effect_the_workflow_can_fit():
    fittable = {e for e in TRANSLATIONAL_EFFECTS if untestable_by_design(effect_class(e)) is None}
    assert set(STRENGTHS) == fittable


@pytest.mark.slow
@pytest.mark.parametrize(("airframe", "effect_id", "strength", "noise"), CASES)
def test_hidden_effect_is_named_with_its_parameters(airframe, effect_id, strength, noise):
    truth = STRENGTHS[effect_id][strength]
    log = flight(airframe, (effect(effect_id, **truth),), duration_s=30.0, seed=strength + 1, noise=noise)
    report = find_discrepancy(airframe, log, [])
    assert report.missing_effect == effect_id, report.explanation
    for name, value in truth.items():
        if name == "motor":
            assert report.parameters["motor"] == value
        elif name == "t_fault_s":
            assert report.parameters[name] == pytest.approx(value, abs=0.25)
        else:
            assert report.parameters[name] == pytest.approx(value, rel=0.15), name
    # At the high noise level the noise floor is most of what is left: the gap shrinks, not by half.
    assert sum(report.mse_after.values()) < (0.5 if noise == "low" else 0.9) * sum(report.mse_before.values())


@pytest.mark.slow
@pytest.mark.parametrize("airframe", ["x8_octorotor", "hexarotor_f550"])
@pytest.mark.parametrize("noise", ["low", "high"])
def test_nothing_hidden_gives_none(airframe, noise):
    report = find_discrepancy(airframe, flight(airframe, (), duration_s=30.0, seed=7, noise=noise), [])
    assert report.missing_effect == "none", [
        (c.effect, c.score, c.z_statistic) for c in report.candidates[:3]
    ]
