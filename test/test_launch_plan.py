"""The launch files: what their plans start for given arguments, and the files themselves.

``launch`` and ``launch_ros`` are not on PyPI (its ``launch`` 0.1.3 is an unrelated 2017 package) nor in
Debian, the only sources the test machines reach, so the launch files are thin and what they start is
computed by multirotor_ros/launch_plan.py, tested here without them: every node a plan starts declares
the parameters it is given, with their types and ranges; namespaces and frames line up; each argument
reaches the parameter it is for; a bad argument is refused naming it. The launch files are compiled
always and loaded with the real ``launch`` where it is importable. test/test_mission.py starts the
processes of the one-vehicle plan and flies them over real DDS.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

from multirotor_ros import launch_plan
from multirotor_ros.control.gains import airframe_gains
from multirotor_ros.launch_plan import (
    FLEET,
    LAUNCH_FILES,
    MAVLINK,
    SIM,
    VEHICLE,
    LaunchArgumentError,
    NodePlan,
    frame_prefix,
)
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes import mavlink_bridge, mission
from multirotor_ros.nodes.controller import controller_parameters
from multirotor_ros.nodes.identifier import identifier_parameters
from multirotor_ros.nodes.parameters import NodeParameter
from multirotor_ros.nodes.simulator import sensor_parameters, simulator_parameters
from multirotor_ros.nodes.vehicles import parse_vehicles
from multirotor_ros.simulation.sensors import airframe_sensor_config

REPOSITORY = Path(__file__).resolve().parent.parent
LAUNCH = REPOSITORY / "launch"
# Another helper is writing the visualizer node: the plans list it, these tests do not start or read it.
NOT_CHECKED = {"visualizer", "rviz2"}
# Declared by the simulator and the controller themselves, before their other parameters.
AIRFRAME_ROW = NodeParameter("airframe", "", "config name or YAML path")
REAL_LAUNCH_MISSING = (
    "launch_ros is not importable: launch and launch_ros are on neither PyPI nor Debian, so only a ROS 2 "
    "install (colcon or apt) has them; the plans are tested without them above"
)


def _declared(plan: NodePlan) -> dict[str, NodeParameter]:
    """The parameters the node of ``plan`` declares, for its airframe (and vehicles)."""
    airframe = load_airframe(plan.parameters["airframe"]) if "airframe" in plan.parameters else None
    rows: list[NodeParameter]
    if plan.executable == "simulator":
        assert airframe is not None
        vehicles = parse_vehicles(plan.parameters.get("vehicles", []))
        rows = (
            simulator_parameters(airframe.n_rotors, vehicles)
            if vehicles
            else simulator_parameters(airframe.n_rotors)
        )
        rows += sensor_parameters(airframe_sensor_config(airframe))
        rows += [AIRFRAME_ROW, NodeParameter("vehicles", "", "checked by parse_vehicles")]
    elif plan.executable == "controller":
        rows = controller_parameters(airframe_gains(airframe).as_dict()) + [AIRFRAME_ROW]
    elif plan.executable == "fleet_controller":
        # Its vehicles, and what a launch's parameters give every node of the process: each controller's.
        rows = controller_parameters(airframe_gains(airframe).as_dict()) + [AIRFRAME_ROW]
        rows += [
            NodeParameter("vehicles", "", "checked by parse_vehicles"),
            NodeParameter("bundles", False, ""),
        ]
    elif plan.executable == "identifier":
        rows = identifier_parameters()
    elif plan.executable == "mavlink_bridge":
        assert airframe is not None
        rows = list(mavlink_bridge.PARAMETERS)
        rows += mavlink_bridge.fault_parameters(mavlink_bridge.VehicleSpec(""), airframe.n_rotors)
    elif plan.executable == "mission":
        rows = list(mission.PARAMETERS)
    else:
        raise AssertionError(f"no declared parameters known for {plan.executable}")
    return {row.name: row for row in rows + [NodeParameter("use_sim_time", False, "rclpy's")]}


def _by_executable(nodes: list[NodePlan], executable: str) -> list[NodePlan]:
    return [node for node in nodes if node.executable == executable]


def _one(nodes: list[NodePlan], executable: str, namespace: str = "/") -> NodePlan:
    (node,) = [n for n in _by_executable(nodes, executable) if n.namespace == namespace]
    return node


ALL_ON = {"rviz": "true", "fault_motor": "2", "fault_effectiveness": "0.5", "effects": "rotor_drag"}
PLANS = [
    pytest.param(file, given, id=f"{file}-{'defaults' if not given else 'all-on'}")
    for file in LAUNCH_FILES
    for given in ({}, ALL_ON)
]


@pytest.mark.parametrize(("file", "given"), PLANS)
def test_every_node_is_given_only_parameters_it_declares_with_their_type_and_range(file, given) -> None:
    nodes = LAUNCH_FILES[file].nodes(given)
    checked = [node for node in nodes if node.executable not in NOT_CHECKED]
    assert checked
    for node in checked:
        assert node.package == "multirotor_ros"
        declared = _declared(node)
        for name, value in node.parameters.items():
            assert name in declared, f"{file}: {node.executable} does not declare {name}"
            row = declared[name]
            if name not in ("airframe", "vehicles"):
                # The exact type: rcl refuses an integer for a double parameter (check() would accept it).
                assert type(value) is type(row.default), f"{file}: {node.executable} {name}: {value!r}"
                assert row.check(value) is None, f"{file}: {node.executable} {name}: {row.check(value)}"


def test_one_vehicle_flies_its_mission_on_the_simulators_clock() -> None:
    nodes = VEHICLE.nodes()
    assert [n.executable for n in nodes] == ["simulator", "controller", "identifier", "mission", "visualizer"]
    simulator = nodes[0]
    assert simulator.parameters["publish_clock"] is True
    assert simulator.parameters["real_time_factor"] == 0.0
    assert all(n.parameters["use_sim_time"] is True for n in nodes[1:])
    assert all(n.namespace == "/" for n in nodes)
    assert _one(nodes, "mission").parameters == {
        "mission_file": str(REPOSITORY / "config" / "missions" / "square.csv"),
        "frame_id": "odom",
        "relative_to_start": False,
        "use_sim_time": True,
    }


def test_a_namespace_prefixes_every_frame_of_the_vehicle() -> None:
    for given, namespace, prefix in [("uav1", "/uav1", "uav1/"), ("/team/uav1/", "/team/uav1", "team/uav1/")]:
        nodes = VEHICLE.nodes({"namespace": given})
        assert {n.namespace for n in nodes} == {namespace}
        assert _one(nodes, "simulator", namespace).parameters["frame_prefix"] == prefix
        assert _one(nodes, "mission", namespace).parameters["frame_id"] == prefix + "odom"
        assert _one(nodes, "visualizer", namespace).parameters["frame_prefix"] == prefix


def test_arguments_reach_the_parameters_they_are_for(tmp_path) -> None:
    mission_file = tmp_path / "hop.csv"
    mission_file.write_text("t,x,y,z,yaw\n0,0,0,1,0\n")
    nodes = VEHICLE.nodes(
        {
            "airframe": "quad_x",
            "effects": "rotor_drag,ground_effect",
            "noise": "false",
            "fault_motor": "3",
            "fault_effectiveness": "0.25",
            "real_time_factor": "1",
            "mission": str(mission_file),
        }
    )
    simulator = _one(nodes, "simulator")
    assert simulator.parameters["airframe"] == "quad_x"
    assert simulator.parameters["noise"] is False
    assert (simulator.parameters["fault_motor"], simulator.parameters["fault_effectiveness"]) == (3, 0.25)
    assert simulator.parameters["real_time_factor"] == 1.0
    assert isinstance(simulator.parameters["real_time_factor"], float)
    assert _one(nodes, "identifier").parameters["effects"] == "rotor_drag,ground_effect"
    assert _one(nodes, "mission").parameters["mission_file"] == str(mission_file)
    assert {n.parameters["airframe"] for n in nodes if "airframe" in n.parameters} == {"quad_x"}


def test_nodes_can_be_left_out() -> None:
    executables = [
        n.executable for n in VEHICLE.nodes({"identifier": "false", "mission": "none", "visualizer": "0"})
    ]
    assert executables == ["simulator", "controller"]


def test_rviz_starts_with_the_packages_configuration_on_simulated_time() -> None:
    (rviz,) = _by_executable(VEHICLE.nodes({"rviz": "true"}), "rviz2")
    assert rviz.package == "rviz2"
    assert rviz.arguments == ("-d", str(REPOSITORY / "rviz" / "multirotor.rviz"))
    assert rviz.parameters == {"use_sim_time": True}


def test_rviz_of_a_namespaced_vehicle_shows_its_topics_and_frames() -> None:
    for file, arguments, namespace in (
        (VEHICLE, {"rviz": "true", "namespace": "uav7"}, "/uav7"),
        (FLEET, {"rviz": "true", "vehicles": "2"}, "/uav1"),
    ):
        (rviz,) = _by_executable(file.nodes(arguments), "rviz2")
        config = Path(rviz.arguments[1])
        try:
            manager = yaml.safe_load(config.read_text(encoding="utf-8"))["Visualization Manager"]
        finally:
            config.unlink()
        topics = {d["Topic"]["Value"] for d in manager["Displays"] if "Topic" in d}
        assert topics == {f"{namespace}/markers", f"{namespace}/path", f"{namespace}/odom"}
        assert manager["Global Options"]["Fixed Frame"] == f"{namespace[1:]}/odom"


def test_sim_launch_keeps_its_arguments_and_starts_no_mission() -> None:
    names = [a.name for a in SIM.arguments]
    assert {"airframe", "real_time_factor", "namespace", "identifier"} <= set(names)
    assert [n.executable for n in SIM.nodes()] == ["simulator", "controller", "identifier"]
    assert [n.executable for n in SIM.nodes({"identifier": "false"})] == ["simulator", "controller"]


def test_a_fleet_is_one_simulator_and_each_vehicles_nodes_in_its_namespace() -> None:
    nodes = FLEET.nodes({"vehicles": "3", "spacing": "5", "fault_vehicle": "uav2", "fault_motor": "1"})
    (simulator,) = _by_executable(nodes, "simulator")
    assert simulator.namespace == "/"
    assert simulator.parameters["vehicles"] == ["uav1 0 0 0", "uav2 5 0 0", "uav3 10 0 0"]
    assert simulator.parameters["uav2.fault_motor"] == 1
    assert "fault_motor" not in simulator.parameters
    # The controllers are nodes of one process, /uavK/controller each (nodes/fleet_controller.py).
    (controllers,) = _by_executable(nodes, "fleet_controller")
    assert controllers.namespace == "/"
    assert controllers.parameters["vehicles"] == ["uav1", "uav2", "uav3"]
    assert controllers.parameters["use_sim_time"] is True
    assert controllers.parameters["bundles"] is True  # with the simulator's fleet bundles (nodes/bundle.py)
    assert not _by_executable(nodes, "controller")
    for k in (1, 2, 3):
        namespace = f"/uav{k}"
        assert {n.executable for n in nodes if n.namespace == namespace} == {
            "identifier",
            "mission",
            "visualizer",
        }
        # The simulator names vehicle k's frames frame_prefix + "uavk/" (nodes/simulator.py).
        frames = simulator.parameters["frame_prefix"] + f"uav{k}/"
        assert _one(nodes, "mission", namespace).parameters["frame_id"] == frames + "odom"
        assert _one(nodes, "mission", namespace).parameters["relative_to_start"] is True
        assert _one(nodes, "visualizer", namespace).parameters["frame_prefix"] == frames


def test_a_fleet_under_a_namespace_keeps_topics_and_frames_together() -> None:
    nodes = FLEET.nodes({"vehicles": "2", "namespace": "team"})
    simulator = _one(nodes, "simulator", "/team")
    assert simulator.parameters["frame_prefix"] == "team/"
    assert _one(nodes, "fleet_controller", "/team").parameters["vehicles"] == ["uav1", "uav2"]
    assert _one(nodes, "mission", "/team/uav2").parameters["frame_id"] == "team/uav2/odom"
    assert frame_prefix("/team/uav2") == "team/uav2/"


def test_the_mavlink_bridge_owns_the_physics_and_the_clock_with_either_flight_stack() -> None:
    for stack in ("px4", "ardupilot"):
        nodes = MAVLINK.nodes(
            {"flight_stack": stack, "noise": "false", "fault_motor": "4", "namespace": "uav7"}
        )
        assert [n.executable for n in nodes] == ["mavlink_bridge", "identifier", "visualizer"]
        bridge = nodes[0]
        assert bridge.parameters["flight_stack"] == stack
        assert bridge.parameters["internal_physics"] is True
        assert bridge.parameters["publish_clock"] is True
        assert bridge.parameters["sensor_noise"] is False
        assert bridge.parameters["fault_motor"] == 4
        assert bridge.parameters["frame_prefix"] == "uav7/"
        assert bridge.parameters["airframe"] == "quad_x"
        assert all(n.namespace == "/uav7" for n in nodes)


@pytest.mark.parametrize(
    ("launch_file", "given", "message"),
    [
        (
            VEHICLE,
            {"airframe": "no_such_frame"},
            "launch argument airframe: unknown airframe 'no_such_frame'",
        ),
        (VEHICLE, {"airframe": "quad_x", "fault_motor": "5"}, "fault_motor: must be within 0..4, got 5"),
        (VEHICLE, {"fault_effectiveness": "1.5"}, "fault_effectiveness: must be within 0..1"),
        (VEHICLE, {"noise": "maybe"}, "noise: expected true or false, got 'maybe'"),
        (VEHICLE, {"real_time_factor": "fast"}, "real_time_factor: not a number: 'fast'"),
        (VEHICLE, {"real_time_factor": "-1"}, "real_time_factor: must be within 0..1000"),
        (VEHICLE, {"namespace": "uav-1"}, "namespace 'uav-1': 'uav-1' is not a ROS name"),
        (VEHICLE, {"mission": "no_such_mission"}, "unknown mission 'no_such_mission'; known: square"),
        (VEHICLE, {"mission": "/no/such/file.csv"}, "mission: no such file '/no/such/file.csv'"),
        (VEHICLE, {"speed": "1"}, "unknown launch argument speed"),
        (FLEET, {"vehicles": "0"}, "vehicles: must be within 1..256, got 0"),
        (
            FLEET,
            {"vehicles": "2", "fault_motor": "1", "fault_vehicle": "uav3"},
            "'uav3' is none of the vehicles",
        ),
        (MAVLINK, {"flight_stack": "betaflight"}, "flight_stack: 'betaflight'; choose one of px4, ardupilot"),
        (MAVLINK, {"gcs_port": "0"}, "gcs_port: must be within 1..65535, got 0"),
    ],
)
def test_a_bad_argument_is_refused_naming_it(launch_file, given, message) -> None:
    with pytest.raises(LaunchArgumentError) as error:
        launch_file.nodes(given)
    assert message in str(error.value)


def test_a_bad_mission_file_stops_the_launch_naming_file_and_line(tmp_path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("# a comment\nt,x,y,z,yaw\n0,0,0,1,0\n4,1,0,one,0\n")
    with pytest.raises(
        LaunchArgumentError, match=rf"launch argument mission: {bad}:4: column 'z': not a number"
    ):
        VEHICLE.nodes({"mission": str(bad)})


# ---------------------------------------------------------------------------------------------- the files


def _launch_file_names() -> list[str]:
    return sorted(p.name for p in LAUNCH.glob("*.launch.py"))


def test_each_launch_file_is_a_launch_file_of_the_plan_module() -> None:
    assert _launch_file_names() == sorted(LAUNCH_FILES)


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_the_launch_file_compiles_names_its_plan_and_documents_its_command_and_arguments(name) -> None:
    source = (LAUNCH / name).read_text(encoding="utf-8")
    tree = ast.parse(compile(source, name, "exec", flags=ast.PyCF_ONLY_AST), filename=name)
    imported = [
        alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.module == "multirotor_ros.launch_plan"
        for alias in node.names
    ]
    assert [getattr(launch_plan, n) for n in imported] == [LAUNCH_FILES[name]]
    assert any(
        isinstance(node, ast.FunctionDef) and node.name == "generate_launch_description" for node in tree.body
    )
    docstring = ast.get_docstring(tree) or ""
    assert f"ros2 launch multirotor_ros {name}" in docstring
    undocumented = [a.name for a in LAUNCH_FILES[name].arguments if a.name not in docstring]
    assert not undocumented, f"{name}: arguments missing from the docstring: {undocumented}"


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_the_launch_file_loads_with_the_real_launch(name) -> None:
    pytest.importorskip("launch_ros", reason=REAL_LAUNCH_MISSING)
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.launch_context import LaunchContext
    from launch.launch_description_sources import get_launch_description_from_python_launch_file

    description = get_launch_description_from_python_launch_file(str(LAUNCH / name))
    declared = [e for e in description.entities if isinstance(e, DeclareLaunchArgument)]
    assert [d.name for d in declared] == [a.name for a in LAUNCH_FILES[name].arguments]
    context = LaunchContext()
    for declaration in declared:
        declaration.execute(context)  # sets each argument to its default
    (opaque,) = [e for e in description.entities if isinstance(e, OpaqueFunction)]
    actions = opaque.execute(context)
    assert [(a.node_package, a.node_executable) for a in actions] == [
        (n.package, n.executable) for n in LAUNCH_FILES[name].nodes()
    ]
