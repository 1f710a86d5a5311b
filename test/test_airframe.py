"""Airframes as data: the derived allocation reproduces the papers, bad YAML is refused with file and key."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from multirotor_ros.frames import FLU_TO_FRD
from multirotor_ros.model.airframe import AirframeError, load_airframe
from multirotor_ros.model.model import Model
from multirotor_ros.resources import available_airframes

AIRFRAMES = ["x8_octorotor", "hexarotor_f550", "quad_x"]


def test_shipped_airframes_are_found() -> None:
    assert set(AIRFRAMES) <= set(available_airframes())


def test_x8_allocation_is_seed1_eq4() -> None:
    x8 = load_airframe("x8_octorotor")
    k_f, k_t, arm = 1.7e-5, 2.5e-7, 0.23 * math.sqrt(2) / 2
    F = np.eye(8)  # column i: rotor i alone at unit omega^2, so F_i = k_f.

    def pair(i: int, j: int) -> np.ndarray:
        return k_f * (F[i - 1] + F[j - 1])

    def tau(i: int) -> np.ndarray:
        return k_t * F[i - 1]

    seed1 = np.vstack(
        [
            pair(1, 2) + pair(3, 4) + pair(5, 6) + pair(7, 8),
            (pair(7, 8) + pair(5, 6) - pair(3, 4) - pair(1, 2)) * arm,
            (pair(3, 4) + pair(5, 6) - pair(7, 8) - pair(1, 2)) * arm,
            (tau(2) + tau(3) + tau(6) + tau(7)) - (tau(1) + tau(4) + tau(5) + tau(8)),
        ]
    )
    np.testing.assert_allclose(x8.allocation, seed1, rtol=1e-12, atol=1e-18)


def test_hexarotor_allocation_is_seed2_eq13_in_frd() -> None:
    hexa = load_airframe("hexarotor_f550")
    d, k_f, k_t = 0.275, hexa.k_f_N_s2, hexa.k_t_N_m_s2
    T = k_f * np.eye(6)
    Q = k_t * np.eye(6)

    def t(i: int) -> np.ndarray:
        return T[i - 1]

    def q(i: int) -> np.ndarray:
        return Q[i - 1]

    eq13_frd = np.vstack(
        [
            d * (t(5) - t(2)) + (t(6) + t(4) - t(3) - t(1)) * d / 2,
            (t(1) + t(6) - t(4) - t(3)) * d * math.sqrt(3) / 2,
            q(1) - q(2) + q(3) - q(4) + q(5) - q(6),
        ]
    )
    torques_frd = FLU_TO_FRD @ hexa.allocation[1:]
    np.testing.assert_allclose(torques_frd, eq13_frd, rtol=1e-12, atol=1e-18)
    # Seed 2 eq. 14: thrust is k_f times the sum of squared speeds.
    np.testing.assert_allclose(hexa.allocation[0], np.full(6, k_f))


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("x8_octorotor", math.sqrt(1.6 * 9.81 / (8 * 1.7e-5))),
        ("hexarotor_f550", math.sqrt(0.890 * 9.81 / (6 * 1.378e-5))),
        ("quad_x", math.sqrt(1.5 * 9.81 / (4 * 5.84e-6))),
    ],
)
def test_hover_speed(name: str, expected: float) -> None:
    assert Model(load_airframe(name)).hover_speed_rad_s() == pytest.approx(expected, rel=1e-9)


def test_x8_hover_speed_is_near_340() -> None:
    assert 335 < Model(load_airframe("x8_octorotor")).hover_speed_rad_s() < 345


def test_hover_speed_accounts_for_effects() -> None:
    x8 = load_airframe("x8_octorotor")
    with_loss = Model(x8, [{"id": "coaxial_loss", "eta_lower": 0.8}]).hover_speed_rad_s()
    assert with_loss == pytest.approx(math.sqrt(1.6 * 9.81 / (4 * 1.7e-5 * 1.8)), rel=1e-9)


@pytest.mark.parametrize("name", AIRFRAMES)
def test_every_number_in_config_has_its_unit_and_source(name: str) -> None:
    """Every top-level number carries a comment (same line or the block above): unit and source."""
    path = Path(load_airframe(name).source_path)
    lines = path.read_text().splitlines()
    for index, line in enumerate(lines):
        match = re.match(r"^(\w+):\s*([-+\d.\[][^#]*)(#.*)?$", line)
        if match and re.search(r"\d", match.group(2)):
            commented = match.group(3) is not None or lines[index - 1].lstrip().startswith("#")
            assert commented, f"{path.name}:{index + 1}: {match.group(1)} has no unit/source comment"


def _write(tmp_path: Path, document: dict) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def _x8_document() -> dict:
    return yaml.safe_load(Path(load_airframe("x8_octorotor").source_path).read_text())


@pytest.mark.parametrize(
    ("change", "key_in_message"),
    [
        (lambda d: d.update(wingspan_m=1.0), "wingspan_m"),
        (lambda d: d.pop("mass_kg"), "mass_kg"),
        (lambda d: d.update(mass_g=1600) or d.pop("mass_kg"), "mass_g"),
        (lambda d: d.update(mass_kg=-1.6), "mass_kg"),
        (lambda d: d.update(mass_kg=float("nan")), "mass_kg"),
        (lambda d: d.update(k_f_N_s2="a lot"), "k_f_N_s2"),
        (lambda d: d.update(inertia_kg_m2=[0.042, -0.042, 0.075]), "inertia_kg_m2"),
        (lambda d: d["rotors"][2].update(spin="sideways"), "rotors[2].spin"),
        (lambda d: d["rotors"][0].update(colour="red"), "rotors[0].colour"),
        (lambda d: [r.update(spin="ccw") for r in d["rotors"]], "rotors"),
        (lambda d: d.update(rotors=d["rotors"][:3]), "rotors"),
        (lambda d: d["effects"].append({"id": "warp_drive"}), "effects[1]"),
        (lambda d: d["effects"][0].update(c_q=1.0), "effects[0]"),
        (lambda d: d["motor_map"].update(input_unit="volts"), "motor_map.input_unit"),
        (lambda d: d.update(rotor_speed_max_rad_s=0.0), "rotor_speed_max_rad_s"),
    ],
)
def test_malformed_airframe_names_file_and_key(tmp_path: Path, change, key_in_message: str) -> None:
    document = _x8_document()
    change(document)
    path = _write(tmp_path, document)
    with pytest.raises(AirframeError) as error:
        load_airframe(path)
    assert str(path) in str(error.value)
    assert key_in_message in str(error.value)


def test_yaml_syntax_error_names_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("mass_kg: [1.6\nrotors: {")
    with pytest.raises(AirframeError, match="broken.yaml"):
        load_airframe(path)


def test_unknown_airframe_name_lists_known_ones() -> None:
    with pytest.raises(AirframeError, match="x8_octorotor"):
        load_airframe("no_such_airframe")


def test_motor_map_round_trip() -> None:
    motor_map = load_airframe("quad_x").motor_map
    pwm = np.linspace(1000, 2000, 11)
    np.testing.assert_allclose(motor_map.command_from_speed(motor_map.speed_from_command(pwm)), pwm)
    assert motor_map.speed_from_command(900) == 0.0
    assert motor_map.speed_from_command(2100) == 1100.0
