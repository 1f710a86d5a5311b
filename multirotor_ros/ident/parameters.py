"""The parameters the identifier fits, named ``(effect id, name)``, and their facts for one airframe.

Everything about an effect's parameter (unit, neutral value, valid range, the scale that matters, what
excites it, whether it is linear) is its :class:`~multirotor_ros.model.effects.Parameter`, in the effect's
class. The one parameter that belongs to no effect is the airframe's thrust coefficient k_f, fitted under
``("airframe", "k_f_N_s2")``: its facts are here.

A parameter whose standard deviation exceeds half of max(|value - neutral|, scale) is *not identifiable*
from the log: the data cannot tell a relevant value from nothing (:mod:`multirotor_ros.ident.fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import Parameter, ReferenceCondition, effect_class

AIRFRAME = "airframe"
K_F = "k_f_N_s2"
ParameterRef = tuple[str, str]

# The airframe's own thrust coefficient: its scale is itself (the force of a 5 % change is 5 % of the
# thrust, the reference share of the weight).
K_F_PARAMETER = Parameter(K_F, "N s^2/rad^2", 0.0, lambda r: r.k_f_N_s2, "thrust (any flight)", lower=0.0)


def parameter_facts(ref: ParameterRef) -> Parameter:
    """The :class:`Parameter` of ``(effect id, name)`` (or of k_f); errors name the known ones."""
    effect_id, name = ref
    if effect_id == AIRFRAME:
        if name != K_F:
            raise ValueError(f"the only airframe parameter fitted is {K_F}, not {name!r}")
        return K_F_PARAMETER
    return effect_class(effect_id).parameter(name)


@dataclass(frozen=True)
class FittedParameter:
    """A parameter as the identifier fits it on one airframe: its facts with bounds and scale evaluated."""

    ref: ParameterRef
    facts: Parameter
    lower: float
    upper: float
    scale: float

    @classmethod
    def of(cls, ref: ParameterRef, airframe: Airframe) -> FittedParameter:
        """The parameter ``(effect id, name)`` on ``airframe``."""
        facts = parameter_facts(ref)
        reference = ReferenceCondition.of(airframe)
        lower, upper = facts.bounds(reference)
        return cls(ref, facts, lower, upper, facts.scale(reference))

    @property
    def name(self) -> str:
        """The parameter's name in effects.md (or ``k_f_N_s2``)."""
        return self.ref[1]

    def bound_reached(self, value: float) -> str | None:
        """Which bound ``value`` sits on ("lower bound 0.0001"), or None: a bound is no estimate."""
        if self.facts.discrete:
            return None  # a rotor number or a count: its range is no estimate's limit
        tolerance = 1e-6 * self.scale
        for which, bound in (("lower", self.lower), ("upper", self.upper)):
            if math.isfinite(bound) and abs(value - bound) <= tolerance:
                return f"{which} bound {bound:.6g}"
        return None

    @property
    def neutral(self) -> float:
        """The value at which its effect does nothing."""
        return self.facts.neutral
