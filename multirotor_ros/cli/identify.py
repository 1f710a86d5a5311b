"""``multirotor identify --airframe A --log L --effects E1,E2 --out DIR``: fit a model to a flight log."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from multirotor_ros.cli import CommandError

COMMAND = "identify"
HELP = "fit k_f and the parameters of chosen effects to a flight log (identified.json and an airframe YAML)"

DESCRIPTION = """\
Fit the model "base + exactly the effects given" to a flight-log CSV (shared/spec/flight_log.md): the
base thrust coefficient k_f and every parameter of the effects (shared/spec/effects.md names), the
airframe's own effect list being replaced. Parameters entering the force linearly are solved exactly
(least squares on the acceleration, seed 1 eq. 11); ground_effect's radius and motor_lag's time constant
by a bounded search; actuator_fault's rotor and onset by an exhaustive search.

A parameter the log cannot determine (too little excitation, or collinear with another) is reported as
not identifiable, with the reason, instead of a number. Missing motion groups are derived (and the
model's output passes through the same filter); samples without data, across gaps or on the ground are
left out and counted in a warning.

Several --log options fit several flights of the vehicle together (each keeps its own gaps and
accelerometer bias). From the same flights comes the vehicle's rotor balance: the mean thrust each
rotor gives in steady flight and its flight-to-flight scatter, the weight carried, the centre of
gravity and the yaw balance. `multirotor discrepancy` measures a suspect flight's rotors against it.

Writes DIR/identified.json (parameters, std, mse_before, mse_after per axis, validation, rotor balance,
warnings), DIR/<airframe>_identified.yaml (loadable airframe with the fitted values and the
rotor_balance section) and PNG plots of measured against modelled acceleration and position.
"""

EPILOG = """\
examples:
  multirotor identify --airframe x8_octorotor --log flight.csv --effects quadratic_drag,rotor_drag --out fit
  multirotor identify --airframe x8_octorotor --log id.csv --validation-log val.csv --effects none --out fit
  multirotor identify --airframe crazyflie_2_1 --log n1.csv --log n2.csv --log n3.csv --effects none --out cf
"""


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--airframe", required=True, help="airframe config name or YAML path")
    parser.add_argument(
        "--log",
        required=True,
        type=Path,
        action="append",
        help="identification flight-log CSV; repeat for several flights of the vehicle, fitted together "
        "(their rotor balance is the baseline the discrepancy workflow measures a suspect flight against)",
    )
    parser.add_argument(
        "--effects",
        required=True,
        help="comma-separated effect ids of effects.md to fit besides k_f, or 'none'",
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory (created)")
    parser.add_argument("--validation-log", type=Path, help="a separate flight-log CSV to validate on")
    parser.add_argument(
        "--fix-k-f", action="store_true", help="keep the airframe's k_f instead of fitting it"
    )
    parser.add_argument(
        "--no-accel-bias",
        action="store_true",
        help="do not fit the accelerometer's body x/y bias as a nuisance (fitted by default when the "
        "log measures acceleration)",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


def run(args: argparse.Namespace) -> int:
    """Identify, write the results, print a summary; warnings go to stderr."""
    from multirotor_ros.ident.identify import identify
    from multirotor_ros.model.airframe import AirframeError, load_airframe
    from multirotor_ros.model.effects import parse_effect_list

    def progress(message: str) -> None:
        if not args.quiet:
            print(f"identify: {message}", file=sys.stderr, flush=True)

    try:
        airframe = load_airframe(args.airframe)
        effects = parse_effect_list(args.effects)
        result = identify(
            airframe,
            args.log,
            effects,
            validation_log=args.validation_log,
            progress=progress,
            fit_k_f=not args.fix_k_f,
            accelerometer_bias=not args.no_accel_bias,
        )
    except (AirframeError, ValueError, OSError) as error:
        raise CommandError(str(error)) from None
    try:
        written = result.write(args.out, plots=not args.no_plots)
    except OSError as error:
        raise CommandError(f"{args.out}: cannot write: {error}") from None
    print(result.summary())
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
