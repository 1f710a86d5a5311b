"""What the identifier accumulates, kept on disk as it goes, so that a restarted node resumes from it.

A record is a directory (the identifier's ``record_path``) holding:

- ``segment_0001.csv``, ``segment_0002.csv``, ...: the samples the identifier used, as flight logs
  (shared/spec/flight_log.md: ``t, roll, pitch, yaw, x, y, z, vx, vy, vz, ax, ay, az, p, q, r,
  omega_1..N``), with ``t`` the message stamp minus ``# stamp_origin_ns:``. Rows are only ever
  appended; any offline tool (``multirotor identify``) reads a segment as it is. A new segment starts
  when the stamps go back in time (the simulator restarted), since a flight log's ``t`` must increase.
- ``state.npz``: the learnt state (RLS estimate and covariance, the detector's noise and bias), replaced
  atomically (written beside, then renamed) so that it is always either the old or the new one.

:meth:`FlightRecord.flush` appends the buffered rows (flushed and fsync'ed) and replaces the state;
the identifier node calls it every second of wall time, so a crash loses at most the last second. A crash in
the middle of a write leaves at most one torn last line, which :meth:`FlightRecord.resume` cuts off
(and says so) before reading the segment.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from multirotor_ros.io.flight_log import FlightLog, FlightLogError, read_flight_log, rotor_columns
from multirotor_ros.model.rotation import FloatArray, matrix_to_quat, quat_to_euler
from multirotor_ros.model.state import StateBatch

_SEGMENT = re.compile(r"segment_(\d{4,})\.csv")
STATE_FILE = "state.npz"


class RecordError(ValueError):
    """A record directory that cannot be used; the message names the path."""


@dataclass
class Resumed:
    """What a previous run left: its last segment (None if none), learnt state (None if none), notes."""

    log: FlightLog | None
    state: dict[str, FloatArray] | None
    notes: list[str]


def _columns(n_rotors: int) -> list[str]:
    return [
        "t",
        "roll",
        "pitch",
        "yaw",
        "x",
        "y",
        "z",
        "vx",
        "vy",
        "vz",
        "ax",
        "ay",
        "az",
        *rotor_columns("omega", n_rotors),
        "p",
        "q",
        "r",
    ]


class FlightRecord:
    """Append-only record of one vehicle's identifier (module docstring)."""

    def __init__(self, directory: str | Path, airframe_name: str, n_rotors: int):
        self.directory = Path(directory)
        self.airframe_name = airframe_name
        self.n_rotors = n_rotors
        self.columns = _columns(n_rotors)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise RecordError(f"{self.directory}: cannot create the record directory: {error}") from error
        if not self.directory.is_dir():
            raise RecordError(f"{self.directory}: not a directory")
        self._rows: list[str] = []
        self.segment: int = 0
        self.stamp_origin_ns: int | None = None
        self.last_stamp_ns: int | None = None
        self._segment_path: Path | None = None

    # ------------------------------------------------------------------ resume

    def _segments(self) -> list[tuple[int, Path]]:
        found = []
        for path in self.directory.iterdir():
            match = _SEGMENT.fullmatch(path.name)
            if match:
                found.append((int(match.group(1)), path))
        return sorted(found)

    def resume(self) -> Resumed:
        """Read the newest segment and the state; nothing found is not an error (a first start)."""
        notes: list[str] = []
        state = None
        state_path = self.directory / STATE_FILE
        if state_path.exists():
            try:
                with np.load(state_path, allow_pickle=False) as archive:
                    state = {key: archive[key] for key in archive.files}
            except (OSError, ValueError) as error:
                notes.append(f"{state_path}: unreadable ({error}); starting without the learnt state")
        segments = self._segments()
        if not segments:
            return Resumed(None, state, notes)
        self.segment, path = segments[-1]
        try:
            torn = self._cut_torn_line(path)
            if torn:
                notes.append(f"{path}: cut a torn last line ({torn} bytes) left by an interrupted write")
            log = read_flight_log(path, self.n_rotors)
            origin = int(log.metadata["stamp_origin_ns"])
        except (FlightLogError, KeyError, ValueError, OSError) as error:
            notes.append(f"{path}: cannot resume from it ({error}); new samples go to a new segment")
            self.segment += 1
            return Resumed(None, state, notes)
        self.stamp_origin_ns = origin
        self._segment_path = path
        if len(log):
            self.last_stamp_ns = origin + round(float(log.t[-1]) * 1e9)
        notes.append(f"{path}: resuming after {len(log)} recorded samples")
        return Resumed(log, state, notes)

    @staticmethod
    def _cut_torn_line(path: Path) -> int:
        data = path.read_bytes()
        if not data or data.endswith(b"\n"):
            return 0
        keep = data.rfind(b"\n") + 1
        with open(path, "r+b") as handle:
            handle.truncate(keep)
        return len(data) - keep

    # ------------------------------------------------------------------ appending

    def append(self, stamp_ns: int, sample: StateBatch) -> None:
        """Buffer one sample (with the acceleration the identifier used) stamped ``stamp_ns``.

        A stamp not after the last one starts a new segment (the clock went back).
        """
        if sample.size != 1 or sample.a_WB_W is None:
            raise ValueError("a record row is one sample with its acceleration")
        if self.last_stamp_ns is not None and stamp_ns <= self.last_stamp_ns:
            self.start_new_segment()
        if self.stamp_origin_ns is None:
            self.stamp_origin_ns = stamp_ns
        self.last_stamp_ns = stamp_ns
        t = (stamp_ns - self.stamp_origin_ns) * 1e-9
        euler = quat_to_euler(matrix_to_quat(sample.R_WB))
        values = np.concatenate(
            [euler, sample.p_WB_W, sample.v_WB_W, sample.a_WB_W, sample.omega, sample.w_WB_B], axis=1
        )[0]
        self._rows.append(f"{t:.9f}," + ",".join(f"{v:.10g}" for v in values) + "\n")

    def start_new_segment(self) -> None:
        """Close the current segment: the next rows start another (with its own stamp origin)."""
        self._write_rows()
        self.segment += 1
        self._segment_path = None
        self.stamp_origin_ns = None
        self.last_stamp_ns = None

    def flush(self, state: Mapping[str, FloatArray] | None = None) -> None:
        """Append the buffered rows (fsync'ed) and atomically replace the learnt state."""
        self._write_rows()
        if state is not None:
            self._write_state(state)

    def _write_rows(self) -> None:
        if not self._rows:
            return
        if self._segment_path is None:
            self.segment = max(self.segment, 1)
            while (self.directory / f"segment_{self.segment:04d}.csv").exists():
                self.segment += 1
            self._segment_path = self.directory / f"segment_{self.segment:04d}.csv"
            header = (
                f"# airframe: {self.airframe_name}\n"
                "# source: identifier node record (multirotor_ros.diagnosis.record)\n"
                f"# stamp_origin_ns: {self.stamp_origin_ns}\n"
                "# note: ax, ay, az are the accelerations the identifier used (velocity differences or IMU)\n"
                + ",".join(self.columns)
                + "\n"
            )
            self._rows.insert(0, header)
        with open(self._segment_path, "a", encoding="utf-8") as handle:
            handle.write("".join(self._rows))
            handle.flush()
            os.fsync(handle.fileno())
        self._rows = []

    def _write_state(self, state: Mapping[str, FloatArray]) -> None:
        final = self.directory / STATE_FILE
        partial = self.directory / (STATE_FILE + ".partial")
        arrays = {key: np.asarray(value) for key, value in state.items()}
        with open(partial, "wb") as handle:
            # numpy's stub: mypy checks the unpacked arrays against savez's keyword allow_pickle: bool too.
            np.savez(handle, **arrays)  # type: ignore[arg-type]
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(partial, final)


def window_samples(log: FlightLog, window_s: float) -> StateBatch | None:
    """The complete samples of a resumed segment within ``window_s`` of its end, for the identifier."""
    if not len(log):
        return None
    samples = StateBatch.from_flight_log(log)
    assert samples.a_WB_W is not None  # a record's segment has the accelerations the identifier used
    recent = log.t >= log.t[-1] - window_s
    values = [samples.p_WB_W, samples.v_WB_W, samples.R_WB.reshape(-1, 9), samples.w_WB_B, samples.omega]
    complete = np.all(np.isfinite(np.column_stack([*values, samples.a_WB_W])), axis=1)
    keep = recent & complete
    return samples.select(keep) if keep.any() else None
