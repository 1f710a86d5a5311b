"""``multirotor simulate``: the closed loop (simulator + seed 1 controller) offline, as a flight log."""

from __future__ import annotations

import argparse
import time

from multirotor_ros.cli import CommandError

COMMAND = "simulate"
HELP = "fly the closed loop offline (no ROS) through setpoints and write a flight-log CSV"


def configure(parser: argparse.ArgumentParser) -> None:
    """Options of ``multirotor simulate``."""
    parser.add_argument(
        "--airframe", default="x8_octorotor", help="config name or YAML path (default x8_octorotor)"
    )
    parser.add_argument("--duration", type=float, required=True, metavar="T", help="simulated time [s]")
    parser.add_argument(
        "--setpoints",
        required=True,
        metavar="FILE",
        help="CSV with header t,x,y,z,yaw [s, m, m, m, rad], world ENU; each row holds from its t on",
    )
    parser.add_argument("--out", required=True, metavar="LOG.csv", help="flight log to write (flight_log.md)")
    parser.add_argument(
        "--effects",
        metavar="JSON",
        help='true effects replacing the airframe\'s, as a JSON list of {"id": ..., params}',
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    parser.add_argument("--no-noise", action="store_true", help="sensors read the truth")
    parser.add_argument("--physics-rate", type=float, default=1000.0, metavar="HZ", help="default 1000")
    parser.add_argument("--log-rate", type=float, default=100.0, metavar="HZ", help="default 100")


def run(args: argparse.Namespace) -> int:
    """Fly, write the log, print one line about it."""
    import json

    import numpy as np

    from multirotor_ros.control.gains import GainError
    from multirotor_ros.io.flight_log import FlightLogError, write_flight_log
    from multirotor_ros.model.airframe import AirframeError, load_airframe
    from multirotor_ros.simulation.flight import SetpointError, read_setpoints, simulate_flight

    try:
        airframe = load_airframe(args.airframe)
        setpoints = read_setpoints(args.setpoints)
        effects = None
        if args.effects is not None:
            effects = json.loads(args.effects)
            if not isinstance(effects, list):
                raise CommandError('--effects: expected a JSON list of {"id": ..., parameters}')
        started = time.perf_counter()
        log = simulate_flight(
            airframe,
            effects,
            setpoints=setpoints,
            duration_s=args.duration,
            rng=np.random.default_rng(args.seed),
            physics_rate_hz=args.physics_rate,
            log_rate_hz=args.log_rate,
            noise=not args.no_noise,
        )
        write_flight_log(args.out, log)
    except json.JSONDecodeError as error:
        raise CommandError(f"--effects: not valid JSON: {error}") from error
    except (AirframeError, GainError, SetpointError, FlightLogError, ValueError) as error:
        raise CommandError(str(error)) from error
    except FloatingPointError as error:
        raise CommandError(f"the simulation diverged: {error}") from error
    wall = time.perf_counter() - started
    final = {axis: float(log.columns[axis][-1]) for axis in "xyz"}
    print(
        f"{args.out}: {len(log)} rows, {args.duration:g} s simulated in {wall:.1f} s; "
        f"final position x={final['x']:.3f} y={final['y']:.3f} z={final['z']:.3f} m"
    )
    return 0
