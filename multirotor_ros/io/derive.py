"""Fill in what a flight log did not measure, and say how (flight_log.md: tools report it).

:func:`derive_motion` returns position, velocity and acceleration in world ENU for every row of a
log from whichever motion groups it has:

- a measured group is returned as it is (NaN where a row did not measure it);
- a missing group is preferably *differentiated* from the nearest lower-order measured group with a
  Savitzky–Golay filter (:class:`SavitzkyGolay`); the source samples are first linearly resampled to
  a uniform grid at their median sample interval, because the filter assumes uniform spacing;
- otherwise it is *integrated* (trapezoid rule) from a higher-order group, starting from zero
  (the initial position and velocity are unknown), and it drifts.

Derived values are NaN before the first and after the last source sample, inside source gaps
longer than ``max_gap_samples`` sample intervals and, for differentiation, within half a filter
window of such a gap: nothing is invented across a gap.
:func:`rotor_speeds_with_note` does the same for rotor speeds (measured, or through a motor map).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from multirotor_ros.io.flight_log import (
    MOTION_GROUPS,
    FlightLog,
    FlightLogError,
    FloatArray,
    Group,
    MotorMapLike,
)
from multirotor_ros.io.resample import interpolate

_ORDER = {"position": 0, "velocity": 1, "acceleration": 2}


@dataclass(frozen=True)
class SavitzkyGolay:
    """Savitzky–Golay differentiation: a polynomial of ``polyorder`` fitted over ``window_s`` seconds.

    The default 0.2 s cubic window (21 samples at 100 Hz) passes manoeuvres up to a few Hz and
    suppresses the sample-to-sample noise that plain finite differences amplify.
    """

    window_s: float = 0.2
    polyorder: int = 3
    max_gap_samples: float = 3.0

    def window_samples(self, dt: float) -> int:
        """Odd window length in samples for sample interval ``dt``, at least polyorder + 2."""
        n = max(int(round(self.window_s / dt)), self.polyorder + 2)
        return n if n % 2 else n + 1


@dataclass(frozen=True)
class DerivedMotion:
    """(T, 3) world-ENU position [m], velocity [m/s], acceleration [m/s²] on the log's ``t``."""

    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    notes: dict[str, str] = field(default_factory=dict)

    @property
    def description(self) -> str:
        """One line per group: measured, or how it was derived."""
        return "\n".join(f"{group}: {note}" for group, note in self.notes.items())


def _source_samples(t: FloatArray, values: FloatArray) -> tuple[FloatArray, FloatArray]:
    rows = np.all(np.isfinite(values), axis=1)
    return t[rows], values[rows]


def differentiate(
    t: FloatArray, values: FloatArray, order: int, source: str, flt: SavitzkyGolay
) -> tuple[FloatArray, str]:
    """The ``order``-th time derivative of (T, k) ``values`` at ``t`` (module docstring), and its note."""
    ts, xs = _source_samples(t, values)
    if ts.size < 2:
        raise FlightLogError(f"cannot differentiate {source}: fewer than 2 measured rows")
    # A uniform grid from the first to the last sample at about the median interval; the end points
    # are the samples themselves, so no row at either end falls outside it by a rounding error.
    n_grid = int(round((ts[-1] - ts[0]) / float(np.median(np.diff(ts))))) + 1
    grid = np.linspace(ts[0], ts[-1], n_grid)
    dt = float(grid[1] - grid[0])
    window = flt.window_samples(dt)
    if grid.size < window:
        raise FlightLogError(
            f"cannot differentiate {source}: {grid.size} samples, the filter window needs {window}"
        )
    uniform = grid.size == ts.size and np.allclose(grid, ts, rtol=0.0, atol=1e-6 * dt)
    on_grid = xs if uniform else np.column_stack([np.interp(grid, ts, xs[:, i]) for i in range(xs.shape[1])])
    derivative = savgol_filter(on_grid, window, flt.polyorder, deriv=order, delta=dt, axis=0, mode="interp")
    result = interpolate(t, grid, derivative, max_gap=np.inf)
    # The grid bridges source gaps linearly; a filter window that reaches into a gap sees that line,
    # not data, so rows within half a window of a gap stay empty.
    half_window_s = 0.5 * window * dt
    for gap in np.flatnonzero(np.diff(ts) > flt.max_gap_samples * dt):
        result[(t > ts[gap] - half_window_s) & (t < ts[gap + 1] + half_window_s)] = np.nan
    kind = "derivative" if order == 1 else "second derivative"
    how = (
        f"its own uniform {1 / dt:.4g} Hz samples"
        if uniform
        else f"a uniform {1 / dt:.4g} Hz grid (linear resampling)"
    )
    note = (
        f"{kind} of measured {source}: Savitzky-Golay filter, window {window} samples = {window * dt:.3g} s, "
        f"polynomial order {flt.polyorder}, on {how}"
    )
    return result, note


def _integrate(
    t: FloatArray, values: FloatArray, times: int, source: str, flt: SavitzkyGolay
) -> tuple[FloatArray, str]:
    ts, xs = _source_samples(t, values)
    if ts.size < 2:
        raise FlightLogError(f"cannot integrate {source}: fewer than 2 measured rows")
    for _ in range(times):
        steps = 0.5 * (xs[1:] + xs[:-1]) * np.diff(ts)[:, None]
        xs = np.vstack([np.zeros((1, xs.shape[1])), np.cumsum(steps, axis=0)])
    dt = float(np.median(np.diff(ts)))
    max_gap = flt.max_gap_samples * dt
    result = interpolate(t, ts, xs, max_gap)
    start = "zero initial velocity and position" if times == 2 else "zero initial value"
    note = (
        f"{'double ' if times == 2 else ''}integral of measured {source} (trapezoid rule, {start} assumed); "
        "integration drifts: use it for shape, not for absolute values"
    )
    gaps = int(np.count_nonzero(np.diff(ts) > max_gap))
    if gaps:
        note += f"; it runs on across {gaps} gap(s) over {max_gap:.3g} s as if the signal were linear there"
    return result, note


def derive_motion(log: FlightLog, filter: SavitzkyGolay | None = None) -> DerivedMotion:
    """Position, velocity and acceleration (world ENU) for every row, with a note per group."""
    flt = filter or SavitzkyGolay()
    groups: tuple[Group, ...] = ("position", "velocity", "acceleration")
    measured = {group: log.group(group) for group in groups if log.has_group(group)}
    if not measured:
        raise FlightLogError("no motion group to derive from", log.source_path, column="x")
    results: dict[str, FloatArray] = {}
    notes: dict[str, str] = {}
    for target, order in _ORDER.items():
        if target in measured:
            results[target] = measured[target]
            notes[target] = f"measured ({', '.join(MOTION_GROUPS[target])})"
            continue
        lower = [g for g in measured if _ORDER[g] < order]
        if lower:
            source = max(lower, key=_ORDER.__getitem__)
            results[target], notes[target] = differentiate(
                log.t, measured[source], order - _ORDER[source], source, flt
            )
        else:
            source = min(measured, key=_ORDER.__getitem__)
            results[target], notes[target] = _integrate(
                log.t, measured[source], _ORDER[source] - order, source, flt
            )
    return DerivedMotion(results["position"], results["velocity"], results["acceleration"], notes)


def rotor_speeds_with_note(log: FlightLog, motor_map: MotorMapLike | None = None) -> tuple[FloatArray, str]:
    """(T, N) rotor speeds [rad/s] and a line saying where they came from.

    ``omega_k`` columns win (measured, or as ``# omega_source:`` says). Otherwise ``u_k`` go
    through ``motor_map``, whose ``input_unit`` must be the log's ``# actuator_unit:``.
    """
    if log.has_group("rotor_speeds"):
        # A converter that filled omega_k from actuator outputs says so in '# omega_source:'.
        origin = log.metadata.get("omega_source", "measured")
        return log.group(
            "rotor_speeds"
        ), f"rotor speeds omega_1..omega_{log.n_rotors} from the log ({origin})"
    if not log.has_group("actuators"):
        raise FlightLogError("no rotor group (omega_k or u_k)", log.source_path, column="omega_1")
    if motor_map is None:
        raise FlightLogError(
            "the log has actuator outputs u_k but no rotor speeds: a motor map (the airframe's) is needed",
            log.source_path,
            column="u_1",
        )
    unit = log.metadata.get("actuator_unit")
    if unit is None:
        raise FlightLogError(
            "u_k columns but no '# actuator_unit:' metadata line", log.source_path, column="u_1"
        )
    if unit != motor_map.input_unit:
        raise FlightLogError(
            f"actuator outputs are in {unit} but the motor map expects {motor_map.input_unit}",
            log.source_path,
            column="u_1",
        )
    speeds = motor_map.speed_from_command(log.group("actuators"))
    columns = f"u_1..u_{log.n_rotors}"
    note = f"rotor speeds from actuator outputs {columns} ({unit}) via motor map: {motor_map.describe()}"
    return speeds, note
