"""Physics speed: simulated seconds per wall second at 1 kHz, side by side with RotorPy, in one run.

    .venv/bin/python bench/bench_model.py [--seconds 20] [--batch 10000] [--batch-steps 200]

Targets (the issue): one X8 at least 1,000x real time, a batch at least 10^7 vehicle-steps per second
on the 2-core reference machine.

Rows (each on the same machine, in this one process):
- multirotor_ros X8, compiled backend, one `advance` call per simulated second (how a node at
  real_time_factor 0 or an offline run steps it), and one `step` call per 1 ms step (per-call overhead);
- multirotor_ros X8, numpy reference backend (the readable model), one step per call;
- RotorPy (pip `rotorpy`, not a dependency of this package) Multirotor with its Hummingbird parameters,
  `step` at 1 ms with hover speeds (its own scipy solve_ivp integrator, aero on, as its examples use it);
- the same on a trajectory: rotor speeds modulated around hover (0.5 Hz, +-3 %) so that both vehicles
  move, to show the figure does not depend on sitting still;
- a batch of B X8 (10,000 by default), compiled backend, all threads: vehicle-steps per second.
RotorPy's batched vehicle needs PyTorch (a multi-GB install) and is not compared.

Wall-clock figures suffer when other programs share the machine, so every row also gives a CPU-time
figure: the CPU time of the timed thread for one-vehicle rows, and the process CPU time divided by the
number of compiled-kernel threads for the batch (what the kernel would do with the cores to itself).
The load average printed first tells how busy the machine was.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model

DT = 1e-3


def modulation(t: float) -> float:
    return 1.0 + 0.03 * np.sin(2 * np.pi * 0.5 * t)


def timed(run: Callable[[], None]) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this thread) spent in ``run``."""
    wall, cpu = time.perf_counter(), time.thread_time()
    run()
    return time.perf_counter() - wall, time.thread_time() - cpu


def ours(seconds: float, backend: str, per_step_calls: bool, trajectory: bool) -> tuple[float, float]:
    """(wall, CPU) simulated seconds per second for one X8."""
    model = Model(load_airframe("x8_octorotor"))
    hover = model.hover_speed_rad_s()
    integrator = Integrator(model, DT, backend=backend)
    x = S.make_state(8, position_m=(0, 0, 10), rotor_speed_rad_s=hover)
    integrator.advance(0.0, x, np.full(8, hover), 2)  # compile / warm up outside the timing
    steps = int(seconds / DT)

    def run() -> None:
        state = x
        if per_step_calls:
            for k in range(steps):
                u = np.full(8, hover * (modulation(k * DT) if trajectory else 1.0))
                state = integrator.step(k * DT, state, u)
        else:
            chunk = int(0.01 / DT) if trajectory else int(1.0 / DT)  # trajectory: new command every 10 ms
            for k in range(0, steps, chunk):
                u = np.full(8, hover * (modulation(k * DT) if trajectory else 1.0))
                state = integrator.advance(k * DT, state, u, min(chunk, steps - k))

    wall, cpu = timed(run)
    return seconds / wall, seconds / cpu


def rotorpy(seconds: float, trajectory: bool, step_s: float = DT) -> tuple[float, float] | None:
    """(wall, CPU) simulated seconds per second of RotorPy's Multirotor; None if it is not installed."""
    try:
        from rotorpy.vehicles.hummingbird_params import quad_params
        from rotorpy.vehicles.multirotor import Multirotor
    except ImportError:
        return None
    hover = np.sqrt(quad_params["mass"] * 9.81 / (4 * quad_params["k_eta"]))
    start = {
        "x": np.array([0, 0, 10.0]),
        "v": np.zeros(3),
        "q": np.array([0, 0, 0, 1.0]),
        "w": np.zeros(3),
        "wind": np.zeros(3),
        "rotor_speeds": np.full(4, hover),
    }
    vehicle = Multirotor(quad_params, initial_state=start)
    steps = int(seconds / step_s)

    def run() -> None:
        state = start
        for k in range(steps):
            speed = hover * (modulation(k * step_s) if trajectory else 1.0)
            state = vehicle.step(state, {"cmd_motor_speeds": np.full(4, speed)}, step_s)

    wall, cpu = timed(run)
    return seconds / wall, seconds / cpu


def batch(vehicles: int, steps: int) -> tuple[float, float, int]:
    """(wall, CPU-normalised) vehicle-steps per second for a batch of X8, and the kernel's thread count."""
    import numba

    model = Model(load_airframe("x8_octorotor"))
    hover = model.hover_speed_rad_s()
    integrator = Integrator(model, DT, backend="compiled")
    x = S.make_state(8, batch=vehicles, position_m=(0, 0, 10), rotor_speed_rad_s=hover)
    u = np.full((vehicles, 8), hover) * np.linspace(0.97, 1.03, vehicles)[:, None]
    integrator.advance(0.0, x, u, 2)
    threads = numba.get_num_threads()
    wall, cpu = time.perf_counter(), time.process_time()
    integrator.advance(0.0, x, u, steps)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return vehicles * steps / wall, vehicles * steps / (cpu / threads), threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per fast row")
    parser.add_argument("--batch", type=int, default=10_000, help="vehicles in the batch row")
    parser.add_argument("--batch-steps", type=int, default=200, help="1 ms steps of the batch row")
    args = parser.parse_args()
    slow_seconds = min(args.seconds, 2.0)
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs "
        "(wall figures drop when other programs run; CPU figures much less)"
    )
    rows: list[tuple[str, tuple[float, float] | None]] = []
    for trajectory in (False, True):
        label = "trajectory" if trajectory else "hover"
        rows.append((f"RotorPy Multirotor.step, {label}", rotorpy(slow_seconds, trajectory)))
        # Its examples step at 100 Hz, where its adaptive RK45 needs far fewer evaluations per second.
        rows.append(
            (f"RotorPy at its examples' 10 ms step, {label}", rotorpy(slow_seconds * 5, trajectory, 0.01))
        )
        chunks = "10 ms" if trajectory else "1 s"
        rows.append(
            (
                f"ours compiled, advance {chunks} chunks, {label}",
                ours(args.seconds, "compiled", False, trajectory),
            )
        )
        rows.append(
            (
                f"ours compiled, step per 1 ms call, {label}",
                ours(args.seconds / 4, "compiled", True, trajectory),
            )
        )
        rows.append(
            (f"ours numpy reference, step per call, {label}", ours(slow_seconds, "numpy", True, trajectory))
        )
    print(
        f"{'one vehicle, simulated s per s at 1 kHz':50s} {'x real time':>12s} {'(CPU time)':>11s} "
        f"{'vs RotorPy':>11s}"
    )
    reference: tuple[float, float] | None = None
    for name, value in rows:
        if name.startswith("RotorPy Multirotor.step"):
            reference = value
        if value is None:
            print(f"{name:50s} not measured: rotorpy is not installed (pip install rotorpy)")
            continue
        versus = f"{value[1] / reference[1]:10.1f}x" if reference else f"{'-':>11s}"
        print(f"{name:50s} {value[0]:12.1f} {value[1]:11.1f} {versus}")
    wall, cpu, threads = batch(args.batch, args.batch_steps)
    print(
        f"batch of {args.batch} X8, compiled, {threads} threads: {wall:.3g} vehicle-steps/s wall, "
        f"{cpu:.3g} per {threads} busy threads' CPU time "
        f"({cpu / args.batch * DT:.2f} simulated s per s each)"
    )


if __name__ == "__main__":
    main()
