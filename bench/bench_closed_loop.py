"""Closed loop over ROS 2 across two processes, the ceiling rclpy itself sets, and the loop in real time.

    .venv/bin/python bench/bench_closed_loop.py [--seconds 10] [--rounds 1] [--realtime-seconds 30]
        [--executors events,single] [--airframe x8_octorotor] [--profile DIR] [--skip-ceiling] [--identifier]

1. Lockstep: ``multirotor node simulator`` (1 kHz physics, real_time_factor 0, lockstep, clock) and
   ``multirotor node controller`` (250 Hz, use_sim_time) hovering the vehicle, once per executor the
   nodes can spin with (``MULTIROTOR_ROS_EXECUTOR``, nodes/entry.py; the controller keeps its simulated
   time itself, so it spins on the executor named too). First unobserved, as the ceiling runs: simulated
   seconds per wall second and control periods per second from the simulator's own 1 Hz ``pacing``
   status (its simulated time at two statuses, over the wall time between their arrivals), and the CPU
   time each node process spends per control period (all its threads, from /proc: what the loop costs,
   whatever else the machine runs). Then watched: the probe takes every command and state (serialised)
   for the latency from a motor command to the next state that reflects it (the wall time between the
   probe receiving ``motor_speed_cmd`` stamped t and ``odom`` stamped t + 4 ms), and the rate while it
   does (each node then publishes to two readers, and the probe is a third busy process). With
   ``--identifier`` a third process, ``multirotor node identifier`` (use_sim_time), watches the loop as it
   would a flight: a lockstep simulator does not wait for it, so what it keeps up with is reported, the
   state samples it processed per simulated second (``residuals``: one per sample, ``sample_rate_hz`` 100
   asked) and the gaps in its data that restarted its observer (its log), with its CPU time per control
   period.
2. Ceiling: two bare rclpy processes exchanging the same messages (Odometry one way, an 8-rotor JointState
   back) in ping-pong, each answering in its subscription callback, with no physics and no control: round
   trips per second (and the ping side's CPU time per round trip), i.e. the most 4 ms control periods
   rclpy could carry per second; once with the SingleThreadedExecutor and once with the EventsExecutor
   (spun as nodes/entry.py spins it). The loop is compared with the best of the two.
3. Real time (``--realtime-seconds``, 0 to skip): the simulator at real_time_factor 1 with its clock and the
   controller on use_sim_time, default executor. Reported from the simulator's own ``pacing`` status
   (simulation/pacing.py ControlTiming): the share of control periods on time, i.e. whose command
   (stamped at the period's start) was in force before the physics passed the period's end, and the
   achieved real-time factor; and the resident memory (VmRSS) of both node processes after the warm-up,
   at the end, and its growth and trend (least squares, MB/min) over the second half (what a leak shows).

``--profile DIR`` runs the lockstep nodes with ``MULTIROTOR_ROS_PROFILE=DIR`` (cProfile in each node
process, nodes/entry.py) and prints, per node, its top functions per control period: exact call counts,
and wall times (a function in which the process is preempted is charged for the wait: on two cores,
``publish`` often is, when it wakes the receiving process). Profiling slows the Python code down: the
rates of such a run are not the benchmark's. ``py-spy record --native`` gives CPU samples instead.

The probe that watches the loop takes its messages serialised (no conversion to Python messages) and
spins an EventsExecutor, so that it costs the two nodes as little CPU as possible. Every part runs in a
ROS domain of its own (random, localhost only). The machine's load average is printed with each part:
they are wall-clock numbers.
"""

from __future__ import annotations

import argparse
import os
import pstats
import random
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

CONTROL_PERIOD_NS = 4_000_000
ROTORS = 8
EXECUTORS = ("events", "single")
WARM_UP_S = 2.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def raw_stamp_ns(data: bytes) -> int:
    """header.stamp of a serialised stamped message (CDR: 4 bytes of encapsulation, then sec, nanosec)."""
    sec, nanosec = struct.unpack_from("<iI" if data[1] == 1 else ">iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a process, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def start(argv: list[str], log: Path, **env: str) -> subprocess.Popen:
    with open(log, "wb") as output:
        return subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=output,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1", **env),
        )


def stop(processes: list[subprocess.Popen]) -> None:
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(15.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def new_domain() -> None:
    """A ROS domain of its own for what starts next (a finished part's participants cannot interfere)."""
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(101, 200))


def spin_in_slices(executor: Any, keep_going: Callable[[], bool]) -> None:
    """Spin in slices while ``keep_going()``, either executor (the EventsExecutor as nodes/entry.py does).

    The EventsExecutor's ``spin()`` busy-waits in the wheels; both are spun alike so that they stop alike.
    """
    while keep_going():
        executor.spin_once(timeout_sec=0.1)


class Probe:
    """An rclpy node in a context of its own, spun by an EventsExecutor in a background thread."""

    def __init__(self, name: str):
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.context = rclpy.Context()
        rclpy.init(args=[name], context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.running = True
        self.thread = threading.Thread(
            target=spin_in_slices,
            args=(self.executor, lambda: self.running and self.context.ok()),
            daemon=True,
        )
        self.thread.start()

    def stamps(self, topic: str, msg_type: Any, qos: Any = 100) -> tuple[dict[int, float], threading.Lock]:
        """Arrival wall time (perf_counter) per stamp of a topic, taken serialised."""
        arrivals: dict[int, float] = {}
        lock = threading.Lock()

        def on_message(data: bytes) -> None:
            now = time.perf_counter()
            with lock:
                arrivals[raw_stamp_ns(data)] = now

        self.node.create_subscription(msg_type, topic, on_message, qos, raw=True)
        return arrivals, lock

    def pacing(self) -> PacingWatch:
        """Watch the simulator's ``pacing`` status (1 Hz of wall time)."""
        from diagnostic_msgs.msg import DiagnosticArray

        watch = PacingWatch()
        self.node.create_subscription(DiagnosticArray, "/pacing", watch.on_pacing, 10)
        return watch

    def close(self) -> None:
        self.running = False
        self.thread.join(5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def node_processes(
    airframe: str,
    logs: Path,
    tag: str,
    simulator: list[str],
    controller: list[str],
    identifier: bool = False,
    **env: str,
) -> list[subprocess.Popen]:
    node = [sys.executable, "-m", "multirotor_ros.cli", "node"]
    processes = [
        start(
            [*node, "simulator", "--ros-args", "-p", f"airframe:={airframe}", "-p", "publish_clock:=true"]
            + [a for p in ["physics_rate_hz:=1000.0", "initial_z:=1.0", *simulator] for a in ("-p", p)],
            logs / f"simulator-{tag}.log",
            **env,
        ),
        start(
            [*node, "controller", "--ros-args", "-p", f"airframe:={airframe}", "-p", "use_sim_time:=true"]
            + [a for p in controller for a in ("-p", p)],
            logs / f"controller-{tag}.log",
            **env,
        ),
    ]
    if identifier:
        processes.append(
            start(
                [*node, "identifier", "--ros-args"]
                + ["-p", f"airframe:={airframe}", "-p", "use_sim_time:=true"],
                logs / f"identifier-{tag}.log",
                **env,
            )
        )
    return processes


def fly(probe: Probe, processes: list[subprocess.Popen], running: Callable[[], bool], logs: Path) -> None:
    """Wait for the loop to run, send the hover setpoint, let it settle."""
    from geometry_msgs.msg import PoseStamped

    setpoint = probe.node.create_publisher(PoseStamped, "/setpoint", 10)
    deadline = time.monotonic() + 120.0
    while not (running() and setpoint.get_subscription_count()):
        if time.monotonic() > deadline or any(p.poll() is not None for p in processes):
            raise SystemExit(f"the nodes did not come up; logs in {logs}")
        time.sleep(0.1)
    message = PoseStamped()
    message.header.frame_id = "odom"
    message.pose.position.z = 1.0
    message.pose.orientation.w = 1.0
    setpoint.publish(message)
    time.sleep(WARM_UP_S)  # discovery settled, caches hot


class PacingWatch:
    """The simulator's newest ``pacing`` status, its arrival time and how many have come."""

    def __init__(self) -> None:
        self.count = 0
        self.arrival = float("nan")
        self.values: dict[str, str] = {}
        self.lock = threading.Lock()

    def on_pacing(self, message: Any) -> None:
        now = time.perf_counter()
        for item in message.status:
            if item.name.endswith("pacing"):
                with self.lock:
                    self.count, self.arrival = self.count + 1, now
                    self.values = {v.key: v.value for v in item.values}

    def simulated_s(self) -> float:
        with self.lock:
            return float(self.values.get("simulated_time_s", "0"))

    def next(self, processes: list[subprocess.Popen]) -> tuple[float, float, list[float]]:
        """Wait for the next status: its arrival (perf_counter s), simulated time [s], the nodes' CPU [s]."""
        seen = self.count
        deadline = time.monotonic() + 10.0
        while self.count == seen:
            if time.monotonic() > deadline:
                raise SystemExit("no pacing status from the simulator for 10 s")
            time.sleep(0.002)
        cpu = [cpu_s(p.pid) for p in processes]
        with self.lock:
            return self.arrival, float(self.values["simulated_time_s"]), cpu


def lockstep(
    seconds: float,
    airframe: str,
    logs: Path,
    executor: str,
    tag: str,
    profile: Path | None,
    identifier: bool = False,
) -> dict:
    """The loop's rate unobserved (from the simulator's pacing status), then watched by the probe."""
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    new_domain()
    env = {"MULTIROTOR_ROS_EXECUTOR": executor}
    if profile is not None:
        env["MULTIROTOR_ROS_PROFILE"] = str(profile)
    processes = node_processes(airframe, logs, tag, ["real_time_factor:=0.0"], [], identifier, **env)
    probe = Probe("bench_probe")
    try:
        pacing = probe.pacing()
        residuals, residuals_lock = probe.stamps("/residuals", Vector3Stamped, qos=1000)
        fly(probe, processes, lambda: pacing.simulated_s() > 0.0, logs)
        deadline = time.monotonic() + 120.0
        while identifier and not residuals:  # its start-up (compiled kernels) is not measured
            if time.monotonic() > deadline:
                raise SystemExit(f"the identifier published no residuals; logs in {logs}")
            time.sleep(0.1)
        # Unobserved, as the ceiling is: nothing but the 1 Hz status leaves the two nodes.
        gaps_before = gaps_in_log(logs / f"identifier-{tag}.log")
        with residuals_lock:
            residuals.clear()
        start_wall, start_sim, cpu_start = pacing.next(processes)
        time.sleep(max(0.0, seconds - 1.0))
        end_wall, end_sim, cpu_end = pacing.next(processes)
        with residuals_lock:
            residual_stamps = list(residuals)
        gaps = gaps_in_log(logs / f"identifier-{tag}.log") - gaps_before
        wall, simulated_s = end_wall - start_wall, end_sim - start_sim
        periods = simulated_s / (CONTROL_PERIOD_NS * 1e-9)
        cpu = [end - begin for end, begin in zip(cpu_end, cpu_start, strict=True)]
        # Watched: the probe takes every command and state (serialised) to time the step in between; the
        # nodes then publish to two readers each, and the probe is a third busy process.
        commands, lock = probe.stamps("/motor_speed_cmd", JointState)
        odometry, odometry_lock = probe.stamps("/odom", Odometry)
        time.sleep(WARM_UP_S)
        with lock, odometry_lock:
            commands.clear()
            odometry.clear()
        start_watched = time.perf_counter()
        time.sleep(seconds)
        with lock, odometry_lock:
            watched_wall = time.perf_counter() - start_watched
            command_items = sorted(commands.items())
            odometry_items = dict(odometry)
    finally:
        probe.close()
        stop(processes)
    latencies = [
        odometry_items[t + CONTROL_PERIOD_NS] - received
        for t, received in command_items
        if t + CONTROL_PERIOD_NS in odometry_items
    ]
    latencies = [latency for latency in latencies if latency > 0] or [float("nan")] * 2
    identified = (
        {
            "identifier_samples_per_sim_s": len(residual_stamps) / simulated_s,
            "identifier_gaps": gaps,
            "identifier_cpu_ms": 1e3 * cpu[2] / max(periods, 1),
        }
        if identifier
        else {}
    )
    return {
        **identified,
        "sim_s_per_wall_s": simulated_s / wall,
        "periods_per_s": periods / wall,
        "watched_periods_per_s": len(command_items) / watched_wall,
        "latency_median_ms": 1e3 * statistics.median(latencies),
        "latency_p95_ms": 1e3 * statistics.quantiles(latencies, n=20)[-1],
        "simulator_cpu_ms": 1e3 * cpu[0] / max(periods, 1),
        "controller_cpu_ms": 1e3 * cpu[1] / max(periods, 1),
        "periods": periods,
    }


def gaps_in_log(path: Path) -> int:
    """The gaps in its data the identifier stepped over by restarting its observer (its warnings)."""
    return path.read_text(errors="replace").count("] gap of ") if path.exists() else 0


# ------------------------------------------------------------------------------------------------
# Ceiling: bare rclpy ping-pong


def child_node(name: str, executor_name: str) -> tuple[Any, Any, Callable[[Callable[[], bool]], None]]:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    node = rclpy.create_node(name)
    if executor_name == "events":
        from rclpy.experimental import EventsExecutor

        executor: Any = EventsExecutor()
    else:
        executor = SingleThreadedExecutor()
    executor.add_node(node)

    return rclpy, node, lambda keep_going: spin_in_slices(executor, keep_going)


def pong(executor_name: str) -> None:
    """Child role: answer each Odometry with an 8-rotor JointState carrying its stamp."""
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    rclpy, node, spin = child_node("bench_pong", executor_name)
    reply = JointState(name=[f"rotor_{k}" for k in range(1, ROTORS + 1)], velocity=[300.0] * ROTORS)
    publisher = node.create_publisher(JointState, "/bench/cmd", 10)

    def on_odom(message: Odometry) -> None:
        reply.header.stamp = message.header.stamp
        publisher.publish(reply)

    node.create_subscription(Odometry, "/bench/odom", on_odom, 10)
    try:
        spin(rclpy.ok)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def ping(executor_name: str, seconds: float) -> None:
    """Child role: publish the next Odometry from the callback of each answer; print round trips/s."""
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    rclpy, node, spin = child_node("bench_ping", executor_name)
    publisher = node.create_publisher(Odometry, "/bench/odom", 10)
    message = Odometry()
    answers = [0]
    last_sent = [time.monotonic()]

    def send() -> None:
        message.header.stamp = Time(sec=answers[0] // 250, nanosec=(answers[0] % 250) * CONTROL_PERIOD_NS)
        last_sent[0] = time.monotonic()
        publisher.publish(message)

    def on_reply(_: JointState) -> None:
        answers[0] += 1
        send()

    def resend() -> None:  # a lost message would stop the ping-pong
        if time.monotonic() - last_sent[0] > 0.5:
            send()

    node.create_subscription(JointState, "/bench/cmd", on_reply, 10)
    node.create_timer(0.5, resend)
    deadline = time.monotonic() + 60.0
    while publisher.get_subscription_count() == 0 or node.count_publishers("/bench/cmd") == 0:
        if time.monotonic() > deadline:
            raise SystemExit("the ping-pong partner did not come up")
        time.sleep(0.1)
    time.sleep(1.0)
    send()
    warm_end = time.monotonic() + WARM_UP_S
    spin(lambda: time.monotonic() < warm_end)
    counted, started, cpu_started = answers[0], time.perf_counter(), time.process_time()
    end = time.monotonic() + seconds
    spin(lambda: time.monotonic() < end)
    round_trips = answers[0] - counted
    print(f"RATE {round_trips / (time.perf_counter() - started):.1f}", flush=True)
    print(f"CPU {(time.process_time() - cpu_started) / max(round_trips, 1):.6f}", flush=True)


def ceiling(seconds: float, logs: Path, executor: str, tag: str) -> tuple[float, float]:
    """Round trips per second of the ping-pong, both sides on ``executor``; ping's CPU [s] per round trip."""
    new_domain()
    me = [sys.executable, str(Path(__file__).resolve())]
    partner = start([*me, "--role", "pong", "--executors", executor], logs / f"pong-{tag}.log")
    try:
        done = subprocess.run(
            [*me, "--role", "ping", "--executors", executor, "--seconds", str(seconds)],
            capture_output=True,
            text=True,
            timeout=seconds + 120,
        )
    finally:
        stop([partner])
    reported = dict(line.split(maxsplit=1) for line in done.stdout.splitlines() if " " in line)
    if "RATE" not in reported:
        print(f"  the ping side reported no rate; its output:\n{done.stdout}{done.stderr}")
    return float(reported.get("RATE", "nan")), float(reported.get("CPU", "nan"))


# ------------------------------------------------------------------------------------------------
# Real time


def realtime(seconds: float, airframe: str, logs: Path) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    new_domain()
    processes = node_processes(airframe, logs, "realtime", ["real_time_factor:=1.0"], [])
    probe = Probe("bench_realtime_probe")
    status: list[dict[str, str]] = []
    status_lock = threading.Lock()

    def on_pacing(message: DiagnosticArray) -> None:
        for item in message.status:
            if item.name.endswith("pacing"):
                with status_lock:
                    status.append({v.key: v.value for v in item.values})

    def latest() -> dict[str, str]:
        with status_lock:
            return dict(status[-1]) if status else {}

    try:
        probe.node.create_subscription(DiagnosticArray, "/pacing", on_pacing, 10)
        commands, _ = probe.stamps("/motor_speed_cmd", JointState)
        fly(probe, processes, lambda: bool(commands), logs)
        first = latest()
        rss = [(time.monotonic(), [rss_mb(p.pid) for p in processes])]
        cpu_start = [cpu_s(p.pid) for p in processes]
        started = time.monotonic()
        while time.monotonic() - started < seconds:
            time.sleep(min(5.0, max(0.0, seconds - (time.monotonic() - started))))
            rss.append((time.monotonic(), [rss_mb(p.pid) for p in processes]))
            if any(p.poll() is not None for p in processes):
                raise SystemExit(f"a node ended during the real-time run; logs in {logs}")
        wall = time.monotonic() - started
        cpu = [cpu_s(p.pid) - c for p, c in zip(processes, cpu_start, strict=True)]
        time.sleep(1.2)  # one more pacing status
        last = latest()
    finally:
        probe.close()
        stop(processes)
    if not (first and last):
        raise SystemExit(f"no pacing status from the simulator; logs in {logs}")

    def delta(key: str) -> float:
        return float(last.get(key, "nan")) - float(first.get(key, "nan"))

    on_time, late = delta("control_periods_on_time"), delta("control_periods_late")
    half = [(t, sample) for t, sample in rss if t >= rss[0][0] + (rss[-1][0] - rss[0][0]) / 2]
    slopes = []
    for k in range(len(processes)):
        times = [t for t, _ in half]
        values = [sample[k] for _, sample in half]
        slopes.append(
            60 * statistics.linear_regression(times, values).slope if len(half) > 1 else float("nan")
        )
    return {
        "wall_s": wall,
        "on_time_share": on_time / (on_time + late) if on_time + late else float("nan"),
        "periods": on_time + late,
        "late": late,
        "achieved_factor": float(last.get("achieved_real_time_factor_since_start", "nan")),
        "rss_start": rss[0][1],
        "rss_end": rss[-1][1],
        "rss_growth_second_half": [end - mid for end, mid in zip(rss[-1][1], half[0][1], strict=True)],
        "rss_slope_mb_per_min": slopes,
        "cpu_share": [c / wall for c in cpu],
    }


# ------------------------------------------------------------------------------------------------
# Profile


# A function each node calls once per control period: what its profile is divided by (the callbacks
# themselves are called from C++ by the EventsExecutor, where cProfile does not count them reliably).
PERIOD_FUNCTIONS = {"controller": "state_from_odometry", "simulator": "odometry_message"}


def where_the_time_goes(profile_dir: Path, window_periods: int, rows: int = 16) -> None:
    """Per node: its top functions by own time, and its messages and conversions, per control period."""
    for path in sorted(profile_dir.glob("*.prof")):
        entries = pstats.Stats(str(path)).stats  # type: ignore[attr-defined]
        node = path.name.split("-")[0]
        counted = [
            calls for (_, _, name), (_, calls, *_) in entries.items() if name == PERIOD_FUNCTIONS.get(node)
        ]
        periods = max(counted, default=window_periods)
        total = sum(own for (_, _, own, _, _) in entries.values())
        print(f"  {path.name}: {periods} control periods, {1e6 * total / periods:.0f} µs of wall time each")
        print(f"    {'own µs/period':>13} {'calls/period':>12}  function")

        def row(key: tuple[str, int, str], value: tuple, periods: int = periods) -> str:
            filename, line, name = key
            where = (
                name
                if filename == "~"
                else f"{Path(filename).parent.name}/{Path(filename).name}:{line} {name}"
            )
            return f"    {1e6 * value[2] / periods:13.1f} {value[1] / periods:12.2f}  {where}"

        for key, value in sorted(entries.items(), key=lambda item: item[1][2], reverse=True)[:rows]:
            print(row(key, value))
        print("    messages and conversions:")
        conversions = [
            (key, value)
            for key, value in entries.items()
            if key[0].endswith(("nodes/messages.py", "rclpy/publisher.py"))
            or ("/msg/_" in key[0] and key[2] == "__init__")
        ]
        for key, value in sorted(conversions, key=lambda item: item[1][1], reverse=True):
            if value[1] >= 0.05 * periods:
                print(row(key, value))


# ------------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="measuring time of each lockstep/ceiling run"
    )
    parser.add_argument("--rounds", type=int, default=1, help="repeat the lockstep and ceiling runs")
    parser.add_argument("--realtime-seconds", type=float, default=30.0, help="real-time run [s]; 0 = skip")
    parser.add_argument("--executors", default=",".join(EXECUTORS), help="executors of the nodes, in order")
    parser.add_argument("--airframe", default="x8_octorotor")
    parser.add_argument("--profile", type=Path, help="profile the lockstep nodes into this directory")
    parser.add_argument("--skip-ceiling", action="store_true")
    parser.add_argument(
        "--identifier", action="store_true", help="an identifier node watches the lockstep loop"
    )
    parser.add_argument("--role", choices=("pong", "ping"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    executors = [e for e in args.executors.split(",") if e]
    if args.role == "pong":
        pong(executors[0])
        return 0
    if args.role == "ping":
        ping(executors[0], args.seconds)
        return 0
    unknown = set(executors) - set(EXECUTORS)
    if unknown:
        parser.error(f"unknown executor(s) {', '.join(sorted(unknown))}; choose from {', '.join(EXECUTORS)}")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    logs = Path(tempfile.mkdtemp(prefix="bench_closed_loop_"))
    print(f"{os.cpu_count()} CPUs, {load()} at start, logs in {logs}")
    loops: dict[str, list[dict]] = {e: [] for e in executors}
    tops: dict[str, list[float]] = {e: [] for e in EXECUTORS}
    for round_ in range(args.rounds):
        for executor in executors:
            profile = (
                args.profile
                if args.profile is not None and round_ == 0 and executor == executors[0]
                else None
            )
            loop = lockstep(
                args.seconds, args.airframe, logs, executor, f"{executor}-{round_}", profile, args.identifier
            )
            loops[executor].append(loop)
            watched = (
                f"; identifier {loop['identifier_samples_per_sim_s']:.1f} samples per simulated s, "
                f"{loop['identifier_gaps']} gaps, CPU {loop['identifier_cpu_ms']:.2f} ms per period"
                if args.identifier
                else ""
            )
            print(
                f"lockstep, nodes on {executor:6s}: {loop['sim_s_per_wall_s']:.2f} sim s/wall s = "
                f"{loop['periods_per_s']:.0f} control periods/s unobserved (CPU per period: simulator "
                f"{loop['simulator_cpu_ms']:.2f} ms, controller {loop['controller_cpu_ms']:.2f} ms"
                f"{watched}); "
                f"watched by the probe {loop['watched_periods_per_s']:.0f} control periods/s, command -> "
                f"state median {loop['latency_median_ms']:.2f} ms, p95 {loop['latency_p95_ms']:.2f} ms "
                f"({load()})",
                flush=True,
            )
            if profile is not None:
                where_the_time_goes(profile, loop["periods"])
        if not args.skip_ceiling:
            for executor in EXECUTORS:
                rate, ping_cpu_s = ceiling(args.seconds, logs, executor, f"{executor}-{round_}")
                tops[executor].append(rate)
                print(
                    f"ceiling, bare rclpy Odometry -> JointState ping-pong on {executor:6s}: {rate:.0f} "
                    f"round trips/s = {rate * CONTROL_PERIOD_NS * 1e-9:.2f} sim s/wall s (CPU per round "
                    f"trip: ping side {1e3 * ping_cpu_s:.2f} ms) ({load()})",
                    flush=True,
                )
    print("summary (median of the rounds):")
    ceilings = {e: statistics.median(r) for e, r in tops.items() if r}
    for executor, rate in ceilings.items():
        print(f"  ceiling on {executor:6s}: {rate:.0f} round trips/s")
    best = max(ceilings.values(), default=float("nan"))
    for executor, runs in loops.items():
        rate = statistics.median(r["periods_per_s"] for r in runs)
        spread = f" (rounds {', '.join(f'{r["periods_per_s"]:.0f}' for r in runs)})" if len(runs) > 1 else ""
        shares = ", ".join(f"{100 * rate / top:.0f} % of the {e} ceiling" for e, top in ceilings.items())
        print(
            f"  lockstep on {executor:6s}: {rate:.0f} control periods/s{spread} = "
            f"{rate * CONTROL_PERIOD_NS * 1e-9:.2f} x real time" + (f"; {shares}" if shares else "")
        )
    if ceilings:
        print(f"  best ceiling: {best:.0f} round trips/s")
    if args.realtime_seconds > 0:
        print(
            f"real time ({args.realtime_seconds:g} s, nodes on the executor of $MULTIROTOR_ROS_EXECUTOR, "
            f"default events; {load()} at its start):"
        )
        rt = realtime(args.realtime_seconds, args.airframe, logs)
        print(
            f"  {100 * rt['on_time_share']:.2f} % of {rt['periods']:.0f} control periods on time "
            f"({rt['late']:.0f} late); achieved real-time factor {rt['achieved_factor']:.3f}"
        )
        for k, name in enumerate(("simulator", "controller")):
            print(
                f"  {name}: RSS {rt['rss_start'][k]:.1f} MB after warm-up, {rt['rss_end'][k]:.1f} MB after "
                f"{rt['wall_s']:.0f} s ({rt['rss_growth_second_half'][k]:+.1f} MB over the second half, "
                f"trend {rt['rss_slope_mb_per_min'][k]:+.2f} MB/min); "
                f"CPU {100 * rt['cpu_share'][k]:.0f} % of a core"
            )
    print(f"{load()} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
