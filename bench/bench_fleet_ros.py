"""How many vehicles one simulator node keeps in real time, each flown by its own controller process.

    .venv/bin/python bench/bench_fleet_ros.py [--vehicles 1,5,10,15] [--seconds 30]
        [--controllers composed,separate] [--rate-hz 250]

For each fleet size V: ``multirotor node simulator`` with ``vehicles`` = uav1..uavV (x8_octorotor, 1 kHz
physics, real_time_factor 1, publishing /clock and odometry at the control rate, other sensors at their
rates) and a controller per vehicle (use_sim_time, ``--rate-hz``), every vehicle hovering at 1 m: V
``multirotor node controller`` processes (``separate``) or one ``multirotor node fleet_controller``
process holding the V controller nodes (``composed``), each way in turn for each V. After a start-up settle,
the simulator's own ``pacing`` status over ``--seconds`` of flight gives the achieved real-time factor
and the share of control periods whose command came in time (stamped at the period's start and in force
before its end); after it, the probe looks at 100 odometry messages of each vehicle (not during it: its
own Python would take CPU from the nodes measured). A fleet "keeps real time" when the achieved factor is
>= 0.99, >= 99 % of the periods are on time and every vehicle is then within 5 cm of its height.
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


def fly(vehicles: int, seconds: float, logs: Path, composed: bool, rate_hz: float) -> dict[str, float]:
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from ros_harness import NodeProcess, RosProbe
    from test_nodes_sim_control import position

    names = [f"uav{k + 1}" for k in range(vehicles)]
    probe = RosProbe()
    pacing = probe.subscribe("/pacing", DiagnosticArray)
    way = "composed" if composed else "separate"
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
                parameters={"use_sim_time": True, "rate_hz": rate_hz, "vehicles": names},
            )
        ]
        if composed
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
        time.sleep(seconds)
        end, wall_end = next_status(pacing)
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
        return {"achieved": factor, "on_time": on_time, "height_error_after_m": worst}
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
    parser.add_argument(
        "--controllers", default="composed,separate", help="composed (one process), separate (one each)"
    )
    parser.add_argument("--rate-hz", type=float, default=250.0, help="control (and odometry) rate [Hz]")
    args = parser.parse_args(argv)
    logs = Path(tempfile.mkdtemp(prefix="bench_fleet_ros_"))
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} CPUs, logs in {logs}")
    print(f"control rate {args.rate_hz:g} Hz")
    print(
        f"{'vehicles':>8} {'controllers':>11} {'achieved RTF':>12} {'on time':>8} {'|z - 1| after':>14} "
        f"{'keeps real time':>16} {'load':>5}"
    )
    ways = args.controllers.split(",")
    if not set(ways) <= {"composed", "separate"}:
        parser.error(f"--controllers: composed and/or separate, got {args.controllers!r}")
    for vehicles, way in ((int(v), way) for v in args.vehicles.split(",") for way in ways):
        result = fly(vehicles, args.seconds, logs, way == "composed", args.rate_hz)
        keeps = (
            result["achieved"] >= 0.99 and result["on_time"] >= 0.99 and result["height_error_after_m"] < 0.05
        )
        print(
            f"{vehicles:8d} {way:>11} {result['achieved']:12.3f} {100 * result['on_time']:7.1f}% "
            f"{result['height_error_after_m']:13.3f}m {'yes' if keeps else 'no':>16} "
            f"{os.getloadavg()[0]:5.1f}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
