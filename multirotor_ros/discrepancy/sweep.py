"""The hidden-effect sweep (issue 5): each translational effect the workflow fits, hidden from the baseline.

Each effect at two strengths and two noise levels on the X8 and the hexarotor (coaxial_loss on the X8 only:
the hexarotor has no coaxial rotors), plus one flight per airframe and noise level with nothing hidden.
:func:`hidden_effect_flight` flies the closed loop along the excitation schedule with the effect in the
true vehicle; :func:`find_discrepancy` with baseline ``none`` must name it, recover its parameters within
:data:`PARAMETER_TOLERANCE` and cut the gap (:func:`judge`). ``multirotor campaign sweep`` runs it on Dask,
test/test_discrepancy_sweep.py holds it to these criteria.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from multirotor_ros.discrepancy.workflow import DiscrepancyReport
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.rotation import FloatArray

AIRFRAMES = ("x8_octorotor", "hexarotor_f550")
NOISE_LEVELS = ("low", "high")
NOISE_HIGH = 4.0  # "high": every white noise of the airframe's sensors times this (not the biases)
PHYSICS_RATE_HZ = 500.0
FLIGHT_S = 30.0
NOTHING_HIDDEN_SEED = 7
PARAMETER_TOLERANCE = 0.15  # relative, for the continuous parameters
FAULT_ONSET_TOLERANCE_S = 0.25
# The gap after / before must fall below this; at the high noise level the noise floor is most of what is
# left, so the gap shrinks, but not by half.
GAP_RATIO_LIMIT = {"low": 0.5, "high": 0.9}

STRENGTHS: dict[str, tuple[dict[str, float], dict[str, float]]] = {
    "quadratic_drag": ({"c_x": 0.15, "c_y": 0.15, "c_z": 0.1}, {"c_x": 0.4, "c_y": 0.4, "c_z": 0.2}),
    "rotor_drag": ({"k_h": 7e-5}, {"k_h": 2e-4}),
    "thrust_speed_dependence": ({"k_f1": 2e-9}, {"k_f1": 5e-9}),
    "coaxial_loss": ({"eta_lower": 0.9}, {"eta_lower": 0.75}),
    "ground_effect": ({"rotor_radius_m": 0.1}, {"rotor_radius_m": 0.127}),
    "inflow_thrust_loss": ({"k_v": 2e-4}, {"k_v": 5e-4}),
    "motor_lag": ({"tau_s": 0.02}, {"tau_s": 0.05}),
    "mass_offset": ({"dm_kg": 0.05}, {"dm_kg": 0.15}),
    "constant_force": ({"f_x": 0.3, "f_y": -0.2, "f_z": 0.3}, {"f_x": 0.5, "f_y": -0.3, "f_z": 0.5}),
    "actuator_fault": (
        {"motor": 3, "effectiveness": 0.8, "t_fault_s": 15.0},
        {"motor": 5, "effectiveness": 0.6, "t_fault_s": 22.0},
    ),
}


def sweep_cases() -> list[dict[str, Any]]:
    """Every case of the sweep as a JSON description: airframe, effect (``none``), parameters, noise, seed."""
    cases = [
        {
            "airframe": airframe,
            "effect": effect_id,
            "strength": strength,
            "parameters": STRENGTHS[effect_id][strength],
            "noise": noise,
            "seed": strength + 1,
        }
        for airframe in AIRFRAMES
        for effect_id in STRENGTHS
        for strength in (0, 1)
        for noise in NOISE_LEVELS
        if not (effect_id == "coaxial_loss" and airframe != "x8_octorotor")
    ]
    cases += [
        {
            "airframe": airframe,
            "effect": "none",
            "strength": 0,
            "parameters": {},
            "noise": noise,
            "seed": NOTHING_HIDDEN_SEED,
        }
        for airframe in AIRFRAMES
        for noise in NOISE_LEVELS
    ]
    return cases


def case_name(case: Mapping[str, Any]) -> str:
    """``x8-rotor_drag-s1-high``: the airframe's first word, the effect, the strength, the noise."""
    return f"{case['airframe'].split('_')[0]}-{case['effect']}-s{case['strength']}-{case['noise']}"


def airframe_with_noise(name: str, noise: str) -> Airframe:
    """The airframe with its sensors' white noise as the level says (``none`` is handled by the flight)."""
    from multirotor_ros.simulation.sensors import airframe_sensor_config

    airframe = load_airframe(name)
    if noise != "high":
        return airframe
    config = airframe_sensor_config(airframe).as_dict()
    louder = {k: v * NOISE_HIGH for k, v in config.items() if "noise" in k}
    return dataclasses.replace(airframe, sections={**airframe.sections, "sensors": {**config, **louder}})


def hidden_effect_flight(
    airframe: str,
    effects: list[dict[str, Any]] | None,
    duration_s: float = FLIGHT_S,
    seed: int = 1,
    noise: str = "low",
    setpoints: FloatArray | None = None,
) -> FlightLog:
    """The log of a closed-loop flight with true ``effects`` (None: the airframe's own) and ``noise``.

    Along the excitation schedule jittered by ``seed`` unless ``setpoints`` are given; the sensor
    noise's generator is seeded by 1000 + ``seed``.
    """
    from multirotor_ros.ident.excitation import excitation_setpoints
    from multirotor_ros.simulation.flight import simulate_flight

    schedule = (
        setpoints if setpoints is not None else excitation_setpoints(duration_s, np.random.default_rng(seed))
    )
    return simulate_flight(
        airframe_with_noise(airframe, noise),
        effects,
        setpoints=schedule,
        duration_s=duration_s,
        rng=np.random.default_rng(1000 + seed),
        physics_rate_hz=PHYSICS_RATE_HZ,
        noise=noise != "none",
    )


def run_sweep_case(case: Mapping[str, Any]) -> DiscrepancyReport:
    """Fly the case's flight and run the discrepancy workflow on it with baseline ``none``."""
    from multirotor_ros.discrepancy.workflow import find_discrepancy

    hidden = [] if case["effect"] == "none" else [{"id": case["effect"], **case["parameters"]}]
    log = hidden_effect_flight(case["airframe"], hidden, seed=int(case["seed"]), noise=case["noise"])
    return find_discrepancy(case["airframe"], log, [])


def parameter_errors(case: Mapping[str, Any], report: DiscrepancyReport) -> dict[str, float]:
    """Per true parameter: relative error of the fitted value (the rotor and the onset: absolute)."""
    errors = {}
    for name, truth in case["parameters"].items():
        fitted = report.parameters.get(name, float("nan"))
        errors[name] = fitted - truth if name in ("motor", "t_fault_s") else (fitted - truth) / truth
    return errors


def judge(case: Mapping[str, Any], report: DiscrepancyReport) -> list[str]:
    """What the report gets wrong about the case (empty: the case passes)."""
    problems = []
    if report.missing_effect != case["effect"]:
        problems.append(f"named {report.missing_effect!r} instead of {case['effect']!r}")
        return problems
    for name, error in parameter_errors(case, report).items():
        limit = {"motor": 0.0, "t_fault_s": FAULT_ONSET_TOLERANCE_S}.get(name, PARAMETER_TOLERANCE)
        if not abs(error) <= limit:
            problems.append(f"{name} off by {error:+.3g} (limit {limit:g})")
    if case["effect"] != "none":
        ratio = gap_ratio(report)
        if not ratio < GAP_RATIO_LIMIT[case["noise"]]:
            problems.append(f"gap after/before {ratio:.2f} (limit {GAP_RATIO_LIMIT[case['noise']]:g})")
    return problems


def gap_ratio(report: DiscrepancyReport) -> float:
    """Acceleration mse summed over the axes, after over before."""
    return sum(report.mse_after.values()) / sum(report.mse_before.values())
