"""Bench-test identification of seed 2 (§3, eqs. 20-30): inertia from geometry, thrust and speed tests.

Seed 2 identifies its hexarotor without flying it: the inertia is computed from measured component
sizes (eqs. 20-22, Table 1), the thrust constant from a static thrust test (a rotor on a scale, the
command stepped from 0 to 180 "program speed" units, eqs. 23-29) and the motor map from a tachometer
speed test (Fig. 8). This module reproduces the paper's arithmetic and also does it properly:

- :func:`inertia_from_geometry` is eqs. 20-22 as printed. With Table 1 they give I_xx = 0.021968 and
  I_yy = 0.021621 kg m², Table 2's values, and I_zz = 0.044390 kg m², which is neither Table 2's 0.04366
  nor Table 3's 0.04904 (the paper gives no reason for either). Eqs. 20-22 are the quadrotor formula they
  cite (Derawi 2014): they count the motors and rotors of four arms (2 m l² about x and y, 4 m l² about z).
  Six point masses at arm length l on an X hexarotor give 3 m l² about x and y and 6 m l² about z,
  which would make I_xx about 0.0309 kg m². The config keeps the paper's Table 2 values.
- :func:`thrust_constant_at_point` is eq. 24-25, C_T = F / ω² from the single full-speed point
  (7.671 N at 746 rad/s gives 1.378e-5 N s²); :func:`fit_rotor_constant` fits F = C_T ω² by least squares
  over every bench point, with its standard deviation, which is what the single point estimates.
- :func:`paper_thrust_factor` is eq. 27-28: the paper subtracts C_T [N s²] from the slope of the
  thrust-command line [N per command unit], which has no physical meaning (the units differ) but is how
  Table 3's thrust factors a_i were obtained; it is reproduced, not used.
- Eq. 29's C_T = 8.683e-5 N s² contradicts eq. 25 by a factor 6.3 on the same bench data (it would give
  48 N at 746 rad/s instead of the measured 7.671 N); no arithmetic of the paper's data reproduces it.
- Eq. 30, C_Q = C_T L, multiplies a thrust constant by the arm length: that is the roll/pitch moment of
  a rotor's thrust per ω², not the rotor's aerodynamic drag torque constant, even though its unit
  (N m s²) looks right. :func:`seed2_torque_constant` reproduces it; a drag torque constant comes from a
  torque measurement on the bench (:class:`BenchData` ``torque_N_m``) through :func:`fit_rotor_constant`.
- :func:`fit_speed_map` turns the speed test into a :class:`~multirotor_ros.model.airframe.MotorMap`:
  the dead band before the motor starts, the active range up to the highest speed (seed 2's motors slow
  down again above program speed 130: those points are left out and said so), and a straight line between.

Every fit refuses non-finite samples, mismatched lengths and too few points with a :class:`BenchError`
that names the array and the sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.airframe import MotorMap
from multirotor_ros.model.rotation import FloatArray


class BenchError(ValueError):
    """Bench data that cannot be fitted; the message names the array and, where it applies, the sample."""


# ----------------------------------------------------------------------------------------------
# Inertia from geometry (eqs. 20-22)


@dataclass(frozen=True)
class HexarotorGeometry:
    """Component masses and sizes of seed 2 Table 1 (symbols as in eqs. 20-22)."""

    body_mass_kg: float  # m: the central body, a cylinder about body z
    motor_mass_kg: float  # m_m: one motor, a cylinder
    rotor_mass_kg: float  # m_r: one rotor (propeller)
    body_height_m: float  # h_cg
    motor_height_m: float  # h_m
    body_radius_m: float  # r_cg
    motor_radius_m: float  # r_m
    blade_radius_m: float  # r
    chord_m: float  # c: blade chord
    arm_length_m: float  # l

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value > 0):
                raise BenchError(f"geometry: {name} must be a positive finite number, got {value!r}")


# Seed 2 Table 1, "Hexarotor Physical Measurement Values".
SEED2_TABLE1 = HexarotorGeometry(
    body_mass_kg=0.890,
    motor_mass_kg=0.054,
    rotor_mass_kg=0.070,
    body_height_m=0.04,
    motor_height_m=0.03,
    body_radius_m=0.11,
    motor_radius_m=0.0135,
    blade_radius_m=0.125,
    chord_m=0.027,
    arm_length_m=0.275,
)
# [kg m²] seed 2 Table 2 (I_xx, I_yy, I_zz) and Table 3's different I_zz.
SEED2_TABLE2_INERTIA_KG_M2 = (0.02197, 0.02162, 0.04366)
SEED2_TABLE3_IZZ_KG_M2 = 0.04904


def inertia_from_geometry(g: HexarotorGeometry) -> tuple[float, float, float]:
    """(I_xx, I_yy, I_zz) [kg m²] by seed 2 eqs. 20-22 exactly as printed (see the module notes)."""
    m, mm, mr = g.body_mass_kg, g.motor_mass_kg, g.rotor_mass_kg
    l2 = g.arm_length_m**2
    body_xy = m * (g.body_height_m**2 + 3 * g.body_radius_m**2) / 12
    motors_xy = 2 * mm * l2 + (mm / 6) * (3 * g.motor_radius_m**2 + 4 * g.motor_height_m**2)
    i_xx = body_xy + motors_xy + 2 * mr * l2 + mr * g.blade_radius_m**2 / 3
    i_yy = body_xy + motors_xy + 2 * mr * l2 + mr * g.chord_m**2 / 3
    i_zz = (
        m * g.body_radius_m**2 / 2
        + 4 * mm * l2
        + 2 * mm * g.motor_radius_m**2
        + mr * ((2 * g.blade_radius_m) ** 2 + g.chord_m**2) / 3
        + 4 * mr * l2
    )
    return float(i_xx), float(i_yy), float(i_zz)


# ----------------------------------------------------------------------------------------------
# Fits


@dataclass(frozen=True)
class LineFit:
    """y = slope x + intercept by least squares, with standard deviations from the residuals."""

    slope: float
    intercept: float
    slope_std: float
    intercept_std: float
    rmse: float
    n_points: int

    def __call__(self, x: ArrayLike) -> FloatArray:
        """The line at ``x``."""
        return self.slope * np.asarray(x, dtype=float) + self.intercept


@dataclass(frozen=True)
class ConstantFit:
    """y = value · ω² through the origin by least squares (a rotor's thrust or drag-torque constant)."""

    value: float
    std: float
    rmse: float
    n_points: int


def _samples(name: str, values: ArrayLike, length: int | None = None) -> FloatArray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1:
        raise BenchError(f"{name}: expected a 1-D array of samples, got shape {array.shape}")
    if length is not None and array.size != length:
        raise BenchError(f"{name}: {array.size} samples, expected {length} (one per command step)")
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise BenchError(
            f"{name}: sample {bad[0]} is {array[bad[0]]} (every bench sample must be a finite number)"
        )
    return array


def fit_line(x: ArrayLike, y: ArrayLike, x_name: str = "x", y_name: str = "y") -> LineFit:
    """Least-squares line through (x, y): seed 2 eq. 23 / 26 for thrust against command."""
    xs = _samples(x_name, x)
    ys = _samples(y_name, y, xs.size)
    if xs.size < 3:
        raise BenchError(f"{y_name}: a line with its uncertainty needs at least 3 points, got {xs.size}")
    if np.ptp(xs) == 0:
        raise BenchError(f"{x_name}: all samples are equal ({xs[0]:g}); a slope needs different commands")
    design = np.column_stack([xs, np.ones_like(xs)])
    coefficients, *_ = np.linalg.lstsq(design, ys, rcond=None)
    residual = ys - design @ coefficients
    dof = xs.size - 2
    sigma2 = float(residual @ residual) / dof
    covariance = sigma2 * np.linalg.inv(design.T @ design)
    return LineFit(
        slope=float(coefficients[0]),
        intercept=float(coefficients[1]),
        slope_std=float(np.sqrt(covariance[0, 0])),
        intercept_std=float(np.sqrt(covariance[1, 1])),
        rmse=float(np.sqrt(np.mean(residual**2))),
        n_points=int(xs.size),
    )


def fit_rotor_constant(speed_rad_s: ArrayLike, value: ArrayLike, value_name: str = "thrust_N") -> ConstantFit:
    """Least-squares C in value = C ω² (thrust [N] -> C_T [N s²], drag torque [N m] -> C_Q [N m s²]).

    Stopped-rotor samples (ω = 0) carry no information on C and are kept: they weigh nothing.
    """
    omega = _samples("speed_rad_s", speed_rad_s)
    ys = _samples(value_name, value, omega.size)
    regressor = omega**2
    energy = float(regressor @ regressor)
    spinning = int(np.count_nonzero(omega))
    if spinning < 2:
        raise BenchError(
            f"{value_name}: fitting C in C ω² needs at least 2 samples with the rotor turning, got {spinning}"
        )
    constant = float(regressor @ ys) / energy
    residual = ys - constant * regressor
    sigma2 = float(residual @ residual) / (spinning - 1)
    return ConstantFit(
        value=constant,
        std=float(np.sqrt(sigma2 / energy)),
        rmse=float(np.sqrt(np.mean(residual**2))),
        n_points=spinning,
    )


def thrust_constant_at_point(thrust_N: float, speed_rad_s: float) -> float:
    """Seed 2 eqs. 24-25: C_T = F / ω² from one bench point (the paper uses the full-speed one)."""
    if not (np.isfinite(thrust_N) and np.isfinite(speed_rad_s) and speed_rad_s > 0):
        raise BenchError(
            f"thrust constant at a point needs finite F and ω > 0, got F = {thrust_N}, ω = {speed_rad_s}"
        )
    return float(thrust_N) / float(speed_rad_s) ** 2


def paper_thrust_factor(line_slope: float, thrust_constant: float) -> float:
    """Seed 2 eqs. 27-28 as printed: a_i = m - b (slope of the thrust line minus C_T).

    Reproduces Table 3's thrust factors from the paper's own numbers; the subtraction mixes units
    (N per command unit and N s²), so the result is not a physical quantity and nothing else uses it.
    """
    return float(line_slope) - float(thrust_constant)


def seed2_torque_constant(thrust_constant: float, arm_length_m: float) -> float:
    """Seed 2 eq. 30 as printed: C_Q = C_T L. A thrust moment per ω², not a drag torque constant."""
    return float(thrust_constant) * float(arm_length_m)


# ----------------------------------------------------------------------------------------------
# Motor map from the speed test


@dataclass(frozen=True)
class SpeedMapFit:
    """The speed test turned into a motor map, with what was fitted and what was left out."""

    motor_map: MotorMap
    line: LineFit  # speed (law 'linear') or speed² (law 'quadratic') against the command
    start_command: float  # the command at which the rotor starts turning
    saturation_command: float  # the command of the highest measured speed
    notes: tuple[str, ...]


def fit_speed_map(
    command: ArrayLike,
    speed_rad_s: ArrayLike,
    input_unit: Literal["pwm_us", "normalized"] = "normalized",
    law: Literal["linear", "quadratic"] = "linear",
    stopped_below_rad_s: float | None = None,
) -> SpeedMapFit:
    """A :class:`MotorMap` from a speed test: rotor speed measured at a series of commands.

    Samples are sorted by command. A sample is "stopped" below ``stopped_below_rad_s`` (default 2 % of
    the highest speed). The active range runs from the first turning sample to the highest speed;
    points after the maximum (a motor that slows down again, seed 2 Fig. 8) are left out and reported
    in ``notes``. Within it, speed (law 'linear') or speed² ('quadratic') is fitted against the command.
    If the fitted line reaches zero speed between the last stopped and the first turning command (or
    predicts a stopped rotor at the last stopped command), the map starts there at 0 rad/s; otherwise the
    ESC jumps to an idle speed, and the map starts at the
    first turning command with the fitted idle speed (below it, MotorMap clamps to that idle speed:
    say so, since the real motor is stopped there).
    """
    u = _samples("command", command)
    w = _samples("speed_rad_s", speed_rad_s, u.size)
    if np.any(w < 0):
        raise BenchError(
            f"speed_rad_s: sample {int(np.flatnonzero(w < 0)[0])} is negative; give speeds as magnitudes"
        )
    order = np.argsort(u, kind="stable")
    u, w = u[order], w[order]
    if np.any(np.diff(u) == 0):
        raise BenchError("command: a command appears twice; average repeated measurements before fitting")
    top = int(np.argmax(w))
    threshold = 0.02 * w[top] if stopped_below_rad_s is None else float(stopped_below_rad_s)
    turning = np.flatnonzero(w[: top + 1] >= threshold)
    first = int(turning[0]) if turning.size else top
    active = np.arange(first, top + 1)
    if active.size < 3:
        raise BenchError(f"speed_rad_s: only {active.size} samples between motor start and top speed; need 3")
    notes: list[str] = []
    if top < u.size - 1:
        notes.append(
            f"{u.size - 1 - top} sample(s) above command {u[top]:g} left out: the speed falls after its "
            "maximum "
            f"({w[top]:g} rad/s), which the motor map cannot represent; commands above are clamped"
        )
    stopped_inside = np.flatnonzero(w[first : top + 1] < threshold)
    if stopped_inside.size:
        notes.append(f"{stopped_inside.size} sample(s) below {threshold:g} rad/s inside the active range")
    target = w[active] if law == "linear" else w[active] ** 2
    line = fit_line(u[active], target, "command", "speed_rad_s" if law == "linear" else "speed_rad_s^2")
    if line.slope <= 0:
        raise BenchError(
            "speed_rad_s: the fitted speed does not increase with the command; check the test data"
        )
    zero_command = -line.intercept / line.slope
    previous = u[first - 1] if first > 0 else -np.inf
    # The line crossing zero a little below the last stopped command is noise, not an idle jump.
    stopped_fits_line = first == 0 or abs(float(line(previous))) <= (
        threshold if law == "linear" else threshold**2
    )
    if zero_command <= u[first] and (zero_command >= previous or stopped_fits_line):
        start, speed_min = float(max(zero_command, previous)), 0.0
    else:
        start = float(u[first])
        speed_min = max(float(line(start)), 0.0)
        if law == "quadratic":
            speed_min = float(np.sqrt(speed_min))
        if first > 0:
            notes.append(
                f"the motor jumps from stopped to {speed_min:g} rad/s at command {start:g}; below it the map "
                f"clamps to {speed_min:g} rad/s while the real motor is stopped"
            )
    saturation = float(u[top])
    speed_max = float(line(saturation))
    if law == "quadratic":
        speed_max = float(np.sqrt(speed_max))
    if saturation <= start:
        raise BenchError(
            f"command: the motor starts at {start:g} and saturates at {saturation:g}; no active range"
        )
    motor_map = MotorMap(input_unit, start, saturation, speed_min, speed_max, law)
    return SpeedMapFit(motor_map, line, start, saturation, tuple(notes))


# ----------------------------------------------------------------------------------------------
# The whole bench test


@dataclass(frozen=True)
class BenchData:
    """One rotor's bench test: at each command, the thrust [N], the speed [rad/s], optionally the torque."""

    command: Sequence[float] | FloatArray
    thrust_N: Sequence[float] | FloatArray
    speed_rad_s: Sequence[float] | FloatArray
    torque_N_m: Sequence[float] | FloatArray | None = None
    input_unit: Literal["pwm_us", "normalized"] = "normalized"


@dataclass(frozen=True)
class BenchIdentification:
    """What seed 2 §3 derives from a bench test, done both the paper's way and by least squares."""

    thrust_line: LineFit  # eq. 23: thrust against command
    k_f_N_s2: ConstantFit  # F = C_T ω² over every point
    k_f_at_top_speed_N_s2: float  # eq. 24-25: the single full-speed point
    k_t_N_m_s2: ConstantFit | None  # drag torque = C_Q ω², only from a torque measurement
    speed_map: SpeedMapFit
    notes: tuple[str, ...]


def identify_bench(data: BenchData, law: Literal["linear", "quadratic"] = "linear") -> BenchIdentification:
    """A rotor's thrust line, C_T (least squares and eq. 25), C_Q if torque was measured, its motor map."""
    command = _samples("command", data.command)
    thrust = _samples("thrust_N", data.thrust_N, command.size)
    speed = _samples("speed_rad_s", data.speed_rad_s, command.size)
    speed_map = fit_speed_map(command, speed, data.input_unit, law)
    # The thrust line (eq. 23) only means something where the rotor turns and before it saturates.
    active = (command >= speed_map.start_command) & (command <= speed_map.saturation_command)
    thrust_line = fit_line(command[active], thrust[active], "command", "thrust_N")
    top = int(np.argmax(speed))
    notes = list(speed_map.notes)
    torque_fit = None
    if data.torque_N_m is not None:
        torque = _samples("torque_N_m", data.torque_N_m, command.size)
        torque_fit = fit_rotor_constant(speed, np.abs(torque), "torque_N_m")
    else:
        notes.append(
            "no torque measurement: C_Q not identified (seed 2's C_Q = C_T L is a thrust moment, not a drag "
            "torque constant)"
        )
    return BenchIdentification(
        thrust_line=thrust_line,
        k_f_N_s2=fit_rotor_constant(speed, thrust, "thrust_N"),
        k_f_at_top_speed_N_s2=thrust_constant_at_point(float(thrust[top]), float(speed[top])),
        k_t_N_m_s2=torque_fit,
        speed_map=speed_map,
        notes=tuple(notes),
    )
