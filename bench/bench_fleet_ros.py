"""How many vehicles one simulator node keeps in real time, each flown by its own controller process.

    .venv/bin/python bench/bench_fleet_ros.py [--vehicles 1,5,10,15] [--seconds 30]

For each fleet size V: ``multirotor node simulator`` with ``vehicles`` = uav1..uavV (x8_octorotor, 1 kHz
physics, real_time_factor 1, publishing /clock, sensors at their rates) and V ``multirotor node
controller`` processes (use_sim_time, 250 Hz), every vehicle hovering at 1 m. After a start-up settle,
the simulator's own ``pacing`` status over ``--seconds`` of flight gives the achieved real-time factor
and the share of control periods whose command came in time (stamped at the period's start and in force
before its end); the probe gives each vehicle's worst height error. A fleet "keeps real time" when the
achieved factor is >= 0.99, >= 99 % of the periods are on time and every vehicle stays within 5 cm.
Every process runs in a ROS domain of its own choosing (random, localhost only). The load average is
printed with the figures: they are wall-clock numbers.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 200)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

SETTLE_S = 10.0


def pacing_values(message) -> dict[str, float]:  # noqa: ANN001 - diagnostic_msgs/DiagnosticArray
    (status,) = message.status
    return {kv.key: float(kv.value) for kv in status.values}


def fly(vehicles: int, seconds: float, logs: Path) -> dict[str, float]:
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from ros_harness import NodeProcess, RosProbe
    from test_nodes_sim_control import position

    names = [f"uav{k + 1}" for k in range(vehicles)]
    probe = RosProbe()
    odom = {name: probe.subscribe(f"/{name}/odom", Odometry, qos=10) for name in names}
    pacing = probe.subscribe("/pacing", DiagnosticArray)
    simulator = NodeProcess(
        "simulator",
        logs / f"v{vehicles}-simulator.log",
        parameters={
            "real_time_factor": 1.0,
            "publish_clock": True,
            "vehicles": [f"{name} {3.0 * k} 0 1" for k, name in enumerate(names)],
        },
    )
    controllers = [
        NodeProcess(
            "controller",
            logs / f"v{vehicles}-{name}.log",
            namespace=f"/{name}",
            parameters={"use_sim_time": True},
        )
        for name in names
    ]
    try:
        for recorder in odom.values():
            recorder.wait_for(count=1, timeout=180.0)
        pacing.wait_for(lambda m: pacing_values(m)["simulated_time_s"] > SETTLE_S, timeout=300.0)
        start, wall_start = next_status(pacing)
        for recorder in odom.values():
            recorder.clear()
        time.sleep(seconds)
        end, wall_end = next_status(pacing)
        worst = max(abs(position(m)[2] - 1.0) for name in names for m in odom[name].messages)
        periods = (end["control_periods_on_time"] + end["control_periods_late"]) - (
            start["control_periods_on_time"] + start["control_periods_late"]
        )
        on_time = (end["control_periods_on_time"] - start["control_periods_on_time"]) / max(periods, 1.0)
        factor = (end["simulated_time_s"] - start["simulated_time_s"]) / (wall_end - wall_start)
        for process in [simulator, *controllers]:
            process.assert_running()
        return {"achieved": factor, "on_time": on_time, "worst_height_error_m": worst}
    finally:
        for process in [*controllers, simulator]:
            process.stop(check=False)
        probe.close()


def next_status(pacing) -> tuple[dict[str, float], float]:  # noqa: ANN001 - a Recorder
    """The next pacing status to arrive, and the wall time it arrived at."""
    pacing.clear()
    message = pacing.wait_for(count=1, timeout=30.0)[-1]
    return pacing_values(message), time.monotonic()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vehicles", default="1,5,10,15", help="fleet sizes, comma-separated")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured flight per fleet size [s]")
    args = parser.parse_args(argv)
    logs = Path(tempfile.mkdtemp(prefix="bench_fleet_ros_"))
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} CPUs, logs in {logs}")
    print(
        f"{'vehicles':>8} {'achieved RTF':>12} {'on time':>8} {'worst |z - 1|':>14} "
        f"{'keeps real time':>16} {'load':>5}"
    )
    for vehicles in (int(v) for v in args.vehicles.split(",")):
        result = fly(vehicles, args.seconds, logs)
        keeps = (
            result["achieved"] >= 0.99 and result["on_time"] >= 0.99 and result["worst_height_error_m"] < 0.05
        )
        print(
            f"{vehicles:8d} {result['achieved']:12.3f} {100 * result['on_time']:7.1f}% "
            f"{result['worst_height_error_m']:13.3f}m {'yes' if keeps else 'no':>16} "
            f"{os.getloadavg()[0]:5.1f}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
