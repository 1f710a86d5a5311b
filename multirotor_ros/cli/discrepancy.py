"""``multirotor discrepancy --airframe A --log L [--effects E1,E2 | none] --out DIR``: the missing effect."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from multirotor_ros.cli import CommandError

if TYPE_CHECKING:
    from multirotor_ros.discrepancy.workflow import DiscrepancyReport

COMMAND = "discrepancy"
HELP = "find where a model and a flight log disagree, name the missing effect, add it and show the gap shrink"

DESCRIPTION = """\
Run the baseline model (the airframe with --effects, by default its own effect list, parameters as
configured) on a flight log's measured attitude and rotor speeds; find where it disagrees with the
measured motion (per axis, time window and regime); try every translational effect of effects.md it
lacks, fitted on part of the log and scored on the rest; name the one that explains a significant part
of the disagreement (or none), add it, refit, and report the gap before and after.

Writes DIR/report.json (shared/spec/interfaces.md), PNG plots and a self-contained DIR/report.html.
"""

EPILOG = """\
examples:
  multirotor discrepancy --airframe x8_octorotor --log flight.csv --effects none --out gap
  multirotor discrepancy --airframe x8_octorotor --log flight.csv --max-effects 2 --out gap
  multirotor discrepancy --airframe x8_octorotor --log hover.csv --effects none --out gap \
      --propose-experiment next_flight.csv
"""


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--airframe", required=True, help="airframe config name or YAML path")
    parser.add_argument("--log", required=True, type=Path, help="flight-log CSV")
    parser.add_argument(
        "--effects", help="baseline effect list (comma-separated ids, or 'none'); default: the airframe's own"
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory (created)")
    parser.add_argument("--max-effects", type=int, default=1, help="name up to this many effects (default 1)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots (report.html has none)")
    parser.add_argument(
        "--no-accel-bias",
        action="store_true",
        help="do not remove a constant accelerometer bias along body x/y (removed by default when the log "
        "measures acceleration)",
    )
    parser.add_argument(
        "--propose-experiment",
        type=Path,
        metavar="FILE",
        help="when the log cannot tell look-alikes apart, write the setpoint file (multirotor simulate "
        "--setpoints) of the short flight that would, with its expected separation",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


def run(args: argparse.Namespace) -> int:
    """Run the workflow, write the report, print the verdict."""
    from multirotor_ros.discrepancy.workflow import find_discrepancy
    from multirotor_ros.model.airframe import AirframeError, load_airframe
    from multirotor_ros.model.effects import parse_effect_list

    def progress(message: str) -> None:
        if not args.quiet:
            print(f"discrepancy: {message}", file=sys.stderr, flush=True)

    if args.max_effects < 1:
        raise CommandError(f"--max-effects must be >= 1, got {args.max_effects}")
    try:
        airframe = load_airframe(args.airframe)
        baseline = None if args.effects is None else parse_effect_list(args.effects)
        report = find_discrepancy(
            airframe, args.log, baseline, max_effects=args.max_effects, progress=progress
        )
    except (AirframeError, ValueError, OSError) as error:
        raise CommandError(str(error)) from None
    if args.propose_experiment is not None:
        _propose_experiment(report, args.propose_experiment, progress)
    try:
        written = report.write(args.out, plots=not args.no_plots)
    except OSError as error:
        raise CommandError(f"{args.out}: cannot write: {error}") from None
    print(f"missing effect: {report.verdict()}")
    for name, value in report.parameters.items():
        sd = report.std.get(name)
        print(f"  {name} = {value:.6g}" + ("" if sd is None else f" +/- {sd:.2g}"))
    total_before = sum(report.mse_before.values())
    total_after = sum(report.mse_after.values())
    print(f"acceleration mse (sum over axes) before {total_before:.4g}, after {total_after:.4g} (m/s^2)^2")
    for line in report.explanation:
        print(f"  {line}")
    for warning in report.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _propose_experiment(report: DiscrepancyReport, path: Path, progress: Callable[[str], None]) -> None:
    """Write the flight that tells the report's look-alikes apart, and say so in the report."""
    from multirotor_ros.discrepancy.experiment import propose_experiment

    if not report.ambiguous_with:
        print(f"no experiment proposed: this log names {report.verdict()} without a look-alike")
        return
    progress("flying each look-alike through the candidate manoeuvres (noise-free) to propose an experiment")
    proposal = propose_experiment(report)
    assert proposal is not None  # the report has look-alikes
    try:
        proposal.write_setpoints(path)
    except OSError as error:
        raise CommandError(f"{path}: cannot write: {error}") from None
    report.proposed_experiment = proposal.to_json(path)
    report.explanation.append(proposal.summary())
    print(f"proposed experiment: {path} ({proposal.manoeuvre.name}, {proposal.manoeuvre.duration_s:g} s)")
