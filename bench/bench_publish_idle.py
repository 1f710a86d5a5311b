"""What one publish costs the publisher, against how long the processes were idle before it.

    .venv/bin/python bench/bench_publish_idle.py [--count 1000] [--gaps-ms 0,0.5,4] [--sizes 700,7000]
        [--executors events,single]

A subscriber process (reliable, depth 10, taking the bytes: as the simulator and the fleet controller
take each other's bundles) spins on the executor named (``events``: rclpy's EventsExecutor with
``spin_once`` as nodes/entry.py spins it; ``single``: the SingleThreadedExecutor) and does nothing else;
this process publishes a ``std_msgs/UInt8MultiArray`` of each size ``--count`` times, sleeping the gap
before each one, and times the ``publish`` call alone. Beside it, the same gap before ``sum(range(200))``:
what coming back from idle costs plain Python on this host.

Why: on the 2-vCPU virtual machine this project is measured on, a process that slept a control period
(4 ms) wakes up slow, and a publish that wakes an idle subscriber costs its publisher far more than one
to a subscriber that was just busy. Every control period of the real-time loop pays it twice (the state
one way, the command back), which is what the simulator's run-ahead in real time makes room for
(nodes/simulator.py). Numbers are wall-clock; the load average is printed with them.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import time

os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 200)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
TOPIC = "bench_publish_idle"


def qos():  # noqa: ANN201 - rclpy's QoSProfile, imported late (the child imports rclpy itself)
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def subscriber(executor_name: str) -> None:
    """Child role: take every message and do nothing with it, until killed."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import UInt8MultiArray

    rclpy.init()
    node = rclpy.create_node("bench_publish_idle_subscriber")
    node.create_subscription(UInt8MultiArray, TOPIC, lambda _: None, qos(), raw=True)
    executor = EventsExecutor() if executor_name == "events" else SingleThreadedExecutor()
    executor.add_node(node)
    while True:
        executor.spin_once(timeout_sec=0.1)


def percentiles_us(samples_ns: list[int]) -> tuple[float, float]:
    """The median and the 90th percentile [us]."""
    deciles = statistics.quantiles(samples_ns, n=10)
    return deciles[4] / 1e3, deciles[8] / 1e3


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--gaps-ms", default="0,0.5,4")
    parser.add_argument("--sizes", default="700,7000")
    parser.add_argument("--executors", default="events,single")
    parser.add_argument("--subscriber", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        subscriber(args.subscriber)
        return 0

    import rclpy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import UInt8MultiArray

    gaps_s = [float(g) / 1e3 for g in args.gaps_ms.split(",")]
    sizes = [int(s) for s in args.sizes.split(",")]
    rclpy.init()
    node = rclpy.create_node("bench_publish_idle")
    publisher = node.create_publisher(UInt8MultiArray, TOPIC, qos())
    domain, load = os.environ["ROS_DOMAIN_ID"], os.getloadavg()[0]
    print(f"ROS_DOMAIN_ID={domain}, {os.cpu_count()} CPUs, load {load:.1f}")
    print(f"{'subscriber':>10} {'gap':>7} {'bytes':>6} {'publish p50':>12} {'p90':>8} {'sum() p50':>10}")
    for executor_name in args.executors.split(","):
        child = subprocess.Popen(
            [sys.executable, __file__, "--subscriber", executor_name], start_new_session=True
        )
        try:
            deadline = time.monotonic() + 30.0
            while publisher.get_subscription_count() == 0:
                if time.monotonic() > deadline:
                    raise RuntimeError("the subscriber process was not discovered within 30 s")
                time.sleep(0.05)
            time.sleep(1.0)  # the reliable reader matched both ways
            for gap_s in gaps_s:
                for size in sizes:
                    data = serialize_message(UInt8MultiArray(data=bytes(size)))
                    publish_ns, python_ns = [], []
                    for _ in range(args.count):
                        time.sleep(gap_s)
                        start = time.perf_counter_ns()
                        publisher.publish(data)
                        publish_ns.append(time.perf_counter_ns() - start)
                        time.sleep(gap_s)
                        start = time.perf_counter_ns()
                        sum(range(200))
                        python_ns.append(time.perf_counter_ns() - start)
                    p50, p90 = percentiles_us(publish_ns)
                    print(
                        f"{executor_name:>10} {gap_s * 1e3:>5g}ms {size:>6} {p50:>10.1f}us {p90:>6.1f}us "
                        f"{percentiles_us(python_ns)[0]:>8.1f}us",
                        flush=True,
                    )
        finally:
            os.killpg(child.pid, signal.SIGKILL)  # the wheels' re-executed interpreter is its child
            child.wait()
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
