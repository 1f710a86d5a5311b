"""``multirotor convert INPUT --airframe A --out OUT.csv``: other logs -> flight-log CSV."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from multirotor_ros.cli import CommandError

COMMAND = "convert"
HELP = (
    "convert a rosbag2, PX4 ULog, ArduPilot dataflash, data-driven-dynamics CSV or Crazyflie usd log "
    "to a flight-log CSV"
)

DESCRIPTION = """\
Convert a log to the flight-log CSV of shared/spec/flight_log.md (world ENU, body FLU, SI units,
rotor speeds in rad/s), which identify, discrepancy and the other offline tools read.

Formats (--format auto looks at the content):
  rosbag2    a directory with metadata.yaml and .mcap or .db3, recorded from this package's topics:
             odom (time base; twist turned from body to world velocity), motor_speeds -> omega_k,
             motor_speed_cmd -> omega_cmd_k, imu, pose (time base without odom), range.
  ulog       PX4 .ulg: vehicle_local_position (time base, NED -> ENU), vehicle_attitude,
             sensor_combined (p, q, r), actuator_outputs (PWM -> u_k, and omega_k by the motor map).
  dataflash  ArduPilot .bin: XKF1/NKF1 or POS (time base), ATT, IMU, RCOU (PWM), PARM.
  ddd-csv    ethz-asl data-driven-dynamics CSV (timestamp, u0.., vx.. world NED, q0.. FRD->NED,
             acc_b.. FRD specific force): world velocity and gravity-free acceleration.
  crazyflie-usd  Bitcraze micro-SD card log (magic 0xBC), or its CSV export (timestamp [ms], then
             the variables by name): stateEstimate.x/y/z (time base), vx.., ax.. [g], roll/yaw [deg]
             (pitch derived from the acceleration when not logged), motor.m1..m4 / 65535 -> u_k
             (normalized; rebuilt by the firmware's mixer from controller.cmd_* when only the
             controller is logged), pm.vbatMV -> battery_v.

Streams at other rates are brought onto the time base by linear interpolation (measurements),
zero-order hold (actuator outputs, commands) or quaternion interpolation (attitude); cells stay
empty outside a stream's samples and across its gaps. The CSV's '# key: value' lines record the
source, frames, time base, resampling, rotor channels and motor map.

Rotor numbering: rotor k of the airframe YAML (conventions.md), not the flight stack's motor k.
Without --rotor-channels, quad X and hexa X airframes are matched to PX4/ArduPilot's motor order by
geometry, and the log's parameters (PX4 VT_MOT_ID, PWM_MAIN_FUNCn; ArduPilot SERVOn_FUNCTION) say
which channel carries each motor. PX4 quad X numbers its motors 1 front-right, 2 rear-left,
3 front-left, 4 rear-right; our quad_x is 1 front-right, 2 rear-right, 3 rear-left, 4 front-left,
so with motors on channels 1-4 the default is --rotor-channels 1,4,2,3. A Crazyflie log is matched
to Bitcraze's order (M1 front-right, M2 rear-right, M3 rear-left, M4 front-left).
"""

EPILOG = """\
examples:
  multirotor convert flight.ulg --airframe quad_x --out flight.csv
  multirotor convert flight.ulg --airframe quad_x --rotor-channels 5,8,6,7 --out flight.csv
  multirotor convert bags/run1 --airframe x8_octorotor --namespace /uav1 --out run1.csv
  multirotor convert 00000042.BIN --airframe hexarotor_f550 --out flight.csv
  multirotor convert motor_data/normal_flight/E8_log00 --airframe crazyflie_2_1 --out E8_log00.csv
"""


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments and its long help to ``parser``."""
    parser.description = DESCRIPTION
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("input", type=Path, metavar="INPUT", help="log file, or rosbag2 directory")
    parser.add_argument(
        "--airframe",
        required=True,
        help="airframe config name (quad_x, hexarotor_f550, x8_octorotor) or YAML path",
    )
    parser.add_argument("--out", required=True, type=Path, metavar="OUT.csv", help="flight-log CSV to write")
    parser.add_argument(
        "--format",
        default="auto",
        choices=("auto", "rosbag2", "ulog", "dataflash", "ddd-csv", "crazyflie-usd"),
        help="input format",
    )
    parser.add_argument(
        "--rotor-channels",
        metavar="C1,C2,...",
        help="1-based actuator channel of rotor 1, 2, ... in the airframe's numbering "
        "(ulog, dataflash, ddd-csv, crazyflie-usd; ddd-csv channel 1 is u0)",
    )
    parser.add_argument("--namespace", metavar="NS", help="rosbag2 only: topic namespace, e.g. /uav1")
    parser.add_argument(
        "--actuator-instance",
        type=int,
        metavar="I",
        help="ULog only: actuator_outputs instance (0 = MAIN outputs, the default; 1 = AUX)",
    )


def run(args: argparse.Namespace) -> int:
    """Convert, write the CSV, print a summary line and any warnings."""
    from multirotor_ros.io.convert import convert
    from multirotor_ros.io.flight_log import FlightLogError, canonical_order, write_flight_log
    from multirotor_ros.io.log_builder import ConversionError
    from multirotor_ros.model.airframe import AirframeError, load_airframe

    if args.out.resolve() == args.input.resolve():
        raise CommandError(f"--out {args.out} is the input file")
    try:
        airframe = load_airframe(args.airframe)
        conversion = convert(
            args.input,
            airframe,
            fmt=args.format,
            namespace=args.namespace,
            rotor_channels=args.rotor_channels,
            actuator_instance=args.actuator_instance,
        )
        write_flight_log(args.out, conversion.log)
    except (AirframeError, ConversionError, FlightLogError) as error:
        raise CommandError(str(error)) from None
    except OSError as error:
        raise CommandError(f"{args.out}: cannot write: {error.strerror or error}") from None
    for warning in conversion.warnings:
        print(f"multirotor convert: warning: {warning}", file=sys.stderr)
    log = conversion.log
    groups = [
        g for g in ("position", "velocity", "acceleration", "rotor_speeds", "actuators") if log.has_group(g)
    ]
    print(
        f"wrote {args.out}: {len(log)} rows, {log.t[-1]:.2f} s, from {conversion.format}; "
        f"groups: {', '.join(groups)}; columns: {', '.join(canonical_order(['t', *log.columns]))}"
    )
    return 0
