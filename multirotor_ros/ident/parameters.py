"""What the identifier knows about each parameter besides its unit: neutral value, bounds, scale.

- ``neutral``: the value at which the effect does nothing (drag 0, eta 1, effectiveness 1, ...).
  Candidate effects start there, and "significantly different from neutral" is what makes an effect present.
- ``bounds``: the physically meaningful range; fits are constrained to it (a negative drag coefficient is
  not a drag, so it is not reported as one).
- ``scale``: the size of a parameter that matters, from the airframe: the value that changes the force by
  5 % of the weight in a reference condition (3 m/s horizontal speed, 1 m/s climb, hover rotor speed).
  A parameter whose standard deviation exceeds half of max(|value - neutral|, scale) is *not identifiable*
  from the log: the data cannot tell a relevant value from nothing.
- ``excited_by``: the regime that makes the parameter visible, for the message that says why it is not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe

AIRFRAME = "airframe"
K_F = "k_f_N_s2"
ParameterRef = tuple[str, str]

# Reference condition for the scales (see the module docstring).
REFERENCE_FORCE_SHARE = 0.05
REFERENCE_SPEED_M_S = 3.0
REFERENCE_CLIMB_M_S = 1.0


@dataclass(frozen=True)
class ParameterSpec:
    """Identification facts about one parameter (see the module docstring)."""

    ref: ParameterRef
    neutral: float
    lower: float
    upper: float
    scale: float
    excited_by: str
    discrete: bool = False

    @property
    def name(self) -> str:
        """The parameter's name in effects.md (or ``k_f_N_s2``)."""
        return self.ref[1]


def hover_speed_estimate(airframe: Airframe) -> float:
    """Equal rotor speed [rad/s] whose k_f omega^2 thrust carries the weight."""
    return math.sqrt(airframe.mass_kg * GRAVITY_M_S2 / (airframe.n_rotors * airframe.k_f_N_s2))


def parameter_spec(ref: ParameterRef, airframe: Airframe) -> ParameterSpec:
    """The :class:`ParameterSpec` of ``(effect id, parameter name)`` for this airframe."""
    force = REFERENCE_FORCE_SHARE * airframe.mass_kg * GRAVITY_M_S2
    omega_h = hover_speed_estimate(airframe)
    n = airframe.n_rotors
    v_ref, climb = REFERENCE_SPEED_M_S, REFERENCE_CLIMB_M_S
    effect, name = ref
    inf = math.inf
    table: dict[ParameterRef, tuple[float, float, float, float, str]] = {
        (AIRFRAME, K_F): (0.0, 0.0, inf, airframe.k_f_N_s2, "thrust (any flight)"),
        ("quadratic_drag", "c_x"): (0.0, 0.0, inf, force / v_ref**2, "speed along world x"),
        ("quadratic_drag", "c_y"): (0.0, 0.0, inf, force / v_ref**2, "speed along world y"),
        ("quadratic_drag", "c_z"): (0.0, 0.0, inf, force / climb**2, "vertical speed"),
        ("rotor_drag", "k_h"): (0.0, 0.0, inf, force / (n * omega_h * v_ref), "body-horizontal speed"),
        ("thrust_speed_dependence", "k_f1"): (
            0.0,
            -inf,
            inf,
            REFERENCE_FORCE_SHARE * airframe.k_f_N_s2 / omega_h,
            "a spread of rotor speeds",
        ),
        ("coaxial_loss", "eta_lower"): (
            1.0,
            0.05,
            1.5,
            0.05,
            "upper and lower rotor speeds that differ (yaw)",
        ),
        ("ground_effect", "rotor_radius_m"): (
            0.0,
            0.0,
            2.0,
            airframe.rotor_radius_m,
            "flight within a few rotor radii of the ground",
        ),
        ("inflow_thrust_loss", "k_v"): (0.0, 0.0, inf, force / (n * omega_h * climb), "climb and descent"),
        ("motor_lag", "tau_s"): (0.0, 0.0, 0.5, 0.01, "fast changes of rotor speed"),
        ("mass_offset", "dm_kg"): (
            0.0,
            -0.9 * airframe.mass_kg,
            inf,
            REFERENCE_FORCE_SHARE * airframe.mass_kg,
            "thrust (any flight)",
        ),
        ("constant_force", "f_x"): (0.0, -inf, inf, force, "any flight"),
        ("constant_force", "f_y"): (0.0, -inf, inf, force, "any flight"),
        ("constant_force", "f_z"): (0.0, -inf, inf, force, "any flight"),
        ("actuator_fault", "effectiveness"): (1.0, 0.0, 1.0, 0.05, "flight after the fault"),
        ("actuator_fault", "t_fault_s"): (0.0, 0.0, inf, 1.0, "flight after the fault"),
        ("actuator_fault", "motor"): (0.0, 1.0, float(n), 1.0, "rotor speeds that differ between rotors"),
    }
    if ref not in table:
        raise ValueError(f"no identification facts for parameter {name!r} of {effect!r}")
    neutral, lower, upper, scale, excited_by = table[ref]
    return ParameterSpec(
        ref, neutral, lower, upper, scale, excited_by, discrete=ref == ("actuator_fault", "motor")
    )


def neutral_effect_spec(effect_id: str, airframe: Airframe) -> dict[str, float]:
    """Parameters at which ``effect_id`` does (almost) nothing: the starting point of a candidate.

    ground_effect and motor_lag have no exact neutral value inside their valid range (a radius or a time
    constant of 0 is refused); tiny values stand in: a 1 um rotor and a 0.1 ms lag change nothing measurable.
    """
    from multirotor_ros.model.effects import EFFECTS

    starts = {
        "ground_effect": {"rotor_radius_m": 1e-6},
        "motor_lag": {"tau_s": 1e-4},
        "actuator_fault": {"motor": 1.0, "effectiveness": 1.0, "t_fault_s": 0.0},
    }
    if effect_id in starts:
        return dict(starts[effect_id])
    cls = EFFECTS[effect_id]
    return {name: parameter_spec((effect_id, name), airframe).neutral for name in cls.parameter_units}
