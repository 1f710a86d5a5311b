"""The named physical effects of shared/spec/effects.md: everything known about an effect, in its class.

An effect is one class. It carries

- its id and its parameters (:class:`Parameter`: name, unit, neutral value, bounds, the scale that matters
  for identification, whether it enters the force linearly, a search grid if it does not);
- its physics, as *formulas*: plain arithmetic functions whose argument names say what they read
  (parameters by name, and the quantities of :data:`VEHICLE_QUANTITIES` and :data:`ROTOR_QUANTITIES`).
  A formula is written once; the numpy :class:`~multirotor_ros.model.model.Model` calls it on arrays
  (batches of vehicles or the samples of a log) and :mod:`multirotor_ros.model.compiled` generates its
  numba kernel from the same functions, called on scalars lane by lane;
- what the rest of the code asks of it: the regime in which it acts and its torque signature (for the
  discrepancy report), what the airframe or the log must have for it to apply, what a log shows of the
  regime that excites each parameter.

Formulas (all optional; a class defines those through which it acts):

- ``rotor_thrust_term(...)``: thrust added to rotor i's k_f omega_i^2 [N];
- ``rotor_drag_torque_term(...)``: drag-torque magnitude added to rotor i's k_t omega_i^2 [N m];
- ``rotor_thrust_factor(...)``: factor on rotor i's thrust (after the terms); with ``scales_rotor_torque``
  also on its drag torque;
- ``force_W(...)``: (f_x, f_y, f_z) added in world ENU [N];
- ``torque_B(...)``: (tau_x, tau_y, tau_z) added in body FLU [N m];
- ``mass_delta_kg(...)``: added to the airframe's mass [kg];
- ``rotor_time_constant_s(...)``: the rotors follow their commands with this first-order lag [s].

Nothing outside this module switches on an effect's id: :data:`EFFECTS` is the registry, and a new effect
is a new class here plus its row in effects.md.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from multirotor_ros.model.rotation import BoolArray, FloatArray

if TYPE_CHECKING:
    from multirotor_ros.model.airframe import Airframe
    from multirotor_ros.model.state import StateBatch

GRAVITY_M_S2 = 9.80665

# What a formula may read besides its parameters. Per vehicle:
VEHICLE_QUANTITIES: dict[str, str] = {
    "t": "time [s]",
    "p_x": "position x, world ENU [m]",
    "p_y": "position y, world ENU [m]",
    "p_z": "position z (height), world ENU [m]",
    "v_x": "velocity x, world ENU [m/s]",
    "v_y": "velocity y, world ENU [m/s]",
    "v_z": "velocity z, world ENU [m/s]",
    **{
        f"r{i}{j}": f"attitude matrix R_WB[{i}, {j}] (body FLU -> world ENU)"
        for i in range(3)
        for j in range(3)
    },
    "w_x": "body rate x, FLU [rad/s]",
    "w_y": "body rate y, FLU [rad/s]",
    "w_z": "body rate z, FLU [rad/s]",
    "climb": "velocity along the thrust axis, v . e_z [m/s]",
    "omega_sum": "sum of the rotor speeds [rad/s]",
    "spin_momentum": "sum of -s_i omega_i: the rotors' angular momentum about body z per unit J_r [rad/s]",
    "spin_momentum_rate": "its time derivative, sum of -s_i d(omega_i)/dt [rad/s^2] (0 without motor lag)",
    "total_thrust": "sum of the rotor thrusts, all thrust effects included [N] (force_W, torque_B only)",
}
# Per rotor i (rotor formulas only):
ROTOR_QUANTITIES: dict[str, str] = {
    "omega": "rotor speed [rad/s]",
    "rotor_number": "i, counted from 1",
    "is_lower": "1 for the lower rotor of a coaxial pair, else 0",
    "rotor_x": "rotor position x, body FLU [m]",
    "rotor_y": "rotor position y, body FLU [m]",
    "rotor_z": "rotor position z, body FLU [m]",
    "spin": "reaction-torque sign about body +z: -1 ccw, +1 cw",
    "rotor_height": "height of the rotor above z = 0, world [m]",
}
FORMULAS = (
    "rotor_thrust_term",
    "rotor_drag_torque_term",
    "rotor_thrust_factor",
    "force_W",
    "torque_B",
    "mass_delta_kg",
    "rotor_time_constant_s",
)
ROTOR_FORMULAS = ("rotor_thrust_term", "rotor_drag_torque_term", "rotor_thrust_factor")
# Quantities whose value changes within an integration step even with the command held.
STATE_QUANTITIES = frozenset(VEHICLE_QUANTITIES) - {"omega_sum", "spin_momentum", "total_thrust"}


@dataclass(frozen=True)
class ReferenceCondition:
    """Where a parameter's size is judged: 5 % of the weight, at 3 m/s, 1 m/s climb and hover speed."""

    force_N: float
    hover_speed_rad_s: float
    n_rotors: int
    mass_kg: float
    k_f_N_s2: float
    k_t_N_m_s2: float
    rotor_radius_m: float
    arm_length_m: float  # mean horizontal distance of the rotors from the body origin
    speed_m_s: float = 3.0
    climb_m_s: float = 1.0
    force_share: float = 0.05

    @classmethod
    def of(cls, airframe: Airframe) -> ReferenceCondition:
        """The reference condition of an airframe."""
        share = cls.force_share
        weight = airframe.mass_kg * GRAVITY_M_S2
        return cls(
            force_N=share * weight,
            hover_speed_rad_s=hover_speed_estimate(airframe),
            n_rotors=airframe.n_rotors,
            mass_kg=airframe.mass_kg,
            k_f_N_s2=airframe.k_f_N_s2,
            k_t_N_m_s2=airframe.k_t_N_m_s2,
            rotor_radius_m=airframe.rotor_radius_m,
            arm_length_m=float(np.mean(np.linalg.norm(airframe.rotor_positions_m[:, :2], axis=1))),
        )


def hover_speed_estimate(airframe: Airframe) -> float:
    """Equal rotor speed [rad/s] whose k_f omega^2 thrust carries the weight."""
    return math.sqrt(airframe.mass_kg * GRAVITY_M_S2 / (airframe.n_rotors * airframe.k_f_N_s2))


@dataclass(frozen=True)
class Parameter:
    """One parameter of an effect: what it means and what the identifier needs to know about it.

    ``neutral``: the value at which the effect does nothing; candidates start there, and "significantly
    different from neutral" is what makes an effect present. ``search_start`` stands in for it where the
    neutral value is outside the valid range (a radius or a time constant of 0).
    ``scale``: the size that matters, from the airframe's :class:`ReferenceCondition`: a parameter whose
    standard deviation exceeds half of max(|value - neutral|, scale) is not identifiable from the log.
    ``linear``: enters the force linearly for fixed values of the model's other parameters (a thrust factor
    times k_f is bilinear: the identifier relinearises); fitted by least squares. Otherwise searched over
    ``search_grid``. ``linear_given_others``: not linear in general, but linear once the effect's other
    parameters are fixed (a fault's effectiveness, once its rotor and onset are chosen).
    ``fit_bounds``: bounds that depend on the airframe, for the fit (the valid range is ``lower``..``upper``).
    """

    name: str
    unit: str
    neutral: float
    scale: Callable[[ReferenceCondition], float]
    excited_by: str
    lower: float = -math.inf
    upper: float = math.inf
    lower_inclusive: bool = True
    linear: bool = True
    linear_given_others: bool = False
    discrete: bool = False
    fit_bounds: Callable[[ReferenceCondition], tuple[float, float]] | None = None
    # A time in the log from which the effect acts: searched over the log's own sample times.
    onset_time: bool = False
    search_grid: tuple[float, ...] = ()
    search_start: float | None = None

    def bounds(self, reference: ReferenceCondition) -> tuple[float, float]:
        """(lower, upper) for a fit on the airframe of ``reference``."""
        return (self.lower, self.upper) if self.fit_bounds is None else self.fit_bounds(reference)

    @property
    def start(self) -> float:
        """Where a search or a fit of this parameter starts: neutral, or what stands in for it."""
        return self.neutral if self.search_start is None else self.search_start

    def check(self, effect_id: str, value: FloatArray) -> None:
        """Refuse a value outside the valid range, naming the effect and the parameter."""
        low_ok = value >= self.lower if self.lower_inclusive else value > self.lower
        if not np.all(low_ok & (value <= self.upper)):
            low = "[" if self.lower_inclusive else "("
            raise ValueError(
                f"effect {effect_id!r}: {self.name} must be in {low}{self.lower:g}, {self.upper:g}], "
                f"got {np.array2string(value, precision=6)}"
            )
        if self.discrete and not np.all(value == np.round(value)):
            raise ValueError(f"effect {effect_id!r}: {self.name} must be a whole number, got {value}")


def _column(value: FloatArray) -> FloatArray:
    """A (B,) parameter shaped to broadcast against (B, N) per-rotor arrays; scalars stay scalars."""
    array = np.asarray(value, dtype=float)
    return array[..., None] if array.ndim == 1 else array


@cache
def formula_arguments(formula: Callable[..., Any]) -> tuple[str, ...]:
    """The argument names of a formula: the parameters and quantities it reads."""
    return tuple(inspect.signature(formula).parameters)


class Effect:
    """Base class: an effect with named, unit-carrying parameters (see the module docstring)."""

    id: ClassVar[str]
    PARAMETERS: ClassVar[tuple[Parameter, ...]] = ()
    # A parameter given once per rotor, named <name>_1 ... <name>_N; its formulas read it as <name>.
    PER_ROTOR_PARAMETER: ClassVar[Parameter | None] = None
    rotational: ClassVar[bool] = False
    scales_rotor_torque: ClassVar[bool] = False
    # Where in a flight the effect shows itself, for the discrepancy report's "fly ..." advice.
    regime: ClassVar[str] = ""
    # What the effect does to the rotors' torque balance (None: nothing distinctive).
    torque_signature: ClassVar[str | None] = None
    # What a log must hold for the effect to be testable ("height": a measured height).
    log_needs: ClassVar[tuple[str, ...]] = ()

    def __init__(self, **parameters: Any):
        expected = {p.name: p for p in self._parameters_given(parameters)}
        unknown = sorted(set(parameters) - set(expected))
        missing = sorted(set(expected) - set(parameters))
        if unknown or missing:
            details = []
            if unknown:
                details.append(f"unknown parameter(s) {', '.join(unknown)}")
            if missing:
                details.append(f"missing parameter(s) {', '.join(missing)}")
            listing = ", ".join(f"{p.name} [{p.unit}]" for p in self.parameter_list(None))
            raise ValueError(f"effect {self.id!r}: {'; '.join(details)} (expects {listing})")
        self.parameters: dict[str, FloatArray] = {}
        for name, parameter in expected.items():
            try:
                array = np.asarray(parameters[name], dtype=float)
            except (TypeError, ValueError):
                raise ValueError(
                    f"effect {self.id!r}: parameter {name} must be a number, got {parameters[name]!r}"
                ) from None
            if array.ndim > 1 or not np.all(np.isfinite(array)):
                raise ValueError(f"effect {self.id!r}: parameter {name} must be a finite number or 1-D array")
            parameter.check(self.id, array)
            self.parameters[name] = array

    # ------------------------------------------------------------------ parameters

    @classmethod
    def parameter_list(cls, n_rotors: int | None) -> tuple[Parameter, ...]:
        """The parameters for ``n_rotors`` rotors (``None``: the per-rotor one listed once as <name>_i)."""
        per_rotor = cls.PER_ROTOR_PARAMETER
        if per_rotor is None:
            return cls.PARAMETERS
        if n_rotors is None:
            return (*cls.PARAMETERS, _renamed(per_rotor, f"{per_rotor.name}_i"))
        return (
            *cls.PARAMETERS,
            *(_renamed(per_rotor, f"{per_rotor.name}_{i}") for i in range(1, n_rotors + 1)),
        )

    @classmethod
    def _parameters_given(cls, given: Mapping[str, Any]) -> tuple[Parameter, ...]:
        """The parameter list implied by the names given (the per-rotor count is read from them)."""
        per_rotor = cls.PER_ROTOR_PARAMETER
        if per_rotor is None:
            return cls.PARAMETERS
        prefix = per_rotor.name + "_"
        numbers = [name[len(prefix) :] for name in given if name.startswith(prefix)]
        count = max((int(n) for n in numbers if n.isdigit()), default=0)
        return cls.parameter_list(max(count, 1))

    @classmethod
    def parameter(cls, name: str) -> Parameter:
        """The :class:`Parameter` called ``name`` (``e_3`` for a per-rotor one)."""
        for parameter in cls.PARAMETERS:
            if parameter.name == name:
                return parameter
        per_rotor = cls.PER_ROTOR_PARAMETER
        if per_rotor is not None and name.startswith(per_rotor.name + "_") and name.split("_")[-1].isdigit():
            return _renamed(per_rotor, name)
        known = ", ".join(p.name for p in cls.parameter_list(None))
        raise ValueError(f"effect {cls.id!r} has no parameter {name!r}; it has {known}")

    @classmethod
    def neutral_parameters(cls, n_rotors: int) -> dict[str, float]:
        """Parameters at which the effect does (almost) nothing: the starting point of a candidate."""
        return {p.name: p.start for p in cls.parameter_list(n_rotors)}

    @classmethod
    def description(cls) -> str:
        """What the effect adds, in one line (its docstring)."""
        return (cls.__doc__ or cls.id).strip().splitlines()[0]

    @classmethod
    def formulas(cls) -> dict[str, Callable[..., Any]]:
        """The formulas this effect defines, by hook name."""
        return {name: getattr(cls, name) for name in FORMULAS if getattr(cls, name, None) is not None}

    @classmethod
    def not_applicable(cls, airframe: Airframe) -> str | None:
        """Why the effect cannot act on this airframe, or None."""
        return None

    def check_airframe(self, airframe: Airframe) -> None:
        """Refuse parameters that do not fit the airframe (a rotor number it does not have, say)."""
        per_rotor = self.PER_ROTOR_PARAMETER
        if per_rotor is not None:
            count = self._per_rotor_count()
            if count != airframe.n_rotors:
                raise ValueError(
                    f"effect {self.id!r}: {count} values of {per_rotor.name}_i, "
                    f"{airframe.name} has {airframe.n_rotors} rotors"
                )

    # ------------------------------------------------------------------ values

    def __getitem__(self, name: str) -> FloatArray:
        return self.parameters[name]

    def per_rotor_values(self) -> FloatArray | None:
        """(N,) or (B, N): the per-rotor parameter's values in rotor order, or None."""
        per_rotor = self.PER_ROTOR_PARAMETER
        if per_rotor is None:
            return None
        columns = [self.parameters[f"{per_rotor.name}_{i}"] for i in range(1, self._per_rotor_count() + 1)]
        return np.stack(np.broadcast_arrays(*columns), axis=-1)

    def _per_rotor_count(self) -> int:
        """How many values of the per-rotor parameter this effect holds (0 without one)."""
        per_rotor = self.PER_ROTOR_PARAMETER
        if per_rotor is None:
            return 0
        return sum(1 for name in self.parameters if name.startswith(per_rotor.name + "_"))

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
        """Names of the parameters that enter the force linearly."""
        return tuple(name for name in self.parameters if type(self).parameter(name).linear)

    # ------------------------------------------------------------------ what a log shows

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        """(what, values over the log, unit): the quantity whose range makes ``name`` visible."""
        return "the number of usable samples", np.array([float(state.size)]), ""


def _renamed(parameter: Parameter, name: str) -> Parameter:
    return Parameter(**{**parameter.__dict__, "name": name})


def _at_least(lower: float) -> dict[str, Any]:
    return {"lower": lower}


# ====================================================================================== translational


class QuadraticDrag(Effect):
    """Fuselage drag -(c_x vx|vx|, c_y vy|vy|, c_z vz|vz|) in world axes (seed 1 eqs. 13-14)."""

    id = "quadratic_drag"
    PARAMETERS = (
        Parameter(
            "c_x", "N s^2/m^2", 0.0, lambda r: r.force_N / r.speed_m_s**2, "speed along world x", lower=0
        ),
        Parameter(
            "c_y", "N s^2/m^2", 0.0, lambda r: r.force_N / r.speed_m_s**2, "speed along world y", lower=0
        ),
        Parameter("c_z", "N s^2/m^2", 0.0, lambda r: r.force_N / r.climb_m_s**2, "vertical speed", lower=0),
    )
    regime = "horizontal and vertical speeds (drag quadratic in speed)"

    @staticmethod
    def force_W(c_x: Any, c_y: Any, c_z: Any, v_x: Any, v_y: Any, v_z: Any) -> tuple[Any, Any, Any]:
        return -c_x * v_x * abs(v_x), -c_y * v_y * abs(v_y), -c_z * v_z * abs(v_z)

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        axis = name[-1]
        return f"|v_{axis}|", np.abs(state.v_WB_W[:, "xyz".index(axis)]), "m/s"


class RotorDrag(Effect):
    """Hub force / blade flapping: -k_h omega_sum R P R^T v, P = diag(1, 1, 0)."""

    id = "rotor_drag"
    PARAMETERS = (
        Parameter(
            "k_h",
            "N s^2/(m rad)",
            0.0,
            lambda r: r.force_N / (r.n_rotors * r.hover_speed_rad_s * r.speed_m_s),
            "body-horizontal speed",
            lower=0,
        ),
    )
    regime = "horizontal speeds at different rotor speeds (drag linear in speed)"

    @staticmethod
    def force_W(
        k_h: Any,
        omega_sum: Any,
        v_x: Any,
        v_y: Any,
        v_z: Any,
        r00: Any,
        r01: Any,
        r10: Any,
        r11: Any,
        r20: Any,
        r21: Any,
    ) -> tuple[Any, Any, Any]:
        # Body-horizontal part of the velocity, R^T v without its z row, turned back into world axes.
        body_x = r00 * v_x + r10 * v_y + r20 * v_z
        body_y = r01 * v_x + r11 * v_y + r21 * v_z
        gain = -k_h * omega_sum
        return (
            gain * (r00 * body_x + r01 * body_y),
            gain * (r10 * body_x + r11 * body_y),
            gain * (r20 * body_x + r21 * body_y),
        )

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        v_B = np.einsum("tji,tj->ti", state.R_WB, state.v_WB_W)
        return "body-horizontal speed", np.linalg.norm(v_B[:, :2], axis=1), "m/s"


class ThrustSpeedDependence(Effect):
    """Thrust coefficient growing with rotor speed: F_i = (k_f + k_f1 omega_i) omega_i^2 (seed 1 Fig. 4)."""

    id = "thrust_speed_dependence"
    PARAMETERS = (
        Parameter(
            "k_f1",
            "N s^3/rad^3",
            0.0,
            lambda r: r.force_share * r.k_f_N_s2 / r.hover_speed_rad_s,
            "a spread of rotor speeds",
        ),
    )
    regime = "rotor speeds (thrust growing faster than omega^2)"
    torque_signature = "a thrust coefficient growing with speed makes fast rotors' torques larger"

    @staticmethod
    def rotor_thrust_term(k_f1: Any, omega: Any) -> Any:
        return k_f1 * omega * omega * omega

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        return "mean rotor speed", state.omega.mean(axis=1), "rad/s"


class CoaxialLoss(Effect):
    """A lower coaxial rotor gives eta F_i instead of F_i (seed 1 eq. 6, alpha_ij)."""

    id = "coaxial_loss"
    PARAMETERS = (
        Parameter(
            "eta_lower",
            "-",
            1.0,
            lambda r: 0.05,
            "upper and lower rotor speeds that differ (yaw)",
            lower=0.05,
            upper=1.5,
        ),
    )
    regime = "changes of the lower rotors' share of the thrust (on an X8, yaw with diagonal tilt)"
    torque_signature = "a weaker lower rotor in every pair scales the roll and pitch torques by (1 + eta)/2"

    @classmethod
    def not_applicable(cls, airframe: Airframe) -> str | None:
        return None if airframe.lower_rotor_mask.any() else f"{airframe.name} has no coaxial rotors"

    @staticmethod
    def rotor_thrust_factor(eta_lower: Any, is_lower: Any) -> Any:
        return 1.0 + (eta_lower - 1.0) * is_lower

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        lower = airframe.lower_rotor_mask
        squares = state.omega**2
        share = squares[:, lower].sum(axis=1) / np.maximum(squares.sum(axis=1), 1e-9)
        return "the lower rotors' share of sum(omega^2)", share, ""


class GroundEffect(Effect):
    """Thrust x 1/(1 - (R/(4h))^2), h = rotor height above ground (Cheeseman-Bennett)."""

    id = "ground_effect"
    PARAMETERS = (
        Parameter(
            "rotor_radius_m",
            "m",
            0.0,
            lambda r: r.rotor_radius_m,
            "flight within a few rotor radii of the ground",
            lower=0.0,
            lower_inclusive=False,
            upper=2.0,
            linear=False,
            search_grid=tuple(np.geomspace(0.01, 1.0, 15)),
            # A 1 um rotor changes nothing measurable: it stands in for "no ground effect".
            search_start=1e-6,
        ),
    )
    regime = "heights within a few rotor radii of the ground"
    torque_signature = "ground effect scales every rotor's thrust, and so the torques"
    log_needs = ("height",)

    @staticmethod
    def rotor_thrust_factor(rotor_radius_m: Any, rotor_height: Any) -> Any:
        # Below h = R/2 the formula leaves its range of validity and diverges at R/4; the factor is held at
        # its h = R/2 value (4/3): a vehicle resting on the ground gets a finite, plausible thrust gain.
        height = np.maximum(rotor_height, 0.5 * rotor_radius_m)
        ratio = rotor_radius_m / (4.0 * height)
        return 1.0 / (1.0 - ratio * ratio)

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        return f"height (rotor radius about {airframe.rotor_radius_m:g} m)", state.p_WB_W[:, 2], "m"


class InflowThrustLoss(Effect):
    """F_i = k_f omega_i^2 - k_v omega_i (v . e_z): less thrust in climb, more in descent."""

    id = "inflow_thrust_loss"
    PARAMETERS = (
        Parameter(
            "k_v",
            "N s^2/(m rad)",
            0.0,
            lambda r: r.force_N / (r.n_rotors * r.hover_speed_rad_s * r.climb_m_s),
            "climb and descent",
            lower=0,
        ),
    )
    regime = "climbs and descents"
    torque_signature = "inflow changes each rotor's thrust with its speed, and so the torques"

    @staticmethod
    def rotor_thrust_term(k_v: Any, omega: Any, climb: Any) -> Any:
        return -k_v * omega * climb

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        return "climb speed along the thrust axis", np.einsum("ti,ti->t", state.v_WB_W, state.e_z_W), "m/s"


class MotorLag(Effect):
    """Rotor speed follows its input through d(omega)/dt = (omega_in - omega)/tau."""

    id = "motor_lag"
    PARAMETERS = (
        Parameter(
            "tau_s",
            "s",
            0.0,
            lambda r: 0.01,
            "fast changes of rotor speed",
            lower=0.0,
            lower_inclusive=False,
            upper=0.5,
            linear=False,
            search_grid=tuple(np.geomspace(0.002, 0.3, 15)),
            # A 0.1 ms lag changes nothing measurable: it stands in for "no lag".
            search_start=1e-4,
        ),
    )
    regime = "fast changes of rotor speed"
    torque_signature = "lagging rotors delay the torques too"

    @staticmethod
    def rotor_time_constant_s(tau_s: Any) -> Any:
        return tau_s

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        dt = float(np.median(np.diff(state.t))) if state.size > 1 else math.nan
        return (
            "the rate of change of the mean rotor speed",
            np.abs(np.diff(state.omega.mean(axis=1))) / dt,
            "rad/s^2",
        )


class MassOffset(Effect):
    """The mass is m + dm (payload)."""

    id = "mass_offset"
    PARAMETERS = (
        Parameter(
            "dm_kg",
            "kg",
            0.0,
            lambda r: r.force_share * r.mass_kg,
            "thrust (any flight)",
            # A payload can be negative (a lighter battery), but the vehicle keeps most of its mass.
            fit_bounds=lambda r: (-0.9 * r.mass_kg, math.inf),
        ),
    )
    regime = "accelerations (a mass scales the whole force need)"
    torque_signature = "a mass offset leaves the rotors' torques as modelled"

    @staticmethod
    def mass_delta_kg(dm_kg: Any) -> Any:
        return dm_kg

    def check_airframe(self, airframe: Airframe) -> None:
        if np.any(airframe.mass_kg + self["dm_kg"] <= 0):
            raise ValueError(
                f"effect 'mass_offset': dm_kg = {self['dm_kg']} makes the mass of {airframe.name} "
                f"({airframe.mass_kg:g} kg) non-positive"
            )


class ConstantForce(Effect):
    """A steady external force in world axes (steady wind, tether)."""

    id = "constant_force"
    PARAMETERS = tuple(Parameter(f"f_{axis}", "N", 0.0, lambda r: r.force_N, "any flight") for axis in "xyz")
    regime = "headings and attitudes (a steady force does not turn with the vehicle)"
    torque_signature = "a steady force leaves the rotors' torques as modelled"

    @staticmethod
    def force_W(f_x: Any, f_y: Any, f_z: Any) -> tuple[Any, Any, Any]:
        return f_x, f_y, f_z


class RotorEffectiveness(Effect):
    """Rotor i gives e_i F_i (and e_i its drag torque) for the whole log: a damaged or dirty propeller."""

    id = "rotor_effectiveness"
    PER_ROTOR_PARAMETER = Parameter(
        "e", "-", 1.0, lambda r: 0.05, "rotor speeds that differ between rotors", lower=0.0, upper=1.5
    )
    scales_rotor_torque = True
    regime = "the balance of the rotors (each rotor's share of thrust and torque)"
    torque_signature = "a weak rotor leaves a torque the others must balance, from take-off on"

    @staticmethod
    def rotor_thrust_factor(e: Any) -> Any:
        return e

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        rotor = int(name.split("_")[-1]) - 1
        return f"rotor {rotor + 1}'s speed", state.omega[:, rotor], "rad/s"


class ActuatorFault(Effect):
    """From t_fault on, rotor `motor` gives effectiveness x F_i (and x its drag torque)."""

    id = "actuator_fault"
    PARAMETERS = (
        Parameter(
            "motor",
            "1..N",
            0.0,
            lambda r: 1.0,
            "rotor speeds that differ between rotors",
            lower=1.0,
            linear=False,
            discrete=True,
            fit_bounds=lambda r: (1.0, float(r.n_rotors)),
            search_start=1.0,
        ),
        Parameter(
            "effectiveness",
            "-",
            1.0,
            lambda r: 0.05,
            "flight after the fault",
            lower=0.0,
            upper=1.0,
            linear=False,
            linear_given_others=True,
        ),
        Parameter(
            "t_fault_s",
            "s",
            0.0,
            lambda r: 1.0,
            "flight after the fault",
            lower=0.0,
            linear=False,
            onset_time=True,
        ),
    )
    # A damaged propeller or a weak ESC loses torque with thrust: both scale together.
    scales_rotor_torque = True
    regime = "flight before and after the fault with manoeuvres"
    torque_signature = "a weak rotor leaves a torque the others must balance"

    @staticmethod
    def rotor_thrust_factor(motor: Any, effectiveness: Any, t_fault_s: Any, rotor_number: Any, t: Any) -> Any:
        active = (motor == rotor_number) & (t >= t_fault_s)
        return 1.0 + (effectiveness - 1.0) * active

    def check_airframe(self, airframe: Airframe) -> None:
        if np.any(self["motor"] > airframe.n_rotors):
            raise ValueError(
                f"effect 'actuator_fault': motor {self['motor']} but {airframe.name} "
                f"has {airframe.n_rotors} rotors"
            )

    def excitation(self, name: str, state: StateBatch, airframe: Airframe) -> tuple[str, FloatArray, str]:
        onset = float(self["t_fault_s"])
        dt = float(np.median(np.diff(state.t))) if state.size > 1 else 0.0
        after = np.count_nonzero(state.t >= onset) * dt
        return f"usable flight after the onset t = {onset:.2f} s", np.array([after]), "s"


# ====================================================================================== rotational


class Gyroscopic(Effect):
    """Propeller gyroscope -w_B x h_r - dh_r/dt, h_r = J_r sum(-s_i omega_i) e_z (seed 1 eq. 7)."""

    id = "gyroscopic"
    # Scale: the inertia of a 10-inch propeller (about 1e-5 kg m^2), the size that seed 1's X8 would have.
    PARAMETERS = (
        Parameter("j_r", "kg m^2", 0.0, lambda r: 1e-5, "body rates while the rotors turn", lower=0),
    )
    rotational = True
    regime = "roll and pitch rates at high rotor speed, and changes of the rotor-speed balance (yaw)"

    @staticmethod
    def torque_B(
        j_r: Any, w_x: Any, w_y: Any, spin_momentum: Any, spin_momentum_rate: Any
    ) -> tuple[Any, Any, Any]:
        # A ccw rotor (spin -1) turns about +z: its angular momentum is +J_r omega_i e_z, hence the minus in
        # spin_momentum. The body feels -w x h_r, and -dh_r/dt about z when the rotors speed up or slow down
        # (seed 1 eq. 7's J_r dOmega_r/dt yaw term).
        momentum = j_r * spin_momentum
        return -w_y * momentum, w_x * momentum, -j_r * spin_momentum_rate


def _cg_scale(reference: ReferenceCondition) -> float:
    # An offset whose torque is the reference share of the weight acting at the arm's length.
    return reference.force_share * reference.arm_length_m


class YawDragTorque(Effect):
    """Rotor drag torques differ from the airframe's k_t: Q_i = (k_t + dk_t) omega_i^2 (the yaw balance)."""

    id = "yaw_drag_torque"
    PARAMETERS = (
        Parameter(
            "dk_t",
            "N m s^2/rad^2",
            0.0,
            # A change of the yaw torque by the reference share of one rotor's hover drag torque.
            lambda r: r.force_share * r.k_t_N_m_s2,
            "rotor speeds that differ between cw and ccw rotors (yaw manoeuvres, yaw trim)",
        ),
    )
    rotational = True
    regime = "yaw manoeuvres and the yaw trim (cw against ccw rotor speeds)"
    torque_signature = "a larger drag torque makes the cw and ccw rotors' speeds differ more for the same yaw"

    @staticmethod
    def rotor_drag_torque_term(dk_t: Any, omega: Any) -> Any:
        return dk_t * omega * omega


class CgOffset(Effect):
    """Thrust acts about a centre of gravity moved by (r_x, r_y) in body FLU."""

    id = "cg_offset"
    PARAMETERS = (
        Parameter("r_x", "m", 0.0, _cg_scale, "rotor thrusts that differ front to back"),
        Parameter("r_y", "m", 0.0, _cg_scale, "rotor thrusts that differ left to right"),
    )
    rotational = True
    regime = "the balance of the rotors (front against back, left against right)"
    torque_signature = "a moved centre of gravity needs a steady torque from the rotors, at any speed"

    @staticmethod
    def torque_B(r_x: Any, r_y: Any, total_thrust: Any) -> tuple[Any, Any, Any]:
        # Torque about the moved centre: sum (p_i - r) x F_i = sum p_i x F_i - r x (0, 0, T).
        return -r_y * total_thrust, r_x * total_thrust, 0.0 * total_thrust


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
        RotorEffectiveness,
        ActuatorFault,
        Gyroscopic,
        CgOffset,
        YawDragTorque,
    )
}
TRANSLATIONAL_EFFECTS = tuple(k for k, cls in EFFECTS.items() if not cls.rotational)


def check_formulas(cls: type[Effect]) -> None:
    """Every name a formula reads must be a parameter or a known quantity: a typo fails at import."""
    parameters = {p.name for p in cls.PARAMETERS}
    if cls.PER_ROTOR_PARAMETER is not None:
        parameters.add(cls.PER_ROTOR_PARAMETER.name)
    for hook, formula in cls.formulas().items():
        allowed = parameters | set(VEHICLE_QUANTITIES)
        if hook in ROTOR_FORMULAS:
            allowed |= set(ROTOR_QUANTITIES)
        if hook in ("mass_delta_kg", "rotor_time_constant_s"):
            allowed = parameters
        unknown = [name for name in formula_arguments(formula) if name not in allowed]
        if unknown:
            raise TypeError(f"effect {cls.id!r}: {hook} reads unknown name(s) {', '.join(unknown)}")


for _cls in EFFECTS.values():
    check_formulas(_cls)


def effect_class(effect_id: str) -> type[Effect]:
    """The class of a named effect; the error lists the known ones."""
    if effect_id not in EFFECTS:
        raise ValueError(f"unknown effect {effect_id!r}; known: {', '.join(EFFECTS)}")
    return EFFECTS[effect_id]


def make_effect(spec: Mapping[str, Any] | Effect) -> Effect:
    """An effect from ``{"id": ..., parameter: value, ...}`` (or an effect, returned as is)."""
    if isinstance(spec, Effect):
        return spec
    if not isinstance(spec, Mapping) or "id" not in spec:
        raise ValueError(f"an effect is written {{id: <name>, <parameter>: <value>, ...}}, got {spec!r}")
    return effect_class(spec["id"])(**{k: v for k, v in spec.items() if k != "id"})


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


@dataclass
class EffectContext:
    """A batch of states with the airframe geometry the formulas read (see :func:`rotor_quantities`)."""

    t: FloatArray  # (B,) time [s]
    p_WB_W: FloatArray  # (B, 3) position in world ENU [m]
    v_WB_W: FloatArray  # (B, 3) velocity in world ENU [m/s]
    R_WB: FloatArray  # (B, 3, 3) body FLU -> world ENU
    w_WB_B: FloatArray  # (B, 3) body rate in FLU [rad/s]
    omega: FloatArray  # (B, N) rotor speeds that make thrust [rad/s]
    rotor_positions_m: FloatArray  # (N, 3) body FLU
    lower_rotor_mask: BoolArray  # (N,)
    spin_signs: FloatArray  # (N,) -1 ccw, +1 cw
    k_f_N_s2: float
    omega_dot: FloatArray | None = None  # (B, N) rotor accelerations [rad/s^2]; None: the rotors hold speed

    @property
    def e_z_W(self) -> FloatArray:
        """Body z axis in world, (B, 3): the thrust direction."""
        return self.R_WB[:, :, 2]

    def vehicle_quantity(self, name: str) -> FloatArray:
        """A quantity of :data:`VEHICLE_QUANTITIES` over the batch, (B,)."""
        if name == "t":
            return self.t
        if name in ("p_x", "p_y", "p_z"):
            return self.p_WB_W[:, "xyz".index(name[-1])]
        if name in ("v_x", "v_y", "v_z"):
            return self.v_WB_W[:, "xyz".index(name[-1])]
        if name in ("w_x", "w_y", "w_z"):
            return self.w_WB_B[:, "xyz".index(name[-1])]
        if len(name) == 3 and name[0] == "r" and name[1:].isdigit():
            return self.R_WB[:, int(name[1]), int(name[2])]
        if name == "climb":
            return np.einsum("bi,bi->b", self.v_WB_W, self.e_z_W)
        if name == "omega_sum":
            return self.omega.sum(axis=1)
        if name == "spin_momentum":
            return -(self.omega @ self.spin_signs)
        if name == "spin_momentum_rate":
            return np.zeros(self.t.shape) if self.omega_dot is None else -(self.omega_dot @ self.spin_signs)
        raise KeyError(name)

    def rotor_quantity(self, name: str) -> FloatArray:
        """A quantity of :data:`ROTOR_QUANTITIES`, shaped (B, N) or (N,) (vehicle ones as (B, 1))."""
        if name == "omega":
            return self.omega
        if name == "rotor_number":
            return np.arange(1.0, self.omega.shape[1] + 1)
        if name == "is_lower":
            return self.lower_rotor_mask.astype(float)
        if name in ("rotor_x", "rotor_y", "rotor_z"):
            return self.rotor_positions_m[:, "xyz".index(name[-1])]
        if name == "spin":
            return self.spin_signs
        if name == "rotor_height":
            return self.p_WB_W[:, 2:3] + np.einsum("bj,nj->bn", self.R_WB[:, 2, :], self.rotor_positions_m)
        return self.vehicle_quantity(name)[:, None]


def evaluate(effect: Effect, hook: str, ctx: EffectContext, **known: FloatArray) -> Any:
    """Call ``effect``'s formula ``hook`` on the batch: parameters and quantities bound by name.

    ``known``: quantities already computed by the caller (``total_thrust``).
    """
    formula = getattr(type(effect), hook)
    per_rotor = hook in ROTOR_FORMULAS
    per_rotor_name = effect.PER_ROTOR_PARAMETER.name if effect.PER_ROTOR_PARAMETER is not None else None
    arguments: dict[str, FloatArray | None] = {}
    for name in formula_arguments(formula):
        if name in effect.parameters:
            value = effect.parameters[name]
            arguments[name] = _column(value) if per_rotor else value
        elif name == per_rotor_name:
            arguments[name] = effect.per_rotor_values()
        elif name in known:
            arguments[name] = known[name]
        elif per_rotor:
            arguments[name] = ctx.rotor_quantity(name)
        else:
            arguments[name] = ctx.vehicle_quantity(name)
    return formula(**arguments)
