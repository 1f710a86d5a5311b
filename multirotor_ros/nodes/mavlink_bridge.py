"""ROS 2 node ``mavlink_bridge``: the ROS side of :mod:`multirotor_ros.mavlink`.

Connects the graph to a flight stack (PX4 SITL over TCP 4560, ArduPilot SITL over UDP 9002) and to a
ground station (UDP, 127.0.0.1:14550 by default). The MAVLink work runs in a thread of its own
(:class:`~multirotor_ros.mavlink.bridge.MavlinkBridge`); the executor only serves subscriptions and
parameters. Which side owns the physics, and why, is described in :mod:`multirotor_ros.mavlink`:

- ``internal_physics: true`` (default): the node steps its own vehicle in lockstep with the flight
  stack (each frame by exactly its Δt, :mod:`multirotor_ros.mavlink.physics`) and publishes, on simulated
  time, after each answer once no frame waits (:meth:`~multirotor_ros.mavlink.bridge.MavlinkBridge.defer`:
  an odom message costs more than SITL's own frame), ``odom`` and ``motor_speed_cmd`` (at
  ``publish_rate_hz``), ``imu`` (readings the flight stack got, at the airframe's
  ``sensors.imu_rate_hz``), ``motor_speeds`` (the ESC rate of the airframe's sensors) and, with
  ``publish_clock``, ``clock`` (with each odom). A topic nobody subscribes to is neither filled nor
  published (:mod:`multirotor_ros.nodes.listeners`; ``crashed``, latched, always is). ``fault_motor`` and
  ``fault_effectiveness`` (settable at run time, as on the simulator node) inject a rotor fault into it.
  The ground and the crash latch are the simulator's: ``crashed`` (std_msgs/Bool, transient local) turns
  true at a crash, with one error line, and false again when the flight stack restarts the vehicle.
- ``internal_physics: false``: subscribes ``odom``, ``imu`` and ``motor_speeds`` of a simulator node and
  forwards them. ``flight_stack: none`` (ground station only) requires this mode.

The flight stack's outputs reach the rotors through ``rotor_channels``: empty, the map is derived from
the airframe's rotor geometry and the flight stack's published motor numbering; given, it is checked
against it and refused with the reason if a rotor would push the wrong way
(:mod:`multirotor_ros.mavlink.motor_order`). The log says which frame and map are in use.

Always: ``motor_speed_cmd`` (flight-stack actuator outputs through the motor map) and ``setpoint``
(SET_POSITION_TARGET_LOCAL_NED from the ground station, world ENU). Refused input, on any link or
topic, is counted per reason and logged once per reason, then in throttled summaries. The forwarded
topics are checked before use: finite and physically plausible
(:class:`~multirotor_ros.plausibility.StateLimits`), and ``odom`` and ``imu`` stamped no later than this
node's clock allows and not before the newest accepted stamp (:class:`~multirotor_ros.plausibility.StampGate`:
a far-future stamp must not become the flight stack's time).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy._rclpy_pybind11 import RCLError
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import DEFAULT_PORT as ARDUPILOT_PORT
from multirotor_ros.mavlink.ardupilot import MAX_BUSY_WAIT_S, ArduPilotConfig
from multirotor_ros.mavlink.bridge import (
    FLIGHT_STACKS,
    BridgeConfig,
    BridgeOutputs,
    BridgeThread,
    MavlinkBridge,
)
from multirotor_ros.mavlink.gcs import MAX_PEERS_LIMIT, GroundStationConfig, Setpoint
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.px4 import DEFAULT_PORT as PX4_PORT
from multirotor_ros.mavlink.px4 import Px4Config
from multirotor_ros.mavlink.sensors import Home
from multirotor_ros.mavlink.signing import SigningPolicy, parse_signing_key
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import FloatArray, euler_to_quat
from multirotor_ros.nodes.cdr import OdometryWriter
from multirotor_ros.nodes.clock import CLOCK_QOS, GRAPH_CLOCK_TOPIC
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.listeners import ListenerGate
from multirotor_ros.nodes.messages import (
    LATCHED_QOS,
    imu_from_message,
    joint_state_from_rotor_speeds,
    odometry_values_of_state,
    pose_message,
    rotor_speeds_from_joint_state,
    simulated_imu_message,
    stamp_from_ns,
    stamp_to_ns,
    state_from_odometry,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.nodes.simulator import fault_parameters
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.nodes.vehicles import VehicleSpec
from multirotor_ros.plausibility import StampGate, StateLimits
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation import Reading
from multirotor_ros.simulation.sensors import SensorConfig
from multirotor_ros.simulation.vehicle import OVERSIZED_SPEED_FACTOR

NODE_NAME = "mavlink_bridge"

_HOME = Home()
PARAMETERS = (
    NodeParameter("airframe", "x8_octorotor", "airframe config name or YAML path", read_only=True),
    NodeParameter("flight_stack", "px4", "px4, ardupilot or none (ground station only)", read_only=True),
    NodeParameter(
        "internal_physics",
        True,
        "step an own simulation core in lockstep (else forward the simulator node's odom/imu/motor_speeds)",
        read_only=True,
    ),
    NodeParameter(
        "flight_stack_address", "127.0.0.1", "address the flight-stack port binds to", read_only=True
    ),
    NodeParameter(
        "flight_stack_port",
        0,
        "TCP (PX4) or UDP (ArduPilot) port; 0 = 4560 or 9002",
        "port",
        0,
        65535,
        read_only=True,
    ),
    NodeParameter(
        "lockstep_step_s",
        0.004,
        "PX4: simulated time per actuator message",
        "s",
        0.0001,
        0.05,
        read_only=True,
    ),
    NodeParameter(
        "physics_rate_hz",
        1000.0,
        "integration rate of the own simulation core",
        "Hz",
        100.0,
        10000.0,
        read_only=True,
    ),
    NodeParameter(
        "publish_rate_hz",
        250.0,
        "internal physics: rate of odom, motor_speed_cmd and clock (simulated time)",
        "Hz",
        1.0,
        1000.0,
        read_only=True,
    ),
    NodeParameter(
        "publish_clock", False, "internal physics: publish simulated time on /clock", read_only=True
    ),
    NodeParameter(
        "frame_prefix", "", "prefix of the frame ids odom and base_link (e.g. uav1/)", read_only=True
    ),
    NodeParameter("sensor_noise", True, "internal physics: simulate sensor noise", read_only=True),
    NodeParameter(
        "seed", 0, "internal physics: random seed of the sensor noise", "", 0, 2**31 - 1, read_only=True
    ),
    NodeParameter(
        "rotor_channels",
        "",
        "flight-stack output channel (1-based) of rotor 1..N, comma separated; empty = derived from the "
        "rotor geometry and the flight stack's motor numbering (a given map is checked against it)",
        read_only=True,
    ),
    NodeParameter(
        "pwm_min_us",
        1000.0,
        "ArduPilot pulse for no thrust on a normalized motor map",
        "us",
        500.0,
        2500.0,
        read_only=True,
    ),
    NodeParameter(
        "pwm_max_us",
        2000.0,
        "ArduPilot pulse for full thrust on a normalized motor map",
        "us",
        500.0,
        2500.0,
        read_only=True,
    ),
    NodeParameter("gps_rate_hz", 10.0, "PX4: HIL_GPS rate", "Hz", 5.0, 10.0, read_only=True),
    NodeParameter(
        "flight_stack_busy_wait_s",
        ArduPilotConfig.busy_wait_s,
        "ArduPilot: after an answer, poll this long for SITL's next frame when its last turn was as short "
        "(0: always sleep until it comes)",
        "s",
        0.0,
        MAX_BUSY_WAIT_S,
        read_only=True,
    ),
    NodeParameter(
        "flight_stack_answer_ahead",
        ArduPilotConfig.answer_ahead,
        "ArduPilot, the bridge's own physics: answer each frame with the state integrated after the last "
        "one, and integrate its servos while SITL takes its turn (faster on two cores; one frame of "
        "actuator delay)",
        read_only=True,
    ),
    NodeParameter(
        "measure_timing",
        False,
        "keep each lockstep frame's answer time and the flight stack's, logged as percentiles at shutdown",
        read_only=True,
    ),
    NodeParameter("gcs_enabled", True, "send telemetry to a ground station", read_only=True),
    NodeParameter("gcs_address", "127.0.0.1", "ground station address", read_only=True),
    NodeParameter("gcs_port", 14550, "ground station UDP port", "port", 1, 65535, read_only=True),
    NodeParameter(
        "gcs_bind_port",
        0,
        "local UDP port of the ground-station link; 0 = any",
        "port",
        0,
        65535,
        read_only=True,
    ),
    NodeParameter(
        "gcs_telemetry_rate_hz",
        50.0,
        "ATTITUDE and LOCAL_POSITION_NED rate",
        "Hz",
        1.0,
        500.0,
        read_only=True,
    ),
    NodeParameter(
        "gcs_max_peers",
        3,
        "ground stations learnt from their (signed, with a key) messages besides gcs_address:gcs_port",
        "",
        0,
        MAX_PEERS_LIMIT,
        read_only=True,
    ),
    NodeParameter("system_id", 1, "MAVLink system id of the vehicle", "", 1, 255, read_only=True),
    NodeParameter(
        "signing_key",
        "",
        "MAVLink 2 signing: 64 hex digits, or a passphrase whose SHA-256 is the key (as MAVProxy's "
        "'signing key WORD', one word); when set, unsigned or badly signed commands are refused",
        read_only=True,
    ),
    NodeParameter(
        "home_latitude_deg",
        _HOME.latitude_deg,
        "latitude of the odom origin (WGS-84)",
        "deg",
        -89.9,
        89.9,
        read_only=True,
    ),
    NodeParameter(
        "home_longitude_deg",
        _HOME.longitude_deg,
        "longitude of the odom origin",
        "deg",
        -180.0,
        180.0,
        read_only=True,
    ),
    NodeParameter(
        "home_altitude_m",
        _HOME.altitude_m,
        "altitude of the odom origin above mean sea level",
        "m",
        -400.0,
        10000.0,
        read_only=True,
    ),
    NodeParameter(
        "mag_declination_deg",
        _HOME.mag_declination_deg,
        "magnetic declination at home (east +)",
        "deg",
        -180.0,
        180.0,
        read_only=True,
    ),
    NodeParameter(
        "mag_inclination_deg",
        _HOME.mag_inclination_deg,
        "magnetic inclination at home (down +)",
        "deg",
        -90.0,
        90.0,
        read_only=True,
    ),
    NodeParameter(
        "mag_strength_gauss",
        _HOME.mag_strength_gauss,
        "magnetic field strength at home",
        "gauss",
        0.0,
        1.0,
        read_only=True,
    ),
)
_SPECS = {spec.name: spec for spec in PARAMETERS}


def parse_rotor_channels(text: str) -> list[int] | None:
    """``"1,4,2,3"`` -> [1, 4, 2, 3]; '' -> None (derived from the airframe's geometry)."""
    if not text.strip():
        return None
    try:
        return [int(part) for part in text.replace(" ", "").split(",")]
    except ValueError:
        raise ValueError(
            f"rotor_channels {text!r}: expected comma-separated channel numbers such as 1,4,2,3"
        ) from None


class MavlinkBridgeNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameters(self, PARAMETERS)
        if p["flight_stack"] not in FLIGHT_STACKS:
            raise ValueError(
                f"parameter flight_stack {p['flight_stack']!r}: choose one of {', '.join(FLIGHT_STACKS)}"
            )
        self.airframe = load_airframe(p["airframe"])
        self.internal = bool(p["internal_physics"]) and p["flight_stack"] != "none"
        if p["internal_physics"] and p["flight_stack"] == "none":
            self.get_logger().info(
                "flight_stack none: physics comes from the simulator node (internal_physics ignored)"
            )
        # Faults go into the physics this node owns; with external physics they are the simulator node's.
        fault_rows = fault_parameters(VehicleSpec(""), self.airframe.n_rotors) if self.internal else []
        specs = _SPECS | {row.name: row for row in fault_rows}
        fault = declare_parameters(self, fault_rows)
        self.add_on_set_parameters_callback(lambda parameters: check_parameters(specs, parameters))
        self.add_post_set_parameters_callback(self._apply_parameters)
        stack = p["flight_stack"]
        channels = RotorChannels(
            self.airframe,
            parse_rotor_channels(p["rotor_channels"]),
            p["pwm_min_us"],
            p["pwm_max_us"],
            flight_stack=None if stack == "none" else stack,
        )
        home = Home(
            p["home_latitude_deg"],
            p["home_longitude_deg"],
            p["home_altitude_m"],
            p["mag_declination_deg"],
            p["mag_inclination_deg"],
            p["mag_strength_gauss"],
        )
        # Two counters that log alike: the ground station's errors_comm counts MAVLink refusals only.
        self.link_refusals = RefusalCounter(self.get_logger().warning, "input")
        self.topic_refusals = RefusalCounter(self.get_logger().warning, "input")
        signing = SigningPolicy(parse_signing_key(p["signing_key"]))
        self.publish_clock = bool(p["publish_clock"])
        self._frames = (p["frame_prefix"] + "odom", p["frame_prefix"] + "base_link")

        qos = 10
        self.command_publisher = self.create_publisher(JointState, "motor_speed_cmd", qos)
        self._command_heard = ListenerGate(self.command_publisher)
        self.setpoint_publisher = self.create_publisher(PoseStamped, "setpoint", qos)
        # Messages the bridge thread fills and publishes again and again (publish serialises at once):
        # a new Odometry costs six times its filling, and the internal physics publishes about 1,000
        # messages per simulated second.
        self._command_message = JointState()
        self.physics: SimulatorPhysics | None = None
        self._command_period_s = 1.0 / p["publish_rate_hz"]
        self._next_command_s = 0.0
        if self.internal:
            self.physics = SimulatorPhysics.for_airframe(
                self.airframe,
                seed=p["seed"],
                noise=p["sensor_noise"],
                physics_rate_hz=p["physics_rate_hz"],
                odom_rate_hz=p["publish_rate_hz"],
            )
            # The simulator node's QoS, so that every subscriber of its topics matches this node too.
            self.odom_publisher = self.create_publisher(Odometry, "odom", qos)
            self.imu_publisher = self.create_publisher(Imu, "imu", qos_profile_sensor_data)
            self.speeds_publisher = self.create_publisher(JointState, "motor_speeds", qos)
            self.clock_publisher = (
                self.create_publisher(Clock, GRAPH_CLOCK_TOPIC, CLOCK_QOS) if self.publish_clock else None
            )
            # The volatile state topics, by reading kind: filled and published only while heard.
            self._reading_heard = {
                "odom": ListenerGate(self.odom_publisher),
                "imu": ListenerGate(self.imu_publisher),
                "motor_speeds": ListenerGate(self.speeds_publisher),
            }
            self._clock_heard = ListenerGate(self.clock_publisher) if self.clock_publisher else None
            # As the simulator node's: false from the start and after the flight stack restarts the vehicle.
            self.crashed_publisher = self.create_publisher(Bool, "crashed", LATCHED_QOS)
            self.crashed_publisher.publish(Bool(data=False))
            self._crashed = False
            # odom goes out serialised (nodes/cdr.py): rclpy's conversion of an Odometry costs more than
            # SITL's own frame. Its covariances stay zero (unknown), as in the message it replaces.
            odometry = Odometry()
            odometry.header.frame_id, odometry.child_frame_id = self._frames
            self._odom_writer = OdometryWriter(odometry)
            self._imu_message = Imu()
            self._speeds_message, self._clock_message = JointState(), Clock()
        else:
            self._odom: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None
            self._speeds: FloatArray = np.zeros(self.airframe.n_rotors)
            self._limits = StateLimits()
            self._odom_stamps = StampGate()
            self._imu_stamps = StampGate()
            subscribe(self, Odometry, "odom", self._on_odom, qos_profile_sensor_data)
            subscribe(self, Imu, "imu", self._on_imu, qos_profile_sensor_data)
            subscribe(self, JointState, "motor_speeds", self._on_motor_speeds, qos_profile_sensor_data)

        stack_port = p["flight_stack_port"]
        config = BridgeConfig(
            flight_stack=p["flight_stack"],
            px4=Px4Config(
                p["flight_stack_address"],
                stack_port or PX4_PORT,
                p["lockstep_step_s"],
                p["gps_rate_hz"],
                system_id=p["system_id"],
                measure_timing=p["measure_timing"],
            ),
            ardupilot=ArduPilotConfig(
                p["flight_stack_address"],
                stack_port or ARDUPILOT_PORT,
                measure_timing=p["measure_timing"],
                busy_wait_s=p["flight_stack_busy_wait_s"],
                answer_ahead=p["flight_stack_answer_ahead"],
            ),
            ground_station=GroundStationConfig(
                p["gcs_address"],
                p["gcs_port"],
                bind_port=p["gcs_bind_port"],
                system_id=p["system_id"],
                telemetry_rate_hz=p["gcs_telemetry_rate_hz"],
                max_peers=p["gcs_max_peers"],
            )
            if p["gcs_enabled"]
            else None,
            home=home,
        )
        outputs = BridgeOutputs(self._publish_command, self._publish_state, self._publish_setpoint)
        try:
            self.bridge = MavlinkBridge(config, channels, self.physics, outputs, self.link_refusals, signing)
        except OSError as error:
            raise ValueError(str(error)) from error
        self._loop = BridgeThread(self.bridge).start()
        mode = "own physics, lockstep" if self.internal else "physics from topics"
        if stack == "ardupilot" and p["flight_stack_answer_ahead"]:
            mode += (
                ", each frame answered ahead (one frame of actuator delay)"
                if self.internal
                else "; flight_stack_answer_ahead has no effect (the simulator node steps the physics)"
            )
        where = (
            f"{p['flight_stack']} on port {self.bridge.flight_stack_port}"
            if self.bridge.flight_stack_port
            else "no flight stack"
        )
        gcs = (
            f"ground station {p['gcs_address']}:{p['gcs_port']}" if p["gcs_enabled"] else "no ground station"
        )
        signed = ", signed commands only" if signing.enabled else ""
        self.get_logger().info(f"{self.airframe.name}: {where}, {gcs}{signed}; {mode}")
        if stack != "none":
            self.get_logger().info(f"{stack} outputs: {channels.describe()}")
        if fault_rows and fault["fault_motor"]:
            self._inject_fault(fault["fault_motor"], fault["fault_effectiveness"])

    # ------------------------------------------------------------------ bridge -> ROS (bridge thread)

    def _stamp(self, t_s: float) -> Any:
        # Internal physics: simulated time, like the simulator node; external: this node's clock.
        if self.internal:
            return stamp_from_ns(round(t_s * 1e9))
        return self.get_clock().now().to_msg()

    def _publish(self, publisher: Any, message: Any) -> None:
        # Between Ctrl-C (the context shuts down) and destroy_node (the thread stops) the bridge thread
        # may still publish, and rcl refuses ("publisher's context is invalid"): that is the end of the
        # run, not an error. Asked only then: context.ok() takes a lock, about 1,000 times a simulated second.
        try:
            publisher.publish(message)
        except RCLError:
            if self.context.ok():
                raise

    def _publish_command(self, speeds_rad_s: FloatArray, t_s: float) -> None:
        if self.internal:
            # The flight stack's rate (1,200 frames a second from ArduPilot) is for the physics this node
            # owns; the graph gets the newest command at publish_rate_hz of simulated time.
            if t_s < self._next_command_s:
                return
            self._next_command_s = t_s + self._command_period_s
        if not self._command_heard.heard():
            return
        stamp = self._stamp(t_s)
        self.bridge.defer(
            lambda: self._publish(
                self.command_publisher,
                joint_state_from_rotor_speeds(speeds_rad_s, stamp, out=self._command_message),
            )
        )

    def _publish_setpoint(self, setpoint: Setpoint) -> None:
        q = euler_to_quat(np.array([0.0, 0.0, setpoint.yaw_W_rad]))
        stamp = self.get_clock().now().to_msg()
        self._publish(self.setpoint_publisher, pose_message(stamp, self._frames[0], setpoint.p_W_m, q))

    def _publish_state(self, state: VehicleState) -> None:
        assert self.physics is not None
        if state.t_s < self._next_command_s - self._command_period_s:
            self._next_command_s = 0.0  # time went back: the flight stack restarted
            if self._crashed:
                self._crashed = False
                self.bridge.defer(lambda: self._publish(self.crashed_publisher, Bool(data=False)))
        imu_config = self.physics.imu_config
        # One deferred item per message: the flight stack's next frame may come between any two.
        for reading in self.physics.take_readings():
            gate = self._reading_heard.get(reading.kind)  # none for a crash: always told
            if gate is None or gate.heard():
                self.bridge.defer(partial(self._publish_reading, reading, imu_config))
            if reading.kind == "odom" and self._clock_heard is not None and self._clock_heard.heard():
                self.bridge.defer(partial(self._publish_clock, reading.t_ns))

    def _publish_reading(self, reading: Reading, imu_config: SensorConfig) -> None:
        stamp = stamp_from_ns(reading.t_ns)
        if reading.kind == "odom":
            self._publish(
                self.odom_publisher, self._odom_writer.write(stamp, odometry_values_of_state(reading.data))
            )
        elif reading.kind == "imu":
            message = simulated_imu_message(
                stamp, self._frames[1], reading.data, imu_config, out=self._imu_message
            )
            self._publish(self.imu_publisher, message)
        elif reading.kind == "motor_speeds":
            message = joint_state_from_rotor_speeds(reading.data, stamp, out=self._speeds_message)
            self._publish(self.speeds_publisher, message)
        elif reading.kind == "crash":
            self._crashed = True
            self._publish(self.crashed_publisher, Bool(data=True))
            self.get_logger().error(
                f"crashed at t = {reading.t_ns / 1e9:.2f} s: {reading.data.describe()}; "
                "it stays down until the flight stack restarts"
            )

    def _publish_clock(self, t_ns: int) -> None:
        self._clock_message.clock = stamp_from_ns(t_ns)
        self._publish(self.clock_publisher, self._clock_message)

    # ------------------------------------------------------------------ faults (internal physics)

    def _apply_parameters(self, parameters: list[Any]) -> None:
        changed = {p.name: p.value for p in parameters}
        if "fault_motor" in changed or "fault_effectiveness" in changed:
            motor = self.get_parameter("fault_motor").value
            self._inject_fault(motor, float(self.get_parameter("fault_effectiveness").value))

    def _inject_fault(self, motor: int, effectiveness: float) -> None:
        physics = self.physics
        assert physics is not None

        def inject() -> None:
            physics.inject_fault(motor, effectiveness)
            t_s = physics.t_ns * 1e-9
            self.get_logger().warning(
                f"fault injected at t = {t_s:.3f} s: rotor {motor} effectiveness {effectiveness:g}"
                if motor
                else f"fault cleared at t = {t_s:.3f} s"
            )

        self.bridge.run_in_loop(inject)  # the loop's thread owns the physics

    # ------------------------------------------------------------------ ROS -> bridge (external physics)

    def _refused(self, refusal: Refusal | None, topic: str) -> bool:
        if refusal is None:
            return False
        self.topic_refusals.refuse(refusal.reason, f"{topic}: {refusal.detail}")
        return True

    def _stamp_refused(self, gate: StampGate, stamp: Any, topic: str) -> bool:
        now_ns = self.get_clock().now().nanoseconds
        return self._refused(gate.check(stamp_to_ns(stamp), now_ns, topic), topic)

    def _on_odom(self, message: Odometry) -> None:
        result = state_from_odometry(message)
        if isinstance(result, Refusal):
            self._refused(result, "odom")
            return
        p, v, _, w = result
        if self._refused(self._limits.check(p_WB_W=p, v_WB_W=v, w_WB_B=w, what="odom"), "odom"):
            return
        if self._stamp_refused(self._odom_stamps, message.header.stamp, "odom"):
            return
        self._odom = result

    def _on_motor_speeds(self, message: JointState) -> None:
        limit_rad_s = OVERSIZED_SPEED_FACTOR * self.airframe.rotor_speed_max_rad_s
        result = rotor_speeds_from_joint_state(message, self.airframe.n_rotors, limit_rad_s)
        if isinstance(result, Refusal):
            self._refused(result, "motor_speeds")
            return
        self._speeds = result.speeds_rad_s

    def _on_imu(self, message: Imu) -> None:
        imu = imu_from_message(message)
        if isinstance(imu, Refusal):
            self._refused(imu, "imu")
            return
        w_imu_B, f_imu_B = imu
        if self._refused(self._limits.check(w_WB_B=w_imu_B, a_WB_W=f_imu_B, what="imu"), "imu"):
            return
        if self._odom is None:
            return  # nothing to send before the first odometry: position and attitude are unknown
        if self._stamp_refused(self._imu_stamps, message.header.stamp, "imu"):
            return
        p, v, q, w_true = self._odom
        t_s = stamp_to_ns(message.header.stamp) * 1e-9
        self.bridge.update_external_state(VehicleState(t_s, p, v, q, w_true, self._speeds, f_imu_B, w_imu_B))

    # ------------------------------------------------------------------ shutdown

    def destroy_node(self) -> None:
        """Stop the MAVLink thread and close its sockets before the node goes."""
        self._loop.stop()
        for stack, link in (("px4", self.bridge.px4), ("ardupilot", self.bridge.ardupilot)):
            if link is not None and link.times is not None:
                times = link.times.summary_ms()
                ardupilot = self.bridge.ardupilot
                missed = ardupilot.missed_frames if ardupilot else 0
                repeated = ardupilot.repeated_frames if ardupilot else 0
                answer = f", answer p95 {times['answer_p95_ms']:.3g} ms" if "answer_p95_ms" in times else ""
                simulated_s = self.bridge.simulation.latest.t_s
                self.get_logger().info(
                    f"{stack}: {times['frames']:.0f} frames in {simulated_s:.3f} s simulated{answer}, "
                    f"{missed} missed, {repeated} repeated"
                )
                # Asked for (measure_timing), so at info: bench/bench_ardupilot.py reads it from the log.
                self.get_logger().info(
                    "frame timing: " + ", ".join(f"{key} {value:.4g}" for key, value in times.items())
                )
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``mavlink_bridge`` (``ros2 run`` and ``multirotor node``)."""
    return run_node(MavlinkBridgeNode, args)
