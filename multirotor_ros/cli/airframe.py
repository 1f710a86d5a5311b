"""``multirotor airframe NAME_OR_YAML``: the airframe as JSON (interfaces.md)."""

from __future__ import annotations

import argparse
import json

from multirotor_ros.cli import CommandError

COMMAND = "airframe"
HELP = "print an airframe (config name or YAML path) as JSON: mass, inertia, rotors, allocation, hover speed"


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of the sub-command."""
    parser.add_argument("airframe", help="config name (x8_octorotor, hexarotor_f550, quad_x) or a YAML path")


def airframe_summary(name_or_path: str) -> dict:
    """The JSON document of ``multirotor airframe``."""
    from multirotor_ros.model.airframe import load_airframe
    from multirotor_ros.model.model import Model

    airframe = load_airframe(name_or_path)
    model = Model(airframe)
    return {
        "name": airframe.name,
        "mass_kg": airframe.mass_kg,
        "inertia_kg_m2": airframe.inertia_kg_m2.tolist(),
        "k_f_N_s2": airframe.k_f_N_s2,
        "k_t_N_m_s2": airframe.k_t_N_m_s2,
        "rotors": [
            {
                "number": rotor.number,
                "position_m": list(rotor.position_m),
                "spin": rotor.spin,
                **({"pair": rotor.pair, "level": rotor.level} if rotor.pair is not None else {}),
            }
            for rotor in airframe.rotors
        ],
        "allocation": airframe.allocation.tolist(),
        "allocation_rows": ["thrust_N", "tau_x_N_m", "tau_y_N_m", "tau_z_N_m"],
        "effects": airframe.effect_specs(),
        "hover_speed_rad_s": model.hover_speed_rad_s(),
        "rotor_speed_range_rad_s": [airframe.rotor_speed_min_rad_s, airframe.rotor_speed_max_rad_s],
        "motor_map": airframe.motor_map.describe(),
    }


def run(args: argparse.Namespace) -> int:
    """Print the JSON; user errors become CommandError."""
    from multirotor_ros.model.airframe import AirframeError

    try:
        summary = airframe_summary(args.airframe)
    except (AirframeError, ValueError) as error:
        raise CommandError(str(error)) from error
    print(json.dumps(summary, indent=2))
    return 0
