"""``multirotor demo``: the whole loop on ROS 2, flying the X8 through a square-and-climb with a rotor fault.

Starts the simulator, the controller and (when this install has it) the identifier as processes
(``python -m multirotor_ros.cli node NAME``) under the namespace ``/demo``, in lockstep on simulated time
(real_time_factor 0, the simulator's clock), so that the flight is the same on a fast or a busy machine.
It sends the setpoints ahead, stamped with the simulated time each takes effect at, injects a rotor
fault halfway with a parameter set, prints a live status line, a summary, what the identifier reported
on ``diagnostics``, and can save a plot of the flight.

The controller reallocates around the rotor the identifier diagnoses (``rotor_effectiveness``); the
effectiveness it uses is not published, so the demo recomputes it from the same topic with the
controller's own filter and settings (nodes/controller.py) on the odometry's clock: the live line shows
it, and the summary splits the position error at the fault and at the start of the reallocation.
``--no-reallocation`` flies the same with the controller's ``fault_tolerant_allocation`` off; the split
is then where the reallocation would have started.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from multirotor_ros.cli import CommandError
from multirotor_ros.cli.ros_session import background_node

COMMAND = "demo"
HELP = "fly the simulated X8 with the controller (and identifier) over ROS 2, inject a rotor fault, report"

NAMESPACE = "/demo"
# (time [s], x, y, z [m], yaw [rad]): take off, then a 1 m square climbing from 1 m to 2 m, then hold.
TRAJECTORY = (
    (0.0, 0.0, 0.0, 1.0, 0.0),
    (3.0, 1.0, 0.0, 1.25, 0.0),
    (6.0, 1.0, 1.0, 1.5, 0.0),
    (9.0, 0.0, 1.0, 1.75, 0.0),
    (12.0, 0.0, 0.0, 2.0, 0.0),
)
FAULT_TIME_S = 7.5
FLIGHT_S = 16.0
STARTUP_TIMEOUT_S = 90.0
STALL_TIMEOUT_S = 30.0


def configure(parser: argparse.ArgumentParser) -> None:
    """Options of ``multirotor demo``."""
    parser.add_argument(
        "--airframe", default="x8_octorotor", help="config name or YAML path (default x8_octorotor)"
    )
    parser.add_argument(
        "--fault-motor",
        type=int,
        default=3,
        metavar="K",
        help=f"rotor stopped at t = {FAULT_TIME_S:g} s (0 = no fault; default 3)",
    )
    parser.add_argument("--plot", metavar="PNG", help="save a plot of the flight")
    parser.add_argument("--no-identifier", action="store_true", help="do not start the identifier node")
    parser.add_argument(
        "--no-reallocation",
        action="store_true",
        help="the controller keeps the nominal allocation (fault_tolerant_allocation false)",
    )
    parser.add_argument(
        "--logs", metavar="DIR", help="directory for the nodes' output (default: a temporary one)"
    )


@dataclass
class FlightRecord:
    """What the demo saw, in simulated time."""

    t: list[float] = field(default_factory=list)
    position: list[tuple[float, float, float]] = field(default_factory=list)
    target: list[tuple[float, float, float]] = field(default_factory=list)
    speeds_t: list[float] = field(default_factory=list)
    speeds: list[list[float]] = field(default_factory=list)
    diagnostics: list[tuple[float, list[tuple[str, int, str]]]] = field(default_factory=list)
    # The controller's effectiveness in use, recomputed (module docstring): one row per odometry sample.
    effectiveness: list[Any] = field(default_factory=list)
    reallocated_at: float | None = None  # [s] simulated time the reallocation started (or would have)
    lock: threading.Lock = field(default_factory=threading.Lock)


def target_at(t_s: float) -> tuple[float, float, float, float]:
    """The trajectory's setpoint at simulated time t."""
    current = TRAJECTORY[0]
    for row in TRAJECTORY:
        if t_s >= row[0]:
            current = row
    return current[1:]


class NodeProcesses:
    """The demo's node processes; stopped with SIGINT like Ctrl-C, killed if they do not end."""

    def __init__(self, log_directory: Path):
        self.log_directory = log_directory
        self.processes: dict[str, subprocess.Popen] = {}

    def start(self, name: str, ros_args: list[str]) -> None:
        log = open(self.log_directory / f"{name}.log", "wb")  # noqa: SIM115 - the child keeps writing to it
        self.processes[name] = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "multirotor_ros.cli",
                "node",
                name,
                "--ros-args",
                "-r",
                f"__ns:={NAMESPACE}",
                *ros_args,
            ],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        log.close()

    def check_alive(self) -> None:
        for name, process in self.processes.items():
            if process.poll() is not None:
                raise CommandError(
                    f"the {name} node exited with status {process.returncode}; see "
                    f"{self.log_directory / (name + '.log')}"
                )

    def stop(self) -> dict[str, int]:
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        statuses = {}
        for name, process in self.processes.items():
            try:
                statuses[name] = process.wait(10.0)
            except subprocess.TimeoutExpired:
                process.kill()
                statuses[name] = process.wait()
        return statuses


def run(args: argparse.Namespace) -> int:
    """Start the nodes, fly, stop them, report; 0 when the nodes ended cleanly."""
    from multirotor_ros.model.airframe import AirframeError, load_airframe

    try:
        airframe = load_airframe(args.airframe)
    except AirframeError as error:
        raise CommandError(str(error)) from error
    if not 0 <= args.fault_motor <= airframe.n_rotors:
        raise CommandError(f"--fault-motor must be 0..{airframe.n_rotors}, got {args.fault_motor}")
    log_directory = Path(args.logs) if args.logs else Path(tempfile.mkdtemp(prefix="multirotor_demo_"))
    log_directory.mkdir(parents=True, exist_ok=True)
    identifier = (
        not args.no_identifier and importlib.util.find_spec("multirotor_ros.nodes.identifier") is not None
    )
    airframe_arg = ["-p", f"airframe:={args.airframe}"]
    nodes = NodeProcesses(log_directory)
    print(f"multirotor demo: {airframe.name}, nodes under {NAMESPACE}, logs in {log_directory}")
    nodes.start(
        "simulator",
        [
            *airframe_arg,
            "-p",
            "real_time_factor:=0.0",
            "-p",
            "publish_clock:=true",
            "-p",
            "command_timeout_s:=2.0",
        ],
    )
    sim_time = ["-p", "use_sim_time:=true"]
    reallocation = ["-p", f"fault_tolerant_allocation:={'false' if args.no_reallocation else 'true'}"]
    nodes.start("controller", [*airframe_arg, *sim_time, *reallocation])
    if identifier:
        nodes.start("identifier", [*airframe_arg, *sim_time])
    record = FlightRecord()
    started = time.monotonic()
    try:
        _fly(args, airframe, nodes, record)
    finally:
        statuses = nodes.stop()
    wall = time.monotonic() - started
    _summary(args, airframe, record, wall, identifier, statuses)
    if args.plot:
        _plot(args.plot, airframe, record, args.fault_motor)
        print(f"plot: {args.plot}")
    return 0 if all(status == 0 for status in statuses.values()) else 1


def _fly(args: argparse.Namespace, airframe: Any, nodes: NodeProcesses, record: FlightRecord) -> None:
    with background_node("demo", namespace=NAMESPACE) as node:
        _fly_with(node, args, airframe, nodes, record)


def _fly_with(
    node: Any, args: argparse.Namespace, airframe: Any, nodes: NodeProcesses, record: FlightRecord
) -> None:
    """The flight, seen and steered through ``node`` (spinning in the background)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from multirotor_ros.control.fault_tolerance import EffectivenessFilter
    from multirotor_ros.nodes.controller import REALLOCATION_NOTICE
    from multirotor_ros.nodes.effectiveness_message import effectiveness_from_message
    from multirotor_ros.nodes.messages import stamp_to_s
    from multirotor_ros.refusals import Refusal

    in_use = EffectivenessFilter(airframe.n_rotors)  # as the controller's (module docstring)
    diagnosis: list[Any] = [None, None]  # (estimate, std) of the latest rotor_effectiveness

    def on_odom(message: Odometry) -> None:
        p = message.pose.pose.position
        t = stamp_to_s(message.header.stamp)
        effectiveness = in_use.update(t, *diagnosis)
        with record.lock:
            record.t.append(t)
            record.position.append((p.x, p.y, p.z))
            record.target.append(target_at(t)[:3])
            record.effectiveness.append(effectiveness)
            reduced = effectiveness.min() < 1.0 - REALLOCATION_NOTICE
            if record.reallocated_at is None and t >= FAULT_TIME_S and reduced:
                record.reallocated_at = t

    def on_effectiveness(message: Float64MultiArray) -> None:
        received = effectiveness_from_message(message, airframe.n_rotors)
        if not isinstance(received, Refusal):
            diagnosis[:] = received

    def on_speeds(message: JointState) -> None:
        with record.lock:
            record.speeds_t.append(stamp_to_s(message.header.stamp))
            record.speeds.append(list(message.velocity))

    def on_diagnostics(message: DiagnosticArray) -> None:
        with record.lock:
            record.diagnostics.append(
                (
                    stamp_to_s(message.header.stamp),
                    [
                        (
                            s.name,
                            int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level),
                            s.message,
                        )
                        for s in message.status
                    ],
                )
            )

    node.create_subscription(Odometry, "odom", on_odom, 10)
    node.create_subscription(JointState, "motor_speeds", on_speeds, 10)
    node.create_subscription(DiagnosticArray, "diagnostics", on_diagnostics, 10)
    node.create_subscription(Float64MultiArray, "rotor_effectiveness", on_effectiveness, 10)
    setpoints = node.create_publisher(PoseStamped, "setpoint", len(TRAJECTORY) + 10)

    _wait(
        lambda: record.t and setpoints.get_subscription_count() > 0,
        STARTUP_TIMEOUT_S,
        nodes,
        "the simulator and controller did not come up",
    )
    # The whole trajectory at once, each setpoint stamped with the simulated time it takes effect at: the
    # controller holds them until then, so the flight does not depend on when this process runs.
    for row in TRAJECTORY:
        setpoints.publish(_pose(*row[1:], stamp_s=row[0]))
    live = sys.stdout.isatty()
    fault_sent = False
    last_print = 0.0
    last_progress = (time.monotonic(), record.t[-1])
    while True:
        nodes.check_alive()
        with record.lock:
            t, position = record.t[-1], record.position[-1]
            speeds = record.speeds[-1] if record.speeds else []
            effectiveness = record.effectiveness[-1]
        if t >= FLIGHT_S:
            break
        if t > last_progress[1]:
            last_progress = (time.monotonic(), t)
        elif time.monotonic() - last_progress[0] > STALL_TIMEOUT_S:
            raise CommandError(f"simulated time stopped at {t:.2f} s; see the logs in {nodes.log_directory}")
        target = target_at(t)
        if args.fault_motor and not fault_sent and t >= FAULT_TIME_S:
            _set_parameter(node, f"{NAMESPACE}/simulator", "fault_motor", args.fault_motor)
            fault_sent = True
            print(
                ("\n" if live else "") + f"t = {t:5.2f} s: rotor {args.fault_motor} stopped (fault injected)"
            )
        now = time.monotonic()
        if now - last_print >= (0.2 if live else 2.0):
            last_print = now
            error = math.dist(position, target[:3])
            rotor_text = f"{min(speeds):4.0f}-{max(speeds):4.0f} rad/s" if speeds else "-"
            line = (
                f"t = {t:5.2f} s  "
                f"position ({position[0]:5.2f}, {position[1]:5.2f}, {position[2]:5.2f}) m  "
                f"error {error:5.3f} m  rotors {rotor_text}  "
                f"{_effectiveness_text(effectiveness, args.no_reallocation)}"
            )
            print("\r" + line if live else line, end="" if live else "\n", flush=True)
        time.sleep(0.02)
    if live:
        print()
    # Give the identifier a moment of wall time to publish on what it saw last.
    time.sleep(0.5)


def _effectiveness_text(effectiveness: Any, reallocation_off: bool) -> str:
    """The effectiveness in use, for the live line: the reduced rotors, or 'nominal'."""
    reduced = [f"rotor {k + 1} {e:.2f}" for k, e in enumerate(effectiveness) if e < 0.995]
    if reallocation_off:
        return "allocation nominal (reallocation off" + (
            f"; diagnosed {', '.join(reduced)})" if reduced else ")"
        )
    return "effectiveness " + (", ".join(reduced) if reduced else "all 1")


def _wait(condition: Any, timeout: float, nodes: NodeProcesses, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        nodes.check_alive()
        if time.monotonic() > deadline:
            raise CommandError(f"{what} within {timeout:g} s; see the logs in {nodes.log_directory}")
        time.sleep(0.1)


def _pose(x: float, y: float, z: float, yaw: float, stamp_s: float) -> Any:
    from geometry_msgs.msg import PoseStamped

    from multirotor_ros.nodes.messages import stamp_from_ns

    message = PoseStamped()
    message.header.frame_id = "odom"
    message.header.stamp = stamp_from_ns(round(stamp_s * 1e9))
    message.pose.position.x, message.pose.position.y, message.pose.position.z = x, y, z
    message.pose.orientation.z, message.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return message


def _set_parameter(node: Any, node_name: str, name: str, value: Any) -> None:
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    client = node.create_client(SetParameters, f"{node_name}/set_parameters")
    if not client.wait_for_service(timeout_sec=10.0):
        raise CommandError(f"{node_name}: parameter service not available")
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    if not done.wait(10.0):
        raise CommandError(f"{node_name}: no answer to setting {name}")
    result = future.result().results[0]
    if not result.successful:
        raise CommandError(f"{node_name}: {name} refused: {result.reason}")


def _summary(
    args: argparse.Namespace,
    airframe: Any,
    record: FlightRecord,
    wall_s: float,
    identifier: bool,
    statuses: dict[str, int],
) -> None:
    import numpy as np

    t = np.array(record.t)
    error = np.linalg.norm(np.array(record.position) - np.array(record.target), axis=1)
    print("summary")
    print(
        f"  flew {t[-1]:.1f} s of simulated time in {wall_s:.1f} s of wall time "
        f"({t[-1] / wall_s:.2f} x real time, start-up included)"
    )
    print("  position error (RMS, max):")
    for label, (start, end) in _phases(args, record).items():
        inside = error[(t >= start) & (t < end)]
        figures = f"{np.sqrt(np.mean(inside**2)):.3f} m, {inside.max():.3f} m" if inside.size else "-"
        print(f"    {label:<60} {figures}")
    final = record.position[-1]
    print(f"  final position ({final[0]:.2f}, {final[1]:.2f}, {final[2]:.2f}) m, target {record.target[-1]}")
    if args.fault_motor:
        print(f"  fault: rotor {args.fault_motor} of {airframe.n_rotors} stopped at t = {FAULT_TIME_S:g} s")
    if not identifier:
        print("  identifier: not started" + ("" if args.no_identifier else " (not part of this install)"))
    elif not record.diagnostics:
        print("  identifier: published nothing on diagnostics")
    else:
        stamp, statuses_seen = record.diagnostics[-1]
        flagged = [(name, level, text) for name, level, text in statuses_seen if level != 0]
        verdict = "all rotors OK" if not flagged else f"{len(flagged)} rotor(s) flagged"
        print(f"  identifier (diagnostics at t = {stamp:.2f} s): {verdict}")
        for name, level, text in flagged:
            print(f"    {name}: {['OK', 'WARN', 'ERROR', 'STALE'][min(level, 3)]}: {text}")
    bad = {name: status for name, status in statuses.items() if status != 0}
    if bad:
        print(f"  nodes that did not end cleanly: {bad}")


def _phases(args: argparse.Namespace, record: FlightRecord) -> dict[str, tuple[float, float]]:
    """Label -> [start, end) of simulated time: before the fault, until the reallocation, after it."""
    take_off_done, end = TRAJECTORY[1][0], math.inf
    if not args.fault_motor:
        return {f"after take-off (t >= {take_off_done:g} s), no fault": (take_off_done, end)}
    fault = FAULT_TIME_S
    phases = {f"before the fault ({take_off_done:g} s <= t < {fault:g} s)": (take_off_done, fault)}
    reallocated = record.reallocated_at
    if reallocated is None:
        phases["after the fault (no diagnosis, no reallocation)"] = (fault, end)
        return phases
    what = "reallocation would have started (off)" if args.no_reallocation else "reallocation"
    phases[f"fault -> {what} at {reallocated:.2f} s"] = (fault, reallocated)
    phases[f"after it (t >= {reallocated:.2f} s)"] = (reallocated, end)
    return phases


def _plot(path: str, airframe: Any, record: FlightRecord, fault_motor: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    t = np.array(record.t)
    position = np.array(record.position)
    target = np.array(record.target)
    figure, axes = plt.subplots(2, 2, figsize=(12, 8))
    for index, axis_name in enumerate("xyz"):
        axes[0, 0].plot(t, position[:, index], label=f"{axis_name}")
        axes[0, 0].plot(t, target[:, index], "--", color=f"C{index}", alpha=0.6)
    axes[0, 0].set(xlabel="simulated time [s]", ylabel="position [m]", title="position (dashed: setpoints)")
    axes[0, 0].legend()
    axes[0, 1].plot(position[:, 0], position[:, 1], label="flown")
    axes[0, 1].plot(target[:, 0], target[:, 1], "--", label="setpoints")
    axes[0, 1].set(xlabel="x east [m]", ylabel="y north [m]", title="seen from above", aspect="equal")
    axes[0, 1].legend()
    axes[1, 0].plot(t, np.linalg.norm(position - target, axis=1))
    axes[1, 0].set(xlabel="simulated time [s]", ylabel="[m]", title="position error")
    if record.speeds:
        speeds = np.array(record.speeds)
        for k in range(speeds.shape[1]):
            axes[1, 1].plot(record.speeds_t, speeds[:, k], label=f"rotor {k + 1}", linewidth=0.8)
        axes[1, 1].legend(ncol=2, fontsize="small")
    axes[1, 1].set(xlabel="simulated time [s]", ylabel="[rad/s]", title="measured rotor speeds")
    if fault_motor:
        for axis in (axes[0, 0], axes[1, 0], axes[1, 1]):
            axis.axvline(FAULT_TIME_S, color="red", linestyle=":", label=f"rotor {fault_motor} stops")
    figure.suptitle(f"multirotor demo: {airframe.name}, seed 1 saturation control")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
