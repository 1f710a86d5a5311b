"""Simulator and controller nodes: parameter checks (no DDS), then the closed loop over real ROS 2.

Message conversion is tested in test_node_messages.py, refusal counting in test_refusal.py.

The ROS tests start the executables as a user would (``multirotor node NAME --ros-args ...``) in the
session's isolated domain and talk to them only through topics and parameter services. Most of them
share one vehicle flying at real_time_factor 0 in lockstep with a ``use_sim_time`` controller, so
that their numbers do not depend on how loaded the machine is; times below are simulated seconds.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from ros_harness import NodeProcess, Recorder, RosProbe
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, Range

from multirotor_ros.nodes.messages import stamp_from_ns, stamp_to_ns
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters

# ------------------------------------------------------------------ helpers without DDS


def joint_state(names, speeds, stamp_ns=0) -> JointState:
    message = JointState()
    message.header.stamp = stamp_from_ns(stamp_ns)
    message.name = list(names)
    message.velocity = [float(v) for v in speeds]
    return message


def test_parameter_checks_give_reasons() -> None:
    from rclpy.parameter import Parameter

    specs = {
        s.name: s
        for s in [
            NodeParameter("gain", 1.0, "a gain", "1/s", 0.0, 10.0, low_exclusive=True),
            NodeParameter("motor", 0, "a rotor", "-", 0, 8),
            NodeParameter("fixed", 1.0, "read-only", read_only=True),
        ]
    }

    def check(name, value):
        return check_parameters(specs, [Parameter(name, value=value)])

    assert check("gain", 2.0).successful
    assert check("gain", 3).successful  # an integer is a fine value for a double
    assert "must be finite" in check("gain", math.nan).reason
    assert "must be > 0" in check("gain", 0.0).reason
    assert "must be <= 10" in check("gain", 11.0).reason
    assert "must be a float" in check("gain", "fast").reason
    assert "must be <= 8" in check("motor", 9).reason
    assert "read-only" in check("fixed", 2.0).reason
    assert check("use_sim_time", True).successful


# ------------------------------------------------------------------ the closed loop over ROS 2

STARTUP_TIMEOUT_S = 120.0
ODOM_QUEUE_DEPTH = 1000  # [messages] 4 s of odometry at 250 Hz (start_vehicle)


def stamp_s(message) -> float:
    return stamp_to_ns(message.header.stamp) * 1e-9


def position(message: Odometry) -> np.ndarray:
    p = message.pose.pose.position
    return np.array([p.x, p.y, p.z])


def setpoint_message(x: float, y: float, z: float, yaw: float = 0.0) -> PoseStamped:
    message = PoseStamped()
    message.header.frame_id = "odom"
    # float(): the rclpy wheels take a Python int into a float64 field and serialise its bits (3 -> 1.5e-323).
    message.pose.position.x, message.pose.position.y, message.pose.position.z = float(x), float(y), float(z)
    message.pose.orientation.z, message.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return message


@dataclass
class Vehicle:
    """A simulator and a controller under one namespace, with the probe's view of them."""

    namespace: str
    simulator: NodeProcess
    controller: NodeProcess
    odom: Recorder
    probe: RosProbe

    def __post_init__(self) -> None:
        self.setpoints = self.probe.publisher(f"{self.namespace}/setpoint", PoseStamped)

    def latest(self) -> Odometry:
        # The first call waits for the nodes to start: several processes importing numba on a busy machine.
        return self.odom.wait_for(count=1, timeout=STARTUP_TIMEOUT_S)[-1]

    def fly_to(self, x: float, y: float, z: float, yaw: float = 0.0) -> float:
        """Send a setpoint; return the simulated time it was sent at."""
        self.probe.wait_for_subscribers(self.setpoints, timeout=STARTUP_TIMEOUT_S)
        sent_at = stamp_s(self.latest())
        self.setpoints.publish(setpoint_message(x, y, z, yaw))
        return sent_at

    def settle_at(self, x: float, y: float, z: float, tolerance: float = 0.02) -> float:
        """Fly to a point and wait until the vehicle is there (at once if it already is); return the time."""
        sent = self.fly_to(x, y, z)

        def there(message: Odometry) -> bool:
            return stamp_s(message) > sent and np.linalg.norm(position(message) - (x, y, z)) < tolerance

        return stamp_s(self.odom.wait_for(there, timeout=120.0)[-1])

    def until(self, t_s: float, timeout: float = 240.0) -> list[Odometry]:
        """Wait until the odometry reaches simulated time ``t_s``; all odometry received so far.

        In lockstep simulated time runs only as fast as the machine lets four processes exchange
        messages: on a loaded 2-core machine that was seen as low as 0.06 x real time, hence the wait.
        """
        self.odom.wait_for(lambda m: stamp_s(m) >= t_s, timeout=timeout)
        return self.odom.messages

    def between(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """(times, positions) of the odometry in [t0, t1] of simulated time."""
        messages = [m for m in self.until(t1) if t0 <= stamp_s(m) <= t1]
        return np.array([stamp_s(m) for m in messages]), np.array([position(m) for m in messages])


def start_vehicle(
    probe: RosProbe, directory: Path, namespace: str, simulator: dict, controller: dict, sim_time: bool
) -> Vehicle:
    """Start a simulator and a controller under ``namespace``.

    With ``sim_time`` the simulator publishes the graph's clock (``/clock``) and the controller follows it.
    """
    # Deep: the middleware's thread queues a lockstep burst while this process's Python is held up (a
    # probe with the default depth of 10 once lost two seconds of simulated time, test_hover in CI).
    odom = probe.subscribe(f"{namespace}/odom", Odometry, qos=ODOM_QUEUE_DEPTH)
    name = namespace.strip("/")
    sim = NodeProcess(
        "simulator",
        directory / f"{name}-simulator.log",
        namespace=namespace,
        parameters={**simulator, "publish_clock": sim_time},
    )
    ctrl = NodeProcess(
        "controller",
        directory / f"{name}-controller.log",
        namespace=namespace,
        parameters={**controller, "use_sim_time": sim_time},
    )
    return Vehicle(namespace, sim, ctrl, odom, probe)


def stop_vehicles(*vehicles: Vehicle) -> None:
    """SIGINT every node; each must exit with status 0 (failures reported together, with their logs)."""
    failures = []
    for vehicle in vehicles:
        for process in (vehicle.controller, vehicle.simulator):
            try:
                process.stop()
            except AssertionError as error:
                failures.append(str(error))
    assert not failures, "\n\n".join(failures)


def module_probe() -> Iterator[RosProbe]:
    """A probe shared by a module's tests (as a module-scoped fixture)."""
    probe = RosProbe()
    yield probe
    probe.close()


def lockstep_vehicle(probe: RosProbe, directory: Path, namespace: str, seed: int) -> Iterator[Vehicle]:
    """An X8 at real_time_factor 0, lockstep: the simulator publishes the clock, the controller follows it."""
    vehicle = start_vehicle(
        probe,
        directory,
        namespace,
        simulator={"real_time_factor": 0.0, "command_timeout_s": 1.0, "seed": seed},
        controller={},
        sim_time=True,
    )
    yield vehicle
    stop_vehicles(vehicle)


probe = pytest.fixture(scope="module", name="probe")(module_probe)


@pytest.fixture(scope="module")
def vehicle(probe: RosProbe, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    yield from lockstep_vehicle(probe, tmp_path_factory.mktemp("closed_loop"), "/t1", seed=3)


@pytest.mark.ros
def test_hover_holds_within_2_cm(vehicle: Vehicle) -> None:
    sent = vehicle.fly_to(0.0, 0.0, 1.0)
    _, positions = vehicle.between(sent + 6.0, sent + 8.0)
    error = np.linalg.norm(positions - [0.0, 0.0, 1.0], axis=1)
    assert error.max() < 0.02, f"hover error up to {error.max():.3f} m"


BAD_COMMANDS = {
    "non-finite speed": ([f"rotor_{k}" for k in range(1, 9)], [300.0] * 7 + [math.nan]),
    "negative speed": ([f"rotor_{k}" for k in range(1, 9)], [300.0] * 7 + [-1.0]),
    "oversized speed": ([f"rotor_{k}" for k in range(1, 9)], [300.0] * 7 + [1e5]),
    "wrong rotor count": ([f"rotor_{k}" for k in range(1, 5)], [300.0] * 4),
    "unknown rotor name": ([f"rotor_{k}" for k in range(1, 8)] + ["rotor_9"], [300.0] * 8),
}


@pytest.mark.ros
def test_bad_commands_are_refused_counted_and_logged_once_while_the_vehicle_flies_on(
    vehicle: Vehicle, probe: RosProbe
) -> None:
    vehicle.settle_at(0.0, 0.0, 1.0)
    publisher = probe.publisher("/t1/motor_speed_cmd", JointState)
    probe.wait_for_subscribers(publisher, timeout=STARTUP_TIMEOUT_S)
    for _ in range(3):
        for names, speeds in BAD_COMMANDS.values():
            publisher.publish(joint_state(names, speeds, stamp_ns=stamp_to_ns(vehicle.latest().header.stamp)))
        # A valid command stamped before the newest one is out of order.
        publisher.publish(joint_state([f"rotor_{k}" for k in range(1, 9)], [0.0] * 8, stamp_ns=1))
    now = stamp_s(vehicle.latest())
    _, positions = vehicle.between(now, now + 2.0)
    assert np.all(np.isfinite(positions))
    assert np.linalg.norm(positions - [0.0, 0.0, 1.0], axis=1).max() < 0.05
    log = vehicle.simulator.log_text()
    for reason in [*BAD_COMMANDS, "stamp out of order"]:
        assert log.count(f"refused motor_speed_cmd: {reason}:") == 1, reason
    vehicle.simulator.assert_running()


@pytest.mark.ros
def test_a_1_m_step_in_x_settles_within_5_s_with_less_than_20_percent_overshoot(vehicle: Vehicle) -> None:
    vehicle.settle_at(0.0, 0.0, 1.0)
    sent = vehicle.fly_to(1.0, 0.0, 1.0)
    times, positions = vehicle.between(sent, sent + 7.0)
    x = positions[:, 0]
    assert x.max() - 1.0 < 0.20, f"overshoot {x.max() - 1.0:.3f} m"
    outside = np.nonzero(np.abs(x - 1.0) > 0.05)[0]
    assert times[outside[-1]] - sent < 5.0, f"outside 5 % until {times[outside[-1]] - sent:.2f} s"
    assert np.abs(positions[:, 2] - 1.0).max() < 0.1


@pytest.mark.ros
def test_the_controller_follows_simulated_time(vehicle: Vehicle, probe: RosProbe) -> None:
    commands = probe.subscribe("/t1/motor_speed_cmd", JointState)
    clock = probe.subscribe("/clock", Clock, qos_profile_sensor_data)
    received = commands.wait_for(count=100, timeout=60.0)
    latest_clock = clock.wait_for(count=1)[-1].clock
    stamps = np.array([stamp_s(m) for m in received])
    # Simulated time starts at 0, so the stamps are seconds since the simulator started, not the epoch...
    assert stamps.max() < 1e6
    assert stamp_to_ns(latest_clock) * 1e-9 - stamps.max() < 1.0
    # ...and the law runs at its rate_hz of simulated time (250 Hz), one command per period.
    periods = np.diff(np.unique(stamps))
    assert np.median(periods) == pytest.approx(0.004, abs=1e-6)


@pytest.mark.ros
@pytest.mark.parametrize(
    ("node", "values", "reason"),
    [
        ("simulator", {"fault_motor": 9}, "fault_motor"),
        ("simulator", {"fault_effectiveness": 1.5}, "fault_effectiveness"),
        ("simulator", {"fault_effectiveness": math.nan}, "fault_effectiveness"),
        ("simulator", {"physics_rate_hz": 500.0}, "read-only"),
        ("controller", {"k_px": -1.0}, "k_px"),
        ("controller", {"b_dphi": math.inf}, "b_dphi"),
        ("controller", {"k_dz": "fast"}, "Wrong parameter type"),
        ("controller", {"rate_hz": 100.0}, "read-only"),
    ],
)
def test_invalid_parameter_values_are_rejected_with_a_reason(
    vehicle: Vehicle, probe: RosProbe, node, values, reason
) -> None:
    result = probe.set_parameters(f"/t1/{node}", values)
    (outcome,) = result.values()
    assert not outcome.successful
    assert reason in outcome.reason


@pytest.mark.ros
def test_a_gain_can_be_changed_in_flight(vehicle: Vehicle, probe: RosProbe) -> None:
    (outcome,) = probe.set_parameters("/t1/controller", {"k_dz": 6.5}).values()
    assert outcome.successful
    assert probe.get_parameters("/t1/controller", ["k_dz"]) == {"k_dz": 6.5}


@pytest.mark.ros
def test_the_x8_keeps_flying_after_rotor_3_stops(vehicle: Vehicle, probe: RosProbe) -> None:
    faults = probe.subscribe("/t1/injected_faults", DiagnosticArray)
    vehicle.settle_at(0.0, 0.0, 1.0)
    (outcome,) = probe.set_parameters("/t1/simulator", {"fault_motor": 3}).values()
    assert outcome.successful
    injected = stamp_s(vehicle.latest())
    truth = faults.wait_for(lambda m: m.status[2].values[0].value == "0", timeout=30.0)[-1]
    assert [s.name for s in truth.status] == [f"rotor_{k}" for k in range(1, 9)]
    assert [s.values[0].value for s in truth.status] == ["1", "1", "0", "1", "1", "1", "1", "1"]
    _, positions = vehicle.between(injected, injected + 8.0)
    assert positions[:, 2].min() > 0.6
    assert np.hypot(positions[:, 0], positions[:, 1]).max() < 1.5
    assert abs(positions[-1, 2] - 1.0) < 0.05
    (outcome,) = probe.set_parameters("/t1/simulator", {"fault_motor": 0}).values()
    assert outcome.successful


@pytest.mark.ros
def test_a_second_simulator_publishing_the_clock_is_refused(
    vehicle: Vehicle, probe: RosProbe, tmp_path
) -> None:
    vehicle.latest()
    clock = probe.subscribe("/clock", Clock, qos_profile_sensor_data)
    second = NodeProcess(
        "simulator",
        tmp_path / "second.log",
        namespace="/uav2",
        parameters={"real_time_factor": 0.0, "publish_clock": True},
    )
    try:
        assert second.process.wait(STARTUP_TIMEOUT_S) == 2, second.log_tail()
    finally:
        second.stop(check=False)
    log = second.log_text()
    assert "/t1/simulator" in log, log
    if "another node already publishes /clock (" in log:
        # Refused before it published: the graph's time never went back to the second simulator's 0.
        times = [stamp_to_ns(m.clock) for m in clock.messages]
        assert times == sorted(times)
    else:
        # Discovery was later than its check (seen in CI at load 6+): the first one's claim stopped it.
        assert "/t1/simulator claimed /clock " in log and "so this simulator stops" in log, log
    vehicle.latest()  # the first one flies on
    assert vehicle.simulator.running


@pytest.mark.ros
def test_of_two_simulators_started_together_the_second_to_claim_the_clock_stops(
    probe: RosProbe, tmp_path
) -> None:
    # A clock and claim topic of their own: the module's vehicle keeps the graph's /clock meanwhile.
    remaps = {"/clock": "/clock_of_two", "/clock_claim": "/clock_claim_of_two"}
    clock = probe.subscribe("/clock_of_two", Clock, qos_profile_sensor_data)
    simulators = {
        name: NodeProcess(
            "simulator",
            tmp_path / f"{name}.log",
            namespace=f"/{name}",
            parameters={"real_time_factor": 0.0, "publish_clock": True, "airframe": "quad_x"},
            remaps=remaps,
        )
        for name in ("twin_a", "twin_b")
    }
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while all(s.running for s in simulators.values()) and time.monotonic() < deadline:
            time.sleep(0.1)
        stopped = [name for name, s in simulators.items() if not s.running]
        assert len(stopped) == 1, {name: s.log_tail() for name, s in simulators.items()}
        (survivor,) = set(simulators) - set(stopped)
        assert simulators[stopped[0]].process.returncode == 2
        assert f"/{survivor}/simulator" in simulators[stopped[0]].log_text()
        time.sleep(2.0)  # the survivor heard the other's claim too, and keeps the clock
        assert simulators[survivor].running, simulators[survivor].log_tail()
        assert clock.wait_for(count=1, timeout=10.0)
    finally:
        for simulator in simulators.values():
            simulator.stop(check=False)


@pytest.mark.ros
def test_a_lone_simulator_publishes_its_sensors_and_stops_rotors_without_commands(
    probe: RosProbe, tmp_path
) -> None:
    imu = probe.subscribe("/solo/imu", Imu, qos_profile_sensor_data)
    ranges = probe.subscribe("/solo/range", Range, qos_profile_sensor_data)
    speeds = probe.subscribe("/solo/motor_speeds", JointState)
    simulator = NodeProcess(
        "simulator",
        tmp_path / "solo.log",
        namespace="/solo",
        parameters={"command_timeout_s": 0.3, "airframe": "quad_x"},
    )
    try:
        reading = imu.wait_for(count=20, timeout=STARTUP_TIMEOUT_S)[-1]
        assert reading.linear_acceleration.z == pytest.approx(9.81, abs=0.1)  # resting: 1 g up
        assert ranges.wait_for(count=1)[-1].range == pytest.approx(0.09)  # 0.10 m mount, 3 cm steps
        publisher = probe.publisher("/solo/motor_speed_cmd", JointState)
        probe.wait_for_subscribers(publisher)
        publisher.publish(joint_state([f"rotor_{k}" for k in range(1, 5)], [200.0] * 4))
        speeds.wait_for(lambda m: min(m.velocity) > 150.0, timeout=10.0)
        speeds.clear()
        speeds.wait_for(lambda m: max(m.velocity) < 20.0, timeout=10.0)
        assert simulator.log_text().count("no motor command for 0.30 s") == 1
    finally:
        simulator.stop()


def test_a_node_built_with_a_bad_parameter_ends_with_status_2_and_the_reason(capsys) -> None:
    from multirotor_ros.nodes.entry import run_node
    from multirotor_ros.nodes.simulator import SimulatorNode

    assert run_node(SimulatorNode, ["simulator", "--ros-args", "-p", "airframe:=no_such_frame"]) == 2
    assert "simulator: unknown airframe 'no_such_frame'" in capsys.readouterr().err
    assert run_node(SimulatorNode, ["simulator", "--ros-args", "-p", "physics_rate_hz:=-5.0"]) == 2
    assert "physics_rate_hz out of range" in capsys.readouterr().err
