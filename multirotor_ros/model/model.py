"""A multirotor model: the rigid body of an airframe plus a list of effects.

The model's signature follows python-control: ``derivative(t, x, u)`` with the flat state of
:mod:`multirotor_ros.model.state` and ``u`` the commanded rotor speeds [rad/s], batched over B.
The base model (effects.md): gravity -m g e_z (world), thrust sum k_f omega_i^2 along the body z axis,
the rotor drag torques and the full rigid-body rotation I dw/dt = tau - w x I w (seed 1 eq. 7 without
its small-angle shortcuts). Everything else comes from effects.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe
from multirotor_ros.model.effects import (
    FORMULAS,
    Effect,
    EffectContext,
    evaluate,
    formula_arguments,
    make_effect,
)
from multirotor_ros.model.rotation import FloatArray, quat_multiply
from multirotor_ros.model.rotors import rotor_wrench


class Model:
    """Rigid body + effects; batched over a leading axis B."""

    def __init__(
        self,
        airframe: Airframe,
        effects: Iterable[Effect | Mapping[str, Any]] | None = None,
        gravity_m_s2: float = GRAVITY_M_S2,
    ):
        self.airframe = airframe
        self.effects: tuple[Effect, ...] = tuple(
            make_effect(e) for e in (airframe.effect_specs() if effects is None else effects)
        )
        ids = [e.id for e in self.effects]
        duplicated = sorted({i for i in ids if ids.count(i) > 1})
        if duplicated:
            raise ValueError(
                f"effect(s) listed twice: {', '.join(duplicated)}; merge their parameters into one entry"
            )
        for effect in self.effects:
            effect.check_airframe(airframe)
        self.gravity_m_s2 = gravity_m_s2
        self.mass_kg: FloatArray = np.asarray(
            airframe.mass_kg + sum(self._parameter_formulas("mass_delta_kg"), np.zeros(()))
        )
        self.inertia_kg_m2 = airframe.inertia_kg_m2
        self._inertia_inv = np.linalg.inv(self.inertia_kg_m2)
        lags = self._parameter_formulas("rotor_time_constant_s")
        if len(lags) > 1:
            raise ValueError("two effects set the rotors' time constant; keep one")
        self.rotor_time_constant_s: FloatArray | None = lags[0] if lags else None
        self._acting = {hook: [e for e in self.effects if hook in e.formulas()] for hook in FORMULAS}

    def _parameter_formulas(self, hook: str) -> list[FloatArray]:
        """The values of a formula that reads parameters only, one per effect that has it."""
        return [
            np.asarray(formula(**{name: effect[name] for name in formula_arguments(formula)}), dtype=float)
            for effect in self.effects
            if (formula := effect.formulas().get(hook)) is not None
        ]

    # ------------------------------------------------------------------ structure

    @property
    def n_rotors(self) -> int:
        """Rotor count of the airframe."""
        return self.airframe.n_rotors

    @property
    def state_size(self) -> int:
        """Length of the flat state vector."""
        return S.state_size(self.n_rotors)

    @property
    def effect_ids(self) -> list[str]:
        """Ids of the effects, in order."""
        return [e.id for e in self.effects]

    def effect(self, effect_id: str) -> Effect | None:
        """The effect with this id, if the model has it."""
        return next((e for e in self.effects if e.id == effect_id), None)

    def with_effects(self, effects: Iterable[Effect | Mapping[str, Any]]) -> Model:
        """The same airframe with another effect list."""
        return Model(self.airframe, effects, self.gravity_m_s2)

    def __repr__(self) -> str:
        return f"Model({self.airframe.name}: rigid body + [{', '.join(map(repr, self.effects))}])"

    # ------------------------------------------------------------------ forces

    def context(self, state: S.StateBatch, omega_dot: FloatArray | None = None) -> EffectContext:
        """A batch of states for the effects, with the airframe; ``omega_dot``: rotor accelerations."""
        return EffectContext(
            t=state.t,
            p_WB_W=state.p_WB_W,
            v_WB_W=state.v_WB_W,
            R_WB=state.R_WB,
            w_WB_B=state.w_WB_B,
            omega=state.omega,
            rotor_positions_m=self.airframe.rotor_positions_m,
            lower_rotor_mask=self.airframe.lower_rotor_mask,
            spin_signs=self.airframe.spin_signs,
            k_f_N_s2=self.airframe.k_f_N_s2,
            omega_dot=omega_dot,
        )

    def rotor_loads(self, ctx: EffectContext) -> tuple[FloatArray, FloatArray]:
        """Per-rotor thrust [N] and drag-torque magnitude [N m], each (B, N), every rotor effect included.

        Thrust: (k_f omega^2 + terms) x factors; drag torque: (k_t omega^2 + terms) x the factors that scale
        the rotor torque too (a damaged propeller loses both).
        """
        omega_squared = ctx.omega**2
        thrust = self.airframe.k_f_N_s2 * omega_squared
        for effect in self._acting["rotor_thrust_term"]:
            thrust = thrust + evaluate(effect, "rotor_thrust_term", ctx)
        drag_torque = self.airframe.k_t_N_m_s2 * omega_squared
        for effect in self._acting["rotor_drag_torque_term"]:
            drag_torque = drag_torque + evaluate(effect, "rotor_drag_torque_term", ctx)
        for effect in self._acting["rotor_thrust_factor"]:
            factor = evaluate(effect, "rotor_thrust_factor", ctx)
            thrust = thrust * factor
            if effect.scales_rotor_torque:
                drag_torque = drag_torque * factor
        return thrust, drag_torque

    def wrench(self, ctx: EffectContext) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Force in world (gravity excluded) [N], torque in body [N m], per-rotor thrust [N]."""
        thrust, drag_torque = self.rotor_loads(ctx)
        rotors = rotor_wrench(self.airframe, thrust, drag_torque)
        total = rotors[:, 0]
        F_W = total[:, None] * ctx.e_z_W
        tau_B = rotors[:, 1:]
        batch = (total.shape[0],)
        for effect in self._acting["force_W"]:
            components = evaluate(effect, "force_W", ctx, total_thrust=total)
            F_W = F_W + np.stack([np.broadcast_to(c, batch) for c in components], axis=1)
        for effect in self._acting["torque_B"]:
            components = evaluate(effect, "torque_B", ctx, total_thrust=total)
            tau_B = tau_B + np.stack([np.broadcast_to(c, batch) for c in components], axis=1)
        return F_W, tau_B, thrust

    def accelerations(self, ctx: EffectContext) -> tuple[FloatArray, FloatArray]:
        """Linear acceleration in world [m/s^2] (gravity included) and angular acceleration in body."""
        F_W, tau_B, _ = self.wrench(ctx)
        a_W = F_W / self.mass_kg[..., None]
        a_W[:, 2] -= self.gravity_m_s2
        w = ctx.w_WB_B
        gyro = np.cross(w, w @ self.inertia_kg_m2.T)
        return a_W, (tau_B - gyro) @ self._inertia_inv.T

    # ------------------------------------------------------------------ dynamics

    def check_command(self, u: ArrayLike, batch: int) -> FloatArray:
        """Rotor-speed commands as (B, N); raises ValueError naming the vehicle and rotor if not finite."""
        command = np.asarray(u, dtype=float)
        if command.shape != (batch, self.n_rotors):  # broadcast_to costs more than the rest: only if needed
            if command.shape[-1:] != (self.n_rotors,):
                raise ValueError(
                    f"rotor command has {command.shape[-1:]} entries, "
                    f"{self.airframe.name} has {self.n_rotors} rotors"
                )
            command = np.broadcast_to(command, (batch, self.n_rotors))
        if not np.isfinite(command).all():
            vehicle, rotor = np.argwhere(~np.isfinite(command))[0]
            raise ValueError(
                f"rotor command is not finite: vehicle {vehicle}, "
                f"rotor_{rotor + 1} = {command[vehicle, rotor]}"
            )
        return command

    def effective_rotor_speeds(self, x: FloatArray, u: FloatArray) -> FloatArray:
        """The speeds that make thrust: the lagged rotor state with motor_lag, else the command."""
        return x[:, S.ROTORS_START :] if self.rotor_time_constant_s is not None else u

    def derivative(self, t: ArrayLike, x: FloatArray, u: FloatArray) -> FloatArray:
        """dx/dt of the flat state (B, 13 + N) for rotor-speed inputs u (B, N) or (N,)."""
        u = np.broadcast_to(np.asarray(u, dtype=float), (x.shape[0], self.n_rotors))
        omega = self.effective_rotor_speeds(x, u)
        omega_dot = self.rotor_accelerations(omega, u)
        q = x[:, S.QUATERNION]
        ctx = self.context(S.StateBatch.from_flat(t, x, omega), omega_dot)
        a_W, w_dot_B = self.accelerations(ctx)
        dx = np.empty_like(x)
        dx[:, S.POSITION] = x[:, S.VELOCITY]
        dx[:, S.VELOCITY] = a_W
        w_quat = np.zeros_like(q)
        w_quat[:, 1:] = x[:, S.BODY_RATE]
        dx[:, S.QUATERNION] = 0.5 * quat_multiply(q, w_quat)
        dx[:, S.BODY_RATE] = w_dot_B
        dx[:, S.ROTORS_START :] = 0.0 if omega_dot is None else omega_dot
        return dx

    def rotor_accelerations(self, omega: FloatArray, u: FloatArray) -> FloatArray | None:
        """d(omega)/dt (B, N) with motor lag; None without: the rotors turn at the held command."""
        if self.rotor_time_constant_s is None:
            return None
        return (u - omega) / self.rotor_time_constant_s[..., None]

    def post_step(self, x: FloatArray, command: FloatArray) -> None:
        """After an integration step: unit quaternions, algebraic rotor speeds when there is no motor lag."""
        q = x[:, S.QUATERNION]
        x[:, S.QUATERNION] = q / np.linalg.norm(q, axis=1, keepdims=True)
        if self.rotor_time_constant_s is None:
            x[:, S.ROTORS_START :] = command

    def mechanical_energy(self, x: FloatArray) -> FloatArray:
        """Kinetic + potential energy [J] of each vehicle: the Hamiltonian of seed 2 (eq. 5)."""
        v = x[:, S.VELOCITY]
        w = x[:, S.BODY_RATE]
        kinetic = 0.5 * self.mass_kg * np.sum(v * v, axis=1) + 0.5 * np.einsum(
            "bi,ij,bj->b", w, self.inertia_kg_m2, w
        )
        return kinetic + self.mass_kg * self.gravity_m_s2 * x[:, 2]

    def hover_speed_rad_s(self, height_m: float = 10.0) -> float:
        """Equal rotor speed that holds the vehicle still and level at ``height_m`` (first parameter set)."""
        x = S.make_state(self.n_rotors, position_m=(0.0, 0.0, height_m))

        def vertical_acceleration(speed: float) -> float:
            omega = np.full((1, self.n_rotors), speed)
            ctx = self.context(S.StateBatch.from_flat(1e9, x, omega))
            a_W, _ = self.accelerations(ctx)
            return float(a_W[0, 2])

        top = self.airframe.rotor_speed_max_rad_s
        if vertical_acceleration(top) < 0:
            raise ValueError(
                f"{self.airframe.name} cannot hover: full speed {top:g} rad/s gives less thrust than weight"
            )
        return float(brentq(vertical_acceleration, 0.0, top, xtol=1e-9))
