"""The rotor balance: a weakened rotor, a payload or nothing, from the commands that keep a vehicle level.

Three levels: the balance equations on thrusts the test computes (exact answers), closed-loop simulated
Crazyflie flights (each rotor damaged in turn, two at once, an offset payload, a normal flight), and
real CrazyPAD flights through `identify` (several normal flights) and `discrepancy`.
"""

from __future__ import annotations

import dataclasses
import html
from pathlib import Path

import numpy as np
import pytest
import yaml

from multirotor_ros.cli import main as cli_main
from multirotor_ros.discrepancy.sweep import hidden_effect_flight
from multirotor_ros.discrepancy.workflow import find_discrepancy
from multirotor_ros.ident.identify import identify
from multirotor_ros.ident.rotor_balance import (
    BaselineState,
    FlightBalance,
    RotorBaseline,
    balance_rows,
    diagnose,
    flight_balance,
    rotor_baseline,
)
from multirotor_ros.io.convert import convert
from multirotor_ros.io.flight_log import write_flight_log
from multirotor_ros.model.airframe import GRAVITY_M_S2, AirframeError, airframe_from_dict, load_airframe

CRAZYPAD = Path(__file__).resolve().parents[2] / "shared" / "data" / "crazypad" / "motor_data"
if not CRAZYPAD.is_dir():  # CI clones main with shared/ beside it
    CRAZYPAD = Path("/work/shared/data/crazypad/motor_data")
needs_crazypad = pytest.mark.skipif(
    not CRAZYPAD.is_dir(), reason="shared/data/crazypad is not beside the repository"
)


@pytest.fixture(scope="module")
def crazyflie():
    return load_airframe("crazyflie_2_1")


def balanced_thrusts(airframe, mass_kg: float, cg_m=(0.0, 0.0), cw_ratio: float = 1.2) -> np.ndarray:
    """The thrusts that hold the vehicle level: weight, both moments about the cg, yaw balanced."""
    spin = airframe.spin_signs
    rows = np.vstack(
        [
            np.ones(airframe.n_rotors),
            airframe.rotor_positions_m[:, 1] - cg_m[1],
            airframe.rotor_positions_m[:, 0] - cg_m[0],
            np.where(spin < 0, -1.0, cw_ratio),
        ]
    )
    return np.linalg.solve(rows, [mass_kg * GRAVITY_M_S2, 0.0, 0.0, 0.0])


def balance(thrust: np.ndarray, error: float = 2e-4) -> FlightBalance:
    return FlightBalance("test", np.asarray(thrust, dtype=float), np.full(len(thrust), error), 20.0, True)


def test_a_weakened_rotor_a_payload_and_nothing_are_told_apart_on_exact_thrusts(crazyflie) -> None:
    normal = balanced_thrusts(crazyflie, 0.031, cg_m=(-0.002, 0.0004))
    jitter = np.random.default_rng(3).normal(0.0, 3e-4, (4, 4))
    baseline, warnings = rotor_baseline([balance(normal + j) for j in jitter])
    assert warnings == [] and baseline.n_flights == 4
    # The baseline's yaw weights make its own thrusts balance yaw, whatever the cw/ccw drag ratio.
    assert abs(balance_rows(crazyflie, baseline.thrust_N)[3] @ baseline.thrust_N) < 1e-12

    state = BaselineState.of(crazyflie, normal)
    assert state.mass_kg == pytest.approx(0.031) and state.cw_drag_ratio == pytest.approx(1.2)
    assert state.cg_m == pytest.approx((-0.002, 0.0004))

    same = diagnose(crazyflie, baseline, balance(normal))
    assert same.named == "none" and same.flagged == [] and same.ambiguous_with == []

    for rotor in range(4):
        effectiveness = np.ones(4)
        effectiveness[rotor] = 0.85
        weakened = diagnose(crazyflie, baseline, balance(normal / effectiveness))
        assert weakened.named == "rotor_effectiveness", weakened.headline()
        assert weakened.flagged == [rotor + 1]
        assert weakened.effectiveness[rotor] == pytest.approx(0.85, abs=0.01)
        assert weakened.ambiguous_with == [] and weakened.indistinct_rotors == []

    two = diagnose(crazyflie, baseline, balance(normal / np.array([1.0, 0.8, 1.0, 0.9])))
    assert two.named == "rotor_effectiveness" and two.flagged == [2, 4]

    loaded = balanced_thrusts(crazyflie, 0.034, cg_m=(-0.0035, 0.0015))
    payload = diagnose(crazyflie, baseline, balance(loaded))
    assert payload.named == "mass_offset+cg_offset", payload.headline()
    fitted = payload.explanations["mass_offset+cg_offset"].parameters
    assert fitted["dm_kg"] == pytest.approx(0.003, abs=2e-4)
    assert fitted["r_x"] == pytest.approx(-0.0015, abs=2e-4) and fitted["r_y"] == pytest.approx(
        0.0011, abs=2e-4
    )
    assert "payload +3.0 g at r_x = -1.5 mm, r_y = +1.1 mm" in payload.headline()


def test_rotors_whose_commands_rise_alike_are_named_together_not_one_of_them_at_random(crazyflie) -> None:
    """A weight or drag change moving two same-spin rotors alike leaves their e_k within noise."""
    normal = balanced_thrusts(crazyflie, 0.031)
    baseline = RotorBaseline(normal, 0.01 * normal, 4, ("a", "b", "c", "d"))
    alike = diagnose(crazyflie, baseline, balance(normal * [1.045, 1.0, 1.025, 1.0]))
    assert alike.named == "rotor_effectiveness" and alike.flagged == [1], alike.headline()
    assert alike.indistinct_rotors == [3]
    assert "rotor 1 weakened (or rotor 3: e_3 - e_1 = +0.019, within 2 std" in alike.headline()
    assert alike.to_json()["indistinct_rotors"] == [3]
    apart = diagnose(crazyflie, baseline, balance(normal * [1.045, 1.0, 1.0, 1.0]))
    assert apart.flagged == [1] and apart.indistinct_rotors == [], apart.headline()


def test_one_baseline_flight_is_used_with_a_warning_and_the_airframe_section_is_checked(crazyflie) -> None:
    baseline, warnings = rotor_baseline([balance(balanced_thrusts(crazyflie, 0.03))])
    assert "from one flight: the flight-to-flight scatter is unknown" in warnings[0]
    document = yaml.safe_load((Path(crazyflie.source_path)).read_text())
    document["rotor_balance"] = baseline.to_section()
    restored = RotorBaseline.of_airframe(airframe_from_dict(document, origin="cf.yaml"))
    assert restored is not None
    np.testing.assert_allclose(restored.thrust_N, baseline.thrust_N, rtol=1e-5)
    for bad, message in (
        (
            {"thrust_N": [0.07, 0.07, 0.07], "scatter_N": [0, 0, 0, 0], "flights": 2},
            "thrust_N: expected a list of 4",
        ),
        ({"thrust_N": [0.07] * 4, "scatter_N": [0, -1, 0, 0], "flights": 2}, r"scatter_N\[1\]: must be >= 0"),
        ({"thrust_N": [0.07] * 4, "scatter_N": [0] * 4, "flights": 1.5}, "flights: expected a whole number"),
        ({"thrust_N": [0.07] * 4, "scatter_N": [0] * 4}, "rotor_balance.flights: missing"),
    ):
        with pytest.raises(AirframeError, match=message):
            airframe_from_dict({**document, "rotor_balance": bad}, origin="cf.yaml")


def _crazyflie_flight(effects, seed: int):
    return hidden_effect_flight("crazyflie_2_1", effects, duration_s=20.0, seed=seed)


def _effectiveness(**weakened: float) -> list[dict]:
    return [{"id": "rotor_effectiveness", **{f"e_{k}": weakened.get(f"e_{k}", 1.0) for k in range(1, 5)}}]


def test_simulated_crazyflies_each_rotor_in_turn_two_at_once_and_a_payload(crazyflie) -> None:
    """Closed-loop flights along the excitation schedule; nothing here knows which rotor is damaged."""
    baseline, _ = rotor_baseline(
        [flight_balance(_crazyflie_flight([], seed), crazyflie) for seed in (1, 2, 3)]
    )
    cases = {f"rotor {k}": (_effectiveness(**{f"e_{k}": 0.85}), [k]) for k in range(1, 5)}
    cases["rotors 2 and 4"] = (_effectiveness(e_2=0.85, e_4=0.9), [2, 4])
    for name, (effects, damaged) in cases.items():
        found = diagnose(crazyflie, baseline, flight_balance(_crazyflie_flight(effects, 11), crazyflie))
        assert found.named == "rotor_effectiveness", (name, found.headline())
        assert found.flagged == damaged, (name, found.headline())
        assert int(np.argmin(found.effectiveness)) + 1 == damaged[0]
        assert np.all(found.z_scores[[k - 1 for k in damaged]] < -3.0)

    payload = [{"id": "mass_offset", "dm_kg": 0.003}, {"id": "cg_offset", "r_x": -0.0015, "r_y": 0.0015}]
    found = diagnose(crazyflie, baseline, flight_balance(_crazyflie_flight(payload, 11), crazyflie))
    assert found.named == "mass_offset+cg_offset", found.headline()
    fitted = found.explanations["mass_offset+cg_offset"].parameters
    assert fitted["dm_kg"] == pytest.approx(0.003, rel=0.15)

    normal = diagnose(crazyflie, baseline, flight_balance(_crazyflie_flight([], 12), crazyflie))
    assert normal.named == "none" and normal.flagged == [], normal.headline()


@needs_crazypad
def test_real_crazyflie_flights_identify_from_normal_flights_then_name_the_cut_propeller(tmp_path) -> None:
    """The mission's loop on CrazyPAD: the E9 session's normal flights are the baseline."""
    airframe = load_airframe("crazyflie_2_1")

    def flight(folder: str, name: str):
        return convert(CRAZYPAD / folder / name, airframe).log

    normals = [flight("normal_flight", name) for name in ("E9_log00", "E9_log01")]
    result = identify(airframe, normals, [])
    assert result.rotor_balance is not None and result.rotor_balance.n_flights == 2
    vehicle = result.to_json()["rotor_balance"]
    assert 0.0 < vehicle["std"]["r_x"] < 2e-4 and -0.004 < vehicle["cg_offset_m"]["r_x"] < 0.0
    assert 1.1 < vehicle["cw_over_ccw_drag_ratio"] < 1.3  # this Crazyflie's cw rotors carry less
    result.write(tmp_path, plots=False)
    identified = load_airframe(tmp_path / "crazyflie_2_1_identified.yaml")
    assert RotorBaseline.of_airframe(identified) is not None

    cut = find_discrepancy(identified, flight("cut_propeller_M3_3mm", "E9_log00"))
    assert cut.missing_effect == "rotor_effectiveness", cut.verdict()
    balance_report = cut.rotor_balance
    assert balance_report is not None
    effectiveness = np.array(balance_report["effectiveness"])
    std = np.array(balance_report["effectiveness_std"])
    assert int(np.argmin(effectiveness)) == 2 and (1.0 - effectiveness[2]) / std[2] > 3.0
    assert cut.parameters["e_3"] == pytest.approx(effectiveness[2])
    assert cut.to_json()["ambiguous_with"] == []
    written = cut.write(tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text()
    assert "rotor_effectiveness (named)" not in page  # a rotor-balance finding is no translational candidate
    from multirotor_ros.discrepancy.report import CAPTIONS

    plots = [path for path in written if path.suffix == ".png"]
    assert len(plots) >= 3
    assert all(html.escape(CAPTIONS[path.stem]) in page for path in plots)
    tie = dataclasses.replace(
        cut, ambiguous_with=[{"effect": "mass_offset+cg_offset", "parameters": {}, "std": {}}]
    )
    assert tie.verdict() == "rotor_effectiveness or mass_offset+cg_offset: this log cannot tell them apart"

    left_out = find_discrepancy(identified, flight("normal_flight", "E9_log02"))
    assert left_out.missing_effect == "none", left_out.verdict()
    assert left_out.rotor_balance is not None and left_out.rotor_balance["flagged_rotors"] == []


def test_an_airframe_without_a_rotor_balance_says_how_to_get_one(crazyflie) -> None:
    report = find_discrepancy(crazyflie, _crazyflie_flight([], 1), [])
    assert report.rotor_balance is None
    assert any("has no rotor_balance; `multirotor identify`" in line for line in report.explanation)


def test_the_command_line_identifies_from_several_logs_and_names_the_weak_rotor(tmp_path, capsys) -> None:
    logs = []
    for seed in (1, 2):
        path = tmp_path / f"normal{seed}.csv"
        write_flight_log(path, _crazyflie_flight([], seed))
        logs += ["--log", str(path)]
    suspect = tmp_path / "suspect.csv"
    write_flight_log(suspect, _crazyflie_flight(_effectiveness(e_4=0.85), 11))
    out = tmp_path / "fit"
    assert (
        cli_main(
            [
                "identify",
                "--airframe",
                "crazyflie_2_1",
                *logs,
                "--effects",
                "none",
                "--out",
                str(out),
                "--no-plots",
                "--quiet",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "identified k_f on normal1.csv + normal2.csv (crazyflie_2_1)" in printed
    assert "rotor balance over 2 flight(s): rotor thrusts [mN]" in printed
    airframe = out / "crazyflie_2_1_identified.yaml"
    assert (
        cli_main(
            [
                "discrepancy",
                "--airframe",
                str(airframe),
                "--log",
                str(suspect),
                "--out",
                str(tmp_path / "r"),
                "--no-plots",
                "--quiet",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert printed.startswith("missing effect: rotor_effectiveness\n")
    assert "rotor balance: rotor_effectiveness, rotor 4 weakened" in printed
