"""The ``simulator`` node: one simulated vehicle on ROS 2 topics (shared/spec/interfaces.md).

Wiring::

    motor_speed_cmd (JointState) -> validate -> VehicleSimulator -> odom (Odometry, truth, publish_rate_hz)
                                                (simulation/)   -> imu (Imu), pose (PoseStamped),
                                                                   range (Range), motor_speeds (JointState)
                                                                -> clock (with every odom, if publish_clock)
    fault_motor, fault_effectiveness, faults (parameters) -------> injected_faults (DiagnosticArray)
                                                                -> /tf (odom -> base_link, with every odom),
                                                                   /tf_static (base_link -> rotor_k)
    ~/reset (std_srvs/Trigger) --> vehicles to their initial state -> simulation_reset (Header)

Rates: odom and clock at ``publish_rate_hz`` (250 Hz), imu 100 Hz, pose 100 Hz, motor_speeds 100 Hz,
range 15 Hz (the airframe YAML's ``sensors`` section, exposed as read-only ``sensors.*`` parameters).
QoS: odom, motor_speeds, motor_speed_cmd reliable (depth 10); imu, pose, range best effort (sensor data);
clock best effort depth 1 (as rclpy's time source subscribes); injected_faults reliable + transient local,
so a late subscriber gets the current truth. The volatile topics (state topics, /tf, /clock) are filled
and published only while somebody subscribes (nodes/listeners.py, asked every 0.1 s): a controller hears
odom and the clock, and a publish nobody hears still costs its conversion and the middleware's
bookkeeping. Their noise is drawn all the same, so who listens never changes a flight. What lockstep
resends is built from the newest reading even if nobody heard it when it was new.

Fleet bundles (nodes/bundle.py), with a ``vehicles`` list: ``fleet/odom`` (std_msgs/UInt8MultiArray,
reliable, depth 1) carries every vehicle's odom of one instant, serialised as on its own topic, published
after the last one's and before the clock, while somebody listens; ``fleet/motor_speed_cmd`` takes
commands the same way, each checked and applied as if it came on its vehicle's ``motor_speed_cmd``. A
``fleet_controller`` with ``bundles`` on uses them: two messages a control period for the whole fleet
instead of two per vehicle. A bundle that breaks the layout is refused whole, with the reason.

Frames and tf (REP-105): ``frame_prefix`` + ``odom`` / ``base_link`` (+ the vehicle's name in a fleet);
the launch files set the prefix from the namespace (``uav1/``) so that vehicles' frames do not collide.
``/tf`` and ``/tf_static`` are absolute, as tf2 listeners and RViz expect, with tf2's QoS; ``publish_tf``
false leaves them out. The odometry is the true state; its covariances are those of the simulated sensors
that would stand for it (messages.odometry_covariances), zero with ``noise`` false.

Ground and crashes (simulation/vehicle.py): the ground holds a vehicle resting on it; a touchdown too fast
or too tilted is a crash: the vehicle lies where it fell, rotors stopped, commands ignored, until
``~/reset``. Each vehicle's ``crashed`` (std_msgs/Bool, transient local: a late subscriber gets it) is
false from the start, true at a crash, and the node logs one error line saying how it hit the ground.

Reset: ``~/reset`` puts every vehicle back in its initial state (pose, at rest, rotors stopped, crash
cleared; faults stay as their parameters say). Simulated time runs on, since clocks and tf never go back;
each vehicle's ``simulation_reset`` (nodes/reset.py) tells its controller and identifier to start over.

Pacing (simulation/pacing.py), the clock and stamps (issue 10):

- ``real_time_factor`` 0 with ``publish_clock`` (the default of the launch file, ``make demo`` and the
  tests): lockstep. Simulated time runs one ``control_period_s`` past the newest command's stamp and then
  waits, however long, for the command of the next period: the same commands give the same flight on an
  idle or a busy machine. The command watchdog counts simulated time. While it waits the simulator
  resends its newest odometry and clock every ``RESEND_PERIOD_S`` of wall time (a controller that starts
  or restarts then gets a state and a tick), says once at INFO that it waits for a first controller, and
  warns (every ``STALL_REPEAT_S``) when a controller that was commanding has been silent for
  ``STALL_WARNING_S`` of wall time, naming the input and its publishers. ``control_period_s`` 0 runs as
  fast as possible without waiting for anyone.
  Followers: nodes named in ``lockstep_followers`` (topics of std_msgs/Header under each vehicle's
  namespace; by default the identifier's ``identifier/progress``) say up to which stamp they have handled
  their inputs, and simulated time also waits for them: at most the period of the slowest state topic
  (odom, imu, pose, motor_speeds) past the slowest one's word. So an identifier's verdict on the state of
  t reaches the controller within that period of simulated time in every run, however busy the host
  (a hexarotor losing a rotor has no margin for a verdict that comes late). A follower counts from the
  first word heard; one silent for ``FOLLOWER_RELEASE_S`` of wall time while simulated time waits for it
  is let go with a warning, and joins again when heard: a stopped identifier does not stop the flight.
  With ``lockstep_follower_start_wait_s`` > 0 every follower is waited for from the start: simulated time
  stays at 0 (its state resent) until each has been heard, for at most that much wall time each, so that
  a recorder whose subscription discovery matches late still gets the whole flight.
- ``real_time_factor`` r > 0: r x wall time. A control period is late when the command computed for it
  (stamped at its start) is not in force before the physics passes its end; the achieved real-time factor
  and late periods are published every second on ``pacing`` and a throttled warning says when the host
  cannot keep up. A period whose commands have all come (every vehicle's, stamped at its start) is
  integrated at once, as lockstep does, and its readings are published at once, up to one publish period
  (and a physics step) before their wall time, with the clock of their instant: the physics is the same,
  and a controller that answers quickly gets the next state early and has the rest of that period and
  all of the next to answer it, not only what is left of one period after the state's way to it. With
  no command in hand the physics follows the wall clock. As in lockstep, the first command of a
  ``control_period_s`` flies the whole of it. Without ``publish_clock`` (only at r = 1) stamps follow
  the wall clock, up to that period ahead: when the physics falls behind, the stamps jump forward with
  the wall clock rather than drifting behind it.
- Stamps are simulated time when ``publish_clock`` is set. The clock goes on ``/clock`` whatever the
  node's namespace: a graph has one time. A simulator that hears another clock in its first
  ``CLOCK_CHECK_S`` refuses to run (status 2) before publishing anything, naming the publishers; while
  the graph lists another clock publisher not heard yet, or lists no other node at all (discovery not
  done: seen on a loaded machine after 2 s), it listens on, up to ``CLOCK_CHECK_MAX_S`` and
  ``LONE_CHECK_S``. Discovery can take longer than that on a loaded machine, and two simulators started
  together both pass the check; so each one that publishes the clock also claims it on ``/clock_claim``
  (nodes/clock.py ``ClockClaim``, transient local), and the one whose claim came second stops with
  status 2 as soon as it hears the first one's, naming it: one clock in the graph whenever discovery
  completes.
  Several vehicles share one simulator node and its clock.
- ``pacing`` (diagnostic_msgs/DiagnosticArray, 1 Hz wall): one status ``simulator pacing`` with the
  target and achieved real-time factors, control periods on time and late, commands, lockstep waits.

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
from collections.abc import Sequence
from dataclasses import dataclass, fields
from functools import partial
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, Range
from std_msgs.msg import Bool, Header
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.bundle import (
    BUNDLE_TYPE,
    FLEET_COMMAND_TOPIC,
    FLEET_ODOM_TOPIC,
    OdometryBundleWriter,
    bundle_entries,
)
from multirotor_ros.nodes.cdr import OdometryWriter, joint_state_fields_from_cdr
from multirotor_ros.nodes.clock import CLOCK_QOS, GRAPH_CLOCK_TOPIC, ClockClaim, steady_clock
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.listeners import ListenerGate, StateTopic
from multirotor_ros.nodes.messages import (
    LATCHED_QOS,
    joint_state_from_rotor_speeds,
    odometry_covariances,
    odometry_message,
    odometry_values_of_state,
    pose_message,
    rotor_names,
    rotor_speeds_from_parts,
    simulated_imu_message,
    stamp_from_ns,
    stamp_to_ns,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.nodes.reset import RESET_SERVICE, SIMULATION_RESET_QOS, SIMULATION_RESET_TOPIC
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.nodes.vehicles import VehicleSpec, parse_vehicles
from multirotor_ros.nodes.visual_messages import rotor_transforms, transform_from_odometry
from multirotor_ros.plausibility import StampGate
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation.pacing import NS_PER_S, AchievedRate, ControlTiming, Lockstep, RealTimePacer
from multirotor_ros.simulation.sensors import SensorConfig, airframe_sensor_config
from multirotor_ros.simulation.vehicle import (
    CRASH_SPEED_M_S,
    CRASH_TILT_RAD,
    OVERSIZED_SPEED_FACTOR,
    Reading,
    VehicleSimulator,
    period_ns,
    vehicle_generators,
)

# Wall time a free-running (real_time_factor 0, no lockstep) simulator computes before serving callbacks.
FREE_RUN_SLICE_S = 0.005
# Wall time to discover other clock publishers before this simulator publishes its own (discovery on a
# loaded machine was seen to take over a second).
CLOCK_CHECK_S = 2.0
# How long a listed but silent clock publisher is waited for: on a loaded machine the graph listed the
# other simulator 2 s after start while its samples had not come through yet. One listed but silent for
# this long has stopped (discovery forgets a stopped node late) and does not keep this one from starting.
CLOCK_CHECK_MAX_S = 15.0
# What the graph gives as the name of a node that discovery has not fully seen yet (rmw_dds_common).
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"
# How long a simulator that sees no other node in the graph waits for discovery before it concludes it is
# alone: a second simulator under CI load had neither heard nor listed the first after 2 s.
LONE_CHECK_S = 4.0
ONE_CLOCK_ADVICE = (
    "Fly several vehicles in one simulator node (parameter vehicles), or give each simulator a "
    "ROS_DOMAIN_ID of its own"
)
# While lockstep waits: resend the newest state this often; warn about a silent controller after
# STALL_WARNING_S and again every STALL_REPEAT_S (wall time).
RESEND_PERIOD_S = 0.25
STALL_WARNING_S = 2.0
STALL_REPEAT_S = 10.0
# Wall time a silent lockstep follower is waited for before the flight goes on without it.
FOLLOWER_RELEASE_S = 1.0
# The pacing status goes out this often (wall time); in real time a second in which the achieved factor is
# below SLOW_FACTOR_SHARE of the target or more than LATE_PERIOD_SHARE of the control periods were late
# raises a warning, repeated at most every SLOW_WARNING_REPEAT_S.
STATUS_PERIOD_S = 1.0
SLOW_FACTOR_SHARE = 0.95
LATE_PERIOD_SHARE = 0.01
SLOW_WARNING_REPEAT_S = 10.0
# Queue depth of the state topics (odom, motor_speeds): about 0.2 s at 250 Hz.
STATE_QUEUE_DEPTH = 50
# tf2's own QoS (tf2_ros DynamicBroadcasterQoS and StaticBroadcasterQoS): what its listeners and RViz match.
TF_QOS = QoSProfile(depth=100)
TF_STATIC_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def simulator_parameters(
    n_rotors: int, vehicles: Sequence[VehicleSpec] = (VehicleSpec(""),)
) -> list[NodeParameter]:
    """The simulator's own parameters (the ``sensors.*`` ones come from the airframe's YAML).

    Fault injection is per vehicle: ``fault_motor`` of the one unnamed vehicle, ``NAME.fault_motor`` of a
    vehicle of the ``vehicles`` list (and the same for ``fault_effectiveness`` and ``faults``).
    """
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
            "control_period_s",
            0.004,
            "the controllers' period (1 / their rate_hz): in lockstep (real_time_factor 0, publish_clock) "
            "simulated time runs this far past the newest command and waits for the next; in real time a "
            "period whose command comes later is counted late; 0 = as fast as possible without lockstep",
            "s",
            0.0,
            1.0,
            read_only=True,
        ),
        NodeParameter(
            "lockstep_followers",
            "identifier/progress",
            "in lockstep, also wait for these nodes' progress (std_msgs/Header topics under each vehicle's "
            "namespace, comma-separated; '' = none): a follower counts once heard",
            read_only=True,
        ),
        NodeParameter(
            "lockstep_follower_start_wait_s",
            0.0,
            "in lockstep, simulated time stays at 0 until every follower has been heard, for at most this "
            "long of wall time each (a recorder that must see the whole flight); 0 = a follower counts "
            "once heard",
            "s",
            0.0,
            3600.0,
            read_only=True,
        ),
        NodeParameter(
            "command_timeout_s",
            0.5,
            "without a motor command for this long of simulated time the rotors stop (0 = never)",
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
            "crash_speed_m_s",
            CRASH_SPEED_M_S,
            "a touchdown sinking faster than this is a crash (simulation/vehicle.py gives the reason)",
            "m/s",
            0.1,
            1000.0,
            read_only=True,
        ),
        NodeParameter(
            "crash_tilt_rad",
            CRASH_TILT_RAD,
            "a touchdown tilted more than this is a crash; pi = never by tilt",
            "rad",
            0.05,
            math.pi,
            read_only=True,
        ),
        NodeParameter(
            "publish_tf",
            True,
            "broadcast odom -> base_link on /tf with every odometry, base_link -> rotor_k on /tf_static",
            read_only=True,
        ),
        *(fault for vehicle in vehicles for fault in fault_parameters(vehicle, n_rotors)),
    ]


def fault_parameters(vehicle: VehicleSpec, n_rotors: int) -> list[NodeParameter]:
    """``[NAME.]fault_motor``, ``[NAME.]fault_effectiveness`` and ``[NAME.]faults`` of one vehicle."""
    prefix = f"{vehicle.name}." if vehicle.name else ""
    return [
        NodeParameter(
            prefix + "fault_motor",
            0,
            "rotor given fault_effectiveness from now on; 0 = no fault",
            "-",
            0,
            n_rotors,
        ),
        NodeParameter(
            prefix + "fault_effectiveness",
            0.0,
            "share of its thrust the faulty rotor gives; 0 = it stops",
            "-",
            0.0,
            1.0,
        ),
        NodeParameter(
            prefix + "faults",
            "",
            "several rotor faults, 'MOTOR:EFFECTIVENESS' comma-separated (e.g. '3:0, 6:0.5'): those already "
            "in force keep their onset, the others begin now ('' = none); replaces fault_motor's, and "
            "fault_motor replaces these",
        ),
    ]


def parse_faults(text: str, n_rotors: int) -> list[tuple[int, float]]:
    """The (motor, effectiveness) pairs of a ``faults`` parameter; ValueError naming the bad entry."""
    faults = []
    for entry in (e.strip() for e in text.split(",")):
        if not entry:
            continue
        motor_text, colon, effectiveness_text = entry.partition(":")
        try:
            motor, effectiveness = int(motor_text), float(effectiveness_text)
        except ValueError:
            motor, effectiveness = 0, math.nan
        if not colon or not 1 <= motor <= n_rotors or not 0.0 <= effectiveness <= 1.0:
            raise ValueError(
                f"faults: {entry[:40]!r} is not MOTOR:EFFECTIVENESS with MOTOR in 1..{n_rotors} and "
                "EFFECTIVENESS in [0, 1]"
            )
        faults.append((motor, effectiveness))
    motors = [motor for motor, _ in faults]
    if len(set(motors)) != len(motors):
        raise ValueError(f"faults: one fault per motor, got motors {motors}")
    return faults


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


@dataclass
class _Stall:
    """A lockstep wait warned about: the simulated time it stands at, the wall time of the last warning."""

    at_ns: int
    warned_at_s: float


class _VehicleTopics:
    """One vehicle's side of the node: its topics, frames, command checks and counters."""

    def __init__(self, node: SimulatorNode, index: int, spec: VehicleSpec, frame_prefix: str, clock_on: bool):
        self.index = index
        self.spec = spec
        prefix = spec.prefix
        self.frames = (frame_prefix + prefix + "odom", frame_prefix + prefix + "base_link")
        self.fault_parameters = tuple(
            (f"{spec.name}." if spec.name else "") + name
            for name in ("fault_motor", "fault_effectiveness", "faults")
        )
        publish_period_s = node.publish_period_ns / NS_PER_S
        self.command_gate = StampGate(future_tolerance_s=publish_period_s) if clock_on else StampGate()
        self.refusals = RefusalCounter(node.get_logger().warning, prefix + "motor_speed_cmd")
        self.unstamped_commands = 0
        # Each state topic keeps its newest message, sent again while lockstep waits (_resend_state), and
        # publishes only while somebody listens (nodes/listeners.py).
        self.topics = {
            kind: StateTopic(node.create_publisher(message_type, prefix + kind, qos))
            for kind, message_type, qos in (
                # Deep queues: a subscriber busy for a moment (the identifier refitting) gets the backlog.
                ("odom", Odometry, STATE_QUEUE_DEPTH),
                ("imu", Imu, qos_profile_sensor_data),
                ("pose", PoseStamped, qos_profile_sensor_data),
                ("range", Range, qos_profile_sensor_data),
                ("motor_speeds", JointState, STATE_QUEUE_DEPTH),
            )
        }
        # The message /tf's transform is filled from (SimulatorNode._odometry_message), and odom is written
        # serialised from (nodes/cdr.py): the vehicle's frames, covariances fixed by the sensor model.
        self.odometry = Odometry()
        self.odometry.header.frame_id, self.odometry.child_frame_id = self.frames
        covariances = odometry_covariances(node.sim.sensor_config)
        self.odometry.pose.covariance, self.odometry.twist.covariance = covariances
        self.odometry_writer = OdometryWriter(self.odometry)
        self.faults = node.create_publisher(DiagnosticArray, prefix + "injected_faults", LATCHED_QOS)
        self.resets = node.create_publisher(Header, prefix + SIMULATION_RESET_TOPIC, SIMULATION_RESET_QOS)
        self.crashed = node.create_publisher(Bool, prefix + "crashed", LATCHED_QOS)
        self.commands = subscribe(
            node, JointState, prefix + "motor_speed_cmd", partial(node.on_command, self), 10, raw=True
        )
        self.follower_names = [node.resolve_topic_name(prefix + topic) for topic in node.follower_topics]
        self.followers = [
            subscribe(node, Header, name, partial(node.on_follower, name), 10) for name in self.follower_names
        ]


class SimulatorNode(Node):
    """The simulated vehicles as a ROS node; see the module docstring."""

    def __init__(self, **kwargs: Any):
        super().__init__("simulator", **kwargs)
        name = self.declare_parameter(
            "airframe",
            "x8_octorotor",
            NodeParameter("airframe", "", "airframe config name or YAML path", read_only=True).descriptor(),
        ).value
        listed = self.declare_parameter(
            "vehicles",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY,
                description="several vehicles in this node: 'NAME [X Y Z [YAW]]' each (nodes/vehicles.py); "
                "unset = one vehicle, its topics in the node's namespace, posed by initial_*",
                read_only=True,
            ),
        ).value
        self.airframe = load_airframe(name)
        n = self.airframe.n_rotors
        specs_of_vehicles = parse_vehicles(listed or [])
        specs = simulator_parameters(n, specs_of_vehicles or [VehicleSpec("")]) + sensor_parameters(
            airframe_sensor_config(self.airframe)
        )
        self._specs = {spec.name: spec for spec in specs}
        p = declare_parameters(self, specs)
        rate, clock_on = p["real_time_factor"], p["publish_clock"]
        if rate != 1.0 and not clock_on:
            raise ValueError(
                f"real_time_factor {rate:g} needs publish_clock:=true (and use_sim_time:=true on the other "
                "nodes): without a clock the stamps could follow neither the wall clock nor simulated time"
            )
        vehicles = specs_of_vehicles or [
            VehicleSpec("", (p["initial_x"], p["initial_y"], p["initial_z"]), p["initial_yaw"])
        ]
        sensors = SensorConfig(**{f.name: p[f"sensors.{f.name}"] for f in fields(SensorConfig)})
        self.sim = VehicleSimulator(
            self.airframe,
            rng=vehicle_generators(p["seed"], len(vehicles))
            if specs_of_vehicles
            else np.random.default_rng(p["seed"]),
            physics_rate_hz=p["physics_rate_hz"],
            odom_rate_hz=p["publish_rate_hz"],
            motor_lag=p["motor_lag"],
            command_timeout_s=p["command_timeout_s"],
            sensors=sensors,
            noise=p["noise"],
            initial_position_m=[v.position_m for v in vehicles],
            initial_yaw_rad=[v.yaw_rad for v in vehicles],
            crash_speed_m_s=p["crash_speed_m_s"],
            crash_tilt_rad=p["crash_tilt_rad"],
        )
        self._params = p
        self._names = rotor_names(n)
        self.follower_topics = [t.strip() for t in p["lockstep_followers"].split(",") if t.strip()]
        self._speed_limit = OVERSIZED_SPEED_FACTOR * self.airframe.rotor_speed_max_rad_s
        self.publish_period_ns = period_ns(p["publish_rate_hz"])
        self.vehicles = [
            _VehicleTopics(self, k, spec, p["frame_prefix"], clock_on) for k, spec in enumerate(vehicles)
        ]
        for vehicle in self.vehicles:
            motor_name, effectiveness_name, faults_name = vehicle.fault_parameters
            if p[motor_name] and p[faults_name].strip():
                raise ValueError(f"set {motor_name} or {faults_name}, not both")
            if p[motor_name]:
                self.sim.inject_fault(p[motor_name], p[effectiveness_name], vehicle=vehicle.index)
            elif p[faults_name].strip():
                self.sim.inject_faults(parse_faults(p[faults_name], n), vehicle=vehicle.index)
        control_period_ns = round(p["control_period_s"] * NS_PER_S)
        # A follower's next input comes within the period of the slowest state topic.
        state_rates = (sensors.imu_rate_hz, sensors.pose_rate_hz, sensors.rotor_speed_rate_hz)
        slowest_state_ns = max(self.publish_period_ns, *(period_ns(rate) for rate in state_rates))
        self._lockstep = (
            Lockstep(control_period_ns, len(vehicles), slowest_state_ns, FOLLOWER_RELEASE_S)
            if rate == 0 and clock_on and control_period_ns
            else None
        )
        self._pacer = RealTimePacer(rate) if rate > 0 else None
        self._timing = [ControlTiming(control_period_ns or self.publish_period_ns) for _ in vehicles]
        self._achieved = AchievedRate(time.monotonic(), 0)
        self._periods_at_status = (0, 0)  # (on time, late) of all vehicles at the last status
        # Without a clock, stamps are the wall clock: simulated time + this offset, set by the pacing anchor.
        self._stamp_offset_ns = 0
        self._started = False
        self._stall: _Stall | None = None
        self.lockstep_stalls = 0
        self._last_resend_s = -math.inf
        self._last_slow_warning_s = -math.inf

        self._clock_pub = self.create_publisher(Clock, GRAPH_CLOCK_TOPIC, CLOCK_QOS) if clock_on else None
        # tf is absolute, as tf2 listeners expect; frame_prefix and the vehicle names keep vehicles apart.
        self._tf_listeners = (
            ListenerGate(self.create_publisher(TFMessage, "/tf", TF_QOS)) if p["publish_tf"] else None
        )
        self._clock_listeners = ListenerGate(self._clock_pub) if self._clock_pub is not None else None
        self._tf_static_pub = (
            self.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS) if p["publish_tf"] else None
        )
        self.create_service(Trigger, RESET_SERVICE, self._on_reset)
        self._pacing_pub = self.create_publisher(DiagnosticArray, "pacing", 10)
        # A fleet's bundles (nodes/bundle.py): every vehicle's odom in one message, commands likewise.
        self._fleet_odom: StateTopic | None = None
        if specs_of_vehicles:
            self._fleet_odom = StateTopic(self.create_publisher(BUNDLE_TYPE, FLEET_ODOM_TOPIC, 1))
            self._fleet_writer = OdometryBundleWriter([vehicle.odometry_writer for vehicle in self.vehicles])
            self._fleet_refusals = RefusalCounter(self.get_logger().warning, FLEET_COMMAND_TOPIC)
            subscribe(self, BUNDLE_TYPE, FLEET_COMMAND_TOPIC, self._on_fleet_command, 10, raw=True)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        wall = steady_clock()
        # The physics runs from a wall-clock timer: every publish period in real time, continuously when
        # free-running; in lockstep commands drive it and the timer watches for a silent controller.
        free_running = rate == 0 and self._lockstep is None
        self.create_timer(
            0.0 if free_running else self.publish_period_ns / NS_PER_S, self._on_timer, clock=wall
        )
        self.create_timer(1.0, self._publish_faults, clock=wall)
        self.create_timer(STATUS_PERIOD_S, self._publish_status, clock=wall)
        if clock_on:
            # Listen for another clock (discovery needs a moment) before publishing one.
            self._clock_heard = 0
            self._clock_listener = self.create_subscription(
                Clock, GRAPH_CLOCK_TOPIC, self._hear_clock, CLOCK_QOS
            )
            self._clock_claim: ClockClaim | None = ClockClaim(self, self._yield_the_clock)
            self._clock_watch_since_s = time.monotonic()
            self._clock_watch = self.create_timer(CLOCK_CHECK_S, self._watch_clocks, clock=wall)
        else:
            self._clock_claim = None
            self._start()
        self.get_logger().info(
            f"{self.airframe.name}: "
            + (
                f"{len(vehicles)} vehicles ({', '.join(v.name for v in vehicles)}) of "
                if specs_of_vehicles
                else ""
            )
            + f"{n} rotors, physics {p['physics_rate_hz']:g} Hz, real_time_factor {rate:g}"
            + (f", lockstep on control periods of {p['control_period_s']:g} s" if self._lockstep else "")
            + (f", publishing {GRAPH_CLOCK_TOPIC}" if clock_on else ", stamps on the wall clock")
        )

    # ------------------------------------------------------------------ start and the graph's clock

    def _start(self) -> None:
        self._started = True
        if self._clock_claim is not None:
            self._clock_claim.stake()
        if self._clock_pub is None:
            self._stamp_offset_ns = self.get_clock().now().nanoseconds
        self._achieved = AchievedRate(time.monotonic(), self.sim.t_ns)
        self._publish(self.sim.run_until(0))
        self._publish_faults()
        for vehicle in self.vehicles:
            vehicle.crashed.publish(Bool(data=False))
        if self._tf_static_pub is not None:
            stamp = stamp_from_ns(self.sim.t_ns + self._stamp_offset_ns)
            self._tf_static_pub.publish(
                TFMessage(
                    transforms=[
                        transform
                        for vehicle in self.vehicles
                        for transform in rotor_transforms(
                            self.airframe.rotor_positions_m, vehicle.frames[1], stamp
                        )
                    ]
                )
            )
        if self._lockstep is not None:
            start_wait_s = self._params["lockstep_follower_start_wait_s"]
            if start_wait_s > 0:
                now_s = time.monotonic()
                for name in (name for vehicle in self.vehicles for name in vehicle.follower_names):
                    self._lockstep.expect(name, now_s, start_wait_s)
            self._run_to(self._lockstep.limit_ns())

    def _hear_clock(self, _: Clock) -> None:
        self._clock_heard += 1

    def _publisher_names(self, topic: str) -> list[str]:
        return sorted(
            f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            for info in self.get_publishers_info_by_topic(topic)
        )

    def _alone_in_the_graph(self) -> bool:
        """Whether discovery has shown this node no other node yet."""
        mine = (self.get_name(), self.get_namespace())
        return all(node == mine for node in self.get_node_names_and_namespaces())

    def _watch_clocks(self) -> None:
        """Start, unless another node's clock was heard: then refuse to run (module docstring).

        Heard, not merely listed in the graph: a simulator that just stopped stays listed for a while
        (discovery forgets it late) but publishes nothing, and a restart must not be refused because of it.
        A listed publisher not heard yet is listened for until ``CLOCK_CHECK_MAX_S``; so is the name of
        one heard whose node discovery has not named yet (rmw lists it as ``_NODE_NAME_UNKNOWN_``). While
        the graph shows no other node at all, discovery may not have run yet: until ``LONE_CHECK_S``.
        """
        others = [
            name
            for name in self._publisher_names(GRAPH_CLOCK_TOPIC)
            if name != self.get_fully_qualified_name()
        ]
        assert self._clock_claim is not None
        claimants = list(self._clock_claim.heard)
        heard = self._clock_heard or claimants
        named = sorted({name for name in others if UNKNOWN_NODE_NAME not in name} | set(claimants))
        waited_s = time.monotonic() - self._clock_watch_since_s
        if not heard and not others and waited_s < LONE_CHECK_S and self._alone_in_the_graph():
            return  # checked again in CLOCK_CHECK_S
        waiting_for = (heard and not named) or (not heard and others)
        if waiting_for and waited_s < CLOCK_CHECK_MAX_S:
            return  # checked again in CLOCK_CHECK_S
        self._clock_watch.cancel()
        self.destroy_subscription(self._clock_listener)
        if heard:
            self.get_logger().error(
                f"another node already publishes {GRAPH_CLOCK_TOPIC} ({', '.join(named) or 'unknown'}): a "
                f"graph has one simulated time, so this simulator does not start. {ONE_CLOCK_ADVICE}"
            )
            raise SystemExit(2)
        self._start()

    def _yield_the_clock(self, claimant: str, earlier_by_s: float) -> None:
        """Another node claimed the clock before this one (nodes/clock.py ClockClaim): stop, status 2."""
        self.get_logger().error(
            f"{claimant} claimed {GRAPH_CLOCK_TOPIC} {earlier_by_s:.2f} s before this simulator (discovery "
            f"found it only now): a graph has one simulated time, so this simulator stops. {ONE_CLOCK_ADVICE}"
        )
        raise SystemExit(2)

    # ------------------------------------------------------------------ inputs

    def on_command(self, vehicle: _VehicleTopics, data: bytes) -> None:
        """A vehicle's ``motor_speed_cmd``: checked (module docstring), applied, and lockstep moved on.

        Taken serialised and read by nodes/cdr.py (rclpy's JointState object costs more than the rest).
        """
        if self._take_command(vehicle, data):
            self._move_on()

    def _on_fleet_command(self, data: bytes) -> None:
        """A bundle of commands (nodes/bundle.py): each taken as if on its vehicle's motor_speed_cmd.

        Simulated time moves on once, with all of them in force.
        """
        entries = bundle_entries(data, len(self.vehicles))
        if isinstance(entries, Refusal):
            self._fleet_refusals.refuse(entries.reason, entries.detail)
            return
        taken = [self._take_command(self.vehicles[index], command) for index, command in entries]
        if any(taken):
            self._move_on()

    def _take_command(self, vehicle: _VehicleTopics, data: bytes) -> bool:
        """A serialised command checked and applied; True if it was stamped (it may move time on)."""
        command = joint_state_fields_from_cdr(data)
        result = (
            command
            if isinstance(command, Refusal)
            else rotor_speeds_from_parts(
                command.names, command.velocity, command.stamp_ns, self.airframe.n_rotors, self._speed_limit
            )
        )
        if not isinstance(result, Refusal) and result.stamp_ns:
            result = vehicle.command_gate.check(result.stamp_ns, self._now_ns(), "motor_speed_cmd") or result
        if isinstance(result, Refusal):
            vehicle.refusals.refuse(result.reason, result.detail)
            return False
        self.sim.set_command(result.speeds_rad_s, vehicle=vehicle.index)
        if not result.stamp_ns:
            vehicle.unstamped_commands += 1
            self.get_logger().info(
                "motor_speed_cmd without a stamp: taken as of now (unstamped commands are counted)", once=True
            )
            return False
        stamp_ns = result.stamp_ns - self._stamp_offset_ns
        self._timing[vehicle.index].command(stamp_ns)
        if self._lockstep is not None and self._started:
            self._lockstep.command(stamp_ns, vehicle.index)
        return True

    def _move_on(self) -> None:
        """After stamped commands: lockstep runs as far as they allow, real time what they cover (ahead)."""
        if self._lockstep is not None and self._started:
            self._run_to(self._lockstep.limit_ns())
        elif self._pacer is not None and self._started:
            self._run_ahead()

    def _check_parameters(self, parameters: list[Any]) -> SetParametersResult:
        result = check_parameters(self._specs, parameters)
        for parameter in parameters:
            if result.successful and parameter.name.endswith("faults") and parameter.name in self._specs:
                try:
                    parse_faults(parameter.value, self.airframe.n_rotors)
                except ValueError as error:
                    result.successful, result.reason = False, str(error)
        return result

    def _apply_parameters(self, parameters: list[Any]) -> None:
        changed = {p.name: p.value for p in parameters}
        self._params.update(changed)
        for vehicle in self.vehicles:
            motor_name, effectiveness_name, faults_name = vehicle.fault_parameters
            if faults_name in changed:
                faults = parse_faults(self._params[faults_name], self.airframe.n_rotors)
            elif motor_name in changed or effectiveness_name in changed:
                motor = self._params[motor_name]
                faults = [(motor, float(self._params[effectiveness_name]))] if motor else []
            else:
                continue
            self.sim.inject_faults(faults, vehicle=vehicle.index)
            self.get_logger().warning(
                f"fault injected at t = {self.sim.t_s:.3f} s: "
                + ", ".join(f"{vehicle.spec.prefix}rotor {m} effectiveness {e:g}" for m, e in faults)
                if faults
                else f"{vehicle.spec.prefix}fault cleared"
            )
            self._publish_faults()
        if "command_timeout_s" in changed:
            self.sim.command_timeout_ns = round(float(changed["command_timeout_s"]) * NS_PER_S)

    def _on_reset(self, _: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """``~/reset``: every vehicle back to its initial state; simulated time runs on (it never goes back).

        Each vehicle's ``simulation_reset`` tells its controller and identifier to start over too.
        """
        self.sim.reset()
        stamp = stamp_from_ns(self.sim.t_ns + self._stamp_offset_ns)
        states = list(self.sim.x.copy())  # each vehicle's, for its odom and the fleet's bundle
        for vehicle in self.vehicles:
            vehicle.crashed.publish(Bool(data=False))
            vehicle.resets.publish(Header(stamp=stamp, frame_id=vehicle.frames[0]))
            # The state it starts over from, at once: a lockstep controller computes its next command on it
            # (and the simulator resends it while it waits, whichever of the two topics arrives first).
            self._publish_odometry(vehicle, states[vehicle.index], stamp)
        self._publish_fleet_odometry(stamp, states)
        response.success = True
        response.message = f"reset at t = {self.sim.t_s:.3f} s: vehicles at their initial state"
        self.get_logger().info(response.message)
        return response

    # ------------------------------------------------------------------ time

    def on_follower(self, topic: str, message: Header) -> None:
        """A lockstep follower's progress: it has handled its inputs up to the stamp (module docstring)."""
        if self._lockstep is None or not self._started:
            return
        # No follower has handled what is not published yet: a stamp ahead is taken as now.
        handled_ns = min(stamp_to_ns(message.stamp), self.sim.t_ns)
        if self._lockstep.follower(topic, handled_ns, time.monotonic()):
            self.get_logger().info(f"lockstep: simulated time also waits for {topic} (a follower)")
        self._run_to(self._lockstep.limit_ns())

    def _now_ns(self) -> int:
        """This node's clock: the simulated time it publishes, or else its ROS clock."""
        if self._clock_pub is not None:
            return self.sim.t_ns
        return self.get_clock().now().nanoseconds

    def _on_timer(self) -> None:
        if not self._started:
            return
        if self._lockstep is not None:
            self._watch_lockstep()
        elif self._pacer is not None:
            behind = self._pacer.fell_behind
            target = self._pacer.target(time.monotonic_ns(), self.sim.t_ns)
            if self._pacer.fell_behind != behind and self._clock_pub is None:
                # The simulation slows down; the stamps stay on the wall clock (a gap, not a drift).
                self._stamp_offset_ns = self.get_clock().now().nanoseconds - target
            self._run_to(target)
            self._run_ahead()
        else:
            # As fast as possible: several publish periods per tick (each executor round costs about as
            # much as a period of physics), then back to the executor for commands and parameters.
            deadline = time.perf_counter() + FREE_RUN_SLICE_S
            while time.perf_counter() <= deadline:
                self._run_to(self.sim.t_ns + self.publish_period_ns)

    def _run_to(self, t_ns: int) -> None:
        """The physics up to ``t_ns`` (whole steps, at least up to it); its readings published at once."""
        if t_ns > self.sim.t_ns:
            readings = self.sim.run_until(t_ns)
            for timing in self._timing:
                timing.physics_at(self.sim.t_ns)
            self._publish(readings)
        if self._lockstep is not None:
            self._lockstep.reached(self.sim.t_ns, time.monotonic())

    def _run_ahead(self) -> None:
        """In real time, what the commands in hand cover: integrated and published now, up to a period early.

        The physics of a control period is the same whenever it is computed once its commands are in
        force (lockstep's); run as soon as they are, the state after it goes out up to one publish period
        before its wall time, and a controller has the rest of this period and all of the next to answer
        it. Never more than one publish period ahead of the wall clock, never past what the commands of
        every vehicle cover.
        """
        assert self._pacer is not None
        newest = [timing.newest_command_ns for timing in self._timing]
        now_ns = self._pacer.now_ns(time.monotonic_ns())
        if now_ns is None or any(stamp_ns is None for stamp_ns in newest):
            return
        covered_ns = min(stamp_ns for stamp_ns in newest if stamp_ns is not None) + self._timing[0].period_ns
        self._run_to(min(covered_ns, now_ns + self.publish_period_ns))

    def _watch_lockstep(self) -> None:
        """Resend the state while simulated time waits; say when a controller is missing or went silent."""
        assert self._lockstep is not None
        now_s = time.monotonic()
        waited_s = self._lockstep.waiting_s(now_s)
        for topic, last_word_ns in self._lockstep.release_silent(now_s):
            silence = (
                f"not heard in the {self._params['lockstep_follower_start_wait_s']:g} s of wall time "
                f"lockstep_follower_start_wait_s gives it (t = {self.sim.t_s:.3f} s)"
                if last_word_ns is None
                else f"silent for {FOLLOWER_RELEASE_S:g} s of wall time at t = {self.sim.t_s:.3f} s "
                f"(its last word: {last_word_ns / NS_PER_S:.3f} s)"
            )
            self.get_logger().warning(
                f"lockstep: {topic} {silence}: simulated time goes on without that follower until it is "
                "heard again"
            )
        if self._stall is not None and self._stall.at_ns != self.sim.t_ns:
            self.get_logger().info(
                f"lockstep resumed at t = {self._stall.at_ns / NS_PER_S:.3f} s: motor_speed_cmd is back"
            )
            self._stall = None
        if waited_s > RESEND_PERIOD_S and now_s - self._last_resend_s > RESEND_PERIOD_S:
            self._last_resend_s = now_s
            self._resend_state()
        if waited_s < STALL_WARNING_S or not self._lockstep.waiting_for_commands():
            return
        if self._lockstep.commands == 0:
            self.get_logger().info(
                f"lockstep: simulated time waits at {self.sim.t_s:.3f} s for the first motor_speed_cmd "
                f"(from a controller with use_sim_time:=true and rate 1 / control_period_s = "
                f"{NS_PER_S / self._lockstep.period_ns:g} Hz)",
                once=True,
            )
            return
        if self._stall is not None and now_s - self._stall.warned_at_s < STALL_REPEAT_S:
            return
        if self._stall is None:
            self.lockstep_stalls += 1
        self._stall = _Stall(at_ns=self.sim.t_ns, warned_at_s=now_s)
        silent = [self.vehicles[k] for k in self._lockstep.behind()]
        newest_s = self._lockstep.newest_command_ns[silent[0].index] / NS_PER_S
        topics = "; ".join(
            f"{vehicle.commands.topic_name} (publishers: "
            f"{', '.join(self._publisher_names(vehicle.commands.topic_name)) or 'none'})"
            for vehicle in silent
        )
        self.get_logger().warning(
            f"lockstep: simulated time has stood at {self.sim.t_s:.3f} s for {waited_s:.1f} s of wall time: "
            f"motor_speed_cmd went silent after the command stamped {newest_s:.3f} s on {topics}; "
            "waiting for it"
        )

    # ------------------------------------------------------------------ outputs

    def _publish(self, readings: list[Reading]) -> None:
        odometries: list[Any] = []  # the vehicles' states of the instant whose odom is being published
        for reading in readings:
            vehicle = self.vehicles[reading.vehicle]
            stamp = stamp_from_ns(reading.t_ns + self._stamp_offset_ns)
            kind, data = reading.kind, reading.data
            if kind == "odom":
                self._publish_odometry(vehicle, data, stamp)
                odometries.append(data)
                # The bundle and one clock for all vehicles: after the last one's state of this time.
                if reading.vehicle == len(self.vehicles) - 1:
                    self._publish_fleet_odometry(stamp, odometries)
                    odometries = []
                    if self._clock_listeners is not None and self._clock_listeners.heard():
                        self._clock_listeners.publisher.publish(Clock(clock=stamp))
            elif kind == "imu":
                vehicle.topics["imu"].send(
                    partial(simulated_imu_message, stamp, vehicle.frames[1], data, self.sim.sensor_config)
                )
            elif kind == "pose":
                vehicle.topics["pose"].send(partial(pose_message, stamp, vehicle.frames[0], *data))
            elif kind == "range":
                vehicle.topics["range"].send(partial(self._range_message, stamp, vehicle.frames[1], data))
            elif kind == "motor_speeds":
                vehicle.topics["motor_speeds"].send(partial(joint_state_from_rotor_speeds, data, stamp))
            elif kind == "crash":
                vehicle.crashed.publish(Bool(data=True))
                which = f"{vehicle.spec.name}: " if vehicle.spec.name else ""
                self.get_logger().error(
                    f"{which}crashed at t = {reading.t_ns / NS_PER_S:.2f} s: {data.describe()}; "
                    "it stays down until ~/reset"
                )
            elif kind == "watchdog":
                which = f" ({vehicle.spec.name})" if vehicle.spec.name else ""
                self.get_logger().warning(
                    f"no motor command for {data:.2f} s of simulated time{which}: rotors stopped"
                )

    def _publish_odometry(self, vehicle: _VehicleTopics, state: Any, stamp: Any) -> None:
        """A vehicle's odom, with its covariances, and its transform on /tf (``state``: not changed later)."""
        vehicle.topics["odom"].send(partial(self._serialised_odometry, vehicle, state, stamp))
        if self._tf_listeners is not None and self._tf_listeners.heard():
            odometry = self._odometry_message(vehicle, state, stamp)
            self._tf_listeners.publisher.publish(TFMessage(transforms=[transform_from_odometry(odometry)]))

    def _publish_fleet_odometry(self, stamp: Any, states: list[Any]) -> None:
        """Every vehicle's odom of one instant in one bundle (``states``: not changed later)."""
        if self._fleet_odom is not None:
            self._fleet_odom.send(partial(self._fleet_writer.write, stamp, states))

    def _serialised_odometry(self, vehicle: _VehicleTopics, state: Any, stamp: Any) -> bytes:
        # Published as it is: rclpy's conversion and serialisation of an Odometry cost more than the rest
        # of a state's publishing (nodes/cdr.py).
        return vehicle.odometry_writer.write(stamp, odometry_values_of_state(state))

    def _odometry_message(self, vehicle: _VehicleTopics, state: Any, stamp: Any) -> Odometry:
        # Filled in place (a new Odometry costs more than its fields): what it held was published already.
        return odometry_message(state, stamp, *vehicle.frames, out=vehicle.odometry)

    def _resend_state(self) -> None:
        """The newest state messages and clock again (same stamps).

        For a controller that is starting, and for a follower that lost one (imu and pose are best
        effort): without it the follower's word could not pass that stamp, and the wait would last until
        the follower is let go.
        """
        for vehicle in self.vehicles:
            for topic in vehicle.topics.values():
                topic.resend()
        if self._fleet_odom is not None:
            self._fleet_odom.resend()
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=stamp_from_ns(self.sim.t_ns)))

    def _range_message(self, stamp: Any, frame_id: str, distance: float) -> Range:
        c = self.sim.sensor_config
        message = Range()
        message.header.stamp = stamp
        message.header.frame_id = frame_id
        message.radiation_type = Range.ULTRASOUND
        message.field_of_view = 2.0 * c.range_max_tilt_rad
        message.min_range = c.range_min_m
        message.max_range = c.range_max_m
        message.range = distance
        return message

    def _publish_status(self) -> None:
        """The ``pacing`` status; a throttled warning when the host cannot keep up with real time."""
        if not self._started:
            return
        now_s = time.monotonic()
        recent, overall = self._achieved.take(now_s, self.sim.t_ns)
        on_time_total = sum(t.on_time for t in self._timing)
        late_total = sum(t.late for t in self._timing)
        late = late_total - self._periods_at_status[1]
        periods = late + on_time_total - self._periods_at_status[0]
        self._periods_at_status = (on_time_total, late_total)
        target = self._params["real_time_factor"]
        slow = self._pacer is not None and (
            recent < SLOW_FACTOR_SHARE * target or late > LATE_PERIOD_SHARE * max(periods, 1)
        )
        if slow and now_s - self._last_slow_warning_s > SLOW_WARNING_REPEAT_S:
            self._last_slow_warning_s = now_s
            self.get_logger().warning(
                f"the host cannot keep up with real_time_factor {target:g}: achieved {recent:.2f} over the "
                f"last {STATUS_PERIOD_S:g} s, {late} of {periods} control periods late (their command came "
                f"after the period ended; {late_total} late since the start); see the pacing topic"
            )
        waiting_s = 0.0 if self._lockstep is None else self._lockstep.waiting_s(now_s)
        values = {
            "target_real_time_factor": f"{target:g}",
            "achieved_real_time_factor": f"{recent:.3f}",
            "achieved_real_time_factor_since_start": f"{overall:.3f}",
            "simulated_time_s": f"{self.sim.t_s:.3f}",
            "vehicles": str(len(self.vehicles)),
            "control_periods_on_time": str(on_time_total),
            "control_periods_late": str(late_total),
            "physics_fell_behind": str(0 if self._pacer is None else self._pacer.fell_behind),
            "lockstep_waiting_s": f"{waiting_s:.3f}",
            "lockstep_stalls": str(self.lockstep_stalls),
            "unstamped_commands": str(sum(v.unstamped_commands for v in self.vehicles)),
            "refused_commands": str(sum(v.refusals.total for v in self.vehicles)),
        }
        if self._stall is not None:
            level, text = DiagnosticStatus.WARN, f"lockstep waiting {waiting_s:.1f} s for motor_speed_cmd"
        elif slow:
            level, text = (
                DiagnosticStatus.WARN,
                f"behind real time: {recent:.2f} of {target:g}, {late} late periods",
            )
        else:
            mode = "keeping up" if self._pacer else "lockstep" if self._lockstep else "free-running"
            level, text = DiagnosticStatus.OK, mode
        message = DiagnosticArray()
        message.header.stamp = stamp_from_ns(self.sim.t_ns + self._stamp_offset_ns)
        message.status.append(
            DiagnosticStatus(
                level=level,
                name="simulator pacing",
                message=text,
                hardware_id=self.get_fully_qualified_name(),
                values=[KeyValue(key=key, value=value) for key, value in values.items()],
            )
        )
        self._pacing_pub.publish(message)

    def _publish_faults(self) -> None:
        for vehicle in self.vehicles:
            message = DiagnosticArray()
            message.header.stamp = stamp_from_ns(self.sim.t_ns + self._stamp_offset_ns)
            applied = self.sim.injected_effectiveness(vehicle=vehicle.index)
            for name, effectiveness in zip(self._names, applied, strict=True):
                level = (
                    DiagnosticStatus.OK
                    if effectiveness == 1.0
                    else (DiagnosticStatus.ERROR if effectiveness == 0.0 else DiagnosticStatus.WARN)
                )
                text = (
                    "healthy"
                    if effectiveness == 1.0
                    else f"injected fault: {effectiveness:.0%} of its thrust"
                )
                message.status.append(
                    DiagnosticStatus(
                        level=level,
                        name=name,
                        message=text,
                        hardware_id=self.get_fully_qualified_name()
                        + (f"/{vehicle.spec.name}" if vehicle.spec.name else ""),
                        values=[KeyValue(key="effectiveness", value=f"{effectiveness:g}")],
                    )
                )
            vehicle.faults.publish(message)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros simulator`` and ``multirotor node simulator``."""
    return run_node(SimulatorNode, args)
