"""The ``simulator`` node: one simulated vehicle on ROS 2 topics (shared/spec/interfaces.md).

Wiring::

    motor_speed_cmd (JointState) -> validate -> VehicleSimulator -> odom (Odometry, truth, publish_rate_hz)
                                                (simulation/)   -> imu (Imu), pose (PoseStamped),
                                                                   range (Range), motor_speeds (JointState)
                                                                -> clock (with every odom, if publish_clock)
    fault_motor, fault_effectiveness (parameters) ---------------> injected_faults (DiagnosticArray)

Rates: odom and clock at ``publish_rate_hz`` (250 Hz), imu 100 Hz, pose 100 Hz, motor_speeds 100 Hz,
range 15 Hz (the airframe YAML's ``sensors`` section, exposed as read-only ``sensors.*`` parameters).
QoS: odom, motor_speeds, motor_speed_cmd reliable (depth 10); imu, pose, range best effort (sensor data);
clock best effort depth 1 (as rclpy's time source subscribes); injected_faults reliable + transient local,
so a late subscriber gets the current truth.

Pacing: ``real_time_factor`` r > 0 runs r x wall time; 0 runs as fast as possible and, with
``publish_clock`` and ``lockstep_lead_s`` > 0, in lockstep with the controller (simulation/pacing.py).
Stamps are simulated time when ``publish_clock`` is set, else wall time at start + simulated time.
A namespaced simulator publishes ``<ns>/clock``: remap it (``-r clock:=/clock``) for the graph's clock.

Hostile commands (issue 11) are refused, counted per reason, logged once per reason and then summarised
(refusals.py); a refused command leaves the last accepted one in force. ``motor_speed_cmd`` must name
rotor_1..rotor_N once each with as many finite, non-negative speeds no larger than
``OVERSIZED_SPEED_FACTOR`` x the airframe's top speed (above the top speed they are clamped, as an ESC
saturates). Its stamp goes through a ``StampGate`` against this node's clock: simulated time when it
publishes the clock (a sender on that clock cannot be ahead of it: one publish period of slack), else
the node's ROS clock (0.5 s of slack between processes). A future stamp is refused alone and never kept,
so the next valid command is accepted; an older stamp than the newest accepted one is out of order.
A zero stamp means unstamped (``ros2 topic pub`` by hand): the command is taken as of now, without the
order check and without moving lockstep on; such commands are counted, the first one logged.
"""

from __future__ import annotations

import math
import time
from dataclasses import fields
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, Range

from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.clock import CLOCK_QOS, steady_clock
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import (
    joint_state_from_rotor_speeds,
    odometry_message,
    pose_message,
    rotor_names,
    rotor_speeds_from_joint_state,
    simulated_imu_message,
    stamp_from_ns,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.plausibility import StampGate
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation.pacing import NS_PER_S, Lockstep, RealTimePacer
from multirotor_ros.simulation.sensors import SensorConfig, airframe_sensor_config
from multirotor_ros.simulation.vehicle import OVERSIZED_SPEED_FACTOR, Reading, VehicleSimulator, period_ns

# Wall time a free-running (real_time_factor 0, no lockstep) simulator computes before serving callbacks.
FREE_RUN_SLICE_S = 0.005
LATCHED_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def simulator_parameters(n_rotors: int) -> list[NodeParameter]:
    """The simulator's own parameters (the ``sensors.*`` ones come from the airframe's YAML)."""
    return [
        NodeParameter(
            "physics_rate_hz", 1000.0, "integration rate of the physics", "Hz", 10.0, 100000.0, read_only=True
        ),
        NodeParameter("publish_rate_hz", 250.0, "rate of odom and clock", "Hz", 1.0, 10000.0, read_only=True),
        NodeParameter(
            "real_time_factor",
            1.0,
            "simulated seconds per wall second; 0 = as fast as possible",
            "-",
            0.0,
            1000.0,
            read_only=True,
        ),
        NodeParameter(
            "publish_clock", False, "publish simulated time on clock (for use_sim_time nodes)", read_only=True
        ),
        NodeParameter(
            "lockstep_lead_s",
            0.004,
            "at real_time_factor 0 with publish_clock: how far simulated time "
            "may run past the newest command's stamp; the controller's period (a longer lead makes its "
            "timer skip periods); 0 = no lockstep",
            "s",
            0.0,
            1.0,
            read_only=True,
        ),
        NodeParameter(
            "command_timeout_s",
            0.5,
            "without a motor command for this long the rotors stop "
            "(0 = never); also the wall time a lockstep simulator waits before running on",
            "s",
            0.0,
            60.0,
        ),
        NodeParameter(
            "motor_lag",
            True,
            "rotor speeds follow commands with the airframe's motor time constant",
            read_only=True,
        ),
        NodeParameter(
            "noise", True, "sensor noise and biases on (false: sensors read the truth)", read_only=True
        ),
        NodeParameter("seed", 0, "seed of the sensor noise generator", "-", 0, 2**31 - 1, read_only=True),
        NodeParameter("initial_x", 0.0, "initial position x, world ENU", "m", -1e4, 1e4, read_only=True),
        NodeParameter("initial_y", 0.0, "initial position y, world ENU", "m", -1e4, 1e4, read_only=True),
        NodeParameter(
            "initial_z",
            0.0,
            "initial height (0 = on the ground; above: hovering)",
            "m",
            0.0,
            1e4,
            read_only=True,
        ),
        NodeParameter("initial_yaw", 0.0, "initial yaw", "rad", -math.pi, math.pi, read_only=True),
        NodeParameter(
            "frame_prefix", "", "prefix of the frame ids odom and base_link (e.g. uav1/)", read_only=True
        ),
        NodeParameter(
            "fault_motor", 0, "rotor given fault_effectiveness from now on; 0 = no fault", "-", 0, n_rotors
        ),
        NodeParameter(
            "fault_effectiveness",
            0.0,
            "share of its thrust the faulty rotor gives; 0 = it stops",
            "-",
            0.0,
            1.0,
        ),
    ]


def sensor_parameters(config: SensorConfig) -> list[NodeParameter]:
    """``sensors.<field>`` for every field of the airframe's sensor configuration (read-only)."""
    return [
        NodeParameter(
            f"sensors.{f.name}",
            float(getattr(config, f.name)),
            f"sensor model: {f.name} (multirotor_ros/simulation/sensors.py)",
            "SI, see name",
            0.0,
            1e6,
            read_only=True,
        )
        for f in fields(config)
    ]


class SimulatorNode(Node):
    """The simulated vehicle as a ROS node; see the module docstring."""

    def __init__(self, **kwargs: Any):
        super().__init__("simulator", **kwargs)
        name = self.declare_parameter(
            "airframe",
            "x8_octorotor",
            NodeParameter("airframe", "", "airframe config name or YAML path", read_only=True).descriptor(),
        ).value
        self.airframe = load_airframe(name)
        n = self.airframe.n_rotors
        specs = simulator_parameters(n) + sensor_parameters(airframe_sensor_config(self.airframe))
        self._specs = {spec.name: spec for spec in specs}
        p = declare_parameters(self, specs)
        sensors = SensorConfig(**{f.name: p[f"sensors.{f.name}"] for f in fields(SensorConfig)})
        self.sim = VehicleSimulator(
            self.airframe,
            rng=np.random.default_rng(p["seed"]),
            physics_rate_hz=p["physics_rate_hz"],
            odom_rate_hz=p["publish_rate_hz"],
            motor_lag=p["motor_lag"],
            command_timeout_s=p["command_timeout_s"],
            sensors=sensors,
            noise=p["noise"],
            initial_position_m=(p["initial_x"], p["initial_y"], p["initial_z"]),
            initial_yaw_rad=p["initial_yaw"],
        )
        if p["fault_motor"]:
            self.sim.inject_fault(p["fault_motor"], p["fault_effectiveness"])
        self._params = p
        self._names = rotor_names(n)
        self._frames = (p["frame_prefix"] + "odom", p["frame_prefix"] + "base_link")
        self._speed_limit = OVERSIZED_SPEED_FACTOR * self.airframe.rotor_speed_max_rad_s
        self._stamp_offset_ns = 0 if p["publish_clock"] else self.get_clock().now().nanoseconds
        self._publish_period_ns = period_ns(p["publish_rate_hz"])
        self._command_gate = (
            StampGate(future_tolerance_s=self._publish_period_ns / NS_PER_S)
            if p["publish_clock"]
            else StampGate()
        )
        self.unstamped_commands = 0
        self._refusals = RefusalCounter(self.get_logger().warning, "motor_speed_cmd")

        self._pub = {
            "odom": self.create_publisher(Odometry, "odom", 10),
            "imu": self.create_publisher(Imu, "imu", qos_profile_sensor_data),
            "pose": self.create_publisher(PoseStamped, "pose", qos_profile_sensor_data),
            "range": self.create_publisher(Range, "range", qos_profile_sensor_data),
            "motor_speeds": self.create_publisher(JointState, "motor_speeds", 10),
        }
        self._clock_pub = self.create_publisher(Clock, "clock", CLOCK_QOS) if p["publish_clock"] else None
        self._faults_pub = self.create_publisher(DiagnosticArray, "injected_faults", LATCHED_QOS)
        self.create_subscription(JointState, "motor_speed_cmd", self._on_command, 10)
        self.add_on_set_parameters_callback(lambda params: check_parameters(self._specs, params))
        self.add_post_set_parameters_callback(self._apply_parameters)

        rate = p["real_time_factor"]
        self._lockstep = None
        if rate == 0 and p["publish_clock"] and p["lockstep_lead_s"] > 0:
            self._lockstep = Lockstep(
                round(p["lockstep_lead_s"] * NS_PER_S),
                max(p["command_timeout_s"], 0.1),
                last_command_wall_s=time.monotonic(),
            )
        self._pacer = RealTimePacer(rate if rate > 0 else 1.0)
        # A wall-clock timer drives the physics; at real_time_factor 0 it fires continuously (period 0)
        # unless lockstep lets commands drive it, when it only watches for a controller that went silent.
        wall = steady_clock()
        period = self._publish_period_ns / NS_PER_S if rate > 0 or self._lockstep else 0.0
        self.create_timer(period, self._on_timer, clock=wall)
        self.create_timer(1.0, self._publish_faults, clock=wall)
        self._publish(self.sim.run_until(0))
        self._publish_faults()
        self.get_logger().info(
            f"{self.airframe.name}: {n} rotors, physics {p['physics_rate_hz']:g} Hz, "
            f"real_time_factor {rate:g}{', lockstep' if self._lockstep else ''}"
            f"{', publishing clock' if p['publish_clock'] else ''}"
        )

    # ------------------------------------------------------------------ inputs

    def _on_command(self, message: JointState) -> None:
        result = rotor_speeds_from_joint_state(message, self.airframe.n_rotors, self._speed_limit)
        if not isinstance(result, Refusal) and result.stamp_ns:
            result = self._command_gate.check(result.stamp_ns, self._now_ns(), "motor_speed_cmd") or result
        if isinstance(result, Refusal):
            self._refusals.refuse(result.reason, result.detail)
            return
        if not result.stamp_ns:
            self.unstamped_commands += 1
            self.get_logger().info(
                "motor_speed_cmd without a stamp: taken as of now (unstamped commands are counted)", once=True
            )
        self.sim.set_command(result.speeds_rad_s)
        if self._lockstep is not None and result.stamp_ns:
            self._lockstep.command(result.stamp_ns - self._stamp_offset_ns, time.monotonic())
            self._run_to(self._lockstep.limit_ns())

    def _apply_parameters(self, parameters: list[Any]) -> None:
        changed = {p.name: p.value for p in parameters}
        self._params.update(changed)
        if "fault_motor" in changed or "fault_effectiveness" in changed:
            self.sim.inject_fault(self._params["fault_motor"], float(self._params["fault_effectiveness"]))
            self.get_logger().warning(
                f"fault injected at t = {self.sim.t_s:.3f} s: rotor {self._params['fault_motor']} "
                f"effectiveness {self._params['fault_effectiveness']:g}"
                if self._params["fault_motor"]
                else "fault cleared"
            )
            self._publish_faults()
        if "command_timeout_s" in changed:
            self.sim.command_timeout_ns = round(float(changed["command_timeout_s"]) * NS_PER_S)

    # ------------------------------------------------------------------ time

    def _now_ns(self) -> int:
        """This node's clock: the simulated time it publishes, or else its ROS clock."""
        if self._clock_pub is not None:
            return self.sim.t_ns
        return self.get_clock().now().nanoseconds

    def _on_timer(self) -> None:
        if self._lockstep is not None:
            if self._lockstep.stalled(time.monotonic()):
                self._run_to(self._pacer.target(time.monotonic_ns(), self.sim.t_ns))
            else:
                self._pacer.anchor(time.monotonic_ns(), self.sim.t_ns)
            return
        if self._params["real_time_factor"] > 0:
            self._run_to(self._pacer.target(time.monotonic_ns(), self.sim.t_ns))
            if self._pacer.fell_behind:
                self.get_logger().warning(
                    "the physics cannot keep up with real_time_factor: slowing down", once=True
                )
        else:
            # As fast as possible: several publish periods per tick (each executor round costs about as
            # much as a period of physics), then back to the executor for commands and parameters.
            deadline = time.perf_counter() + FREE_RUN_SLICE_S
            while True:
                self._run_to(self.sim.t_ns + self._publish_period_ns)
                if time.perf_counter() > deadline:
                    break

    def _run_to(self, t_ns: int) -> None:
        if t_ns > self.sim.t_ns:
            self._publish(self.sim.run_until(t_ns))

    # ------------------------------------------------------------------ outputs

    def _publish(self, readings: list[Reading]) -> None:
        for reading in readings:
            stamp = stamp_from_ns(reading.t_ns + self._stamp_offset_ns)
            kind, data = reading.kind, reading.data
            if kind == "odom":
                self._pub["odom"].publish(odometry_message(data, stamp, *self._frames))
                if self._clock_pub is not None:
                    self._clock_pub.publish(Clock(clock=stamp))
            elif kind == "imu":
                self._pub["imu"].publish(
                    simulated_imu_message(stamp, self._frames[1], data, self.sim.sensor_config)
                )
            elif kind == "pose":
                self._pub["pose"].publish(pose_message(stamp, self._frames[0], *data))
            elif kind == "range":
                self._pub["range"].publish(self._range_message(stamp, data))
            elif kind == "motor_speeds":
                self._pub["motor_speeds"].publish(joint_state_from_rotor_speeds(data, stamp))
            elif kind == "watchdog":
                self.get_logger().warning(
                    f"no motor command for {data:.2f} s of simulated time: rotors stopped"
                )

    def _range_message(self, stamp: Any, distance: float) -> Range:
        c = self.sim.sensor_config
        message = Range()
        message.header.stamp = stamp
        message.header.frame_id = self._frames[1]
        message.radiation_type = Range.ULTRASOUND
        message.field_of_view = 2.0 * c.range_max_tilt_rad
        message.min_range = c.range_min_m
        message.max_range = c.range_max_m
        message.range = distance
        return message

    def _publish_faults(self) -> None:
        message = DiagnosticArray()
        message.header.stamp = stamp_from_ns(self.sim.t_ns + self._stamp_offset_ns)
        for name, effectiveness in zip(self._names, self.sim.injected_effectiveness(), strict=True):
            level = (
                DiagnosticStatus.OK
                if effectiveness == 1.0
                else (DiagnosticStatus.ERROR if effectiveness == 0.0 else DiagnosticStatus.WARN)
            )
            text = "healthy" if effectiveness == 1.0 else f"injected fault: {effectiveness:.0%} of its thrust"
            message.status.append(
                DiagnosticStatus(
                    level=level,
                    name=name,
                    message=text,
                    hardware_id=self.get_fully_qualified_name(),
                    values=[KeyValue(key="effectiveness", value=f"{effectiveness:g}")],
                )
            )
        self._faults_pub.publish(message)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros simulator`` and ``multirotor node simulator``."""
    return run_node(SimulatorNode, args)
