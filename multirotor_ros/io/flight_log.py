"""The flight-log CSV (shared/spec/flight_log.md): one table every offline tool reads and writes.

Reading validates everything the spec lists and stops at the first problem with a
:class:`FlightLogError` whose message names the file, the 1-based line (metadata lines count) and
the column. Cell rules:

- an empty (or blank) cell means "not measured at this sample" and becomes NaN;
- a literal ``nan`` (any case, optionally signed) is accepted with the same meaning, because numpy,
  pandas and spreadsheets write it for missing values;
- ``inf``/``infinity`` and numbers that overflow a float64 (``1e400``) are errors: no sensor
  measures infinity, so such a cell is a broken log, not a gap;
- anything else that is not a plain decimal number (``0x10``, ``1_000``, ``1,5``, text) is an error.

``t`` must be given in every row and strictly increase. Rotor columns are ``omega_k`` (rad/s),
``u_k`` (unit in ``# actuator_unit:``) and ``omega_cmd_k``, each numbered 1..N without gaps, with
the same N; ``n_rotors`` (the airframe's rotor count) is checked against it when given.
A motion group (position, velocity, acceleration) or rotor group counts when all its columns are
in the header and at least one row has all of them measured.

Parsing has a fast path (character-set scan + ``numpy.loadtxt``) and a slower reference parser
that runs only when the fast path refuses the text; the reference parser either finds and reports
the bad cell or parses what the fast path was too strict for (blank cells with spaces).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

REQUIRED_COLUMNS = ("t", "roll", "pitch", "yaw")
MOTION_GROUPS: dict[str, tuple[str, str, str]] = {
    "position": ("x", "y", "z"),
    "velocity": ("vx", "vy", "vz"),
    "acceleration": ("ax", "ay", "az"),
}
ROTOR_PREFIXES = ("omega", "u", "omega_cmd")
ROTOR_GROUPS = {"rotor_speeds": "omega", "actuators": "u"}
Group = Literal["position", "velocity", "acceleration", "rotor_speeds", "actuators"]
ACTUATOR_UNITS = ("pwm_us", "normalized")
OTHER_SPEC_COLUMNS = ("p", "q", "r", "range")
# Beyond these magnitudes a cell of a spec column is a broken log, not a measurement: 1e6 is 1000 km,
# 1000 km/s or 10^6 rad/s, and no PWM or normalised command comes near it. Bounding the cells keeps every
# square and product the tools form far from overflow (1e300 would reach the fit as inf). t is time since
# the log's start, but a log may keep a clock counted from an epoch.
LARGEST_MEASUREMENT = 1e6
LARGEST_TIME_S = 1e10

_ROTOR_COLUMN = re.compile(r"(omega_cmd|omega|u)_([1-9][0-9]*)")
_ROTOR_LOOKALIKE = re.compile(r"(omega_cmd|omega|u)_[0-9]+")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NOT_MEASURED = re.compile(r"[+-]?nan", re.IGNORECASE)
_INFINITE = re.compile(r"[+-]?inf(?:inity)?", re.IGNORECASE)
# Every character a valid data block can hold; anything else sends the text to the reference parser.
_DATA_CHARACTERS = b"0123456789.eE+-,\nnaNA \t"


class FlightLogError(ValueError):
    """A flight log that cannot be read or written; the message names file, line and column."""

    def __init__(
        self, message: str, path: str | Path | None = None, line: int | None = None, column: str | None = None
    ):
        self.path = None if path is None else str(path)
        self.line = line
        self.column = column
        self.reason = message
        where = self.path or "<flight log>"
        if line is not None:
            where += f":{line}"
        if column is not None:
            where += f": column {column!r}"
        super().__init__(f"{where}: {message}")


def rotor_columns(prefix: str, n_rotors: int) -> list[str]:
    """``[prefix_1, ..., prefix_N]``."""
    return [f"{prefix}_{k}" for k in range(1, n_rotors + 1)]


def canonical_order(names: Iterable[str]) -> list[str]:
    """Column names in the order of flight_log.md (``t`` first), then the others as given."""
    names = list(names)
    present = set(names)
    numbered: dict[str, list[tuple[int, str]]] = {prefix: [] for prefix in ROTOR_PREFIXES}
    for name in names:
        match = _ROTOR_COLUMN.fullmatch(name)
        if match:
            numbered[match.group(1)].append((int(match.group(2)), name))

    def rotors(prefix: str) -> list[str]:
        return [name for _, name in sorted(numbered[prefix])]

    leading = ("t", "roll", "pitch", "yaw", "x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az")
    ordered: list[str] = [n for n in leading if n in present]
    ordered += rotors("omega") + rotors("u")
    ordered += [n for n in ("p", "q", "r") if n in present]
    ordered += rotors("omega_cmd")
    ordered += [n for n in ("range",) if n in present]
    placed = set(ordered)
    return ordered + [n for n in names if n not in placed]


@dataclass
class FlightLog:
    """One flight log in memory: ``t`` [s], named float columns (NaN = not measured), metadata."""

    t: FloatArray
    columns: dict[str, FloatArray]
    metadata: dict[str, str] = field(default_factory=dict)
    source_path: Path | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.columns = {name: np.asarray(values, dtype=float) for name, values in self.columns.items()}
        for name, values in self.columns.items():
            if values.shape != self.t.shape:
                raise FlightLogError(
                    f"has shape {values.shape}, t has {self.t.shape}", self.source_path, column=name
                )

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def n_rotors(self) -> int:
        """Rotor count N from the ``omega_k`` or ``u_k`` columns (0 if there are none)."""
        return len(_rotor_indices(self.columns, "omega") or _rotor_indices(self.columns, "u"))

    def column(self, name: str) -> FloatArray:
        """One column by name (``t`` included); a missing column raises naming the ones present."""
        if name == "t":
            return self.t
        if name not in self.columns:
            raise FlightLogError(
                f"no such column; present: {', '.join(['t', *self.columns])}", self.source_path, column=name
            )
        return self.columns[name]

    def has_group(self, group: Group) -> bool:
        """All columns of the group are present and at least one row has all of them measured."""
        names = self.group_columns(group)
        if not names or any(name not in self.columns for name in names):
            return False
        return bool(np.any(np.all(np.isfinite(np.column_stack([self.columns[n] for n in names])), axis=1)))

    def group_columns(self, group: Group) -> list[str]:
        """Column names of a motion or rotor group (rotor groups: those present in this log)."""
        if group in MOTION_GROUPS:
            return list(MOTION_GROUPS[group])
        if group in ROTOR_GROUPS:
            return rotor_columns(ROTOR_GROUPS[group], len(_rotor_indices(self.columns, ROTOR_GROUPS[group])))
        raise ValueError(
            f"unknown group {group!r}; choose one of {', '.join([*MOTION_GROUPS, *ROTOR_GROUPS])}"
        )

    def group(self, group: Group) -> FloatArray:
        """(T, k) array of a group's columns; raises if the group is absent."""
        if not self.has_group(group):
            raise FlightLogError(
                f"the log has no {group} group", self.source_path, column=",".join(self.group_columns(group))
            )
        return np.column_stack([self.columns[name] for name in self.group_columns(group)])

    def euler(self) -> FloatArray:
        """(T, 3) ZYX Euler angles (roll, pitch, yaw) [rad]."""
        return np.column_stack([self.column("roll"), self.column("pitch"), self.column("yaw")])

    def rotor_speeds(self, motor_map: MotorMapLike | None = None) -> FloatArray:
        """(T, N) rotor speeds [rad/s]: measured ``omega_k``, else ``u_k`` through ``motor_map``.

        See :func:`multirotor_ros.io.derive.rotor_speeds_with_note` for the text saying which it was.
        """
        from multirotor_ros.io.derive import rotor_speeds_with_note

        return rotor_speeds_with_note(self, motor_map)[0]

    def slice(self, t0: float, t1: float) -> FlightLog:
        """Rows with t0 <= t <= t1 (t keeps its origin: it is not shifted to start at 0)."""
        keep = (self.t >= t0) & (self.t <= t1)
        return FlightLog(
            self.t[keep].copy(),
            {name: values[keep].copy() for name, values in self.columns.items()},
            dict(self.metadata),
            self.source_path,
        )

    def validate(self, n_rotors: int | None = None) -> None:
        """The checks of :func:`read_flight_log` on an in-memory log (errors name the row)."""
        names = ["t", *self.columns]
        _check_header(names, n_rotors, _Failer(self.source_path, None))
        values = np.column_stack([self.t, *self.columns.values()]) if len(self) else np.empty((0, len(names)))
        _check_values(values, names, self.metadata, lambda row: None, self.source_path, row_label=True)


class MotorMapLike(Protocol):
    """What the flight log needs of ``multirotor_ros.model.airframe.MotorMap``."""

    @property
    def input_unit(self) -> str: ...

    def speed_from_command(self, command: FloatArray) -> FloatArray: ...

    def describe(self) -> str: ...


def _rotor_indices(names: Iterable[str], prefix: str) -> list[int]:
    indices = []
    for name in names:
        match = _ROTOR_COLUMN.fullmatch(name)
        if match and match.group(1) == prefix:
            indices.append(int(match.group(2)))
    return sorted(indices)


class _Failer:
    """Builds errors at one line of the file (None for a log in memory)."""

    def __init__(self, path: str | Path | None, line: int | None):
        self.path, self.line = path, line

    def __call__(self, message: str, column: str | None = None) -> FlightLogError:
        return FlightLogError(message, self.path, self.line, column)


def _check_header(names: list[str], n_rotors: int | None, fail: _Failer) -> None:
    seen: set[str] = set()
    for index, name in enumerate(names):
        if not name:
            raise fail(f"header cell {index + 1} is empty: every column needs a name", column="")
        if name in seen:
            raise fail("appears twice in the header", column=name)
        seen.add(name)
        if _ROTOR_LOOKALIKE.fullmatch(name) and not _ROTOR_COLUMN.fullmatch(name):
            raise fail(
                "rotor columns are numbered from 1 without leading zeros (omega_1, u_1, ...)", column=name
            )
    for name in REQUIRED_COLUMNS:
        if name not in seen:
            raise fail("required column missing (required: t, roll, pitch, yaw)", column=name)
    for group, columns in MOTION_GROUPS.items():
        partial = [c for c in columns if c in seen]
        if partial and len(partial) < 3:
            missing = next(c for c in columns if c not in seen)
            raise fail(f"the {group} group needs all of {', '.join(columns)}", column=missing)
    if not any(all(c in seen for c in columns) for columns in MOTION_GROUPS.values()):
        raise fail("no motion group: need x,y,z or vx,vy,vz or ax,ay,az", column="x")
    counts: dict[str, int] = {}
    for prefix in ROTOR_PREFIXES:
        indices = _rotor_indices(names, prefix)
        if not indices:
            continue
        for expected, index in enumerate(indices, start=1):
            if index != expected:
                raise fail(
                    f"rotor columns must be {prefix}_1..{prefix}_N without gaps; found {prefix}_{index} "
                    f"but not this one",
                    column=f"{prefix}_{expected}",
                )
        counts[prefix] = len(indices)
    if "omega" not in counts and "u" not in counts:
        raise fail(
            "no rotor group: need omega_1..omega_N (rad/s) or u_1..u_N (actuator outputs)", column="omega_1"
        )
    expected_n: int = n_rotors if n_rotors is not None else counts.get("omega") or counts["u"]
    source = "the airframe has" if n_rotors is not None else f"{'omega' if 'omega' in counts else 'u'}_k give"
    for prefix, count in counts.items():
        if count > expected_n:
            raise fail(
                f"unexpected: {prefix}_1..{prefix}_{count} present but {source} {expected_n} rotors",
                column=f"{prefix}_{expected_n + 1}",
            )
        if count < expected_n:
            raise fail(
                f"missing: {prefix}_1..{prefix}_{count} present but {source} {expected_n} rotors",
                column=f"{prefix}_{count + 1}",
            )


def _check_values(
    values: FloatArray,
    names: list[str],
    metadata: Mapping[str, str],
    line_of_row: Callable[[int], int | None],
    path: str | Path | None,
    row_label: bool = False,
) -> None:
    def fail(message: str, row: int, column: str) -> FlightLogError:
        if row_label:
            message = f"row {row}: {message}"
        return FlightLogError(message, path, line_of_row(row), column)

    if values.shape[0] == 0:
        raise FlightLogError("no data rows after the header", path, line_of_row(0), "t")
    infinite = np.argwhere(np.isinf(values))
    if infinite.size:
        row, col = (int(v) for v in infinite[0])
        raise fail(
            "infinite value (a number too large for float64, or inf): not a measurement", row, names[col]
        )
    limits = np.array([_largest_magnitude(name) for name in names])
    with np.errstate(invalid="ignore"):
        too_large = np.argwhere(np.abs(values) > limits)
    if too_large.size:
        row, col = (int(v) for v in too_large[0])
        raise fail(
            f"{values[row, col]:.6g} is not a measurement: no {names[col]} in a flight log exceeds "
            f"{limits[col]:g} in magnitude",
            row,
            names[col],
        )
    t = values[:, names.index("t")]
    missing_t = np.flatnonzero(np.isnan(t))
    if missing_t.size:
        raise fail("t must be given in every row", int(missing_t[0]), "t")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        row = int(bad[0]) + 1
        kind = "duplicated time stamp" if dt[bad[0]] == 0 else "time stamp out of order"
        raise fail(f"{kind}: t = {t[row]:.9g} after t = {t[row - 1]:.9g}; t must strictly increase", row, "t")
    column_index = {name: i for i, name in enumerate(names)}

    def measured_rows(columns: Iterable[str]) -> bool:
        return bool(np.any(np.all(np.isfinite(values[:, [column_index[c] for c in columns]]), axis=1)))

    groups = {g: c for g, c in MOTION_GROUPS.items() if all(n in column_index for n in c)}
    if not any(measured_rows(columns) for columns in groups.values()):
        first = next(iter(groups.values()))
        raise fail(
            f"no row has a complete motion group ({', '.join(' '.join(g) for g in groups.values())})",
            0,
            first[0],
        )
    rotor_groups = [rotor_columns(p, len(_rotor_indices(names, p))) for p in ("omega", "u")]
    rotor_groups = [g for g in rotor_groups if g]
    if not any(measured_rows(columns) for columns in rotor_groups):
        raise fail("no row has all rotor columns measured", 0, rotor_groups[0][0])
    for key, value in metadata.items():
        problem = _metadata_problem(key, value)
        if problem:
            raise FlightLogError(problem, path, None, None)


def _largest_magnitude(name: str) -> float:
    """Bound on |cell| of a column of the spec (extra columns are not bounded)."""
    if name == "t":
        return LARGEST_TIME_S
    spec_columns = (*REQUIRED_COLUMNS, *(c for g in MOTION_GROUPS.values() for c in g), *OTHER_SPEC_COLUMNS)
    if name in spec_columns or _ROTOR_COLUMN.fullmatch(name):
        return LARGEST_MEASUREMENT
    return math.inf


def _metadata_problem(key: str, value: str) -> str | None:
    if key == "actuator_unit" and value not in ACTUATOR_UNITS:
        return f"'# actuator_unit: {value}' is not one of {', '.join(ACTUATOR_UNITS)}"
    return None


def _decode(raw: bytes, path: Path) -> str:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line_start = raw.rfind(b"\n", 0, error.start) + 1
        line = raw.count(b"\n", 0, error.start) + 1
        cell = raw.count(b",", line_start, error.start)
        header_names = _header_names_for_error(raw)
        column = header_names[cell] if header_names and cell < len(header_names) else f"cell {cell + 1}"
        raise FlightLogError(f"not UTF-8 text (byte 0x{raw[error.start]:02x})", path, line, column) from None
    return text.removeprefix("\ufeff").replace("\r\n", "\n").replace("\r", "\n")


def _header_names_for_error(raw: bytes) -> list[str] | None:
    for line in raw.split(b"\n"):
        if not line.startswith(b"#"):
            try:
                return [cell.strip() for cell in line.decode("utf-8").split(",")]
            except UnicodeDecodeError:
                return None
    return None


def _parse_metadata(line: str, number: int, path: Path, metadata: dict[str, str]) -> None:
    key, colon, value = line[1:].partition(":")
    key, value = key.strip(), value.strip()
    if not colon or not key:
        raise FlightLogError(f"metadata lines are '# key: value', got {line!r}", path, number, None)
    if key in metadata:
        raise FlightLogError(f"metadata key {key!r} appears twice", path, number, None)
    problem = _metadata_problem(key, value)
    if problem:
        raise FlightLogError(problem, path, number, None)
    metadata[key] = value


def _cells_fast(body: str, n_columns: int) -> FloatArray | None:
    """Numpy parse of a data block the reference parser would accept; None = let it decide."""
    try:
        foreign = body.encode("ascii").translate(None, _DATA_CHARACTERS)
    except UnicodeEncodeError:
        return None
    if foreign or "\n\n" in body:
        return None
    # Empty cells become 'nan' for loadtxt: ',,' twice because the replacements cannot overlap.
    filled = "\n" + body + "\n"
    if ",," in filled:
        filled = filled.replace(",,", ",nan,").replace(",,", ",nan,")
    filled = filled.replace("\n,", "\nnan,").replace(",\n", ",nan\n")
    try:
        values = np.loadtxt(io.StringIO(filled), delimiter=",", comments=None, dtype=float, ndmin=2)
    except ValueError:
        return None
    if values.shape != (body.count("\n") + 1, n_columns):
        return None
    return values


def _cells_reference(lines: list[str], first_line: int, names: list[str], path: Path) -> FloatArray:
    """Cell-by-cell parse that names the line and column of the first bad cell."""
    values = np.empty((len(lines), len(names)))
    for row, line in enumerate(lines):
        number = first_line + row
        cells = line.split(",")
        if len(cells) != len(names):
            if not line.strip():
                raise FlightLogError("empty line inside the data", path, number, names[0])
            if line.startswith("#"):
                raise FlightLogError("metadata lines must come before the header", path, number, names[0])
            if len(cells) < len(names):
                column = names[len(cells)]
                message = f"row has {len(cells)} cells, the header has {len(names)}: this column is missing"
            else:
                column = names[-1]
                message = (
                    f"row has {len(cells)} cells, the header has {len(names)}: extra cells after this column"
                )
            raise FlightLogError(message, path, number, column)
        for col, cell in enumerate(cells):
            text = cell.strip()
            if not text or _NOT_MEASURED.fullmatch(text):
                values[row, col] = math.nan
            elif _NUMBER.fullmatch(text):
                values[row, col] = float(text)
            elif _INFINITE.fullmatch(text):
                raise FlightLogError(
                    f"{text!r} is not a measurement (leave the cell empty, or write nan, for 'not measured')",
                    path,
                    number,
                    names[col],
                )
            else:
                raise FlightLogError(f"not a number: {text!r}", path, number, names[col])
    return values


def _line_end(text: str, start: int) -> int:
    end = text.find("\n", start)
    return len(text) if end < 0 else end


def read_flight_log(path: str | Path, n_rotors: int | None = None) -> FlightLog:
    """Read and validate a flight-log CSV; ``n_rotors`` is the airframe's rotor count, if known."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise FlightLogError(f"cannot read: {error.strerror or error}", path) from None
    text = _decode(raw, path).rstrip()
    metadata: dict[str, str] = {}
    start, number = 0, 1
    while text.startswith("#", start):
        end = _line_end(text, start)
        _parse_metadata(text[start:end], number, path, metadata)
        start, number = end + 1, number + 1
    if start >= len(text):
        raise FlightLogError("no header line (expected 't,roll,pitch,yaw,...')", path, number, None)
    header_line = number
    end = _line_end(text, start)
    names = [cell.strip() for cell in text[start:end].split(",")]
    _check_header(names, n_rotors, _Failer(path, header_line))
    body = text[end + 1 :]
    first_data_line = header_line + 1
    values = _cells_fast(body, len(names)) if body else np.empty((0, len(names)))
    if values is None:
        values = _cells_reference(body.split("\n"), first_data_line, names, path)
    _check_values(values, names, metadata, lambda row: first_data_line + row, path)
    t_index = names.index("t")
    columns = {name: values[:, i].copy() for i, name in enumerate(names) if i != t_index}
    return FlightLog(values[:, t_index].copy(), columns, metadata, path)


def _format_column(values: FloatArray) -> list[str]:
    # repr() is the shortest text that reads back to the same float64, so the round trip is exact.
    return ["" if v != v else repr(v) for v in values.tolist()]


def _check_writable(log: FlightLog, path: Path) -> None:
    for key, value in log.metadata.items():
        if not key.strip() or ":" in key or "\n" in key or "\r" in key or key != key.strip():
            raise FlightLogError(f"metadata key {key!r} cannot be written as '# key: value'", path)
        if "\n" in value or "\r" in value or value != value.strip():
            raise FlightLogError(f"metadata value of {key!r} must be one line without outer spaces", path)
    for name in log.columns:
        if (
            name == "t"
            or not name
            or name != name.strip()
            or any(c in name for c in ",\n\r")
            or name.startswith("#")
        ):
            raise FlightLogError("column name cannot be written in a CSV header", path, column=name)


def write_flight_log(path: str | Path, log: FlightLog) -> None:
    """Write ``log`` as flight_log.md says: metadata, then ``t``, the canonical columns, the extras.

    The log is validated first (same checks as the reader), so a written log always reads back.
    """
    path = Path(path)
    _check_writable(log, path)
    log.validate()
    names = canonical_order(["t", *log.columns])
    formatted = [_format_column(log.column(name)) for name in names]
    parts = [f"# {key}: {value}\n" for key, value in log.metadata.items()]
    parts.append(",".join(names) + "\n")
    parts.extend(",".join(row) + "\n" for row in zip(*formatted, strict=True))
    path.write_text("".join(parts), encoding="utf-8")
