"""The model-discrepancy workflow on simulated flights with hidden effects (fast cases; the sweep is slow)."""

import base64
import json

import numpy as np
import pytest
from test_ident_flights import effect, flight, flight_csv

from multirotor_ros.cli import main as cli_main
from multirotor_ros.discrepancy import DiscrepancySettings
from multirotor_ros.discrepancy.workflow import find_discrepancy
from multirotor_ros.ident.identify import identify
from multirotor_ros.ident.samples import NotEnoughData
from multirotor_ros.io.flight_log import FlightLog, FlightLogError

INTERFACE_KEYS = {
    "log",
    "airframe",
    "baseline_effects",
    "metric",
    "mse_before",
    "where",
    "candidates",
    "missing_effect",
    "parameters",
    "mse_after",
}


def total(mse: dict) -> float:
    return sum(mse.values())


def assert_named(report, effect_id: str, truth: dict, rel: float = 0.15) -> None:
    assert report.missing_effect == effect_id, report.explanation
    for name, value in truth.items():
        assert report.parameters[name] == pytest.approx(value, rel=rel), name
    assert total(report.mse_after) < 0.5 * total(report.mse_before)


@pytest.fixture(scope="module")
def quadratic_report():
    log = flight(
        "x8_octorotor", (effect("quadratic_drag", c_x=0.4, c_y=0.4, c_z=0.2),), duration_s=30.0, seed=11
    )
    return find_discrepancy("x8_octorotor", log, [])


def test_names_a_hidden_quadratic_drag_with_its_parameters(quadratic_report):
    assert_named(quadratic_report, "quadratic_drag", {"c_x": 0.4, "c_y": 0.4, "c_z": 0.2})
    best = quadratic_report.candidates[0]
    assert best.effect == "quadratic_drag" and best.significant and best.z_statistic >= 3
    assert "horizontal speed" in " ".join(w["regime"] for w in quadratic_report.where)


def test_effects_with_a_parameter_per_rotor_are_not_testable_with_the_reason(quadratic_report):
    # rotor_effectiveness: translational motion sees only the rotors' combined thrust.
    assert "per rotor" in quadratic_report.not_testable["rotor_effectiveness"]
    assert all(c.effect != "rotor_effectiveness" for c in quadratic_report.candidates)


def test_settings_set_the_thresholds():
    log = flight(
        "x8_octorotor", (effect("quadratic_drag", c_x=0.4, c_y=0.4, c_z=0.2),), duration_s=30.0, seed=11
    )
    report = find_discrepancy("x8_octorotor", log, [], settings=DiscrepancySettings(z_critical=1e6, folds=4))
    assert report.missing_effect == "none"
    assert "needs z >= 1e+06" in report.explanation[0]
    assert report.split.startswith("4-fold")


@pytest.mark.parametrize("kept", ["position and velocity", "position alone"])
def test_works_when_the_log_has_no_acceleration(kept):
    log = flight(
        "x8_octorotor", (effect("quadratic_drag", c_x=0.4, c_y=0.4, c_z=0.2),), duration_s=30.0, seed=11
    )
    dropped = {"ax", "ay", "az"} | ({"vx", "vy", "vz"} if kept == "position alone" else set())
    partial = FlightLog(log.t, {k: v for k, v in log.columns.items() if k not in dropped}, dict(log.metadata))
    report = find_discrepancy("x8_octorotor", partial, [])
    assert_named(report, "quadratic_drag", {"c_x": 0.4, "c_y": 0.4, "c_z": 0.2})
    assert any("Savitzky-Golay" in note for note in report.notes)


def test_report_json_follows_interfaces_md_and_html_is_self_contained(quadratic_report, tmp_path):
    written = quadratic_report.write(tmp_path)
    document = json.loads((tmp_path / "report.json").read_text())
    assert INTERFACE_KEYS <= set(document)
    assert document["missing_effect"] == "quadratic_drag"
    assert document["baseline_effects"] == []
    for key in ("mse_before", "mse_after"):
        assert set(document[key]) == {"x", "y", "z"}
    for window in document["where"]:
        assert set(window) >= {"axis", "t_start", "t_end", "share_of_error", "regime"}
        assert 0 < window["share_of_error"] <= 1
    for candidate in document["candidates"]:
        assert set(candidate) >= {"effect", "parameters", "mse_after", "score"}
    assert "(m/s^2)^2" in document["metric"]
    html = (tmp_path / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len([p for p in written if p.suffix == ".png"]) >= 4
    assert "<img" in html and 'src="http' not in html and "quadratic_drag" in html
    png = html.split("data:image/png;base64,")[1].split('"')[0]
    assert base64.b64decode(png)[:8] == b"\x89PNG\r\n\x1a\n"


def test_says_none_when_nothing_is_hidden():
    # The simulated X8 has exactly the airframe's own effects, which are the default baseline.
    report = find_discrepancy("x8_octorotor", flight("x8_octorotor", None, duration_s=30.0, seed=12))
    assert report.missing_effect == "none", [(c.effect, c.score, c.z_statistic) for c in report.candidates]
    assert report.parameters == {}
    assert report.mse_after == report.mse_before
    assert any("none" in line for line in report.explanation)


@pytest.mark.parametrize(
    ("hidden", "truth", "lookalike"),
    [
        ("mass_offset", {"dm_kg": 0.12}, "thrust_speed_dependence"),
        ("thrust_speed_dependence", {"k_f1": 4e-9}, "mass_offset"),
        ("rotor_drag", {"k_h": 1.5e-4}, "quadratic_drag"),
        ("coaxial_loss", {"eta_lower": 0.8}, "mass_offset"),
    ],
)
def test_tells_lookalikes_apart_by_the_regime_or_the_torques(hidden, truth, lookalike):
    log = flight("x8_octorotor", (effect(hidden, **truth),), duration_s=30.0, seed=13)
    report = find_discrepancy("x8_octorotor", log, [])
    assert_named(report, hidden, truth)
    rival = next(c for c in report.candidates if c.effect == lookalike)
    # The look-alike explains much of the same error, yet is not named, for a stated reason.
    assert rival.effect not in report.missing_effects
    assert rival.verdict.startswith("explained away") or not rival.significant
    assert not report.candidates[0].ambiguous_with or report.candidates[0].effect != hidden


def test_names_an_actuator_fault_on_the_hexarotor():
    truth = {"motor": 4, "effectiveness": 0.7, "t_fault_s": 18.0}
    log = flight("hexarotor_f550", (effect("actuator_fault", **truth),), duration_s=30.0, seed=14)
    report = find_discrepancy("hexarotor_f550", log)
    assert report.missing_effect == "actuator_fault"
    assert report.parameters["motor"] == 4
    assert report.parameters["effectiveness"] == pytest.approx(0.7, rel=0.15)
    assert report.parameters["t_fault_s"] == pytest.approx(18.0, abs=0.1)
    assert total(report.mse_after) < 0.5 * total(report.mse_before)


def test_a_baseline_effect_the_airframe_does_not_configure_is_fitted_first():
    truth = (effect("quadratic_drag", c_x=0.3, c_y=0.3, c_z=0.1), effect("mass_offset", dm_kg=0.08))
    log = flight("hexarotor_f550", truth, duration_s=30.0, seed=19)
    report = find_discrepancy("hexarotor_f550", log, ["quadratic_drag"])
    assert report.baseline_effects == ["quadratic_drag"]
    assert any("fitted to this log first" in note for note in report.notes)
    assert_named(report, "mass_offset", {"dm_kg": 0.08})


def test_names_two_hidden_effects_with_max_effects_2():
    hidden = (effect("rotor_drag", k_h=1.5e-4), effect("mass_offset", dm_kg=0.12))
    report = find_discrepancy(
        "x8_octorotor", flight("x8_octorotor", hidden, duration_s=30.0, seed=15), [], max_effects=2
    )
    assert sorted(report.missing_effects) == ["mass_offset", "rotor_drag"]
    assert report.parameters["k_h"] == pytest.approx(1.5e-4, rel=0.15)
    assert report.parameters["dm_kg"] == pytest.approx(0.12, rel=0.15)
    assert {c.round for c in report.candidates} == {1, 2}
    first_round_best = min(sum(c.mse_after.values()) for c in report.candidates if c.round == 1)
    assert total(report.mse_after) < 0.5 * first_round_best


def test_seed_1_story_simplified_model_against_the_identified_one():
    """Seed 1 §III-D on a simulated X8, as in its Figs. 5-12.

    Thrust and gravity alone miss the motion; speed-dependent thrust, hub forces and drag close the gap,
    in acceleration and in position over short horizons.
    """
    truth = (
        effect("quadratic_drag", c_x=0.4688, c_y=0.4688, c_z=0.0),
        effect("rotor_drag", k_h=1e-4),
        effect("thrust_speed_dependence", k_f1=3e-9),
    )
    log = flight("x8_octorotor", truth, duration_s=45.0, seed=16)
    report = find_discrepancy("x8_octorotor", log, [], max_effects=3)
    assert sorted(report.missing_effects) == ["quadratic_drag", "rotor_drag", "thrust_speed_dependence"]
    assert total(report.mse_after) < 0.1 * total(report.mse_before)
    assert total(report.position_mse_after) < 0.2 * total(report.position_mse_before)
    identified = identify("x8_octorotor", log, ["thrust_speed_dependence", "rotor_drag", "quadratic_drag"])
    assert identified.parameters["c_x"] == pytest.approx(0.4688, rel=0.1)
    assert identified.parameters["k_f1"] == pytest.approx(3e-9, rel=0.15)


def test_cli_writes_the_report_and_prints_the_verdict(tmp_path, capsys):
    log = flight(
        "x8_octorotor", (effect("constant_force", f_x=0.5, f_y=-0.3, f_z=0.2),), duration_s=25.0, seed=17
    )
    path = flight_csv(tmp_path, "wind", log)
    status = cli_main(
        [
            "discrepancy",
            "--airframe",
            "x8_octorotor",
            "--log",
            str(path),
            "--effects",
            "none",
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ]
    )
    assert status == 0
    document = json.loads((tmp_path / "out" / "report.json").read_text())
    assert document["missing_effect"] == "constant_force"
    assert document["log"] == "wind.csv"
    assert document["parameters"]["f_x"] == pytest.approx(0.5, rel=0.15)
    assert "missing effect: constant_force" in capsys.readouterr().out


def test_bad_input_gets_a_clear_message_and_no_effect_on_no_evidence(tmp_path, capsys):
    hexa = flight("hexarotor_f550", duration_s=8.0, seed=18)
    with pytest.raises(FlightLogError, match="rotor"):
        find_discrepancy("x8_octorotor", hexa, [])
    log = flight("x8_octorotor", duration_s=8.0, seed=18)
    short = FlightLog(log.t[:400], {k: v[:400] for k, v in log.columns.items()}, dict(log.metadata))
    with pytest.raises(NotEnoughData, match="needs at least"):
        find_discrepancy("x8_octorotor", short, [])
    path = flight_csv(tmp_path, "hexa", hexa)
    assert (
        cli_main(
            ["discrepancy", "--airframe", "x8_octorotor", "--log", str(path), "--out", str(tmp_path / "o")]
        )
        == 2
    )
    assert "rotor" in capsys.readouterr().err


def test_a_hover_cannot_reveal_horizontal_drag_and_says_so():
    # Horizontal drag only: the take-off climb would reveal a vertical one.
    hover = flight(
        "x8_octorotor",
        (effect("quadratic_drag", c_x=0.4, c_y=0.4, c_z=0.0),),
        duration_s=15.0,
        setpoints=((1.0, 0.0, 0.0, 1.5, 0.0),),
    )
    report = find_discrepancy("x8_octorotor", hover, [])
    assert report.missing_effect == "none"
    # Rotor drag acts on horizontal speed only: untestable. Quadratic drag keeps c_z (the take-off climb).
    assert (
        "rotor_drag" in report.not_testable and "body-horizontal speed" in report.not_testable["rotor_drag"]
    )
    drag = next(c for c in report.candidates if c.effect == "quadratic_drag")
    assert set(drag.not_identifiable) == {"c_x", "c_y"}
    assert any("Not testable" in line for line in report.explanation)
    assert np.isfinite(total(report.mse_before))


# ---------------------------------------------------------------------------------------------
# Reports that never contradict themselves (issue 14, item 4)


def test_two_effects_that_add_to_each_other_are_said_present_only_if_a_round_names_both():
    from multirotor_ros.discrepancy.workflow import Naming, _both_present_sentence

    named_both = Naming({}, named=["rotor_drag", "quadratic_drag"])
    assert _both_present_sentence(1, "rotor_drag", "quadratic_drag", named_both, 2).endswith(
        "both are present, and round 2 names quadratic_drag."
    )
    named_one = Naming({}, named=["rotor_drag"])
    assert _both_present_sentence(1, "rotor_drag", "quadratic_drag", named_one, 2).endswith(
        "with rotor_drag in the model quadratic_drag is no longer significant in round 2: "
        "only rotor_drag is named."
    )
    assert _both_present_sentence(1, "rotor_drag", "quadratic_drag", named_one, 1).endswith(
        "quadratic_drag may be present too; --max-effects 2 tests it in a further round."
    )


def test_a_regime_variable_without_spread_is_never_a_regime():
    from multirotor_ros.discrepancy.regimes import RegimeVariable, concentration

    rows = np.ones(200, dtype=bool)
    error = np.linspace(0.0, 1.0, 200) ** 2
    constant = RegimeVariable("split", "lower rotors' share of thrust", "", np.full(200, 0.5))
    speed = RegimeVariable("speed", "horizontal speed", "m/s", np.linspace(0.0, 3.0, 200))
    found = concentration(error, rows, [constant, speed])
    assert [c.variable for c in found] == ["speed"]
    assert "0.5 to 0.5" not in found[0].text and "highest fifth" in found[0].text


def test_a_fault_with_no_flight_before_its_onset_is_not_significant_and_an_onset_is_stated():
    from multirotor_ros.discrepancy.workflow import _onset_without_flight_before, _regime_text
    from multirotor_ros.ident.samples import load_samples
    from multirotor_ros.model.airframe import load_airframe

    samples = load_samples(flight("x8_octorotor", duration_s=8.0, seed=5), load_airframe("x8_octorotor"))
    first = float(samples.t[samples.valid][0])
    why = _onset_without_flight_before({"t_fault_s": first + 0.05}, samples, DiscrepancySettings())
    assert why is not None and why.startswith("not significant: its onset") and "rotor_effectiveness" in why
    assert _onset_without_flight_before({"t_fault_s": 5.0}, samples, DiscrepancySettings()) is None
    assert _onset_without_flight_before({"k_h": 1e-4}, samples, DiscrepancySettings()) is None
    assert _regime_text({"t_fault_s": 40.0}, []) == "explains nothing"


def test_a_parameter_on_its_bound_is_reported_as_a_bound_without_a_std():
    from multirotor_ros.ident.parameters import FittedParameter
    from multirotor_ros.model.airframe import load_airframe

    x8 = load_airframe("x8_octorotor")
    tau = FittedParameter.of(("motor_lag", "tau_s"), x8)
    assert tau.bound_reached(tau.lower) == f"lower bound {tau.lower:.6g}"
    assert tau.bound_reached(0.5 * (tau.lower + min(tau.upper, 1.0))) is None
    motor = FittedParameter.of(("actuator_fault", "motor"), x8)
    assert motor.bound_reached(motor.lower) is None  # a rotor number: its range bounds no estimate
