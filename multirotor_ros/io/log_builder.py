"""Assemble a :class:`FlightLog` from streams sampled at different rates, and record how.

One stream's stamps are the time base (the motion source: odometry, local position, EKF). Every
other stream is brought onto it by one of three stated methods, each noted in ``# resampling:``:

- ``linear``: linear interpolation, for continuous measurements (rates, specific force, range,
  measured rotor speeds);
- ``hold``: zero-order hold of the latest sample, for commands and actuator outputs, which are
  piecewise constant by nature;
- attitude: normalised linear interpolation of the quaternion (equal to slerp at these rates).

A cell stays empty before a stream's first sample, after its last and inside gaps longer than
``GAP_PERIODS`` of its median period (for ``hold``: when the latest sample is older than that).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from multirotor_ros.io.flight_log import FlightLog, FloatArray, rotor_columns
from multirotor_ros.io.resample import hold, interpolate, interpolate_quaternion, median_period
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import quat_to_euler

GAP_PERIODS = 3.0


class ConversionError(ValueError):
    """A source log that cannot be converted; the message names the file and what is missing."""


def read_numeric_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """A source CSV's header and cells as floats (an empty cell is NaN); a bad row names line and column."""
    try:
        with path.open(newline="", encoding="utf-8") as stream:
            reader = csv.reader(stream)
            header = [name.strip() for name in next(reader, [])]
            rows = list(reader)
    except (OSError, UnicodeDecodeError) as error:
        raise ConversionError(f"{path}: cannot read as UTF-8 CSV: {error}") from None
    values = np.full((len(rows), len(header)), np.nan)
    for row_index, row in enumerate(rows):
        if len(row) != len(header):
            raise ConversionError(f"{path}:{row_index + 2}: {len(row)} cells, the header has {len(header)}")
        for col, cell in enumerate(row):
            if cell.strip():
                try:
                    values[row_index, col] = float(cell)
                except ValueError:
                    raise ConversionError(
                        f"{path}:{row_index + 2}: column {header[col]!r}: not a number: {cell!r}"
                    ) from None
    return header, values


def _rate(ts: FloatArray) -> str:
    period = median_period(ts)
    return f"{1.0 / period:.4g} Hz" if np.isfinite(period) and period > 0 else "a single sample"


class LogBuilder:
    """Columns on one time base (absolute stamps [s]); ``build`` shifts t to start at 0."""

    def __init__(self, t_abs: FloatArray, time_base: str):
        self.t_abs = np.asarray(t_abs, dtype=float)
        self.columns: dict[str, FloatArray] = {}
        self.metadata: dict[str, str] = {}
        self._resampling: list[str] = []
        self._resampled = False
        self.time_base = (
            f"{time_base} ({_rate(self.t_abs)} median); t = 0 at {self.t_abs[0]:.6f} s of the source's clock"
        )

    def put(self, names: Sequence[str], values: FloatArray) -> None:
        """Columns sampled at the time-base stamps themselves."""
        values = np.asarray(values, dtype=float).reshape(self.t_abs.size, len(names))
        for i, name in enumerate(names):
            self.columns[name] = values[:, i]

    def put_stream(
        self,
        names: Sequence[str],
        ts: FloatArray,
        values: FloatArray,
        method: Literal["linear", "hold"],
        label: str,
        max_gap_s: float | None = None,
    ) -> None:
        """A stream sampled at its own stamps ``ts``, brought onto the time base by ``method``.

        Nothing is bridged across a gap longer than ``max_gap_s`` (default: a few of the stream's
        periods); a state published only when it changes is held with ``math.inf``.
        """
        values = np.asarray(values, dtype=float).reshape(ts.size, len(names))
        max_gap = GAP_PERIODS * median_period(ts) if max_gap_s is None else max_gap_s
        resample, how = (
            (interpolate, "linear interpolation") if method == "linear" else (hold, "zero-order hold")
        )
        self.put(names, resample(self.t_abs, ts, values, max_gap))
        self._note(names, label, ts, how)

    def put_attitude(self, ts: FloatArray, q_WB: FloatArray, label: str) -> None:
        """roll, pitch, yaw from quaternions (w, x, y, z), body FLU -> world ENU, at stamps ts."""
        q = interpolate_quaternion(self.t_abs, ts, q_WB, GAP_PERIODS * median_period(ts))
        self.put(["roll", "pitch", "yaw"], quat_to_euler(q))
        self._note(["roll", "pitch", "yaw"], label, ts, "normalised quaternion interpolation")

    def _note(self, names: Sequence[str], label: str, ts: FloatArray, how: str) -> None:
        if ts.shape == self.t_abs.shape and np.array_equal(ts, self.t_abs):
            self._resampling.append(f"{_span(names)} from {label} at the time-base stamps (not resampled)")
        else:
            self._resampling.append(f"{_span(names)} from {label} ({_rate(ts)}) by {how}")
            self._resampled = True

    def put_actuators(
        self,
        ts: FloatArray,
        outputs: FloatArray,
        channels: Sequence[int],
        channel_note: str,
        unit: str,
        airframe: Airframe,
        label: str,
    ) -> str | None:
        """u_k = the outputs' ``channels`` (held), and omega_k through the airframe's motor map.

        Returns a warning when the motor map cannot be applied (its input unit is not the log's).
        """
        n = airframe.n_rotors
        selected = np.asarray(outputs, dtype=float)[:, [c - 1 for c in channels]]
        self.put_stream(rotor_columns("u", n), ts, selected, "hold", label)
        self.metadata["actuator_unit"] = unit
        self.metadata["rotor_channels"] = channel_note
        motor_map = airframe.motor_map
        if motor_map.input_unit != unit:
            return (
                f"omega_k not written: the airframe's motor map takes {motor_map.input_unit}, "
                f"the log has {unit}; tools map u_k themselves"
            )
        u = np.column_stack([self.columns[name] for name in rotor_columns("u", n)])
        self.put(rotor_columns("omega", n), motor_map.speed_from_command(u))
        self.metadata["motor_map"] = f"{airframe.name}: {motor_map.describe()}"
        self.metadata["omega_source"] = "u_k through the airframe's motor map (not measured)"
        return None

    def build(self, first: dict[str, str]) -> FlightLog:
        """The log; metadata = ``first``, then time base, resampling, then what ``put_*`` recorded."""
        metadata = dict(first)
        metadata["time_base"] = self.time_base
        if self._resampling:
            gaps = (
                f"cells are empty outside a stream's samples and in gaps over {GAP_PERIODS:g} median periods"
            )
            metadata["resampling"] = "; ".join(self._resampling + ([gaps] if self._resampled else []))
        metadata.update(self.metadata)
        return FlightLog(self.t_abs - self.t_abs[0], dict(self.columns), metadata)


def _span(names: Sequence[str]) -> str:
    if len(names) > 3 and names[0].endswith("_1"):
        return f"{names[0]}..{names[-1]}"
    return ",".join(names)
