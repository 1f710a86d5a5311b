"""Look-alikes a hover cannot tell apart, and the flight the workflow proposes to tell them apart (issue 14).

In a hover every rotor turns at about one speed, so a payload (mass_offset), a weaker lower coaxial rotor
(coaxial_loss) and a thrust coefficient growing with speed (thrust_speed_dependence) scale the thrust
alike and the torques carry nothing but rotor-speed noise. Each hidden in turn in an X8 hover, the
answer must be the three of them, never one chosen; ``--propose-experiment`` writes the manoeuvre that
separates them; flying it with ``multirotor simulate`` (the true model holding the hidden effect) and
running the discrepancy on the new log alone names the hidden effect, without a look-alike.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from multirotor_ros.cli import main as cli_main
from multirotor_ros.discrepancy.experiment import MANOEUVRES, Proposal, Separation
from multirotor_ros.discrepancy.workflow import rotor_speed_noise
from multirotor_ros.simulation.flight import read_setpoints

pytestmark = pytest.mark.slow

LOOKALIKES = {"mass_offset", "coaxial_loss", "thrust_speed_dependence"}
HOVER_S = 30.0


def simulate(tmp: Path, name: str, setpoints: Path, duration_s: float, hidden: dict, seed: int) -> Path:
    out = tmp / f"{name}.csv"
    effects = json.dumps([hidden])
    argv = ["simulate", "--airframe", "x8_octorotor", "--setpoints", str(setpoints), "--out", str(out)]
    argv += ["--duration", f"{duration_s:g}", "--effects", effects, "--seed", str(seed)]
    argv += ["--physics-rate", "500"]
    assert cli_main(argv) == 0
    return out


def discrepancy(tmp: Path, log: Path, name: str, *extra: str) -> dict:
    out = tmp / name
    argv = ["discrepancy", "--airframe", "x8_octorotor", "--log", str(log), "--effects", "none"]
    assert cli_main([*argv, "--out", str(out), "--no-plots", "--quiet", *extra]) == 0
    return json.loads((out / "report.json").read_text())


@pytest.mark.parametrize(
    "hidden",
    [
        {"id": "mass_offset", "dm_kg": 0.15},
        {"id": "coaxial_loss", "eta_lower": 0.75},
        {"id": "thrust_speed_dependence", "k_f1": 5e-9},
    ],
    ids=lambda hidden: hidden["id"],
)
def test_a_hover_tie_is_an_answer_and_the_proposed_flight_resolves_it(tmp_path, capsys, hidden):
    hover = tmp_path / "hover_setpoints.csv"
    hover.write_text("t,x,y,z,yaw\n0,0,0,2,0\n")
    hover_log = simulate(tmp_path, "hover", hover, HOVER_S, hidden, seed=2)
    proposal_file = tmp_path / "next_flight.csv"
    tie = discrepancy(tmp_path, hover_log, "hover_report", "--propose-experiment", str(proposal_file))
    printed = capsys.readouterr().out

    # The tie is the answer: the hidden effect among the look-alikes, none of them chosen.
    named = {tie["missing_effect"], *(entry["effect"] for entry in tie["ambiguous_with"])}
    assert named == LOOKALIKES, tie["explanation"]
    assert "this log cannot tell them apart" in printed
    for entry in tie["ambiguous_with"]:
        assert set(entry["parameters"]) and set(entry["std"]) == set(entry["parameters"])

    # The proposal: a setpoint file simulate reads, its expected separations in report.json.
    proposed = tie["proposed_experiment"]
    assert proposed["setpoint_file"] == str(proposal_file) and proposed["separates"]
    assert len(proposed["separations"]) == 6  # each look-alike true, each other fitted to it
    assert proposed["worst_z"] == min(s["z"] for s in proposed["separations"]) >= proposed["z_needed"]
    assert set(proposed["worst_z_per_manoeuvre"]) == {m.name for m in MANOEUVRES}
    assert proposed["worst_z"] == max(proposed["worst_z_per_manoeuvre"].values())
    setpoints = read_setpoints(proposal_file)
    assert setpoints.shape[1] == 5 and np.all(np.diff(setpoints[:, 0]) > 0)
    assert "Proposed experiment" in tie["explanation"][-1]

    resolved = discrepancy(
        tmp_path,
        simulate(tmp_path, "proposed", proposal_file, proposed["duration_s"], hidden, seed=5),
        "proposed_report",
    )
    assert resolved["missing_effect"] == hidden["id"], resolved["explanation"]
    assert resolved["ambiguous_with"] == []
    for name, truth in hidden.items():
        if name != "id":
            assert resolved["parameters"][name] == pytest.approx(truth, rel=0.1)


def test_a_log_without_lookalikes_gets_no_proposal(tmp_path, capsys):
    setpoints = tmp_path / "steps.csv"
    setpoints.write_text("t,x,y,z,yaw\n0,0,0,2,0\n8,3,0,4,0\n16,-3,2,2,1.5\n24,0,0,2,0\n")
    log = simulate(
        tmp_path, "steps", setpoints, 30.0, {"id": "quadratic_drag", "c_x": 0.4, "c_y": 0.4, "c_z": 0.2}, 3
    )
    proposal_file = tmp_path / "next_flight.csv"
    report = discrepancy(tmp_path, log, "report", "--propose-experiment", str(proposal_file))
    assert report["missing_effect"] == "quadratic_drag" and report["ambiguous_with"] == []
    assert report["proposed_experiment"] is None and not proposal_file.exists()
    assert "no experiment proposed" in capsys.readouterr().out


def test_the_proposal_reads_as_it_decides():
    manoeuvre = MANOEUVRES[1]
    proposal = Proposal(
        manoeuvre,
        [
            Separation("mass_offset", "coaxial_loss", 1.0, 30.0),
            Separation("coaxial_loss", "mass_offset", 2.5, 0),
        ],
        {m.name: 0.0 for m in MANOEUVRES},
        ["mass_offset", "coaxial_loss"],
        "x8_octorotor",
        z_needed=4.0,
    )
    # The workflow reads the translational fit first and the torques otherwise: the larger decides.
    assert [s.z for s in proposal.separations] == [30.0, 2.5]
    assert proposal.worst.truth == "coaxial_loss" and not proposal.separates
    assert "short of the z = 4 needed" in proposal.summary()
    assert "(roll and pitch torques)" in proposal.summary()


def test_the_rotor_speed_noise_is_read_off_a_log_that_manoeuvres():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 30.0, 0.01)[:, None]
    # Rotor speeds a controller moves (a motor is a low-pass filter: smooth at 100 Hz), plus white noise.
    speeds = 400.0 + 60.0 * np.sin(0.8 * t + np.arange(4)) + 25.0 * np.sin(5.0 * t)
    sigma = np.array([1.0, 2.0, 4.0, 8.0])
    estimate = rotor_speed_noise(speeds + sigma * rng.standard_normal(speeds.shape))
    assert estimate == pytest.approx(sigma, rel=0.1)
    assert rotor_speed_noise(speeds) == pytest.approx(np.zeros(4), abs=0.1)
