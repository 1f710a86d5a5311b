"""The flight-log CSV: round trips, every validation error with file/line/column, derivation notes."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from multirotor_ros.io import flight_log
from multirotor_ros.io.derive import SavitzkyGolay, derive_motion, rotor_speeds_with_note
from multirotor_ros.io.flight_log import (
    FlightLog,
    FlightLogError,
    canonical_order,
    read_flight_log,
    write_flight_log,
)
from multirotor_ros.io.resample import hold, interpolate, interpolate_quaternion
from multirotor_ros.model.airframe import MotorMap


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal as float64 bit patterns, except that every NaN equals every NaN."""
    both_nan = np.isnan(a) & np.isnan(b)
    return a.shape == b.shape and bool(np.all(both_nan | ((a == b) & (np.signbit(a) == np.signbit(b)))))


def _assert_same_log(a: FlightLog, b: FlightLog) -> None:
    assert _same(a.t, b.t)
    assert set(a.columns) == set(b.columns)
    for name in a.columns:
        assert _same(a.columns[name], b.columns[name]), name
    assert a.metadata == b.metadata
    assert list(a.metadata) == list(b.metadata)


def _example_log(n: int = 50) -> FlightLog:
    t = np.arange(n) * 0.01
    rng = np.random.default_rng(1)
    columns = {name: rng.normal(size=n) for name in ("roll", "pitch", "yaw", "x", "y", "z", "p", "q", "r")}
    columns.update({f"omega_{k}": 400 + rng.normal(size=n) for k in range(1, 5)})
    columns.update({f"omega_cmd_{k}": 400 + rng.normal(size=n) for k in range(1, 5)})
    columns["range"] = np.where(np.arange(n) % 3 == 0, 1.5, np.nan)
    columns["battery_v"] = np.full(n, 12.6)
    metadata = {"airframe": "quad_x", "source": "test", "note": "ratios: 1:2, ünïcode kept"}
    return FlightLog(t, columns, metadata)


# ---------------------------------------------------------------------------------------------
# Round trip and layout


def test_round_trip_is_exact_and_rewrites_identically(tmp_path: Path) -> None:
    log = _example_log()
    path = tmp_path / "log.csv"
    write_flight_log(path, log)
    back = read_flight_log(path, n_rotors=4)
    _assert_same_log(log, back)
    assert back.source_path == path
    again = tmp_path / "again.csv"
    write_flight_log(again, back)
    assert again.read_bytes() == path.read_bytes()


def test_written_layout_follows_the_spec(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    write_flight_log(path, _example_log(4))
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[:3] == ["# airframe: quad_x", "# source: test", "# note: ratios: 1:2, ünïcode kept"]
    assert lines[3].split(",") == [
        "t", "roll", "pitch", "yaw", "x", "y", "z", "omega_1", "omega_2", "omega_3", "omega_4",
        "p", "q", "r", "omega_cmd_1", "omega_cmd_2", "omega_cmd_3", "omega_cmd_4", "range", "battery_v",
    ]  # fmt: skip
    assert lines[5].split(",")[-2] == ""  # range not measured on row 2: an empty cell


def test_canonical_order_sorts_rotors_numerically() -> None:
    names = ["omega_10", "extra", "omega_2", "t", "u_1", "omega_1", "yaw"]
    assert canonical_order(names) == ["t", "yaw", "omega_1", "omega_2", "omega_10", "u_1", "extra"]


def test_nan_text_and_blank_cells_are_not_measured(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_text(
        "t,roll,pitch,yaw,vx,vy,vz,u_1,u_2,u_3,u_4\n0,0,0,0,1,2,3,1,1,1,1\n0.1, ,NaN,-nan,1,2,3,1,1,1,1\n"
    )
    log = read_flight_log(path)
    assert (
        np.isnan(log.column("roll")[1])
        and np.isnan(log.column("pitch")[1])
        and np.isnan(log.column("yaw")[1])
    )
    assert log.n_rotors == 4 and log.has_group("velocity") and not log.has_group("position")


def test_crlf_and_byte_order_mark_are_accepted(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_bytes(
        b"\xef\xbb\xbf# a: b\r\nt,roll,pitch,yaw,ax,ay,az,omega_1\r\n0,0,0,0,0,0,0,1\r\n1,0,0,0,0,0,0,1\r\n"
    )
    log = read_flight_log(path)
    assert log.metadata == {"a": "b"} and list(log.t) == [0.0, 1.0]


def test_fast_parser_is_used_for_ordinary_files_and_is_fast(tmp_path: Path, monkeypatch) -> None:
    """flight_log.md: a 90 s log at 100 Hz with ~30 columns reads well under 0.5 s."""
    n = 9000
    rng = np.random.default_rng(0)
    names = [
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
        "p",
        "q",
        "r",
        "range",
    ]
    columns = {name: rng.normal(size=n) for name in names}
    columns.update({f"omega_{k}": rng.normal(size=n) + 500 for k in range(1, 9)})
    columns.update({f"omega_cmd_{k}": rng.normal(size=n) + 500 for k in range(1, 9)})
    columns["range"][::2] = np.nan
    path = tmp_path / "big.csv"
    write_flight_log(path, FlightLog(np.arange(n) * 0.01, columns, {"airframe": "x8_octorotor"}))

    def refuse(*args: object) -> None:
        raise AssertionError("the reference parser ran on a valid file")

    monkeypatch.setattr(flight_log, "_cells_reference", refuse)
    durations = []
    for _ in range(3):
        start = time.perf_counter()
        log = read_flight_log(path, n_rotors=8)
        durations.append(time.perf_counter() - start)
    assert len(log) == n and len(log.columns) == 32
    assert min(durations) < 0.5, durations


# ---------------------------------------------------------------------------------------------
# Validation: every error names the file, the 1-based line and the column.

HEADER = "t,roll,pitch,yaw,x,y,z,omega_1,omega_2,omega_3,omega_4"
ROW0 = "0.00,0,0,0,0,0,0,400,400,400,400"
ROW1 = "0.01,0,0,0,0,0,0,400,400,400,400"


def _file(*lines: str) -> bytes:
    return ("\n".join(lines) + "\n").encode("utf-8")


# (content, n_rotors, line, column, words in the message), one case per malformed input.
MALFORMED = [
    pytest.param(
        _file(HEADER, ROW0).replace(b"0,400,400,400,400\n", b"0,4\xff0,400,400,400\n"),
        None,
        2,
        "omega_1",
        "UTF-8",
        id="not utf-8",
    ),
    pytest.param(
        _file(HEADER.replace("roll,", ""), ROW0[:-2]), None, 1, "roll", "required", id="missing roll"
    ),
    pytest.param(
        _file("t,roll,pitch,yaw,omega_1", "0,0,0,0,1"), None, 1, "x", "motion group", id="no motion group"
    ),
    pytest.param(
        _file("t,roll,pitch,yaw,x,y,omega_1", "0,0,0,0,0,0,1"),
        None,
        1,
        "z",
        "x, y, z",
        id="incomplete position",
    ),
    pytest.param(
        _file("t,roll,pitch,yaw,x,y,z,omega_cmd_1", "0,0,0,0,0,0,0,1"),
        None,
        1,
        "omega_1",
        "rotor group",
        id="no rotor group",
    ),
    pytest.param(
        _file("t,roll,pitch,yaw,x,y,z,omega_1,omega_3", "0,0,0,0,0,0,0,1,1"),
        None,
        1,
        "omega_2",
        "without gaps",
        id="rotor gap",
    ),
    pytest.param(
        _file("t,roll,pitch,yaw,x,y,z,omega_01", "0,0,0,0,0,0,0,1"),
        None,
        1,
        "omega_01",
        "leading zeros",
        id="leading zero",
    ),
    pytest.param(
        _file(HEADER + ",u_1,u_2", ROW0 + ",1,1"), None, 1, "u_3", "missing", id="u and omega disagree"
    ),
    pytest.param(_file(HEADER, ROW0), 8, 1, "omega_5", "airframe has 8", id="airframe has more rotors"),
    pytest.param(_file(HEADER, ROW0), 2, 1, "omega_3", "unexpected", id="airframe has fewer rotors"),
    pytest.param(_file(HEADER + ",x", ROW0 + ",1"), None, 1, "x", "twice", id="duplicate header"),
    pytest.param(_file(HEADER + ",", ROW0 + ",1"), None, 1, "", "empty", id="empty header cell"),
    pytest.param(
        _file(HEADER, ROW0, ROW1.replace("0.01,0,0,0,0", "0.01,0,0,0,abc")),
        None,
        3,
        "x",
        "not a number",
        id="text cell",
    ),
    pytest.param(
        _file(HEADER, ROW0, ROW1.replace(",0,0,0,400", ",0,0,inf,400")),
        None,
        3,
        "z",
        "not a measurement",
        id="inf cell",
    ),
    pytest.param(
        _file(HEADER, ROW1.replace("0.01,0", "0.01,-Infinity")),
        None,
        2,
        "roll",
        "not a measurement",
        id="-Infinity cell",
    ),
    pytest.param(
        _file(HEADER, ROW0, ROW1.replace(",400,400,400,400", ",400,1e400,400,400")),
        None,
        3,
        "omega_2",
        "infinite",
        id="overflowing number",
    ),
    pytest.param(
        _file(HEADER, ROW0.replace("400,400,400,400", "400,400,400,1_000")),
        None,
        2,
        "omega_4",
        "not a number",
        id="underscore digits",
    ),
    pytest.param(
        _file(HEADER, ROW0.replace(",0,0,0,400", ",0,0x10,0,400")),
        None,
        2,
        "y",
        "not a number",
        id="hex number",
    ),
    pytest.param(
        _file(HEADER, "0.00,0,0,0,0,0,0,400,400,400,4 00"),
        None,
        2,
        "omega_4",
        "not a number",
        id="decimal comma",
    ),
    pytest.param(_file(HEADER, ROW0, ROW1, ROW1), None, 4, "t", "duplicated", id="duplicated stamp"),
    pytest.param(_file(HEADER, ROW1, ROW0), None, 3, "t", "out of order", id="stamp out of order"),
    pytest.param(_file(HEADER, ROW0, ROW1.replace("0.01", "")), None, 3, "t", "every row", id="empty t"),
    pytest.param(
        _file(HEADER, ROW0, ROW1.rsplit(",", 2)[0]), None, 3, "omega_3", "missing", id="too few cells"
    ),
    pytest.param(_file(HEADER, ROW0 + ",7"), None, 2, "omega_4", "extra cells", id="too many cells"),
    pytest.param(_file(HEADER, ROW0, "", ROW1), None, 3, "t", "empty line", id="empty line in data"),
    pytest.param(
        _file(HEADER, ROW0, "# late: 1", ROW1), None, 3, "t", "before the header", id="metadata after header"
    ),
    pytest.param(
        _file("# just a comment", HEADER, ROW0), None, 1, None, "key: value", id="metadata without colon"
    ),
    pytest.param(_file("# a: 1", "# a: 2", HEADER, ROW0), None, 2, None, "twice", id="metadata key twice"),
    pytest.param(
        _file("# actuator_unit: volts", HEADER, ROW0), None, 1, None, "pwm_us", id="unknown actuator unit"
    ),
    pytest.param(_file("# a: 1", HEADER), None, 3, "t", "no data rows", id="no data rows"),
    pytest.param(b"", None, 1, None, "no header", id="empty file"),
    pytest.param(_file("# a: 1"), None, 2, None, "no header", id="only metadata"),
    pytest.param(
        _file(HEADER, "0,0,0,0,,,,1,1,1,1"),
        None,
        2,
        "x",
        "complete motion group",
        id="motion group never measured",
    ),
    pytest.param(
        _file(HEADER, "0,0,0,0,0,0,0,,1,1,1"),
        None,
        2,
        "omega_1",
        "rotor columns",
        id="rotor group never measured",
    ),
    pytest.param(
        _file("# a: 1", "# b: 2", HEADER, ROW0.replace(",0,0,0,0", ",0,0,?,0")),
        None,
        4,
        "yaw",
        "not a number",
        id="line numbers count metadata",
    ),
]


@pytest.mark.parametrize(("content", "n_rotors", "line", "column", "words"), MALFORMED)
def test_every_error_names_file_line_and_column(
    tmp_path: Path, content: bytes, n_rotors: int | None, line: int, column: str | None, words: str
) -> None:
    path = tmp_path / "bad.csv"
    path.write_bytes(content)
    with pytest.raises(FlightLogError) as caught:
        read_flight_log(path, n_rotors=n_rotors)
    error = caught.value
    assert (error.path, error.line, error.column) == (str(path), line, column), str(error)
    message = str(error)
    assert message.startswith(f"{path}:{line}")
    if column is not None:
        assert f"column {column!r}" in message
    assert words in message
    assert isinstance(error, ValueError)


def test_missing_file_is_a_flight_log_error(tmp_path: Path) -> None:
    with pytest.raises(FlightLogError, match="cannot read"):
        read_flight_log(tmp_path / "absent.csv")


def test_writer_refuses_what_it_could_not_read_back(tmp_path: Path) -> None:
    log = _example_log(3)
    bad_t = FlightLog(np.array([0.0, 0.0, 1.0]), log.columns, {})
    with pytest.raises(FlightLogError, match="duplicated"):
        write_flight_log(tmp_path / "a.csv", bad_t)
    with pytest.raises(FlightLogError, match="one line"):
        write_flight_log(tmp_path / "b.csv", FlightLog(log.t, log.columns, {"note": "two\nlines"}))
    with pytest.raises(FlightLogError, match="metadata key"):
        write_flight_log(tmp_path / "c.csv", FlightLog(log.t, log.columns, {"a:b": "c"}))
    with pytest.raises(FlightLogError, match="header"):
        write_flight_log(tmp_path / "d.csv", FlightLog(log.t, {**log.columns, "a,b": log.t}, {}))
    infinite = dict(log.columns, x=np.array([0.0, np.inf, 0.0]))
    with pytest.raises(FlightLogError, match="row 1: infinite") as caught:
        write_flight_log(tmp_path / "e.csv", FlightLog(log.t, infinite, {}))
    assert caught.value.column == "x"
    assert not any(tmp_path.iterdir())


def test_columns_must_match_t() -> None:
    with pytest.raises(FlightLogError, match="shape"):
        FlightLog(np.arange(3.0), {"roll": np.zeros(4)})


# ---------------------------------------------------------------------------------------------
# Property: any valid log written then read is identical.

# A valid log's cells stay within the bound the reader puts on measurements.
_finite = st.floats(
    min_value=-flight_log.LARGEST_MEASUREMENT,
    max_value=flight_log.LARGEST_MEASUREMENT,
    allow_nan=False,
    width=64,
)
_cell = st.one_of(_finite, st.just(math.nan))
_text = st.text(st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp")), max_size=12).map(str.strip)
_RESERVED = {
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
    "p",
    "q",
    "r",
    "range",
}
_extra_names = st.from_regex(r"[a-z][a-z0-9_]{0,8}", fullmatch=True).filter(
    lambda name: name not in _RESERVED and not flight_log._ROTOR_LOOKALIKE.fullmatch(name)
)


@st.composite
def valid_logs(draw: st.DrawFn) -> FlightLog:
    t = np.array(sorted(draw(st.lists(_finite, min_size=1, max_size=25, unique=True))))
    n = t.size

    def column() -> np.ndarray:
        return np.array(draw(st.lists(_cell, min_size=n, max_size=n)))

    def measured() -> np.ndarray:
        values = column()
        values[0] = draw(_finite)
        return values

    columns = {name: column() for name in ("roll", "pitch", "yaw")}
    groups = draw(st.sets(st.sampled_from(sorted(flight_log.MOTION_GROUPS)), min_size=1))
    for i, group in enumerate(sorted(groups)):
        for name in flight_log.MOTION_GROUPS[group]:
            columns[name] = measured() if i == 0 else column()
    n_rotors = draw(st.integers(1, 8))
    prefixes = draw(st.sets(st.sampled_from(["omega", "u"]), min_size=1))
    for i, prefix in enumerate(sorted(prefixes)):
        for k in range(1, n_rotors + 1):
            columns[f"{prefix}_{k}"] = measured() if i == 0 else column()
    if draw(st.booleans()):
        for k in range(1, n_rotors + 1):
            columns[f"omega_cmd_{k}"] = column()
    for name in draw(st.sets(st.sampled_from(["p", "q", "r", "range"]))):
        columns[name] = column()
    for name in draw(st.sets(_extra_names, max_size=3)):
        columns[name] = column()
    keys = st.text(
        st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp"), blacklist_characters=":"), min_size=1
    )
    metadata = draw(
        st.dictionaries(
            keys.map(str.strip).filter(bool).filter(lambda k: k != "actuator_unit"), _text, max_size=4
        )
    )
    if "u" in prefixes:
        metadata["actuator_unit"] = draw(st.sampled_from(flight_log.ACTUATOR_UNITS))
    return FlightLog(t, columns, metadata)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(log=valid_logs())
def test_any_valid_log_survives_write_then_read(tmp_path: Path, log: FlightLog) -> None:
    path = tmp_path / "property.csv"
    write_flight_log(path, log)
    back = read_flight_log(path, n_rotors=log.n_rotors)
    _assert_same_log(log, back)


@settings(max_examples=40, deadline=None)
@given(log=valid_logs())
def test_fast_and_reference_parsers_agree(log: FlightLog) -> None:
    names = canonical_order(["t", *log.columns])
    body = "\n".join(
        ",".join("" if math.isnan(v) else repr(v) for v in row)
        for row in zip(*(log.column(name).tolist() for name in names), strict=True)
    )
    fast = flight_log._cells_fast(body, len(names))
    reference = flight_log._cells_reference(body.split("\n"), 2, names, Path("x.csv"))
    assert fast is not None and _same(fast, reference)


# ---------------------------------------------------------------------------------------------
# Accessors


def test_accessors() -> None:
    log = _example_log(10)
    assert log.n_rotors == 4 and len(log) == 10
    assert log.has_group("position") and log.has_group("rotor_speeds")
    assert not log.has_group("velocity") and not log.has_group("actuators")
    assert log.euler().shape == (10, 3) and log.rotor_speeds().shape == (10, 4)
    assert log.group_columns("rotor_speeds") == ["omega_1", "omega_2", "omega_3", "omega_4"]
    with pytest.raises(FlightLogError, match="no such column") as caught:
        log.column("vx")
    assert caught.value.column == "vx"
    with pytest.raises(FlightLogError, match="no velocity group"):
        log.group("velocity")
    with pytest.raises(ValueError, match="unknown group"):
        log.has_group("wind")  # type: ignore[arg-type]
    part = log.slice(0.02, 0.05)
    assert list(part.t) == [0.02, 0.03, 0.04, 0.05] and part.metadata == log.metadata
    assert _same(part.column("omega_2"), log.column("omega_2")[2:6])


def test_rotor_speeds_from_actuators_need_a_matching_motor_map() -> None:
    t = np.arange(3.0)
    columns = {
        "roll": t,
        "pitch": t,
        "yaw": t,
        "x": t,
        "y": t,
        "z": t,
        "u_1": np.array([1000.0, 1500.0, 2000.0]),
    }
    pwm_map = MotorMap("pwm_us", 1000.0, 2000.0, 0.0, 1000.0)
    with pytest.raises(FlightLogError, match="motor map"):
        rotor_speeds_with_note(FlightLog(t, columns, {"actuator_unit": "pwm_us"}))
    with pytest.raises(FlightLogError, match="actuator_unit"):
        rotor_speeds_with_note(FlightLog(t, columns, {}), pwm_map)
    with pytest.raises(FlightLogError, match="expects normalized"):
        rotor_speeds_with_note(
            FlightLog(t, columns, {"actuator_unit": "pwm_us"}), MotorMap("normalized", 0.0, 1.0, 0.0, 1.0)
        )
    speeds, note = rotor_speeds_with_note(FlightLog(t, columns, {"actuator_unit": "pwm_us"}), pwm_map)
    assert list(speeds[:, 0]) == [0.0, 500.0, 1000.0]
    assert "motor map" in note and "pwm_us" in note
    log = FlightLog(
        t, {**columns, "omega_1": speeds[:, 0]}, {"actuator_unit": "pwm_us", "omega_source": "converter"}
    )
    assert "converter" in rotor_speeds_with_note(log)[1]


# ---------------------------------------------------------------------------------------------
# Derived motion: differentiation with a stated filter, integration that says it drifts.


def _trajectory_log(groups: tuple[str, ...], rate_hz: float = 100.0, duration_s: float = 4.0) -> FlightLog:
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    w = 2.0 * np.pi * 0.5
    truth = {
        "position": np.column_stack([np.sin(w * t), np.cos(w * t), 0.5 * t**2]),
        "velocity": np.column_stack([w * np.cos(w * t), -w * np.sin(w * t), t]),
        "acceleration": np.column_stack([-(w**2) * np.sin(w * t), -(w**2) * np.cos(w * t), np.ones_like(t)]),
    }
    columns = {"roll": 0 * t, "pitch": 0 * t, "yaw": 0 * t, "omega_1": 0 * t + 1}
    for group in groups:
        for i, name in enumerate(flight_log.MOTION_GROUPS[group]):
            columns[name] = truth[group][:, i]
    return FlightLog(t, columns, {})


def test_differentiation_recovers_velocity_and_acceleration_and_says_how() -> None:
    log = _trajectory_log(("position",))
    derived = derive_motion(log, SavitzkyGolay(window_s=0.2, polyorder=3))
    w = 2.0 * np.pi * 0.5
    assert np.allclose(derived.velocity[:, 0], w * np.cos(w * log.t), atol=3e-3)
    # The second derivative is within 1 % of its amplitude away from the ends (the polynomial fits
    # over the first and last half window are extrapolations).
    inner = slice(11, -11)
    assert np.allclose(derived.acceleration[inner, 1], -(w**2) * np.cos(w * log.t[inner]), atol=0.1)
    assert derived.notes["position"].startswith("measured")
    assert (
        "Savitzky-Golay" in derived.notes["velocity"] and "21 samples = 0.21 s" in derived.notes["velocity"]
    )
    assert "second derivative of measured position" in derived.notes["acceleration"]
    assert derived.description.count("\n") == 2


def test_acceleration_comes_from_velocity_when_both_lower_groups_exist() -> None:
    derived = derive_motion(_trajectory_log(("position", "velocity")))
    assert derived.notes["acceleration"].startswith("derivative of measured velocity")


def test_integration_is_used_only_without_lower_groups_and_warns_of_drift() -> None:
    log = _trajectory_log(("acceleration",))
    derived = derive_motion(log)
    w = 2.0 * np.pi * 0.5
    # Integration starts from zero: velocity = truth - truth(0).
    assert np.allclose(derived.velocity[:, 2], log.t, atol=1e-6)
    assert np.allclose(derived.velocity[:, 0], w * np.cos(w * log.t) - w, atol=5e-3)
    assert "drifts" in derived.notes["velocity"] and "double integral" in derived.notes["position"]


def test_derivation_handles_multirate_rows_and_does_not_bridge_gaps() -> None:
    log = _trajectory_log(("position",))
    x = log.columns["x"].copy()
    x[1::2] = np.nan  # position at 50 Hz in a 100 Hz log
    x[200:260] = np.nan  # a 0.6 s dropout
    for name in ("x", "y", "z"):
        log.columns[name] = np.where(np.isnan(x), np.nan, log.columns[name])
    derived = derive_motion(log)
    w = 2.0 * np.pi * 0.5
    good = ~np.isnan(derived.velocity[:, 0])
    assert np.all(np.isnan(derived.velocity[205:255, 0]))
    assert np.count_nonzero(good) > 300
    assert np.allclose(derived.velocity[good, 0], w * np.cos(w * log.t[good]), atol=0.05)
    assert "50 Hz" in derived.notes["velocity"]


def test_too_short_a_log_to_differentiate_says_so() -> None:
    with pytest.raises(FlightLogError, match="window needs"):
        derive_motion(_trajectory_log(("position",), duration_s=0.05))


# ---------------------------------------------------------------------------------------------
# Resampling helpers (used by the converters)


def test_interpolation_and_hold_leave_gaps_empty() -> None:
    ts = np.array([0.0, 0.1, 0.2, 1.0, 1.1])
    values = ts[:, None] * 10
    t = np.array([-0.05, 0.05, 0.15, 0.6, 1.05, 1.2])
    linear = interpolate(t, ts, values, max_gap=0.3)[:, 0]
    assert np.allclose(linear[[1, 2, 4]], [0.5, 1.5, 10.5]) and np.all(np.isnan(linear[[0, 3, 5]]))
    held = hold(t, ts, values, max_age=0.3)[:, 0]
    assert np.allclose(held[[1, 2, 4, 5]], [0.0, 1.0, 10.0, 11.0]) and np.all(np.isnan(held[[0, 3]]))


def test_quaternion_interpolation_takes_the_short_arc_across_a_sign_flip() -> None:
    half = np.radians(10.0) / 2
    q = np.array([[np.cos(half), 0, 0, np.sin(half)], [-np.cos(3 * half), 0, 0, -np.sin(3 * half)]])
    middle = interpolate_quaternion(np.array([0.5]), np.array([0.0, 1.0]), q, max_gap=2.0)[0]
    assert np.isclose(2 * np.degrees(np.arctan2(middle[3], middle[0])), 20.0, atol=0.01)
