"""The README's command-line examples run as written, and what they print or write makes sense.

A fenced block is an example to run when every command in it is ``printf`` or ``.venv/bin/multirotor``
(``node`` and ``demo`` excepted: they run until stopped, and the ROS tests start them). Each block runs
with bash in its own temporary directory, where ``.venv/bin`` is this interpreter's bin directory.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from multirotor_ros.model.airframe import GRAVITY_M_S2, load_airframe

REPOSITORY = Path(__file__).resolve().parent.parent
COMMAND = ".venv/bin/multirotor"
LONG_RUNNING = ("node", "demo")
# The hidden-effect sweep's standard (README, "Hidden-effect sweep"): parameters within 15 %.
PARAMETER_TOLERANCE = 0.15
BLOCK_TIMEOUT_S = 60


@dataclass(frozen=True)
class Example:
    """One runnable README block: its source line and its commands (continuation lines joined)."""

    line: int
    commands: tuple[str, ...]

    @property
    def script(self) -> str:
        return "set -e\n" + "\n".join(self.commands) + "\n"

    def invocations(self, subcommand: str) -> list[list[str]]:
        """The argument lists after ``multirotor SUBCOMMAND``, one per such command."""
        found = []
        for command in self.commands:
            words = shlex.split(command)
            if words[:2] == [COMMAND, subcommand]:
                found.append(words[2:])
        return found


def _option(arguments: list[str], name: str) -> str:
    return arguments[arguments.index(name) + 1]


def readme_examples(text: str) -> list[Example]:
    """The runnable fenced blocks of a README (module docstring)."""
    examples = []
    for match in re.finditer(r"^```[^\n]*\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL):
        commands = re.sub(r"\\\n\s*", "", match.group(1)).strip().splitlines()
        runnable = bool(commands) and all(
            c.startswith("printf ") or (c.startswith(COMMAND + " ") and c.split()[1] not in LONG_RUNNING)
            for c in commands
        )
        if runnable and any(c.startswith(COMMAND) for c in commands):
            examples.append(Example(text.count("\n", 0, match.start()) + 1, tuple(commands)))
    return examples


EXAMPLES = readme_examples((REPOSITORY / "README.md").read_text(encoding="utf-8"))


def _is_slow(example: Example) -> bool:
    # Blocks that simulate or search take seconds: marked slow, they still run in `make test`.
    return any(example.invocations(s) for s in ("simulate", "discrepancy", "identify", "campaign"))


EXAMPLE_PARAMETERS = [
    pytest.param(e, id=f"README.md:{e.line}", marks=[pytest.mark.slow] if _is_slow(e) else [])
    for e in EXAMPLES
]


def test_the_readme_has_the_examples_this_file_checks() -> None:
    subcommands = {c.split()[1] for e in EXAMPLES for c in e.commands if c.startswith(COMMAND)}
    assert {"simulate", "discrepancy", "airframe"} <= subcommands


@pytest.mark.parametrize("example", EXAMPLE_PARAMETERS)
def test_readme_example_runs_and_its_output_makes_sense(example: Example, tmp_path: Path) -> None:
    bin_directory = Path(sys.executable).parent
    if not (bin_directory / "multirotor").exists():
        pytest.skip(f"no multirotor command beside {sys.executable} (pip install -e '.[test]')")
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / "bin").symlink_to(bin_directory)
    result = subprocess.run(
        ["bash", "-c", example.script],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=BLOCK_TIMEOUT_S,
    )
    output = f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    assert result.returncode == 0, f"README.md:{example.line} failed:\n{example.script}\n{output}"
    for arguments in example.invocations("discrepancy"):
        _check_discrepancy_finds_what_was_hidden(example, tmp_path, arguments)
    for arguments in example.invocations("airframe"):
        _check_airframe_hovers(result.stdout, arguments[0])
    for arguments in example.invocations("campaign"):
        _check_campaign_stored_every_case(tmp_path / _option(arguments, "--out"))


def _check_discrepancy_finds_what_was_hidden(example: Example, directory: Path, arguments: list[str]) -> None:
    log = _option(arguments, "--log")
    (simulation,) = [a for a in example.invocations("simulate") if _option(a, "--out") == log]
    hidden = {spec.pop("id"): spec for spec in json.loads(_option(simulation, "--effects"))}
    report = json.loads((directory / _option(arguments, "--out") / "report.json").read_text(encoding="utf-8"))
    fitted = {effect_id: report["parameters"] for effect_id in report["missing_effects"]}
    if report["ambiguous_with"]:
        # "X or Y: this log cannot tell them apart": the hidden effect is one of them, fitted as hidden,
        # and the experiment asked for was proposed.
        fitted.update({entry["effect"]: entry["parameters"] for entry in report["ambiguous_with"]})
        assert len(hidden) == 1 and set(hidden) <= set(fitted)
        if "--propose-experiment" in arguments:
            assert (directory / _option(arguments, "--propose-experiment")).is_file()
            assert report["proposed_experiment"]["separates"]
    else:
        assert report["missing_effects"] == list(hidden)
    for effect_id, effect_spec in hidden.items():
        for name, value in effect_spec.items():
            assert fitted[effect_id][name] == pytest.approx(value, rel=PARAMETER_TOLERANCE), name


def _check_campaign_stored_every_case(out: Path) -> None:
    # Exit status 0 says no case failed; each case has its row on disk and the page names them all.
    cases = json.loads((out / "campaign.json").read_text(encoding="utf-8"))["cases"]
    keys = [
        row["key"]
        for part in (out / "results").glob("part-*.parquet")
        for row in pq.read_table(part).to_pylist()
    ]
    assert sorted(keys) == sorted(case["key"] for case in cases)
    page = (out / "summary.html").read_text(encoding="utf-8")
    assert all(case["key"] in page for case in cases)


def _check_airframe_hovers(stdout: str, name: str) -> None:
    # An airframe without effects hovers where its rotors' thrust k_f N omega^2 equals its weight.
    description = json.loads(stdout)
    airframe = load_airframe(name)
    assert description["name"] == airframe.name
    assert not airframe.effects, "the check below holds for the rigid body and rotor thrust alone"
    thrust = airframe.n_rotors * airframe.k_f_N_s2 * description["hover_speed_rad_s"] ** 2
    assert thrust == pytest.approx(airframe.mass_kg * GRAVITY_M_S2, rel=1e-6)
    np.testing.assert_allclose(description["inertia_kg_m2"], airframe.inertia_kg_m2)
