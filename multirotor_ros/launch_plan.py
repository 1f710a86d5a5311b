"""What the launch files start, computed without ``launch``: nodes, namespaces and parameters.

Each file in ``launch/`` is a :class:`LaunchFile` of this module (``LAUNCH_FILES``): its arguments, with
defaults and descriptions, and a plan, the function that turns the arguments' values (strings, as
``ros2 launch`` gives them) into :class:`NodePlan` rows: package, executable, namespace, parameters and
command-line arguments of each process. ``multirotor_ros/launch_actions.py`` makes launch_ros ``Node``
actions of the rows in an ``OpaqueFunction``, so the launch files hold nothing to get wrong.

Why this split: ``launch`` and ``launch_ros`` exist only in a ROS 2 install (built by colcon or from
apt); PyPI has neither (its ``launch`` 0.1.3 is an unrelated 2017 package) nor does Debian, and the
machines that run the test suite reach only those two. The plans are tested here
(test/test_launch_plan.py), and the processes a plan describes are started as real processes with the
same executables and parameters and fly over real DDS (test/test_mission.py); the launch files
themselves are compiled always and loaded with the real ``launch`` where it is importable.

No remappings: every topic name of the package is relative, so a node's namespace is all that places
it. Each vehicle's frames are prefixed with its namespace (``uav1/odom``, ``uav1/base_link``) so that
two vehicles' frames do not collide; the mission's ``frame_id`` is that vehicle's ``odom`` frame,
which the controller requires of a setpoint.

A bad argument is a :class:`LaunchArgumentError` naming the argument, raised before any process starts:
the airframe is loaded, the fault's rotor checked against it, and the mission file read with the
parser of ``multirotor simulate --setpoints`` (the error names the file and line).
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from multirotor_ros.control.mission import read_mission
from multirotor_ros.model.airframe import AirframeError, load_airframe
from multirotor_ros.nodes.vehicles import MAX_VEHICLES, parse_vehicles
from multirotor_ros.resources import PACKAGE_NAME, config_directory
from multirotor_ros.rviz_config import namespaced_rviz_config

ParameterValue = bool | int | float | str | list[str]
# A namespace segment, as ROS accepts it.
_NAMESPACE_TOKEN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
NO_MISSION = "none"
FLIGHT_STACKS = ("px4", "ardupilot")
RVIZ_CONFIG = Path("rviz") / "multirotor.rviz"


class LaunchArgumentError(ValueError):
    """A launch argument whose value cannot be used; the message names it."""


@dataclass(frozen=True)
class LaunchArgument:
    """One ``name:=value`` of a launch file: its default (a string, as on the command line) and meaning."""

    name: str
    default: str
    description: str


@dataclass(frozen=True)
class NodePlan:
    """One process: ``ros2 run PACKAGE EXECUTABLE ARGUMENTS --ros-args -r __ns:=NAMESPACE -p ...``.

    The node keeps its own name, which is its executable's (one node per executable and namespace).
    """

    executable: str
    namespace: str  # absolute: "/" or "/uav1"
    parameters: dict[str, ParameterValue]
    package: str = PACKAGE_NAME
    arguments: tuple[str, ...] = ()


Plan = Callable[[Mapping[str, str]], list[NodePlan]]


@dataclass(frozen=True)
class LaunchFile:
    """A launch file's arguments and the plan its ``OpaqueFunction`` runs."""

    arguments: tuple[LaunchArgument, ...]
    plan: Plan = field(repr=False)

    def nodes(self, given: Mapping[str, str] | None = None) -> list[NodePlan]:
        """The processes for these argument values (the defaults for those not given)."""
        names = [argument.name for argument in self.arguments]
        unknown = sorted(set(given or {}) - set(names))
        if unknown:
            raise LaunchArgumentError(
                f"unknown launch argument {', '.join(unknown)}; known: {', '.join(names)}"
            )
        return self.plan({a.name: (given or {}).get(a.name, a.default) for a in self.arguments})

    def with_defaults(self, **defaults: str) -> LaunchFile:
        """The same launch file with other defaults for some arguments."""
        unknown = set(defaults) - {a.name for a in self.arguments}
        if unknown:
            raise ValueError(f"no argument {', '.join(sorted(unknown))} to give a default")
        return replace(
            self,
            arguments=tuple(replace(a, default=defaults.get(a.name, a.default)) for a in self.arguments),
        )


# ---------------------------------------------------------------------------------------------- arguments

AIRFRAME = LaunchArgument("airframe", "x8_octorotor", "airframe config name (config/*.yaml) or YAML path")
NAMESPACE = LaunchArgument(
    "namespace", "", "namespace of the vehicle's nodes (e.g. uav1); its frames get the prefix uav1/"
)
MISSION = LaunchArgument(
    "mission",
    "square",
    "mission CSV (t,x,y,z,yaw; config/missions/NAME.csv or a path) flown from the start; none = no mission",
)
EFFECTS = LaunchArgument(
    "effects",
    "",
    "effects the identifier fits, comma-separated ids of effects.md; '' = the airframe's own fittable "
    "effects, none = the thrust constant only",
)
IDENTIFIER = LaunchArgument("identifier", "true", "start the identifier (online identification, diagnosis)")
NOISE = LaunchArgument("noise", "true", "sensor noise and biases (false: the sensors read the truth)")
FAULT_MOTOR = LaunchArgument(
    "fault_motor", "0", "rotor (1..N) given fault_effectiveness from the start; 0 = none"
)
FAULT_EFFECTIVENESS = LaunchArgument(
    "fault_effectiveness", "0.0", "share of its thrust the faulty rotor gives, 0..1 (0 = it stops)"
)
REAL_TIME_FACTOR = LaunchArgument(
    "real_time_factor",
    "0.0",
    "time mode: 0 = lockstep (simulated time waits for each control period's command: the same flight "
    "on any machine); r > 0 = r x wall time. Every node runs on the simulator's /clock either way",
)
VISUALIZER = LaunchArgument("visualizer", "true", "start the visualizer (markers and frames for RViz)")
RVIZ = LaunchArgument("rviz", "false", "start rviz2 with share/multirotor_ros/rviz/multirotor.rviz")
VEHICLES = LaunchArgument("vehicles", "2", f"number of vehicles, uav1..uavN (1..{MAX_VEHICLES})")
SPACING = LaunchArgument(
    "spacing", "4.0", "distance between neighbouring vehicles on the ground, in a row along x [m]"
)
FAULT_VEHICLE = LaunchArgument("fault_vehicle", "uav1", "the vehicle whose rotor fault_motor is")
FLEET_NAMESPACE = LaunchArgument(
    "namespace", "", "namespace above the vehicles' (e.g. team: /team/uav1/odom, frames team/uav1/odom)"
)
FLIGHT_STACK = LaunchArgument("flight_stack", "px4", "px4 (TCP 4560) or ardupilot (JSON, UDP 9002)")
FLIGHT_STACK_PORT = LaunchArgument("flight_stack_port", "0", "flight-stack port; 0 = 4560 (px4) or 9002")
GCS_PORT = LaunchArgument("gcs_port", "14550", "UDP port of the ground station on 127.0.0.1")


# ---------------------------------------------------------------------------------------------- values


def _flag(values: Mapping[str, str], name: str) -> bool:
    text = values[name].strip().lower()
    if text in ("true", "1"):
        return True
    if text in ("false", "0"):
        return False
    raise LaunchArgumentError(f"launch argument {name}: expected true or false, got {values[name]!r}")


def _number(values: Mapping[str, str], name: str, low: float, high: float) -> float:
    try:
        number = float(values[name])
    except ValueError:
        raise LaunchArgumentError(f"launch argument {name}: not a number: {values[name]!r}") from None
    if not (math.isfinite(number) and low <= number <= high):
        raise LaunchArgumentError(
            f"launch argument {name}: must be within {low:g}..{high:g}, got {values[name]}"
        )
    return number


def _integer(values: Mapping[str, str], name: str, low: int, high: int) -> int:
    try:
        number = int(values[name])
    except ValueError:
        raise LaunchArgumentError(f"launch argument {name}: not an integer: {values[name]!r}") from None
    if not low <= number <= high:
        raise LaunchArgumentError(f"launch argument {name}: must be within {low}..{high}, got {number}")
    return number


def namespace_path(text: str) -> str:
    """``uav1``, ``/uav1`` or ``/team/uav1/`` -> the absolute namespace (``/`` for none)."""
    segments = [s for s in text.strip().split("/") if s]
    bad = [s for s in segments if not _NAMESPACE_TOKEN.fullmatch(s)]
    if bad:
        raise LaunchArgumentError(
            f"launch argument namespace {text!r}: {bad[0]!r} is not a ROS name "
            "(a letter, then letters, digits or _)"
        )
    return "/" + "/".join(segments)


def frame_prefix(namespace: str) -> str:
    """The frame-id prefix of a namespace: ``/team/uav1`` -> ``team/uav1/``, ``/`` -> ''."""
    inner = namespace.strip("/")
    return f"{inner}/" if inner else ""


def _joined(namespace: str, name: str) -> str:
    return namespace.rstrip("/") + "/" + name


def mission_path(text: str) -> Path | None:
    """A mission argument -> its file: a name of config/missions, a path, or None for ``none``."""
    if text.strip() in ("", NO_MISSION):
        return None
    candidate = Path(text).expanduser()
    if candidate.suffix or "/" in text:
        if not candidate.is_file():
            raise LaunchArgumentError(f"launch argument mission: no such file {text!r}")
        return candidate.resolve()
    directory = config_directory() / "missions"
    path = directory / f"{text}.csv"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in directory.glob("*.csv"))) or "none shipped"
        raise LaunchArgumentError(
            f"launch argument mission: unknown mission {text!r}; known: {known} (or give a CSV path)"
        )
    return path


@dataclass(frozen=True)
class _Common:
    """The arguments every vehicle plan shares, checked."""

    airframe: str
    n_rotors: int
    effects: str
    identifier: bool
    noise: bool
    fault_motor: int
    fault_effectiveness: float
    visualizer: bool
    rviz: bool


def _common(values: Mapping[str, str]) -> _Common:
    try:
        n_rotors = load_airframe(values["airframe"]).n_rotors
    except (AirframeError, FileNotFoundError) as error:
        raise LaunchArgumentError(f"launch argument airframe: {error}") from None
    return _Common(
        airframe=values["airframe"],
        n_rotors=n_rotors,
        effects=values["effects"].strip(),
        identifier=_flag(values, "identifier"),
        noise=_flag(values, "noise"),
        fault_motor=_integer(values, "fault_motor", 0, n_rotors),
        fault_effectiveness=_number(values, "fault_effectiveness", 0.0, 1.0),
        visualizer=_flag(values, "visualizer"),
        rviz=_flag(values, "rviz"),
    )


def _mission_file(values: Mapping[str, str]) -> Path | None:
    """The mission file, read once here so that a bad one stops the launch before anything starts."""
    path = mission_path(values["mission"])
    if path is not None:
        try:
            read_mission(path)
        except ValueError as error:
            raise LaunchArgumentError(f"launch argument mission: {error}") from None
    return path


# ---------------------------------------------------------------------------------------------- nodes

SIMULATED_TIME: dict[str, ParameterValue] = {"use_sim_time": True}


def _controller(common: _Common, namespace: str) -> NodePlan:
    return NodePlan("controller", namespace, {"airframe": common.airframe, **SIMULATED_TIME})


def _vehicle_nodes(
    common: _Common, namespace: str, mission: Path | None, relative_mission: bool
) -> list[NodePlan]:
    """Identifier, mission and visualizer of one vehicle under ``namespace`` (its controller apart)."""
    prefix = frame_prefix(namespace)
    nodes: list[NodePlan] = []
    if common.identifier:
        nodes.append(
            NodePlan(
                "identifier",
                namespace,
                {"airframe": common.airframe, "effects": common.effects, **SIMULATED_TIME},
            )
        )
    if mission is not None:
        nodes.append(
            NodePlan(
                "mission",
                namespace,
                {
                    "mission_file": str(mission),
                    "frame_id": prefix + "odom",
                    "relative_to_start": relative_mission,
                    **SIMULATED_TIME,
                },
            )
        )
    if common.visualizer:
        nodes.append(
            NodePlan(
                "visualizer",
                namespace,
                {"airframe": common.airframe, "frame_prefix": prefix, **SIMULATED_TIME},
            )
        )
    return nodes


def _rviz(common: _Common, namespace: str, prefix: str) -> list[NodePlan]:
    """rviz2 showing the vehicle under ``namespace``: the shipped view, or a copy moved to the namespace.

    RViz knows no namespace (its configuration names absolute topics and frames), so a vehicle under one
    gets a copy of the configuration with its topics and frames (rviz_config.py) in a temporary file.
    """
    if not common.rviz:
        return []
    config = config_directory().parent / RVIZ_CONFIG
    if namespace != "/" or prefix:
        text = namespaced_rviz_config(config.read_text(encoding="utf-8"), namespace, prefix)
        handle, name = tempfile.mkstemp(prefix=f"multirotor_{prefix.strip('/') or 'root'}_", suffix=".rviz")
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(text)
        config = Path(name)
    return [NodePlan("rviz2", "/", dict(SIMULATED_TIME), package="rviz2", arguments=("-d", str(config)))]


def _fault_parameters(common: _Common, prefix: str = "") -> dict[str, ParameterValue]:
    return {
        prefix + "fault_motor": common.fault_motor,
        prefix + "fault_effectiveness": common.fault_effectiveness,
    }


def vehicle_plan(values: Mapping[str, str]) -> list[NodePlan]:
    """One vehicle: simulator (publishing /clock), controller, identifier, mission, visualizer, rviz2."""
    common = _common(values)
    namespace = namespace_path(values["namespace"])
    simulator = NodePlan(
        "simulator",
        namespace,
        {
            "airframe": common.airframe,
            "real_time_factor": _number(values, "real_time_factor", 0.0, 1000.0),
            "publish_clock": True,
            "noise": common.noise,
            "frame_prefix": frame_prefix(namespace),
            **_fault_parameters(common),
        },
    )
    return [
        simulator,
        _controller(common, namespace),
        *_vehicle_nodes(common, namespace, _mission_file(values), False),
        *_rviz(common, namespace, frame_prefix(namespace)),
    ]


def fleet_plan(values: Mapping[str, str]) -> list[NodePlan]:
    """N vehicles in one simulator node (one graph, one /clock), the other nodes per vehicle namespace.

    The vehicles ``uav1``..``uavN`` stand in a row along x, ``spacing`` apart; each flies the mission
    from where it stands (``relative_to_start``), so one mission file serves the whole fleet.
    """
    common = _common(values)
    namespace = namespace_path(values["namespace"])
    count = _integer(values, "vehicles", 1, MAX_VEHICLES)
    spacing = _number(values, "spacing", 0.0, 1000.0)
    entries = [f"uav{k + 1} {k * spacing:g} 0 0" for k in range(count)]
    names = [spec.name for spec in parse_vehicles(entries)]
    fault_vehicle = values["fault_vehicle"].strip()
    if common.fault_motor and fault_vehicle not in names:
        raise LaunchArgumentError(
            f"launch argument fault_vehicle: {fault_vehicle!r} is none of the vehicles {', '.join(names)}"
        )
    simulator = NodePlan(
        "simulator",
        namespace,
        {
            "airframe": common.airframe,
            "vehicles": entries,
            "real_time_factor": _number(values, "real_time_factor", 0.0, 1000.0),
            "publish_clock": True,
            "noise": common.noise,
            # The simulator names each vehicle's frames NAME/odom itself; this prefixes the fleet's namespace.
            "frame_prefix": frame_prefix(namespace),
            **(_fault_parameters(common, f"{fault_vehicle}.") if common.fault_motor else {}),
        },
    )
    # The controllers in one process, each a node of its own under /NAMESPACE/NAME (fleet_controller.py):
    # a process per controller kept 4 vehicles' control periods on time 79 % of the time on a 2-core
    # machine, one process 98.5 % (bench/bench_fleet_ros.py). They exchange the fleet's odometries and
    # commands with the simulator in bundles (nodes/bundle.py): half the CPU of either process at ten.
    controllers = NodePlan(
        "fleet_controller",
        namespace,
        {"airframe": common.airframe, "vehicles": names, "bundles": True, **SIMULATED_TIME},
    )
    mission = _mission_file(values)
    vehicles = [
        node for name in names for node in _vehicle_nodes(common, _joined(namespace, name), mission, True)
    ]
    # RViz follows the first vehicle (the others' markers can be added in its Displays panel).
    first = _joined(namespace, names[0])
    return [simulator, controllers, *vehicles, *_rviz(common, first, frame_prefix(first))]


def mavlink_plan(values: Mapping[str, str]) -> list[NodePlan]:
    """The MAVLink bridge with its own physics in lockstep with PX4 or ArduPilot SITL, and the ROS side.

    The flight stack flies (no controller, no mission: missions come from the ground station, whose
    setpoints the bridge publishes); the flight stack's lockstep sets the pace, so there is no
    real_time_factor: PX4_SIM_SPEED_FACTOR or ArduPilot's --speedup choose it. The bridge publishes
    /clock. The flight stack itself is started apart (its own SITL build).
    """
    common = _common(values)
    namespace = namespace_path(values["namespace"])
    stack = values["flight_stack"].strip()
    if stack not in FLIGHT_STACKS:
        raise LaunchArgumentError(
            f"launch argument flight_stack: {stack!r}; choose one of {', '.join(FLIGHT_STACKS)}"
        )
    bridge = NodePlan(
        "mavlink_bridge",
        namespace,
        {
            "airframe": common.airframe,
            "flight_stack": stack,
            "internal_physics": True,
            "publish_clock": True,
            "sensor_noise": common.noise,
            "frame_prefix": frame_prefix(namespace),
            "flight_stack_port": _integer(values, "flight_stack_port", 0, 65535),
            "gcs_port": _integer(values, "gcs_port", 1, 65535),
            **_fault_parameters(common),
        },
    )
    others = _vehicle_nodes(common, namespace, None, False)
    return [bridge, *others, *_rviz(common, namespace, frame_prefix(namespace))]


_VEHICLE_COMMON = (AIRFRAME, EFFECTS, IDENTIFIER, NOISE, FAULT_MOTOR, FAULT_EFFECTIVENESS)
VEHICLE = LaunchFile((*_VEHICLE_COMMON, NAMESPACE, MISSION, REAL_TIME_FACTOR, VISUALIZER, RVIZ), vehicle_plan)
# The first launch file of the package: simulator, controller and identifier, no mission (you send the
# setpoints), no visualizer; its arguments airframe, real_time_factor, namespace and identifier are kept.
SIM = VEHICLE.with_defaults(mission=NO_MISSION, visualizer="false")
FLEET = LaunchFile(
    (
        *_VEHICLE_COMMON,
        FLEET_NAMESPACE,
        VEHICLES,
        SPACING,
        FAULT_VEHICLE,
        MISSION,
        REAL_TIME_FACTOR,
        VISUALIZER,
        RVIZ,
    ),
    fleet_plan,
)
MAVLINK = LaunchFile(
    (FLIGHT_STACK, *_VEHICLE_COMMON, NAMESPACE, FLIGHT_STACK_PORT, GCS_PORT, VISUALIZER, RVIZ), mavlink_plan
).with_defaults(airframe="quad_x")
LAUNCH_FILES = {
    "sim.launch.py": SIM,
    "vehicle.launch.py": VEHICLE,
    "fleet.launch.py": FLEET,
    "mavlink.launch.py": MAVLINK,
}
