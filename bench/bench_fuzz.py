"""Hostile input at volume: every node, every input topic, at least 10,000 bad messages each.

    .venv/bin/python bench/bench_fuzz.py [--count 10000] [--rate 1000] [--seed 1] [--nodes controller ...]

Starts each node (simulator, controller, identifier, mavlink_bridge with flight_stack none) as a process
of its own, in a random ROS_DOMAIN_ID on localhost only, floods each of its input topics in turn with the
seeded mix of ``multirotor fuzz`` (the same code: ``multirotor_ros.cli.fuzz.fuzz_node``), and prints the
table: messages, refusals, crash, tracebacks, non-finite outputs, log lines, memory before and after.
The bridge sends its ground-station telemetry to a port this script listens on, so non-finite values in
MAVLink telemetry count as non-finite outputs too. Node output goes to --log-dir (a temporary directory
by default). Exit status 1 if any node crashed, printed a traceback or emitted a non-finite value.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

# Before anything imports rclpy: this run must not hear, or be heard by, other ROS graphs on the machine.
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 200))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

NAMESPACE = "/fuzz"
# (row name, executable, parameters): the identifier reads odom or pose + imu, so it runs once per input.
RUNS = (
    ("simulator", "simulator", {}),
    ("controller", "controller", {}),
    ("identifier", "identifier", {}),
    ("identifier/pose_imu", "identifier", {"input": "pose_imu"}),
    ("mavlink_bridge", "mavlink_bridge", {"flight_stack": "none"}),
)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _start(node: str, parameters: dict[str, Any], log_path: Path) -> subprocess.Popen[bytes]:
    arguments = ["--ros-args", "-r", f"__ns:={NAMESPACE}"]
    for name, value in parameters.items():
        arguments += ["-p", f"{name}:={value}"]
    environment = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
    with open(log_path, "wb") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "multirotor_ros.cli", "node", node, *arguments],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=environment,
        )


def _stop(process: subprocess.Popen[bytes]) -> int | None:
    """SIGINT and wait; the exit status, or None if it had to be killed."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(15.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            return None
    return process.returncode


def main(argv: list[str] | None = None) -> int:
    from multirotor_ros.cli.fuzz import TopicReport, format_table, fuzz_node

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=10_000, help="messages per input topic")
    parser.add_argument("--rate", type=float, default=1000.0, help="messages per second (bursts excepted)")
    parser.add_argument("--seed", type=int, default=1)
    names = [name for name, _, _ in RUNS]
    parser.add_argument("--nodes", nargs="+", choices=names, default=names, help="which rows to run")
    parser.add_argument("--log-dir", type=Path, help="where node output goes (default: a temporary one)")
    args = parser.parse_args(argv)
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="bench_fuzz_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, node output in {log_dir}", flush=True)

    reports: list[TopicReport] = []
    failed: list[str] = []
    exit_notes: list[str] = []
    for name, node, parameters in (run for run in RUNS if run[0] in args.nodes):
        gcs_port = _free_udp_port() if node == "mavlink_bridge" else None
        log_path = log_dir / f"{name.replace('/', '_')}.log"
        process = _start(node, {**parameters, **({"gcs_port": gcs_port} if gcs_port else {})}, log_path)
        started_s = time.monotonic()
        try:
            rows = fuzz_node(
                node,
                namespace=NAMESPACE,
                count=args.count,
                seed=args.seed,
                rate_hz=args.rate,
                pid=process.pid,
                log_path=log_path,
                gcs_port=gcs_port,
                discovery_timeout_s=30.0,
            )
        except Exception as error:  # one node failing to start must not hide the others' rows
            failed.append(name)
            rows = [TopicReport(name, "-", note=f"{type(error).__name__}: {error}")]
        for row in rows:
            row.node = name
        reports += rows
        status = _stop(process)
        exit_notes.append(
            f"{name}: {time.monotonic() - started_s:.0f} s, "
            f"{'killed 15 s after SIGINT' if status is None else f'exit status {status} after SIGINT'}"
        )
        print(f"{name} done", flush=True)

    print()
    print(format_table(reports))
    print()
    print("\n".join(exit_notes))
    return int(bool(failed) or any(r.crashed or r.tracebacks or r.non_finite_outputs for r in reports))


if __name__ == "__main__":
    sys.exit(main())
