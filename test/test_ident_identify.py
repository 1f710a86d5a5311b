"""Offline identification (multirotor identify) on simulated flights with known parameters, and bad input."""

import json

import numpy as np
import pytest
from test_ident_flights import effect, flight, flight_csv

from multirotor_ros.cli import main as cli_main
from multirotor_ros.ident.identify import identify
from multirotor_ros.ident.samples import LogMismatch, NotEnoughData, load_samples
from multirotor_ros.io.flight_log import FlightLog, FlightLogError
from multirotor_ros.model.airframe import load_airframe

X8 = load_airframe("x8_octorotor")
DRAGS = (effect("quadratic_drag", c_x=0.4688, c_y=0.4688, c_z=0.2), effect("rotor_drag", k_h=1.5e-4))
TRUTH = {"k_f_N_s2": X8.k_f_N_s2, "c_x": 0.4688, "c_y": 0.4688, "c_z": 0.2, "k_h": 1.5e-4}
HOVER = ((1.0, 0.0, 0.0, 1.5, 0.0),)


@pytest.fixture(scope="module")
def drag_flight():
    return flight("x8_octorotor", DRAGS, duration_s=60.0, seed=1)


@pytest.fixture(scope="module")
def drag_result(drag_flight):
    return identify(
        X8,
        drag_flight,
        ["quadratic_drag", "rotor_drag"],
        validation_log=flight("x8_octorotor", DRAGS, duration_s=30.0, seed=2),
    )


def test_k_f_drag_and_k_h_come_back_within_5_percent_from_a_60_s_flight(drag_result):
    for name, truth in TRUTH.items():
        assert drag_result.parameters[name] == pytest.approx(truth, rel=0.05), name
        assert 0 < drag_result.std[name] < 0.05 * truth, name
    assert not drag_result.not_identifiable


def test_fit_shrinks_the_error_on_the_identification_and_the_validation_log(drag_result):
    for fit in (drag_result.identification, drag_result.validation):
        assert sum(fit.mse_after.values()) < 0.1 * sum(fit.mse_before.values())
        assert sum(fit.position_mse_after.values()) < sum(fit.position_mse_before.values())


def test_cli_writes_identified_json_and_a_loadable_airframe_yaml(drag_flight, tmp_path, capsys):
    log_path = flight_csv(tmp_path, "drag", drag_flight)
    out = tmp_path / "fit"
    status = cli_main(
        [
            "identify",
            "--airframe",
            "x8_octorotor",
            "--log",
            str(log_path),
            "--effects",
            "quadratic_drag,rotor_drag",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert status == 0
    document = json.loads((out / "identified.json").read_text())
    assert set(document) >= {"parameters", "std", "mse_before", "mse_after"}
    assert set(document["mse_before"]) == {"x", "y", "z"}
    assert document["parameters"]["k_h"] == pytest.approx(1.5e-4, rel=0.05)
    fitted = load_airframe(out / "x8_octorotor_identified.yaml")
    assert fitted.k_f_N_s2 == pytest.approx(document["parameters"]["k_f_N_s2"])
    assert {spec["id"] for spec in fitted.effect_specs()} == {"quadratic_drag", "rotor_drag"}
    assert (out / "identification_acceleration.png").stat().st_size > 10_000
    assert "k_h" in capsys.readouterr().out


def test_nonlinear_parameters_are_found_by_search():
    truth = (
        effect("ground_effect", rotor_radius_m=0.127),
        effect("motor_lag", tau_s=0.04),
        effect("actuator_fault", motor=6, effectiveness=0.7, t_fault_s=20.0),
    )
    result = identify(
        X8,
        flight("x8_octorotor", truth, duration_s=30.0, seed=4),
        ["ground_effect", "motor_lag", "actuator_fault"],
    )
    assert result.parameters["rotor_radius_m"] == pytest.approx(0.127, rel=0.1)
    assert result.parameters["tau_s"] == pytest.approx(0.04, rel=0.1)
    assert result.parameters["motor"] == 6
    assert result.parameters["effectiveness"] == pytest.approx(0.7, abs=0.05)
    assert result.parameters["t_fault_s"] == pytest.approx(20.0, abs=0.05)


def test_a_hover_says_which_drag_parameters_are_not_identifiable_and_why():
    hover = flight("x8_octorotor", DRAGS, duration_s=15.0, setpoints=HOVER)
    result = identify(X8, hover, ["quadratic_drag", "rotor_drag"])
    for name in ("c_x", "c_y", "k_h"):
        assert result.parameters[name] is None, name
        assert (
            "too little excitation" in result.not_identifiable[name]
            or "collinear" in result.not_identifiable[name]
        )
    assert "|v_x|" in result.not_identifiable["c_x"]
    assert any("c_x" in w and "not identifiable" in w for w in result.warnings)
    # k_f is still well determined by a hover.
    assert result.parameters["k_f_N_s2"] == pytest.approx(X8.k_f_N_s2, rel=0.01)


def test_a_mass_offset_beside_k_f_is_reported_as_collinear_not_as_a_number():
    result = identify(
        X8, flight("x8_octorotor", (effect("mass_offset", dm_kg=0.1),), duration_s=20.0), ["mass_offset"]
    )
    # k_f and dm scale the same force: one of them is held, and the message says so.
    held = [name for name in ("k_f_N_s2", "dm_kg") if result.parameters[name] is None]
    assert held == ["k_f_N_s2"]
    assert "collinear with dm_kg" in result.not_identifiable["k_f_N_s2"]
    assert result.parameters["dm_kg"] == pytest.approx(0.1, rel=0.05)


def _edit(log: FlightLog, **changes) -> FlightLog:
    columns = {k: v.copy() for k, v in log.columns.items()}
    t = log.t.copy()
    for name, function in changes.items():
        if name == "t":
            t = function(t)
        else:
            columns[name] = function(columns[name])
    return FlightLog(t, columns, dict(log.metadata))


def test_duplicated_and_out_of_order_stamps_are_errors_naming_the_line(tmp_path):
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    path = flight_csv(tmp_path, "ok", log)
    lines = path.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("t,"))
    duplicated = lines[: header + 12] + [lines[header + 11]] + lines[header + 12 :]
    (tmp_path / "dup.csv").write_text("\n".join(duplicated) + "\n")
    with pytest.raises(FlightLogError, match=rf"dup.csv:{header + 13}: column 't': duplicated time stamp"):
        identify(X8, tmp_path / "dup.csv", [])
    swapped = lines[: header + 11] + [lines[header + 12], lines[header + 11]] + lines[header + 13 :]
    (tmp_path / "swap.csv").write_text("\n".join(swapped) + "\n")
    with pytest.raises(FlightLogError, match="out of order"):
        identify(X8, tmp_path / "swap.csv", [])


def test_a_log_of_another_airframe_is_refused():
    hexa_log = flight("hexarotor_f550", duration_s=8.0, seed=5)
    with pytest.raises(FlightLogError, match="8|rotor"):
        identify(X8, hexa_log, [])


def test_rotor_speeds_in_rpm_are_recognised():
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    rpm = _edit(log, **{f"omega_{k}": (lambda w: w * 30 / np.pi) for k in range(1, 9)})
    with pytest.raises(LogMismatch, match="look like rpm"):
        identify(X8, rpm, [])


def test_an_attitude_in_degrees_is_refused_with_its_evidence():
    """By its range where an angle goes beyond what radians allow, else by p and q (issue 13)."""
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    degrees = _edit(log, **{name: np.degrees for name in ("roll", "pitch", "yaw")})
    with pytest.raises(
        LogMismatch, match=r"column (roll|pitch) is .* which no ZYX .* looks logged in degrees"
    ):
        identify(X8, degrees, [])
    # A gentle flight: never beyond 1.5 degrees, which a pitch in radians may be, so only the rates can tell.
    gentle = _edit(log, **{name: (lambda x: 0.05 * x) for name in ("roll", "pitch", "p", "q")})
    assert np.degrees(np.abs(np.concatenate([gentle.column("roll"), gentle.column("pitch")]))).max() < 1.5
    identify(X8, gentle, [])  # radians: accepted
    gentle_degrees = _edit(gentle, **{name: np.degrees for name in ("roll", "pitch", "yaw")})
    with pytest.raises(LogMismatch, match=r"change 5\d\.\d times as fast as the body rates p and q"):
        identify(X8, gentle_degrees, [])


def test_accelerations_in_g_are_refused_with_their_evidence():
    """Against the rate of change of the logged velocity (issue 13); the same log in m/s^2 is accepted."""
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    in_g = _edit(log, **{name: (lambda a: a / 9.80665) for name in ("ax", "ay", "az")})
    with pytest.raises(LogMismatch, match=r"columns ax, ay, az are 0\.10\d times the rate of change of vx"):
        identify(X8, in_g, [])
    identify(X8, log, [])


def test_a_rest_with_motors_off_and_a_noisy_estimate_is_ground_not_flight():
    """Motors off at 2-3 cm, the estimate's velocity and acceleration wandering as an EKF's on the ground."""
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    rest_s, dt = 3.0, float(np.median(np.diff(log.t)))
    n = round(rest_s / dt)
    rng = np.random.default_rng(3)
    rest = {name: np.zeros(n) for name in log.columns}
    rest["z"] = 0.025 + 0.005 * rng.standard_normal(n)
    for name in ("vx", "vy", "vz"):
        rest[name] = 0.1 * rng.standard_normal(n)
    for name in ("ax", "ay", "az"):
        rest[name] = 1.0 * rng.standard_normal(n)
    rested = FlightLog(
        np.concatenate([np.arange(n) * dt, log.t + rest_s]),
        {name: np.concatenate([rest[name], values]) for name, values in log.columns.items()},
        dict(log.metadata),
    )
    samples = load_samples(rested, X8)
    assert not np.any(samples.valid[:n])
    assert any("on the ground are not fitted" in note for note in samples.notes + samples.warnings)
    assert np.count_nonzero(samples.valid[n:]) == np.count_nonzero(load_samples(log, X8).valid)


def test_nan_samples_and_gaps_are_left_out_with_a_warning():
    log = flight("x8_octorotor", DRAGS, duration_s=20.0, seed=6)
    rng = np.random.default_rng(0)
    holes = rng.choice(np.arange(100, log.t.size - 100), 40, replace=False)
    with_nan = _edit(log, omega_3=lambda w: np.where(np.isin(np.arange(w.size), holes), np.nan, w))
    keep = np.ones(log.t.size, dtype=bool)
    keep[700:760] = False  # 0.6 s of missing rows
    gapped = FlightLog(
        with_nan.t[keep], {k: v[keep] for k, v in with_nan.columns.items()}, dict(log.metadata)
    )
    samples = load_samples(gapped, X8)
    text = " ".join(samples.warnings)
    assert "40 samples (" in text and "lack attitude, rotor speeds" in text
    assert "1 gap(s) in time" in text
    assert not np.any(samples.valid[np.isin(np.arange(log.t.size), holes)[keep]])
    result = identify(X8, gapped, ["quadratic_drag", "rotor_drag"])
    assert result.parameters["k_h"] == pytest.approx(1.5e-4, rel=0.1)


def test_a_log_too_short_is_an_error_saying_what_is_missing():
    log = flight("x8_octorotor", duration_s=8.0, seed=5)
    short = FlightLog(log.t[300:330], {k: v[300:330] for k, v in log.columns.items()}, dict(log.metadata))
    with pytest.raises(NotEnoughData, match="only 30 usable samples"):
        identify(X8, short, [])


def test_rotational_effects_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="rotational effects are not identified"):
        identify(X8, flight("x8_octorotor", duration_s=8.0, seed=5), ["gyroscopic"])


def test_a_weak_rotor_is_named_not_identifiable_rather_than_fitted_from_the_force_alone():
    """rotor_effectiveness: each rotor's share of the thrust shows in the torque balance, not in the force.

    Fitted from the force alone, e_1 ... e_8 come out confident and wrong (the loss of rotor 3 spread over
    its neighbours, differently from log to log), so the identifier names every e_i and says why.
    """
    weak_rotor = {f"e_{i}": 0.8 if i == 3 else 1.0 for i in range(1, 9)}
    log = flight("x8_octorotor", (effect("rotor_effectiveness", **weak_rotor),), duration_s=40.0, seed=7)
    result = identify(X8, log, ["rotor_effectiveness"])
    for i in range(1, 9):
        assert result.parameters[f"e_{i}"] is None
        assert "torque balance" in result.not_identifiable[f"e_{i}"]
    # k_f takes the mean loss of thrust: one rotor of eight at 80 %.
    assert result.parameters["k_f_N_s2"] == pytest.approx(0.975 * X8.k_f_N_s2, rel=0.01)
