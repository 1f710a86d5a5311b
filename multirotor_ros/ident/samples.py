"""A flight log made ready for identification: every sample's state, inputs and usability.

:func:`load_samples` reads a flight-log CSV (or takes a :class:`FlightLog`), checks it against the
airframe, and returns :class:`FlightSamples`: world position, velocity and acceleration, attitude, body
rates, rotor speeds, a mask of the samples that may be fitted, and notes/warnings a person reads.

- Missing motion groups are derived by :func:`multirotor_ros.io.derive.derive_motion` (Savitzky–Golay
  differentiation). A filtered derivative is not the true acceleration but a smoothed one, so the model's
  output must go through the same filter before it is compared: :class:`MeasurementChain` integrates the
  model's acceleration as many times as the log's acceleration was differentiated and applies the same
  differentiating filter. Without that the fit would chase the filter's smoothing.
- Samples are excluded (and counted in a warning) when a needed value is not measured, within half a
  filter window of a gap in time, or while the vehicle may touch the ground (the ground's reaction force
  is in no model): a ``landed`` column when the log has one, rotors too slow to carry the weight while
  the vehicle does not move, or rotors less than 2 cm above the ground.
- A log whose thrust (airframe k_f and the logged rotor speeds) is far from what the measured motion
  needs does not belong to this airframe, or has its rotor speeds in another unit: :class:`LogMismatch`.

:func:`lag_filter` is the motor_lag effect on logged speeds (effects.md): exact discretisation of
d(omega)/dt = (omega_log - omega)/tau with the logged speed interpolated linearly between samples.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.signal import lfilter, savgol_filter

from multirotor_ros.ident.settings import FitSettings
from multirotor_ros.io.derive import SavitzkyGolay, derive_motion, rotor_speeds_with_note
from multirotor_ros.io.flight_log import FlightLog, FlightLogError, read_flight_log
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe
from multirotor_ros.model.effects import EffectContext, hover_speed_estimate
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray, euler_rates_matrix, euler_to_matrix
from multirotor_ros.model.state import StateBatch


class LogMismatch(ValueError):
    """The log cannot be of this airframe (or its rotor speeds are not in rad/s); the message says why."""


class NotEnoughData(ValueError):
    """Too few usable samples for what was asked; the message says what is missing."""


@dataclass(frozen=True)
class MeasurementChain:
    """How the log's acceleration was obtained, applied to model outputs (module docstring).

    ``order`` 0: acceleration measured, the chain is the identity; 1: derivative of velocity; 2: second
    derivative of position, with the Savitzky–Golay filter ``flt`` on the uniform grid of spacing ``dt``.
    """

    order: int
    flt: SavitzkyGolay
    dt: float

    @property
    def half_window(self) -> int:
        """Samples at each end of a segment where the filter is not the one applied to the log."""
        return 0 if self.order == 0 else self.flt.window_samples(self.dt) // 2

    def describe(self) -> str:
        """One line for reports."""
        if self.order == 0:
            return "acceleration measured in the log; model accelerations compared as they are"
        source = "velocity" if self.order == 1 else "position"
        window = self.flt.window_samples(self.dt)
        return (
            f"acceleration differentiated from the log's {source}; model accelerations pass through the same "
            f"Savitzky-Golay filter (window {window} samples = {window * self.dt:.3g} s, order "
            f"{self.flt.polyorder})"
        )

    def apply(self, t: FloatArray, values: FloatArray, segments: list[tuple[int, int]]) -> FloatArray:
        """The chain on ``values`` (T, ...) sampled at ``t``, segment by segment; NaN outside segments."""
        if self.order == 0 or values.size == 0:
            return values
        out = np.full(values.shape, np.nan)
        window = self.flt.window_samples(self.dt)
        flat = values.reshape(values.shape[0], -1)
        out_flat = out.reshape(values.shape[0], -1)
        for start, stop in segments:
            if stop - start < window:
                continue
            ts = t[start:stop]
            x = flat[start:stop]
            for _ in range(self.order):
                x = cumulative_trapezoid(x, ts, axis=0, initial=0.0)
            grid = ts[0] + self.dt * np.arange(int(np.floor((ts[-1] - ts[0]) / self.dt + 1e-9)) + 1)
            uniform = grid.size == ts.size and np.allclose(grid, ts, rtol=0.0, atol=1e-6 * self.dt)
            if not uniform:
                x = np.column_stack([np.interp(grid, ts, x[:, i]) for i in range(x.shape[1])])
            d = savgol_filter(
                x, window, self.flt.polyorder, deriv=self.order, delta=self.dt, axis=0, mode="interp"
            )
            if not uniform:
                d = np.column_stack([np.interp(ts, grid, d[:, i]) for i in range(d.shape[1])])
            out_flat[start:stop] = d
        return out


@dataclass
class FlightSamples:
    """One log as arrays over its T rows (world ENU, body FLU, SI), with the usable-sample mask."""

    t: FloatArray  # (T,) [s]
    p_WB_W: FloatArray  # (T, 3) [m]
    v_WB_W: FloatArray  # (T, 3) [m/s]
    a_W: FloatArray  # (T, 3) [m/s^2], gravity not included
    euler: FloatArray  # (T, 3) roll, pitch, yaw [rad]
    R_WB: FloatArray  # (T, 3, 3)
    w_WB_B: FloatArray  # (T, 3) [rad/s]
    w_dot_B: FloatArray  # (T, 3) [rad/s^2] (differentiated; NaN where unknown)
    omega: FloatArray  # (T, N) logged rotor speeds [rad/s]
    valid: BoolArray  # (T,) usable for fitting
    segments: list[tuple[int, int]]  # [start, stop) index ranges without gaps or unusable inputs
    chain: MeasurementChain
    rate_chain: MeasurementChain  # how w_dot_B was obtained (from body rates or Euler angles)
    height_known: bool  # z is a measured height above the ground (ground effect can be seen)
    position_measured: bool
    source: str = "<log>"
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    # Columns (T, 3, K) of nuisance parameters fitted alongside every model (see accelerometer_bias_columns).
    nuisance: FloatArray | None = None
    nuisance_names: tuple[str, ...] = ()
    # [m/s^2] Standard deviation of the IMU's constant bias per body axis (the airframe's sensors section,
    # its datasheet's initial bias); 0 when the acceleration is not measured. An axis not fitted as a
    # nuisance (body z always) biases the fit by an unknown amount of this size: the standard deviations
    # include it (multirotor_ros.ident.fit.bias_sensitivity).
    accelerometer_bias_std_m_s2: float = 0.0
    # [s] How often the rotor commands change (the log's controller_rate_hz; its sample interval when it
    # does not say): a logged command is a sample of a staircase whose steps the log does not time.
    # 0: timed exactly (no uncertainty added).
    rotor_command_period_s: float = 0.0
    # The thresholds the log was prepared with; its fits use them too.
    settings: FitSettings = field(default_factory=FitSettings)
    # Regression designs by model, filled by multirotor_ros.ident.fit.build_design.
    design_cache: dict[tuple, Any] = field(default_factory=dict, repr=False)

    @property
    def n_rotors(self) -> int:
        """Rotor count."""
        return int(self.omega.shape[1])

    @property
    def dt(self) -> float:
        """Median sample interval [s]."""
        return float(np.median(np.diff(self.t))) if self.t.size > 1 else math.nan

    @property
    def duration_s(self) -> float:
        """Time covered by usable samples [s] (their count times the median interval)."""
        return float(np.count_nonzero(self.valid) * self.dt)

    def states(self, rows: BoolArray | slice | None = None) -> StateBatch:
        """The samples (all, or ``rows``) as states with their logged rotor speeds and accelerations."""
        index = slice(None) if rows is None else rows
        return StateBatch(
            self.t[index],
            self.p_WB_W[index],
            self.v_WB_W[index],
            self.R_WB[index],
            self.w_WB_B[index],
            self.omega[index],
            self.a_W[index],
        )

    def thrust_speeds(self, model: Model) -> FloatArray:
        """(T, N) rotor speeds that make thrust in ``model``.

        The logged ones, lagged by the model's rotor time constant when it has one (motor_lag: the log
        holds the speeds the ESCs were asked for).
        """
        tau_s = model.rotor_time_constant_s
        return self.omega if tau_s is None else lag_filter(self.t, self.omega, float(tau_s), self.segments)

    def model_context(self, model: Model) -> EffectContext:
        """``model``'s effect context over every sample, with the rotor speeds that make its thrust."""
        return model.context(self.states().with_omega(self.thrust_speeds(model)))

    def through_chain(self, values: FloatArray) -> FloatArray:
        """Model outputs (T, ...) as the log would show them (see :class:`MeasurementChain`)."""
        return self.chain.apply(self.t, values, self.segments)

    def estimate_accelerometer_bias(self, mass_kg: float) -> None:
        """Fit a constant accelerometer bias along body x and y as a nuisance in every later fit.

        An IMU's bias of a few mg (seed 1's 3DM-GX3: +-2 mg) is a force of m * bias that a slow flight's
        drag cannot be told from unless it is modelled: a measured a_W = a + R b makes m (a_W + g e_z) =
        F + m R b. Body z is left out: there the bias is nearly collinear with thrust (it changes k_f, a
        mass or a vertical force by bias/g, 0.2 % for 2 mg); its uncertainty enters the standard
        deviations instead (:meth:`unfitted_bias_axes`). Only for measured accelerations (a
        differentiated position has no such bias).
        """
        if self.chain.order != 0:
            return
        self.nuisance = mass_kg * self.R_WB[:, :, :2]
        self.nuisance_names = ("accelerometer_bias_x_m_s2", "accelerometer_bias_y_m_s2")
        self.design_cache.clear()

    def unfitted_bias_axes(self) -> list[int]:
        """The body axes (0 x, 1 y, 2 z) along which an accelerometer bias may be and is not fitted."""
        if self.chain.order != 0 or self.accelerometer_bias_std_m_s2 == 0:
            return []
        return [2] if self.nuisance is not None else [0, 1, 2]


def concatenate_samples(parts: Sequence[FlightSamples]) -> FlightSamples:
    """Several logs of one vehicle as one set of samples, fitted together.

    Each log keeps its own segments (nothing is bridged or filtered across logs: later logs' times are
    shifted to follow the previous one after a gap), its own accelerometer bias (the nuisance columns
    are block-diagonal, named after their log), and its notes and warnings, prefixed by its name.
    Raises ValueError when the logs' motion was measured differently (one chain serves them all).
    """
    if not parts:
        raise ValueError("no logs to identify from")
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    for part in parts[1:]:
        if part.chain.order != first.chain.order or part.chain.half_window != first.chain.half_window:
            raise ValueError(
                f"{part.source}: {part.chain.describe()}, but {first.source}: {first.chain.describe()}; "
                "logs fitted together need the same acceleration source: identify them separately"
            )
    offsets, t_parts, segments = [], [], []
    start_t, start_row = 0.0, 0
    for part in parts:
        gap = 10.0 * part.dt if np.isfinite(part.dt) else 1.0
        shift = start_t - part.t[0]
        t_parts.append(part.t + shift)
        segments += [(a + start_row, b + start_row) for a, b in part.segments]
        offsets.append(start_row)
        start_t = t_parts[-1][-1] + gap
        start_row += part.t.size
    nuisance, names = None, []
    if any(part.nuisance is not None for part in parts):
        widths = [0 if part.nuisance is None else part.nuisance.shape[2] for part in parts]
        nuisance = np.zeros((start_row, 3, sum(widths)))
        column = 0
        for part, offset, width in zip(parts, offsets, widths, strict=True):
            if part.nuisance is not None:
                nuisance[offset : offset + part.t.size, :, column : column + width] = part.nuisance
                names += [f"{name} ({Path(part.source).name})" for name in part.nuisance_names]
            column += width

    def joined(attribute: str) -> np.ndarray:
        return np.concatenate([getattr(part, attribute) for part in parts], axis=0)

    def labelled(attribute: str) -> list[str]:
        return [f"{Path(part.source).name}: {line}" for part in parts for line in getattr(part, attribute)]

    return FlightSamples(
        t=np.concatenate(t_parts),
        p_WB_W=joined("p_WB_W"),
        v_WB_W=joined("v_WB_W"),
        a_W=joined("a_W"),
        euler=joined("euler"),
        R_WB=joined("R_WB"),
        w_WB_B=joined("w_WB_B"),
        w_dot_B=joined("w_dot_B"),
        omega=joined("omega"),
        valid=joined("valid"),
        segments=segments,
        chain=first.chain,
        rate_chain=first.rate_chain,
        height_known=all(part.height_known for part in parts),
        position_measured=all(part.position_measured for part in parts),
        source=" + ".join(Path(part.source).name for part in parts),
        notes=labelled("notes"),
        warnings=labelled("warnings"),
        nuisance=nuisance,
        nuisance_names=tuple(names),
        # One bias shared by the logs (each had its own, whose effects may partly cancel; not counted on).
        accelerometer_bias_std_m_s2=max(part.accelerometer_bias_std_m_s2 for part in parts),
        rotor_command_period_s=max(part.rotor_command_period_s for part in parts),
        settings=first.settings,
    )


def lag_filter(
    t: FloatArray, omega: FloatArray, tau_s: float, segments: list[tuple[int, int]] | None = None
) -> FloatArray:
    """Omega (T, N) through d(w)/dt = (omega - w)/tau; w starts at omega.

    Exact discretisation for the logged speed interpolated linearly between samples (first-order hold):
    w[k+1] = a w[k] + (1 - a) omega[k] + c (omega[k+1] - omega[k]), a = exp(-h/tau), c = 1 - (tau/h)(1 - a).
    Unlike a zero-order hold it tends to w = omega as tau -> 0, not to a one-sample delay, so "no lag" is
    the limit of the family. Each segment restarts from its first logged speed (nothing is known across a
    gap).
    """
    if not tau_s > 0:
        raise ValueError(f"motor_lag tau_s must be > 0, got {tau_s}")
    omega = np.asarray(omega, dtype=float)
    out = np.full(omega.shape, np.nan)
    for start, stop in segments or [(0, omega.shape[0])]:
        seg = omega[start:stop]
        if seg.shape[0] == 0:
            continue
        h = np.diff(t[start:stop])
        a = np.exp(-h / tau_s)
        c = 1.0 - (tau_s / h) * (1.0 - a)
        if h.size and np.allclose(h, h[0], rtol=1e-6, atol=0.0):
            a0, c0 = float(a[0]), float(c[0])
            # w[k] - a w[k-1] = c omega[k] + (1 - a - c) omega[k-1], started at w[0] = omega[0].
            lagged = lfilter([c0, 1.0 - a0 - c0], [1.0, -a0], seg, axis=0, zi=(1.0 - c0) * seg[:1])[0]
        else:
            lagged = np.empty_like(seg)
            lagged[0] = seg[0]
            for k in range(h.size):
                lagged[k + 1] = a[k] * lagged[k] + (1.0 - a[k]) * seg[k] + c[k] * (seg[k + 1] - seg[k])
        out[start:stop] = lagged
    return out


def _segments(mask: BoolArray, t: FloatArray, dt: float, gap_factor: float) -> list[tuple[int, int]]:
    """Maximal runs of True in ``mask`` without a time gap (a step above ``gap_factor`` dt) inside."""
    breaks = np.zeros(mask.size, dtype=bool)
    breaks[1:] = np.diff(t) > gap_factor * dt
    segments = []
    start = None
    for i, ok in enumerate(mask):
        if ok and (start is None or breaks[i]):
            if start is not None:
                segments.append((start, i))
            start = i
        elif not ok and start is not None:
            segments.append((start, i))
            start = None
    if start is not None:
        segments.append((start, mask.size))
    return segments


def _smooth_derivative(
    t: FloatArray, values: FloatArray, segments: list[tuple[int, int]], flt: SavitzkyGolay, dt: float
) -> FloatArray:
    """Savitzky–Golay first derivative per segment (NaN elsewhere); assumes near-uniform sampling."""
    out = np.full(values.shape, np.nan)
    window = flt.window_samples(dt)
    for start, stop in segments:
        if stop - start >= window:
            out[start:stop] = savgol_filter(
                values[start:stop], window, flt.polyorder, deriv=1, delta=dt, axis=0
            )
    return out


def _describe_rows(t: FloatArray, rows: BoolArray, limit: int = 3) -> str:
    """'t = 1.2-3.4 s, 5.0-5.1 s, ...' for a boolean row mask."""
    idx = np.flatnonzero(rows)
    if idx.size == 0:
        return "none"
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    parts = [f"{t[r[0]]:.2f}-{t[r[-1]]:.2f} s" for r in runs[:limit]]
    more = f" and {len(runs) - limit} more" if len(runs) > limit else ""
    return "t = " + ", ".join(parts) + more


def load_samples(
    log: FlightLog | str | Path,
    airframe: Airframe,
    filter: SavitzkyGolay | None = None,  # noqa: A002 - the name derive_motion uses
    check_thrust: bool = True,
    settings: FitSettings | None = None,
) -> FlightSamples:
    """Read (if a path) and prepare a log for identification with ``airframe`` (module docstring).

    Four stages: read and check the log against the airframe, derive the motion it lacks, mark the
    samples that may be fitted, and check that its thrust is of this airframe; each adds its notes.
    """
    settings = settings or FitSettings()
    flt = filter or SavitzkyGolay()
    flight, source, read_warnings = _read_log(log, airframe, settings)
    motion = _derive_motion(flight, airframe, flt, settings)
    usable = _mark_usable(flight, airframe, motion, settings)
    n_valid = int(np.count_nonzero(usable.valid))
    if n_valid < settings.min_usable_samples:
        raise NotEnoughData(
            f"{source}: only {n_valid} usable samples (of {flight.t.size}); identification needs at least "
            f"{settings.min_usable_samples} samples in flight with attitude, rotor speeds and motion measured"
        )
    thrust_notes, thrust_warnings = (
        _check_thrust(airframe, motion, usable.valid, source, settings) if check_thrust else ([], [])
    )
    return FlightSamples(
        t=flight.t,
        p_WB_W=np.where(np.isfinite(motion.p_WB_W), motion.p_WB_W, 0.0),
        v_WB_W=np.where(np.isfinite(motion.v_WB_W), motion.v_WB_W, 0.0),
        a_W=np.where(np.isfinite(motion.a_W), motion.a_W, 0.0),
        euler=np.where(np.isfinite(motion.euler), motion.euler, 0.0),
        R_WB=motion.R_WB,
        w_WB_B=motion.w_WB_B,
        w_dot_B=motion.w_dot_B,
        omega=np.where(np.isfinite(motion.omega), motion.omega, 0.0),
        valid=usable.valid,
        segments=usable.segments,
        chain=motion.chain,
        rate_chain=motion.rate_chain,
        height_known=motion.height_known,
        position_measured=motion.position_measured,
        source=source,
        notes=motion.notes + usable.notes + thrust_notes + [f"acceleration: {motion.chain.describe()}"],
        warnings=read_warnings + usable.warnings + thrust_warnings,
        accelerometer_bias_std_m_s2=_accelerometer_bias_std(airframe) if motion.chain.order == 0 else 0.0,
        rotor_command_period_s=_rate_period_s(flight, "controller_rate_hz", motion.dt),
        settings=settings,
    )


def _rate_period_s(flight: FlightLog, key: str, default_s: float) -> float:
    """[s] 1 / the rate the log's metadata gives under ``key``, ``default_s`` when it gives none."""
    try:
        period_s = 1.0 / float(flight.metadata[key])
    except (KeyError, ValueError, ZeroDivisionError):
        return default_s
    return period_s if math.isfinite(period_s) and period_s > 0 else default_s


def _accelerometer_bias_std(airframe: Airframe) -> float:
    """[m/s^2] The airframe IMU's initial bias per axis (its sensors section, or the simulator's default)."""
    from multirotor_ros.simulation.sensors import airframe_sensor_config

    return airframe_sensor_config(airframe).accel_bias_initial_m_s2


def _read_log(
    log: FlightLog | str | Path, airframe: Airframe, settings: FitSettings
) -> tuple[FlightLog, str, list[str]]:
    """The log (read if a path) checked against the airframe: (log, its name for messages, warnings)."""
    if isinstance(log, FlightLog):
        log.validate(airframe.n_rotors)
        flight = log
    else:
        flight = read_flight_log(log, airframe.n_rotors)
    source = str(flight.source_path) if flight.source_path else "<log>"
    warnings: list[str] = []
    if flight.n_rotors != airframe.n_rotors:
        raise FlightLogError(
            f"the log has {flight.n_rotors} rotors, {airframe.name} has {airframe.n_rotors}",
            flight.source_path,
            column="omega_1",
        )
    named = flight.metadata.get("airframe")
    if named and named not in (airframe.name, Path(str(airframe.source_path or "")).stem):
        warnings.append(f"the log says '# airframe: {named}' but it is analysed as {airframe.name}")
    t = flight.t
    if t.size < 3:
        raise NotEnoughData(
            f"{source}: {t.size} samples; identification needs at least {settings.min_usable_samples}"
        )
    for wrong_unit in (_attitude_in_degrees(flight), _acceleration_in_g(flight)):
        if wrong_unit is not None:
            raise LogMismatch(f"{source}: {wrong_unit}")
    dt = float(np.median(np.diff(t)))
    gaps = np.flatnonzero(np.diff(t) > settings.gap_factor * dt)
    if gaps.size:
        listed = ", ".join(f"{t[g]:.3f}-{t[g + 1]:.3f} s" for g in gaps[:5])
        warnings.append(
            f"{gaps.size} gap(s) in time longer than {settings.gap_factor:g} sample intervals ({listed}"
            f"{', ...' if gaps.size > 5 else ''}): nothing is derived or integrated across them"
        )
    return flight, source, warnings


# Below this share of the weight, the rotors' thrust cannot be flight (idle, or stopped).
IDLE_THRUST_SHARE = 0.1
# ZYX Euler angles in radians: roll within +-pi, pitch within +-pi/2 (yaw is not bounded: a log may
# unwrap it); a little more for rounding.
EULER_BOUNDS_RAD = {"roll": math.pi, "pitch": math.pi / 2}
EULER_BOUND_MARGIN_RAD = 0.01
# Roll and pitch change about as fast as p and q say in radians, 180/pi = 57.3 times as fast in degrees;
# a log is taken for degrees within this factor of 57.3, when the two go together (correlation at least
# this, over at least this many sample pairs: the rotation is signal, not sensor noise). The same
# factor and evidence serve accelerations in g against the velocity's rate of change (1/9.81).
DEGREE_RATIO_SPREAD = 1.5
DEGREE_RATIO_MIN_CORRELATION = 0.5
DEGREE_RATIO_MIN_PAIRS = 20


def _acceleration_in_g(flight: FlightLog) -> str | None:
    """Why the log's accelerations are plainly in g (flight_log.md gives m/s^2), or None.

    Evidence: with velocity logged too, the acceleration is about 1/9.81 of the velocity's rate of
    change (least squares over the samples, the two correlated: the motion is signal, not noise).
    """
    if not (flight.has_group("acceleration") and flight.has_group("velocity")) or flight.t.size < 3:
        return None
    rate = np.gradient(flight.group("velocity"), flight.t, axis=0).ravel()
    logged = flight.group("acceleration").ravel()
    usable = np.isfinite(rate) & np.isfinite(logged)
    rate, logged = rate[usable], logged[usable]
    if rate.size < DEGREE_RATIO_MIN_PAIRS or np.ptp(rate) == 0 or np.ptp(logged) == 0:
        return None
    if not np.corrcoef(rate, logged)[0, 1] >= DEGREE_RATIO_MIN_CORRELATION:
        return None
    ratio = float(np.dot(logged, rate) / np.dot(rate, rate))
    if not 1.0 / (GRAVITY_M_S2 * DEGREE_RATIO_SPREAD) <= ratio <= DEGREE_RATIO_SPREAD / GRAVITY_M_S2:
        return None
    return (
        f"columns ax, ay, az are {ratio:.3f} times the rate of change of vx, vy, vz (least squares over "
        f"{rate.size} values; 1 if both were SI, 1/9.81 = 0.102 for accelerations in g): the accelerations "
        "look logged in g; the flight log gives m/s^2 (multiply g by 9.80665)"
    )


def _attitude_in_degrees(flight: FlightLog) -> str | None:
    """Why the log's attitude is plainly in degrees (flight_log.md gives radians), or None.

    Evidence: a roll or pitch that no ZYX angle in radians can be; or, with p and q logged, roll and
    pitch changing about 57.3 times as fast as the body rates say.
    """
    advice = "the flight log gives roll, pitch, yaw in radians (multiply degrees by pi/180)"
    for name, bound in EULER_BOUNDS_RAD.items():
        angle = flight.column(name)
        with np.errstate(invalid="ignore"):
            beyond = np.flatnonzero(np.abs(angle) > bound + EULER_BOUND_MARGIN_RAD)
        if beyond.size:
            k = int(beyond[0])
            return (
                f"column {name} is {angle[k]:.6g} at t = {flight.t[k]:.6g} s, which no ZYX {name} in radians "
                f"can be (at most {bound:.4f} in magnitude): the attitude looks logged in degrees; {advice}"
            )
    if not all(name in flight.columns for name in ("p", "q")):
        return None
    dt = np.diff(flight.t)
    changes, rotations = [], []
    for angle_name, rate_name in (("roll", "p"), ("pitch", "q")):
        changes.append(np.diff(flight.column(angle_name)))
        rate_values = flight.column(rate_name)
        rotations.append(0.5 * (rate_values[1:] + rate_values[:-1]) * dt)
    change, rotation = np.concatenate(changes), np.concatenate(rotations)
    usable = np.isfinite(change) & np.isfinite(rotation)
    change, rotation = change[usable], rotation[usable]
    if change.size < DEGREE_RATIO_MIN_PAIRS or np.ptp(rotation) == 0 or np.ptp(change) == 0:
        return None
    if not np.corrcoef(change, rotation)[0, 1] >= DEGREE_RATIO_MIN_CORRELATION:
        return None  # too little rotation against the noise to tell
    ratio = float(np.dot(change, rotation) / np.dot(rotation, rotation))
    per_degree = 180.0 / math.pi
    if not per_degree / DEGREE_RATIO_SPREAD <= ratio <= per_degree * DEGREE_RATIO_SPREAD:
        return None
    return (
        f"columns roll and pitch change {ratio:.1f} times as fast as the body rates p and q say (least "
        f"squares over {change.size} sample pairs; 1 if both were radians, 57.3 for degrees against rad/s): "
        f"the attitude looks logged in degrees; {advice}"
    )


@dataclass
class _Motion:
    """Everything the log gives or lets derive of the motion, NaN where unknown, with how it was had."""

    dt: float  # median sample interval [s]
    p_WB_W: FloatArray
    v_WB_W: FloatArray
    a_W: FloatArray
    euler: FloatArray
    R_WB: FloatArray
    w_WB_B: FloatArray  # 0 where unknown
    w_dot_B: FloatArray
    omega: FloatArray
    inputs_known: BoolArray  # (T,) attitude, rotor speeds, position and velocity all finite
    chain: MeasurementChain
    rate_chain: MeasurementChain
    height_known: bool
    position_measured: bool
    notes: list[str]


def _derive_motion(
    flight: FlightLog, airframe: Airframe, flt: SavitzkyGolay, settings: FitSettings
) -> _Motion:
    """Position, velocity, acceleration, attitude, body rates and their derivative, rotor speeds."""
    t = flight.t
    dt = float(np.median(np.diff(t)))
    motion = derive_motion(flight, flt)
    notes = [f"{group}: {note}" for group, note in motion.notes.items()]
    omega, omega_note = rotor_speeds_with_note(flight, airframe.motor_map)
    notes.append(f"rotor speeds: {omega_note}")
    euler = flight.euler()
    order = 0 if flight.has_group("acceleration") else (1 if flight.has_group("velocity") else 2)
    position_measured = flight.has_group("position")
    p = np.array(motion.position, dtype=float)
    height_known = position_measured
    if not position_measured and "range" in flight.columns and np.any(np.isfinite(flight.columns["range"])):
        # A downward range sensor measures the height that ground effect depends on; x, y stay integrated.
        p[:, 2] = flight.columns["range"]
        height_known = True
        notes.append("height: the range column stands in for z (no position measured)")
    elif not position_measured:
        notes.append(
            "height: not measured (position integrated from velocity drifts): ground_effect cannot be seen"
        )

    inputs_known = np.all(np.isfinite(euler), axis=1) & np.all(np.isfinite(omega), axis=1)
    inputs_known &= np.all(np.isfinite(motion.velocity), axis=1) & np.all(np.isfinite(p), axis=1)
    rates_cols = ("p", "q", "r")
    if all(c in flight.columns for c in rates_cols) and np.any(
        np.all(np.isfinite(np.column_stack([flight.columns[c] for c in rates_cols])), axis=1)
    ):
        w = np.column_stack([flight.columns[c] for c in rates_cols])
        rate_order = 1
        notes.append("body rates: measured (p, q, r)")
    else:
        # Unwrap yaw before differentiating: a jump of 2 pi is not a rotation.
        euler_unwrapped = euler.copy()
        finite_yaw = np.isfinite(euler[:, 2])
        euler_unwrapped[finite_yaw, 2] = np.unwrap(euler[finite_yaw, 2])
        input_segments = _segments(inputs_known, t, dt, settings.gap_factor)
        euler_dot = _smooth_derivative(t, euler_unwrapped, input_segments, flt, dt)
        w = np.einsum("tij,tj->ti", euler_rates_matrix(euler), euler_dot)
        rate_order = 2
        notes.append("body rates: derived from the Euler angles (Savitzky-Golay derivative)")
    rate_segments = _segments(inputs_known & np.all(np.isfinite(w), axis=1), t, dt, settings.gap_factor)
    w_dot = _smooth_derivative(t, np.where(np.isfinite(w), w, 0.0), rate_segments, flt, dt)
    a_W = np.asarray(motion.acceleration, dtype=float)
    if order == 0:
        a_W = _acceleration_at_row_times(flight, a_W, settings, notes)
    return _Motion(
        dt=dt,
        p_WB_W=p,
        v_WB_W=np.asarray(motion.velocity, dtype=float),
        a_W=a_W,
        euler=euler,
        R_WB=euler_to_matrix(np.where(np.isfinite(euler), euler, 0.0)),
        w_WB_B=np.where(np.isfinite(w), w, 0.0),
        w_dot_B=w_dot,
        omega=omega,
        inputs_known=inputs_known,
        chain=MeasurementChain(order, flt, dt),
        rate_chain=MeasurementChain(rate_order, flt, dt),
        height_known=height_known,
        position_measured=position_measured,
        notes=notes,
    )


def _acceleration_at_row_times(
    flight: FlightLog, a_W: FloatArray, settings: FitSettings, notes: list[str]
) -> FloatArray:
    """The measured acceleration moved to the time of its row, when the log says it was read earlier.

    The simulator's IMU reads the mean acceleration over its last physics step (``physics_rate_hz`` in
    the log's metadata, multirotor_ros.simulation.vehicle): the acceleration half a step before the
    row's attitude, velocity and rotor speeds. Small as it is (1 ms at 500 Hz), a skew between a force
    and its rate of change biases drag, inflow and lag parameters by several of their standard
    deviations. Each sample is interpolated half a step towards the next one.
    """
    delay_s = 0.5 * _rate_period_s(flight, "physics_rate_hz", 0.0)
    if delay_s == 0 or flight.t.size < 2:
        return a_W
    step = np.diff(flight.t)
    # Not across a gap, nor from or to an unmeasured sample.
    joined = (step > 0) & (step <= settings.gap_factor * float(np.median(step)))
    joined &= np.all(np.isfinite(a_W[1:]) & np.isfinite(a_W[:-1]), axis=1)
    share = np.divide(delay_s, step, out=np.zeros_like(step), where=joined)[:, None]
    shifted = a_W.copy()
    shifted[:-1] = np.where(joined[:, None], a_W[:-1] + share * (a_W[1:] - a_W[:-1]), a_W[:-1])
    notes.append(
        f"acceleration: the log's IMU read the mean of its last physics step "
        f"({flight.metadata['physics_rate_hz']} Hz), moved "
        f"{1e3 * delay_s:.3g} ms forward to the time of its row"
    )
    return shifted


@dataclass
class _Usable:
    """The samples that may be fitted, the gap-free segments they form, and what was left out and why."""

    valid: BoolArray  # (T,)
    segments: list[tuple[int, int]]
    notes: list[str]
    warnings: list[str]


def _mark_usable(flight: FlightLog, airframe: Airframe, motion: _Motion, settings: FitSettings) -> _Usable:
    """Samples with every input and the acceleration known, away from segment ends and off the ground."""
    t = flight.t
    valid = motion.inputs_known & np.all(np.isfinite(motion.a_W), axis=1)
    segments = _segments(valid, t, motion.dt, settings.gap_factor)
    # The filter's ends differ from its middle; the model side cannot reproduce what crossed a gap.
    trimmed = np.zeros_like(valid)
    half = motion.chain.half_window
    for start, stop in segments:
        if stop - start > 2 * half:
            trimmed[start + half : stop - half] = True
    edge_rows = valid & ~trimmed
    valid = trimmed
    notes: list[str] = []
    warnings: list[str] = []

    contact, contact_note = _ground_contact(flight, airframe, motion, settings)
    notes += contact_note
    if np.any(contact & valid):
        warnings.append(
            f"{np.count_nonzero(contact & valid)} samples with the vehicle on the ground are not fitted "
            f"(the ground's reaction is in no model): {_describe_rows(t, contact & valid)}"
        )
    valid &= ~contact

    missing_inputs = ~motion.inputs_known
    if np.any(missing_inputs):
        share = np.count_nonzero(missing_inputs) / t.size
        warnings.append(
            f"{np.count_nonzero(missing_inputs)} samples ({100 * share:.1f} %) lack attitude, rotor speeds, "
            "position or "
            f"velocity and are not used: {_describe_rows(t, missing_inputs)}"
        )
    if np.any(edge_rows) and motion.chain.order > 0:
        notes.append(
            f"{np.count_nonzero(edge_rows)} samples within half a filter window of a segment end are not used"
        )
    return _Usable(valid, segments, notes, warnings)


def _ground_contact(
    flight: FlightLog, airframe: Airframe, motion: _Motion, settings: FitSettings
) -> tuple[BoolArray, list[str]]:
    """(T,) bool: samples where the vehicle may touch the ground, and a note on how that was decided."""
    p = motion.p_WB_W
    acceleration = motion.a_W
    thrust_nominal = airframe.k_f_N_s2 * np.sum(
        np.where(np.isfinite(motion.omega), motion.omega, 0.0) ** 2, axis=1
    )
    weight = airframe.mass_kg * GRAVITY_M_S2
    speed = np.linalg.norm(np.where(np.isfinite(motion.v_WB_W), motion.v_WB_W, 0.0), axis=1)
    still = (speed < 0.05) & (np.abs(np.nan_to_num(acceleration[:, 2])) < 0.5)
    if "landed" in flight.columns:
        # The flight stack's own landing detector knows better than any rule of thumb here.
        landed = flight.columns["landed"]
        contact = np.isfinite(landed) & (landed > 0.5)
        return contact, [
            f"ground contact: the log's landed column ({np.count_nonzero(contact)} samples landed)"
        ]
    # Rotors at idle or stopped hold nothing up: the vehicle rests on something, however its estimated
    # motion wanders (an EKF's velocity on the ground is noisy). A log resting at 2-3 cm with motors off,
    # fitted as flight, came out as a dead motor.
    idle = np.all(np.isfinite(motion.omega), axis=1) & (thrust_nominal < IDLE_THRUST_SHARE * weight)
    if motion.height_known:
        rotor_height = p[:, 2:3] + np.einsum("tj,nj->tn", motion.R_WB[:, 2, :], airframe.rotor_positions_m)
        lowest = np.nanmin(p[:, 2]) if np.any(np.isfinite(p[:, 2])) else np.inf
        # Rotors so close to the ground that landing gear may touch, or resting at the lowest height with
        # too little thrust to fly.
        contact = np.nan_to_num(np.min(rotor_height, axis=1), nan=np.inf) < settings.min_rotor_height_m
        contact |= (
            still & (thrust_nominal < 0.85 * weight) & (np.nan_to_num(p[:, 2], nan=np.inf) < lowest + 0.05)
        )
        return contact | idle, []
    # Without height, only thrust far below the weight while still says "on the ground".
    return idle | (still & (thrust_nominal < 0.5 * weight)), []


def _check_thrust(
    airframe: Airframe, motion: _Motion, valid: BoolArray, source: str, settings: FitSettings
) -> tuple[list[str], list[str]]:
    """(notes, warnings) of the thrust check; LogMismatch when the log cannot be of this airframe."""
    needed_specific_force = motion.a_W.copy()
    needed_specific_force[:, 2] += GRAVITY_M_S2
    ratio = _thrust_ratio(airframe, motion.omega, needed_specific_force, valid)
    if not math.isfinite(ratio):
        raise NotEnoughData(
            f"{source}: no usable sample in flight (the needed force is never near the weight)"
        )
    notes = [f"thrust check: k_f sum(omega^2) / (m |a + g|) = {ratio:.3f} (median over usable samples)"]
    low, high = settings.mismatch_ratio
    if not low <= ratio <= high:
        hint = " Wrong airframe, rotor channels or motor map, or rotor speeds not in rad/s."
        if 0.6 * (30 / math.pi) ** 2 <= ratio <= 1.6 * (30 / math.pi) ** 2:
            hint = " The rotor speeds look like rpm: the log must give rad/s (rpm * pi / 30)."
        elif 0.6 * (2 * math.pi) ** -2 <= ratio <= 1.6 * (2 * math.pi) ** -2:
            hint += " (A ratio near 1/(2 pi)^2 = 0.025 is what rev/s instead of rad/s would give.)"
        hover = hover_speed_estimate(airframe)
        median_speed = float(np.median(motion.omega[valid]))
        raise LogMismatch(
            f"{source}: the log does not match airframe {airframe.name}: with k_f = "
            f"{airframe.k_f_N_s2:g} "
            f"N s^2/rad^2 and m = {airframe.mass_kg:g} kg the logged rotor speeds (median "
            f"{median_speed:.0f} "
            f"rad/s; hovering needs about {hover:.0f}) give {ratio:.2f} times the force the measured "
            "motion "
            f"needs (a matching log gives about 1).{hint}"
        )
    warnings = []
    low, high = settings.plausible_ratio
    if not low <= ratio <= high:
        warnings.append(
            f"the airframe's k_f and mass give {ratio:.2f} times the force the measured motion needs: "
            f"k_f, the mass or the motor map of {airframe.name} is off for this vehicle"
        )
    return notes, warnings


def _thrust_ratio(airframe: Airframe, omega: FloatArray, s_needed: FloatArray, valid: BoolArray) -> float:
    needed = airframe.mass_kg * np.linalg.norm(s_needed[valid], axis=1)
    thrust = airframe.k_f_N_s2 * np.sum(omega[valid] ** 2, axis=1)
    flying = needed > 0.3 * airframe.mass_kg * GRAVITY_M_S2
    if not np.any(flying):
        return math.nan
    return float(np.median(thrust[flying] / needed[flying]))


def describe_range(values: FloatArray, unit: str, fmt: Callable[[float], str] = lambda v: f"{v:.3g}") -> str:
    """'a to b unit' (5th to 95th percentile; one number if they agree) for messages about excitation."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return "not measured"
    lo, hi = np.percentile(finite, [5, 95])
    text = fmt(lo) if lo == hi else f"{fmt(lo)} to {fmt(hi)}"
    return f"{text} {unit}".rstrip()
