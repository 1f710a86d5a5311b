"""How many vehicles one simulator node keeps in real time, each flown by its own controller process.

    .venv/bin/python bench/bench_fleet_ros.py [--vehicles 1,5,10,15] [--seconds 30]
        [--controllers composed,bundled,separate] [--rate-hz 250] [--no-ceiling]

For each fleet size V: ``multirotor node simulator`` with ``vehicles`` = uav1..uavV (x8_octorotor, 1 kHz
physics, real_time_factor 1, publishing /clock and odometry at the control rate, other sensors at their
rates) and a controller per vehicle (use_sim_time, ``--rate-hz``), every vehicle hovering at 1 m: V
``multirotor node controller`` processes (``separate``) or one ``multirotor node fleet_controller`` process
holding the V controller nodes, each on its vehicle's topics (``composed``) or all of them on the
simulator's fleet bundles (``bundled``: ``bundles`` true, nodes/bundle.py), each way in turn for each V.
After a start-up settle, the simulator's own ``pacing`` status over ``--seconds`` of flight gives the
achieved real-time factor and the share of control periods whose command came in time (stamped at the
period's start and in force before its end); after it, the probe looks at 100 odometry messages of each
vehicle (not during it: its own Python would take CPU from the nodes measured). A fleet "keeps real time"
when the achieved factor is >= 0.99, >= 99 % of the periods are on time and every vehicle is then within 5
cm of its height. The CPU columns: the simulator's process and the controllers' (summed) over the
measured window, in cores (from /proc).

Beside each fleet size, in the same run and before it, the ceiling rclpy sets on this host at that moment
(``--ceiling``, on by default): the same messages with no physics and no control. A bare plant process
publishes V serialised odometries and a ``/clock`` every period from a wall-clock timer, as the simulator's
real-time timer does, and a bare controllers process answers each odometry at once with a serialised
8-rotor JointState carrying its stamp, on each vehicle's ``motor_speed_cmd``; the same QoS and queue
depths as the nodes, both on the EventsExecutor. The plant judges the answers with the simulator's own
``ControlTiming`` (simulation/pacing.py). What the fleet loses against it is the nodes' own work; what the
ceiling loses is the host's and the middleware's.

Every process runs in a ROS domain of its own choosing (random, localhost only). The load average is
printed with the figures: they are wall-clock numbers.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import struct
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 200)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

SETTLE_S = 10.0
BARE_SETTLE_S = 3.0  # [s] of the bare exchange before its measured window (discovery, first answers)
BARE_ROTORS = 8
STAMP = struct.Struct("<iI")  # header.stamp (sec, nanosec) in little-endian CDR, as rclpy serialises here


def pacing_values(message) -> dict[str, float]:  # noqa: ANN001 - diagnostic_msgs/DiagnosticArray
    (status,) = message.status
    return {kv.key: float(kv.value) for kv in status.values}


def fly(vehicles: int, seconds: float, logs: Path, way: str, rate_hz: float) -> dict[str, float]:
    from bench_closed_loop import cpu_s
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from ros_harness import NodeProcess, RosProbe
    from test_nodes_sim_control import position

    names = [f"uav{k + 1}" for k in range(vehicles)]
    probe = RosProbe()
    pacing = probe.subscribe("/pacing", DiagnosticArray)
    simulator = NodeProcess(
        "simulator",
        logs / f"v{vehicles}-{way}-simulator.log",
        parameters={
            "real_time_factor": 1.0,
            "publish_clock": True,
            "publish_rate_hz": rate_hz,
            "control_period_s": 1.0 / rate_hz,
            "vehicles": [f"{name} {3.0 * k} 0 1" for k, name in enumerate(names)],
        },
    )
    controllers = (
        [
            NodeProcess(
                "fleet_controller",
                logs / f"v{vehicles}-{way}-fleet_controller.log",
                parameters={
                    "use_sim_time": True,
                    "rate_hz": rate_hz,
                    "vehicles": names,
                    "bundles": way == "bundled",
                },
            )
        ]
        if way != "separate"
        else [
            NodeProcess(
                "controller",
                logs / f"v{vehicles}-{way}-{name}.log",
                namespace=f"/{name}",
                parameters={"use_sim_time": True, "rate_hz": rate_hz},
            )
            for name in names
        ]
    )
    try:
        pacing.wait_for(lambda m: pacing_values(m)["simulated_time_s"] > SETTLE_S, timeout=300.0)
        start, wall_start = next_status(pacing)
        cpu_start = [cpu_s(p.process.pid) for p in [simulator, *controllers]]
        time.sleep(seconds)
        end, wall_end = next_status(pacing)
        cpu = [
            (cpu_s(p.process.pid) - s) / (wall_end - wall_start)
            for p, s in zip([simulator, *controllers], cpu_start, strict=True)
        ]
        # Looked at after the window: converting every vehicle's odometry in this process took about half
        # a core at 10 vehicles, which the nodes measured would have lost.
        odom = {name: probe.subscribe(f"/{name}/odom", Odometry, qos=1000) for name in names}
        worst = max(
            abs(position(m)[2] - 1.0)
            for recorder in odom.values()
            for m in recorder.wait_for(count=100, timeout=60.0)
        )
        periods = (end["control_periods_on_time"] + end["control_periods_late"]) - (
            start["control_periods_on_time"] + start["control_periods_late"]
        )
        on_time = (end["control_periods_on_time"] - start["control_periods_on_time"]) / max(periods, 1.0)
        factor = (end["simulated_time_s"] - start["simulated_time_s"]) / (wall_end - wall_start)
        for process in [simulator, *controllers]:
            process.assert_running()
        return {
            "achieved": factor,
            "on_time": on_time,
            "height_error_after_m": worst,
            "simulator_cpu": cpu[0],
            "controllers_cpu": sum(cpu[1:]),
        }
    finally:
        for process in [*controllers, simulator]:
            process.stop(check=False)
        probe.close()


def bare_plant(vehicles: int, rate_hz: float, seconds: float) -> None:
    """Child role: odometries and a /clock every period, no physics; prints the answers on time and late."""
    from bench_closed_loop import child_node, raw_stamp_ns
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from multirotor_ros.nodes.clock import CLOCK_QOS
    from multirotor_ros.nodes.messages import stamp_from_ns
    from multirotor_ros.simulation.pacing import ControlTiming

    _, node, spin = child_node("bare_plant", "events")
    period_ns = round(1e9 / rate_hz)
    timing = [ControlTiming(period_ns) for _ in range(vehicles)]
    odometry = [node.create_publisher(Odometry, f"/bare{k}/odom", 10) for k in range(vehicles)]
    clock = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    for k in range(vehicles):
        node.create_subscription(
            JointState,
            f"/bare{k}/motor_speed_cmd",
            lambda data, judge=timing[k]: judge.command(raw_stamp_ns(data)),
            10,
            raw=True,
        )
    message = bytearray(serialize_message(Odometry(child_frame_id="base_link")))
    assert message[1] == 1, "expected little-endian CDR"
    started_ns = time.monotonic_ns()
    next_period = [0]

    def tick() -> None:
        # Every period the wall clock has passed, as the simulator runs its physics up to it.
        due = (time.monotonic_ns() - started_ns) // period_ns
        for period in range(next_period[0], due + 1):
            t_ns = period * period_ns
            for judge in timing:
                judge.physics_at(t_ns)
            STAMP.pack_into(message, 4, t_ns // 1_000_000_000, t_ns % 1_000_000_000)
            data = bytes(message)
            for publisher in odometry:
                publisher.publish(data)
            clock.publish(Clock(clock=stamp_from_ns(t_ns)))
        next_period[0] = due + 1

    node.create_timer(period_ns / 1e9, tick)
    window_start = time.monotonic() + BARE_SETTLE_S
    spin(lambda: time.monotonic() < window_start)
    on_time_before, late_before = sum(j.on_time for j in timing), sum(j.late for j in timing)
    window_end = time.monotonic() + seconds
    spin(lambda: time.monotonic() < window_end)
    on_time, late = sum(j.on_time for j in timing), sum(j.late for j in timing)
    print(f"ON_TIME {on_time - on_time_before}\nLATE {late - late_before}", flush=True)


def bare_controllers(vehicles: int) -> None:
    """Child role: answer each odometry at once with an 8-rotor JointState carrying its stamp."""
    from bench_closed_loop import child_node
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from multirotor_ros.nodes.clock import CLOCK_QOS

    rclpy, node, spin = child_node("bare_controllers", "events")
    reply = bytearray(
        serialize_message(
            JointState(name=[f"rotor_{k}" for k in range(1, BARE_ROTORS + 1)], velocity=[300.0] * BARE_ROTORS)
        )
    )
    commands = [node.create_publisher(JointState, f"/bare{k}/motor_speed_cmd", 10) for k in range(vehicles)]

    def answer(publisher: Any, data: bytes) -> None:
        reply[4:12] = data[4:12]  # header.stamp, right after the CDR encapsulation in both messages
        publisher.publish(bytes(reply))

    for k, publisher in enumerate(commands):
        node.create_subscription(Odometry, f"/bare{k}/odom", partial(answer, publisher), 1, raw=True)
    node.create_subscription(Clock, "/clock", lambda _: None, CLOCK_QOS, raw=True)  # taken, as the nodes do
    try:
        spin(rclpy.ok)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def bare_exchange(vehicles: int, rate_hz: float, seconds: float, logs: Path) -> float:
    """The share of control periods the bare plant and controllers keep on time (module docstring)."""
    from bench_closed_loop import start, stop

    me = [sys.executable, str(Path(__file__).resolve())]
    controllers = start(
        [*me, "--role", "bare-controllers", "--vehicles", str(vehicles)], logs / f"v{vehicles}-bare.log"
    )
    try:
        done = subprocess.run(
            [*me, "--role", "bare-plant", "--vehicles", str(vehicles), "--rate-hz", str(rate_hz),
             "--seconds", str(seconds)],
            capture_output=True, text=True, timeout=seconds + 120,
        )  # fmt: skip
    finally:
        stop([controllers])
    reported = dict(line.split(maxsplit=1) for line in done.stdout.splitlines() if " " in line)
    if "ON_TIME" not in reported:
        print(f"  the bare plant reported nothing; its output:\n{done.stdout}{done.stderr}")
        return math.nan
    on_time, late = int(reported["ON_TIME"]), int(reported["LATE"])
    return on_time / max(on_time + late, 1)


def next_status(pacing) -> tuple[dict[str, float], float]:  # noqa: ANN001 - a Recorder
    """The next pacing status to arrive, and the wall time it arrived at."""
    pacing.clear()
    message = pacing.wait_for(count=1, timeout=30.0)[-1]
    return pacing_values(message), time.monotonic()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vehicles", default="1,5,10,15", help="fleet sizes, comma-separated")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured flight per fleet size [s]")
    parser.add_argument(
        "--controllers",
        default="composed,bundled,separate",
        help="composed (one process), bundled (one process, fleet bundles), separate (one each)",
    )
    parser.add_argument("--rate-hz", type=float, default=250.0, help="control (and odometry) rate [Hz]")
    parser.add_argument(
        "--ceiling",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="measure the bare exchange beside each fleet size",
    )
    parser.add_argument("--role", choices=("bare-plant", "bare-controllers"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "bare-plant":
        bare_plant(int(args.vehicles), args.rate_hz, args.seconds)
        return 0
    if args.role == "bare-controllers":
        bare_controllers(int(args.vehicles))
        return 0
    logs = Path(tempfile.mkdtemp(prefix="bench_fleet_ros_"))
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} CPUs, logs in {logs}")
    print(f"control rate {args.rate_hz:g} Hz")
    print(
        f"{'vehicles':>8} {'controllers':>11} {'achieved RTF':>12} {'on time':>8} {'|z - 1| after':>14} "
        f"{'keeps real time':>16} {'load':>5} {'CPU sim':>8} {'CPU ctrl':>8}"
    )
    ways = args.controllers.split(",")
    if not set(ways) <= {"composed", "bundled", "separate"}:
        parser.error(f"--controllers: composed, bundled and/or separate, got {args.controllers!r}")
    for vehicles in (int(v) for v in args.vehicles.split(",")):
        if args.ceiling:
            share = bare_exchange(vehicles, args.rate_hz, args.seconds, logs)
            print(
                f"{vehicles:8d} {'bare':>11} {'':>12} {100 * share:7.1f}% {'':>14} "
                f"{'yes' if share >= 0.99 else 'no':>16} {os.getloadavg()[0]:5.1f}",
                flush=True,
            )
        for way in ways:
            result = fly(vehicles, args.seconds, logs, way, args.rate_hz)
            keeps = (
                result["achieved"] >= 0.99
                and result["on_time"] >= 0.99
                and result["height_error_after_m"] < 0.05
            )
            print(
                f"{vehicles:8d} {way:>11} {result['achieved']:12.3f} {100 * result['on_time']:7.1f}% "
                f"{result['height_error_after_m']:13.3f}m {'yes' if keeps else 'no':>16} "
                f"{os.getloadavg()[0]:5.1f} {100 * result['simulator_cpu']:7.0f}% "
                f"{100 * result['controllers_cpu']:7.0f}%",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
