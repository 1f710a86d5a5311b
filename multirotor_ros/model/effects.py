"""The named physical effects of shared/spec/effects.md as small composable terms.

An effect knows its id, its parameters (names and units fixed by effects.md) and how it changes the
forces on the vehicle. It acts through one or more of these hooks, all batched over a leading axis B
(vehicles, parameter sets, or the samples of a log):

- ``thrust_terms(ctx)``  -> (B, N) thrust added to each rotor's k_f omega^2 [N]
- ``thrust_factor(ctx)`` -> (B, N) factor multiplying each rotor's thrust (applied after the terms)
- ``wrench(ctx, thrust)`` -> (F_W (B, 3) [N] in world ENU, tau_B (B, 3) [N m] in body FLU)
- ``mass_delta_kg``, ``rotor_time_constant_s``: changes to the rigid body and the rotor dynamics.

Parameters not listed in ``nonlinear_parameters`` enter the force linearly (given the measured
acceleration, for ``dm_kg``), so the identifier gets their regressor columns from the model itself
(force at parameter 1 minus force at 0) and solves them by least squares.
Parameters are floats or arrays of shape (B,), so one model steps many parameter sets at once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from multirotor_ros.model.rotation import FloatArray


@dataclass
class EffectContext:
    """What an effect may look at, batched over B: state, rotor speeds and the airframe's geometry."""

    t: FloatArray  # (B,) time [s]
    p_WB_W: FloatArray  # (B, 3) position in world ENU [m]
    v_WB_W: FloatArray  # (B, 3) velocity in world ENU [m/s]
    R_WB: FloatArray  # (B, 3, 3) body FLU -> world ENU
    w_WB_B: FloatArray  # (B, 3) body rate in FLU [rad/s]
    omega: FloatArray  # (B, N) rotor speeds [rad/s]
    rotor_positions_m: FloatArray  # (N, 3) body FLU
    lower_rotor_mask: FloatArray  # (N,) bool
    spin_signs: FloatArray  # (N,) -1 ccw, +1 cw
    k_f_N_s2: float

    @property
    def e_z_W(self) -> FloatArray:
        """Body z axis in world, (B, 3): the thrust direction."""
        return self.R_WB[:, :, 2]


def _column(value: FloatArray) -> FloatArray:
    """A parameter shaped to broadcast against (B, k) arrays: scalar -> (1,), (B,) -> (B, 1)."""
    return np.asarray(value, dtype=float)[..., None]


class Effect:
    """Base class: an effect with named, unit-carrying parameters. Subclasses set the class fields."""

    id: ClassVar[str]
    parameter_units: ClassVar[dict[str, str]]
    rotational: ClassVar[bool] = False
    # Parameters that are not fitted by least squares (discrete, or entering non-linearly).
    nonlinear_parameters: ClassVar[tuple[str, ...]] = ()
    scales_rotor_torque: ClassVar[bool] = False

    def __init__(self, **parameters: Any):
        unknown = sorted(set(parameters) - set(self.parameter_units))
        missing = sorted(set(self.parameter_units) - set(parameters))
        if unknown or missing:
            details = []
            if unknown:
                details.append(f"unknown parameter(s) {', '.join(unknown)}")
            if missing:
                details.append(f"missing parameter(s) {', '.join(missing)}")
            expected = ", ".join(f"{k} [{u}]" for k, u in self.parameter_units.items())
            raise ValueError(f"effect {self.id!r}: {'; '.join(details)} (expects {expected})")
        self.parameters: dict[str, FloatArray] = {}
        for name, value in parameters.items():
            array = np.asarray(value, dtype=float)
            if array.ndim > 1 or not np.all(np.isfinite(array)):
                raise ValueError(f"effect {self.id!r}: parameter {name} must be a finite number or 1-D array")
            self.parameters[name] = array
        self._check_ranges()

    @classmethod
    def description(cls) -> str:
        """What the effect adds, in one line (its docstring)."""
        return (cls.__doc__ or cls.id).strip().splitlines()[0]

    def _check_ranges(self) -> None:
        """Subclasses refuse physically meaningless values here."""

    def _require(self, name: str, ok: bool, rule: str) -> None:
        if not ok:
            raise ValueError(f"effect {self.id!r}: {name} {rule}, got {self.parameters[name]}")

    def __getitem__(self, name: str) -> FloatArray:
        return self.parameters[name]

    def with_parameters(self, **changes: Any) -> Effect:
        """A copy with some parameters replaced."""
        return type(self)(**{**self.parameters, **changes})

    def spec(self) -> dict[str, Any]:
        """Plain-data form, as in an airframe YAML ``effects`` entry."""
        return {"id": self.id, **{k: v.tolist() for k, v in self.parameters.items()}}

    def __repr__(self) -> str:
        values = ", ".join(f"{k}={np.array2string(v, precision=6)}" for k, v in self.parameters.items())
        return f"{self.id}({values})"

    @property
    def linear_parameters(self) -> tuple[str, ...]:
        """Parameters that enter the force linearly."""
        return tuple(k for k in self.parameter_units if k not in self.nonlinear_parameters)

    # Hooks; the defaults mean "does not act this way".
    mass_delta_kg: FloatArray | float = 0.0
    rotor_time_constant_s: FloatArray | None = None

    def thrust_terms(self, ctx: EffectContext) -> FloatArray | None:
        return None

    def thrust_factor(self, ctx: EffectContext) -> FloatArray | None:
        return None

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray] | None:
        return None


class QuadraticDrag(Effect):
    """Fuselage drag -(c_x vx|vx|, c_y vy|vy|, c_z vz|vz|) in world axes (seed 1 eqs. 13-14)."""

    id = "quadratic_drag"
    parameter_units = {"c_x": "N s^2/m^2", "c_y": "N s^2/m^2", "c_z": "N s^2/m^2"}

    def _check_ranges(self) -> None:
        for name in self.parameter_units:
            self._require(name, bool(np.all(self[name] >= 0)), "must be >= 0")

    def _c(self) -> FloatArray:
        return np.stack(np.broadcast_arrays(self["c_x"], self["c_y"], self["c_z"]), axis=-1)

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray]:
        v = ctx.v_WB_W
        return -self._c() * v * np.abs(v), np.zeros_like(v)


class RotorDrag(Effect):
    """Hub force / blade flapping: -k_h omega_sum R P R^T v, P = diag(1, 1, 0)."""

    id = "rotor_drag"
    parameter_units = {"k_h": "N s^2/(m rad)"}

    def _check_ranges(self) -> None:
        self._require("k_h", bool(np.all(self["k_h"] >= 0)), "must be >= 0")

    @staticmethod
    def _unit_force(ctx: EffectContext) -> FloatArray:
        v_B = np.einsum("bji,bj->bi", ctx.R_WB, ctx.v_WB_W)
        v_B[:, 2] = 0.0
        return -ctx.omega.sum(axis=1)[:, None] * np.einsum("bij,bj->bi", ctx.R_WB, v_B)

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray]:
        force = _column(self["k_h"]) * self._unit_force(ctx)
        return force, np.zeros_like(force)


class ThrustSpeedDependence(Effect):
    """Thrust coefficient growing with rotor speed: F_i = (k_f + k_f1 omega_i) omega_i^2 (seed 1 Fig. 4)."""

    id = "thrust_speed_dependence"
    parameter_units = {"k_f1": "N s^3/rad^3"}

    def thrust_terms(self, ctx: EffectContext) -> FloatArray:
        return _column(self["k_f1"]) * ctx.omega**3


class CoaxialLoss(Effect):
    """A lower coaxial rotor gives eta F_i instead of F_i (seed 1 eq. 6, alpha_ij)."""

    id = "coaxial_loss"
    parameter_units = {"eta_lower": "-"}

    def _check_ranges(self) -> None:
        self._require(
            "eta_lower",
            bool(np.all((self["eta_lower"] > 0) & (self["eta_lower"] <= 1.5))),
            "must be in (0, 1.5]",
        )

    def thrust_factor(self, ctx: EffectContext) -> FloatArray:
        return np.where(ctx.lower_rotor_mask, _column(self["eta_lower"]), 1.0) * np.ones_like(ctx.omega)


class GroundEffect(Effect):
    """Thrust x 1/(1 - (R/(4h))^2), h = rotor height above ground (Cheeseman-Bennett)."""

    id = "ground_effect"
    parameter_units = {"rotor_radius_m": "m"}
    nonlinear_parameters = ("rotor_radius_m",)
    # Below h = R/2 the formula leaves its range of validity and diverges at R/4; the factor is held at
    # its h = R/2 value (4/3) so that a vehicle resting on the ground gets a finite, plausible thrust gain.
    MIN_HEIGHT_IN_RADII = 0.5

    def _check_ranges(self) -> None:
        self._require("rotor_radius_m", bool(np.all(self["rotor_radius_m"] > 0)), "must be > 0")

    def thrust_factor(self, ctx: EffectContext) -> FloatArray:
        radius = _column(self["rotor_radius_m"])
        height = ctx.p_WB_W[:, 2:3] + np.einsum("bj,nj->bn", ctx.R_WB[:, 2, :], ctx.rotor_positions_m)
        height = np.maximum(height, self.MIN_HEIGHT_IN_RADII * radius)
        return 1.0 / (1.0 - (radius / (4.0 * height)) ** 2)


class InflowThrustLoss(Effect):
    """F_i = k_f omega_i^2 - k_v omega_i (v . e_z): less thrust in climb, more in descent."""

    id = "inflow_thrust_loss"
    parameter_units = {"k_v": "N s^2/(m rad)"}

    def _climb(self, ctx: EffectContext) -> FloatArray:
        return np.einsum("bi,bi->b", ctx.v_WB_W, ctx.e_z_W)[:, None]

    def thrust_terms(self, ctx: EffectContext) -> FloatArray:
        return -_column(self["k_v"]) * ctx.omega * self._climb(ctx)


class MotorLag(Effect):
    """Rotor speed follows its input through d(omega)/dt = (omega_in - omega)/tau."""

    id = "motor_lag"
    parameter_units = {"tau_s": "s"}
    nonlinear_parameters = ("tau_s",)

    def _check_ranges(self) -> None:
        self._require("tau_s", bool(np.all(self["tau_s"] > 0)), "must be > 0")

    @property
    def rotor_time_constant_s(self) -> FloatArray:  # type: ignore[override]
        return self["tau_s"]


class MassOffset(Effect):
    """The mass is m + dm (payload)."""

    id = "mass_offset"
    parameter_units = {"dm_kg": "kg"}

    @property
    def mass_delta_kg(self) -> FloatArray:  # type: ignore[override]
        return self["dm_kg"]


class ConstantForce(Effect):
    """A steady external force in world axes (steady wind, tether)."""

    id = "constant_force"
    parameter_units = {"f_x": "N", "f_y": "N", "f_z": "N"}

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray]:
        force = np.stack(np.broadcast_arrays(self["f_x"], self["f_y"], self["f_z"]), axis=-1)
        force = np.broadcast_to(force, ctx.v_WB_W.shape).copy()
        return force, np.zeros_like(force)


class ActuatorFault(Effect):
    """From t_fault on, rotor `motor` gives effectiveness x F_i (and x its drag torque)."""

    id = "actuator_fault"
    parameter_units = {"motor": "1..N", "effectiveness": "-", "t_fault_s": "s"}
    nonlinear_parameters = ("motor", "effectiveness", "t_fault_s")
    # A damaged propeller or a weak ESC loses torque with thrust: both scale together.
    scales_rotor_torque = True

    def _check_ranges(self) -> None:
        motor = self["motor"]
        self._require(
            "motor", bool(np.all((motor >= 1) & (motor == np.round(motor)))), "must be a rotor number 1..N"
        )
        eff = self["effectiveness"]
        self._require("effectiveness", bool(np.all((eff >= 0) & (eff <= 1))), "must be in [0, 1]")

    def thrust_factor(self, ctx: EffectContext) -> FloatArray:
        n_rotors = ctx.omega.shape[1]
        if np.any(self["motor"] > n_rotors):
            raise ValueError(
                f"effect 'actuator_fault': motor {self['motor']} but the airframe has {n_rotors} rotors"
            )
        rotor_numbers = np.arange(1, n_rotors + 1)
        active = (rotor_numbers == _column(self["motor"])) & (ctx.t[:, None] >= _column(self["t_fault_s"]))
        return np.where(active, _column(self["effectiveness"]), 1.0)


class Gyroscopic(Effect):
    """Propeller gyroscopic torque -w_B x (J_r sum(s_i omega_i) e_z) (seed 1 eq. 7, J_r Omega_r)."""

    id = "gyroscopic"
    parameter_units = {"j_r": "kg m^2"}
    rotational = True

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray]:
        # A ccw rotor (seen from above) spins about +z: its angular momentum is +J_r omega_i e_z, so the
        # momentum sign is the opposite of the reaction-torque sign.
        momentum_B = np.zeros_like(ctx.w_WB_B)
        momentum_B[:, 2] = self["j_r"] * (-ctx.spin_signs * ctx.omega).sum(axis=1)
        torque = -np.cross(ctx.w_WB_B, momentum_B)
        return np.zeros_like(torque), torque


class CgOffset(Effect):
    """Thrust acts about a centre of gravity moved by (r_x, r_y) in body FLU."""

    id = "cg_offset"
    parameter_units = {"r_x": "m", "r_y": "m"}
    rotational = True

    def wrench(self, ctx: EffectContext, thrust: FloatArray) -> tuple[FloatArray, FloatArray]:
        # Torque about the moved centre: sum (p_i - r) x F_i = sum p_i x F_i - r x (0, 0, T).
        total = thrust.sum(axis=1)
        torque = np.zeros_like(ctx.w_WB_B)
        torque[:, 0] = -self["r_y"] * total
        torque[:, 1] = self["r_x"] * total
        return np.zeros_like(torque), torque


EFFECTS: dict[str, type[Effect]] = {
    cls.id: cls
    for cls in (
        QuadraticDrag,
        RotorDrag,
        ThrustSpeedDependence,
        CoaxialLoss,
        GroundEffect,
        InflowThrustLoss,
        MotorLag,
        MassOffset,
        ConstantForce,
        ActuatorFault,
        Gyroscopic,
        CgOffset,
    )
}
TRANSLATIONAL_EFFECTS = tuple(k for k, cls in EFFECTS.items() if not cls.rotational)


def make_effect(spec: Mapping[str, Any] | Effect) -> Effect:
    """An effect from ``{"id": ..., parameter: value, ...}`` (or an effect, returned as is)."""
    if isinstance(spec, Effect):
        return spec
    if not isinstance(spec, Mapping) or "id" not in spec:
        raise ValueError(f"an effect is written {{id: <name>, <parameter>: <value>, ...}}, got {spec!r}")
    effect_id = spec["id"]
    if effect_id not in EFFECTS:
        raise ValueError(f"unknown effect {effect_id!r}; known: {', '.join(EFFECTS)}")
    return EFFECTS[effect_id](**{k: v for k, v in spec.items() if k != "id"})


def validate_effect_spec(spec: Any, origin: str) -> dict[str, Any]:
    """Check an effect entry of an airframe YAML; errors name ``origin`` (file and list index)."""
    try:
        make_effect(spec)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{origin}: {error}") from error
    return dict(spec)


def parse_effect_list(text: str) -> list[str]:
    """``"quadratic_drag,rotor_drag"`` or ``"none"`` -> list of effect ids (validated)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names in ([], ["none"]):
        return []
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECTS)} or 'none'")
    return names
