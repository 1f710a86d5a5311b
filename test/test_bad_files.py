"""Bad files for the offline tools: every malformed input names its file and line/column/key, no traceback."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from multirotor_ros.cli import main
from multirotor_ros.io.flight_log import FlightLog, read_flight_log, write_flight_log
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.resources import config_directory

NUMPY_REPR = re.compile(r"np\.(float|int)\d*\(|array\(")
QUAD_X = yaml.safe_load((config_directory() / "quad_x.yaml").read_text())


def write_airframe(directory: Path, document: object, name: str = "bad.yaml") -> Path:
    path = directory / name
    path.write_text(yaml.safe_dump(document))
    return path


def every_rotor_at_angle(angle_deg: float) -> dict:
    rotors = [{"number": k, "angle_deg": angle_deg, "spin": ("ccw", "cw")[k % 2]} for k in range(1, 5)]
    return {**QUAD_X, "arm_length_m": 0.25, "rotors": rotors}


def flight_log_text(cell: str = "0.5", column: str = "vx") -> str:
    header = ["t", "roll", "pitch", "yaw", "vx", "vy", "vz", "omega_1", "omega_2", "omega_3", "omega_4"]
    rows = [[f"{0.01 * i:g}", "0", "0", "0", "0", "0", "0", "400", "400", "400", "400"] for i in range(6)]
    rows[3][header.index(column)] = cell
    return "\n".join(",".join(row) for row in [header, *rows]) + "\n"


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.err


def test_rotors_all_at_one_angle_name_the_file_and_key(tmp_path: Path) -> None:
    path = write_airframe(tmp_path, every_rotor_at_angle(0.0))
    with pytest.raises(ValueError) as raised:
        load_airframe(path)
    message = str(raised.value)
    assert message.startswith(f"{path}: rotors: ")
    assert "roll torque" in message and "SVD" not in message


def test_huge_rotor_positions_are_refused_with_the_key(tmp_path: Path) -> None:
    document = {**QUAD_X, "rotors": [{**r, "position_m": [1e300, 1e300, 0.0]} for r in QUAD_X["rotors"]]}
    with pytest.raises(ValueError, match=r"bad\.yaml: rotors\[0\]\.position_m: 1e\+300 m from the centre"):
        load_airframe(write_airframe(tmp_path, document))


def test_convert_and_airframe_commands_print_one_line_for_a_bad_airframe(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    airframe = write_airframe(tmp_path, every_rotor_at_angle(0.0))
    log = tmp_path / "log.csv"
    log.write_text(flight_log_text())
    for argv in (
        ("airframe", str(airframe)),
        ("convert", str(log), "--airframe", str(airframe), "--out", str(tmp_path / "out.csv")),
        (
            "simulate",
            "--airframe",
            str(airframe),
            "--duration",
            "1",
            "--setpoints",
            str(log),
            "--out",
            "x.csv",
        ),
    ):
        status, err = run_cli(capsys, *argv)
        assert status == 2, argv
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert f"{airframe}: rotors:" in err


@pytest.mark.parametrize("column", ["vx", "omega_2", "t", "roll"])
def test_a_huge_value_in_a_flight_log_names_file_line_and_column(tmp_path: Path, column: str) -> None:
    path = tmp_path / "log.csv"
    path.write_text(flight_log_text("1e300", column))
    with pytest.raises(ValueError) as raised:
        read_flight_log(path)
    assert str(raised.value).startswith(f"{path}:5: column '{column}': 1e+300 is not a measurement")


def test_identify_prints_one_line_for_a_huge_value(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "log.csv"
    path.write_text(flight_log_text("1e300", "vx"))
    status, err = run_cli(
        capsys,
        "identify",
        "--airframe",
        "quad_x",
        "--log",
        str(path),
        "--effects",
        "none",
        "--out",
        str(tmp_path),
    )
    assert status == 2
    assert err.startswith(f"multirotor identify: {path}:5: column 'vx': 1e+300 is not a measurement")
    assert err.count("\n") == 1


def test_extra_columns_are_not_bounded(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    text = flight_log_text().splitlines()
    text = [f"{line},{'epoch_us' if i == 0 else '1.7e15'}" for i, line in enumerate(text)]
    path.write_text("\n".join(text) + "\n")
    assert read_flight_log(path).column("epoch_us")[0] == 1.7e15


def test_time_going_back_is_reported_without_numpy_reprs(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_text(flight_log_text("0.01", "t"))
    with pytest.raises(ValueError) as raised:
        read_flight_log(path)
    message = str(raised.value)
    assert "t = 0.01 after t = 0.02" in message and not NUMPY_REPR.search(message)


def test_in_memory_logs_are_bounded_too(tmp_path: Path) -> None:
    log = read_flight_log(_written(tmp_path))
    columns = {**log.columns, "vx": log.columns["vx"] * 0 + 1e300}
    with pytest.raises(ValueError, match="1e\\+300 is not a measurement"):
        write_flight_log(tmp_path / "huge.csv", FlightLog(log.t, columns, log.metadata))


def _written(tmp_path: Path) -> Path:
    path = tmp_path / "good.csv"
    path.write_text(flight_log_text())
    return path


# ------------------------------------------------------------------------------------------------
# Garbage: the loaders raise ValueError naming the file (and where in it), nothing else

CSV_CELLS = st.one_of(
    st.sampled_from(["", "nan", "inf", "-inf", "1e300", "-1e400", "0x10", "1,5", "abc", "1e6", "#", " "]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=6),
)
CSV_NAMES = st.sampled_from(
    [
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
        "omega_1",
        "omega_2",
        "omega_01",
        "u_1",
        "",
        "t",
    ]
)


@st.composite
def garbage_csv(draw: st.DrawFn) -> str:
    header = draw(st.lists(CSV_NAMES, min_size=1, max_size=8))
    rows = draw(st.lists(st.lists(CSV_CELLS, min_size=0, max_size=len(header) + 1), max_size=5))
    metadata = draw(st.lists(st.sampled_from(["# actuator_unit: pwm", "# a: b", "#", "# x"]), max_size=2))
    return "\n".join([*metadata, ",".join(header), *(",".join(row) for row in rows)])


YAML_VALUES = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(10**20), 10**20),
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from(["ccw", "cw", "upper", "pwm_us", "linear", "quadratic"]),
        st.text(max_size=5),
    ),
    lambda children: (
        st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=6), children, max_size=4)
    ),
    max_leaves=20,
)


@st.composite
def garbage_airframe(draw: st.DrawFn) -> object:
    """A quad_x document with some keys replaced, removed or added, or something else entirely."""
    if draw(st.booleans()):
        return draw(YAML_VALUES)
    document = dict(QUAD_X)
    for key in draw(st.lists(st.sampled_from(sorted(QUAD_X)), max_size=3)):
        if draw(st.booleans()):
            document[key] = draw(YAML_VALUES)
        else:
            document.pop(key, None)
    rotors = document.get("rotors")
    if isinstance(rotors, list) and rotors and draw(st.booleans()):
        index = draw(st.integers(0, len(rotors) - 1))
        entry = dict(rotors[index]) if isinstance(rotors[index], dict) else {}
        entry[draw(st.sampled_from(["position_m", "angle_deg", "spin", "number", "pair", "level"]))] = draw(
            YAML_VALUES
        )
        rotors = [*rotors]
        rotors[index] = entry
        document["rotors"] = rotors
        document.setdefault("arm_length_m", draw(YAML_VALUES))
    return document


SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(text=garbage_csv())
def test_garbage_csv_is_a_located_value_error(tmp_path: Path, text: str) -> None:
    path = tmp_path / "garbage.csv"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        read_flight_log(path)
    except ValueError as error:
        message = str(error)
        assert message.startswith(f"{path}:"), message
        assert not NUMPY_REPR.search(message), message


@SETTINGS
@given(document=garbage_airframe())
def test_garbage_yaml_is_a_located_value_error(tmp_path: Path, document: object) -> None:
    path = tmp_path / "garbage.yaml"
    path.write_text(yaml.safe_dump(document))
    try:
        load_airframe(path)
    except ValueError as error:
        message = str(error)
        assert message.startswith(f"{path}: "), message
        assert not NUMPY_REPR.search(message), message


@SETTINGS
@given(raw=st.binary(max_size=200))
def test_garbage_bytes_are_located_value_errors(tmp_path: Path, raw: bytes) -> None:
    for name, load in (("garbage.yaml", load_airframe), ("garbage.csv", read_flight_log)):
        path = tmp_path / name
        path.write_bytes(raw)
        try:
            load(path)
        except ValueError as error:
            assert str(error).startswith(f"{path}:"), str(error)
