"""Residuals from the identified model: what the vehicle does that the model does not explain.

A super-twisting observer (:mod:`multirotor_ros.diagnosis.observer`) runs on six channels, the world
velocity v_WB_W and the body rate w_WB_B; the model gives their derivatives from the measured state and
rotor speeds, and the observer's equivalent injection estimates what is missing:

- ``accel_W`` (B, 3): measured minus modelled world force per unit mass [m/s²] (the ``residuals`` topic);
- ``wrench`` (B, 4): the same as a body wrench the rotors could have made, (F_z [N] along body z,
  τ_x, τ_y, τ_z [N m] in body FLU): m e_zᵀ accel_W and I times the angular-acceleration residual.

A rotor i that gives only e_i of its thrust (and drag torque) leaves the wrench residual
-(1 - e_i) s_i, where the rotor's signature s_i = (T_i, T_i y_i, -T_i x_i, σ_i k_t ω_i² f_i) is its own
contribution to the wrench, computed here from the model's per-rotor thrust T_i (all thrust effects
included) and drag torque (σ_i the spin sign, f_i the model's torque factor). The controller
compensates a fault within a fraction of a second, so position and attitude errors vanish; the wrench
residual does not, because the model is fed the speeds the rotors actually turn at.

The observer reaches a step in about ``convergence_time_s``, and what it reports on the way is a
fraction of the fault. ``raw_wrench`` is the same wrench from the last interval alone, unfiltered: the
measured rates' change over the interval minus the model's mean rate over it (for a measured
acceleration, that acceleration minus the model's). It is noisy (a whole stopped rotor is about 20
noise levels in roll and pitch on the shipped airframes, well under one in thrust and yaw) but shows a
step in full from the first interval after it, which is what a test of "this rotor stopped" needs
(:mod:`multirotor_ros.diagnosis.stopped`).

Observer gains are scaled per channel to what one stopped rotor does at hover (its thrust over the
mass, its torques over the inertia), so that every channel converges to a stopped rotor in
``convergence_time_s`` and chatters by the same fraction of that signal.

:class:`InnovationGate` keeps a bad sample from driving the observers. A sample whose rotor speeds are
not the rotors' (plausible, but wrong) gives a model derivative off by a few stopped rotors for one
step; the sliding mode turns that into a transient that lasts about ``convergence_time_s`` and looks
like a fault. Before a sample is used, its :meth:`WrenchResidualGenerator.innovation` (how far the
measurement lies from the observers' one-step prediction, in stopped-rotor units per channel) is
compared with ``sigma`` times the channel's noise level (the median of the last ``memory`` samples'
innovations, scaled to a standard deviation; at least ``floor``). Beyond it, the sample is held back,
at most ``max_held`` in a row. A surprise that lasts longer is the vehicle (a fault, or a manoeuvre
harder than the model follows): the held samples were real, and the caller uses them after all, in
order, so that a fault's first samples are not lost and the observer never steps over a violent
manoeuvre (stepping over 60 ms of one looked like a stopped rotor on loaded machines). A surprise
that ends sooner was bad messages: the held samples are dropped as missing data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from multirotor_ros.diagnosis.observer import SuperTwistingObserver, levant_gains
from multirotor_ros.model.effects import EffectContext
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.model.rotors import rotor_signatures
from multirotor_ros.model.state import StateBatch


@dataclass(frozen=True)
class ObserverSettings:
    """How fast the observer follows a step: a stopped rotor is reached in about ``convergence_time_s``."""

    convergence_time_s: float = 0.15  # [s]
    filter_time_constant_s: float = 0.03  # [s] low-pass on the equivalent injection (sampling chatter)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.convergence_time_s) and self.convergence_time_s > 0):
            raise ValueError(f"convergence_time_s must be > 0, got {self.convergence_time_s}")
        if not (np.isfinite(self.filter_time_constant_s) and self.filter_time_constant_s >= 0):
            raise ValueError(f"filter_time_constant_s must be >= 0, got {self.filter_time_constant_s}")


@dataclass(frozen=True)
class ResidualSample:
    """One sample of residuals for a batch of B vehicles (see the module docstring)."""

    accel_W: FloatArray  # (B, 3) [m/s²] world ENU
    angular_accel_B: FloatArray  # (B, 3) [rad/s²] body FLU
    wrench: FloatArray  # (B, 4) F_z [N], tau_B [N m]
    signatures: FloatArray  # (B, 4, N) each rotor's own wrench contribution
    model_change_wrench: FloatArray | None = None  # (B, 4) residual shift from a model swap at this sample
    # (B, 4) the wrench residual of the last interval alone, unfiltered (module docstring); None at the
    # first sample after a start and at a model swap (no interval with one model)
    raw_wrench: FloatArray | None = None


def stopped_rotor_scales(model: Model) -> tuple[FloatArray, FloatArray]:
    """What one stopped rotor does at hover: (6,) observer channel scale and (4,) wrench scale.

    Observer channels: thrust / mass on each world axis (the thrust direction tilts), then the largest
    single-rotor torque over the inertia about each body axis. Wrench scale: the largest |s_i| per channel.
    """
    airframe = model.airframe
    omega_hover = model.hover_speed_rad_s()
    signature = airframe.allocation * omega_hover**2  # (4, N) at hover
    wrench_scale = np.abs(signature).max(axis=1)
    mass = float(np.atleast_1d(model.mass_kg)[0])
    inertia = np.diag(model.inertia_kg_m2)
    channel_scale = np.concatenate([np.full(3, wrench_scale[0] / mass), wrench_scale[1:] / inertia])
    return channel_scale, wrench_scale


# Median of |x| over the standard deviation of a Gaussian x.
_MEDIAN_ABS_TO_SIGMA = 1.0 / 0.6745


# InnovationGate.judge: within the noise; held back (too surprising); surprising for longer than
# max_held samples (the held ones were the vehicle's).
GateVerdict = Literal["usual", "held", "lasting"]


@dataclass
class InnovationGate:
    """Holds back samples that surprise the observer far beyond its noise (module docstring)."""

    sigma: float = 6.0  # noise levels an innovation may reach
    floor: float = 0.25  # [stopped-rotor units] the gate never closes below this (noise-free data)
    memory: int = 200  # samples whose median innovation is the noise level; none held before memory / 4
    max_held: int = 5  # samples held in a row at most
    # The last ``memory`` sizes, a ring (the median ignores their order): no stacking of a queue per sample.
    _recent: FloatArray | None = field(default=None, repr=False)
    _judged: int = 0
    _held: int = 0

    def judge(self, innovation: FloatArray) -> GateVerdict:
        """What to do with the sample of this (C,) innovation (module docstring)."""
        size = np.abs(innovation)
        if self._recent is None:
            self._recent = np.empty((self.memory, size.shape[0]))
        self._recent[self._judged % self.memory] = size
        self._judged += 1
        known = min(self._judged, self.memory)
        if known < self.memory // 4:
            return "usual"
        noise = _MEDIAN_ABS_TO_SIGMA * np.median(self._recent[:known], axis=0)
        if not np.any(size > np.maximum(self.sigma * noise, self.floor)):
            self._held = 0
            return "usual"
        if self._held < self.max_held:
            self._held += 1
            return "held"
        return "lasting"


class WrenchResidualGenerator:
    """Feeds the observer from measurements and turns its estimate into world and wrench residuals.

    Two ways to measure the translational part: from the velocity (odometry), through the
    super-twisting observer like the body rates; or, when a measured acceleration is given (an IMU's
    specific force rotated to world, gravity removed), directly as a_W - a_model, low-passed with the
    same filter as the observer's estimate. The rotational part always comes from the body rates.
    """

    def __init__(self, model: Model, settings: ObserverSettings | None = None):
        self.settings = settings or ObserverSettings()
        self.channel_scale, self.wrench_scale = stopped_rotor_scales(model)
        lambda_gain, alpha_gain = levant_gains(self.channel_scale / self.settings.convergence_time_s)
        tau = self.settings.filter_time_constant_s
        self.translational = SuperTwistingObserver(lambda_gain[:3], alpha_gain[:3], tau)
        self.rotational = SuperTwistingObserver(lambda_gain[3:], alpha_gain[3:], tau)
        self._measured_accel_residual: FloatArray | None = None
        # The last sample's measured rates and model rates (v_W, w_B, a_model_W, w_dot_model_B), for
        # the raw residual of the next interval.
        self._last_rates: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None
        self._previous_model: Model | None = None
        self._evaluated: tuple[StateBatch, Model, tuple[EffectContext, FloatArray, FloatArray]] | None = None
        self.set_model(model)

    def set_model(self, model: Model) -> None:
        """Use another model (an identified one) from the next :meth:`update` on.

        The observer's estimate of the measured derivative, f + z, must not jump because f changed:
        at the next sample z is shifted by f_old - f_new, and that sample's ``model_change_wrench``
        says by how much the wrench residual moved, so that a detector can move its baseline with it.
        """
        current = getattr(self, "model", None)
        if current is not None and current.n_rotors != model.n_rotors:
            raise ValueError(
                f"the new model has {model.n_rotors} rotors, the observer was built for {current.n_rotors}"
            )
        if current is not None and self._previous_model is None:
            self._previous_model = current
        self.model = model

    def reset(self) -> None:
        """Forget the observer's state (after a gap in the data): the next :meth:`update` starts it again."""
        self.translational.y_hat = None
        self.rotational.y_hat = None
        self._measured_accel_residual = None
        self._last_rates = None

    @property
    def started(self) -> bool:
        """Whether the observer has had a measurement since its start or last reset."""
        return self.rotational.started

    def signatures(self, ctx: EffectContext) -> FloatArray:
        """(B, 4, N) each rotor's own wrench contribution in the model at these states."""
        thrust, drag_torque = self.model.rotor_loads(ctx)
        return rotor_signatures(self.model.airframe, thrust, drag_torque)

    def innovation(self, state: StateBatch, dt_s: float) -> FloatArray | None:
        """(B, 6) the sample's surprise to the observers in stopped-rotor units, None before they start.

        World x, y, z then body x, y, z: the measurement's distance from the one-step prediction (for a
        measured acceleration, from the filtered residual), nothing updated (module docstring).
        """
        if not self.started:
            return None
        _, a_model_W, w_dot_model_B = self._evaluate(state)
        rotational = self.rotational.prediction_error(dt_s, state.w_WB_B, w_dot_model_B)
        if state.a_WB_W is None:
            translational = self.translational.prediction_error(dt_s, state.v_WB_W, a_model_W)
        else:
            assert self._measured_accel_residual is not None  # set with the first measurement
            translational = state.a_WB_W - a_model_W - self._measured_accel_residual
        return np.concatenate([translational, rotational], axis=1) / self.channel_scale

    def update(self, state: StateBatch, dt_s: float) -> ResidualSample:
        """Residuals at a new measurement of B vehicles; ``dt_s`` since the previous one.

        The state's measured acceleration ``a_WB_W`` (world, gravity excluded) is used when given, the
        velocity otherwise.
        """
        ctx, a_model_W, w_dot_model_B = self._evaluate(state)
        model_change = None
        if self._previous_model is not None:
            model_change = self._carry_over(ctx, a_model_W, w_dot_model_B)
            self._last_rates = None
        raw_wrench = self._raw_wrench(ctx, state, dt_s, a_model_W, w_dot_model_B)
        angular_accel_B = self.rotational.update(dt_s, state.w_WB_B, w_dot_model_B)
        if state.a_WB_W is None:
            accel_W = self.translational.update(dt_s, state.v_WB_W, a_model_W)
        else:
            raw = state.a_WB_W - a_model_W
            if self._measured_accel_residual is None or self.settings.filter_time_constant_s == 0:
                self._measured_accel_residual = raw
            else:
                blend = 1.0 - np.exp(-dt_s / self.settings.filter_time_constant_s)
                self._measured_accel_residual = self._measured_accel_residual + blend * (
                    raw - self._measured_accel_residual
                )
            accel_W = self._measured_accel_residual
        return ResidualSample(
            accel_W=accel_W,
            angular_accel_B=angular_accel_B,
            wrench=self._as_wrench(ctx, accel_W, angular_accel_B),
            signatures=self.signatures(ctx),
            model_change_wrench=model_change,
            raw_wrench=raw_wrench,
        )

    def _as_wrench(self, ctx: EffectContext, accel_W: FloatArray, angular_accel_B: FloatArray) -> FloatArray:
        """(B, 4) body wrench of a world acceleration and a body angular acceleration residual."""
        mass = np.broadcast_to(np.asarray(self.model.mass_kg, dtype=float), (accel_W.shape[0],))
        thrust_residual = mass * np.einsum("bi,bi->b", accel_W, ctx.e_z_W)
        return np.concatenate(
            [thrust_residual[:, None], angular_accel_B @ self.model.inertia_kg_m2.T], axis=1
        )

    def _raw_wrench(
        self,
        ctx: EffectContext,
        state: StateBatch,
        dt_s: float,
        a_model_W: FloatArray,
        w_dot_model_B: FloatArray,
    ) -> FloatArray | None:
        """(B, 4) unfiltered wrench residual of the interval ending at ``state`` (module docstring).

        None when there is no previous sample of the same model; this sample's rates are kept for the next.
        """
        last = self._last_rates
        self._last_rates = (state.v_WB_W.copy(), state.w_WB_B.copy(), a_model_W, w_dot_model_B)
        if last is None or not dt_s > 0:
            return None
        last_v_W, last_w_B, last_a_model_W, last_w_dot_model_B = last
        # The model's rate enters as the mean of both ends of the interval, as in the observer.
        angular = (state.w_WB_B - last_w_B) / dt_s - 0.5 * (w_dot_model_B + last_w_dot_model_B)
        if state.a_WB_W is not None:
            translational = state.a_WB_W - a_model_W
        else:
            translational = (state.v_WB_W - last_v_W) / dt_s - 0.5 * (a_model_W + last_a_model_W)
        return self._as_wrench(ctx, translational, angular)

    def _evaluate(self, state: StateBatch) -> tuple[EffectContext, FloatArray, FloatArray]:
        """The model at ``state``: its context and accelerations (world, body).

        The last evaluation is kept: the innovation gate and then the update ask for the same sample,
        and the model is most of a sample's cost.
        """
        kept = self._evaluated
        if kept is not None and kept[0] is state and kept[1] is self.model:
            return kept[2]
        ctx = self.model.context(state)
        evaluated = (ctx, *self.model.accelerations(ctx))
        self._evaluated = (state, self.model, evaluated)
        return evaluated

    def _carry_over(
        self, ctx: EffectContext, a_new_W: FloatArray, w_dot_new_B: FloatArray
    ) -> FloatArray | None:
        """Shift the observers by f_old - f_new at this sample; the (B, 4) wrench of that shift."""
        assert self._previous_model is not None
        a_old_W, w_dot_old_B = self._previous_model.accelerations(ctx)
        self._previous_model = None
        if not self.started:
            return None
        da_W = a_old_W - a_new_W
        dw_B = w_dot_old_B - w_dot_new_B
        for observer, shift in ((self.translational, da_W), (self.rotational, dw_B)):
            if observer.started:
                observer.shift_model(shift)
        if self._measured_accel_residual is not None:
            self._measured_accel_residual = self._measured_accel_residual + da_W
        mass = np.broadcast_to(np.asarray(self.model.mass_kg, dtype=float), (da_W.shape[0],))
        thrust_shift = mass * np.einsum("bi,bi->b", da_W, ctx.e_z_W)
        return np.concatenate([thrust_shift[:, None], dw_B @ self.model.inertia_kg_m2.T], axis=1)
