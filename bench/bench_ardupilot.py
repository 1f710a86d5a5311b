"""Lockstep against the real ArduCopter: the bridge's answer per frame beside SITL's own, and the speed.

    .venv/bin/python bench/bench_ardupilot.py [--speedups 1,5,10] [--rate 1200] [--airframe quad_x]
                                              [--via library,node,node-heard,node-heard-typed]
                                              [--answers exact,ahead]
                                              [--rounds 1] [--json FILE]

ArduCopter SITL (shared/flight_stacks/ardupilot, see SOURCE.md there) flies the test mission of
:mod:`multirotor_ros.mavlink.arducopter` (pre-arm checks and EKF, GUIDED, arm, 5 m, hover, 10 m north
turning east, LAND, disarm) against the bridge, once per requested speedup and way of running the bridge:

- ``library``: :class:`~multirotor_ros.mavlink.bridge.MavlinkBridge` with its own physics, its loop in
  this process's main thread, no ROS; the ground station runs in a process of its own, so that nothing
  else shares the bridge's interpreter;
- ``node``: the ``mavlink_bridge`` node as ``multirotor node`` starts it (``odom``, ``imu``,
  ``motor_speeds``, ``motor_speed_cmd`` and ``/clock`` in a ROS graph of its own, ROS_DOMAIN_ID random,
  localhost only) with nobody subscribing, so that it publishes nothing (nodes/listeners.py); the ground
  station in this process;
- ``node-heard``: the same with a process subscribing to those five topics serialised, as ``ros2 bag
  record`` does, which prints how many messages of each it got;
- ``node-heard-typed``: the same with the subscriber taking message objects, as a Python node that reads
  every field does (an Odometry costs it about 45 us to convert).

And once per way of answering (``--answers``): ``exact`` lockstep, each frame integrated before it is
answered, and ``ahead`` (``answer_ahead``, :mod:`multirotor_ros.mavlink.ardupilot`): each frame answered
with the state integrated after the last one, its own servos integrated while SITL takes its turn.

Either subscriber, in Python, takes as many messages as a core lets it: on two cores it is a third busy
process beside SITL and the bridge.

Per run: the real-time factor achieved (ArduCopter's simulated seconds per wall second, from connecting
to disarming) against the requested speedup; the bridge's answer time per frame (the servo packet's
arrival, kernel time stamp, to our answer leaving) and SITL's own time per frame (our answer leaving to
its next packet's arrival: at 1200 Hz two frames in three SITL only integrates, the third runs
ArduCopter's 400 Hz loop), p50 / p95 / p99; how long each frame kept the bridge busy (the arrival to the
end of its work on the frame: answering ahead, the next frame's integration included); the bridge
process's CPU use; frames, missed and repeated
frames. The load average is printed with every figure: the machine may be shared.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import resource
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict
from functools import partial
from pathlib import Path


def _cpu_s(pid: int | None = None) -> float:
    if pid is None:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return usage.ru_utime + usage.ru_stime
    from bench_closed_loop import cpu_s

    return cpu_s(pid)


def _sitl(workdir: Path, port: int, airframe_name: str, speedup: float, rate_hz: int):
    from multirotor_ros.mavlink.actuators import RotorChannels
    from multirotor_ros.mavlink.arducopter import ArduCopterSitl, find_arducopter, frame_parameters
    from multirotor_ros.model.airframe import load_airframe

    binary = find_arducopter()
    if binary is None:
        raise SystemExit("no ArduCopter SITL binary: set MULTIROTOR_ARDUCOPTER or see shared/flight_stacks")
    frame = RotorChannels(load_airframe(airframe_name)).map.frame
    return ArduCopterSitl(binary, workdir, port, frame_parameters(frame), speedup=speedup, rate_hz=rate_hz)


def ground_station(port: int) -> dict[str, float]:
    """Fly the mission; ArduCopter's phase times and the wall time from connecting to disarming."""
    from multirotor_ros.mavlink.arducopter import GroundStation, fly

    start = time.monotonic()
    station = GroundStation(port)
    try:
        times = fly(station)
    finally:
        station.close()
    return {**asdict(times), "wall_s": time.monotonic() - start}


def run_library(
    airframe_name: str, speedup: float, rate_hz: int, workdir: Path, answer_ahead: bool
) -> dict[str, float]:
    from multirotor_ros.mavlink.actuators import RotorChannels
    from multirotor_ros.mavlink.ardupilot import ArduPilotConfig
    from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, MavlinkBridge
    from multirotor_ros.mavlink.physics import SimulatorPhysics
    from multirotor_ros.model.airframe import load_airframe

    airframe = load_airframe(airframe_name)
    config = BridgeConfig(
        "ardupilot",
        ardupilot=ArduPilotConfig(port=0, measure_timing=True, answer_ahead=answer_ahead),
        ground_station=None,
    )
    outputs = BridgeOutputs(lambda speeds, t: None, lambda state: None, lambda setpoint: None)
    bridge = MavlinkBridge(config, RotorChannels(airframe), SimulatorPhysics.for_airframe(airframe), outputs)
    assert bridge.ardupilot is not None and bridge.ardupilot.times is not None
    sitl = _sitl(workdir, bridge.ardupilot.endpoint.port, airframe_name, speedup, rate_hz).start()
    station = subprocess.Popen(
        [sys.executable, __file__, "--role", "ground-station", "--port", str(sitl.mavlink_port)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    flown = threading.Event()

    def watch() -> None:
        station.wait()
        flown.set()

    threading.Thread(target=watch, daemon=True).start()
    try:
        cpu = _cpu_s()
        started = time.monotonic()
        bridge.run(flown)  # the loop in this thread, as the node's own thread runs it
        cpu_share = (_cpu_s() - cpu) / (time.monotonic() - started)
    finally:
        sitl.stop()
        bridge.close()
    if station.returncode != 0:
        raise RuntimeError(f"the flight failed; SITL's log ends:\n{sitl.log_tail()}")
    assert station.stdout is not None
    flight = json.loads(station.stdout.read().strip().splitlines()[-1])
    return {
        **flight,
        **bridge.ardupilot.times.summary_ms(),
        "cpu_share": cpu_share,
        "missed_frames": bridge.ardupilot.missed_frames,
        "repeated_frames": bridge.ardupilot.repeated_frames,
    }


LISTENED_TOPICS = ("odom", "imu", "motor_speeds", "motor_speed_cmd", "/clock")
# The subscriber process's roles (--role), each with whether it takes message objects.
LISTENER_TYPED = {"recorder": False, "typed-listener": True}


def listen(typed: bool) -> dict[str, int]:
    """Subscribe to the bridge's state topics until SIGINT; messages received per topic.

    Serialised (``typed`` false) as ``ros2 bag record`` takes them, or converted to message objects as a
    Python node reading every field would. One executor spins throughout: ``rclpy.spin_once`` would
    rebuild its wait set for each message and cost the machine more than the subscriber's own work.
    """
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    from multirotor_ros.nodes.clock import CLOCK_QOS

    rclpy.init()
    node = rclpy.create_node("bench_listener")
    counts = dict.fromkeys(LISTENED_TOPICS, 0)
    types = {"odom": (Odometry, 10), "imu": (Imu, qos_profile_sensor_data), "/clock": (Clock, CLOCK_QOS)}

    def count(topic: str):
        return lambda _message: counts.__setitem__(topic, counts[topic] + 1)

    for topic in LISTENED_TOPICS:
        kind, qos = types.get(topic, (JointState, 10))
        node.create_subscription(kind, topic, count(topic), qos, raw=not typed)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    return counts


def run_node(
    airframe_name: str,
    speedup: float,
    rate_hz: int,
    workdir: Path,
    answer_ahead: bool,
    listener_kind: str | None = None,
) -> dict[str, float]:
    port = _free_udp_port()
    environment = dict(
        os.environ, ROS_DOMAIN_ID=str(random.randint(1, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"
    )
    parameters = {
        "airframe": airframe_name, "flight_stack": "ardupilot", "flight_stack_port": port,
        "publish_clock": "true", "gcs_enabled": "false", "measure_timing": "true",
        "flight_stack_answer_ahead": str(answer_ahead).lower(),
    }  # fmt: skip
    command = [sys.executable, "-m", "multirotor_ros.cli", "node", "mavlink_bridge", "--ros-args"]
    for name, value in parameters.items():
        command += ["-p", f"{name}:={value}"]
    log_path = workdir / "node.log"
    with open(log_path, "w") as log:
        node = subprocess.Popen(command, env=environment, stdout=log, stderr=subprocess.STDOUT)
    sitl = _sitl(workdir, port, airframe_name, speedup, rate_hz)
    listener: subprocess.Popen[str] | None = None
    try:
        deadline = time.monotonic() + 60.0
        while "outputs:" not in log_path.read_text():
            if node.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the node did not start:\n{log_path.read_text()}")
            time.sleep(0.1)
        if listener_kind is not None:
            listener = subprocess.Popen(
                [sys.executable, __file__, "--role", listener_kind],
                env=environment,
                stdout=subprocess.PIPE,
                text=True,
            )
        sitl.start()
        cpu = _cpu_s(node.pid)
        started = time.monotonic()
        flight = ground_station(sitl.mavlink_port)
        cpu_share = (_cpu_s(node.pid) - cpu) / (time.monotonic() - started)
    finally:
        sitl.stop()
        node.send_signal(2)
        node.wait(30)
        received = {}
        if listener is not None:
            listener.send_signal(2)
            out, _ = listener.communicate(timeout=30)
            received = json.loads(out.strip().splitlines()[-1])
    text = log_path.read_text()
    timing = re.search(r"frame timing: (.*)", text)
    frames = re.search(r"ardupilot: \d+ frames in .*, (\d+) missed, (\d+) repeated", text)
    if timing is None or frames is None:
        raise RuntimeError(f"no timing in the node's log:\n{text[-3000:]}")
    items = (item.rsplit(" ", 1) for item in timing.group(1).split(", "))
    times = {key: float(value) for key, value in items}
    return {
        **flight,
        **times,
        "cpu_share": cpu_share,
        "missed_frames": int(frames.group(1)),
        "repeated_frames": int(frames.group(2)),
        **{f"received {topic}": count for topic, count in received.items()},
    }


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _line(via: str, answers: str, speedup: float, rate_hz: int, run: dict[str, float]) -> str:
    factor = run["landed_s"] / run["wall_s"]
    return (
        f"  {via:10s} {answers:5s} speedup {speedup:4g}: {factor:5.2f}x real time "
        f"({run['frames']:.0f} frames at {rate_hz} Hz, "
        f"{run['missed_frames']:.0f} missed, {run['repeated_frames']:.0f} repeated); answer p50/p95/p99 "
        f"{run['answer_p50_ms']:.3f}/{run['answer_p95_ms']:.3f}/{run['answer_p99_ms']:.3f} ms, SITL "
        f"{run['flight_stack_p50_ms']:.3f}/{run['flight_stack_p95_ms']:.3f}/"
        f"{run['flight_stack_p99_ms']:.3f} ms, busy p50/p99 "
        f"{run['busy_p50_ms']:.3f}/{run['busy_p99_ms']:.3f} ms; "
        f"bridge CPU {100 * run['cpu_share']:.0f} % of a core; take-off to 5 m "
        f"{run['reached_s'] - run['armed_s']:.1f} s; load average {os.getloadavg()[0]:.1f}"
        + "".join(f"; {key} {value:.0f}" for key, value in run.items() if key.startswith("received "))
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speedups", default="1,5,10", help="requested SITL speedups, comma separated")
    parser.add_argument("--rate", type=int, default=1200, help="SITL frame rate [Hz] (SIM_RATE_HZ)")
    parser.add_argument("--airframe", default="quad_x")
    parser.add_argument(
        "--via",
        default="library,node,node-heard",
        help="library, node, node-heard, node-heard-typed (comma separated)",
    )
    parser.add_argument(
        "--answers", default="exact,ahead", help="exact, ahead (comma separated): how frames are answered"
    )
    parser.add_argument("--rounds", type=int, default=1, help="runs of each combination")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--role", choices=["ground-station", *LISTENER_TYPED], help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "ground-station":
        print(json.dumps(ground_station(args.port)), flush=True)
        return 0
    if args.role in LISTENER_TYPED:
        print(json.dumps(listen(typed=LISTENER_TYPED[args.role])), flush=True)
        return 0

    answer_modes = args.answers.split(",")
    if not set(answer_modes) <= {"exact", "ahead"}:
        parser.error(f"--answers takes exact and/or ahead, got {args.answers!r}")
    runners = {
        "library": run_library,
        "node": run_node,
        "node-heard": partial(run_node, listener_kind="recorder"),
        "node-heard-typed": partial(run_node, listener_kind="typed-listener"),
    }
    print(f"{args.airframe}, ArduCopter SITL at {args.rate} Hz, {os.cpu_count()} cores")
    results: list[dict[str, object]] = []
    for _ in range(args.rounds):
        for speedup in (float(s) for s in args.speedups.split(",")):
            for via in args.via.split(","):
                for answers in answer_modes:
                    with tempfile.TemporaryDirectory(prefix="bench_ardupilot_") as scratch:
                        run = runners[via](
                            args.airframe, speedup, args.rate, Path(scratch), answers == "ahead"
                        )
                    print(_line(via, answers, speedup, args.rate, run), flush=True)
                    results.append(
                        {"via": via, "answers": answers, "speedup": speedup, "rate_hz": args.rate, **run}
                    )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
