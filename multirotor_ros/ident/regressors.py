"""Regressors of the equation-error form m (a + g e_z) = F(theta), built from the model itself.

For a model and a list of parameters ``(effect id, name)`` (``("airframe", "k_f_N_s2")`` is the base
thrust coefficient), :class:`ForceRegressor` returns, for a batch of samples,

    y (B, 3) [N],  Phi (B, 3, P) [N per unit parameter]   with   y = Phi theta   (world ENU)

where y = m (a_W + g e_z) - F(theta_0) + Phi theta_0 and column j is F(theta_0 + delta e_j) - F(theta_0)
divided by delta. For a parameter that enters the force linearly this difference is exact whatever delta,
so the columns need no knowledge of the formulas: any effect written with the hooks of
:mod:`multirotor_ros.model.effects` gets its regressor for free. A parameter that changes the mass
(``dm_kg``) moves to the left side: its column is -(dm/dtheta) (a_W + g e_z).

Two parameters that multiply each other (k_f and eta_lower: a lower rotor gives eta k_f omega^2) are
bilinear: the columns are then the exact partial derivatives at theta_0, y = Phi theta holds to first order,
and the caller iterates (:meth:`ForceRegressor.relinearise`), which :mod:`multirotor_ros.ident.fit` does.

Torque columns come the same way (:meth:`ForceRegressor.wrench_columns`); the actuator-fault search uses
them, because a rotor that lost thrust shows itself most clearly in the torque balance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from multirotor_ros.ident.parameters import AIRFRAME, K_F, ParameterRef, parameter_facts
from multirotor_ros.model.effects import Effect, EffectContext, effect_class
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.model.state import StateBatch


def is_regressed(ref: ParameterRef) -> bool:
    """Whether a parameter is solved by least squares rather than searched.

    k_f, a linear parameter, or one that is linear once the other parameters of its effect are fixed
    (a fault's effectiveness, its rotor and onset chosen).
    """
    facts = parameter_facts(ref)
    return facts.linear or facts.linear_given_others


def _is_thrust_factor(ref: ParameterRef) -> bool:
    """A parameter of an effect that scales the rotors' thrust (a factor makes products with thrust terms)."""
    return ref[0] != AIRFRAME and "rotor_thrust_factor" in effect_class(ref[0]).formulas()


def _is_thrust_term(ref: ParameterRef) -> bool:
    """k_f, or a linear parameter of an effect that adds to the rotors' thrust."""
    if ref[0] == AIRFRAME:
        return True
    return "rotor_thrust_term" in effect_class(ref[0]).formulas() and parameter_facts(ref).linear


def parameter_value(model: Model, ref: ParameterRef) -> float:
    """Current value of a parameter in ``model`` (scalar parameters only)."""
    effect_id, name = ref
    if effect_id == AIRFRAME:
        parameter_facts(ref)  # refuses any airframe parameter but k_f
        return float(model.airframe.k_f_N_s2)
    effect = model.effect(effect_id)
    if effect is None:
        raise ValueError(
            f"the model has no effect {effect_id!r} (it has: {', '.join(model.effect_ids) or 'none'})"
        )
    if name not in effect.parameters:
        raise ValueError(
            f"effect {effect_id!r} has no parameter {name!r}; it has {', '.join(effect.parameters)}"
        )
    value = effect.parameters[name]
    if value.ndim != 0:
        raise ValueError(f"{effect_id}.{name} holds {value.shape[0]} values; identification fits one vehicle")
    return float(value)


def with_values(model: Model, values: Mapping[ParameterRef, float]) -> Model:
    """A copy of ``model`` with some parameters replaced (the effects' range checks apply)."""
    airframe = model.airframe
    if (AIRFRAME, K_F) in values:
        airframe = dataclasses.replace(airframe, k_f_N_s2=float(values[(AIRFRAME, K_F)]))
    effects: list[Effect] = []
    for effect in model.effects:
        changes = {name: float(v) for (eid, name), v in values.items() if eid == effect.id}
        effects.append(effect.with_parameters(**changes) if changes else effect)
    unknown = sorted({eid for eid, _ in values} - set(model.effect_ids) - {AIRFRAME})
    if unknown:
        raise ValueError(f"the model has no effect {', '.join(unknown)}")
    return Model(airframe, effects, model.gravity_m_s2)


def linear_refs(model: Model, effect_ids: Iterable[str], include_k_f: bool = False) -> list[ParameterRef]:
    """The linearly entering parameters of these effects (effects.md order), k_f first if asked.

    A per-rotor parameter is listed once per rotor of the model's airframe (e_1 ... e_N).
    """
    refs: list[ParameterRef] = [(AIRFRAME, K_F)] if include_k_f else []
    for effect_id in effect_ids:
        parameters = effect_class(effect_id).parameter_list(model.n_rotors)
        refs += [(effect_id, parameter.name) for parameter in parameters if parameter.linear]
    return refs


def _difference_step(model: Model, ref: ParameterRef, value: float) -> float:
    """A step delta such that value + delta is inside the effect's valid range (any works when linear)."""
    effect_id, name = ref
    effect = None if effect_id == AIRFRAME else model.effect(effect_id)
    for delta in (1.0, -1.0, 0.5, -0.5, 0.1, -0.1, 0.01, -0.01):
        if effect is None:
            if value + delta > 0:
                return delta
            continue
        try:
            effect.with_parameters(**{name: value + delta})
        except ValueError:
            continue
        return delta
    raise ValueError(f"cannot vary {effect_id}.{name} around {value}: every nearby value is refused")


def is_bilinear(refs: Sequence[ParameterRef]) -> bool:
    """Whether ``refs`` hold a thrust factor (eta_lower, e_i, ...) and a thrust term (k_f, k_f1, k_v, ...)."""
    return any(_is_thrust_factor(r) for r in refs) and any(_is_thrust_term(r) for r in refs)


class ForceRegressor:
    """y, Phi of the equation-error form for a fixed model structure and parameter list (module docstring).

    The model variants (one per parameter) are built once here; each call costs 1 + P ``Model.wrench``
    evaluations on the batch and some array arithmetic.
    """

    def __init__(self, model: Model, refs: Sequence[ParameterRef]):
        # Lists (from YAML or JSON) become tuples: refs are compared and used as keys.
        self.refs: list[ParameterRef] = [(effect_id, name) for effect_id, name in refs]
        duplicated = sorted({r for r in self.refs if self.refs.count(r) > 1})
        if duplicated:
            raise ValueError(f"parameter(s) listed twice: {duplicated}")
        for effect_id, name in self.refs:
            if not is_regressed((effect_id, name)):
                raise ValueError(
                    f"{effect_id}.{name} enters the force non-linearly: it is searched, not regressed "
                    f"(see multirotor_ros.ident.fit)"
                )
        self.names = [name for _, name in self.refs]
        self.bilinear = is_bilinear(self.refs)
        self.model = model
        self.relinearise([parameter_value(model, r) for r in self.refs])

    @property
    def theta0(self) -> FloatArray:
        """The parameter values the regressor is built around (exact for linear parameters anyway)."""
        return self._theta0.copy()

    def relinearise(self, theta: Sequence[float] | FloatArray) -> None:
        """Rebuild the variants around ``theta`` (needed only when :attr:`bilinear`)."""
        theta = np.asarray(theta, dtype=float)
        values = dict(zip(self.refs, theta.tolist(), strict=True))
        self._base = with_values(self.model, values)
        self._variants: list[Model] = []
        self._steps = np.empty(len(self.refs))
        for j, ref in enumerate(self.refs):
            delta = _difference_step(self._base, ref, values[ref])
            self._steps[j] = delta
            self._variants.append(with_values(self._base, {ref: values[ref] + delta}))
        self._mass0 = np.asarray(self._base.mass_kg, dtype=float)
        self._dmass = np.array(
            [
                (np.asarray(v.mass_kg) - self._mass0) / d
                for v, d in zip(self._variants, self._steps, strict=True)
            ]
        )
        self._theta0 = theta

    def wrench_columns(self, ctx: EffectContext) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """F0_W (B, 3), tau0_B (B, 3) at theta_0 and their columns dF (B, 3, P), dtau (B, 3, P).

        The mass columns are not included here (see :meth:`__call__`).
        """
        F0, tau0, _ = self._base.wrench(ctx)
        dF = np.empty(F0.shape + (len(self.refs),))
        dtau = np.empty_like(dF)
        for j, (variant, delta) in enumerate(zip(self._variants, self._steps, strict=True)):
            F, tau, _ = variant.wrench(ctx)
            dF[:, :, j] = (F - F0) / delta
            dtau[:, :, j] = (tau - tau0) / delta
        return F0, tau0, dF, dtau

    def specific_force(self, a_W: FloatArray) -> FloatArray:
        """a_W + g e_z (world): the force per unit mass that thrust and effects must provide."""
        s = np.array(a_W, dtype=float, copy=True)
        s[:, 2] += self.model.gravity_m_s2
        return s

    def parts(self, ctx: EffectContext, a_W: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(a_W + g e_z (B, 3), model force F0 at theta_0 (B, 3), force columns dF (B, 3, P)).

        Kept apart so that a caller can pass the model side (F0, dF) through the same filter as the
        measured acceleration before :meth:`assemble` (the mass columns are measured-side).
        """
        F0, _, dF, _ = self.wrench_columns(ctx)
        return self.specific_force(a_W), F0, dF

    def assemble(self, s: FloatArray, F0: FloatArray, dF: FloatArray) -> tuple[FloatArray, FloatArray]:
        """y, Phi from :meth:`parts` (possibly filtered)."""
        Phi = dF - s[:, :, None] * self._dmass[None, None, :] if np.any(self._dmass != 0) else dF
        return self._mass0 * s - F0 + Phi @ self._theta0, Phi

    def __call__(self, ctx: EffectContext, a_W: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Y (B, 3) [N] and Phi (B, 3, P) with y = Phi theta for measured accelerations ``a_W`` (B, 3)."""
        return self.assemble(*self.parts(ctx, a_W))

    def from_states(self, states: StateBatch) -> tuple[FloatArray, FloatArray]:
        """:meth:`__call__` on states with their measured accelerations ``a_WB_W``."""
        if states.a_WB_W is None:
            raise ValueError("the regressor needs the states' measured accelerations (a_WB_W)")
        return self(self.model.context(states), states.a_WB_W)

    @property
    def mass_columns(self) -> FloatArray:
        """(P,) d(mass)/d(theta_j): nonzero for ``dm_kg``."""
        return self._dmass.copy()
