"""Closed loop over ROS 2 across two processes, and the ceiling rclpy itself sets on this machine.

    .venv/bin/python bench/bench_closed_loop.py [--seconds 10] [--airframe x8_octorotor]

1. Closed loop: ``multirotor node simulator`` (1 kHz physics, real_time_factor 0, lockstep, clock) and
   ``multirotor node controller`` (250 Hz, use_sim_time) hovering the vehicle. Reported: simulated seconds
   per wall second, and the latency from a motor command to the next state that reflects it: the wall
   time between a probe receiving ``motor_speed_cmd`` stamped t and receiving the ``odom`` stamped
   t + 4 ms (in lockstep the command holds from t on, so that odometry is the first to reflect it).
2. Ceiling: two bare rclpy processes exchanging the same messages (Odometry one way, an 8-rotor
   JointState back) in ping-pong, with no physics and no control: round trips per second, i.e. the most
   4 ms control periods rclpy could carry per second; and the one-way Odometry rate of a publisher that
   publishes as fast as it can.

Every process runs in a ROS domain of its own choosing (random, localhost only), so the numbers are not
mixed with other traffic. The machine's load is printed with them: they are wall-clock numbers.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

CONTROL_PERIOD_NS = 4_000_000
ROTORS = 8


def stamp_ns(message) -> int:  # noqa: ANN001 - any stamped message
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def start(argv: list[str], log: Path) -> subprocess.Popen:
    with open(log, "wb") as output:
        return subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=output,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )


def stop(processes: list[subprocess.Popen]) -> None:
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(10.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class Probe:
    """An rclpy node spun in a background thread."""

    def __init__(self, name: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(args=[name], context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(5.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def closed_loop(seconds: float, airframe: str, logs: Path) -> dict[str, float]:
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    node = [sys.executable, "-m", "multirotor_ros.cli", "node"]
    processes = [
        start(
            [
                *node,
                "simulator",
                "--ros-args",
                "-p",
                f"airframe:={airframe}",
                "-p",
                "real_time_factor:=0.0",
                "-p",
                "publish_clock:=true",
                "-p",
                "physics_rate_hz:=1000.0",
                "-p",
                "initial_z:=1.0",
            ],
            logs / "simulator.log",
        ),
        start(
            [*node, "controller", "--ros-args", "-p", f"airframe:={airframe}", "-p", "use_sim_time:=true"],
            logs / "controller.log",
        ),
    ]
    probe = Probe("bench_probe")
    commands: dict[int, float] = {}
    odometry: dict[int, float] = {}
    lock = threading.Lock()

    def on_command(message: JointState) -> None:
        with lock:
            commands[stamp_ns(message)] = time.perf_counter()

    def on_odom(message: Odometry) -> None:
        with lock:
            odometry[stamp_ns(message)] = time.perf_counter()

    try:
        probe.node.create_subscription(JointState, "/motor_speed_cmd", on_command, 100)
        probe.node.create_subscription(Odometry, "/odom", on_odom, 100)
        setpoint = probe.node.create_publisher(PoseStamped, "/setpoint", 10)
        deadline = time.monotonic() + 120.0
        while not (commands and setpoint.get_subscription_count()):
            if time.monotonic() > deadline or any(p.poll() is not None for p in processes):
                raise SystemExit(f"the nodes did not come up; logs in {logs}")
            time.sleep(0.1)
        message = PoseStamped()
        message.header.frame_id = "odom"
        message.pose.position.z = 1.0
        message.pose.orientation.w = 1.0
        setpoint.publish(message)
        time.sleep(2.0)  # warm-up: discovery settled, caches hot
        with lock:
            commands.clear()
            odometry.clear()
        start_wall = time.perf_counter()
        time.sleep(seconds)
        with lock:
            wall = time.perf_counter() - start_wall
            command_items = sorted(commands.items())
            odometry_items = dict(odometry)
    finally:
        probe.close()
        stop(processes)
    simulated = (max(odometry_items) - min(odometry_items)) * 1e-9
    latencies = [
        odometry_items[t + CONTROL_PERIOD_NS] - received
        for t, received in command_items
        if t + CONTROL_PERIOD_NS in odometry_items
    ]
    latencies = [latency for latency in latencies if latency > 0]
    return {
        "sim_s_per_wall_s": simulated / wall,
        "control_periods_per_s": len(command_items) / wall,
        "latency_median_ms": 1e3 * statistics.median(latencies),
        "latency_p95_ms": 1e3 * statistics.quantiles(latencies, n=20)[-1],
        "latency_samples": len(latencies),
    }


def pong() -> None:
    """Child role: answer each Odometry with an 8-rotor JointState carrying its stamp."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("bench_pong")
    reply = JointState(name=[f"rotor_{k}" for k in range(1, ROTORS + 1)], velocity=[300.0] * ROTORS)
    publisher = node.create_publisher(JointState, "/bench/cmd", 10)

    def on_odom(message: Odometry) -> None:
        reply.header.stamp = message.header.stamp
        publisher.publish(reply)

    node.create_subscription(Odometry, "/bench/odom", on_odom, 10)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def sink() -> None:
    """Child role: count Odometry messages; print the count when interrupted."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException

    rclpy.init()
    node = rclpy.create_node("bench_sink")
    received = []
    node.create_subscription(Odometry, "/bench/stream", lambda m: received.append(time.perf_counter()), 1000)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # SIGINT can shut the context down while a message is being taken: the count so far stands.
        if rclpy.ok():
            raise
    if len(received) > 1:
        print(f"RATE {(len(received) - 1) / (received[-1] - received[0]):.1f}", flush=True)


def ceiling(seconds: float, logs: Path) -> dict[str, float]:
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    me = [sys.executable, str(Path(__file__).resolve())]
    partner = start([*me, "--role", "pong"], logs / "pong.log")
    probe = Probe("bench_ping")
    round_trips = 0
    answered = threading.Event()

    def on_reply(_: JointState) -> None:
        answered.set()

    try:
        probe.node.create_subscription(JointState, "/bench/cmd", on_reply, 10)
        publisher = probe.node.create_publisher(Odometry, "/bench/odom", 10)
        message = Odometry()
        deadline = time.monotonic() + 60.0
        while publisher.get_subscription_count() == 0 or probe.node.count_publishers("/bench/cmd") == 0:
            if time.monotonic() > deadline:
                raise SystemExit(f"the ping-pong partner did not come up; log in {logs / 'pong.log'}")
            time.sleep(0.1)
        time.sleep(1.0)
        end = time.perf_counter() + seconds
        started = time.perf_counter()
        while time.perf_counter() < end:
            answered.clear()
            message.header.stamp = Time(
                sec=round_trips // 250, nanosec=(round_trips % 250) * CONTROL_PERIOD_NS
            )
            publisher.publish(message)
            if not answered.wait(1.0):
                continue  # a lost message: send the next one
            round_trips += 1
        elapsed = time.perf_counter() - started
    finally:
        probe.close()
        stop([partner])

    counter = subprocess.Popen(
        [*me, "--role", "sink"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
        text=True,
    )
    probe = Probe("bench_stream")
    try:
        publisher = probe.node.create_publisher(Odometry, "/bench/stream", 1000)
        deadline = time.monotonic() + 60.0
        while publisher.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                raise SystemExit("the stream counter did not come up")
            time.sleep(0.1)
        time.sleep(1.0)
        message = Odometry()
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            publisher.publish(message)
        time.sleep(0.5)
    finally:
        probe.close()
        counter.send_signal(signal.SIGINT)
        output, _ = counter.communicate(timeout=20.0)
    rates = [float(line.split()[1]) for line in output.splitlines() if line.startswith("RATE ")]
    if not rates:
        print(f"the stream counter reported no rate; its output:\n{output}")
    return {
        "round_trips_per_s": round_trips / elapsed,
        "ceiling_sim_s_per_wall_s": round_trips / elapsed * CONTROL_PERIOD_NS * 1e-9,
        "one_way_odometry_per_s": rates[0] if rates else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring time of each part [s]")
    parser.add_argument("--airframe", default="x8_octorotor")
    parser.add_argument("--role", choices=("pong", "sink"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "pong":
        pong()
        return 0
    if args.role == "sink":
        sink()
        return 0
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(101, 200)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    logs = Path(tempfile.mkdtemp(prefix="bench_closed_loop_"))
    print(
        f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.2f} at start, logs in {logs}"
    )
    loop = closed_loop(args.seconds, args.airframe, logs)
    print(f"closed loop ({args.airframe}, 1 kHz physics, 250 Hz control, real_time_factor 0, lockstep):")
    print(
        f"  {loop['sim_s_per_wall_s']:.2f} simulated s per wall s "
        f"({loop['control_periods_per_s']:.0f} control "
        f"periods/s)"
    )
    print(
        f"  command -> next state reflecting it: median {loop['latency_median_ms']:.2f} ms, "
        f"95th percentile {loop['latency_p95_ms']:.2f} ms ({loop['latency_samples']} commands)"
    )
    top = ceiling(args.seconds, logs)
    print("ceiling (bare rclpy, same messages, no physics, no control):")
    print(
        f"  Odometry -> JointState ping-pong: {top['round_trips_per_s']:.0f} round trips/s "
        f"= {top['ceiling_sim_s_per_wall_s']:.2f} simulated s per wall s at 4 ms per period"
    )
    print(f"  one-way Odometry stream: {top['one_way_odometry_per_s']:.0f} messages/s")
    print(
        f"  the closed loop reaches {100 * loop['sim_s_per_wall_s'] / top['ceiling_sim_s_per_wall_s']:.0f} % "
        f"of the ping-pong ceiling; load average {os.getloadavg()[0]:.2f} at the end"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
