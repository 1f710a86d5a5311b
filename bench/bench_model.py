"""Physics speed: simulated seconds per wall second at 1 kHz, side by side with RotorPy, in one run.

    .venv/bin/python bench/bench_model.py [--seconds 20] [--batch 10000]

Rows (each on the same machine, in this one process):
- multirotor_ros X8, compiled backend, one `advance` call per simulated second (how a node at
  real_time_factor 0 or an offline run steps it), and one `step` call per 1 ms step (per-call overhead);
- multirotor_ros X8, numpy reference backend (the readable model), one step per call;
- RotorPy (pip `rotorpy`) Multirotor with its Hummingbird parameters, `step` at 1 ms with hover speeds
  (its own scipy solve_ivp integrator, aero on, as its examples use it);
- the same on a trajectory: rotor speeds modulated around hover (0.5 Hz, +-3 %) so that both vehicles
  move, to show the figure does not depend on sitting still;
- a batch of B vehicles (10,000 by default), compiled backend: vehicle-steps per second.
RotorPy's batched vehicle needs PyTorch (a multi-GB install) and is not compared.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model

DT = 1e-3


def modulation(t: float) -> float:
    return 1.0 + 0.03 * np.sin(2 * np.pi * 0.5 * t)


def ours(seconds: float, backend: str, per_step_calls: bool, trajectory: bool) -> float:
    model = Model(load_airframe("x8_octorotor"))
    hover = model.hover_speed_rad_s()
    integrator = Integrator(model, DT, backend=backend)
    x = S.make_state(8, position_m=(0, 0, 10), rotor_speed_rad_s=hover)
    integrator.advance(0.0, x, np.full(8, hover), 2)  # compile / warm up outside the timing
    steps = int(seconds / DT)
    start = time.perf_counter()
    if per_step_calls:
        for k in range(steps):
            u = np.full(8, hover * (modulation(k * DT) if trajectory else 1.0))
            x = integrator.step(k * DT, x, u)
    else:
        chunk = int(0.01 / DT) if trajectory else steps  # trajectory: new command every 10 ms
        for k in range(0, steps, chunk):
            u = np.full(8, hover * (modulation(k * DT) if trajectory else 1.0))
            x = integrator.advance(k * DT, x, u, chunk)
    return seconds / (time.perf_counter() - start)


def rotorpy(seconds: float, trajectory: bool) -> float:
    from rotorpy.vehicles.hummingbird_params import quad_params
    from rotorpy.vehicles.multirotor import Multirotor

    hover = np.sqrt(quad_params["mass"] * 9.81 / (4 * quad_params["k_eta"]))
    state = {"x": np.array([0, 0, 10.0]), "v": np.zeros(3), "q": np.array([0, 0, 0, 1.0]), "w": np.zeros(3),
             "wind": np.zeros(3), "rotor_speeds": np.full(4, hover)}
    vehicle = Multirotor(quad_params, initial_state=state)
    steps = int(seconds / DT)
    start = time.perf_counter()
    for k in range(steps):
        speed = hover * (modulation(k * DT) if trajectory else 1.0)
        state = vehicle.step(state, {"cmd_motor_speeds": np.full(4, speed)}, DT)
    return seconds / (time.perf_counter() - start)


def batch(vehicles: int, steps: int) -> float:
    model = Model(load_airframe("x8_octorotor"))
    hover = model.hover_speed_rad_s()
    integrator = Integrator(model, DT, backend="compiled")
    x = S.make_state(8, batch=vehicles, position_m=(0, 0, 10), rotor_speed_rad_s=hover)
    u = np.full((vehicles, 8), hover) * np.linspace(0.97, 1.03, vehicles)[:, None]
    integrator.advance(0.0, x, u, 2)
    start = time.perf_counter()
    integrator.advance(0.0, x, u, steps)
    return vehicles * steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per fast row")
    parser.add_argument("--batch", type=int, default=10_000, help="vehicles in the batch row")
    args = parser.parse_args()
    slow_seconds = min(args.seconds, 2.0)
    rows = []
    for trajectory in (False, True):
        label = "trajectory" if trajectory else "hover"
        reference = rotorpy(slow_seconds, trajectory)
        rows.append((f"RotorPy Multirotor.step, {label}", reference, reference))
        rows.append((f"ours compiled, advance 1 s chunks, {label}",
                     ours(args.seconds, "compiled", False, trajectory), reference))
        rows.append((f"ours compiled, step per 1 ms call, {label}",
                     ours(args.seconds / 4, "compiled", True, trajectory), reference))
        rows.append((f"ours numpy reference, step per call, {label}",
                     ours(slow_seconds, "numpy", True, trajectory), reference))
    print(f"{'simulated s per wall s at 1 kHz':58s} {'x real time':>12s} {'vs RotorPy':>11s}")
    for name, value, reference in rows:
        print(f"{name:58s} {value:12.1f} {value / reference:10.1f}x")
    steps_per_second = batch(args.batch, 200)
    print(f"batch of {args.batch} X8, compiled: {steps_per_second:.3g} vehicle-steps/s "
          f"({steps_per_second / args.batch * DT:.2f} simulated s per wall s each)")


if __name__ == "__main__":
    main()
