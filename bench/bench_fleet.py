"""Fleet simulation speed: V vehicles in one batched simulator against V separate simulators.

    .venv/bin/python bench/bench_fleet.py [--seconds 5] [--vehicles 1,2,5,10,20,50]

What the simulator node does per vehicle, without ROS: x8_octorotor (its YAML's effects, motor lag,
its sensors: odometry 250 Hz, IMU, motion capture and ESC speeds 100 Hz, range 15 Hz), 1 kHz physics,
and every vehicle gets a new command each 4 ms (a 250 Hz controller: hover speed modulated by +-2 % at
0.5 Hz, a phase per vehicle, so that the vehicles move) through ``set_command(speeds, vehicle=k)``,
then ``run_until`` the next control period; every reading is generated and counted.

Rows per fleet size V:
- fleet: one :class:`VehicleSimulator` with V lanes (one integrator call per physics chunk for all);
- separate: V single-vehicle simulators stepped one after the other in a Python loop (the best one can
  do without the fleet), with the same generators, so the same readings;
- ratio: fleet over separate.
Figures are simulated seconds per second of the whole fleet (1.0 = all V vehicles in real time), on
wall time and on the CPU time of this thread (what the machine's other jobs do not take away). The load
average is printed before and after: the machine is shared.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.simulation.vehicle import NS_PER_S, VehicleSimulator, vehicle_generators

CONTROL_PERIOD_NS = 4_000_000  # 250 Hz, the controller's rate
SEED = 1


def positions(count: int) -> np.ndarray:
    """A grid 3 m apart, 2 m up: every vehicle starts in the air at hover."""
    side = int(np.ceil(np.sqrt(count)))
    return np.array([(3.0 * (k % side), 3.0 * (k // side), 2.0) for k in range(count)])


def commands(hover: float, count: int, n_rotors: int, t_ns: int) -> np.ndarray:
    """(V, N) the commands of one control period: hover +-2 % at 0.5 Hz, a phase per vehicle."""
    phase = 2 * np.pi * 0.5 * t_ns / NS_PER_S + np.arange(count)
    return np.repeat((hover * (1.0 + 0.02 * np.sin(phase)))[:, None], n_rotors, axis=1)


def timed(run: Callable[[], int]) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds of this thread, what ``run`` returned)."""
    wall, cpu = time.perf_counter(), time.thread_time()
    result = run()
    return time.perf_counter() - wall, time.thread_time() - cpu, result


def fleet_run(airframe, count: int, seconds: float) -> tuple[float, float, int]:
    sim = VehicleSimulator(airframe, rng=vehicle_generators(SEED, count), initial_position_m=positions(count))
    end_ns = round(seconds * NS_PER_S)
    n = airframe.n_rotors

    def run() -> int:
        readings = len(sim.run_until(0))
        for t_ns in range(CONTROL_PERIOD_NS, end_ns + 1, CONTROL_PERIOD_NS):
            speeds = commands(sim.hover_speed_rad_s, count, n, sim.t_ns)
            for k in range(count):
                sim.set_command(speeds[k], vehicle=k)
            readings += len(sim.run_until(t_ns))
        return readings

    return timed(run)


def separate_run(airframe, count: int, seconds: float) -> tuple[float, float, int]:
    sims = [
        VehicleSimulator(airframe, rng=rng, initial_position_m=position)
        for rng, position in zip(vehicle_generators(SEED, count), positions(count), strict=True)
    ]
    end_ns = round(seconds * NS_PER_S)
    n = airframe.n_rotors

    def run() -> int:
        readings = sum(len(sim.run_until(0)) for sim in sims)
        for t_ns in range(CONTROL_PERIOD_NS, end_ns + 1, CONTROL_PERIOD_NS):
            speeds = commands(sims[0].hover_speed_rad_s, count, n, sims[0].t_ns)
            for k, sim in enumerate(sims):
                sim.set_command(speeds[k])
                readings += len(sim.run_until(t_ns))
        return readings

    return timed(run)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per measurement")
    parser.add_argument("--vehicles", default="1,2,5,10,20,50", help="fleet sizes, comma-separated")
    parser.add_argument("--airframe", default="x8_octorotor")
    args = parser.parse_args()
    sizes = [int(v) for v in args.vehicles.split(",")]
    airframe = load_airframe(args.airframe)
    fleet_run(airframe, 2, 0.05)  # load the kernels (integrator, sensors) outside the timing
    separate_run(airframe, 1, 0.05)

    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; {airframe.name}, 1 kHz physics, "
        f"commands at 250 Hz per vehicle, {args.seconds:g} simulated s per row"
    )
    print("simulated s per s of the whole fleet (1.0 = every vehicle in real time); wall (CPU)")
    print(f"{'V':>4} {'fleet':>17} {'separate':>17} {'ratio':>13} {'readings/sim s':>15}")
    for count in sizes:
        wall_f, cpu_f, readings_f = fleet_run(airframe, count, args.seconds)
        wall_s, cpu_s, readings_s = separate_run(airframe, count, args.seconds)
        assert readings_f == readings_s, (readings_f, readings_s)
        s = args.seconds
        print(
            f"{count:4d} {s / wall_f:8.1f} ({s / cpu_f:6.1f}) {s / wall_s:8.1f} ({s / cpu_s:6.1f}) "
            f"{wall_s / wall_f:5.1f} ({cpu_s / cpu_f:5.1f}) {readings_f / s:15.0f}"
        )
    print(f"load average {os.getloadavg()[0]:.1f} after")


if __name__ == "__main__":
    main()
