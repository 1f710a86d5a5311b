"""The ``identifier`` node: online identification and rotor fault diagnosis (shared/spec/interfaces.md).

Wiring::

    motor_speeds (JointState) --> validate --+
    odom (Odometry) ------------> validate --+--> FlightMonitor --------> residuals (Vector3Stamped)
      or pose (PoseStamped) + imu (Imu) -----+    (diagnosis/monitor.py)   identified_parameters,
                                                                           diagnostics (DiagnosticArray)
                                                                           rotor_effectiveness
                                                                             (Float64MultiArray)
    FlightMonitor: RLS + window refit, observer, detector, record under record_path

``input``: ``odom`` (state from odometry: pose ENU, twist in body FLU; the acceleration the identifier
needs is the central difference of the velocity) or ``pose_imu`` (position and attitude from the pose,
body rates and specific force from the IMU, velocity from position differences, low-passed:
ident/pose_imu.py).
``residuals`` is published with every processed sample (``sample_rate_hz`` on average);
``identified_parameters``, ``diagnostics`` and ``rotor_effectiveness`` every 1/``publish_rate_hz`` of
wall time, and the record is flushed every second. Stamps come from the messages, so the node follows
simulated time as it is.

``rotor_effectiveness`` (std_msgs/Float64MultiArray, reliable; layout in nodes/effectiveness_message.py)
is what a controller reallocates from: row 0 each rotor's estimated remaining effectiveness, row 1 its
standard deviation. Before the detector has learnt the residual noise (the observer converging, or
settling after a gap) every rotor is 1 with std 1.0: nothing known. Then healthy rotors are 1 and the
rotor in alarm has its estimate, each with the standard deviation of one sample's loss estimate (about
0.01-0.03 on the X8); a coaxial pair the detector cannot tell apart both get at least the estimated loss
as std (FlightMonitor.effectiveness). Besides the periodic publish it is published at once, from the
sample that changed it, when any rotor's estimate moves by more than ``EFFECTIVENESS_STEP`` or its std
by more than ``EFFECTIVENESS_STD_STEP``: an alarm, its refinement and its clearing reach the controller
without waiting for the timer.

Bad input never stops the node nor moves an estimate. A message that fails validation is refused,
counted, and logged once per reason with throttled summaries after: wrong rotor count or names,
values that are not finite or not physically plausible (multirotor_ros.plausibility: positions,
speeds, rates, accelerations, a position jump since the last accepted one, rotor speeds above the
airframe's maximum), a stamp that repeats with other content, goes back, or lies more than
``future_stamp_tolerance_s`` ahead of the node's clock (refused alone, never kept as the newest). Under
``use_sim_time`` the node's clock is the newest ``clock`` message, and one that has arrived is heard
before a stamp is judged ahead of it (nodes/clock.py ``NodeTime.now_to_judge``); a message that comes before
the node's first ``clock`` is not looked at: there is no time yet to judge it by, and a node joining a
running simulator gets its odometry and clock in either order. A message equal to the last one
used on its topic is a resend (a lockstep simulator resends its newest odometry while it waits for a
command): no data and no error, ignored without a log line and counted (``<topic>_resent`` in the
``inputs`` status below). Samples that pass are still gated on their force residual
before the identifier learns from them (ident/rls.py). Missing data is never evidence
(diagnosis/monitor.py, "Breaks"): gaps are logged as warnings, restart the observer, and the residual
noise is learnt again before any alarm; samples taken while the vehicle may be held (on the ground,
before take-off) are not used (diagnosis/contact.py). When the node's clock goes back by more than
``future_stamp_tolerance_s`` (a restarted simulator under ``use_sim_time``), the identifier starts a
new time line (FlightMonitor.restart) and says so. An exception in a callback or timer (a bug, not bad
input) is logged once per kind with a count and the node goes on. Detection thresholds are parameters
``detection.*`` that ``ros2 param set`` may change.

``~/progress`` (std_msgs/Header): after each input message, the stamp up to which every input has been
handled (the oldest of the inputs' newest stamps; a state sample waiting for its rotor speeds is not
handled yet), when it moves on. A lockstep simulator waits for it (its ``lockstep_followers``), so that
the verdict on the state of t reaches the controller at the same simulated time in every run.

A stalled peer is named (diagnosis/inputs.py): when an input (``motor_speeds``, ``odom``, or ``pose``
and ``imu``) brings nothing for ``input_timeout_s`` of the node's clock or of wall time, a warning
says which, and whether the others still come (once per episode; a line when it is back), and
``diagnostics`` carries a status named ``inputs`` (OK, or WARN naming the silent inputs; resends do not
end a silence, and a silence with resends says that its publisher is alive and waits). It is
published as a DiagnosticArray of its own just before the rotors' one, which keeps one status per
rotor and nothing else.

``/diagnostics`` (absolute, for diagnostic_aggregator, which reads only that topic): the same statuses
(levels, messages, values) in one DiagnosticArray per period, named ``<node>: inputs`` and
``<node>: rotor_k`` as diagnostic_updater names them, ``<node>`` being the node's fully qualified name
without the leading slash (``identifier`` at the root namespace, ``uav1/identifier`` under ``/uav1``: two
vehicles do not collide), and ``hardware_id`` the vehicle: its namespace (the airframe's name at the root
namespace). At the root namespace the relative ``diagnostics`` is ``/diagnostics`` too: both forms are
published on it, the spec's two arrays and the aggregator's one.

Starting over (nodes/reset.py): the ``~/reset`` service (std_srvs/Trigger) and a ``simulation_reset``
message (the simulator put the vehicle back in its initial state) drop the estimates, the refit window,
the observer, the detector's learnt noise and every fault finding, as if the node had just started with
its parameters as they are now (``_reset``); one INFO line says so.

The log: one short line per event (a fault found or cleared, an input silent or back, a gap, a reset),
details at DEBUG (the refits among them). Times in it are seconds of the messages' clock (simulated time
under a simulator) since the first state sample the node took, or took after its last reset
(FlightMonitor.since_start_s), never the stamp itself, which on wall time is seconds since 1970.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from dataclasses import fields
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray, Header

from multirotor_ros.diagnosis.detection import DetectionSettings, DetectorOutput
from multirotor_ros.diagnosis.diagnoser import RotorReport
from multirotor_ros.diagnosis.inputs import InputsStatus, InputWatch
from multirotor_ros.diagnosis.monitor import (
    FlightMonitor,
    MonitorSettings,
    Refused,
    StepResult,
    fittable_effects,
)
from multirotor_ros.diagnosis.record import FlightRecord, RecordError
from multirotor_ros.diagnosis.residuals import ObserverSettings
from multirotor_ros.ident.pose_imu import PoseImuFusion, StateSample, Unpaired
from multirotor_ros.ident.rls import OnlineSettings
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.effects import parse_effect_list
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.nodes.clock import NodeTime, steady_clock
from multirotor_ros.nodes.effectiveness_message import rotor_effectiveness_message
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import (
    imu_from_message,
    pose_from_message,
    rotor_speeds_from_joint_state,
    stamp_from_ns,
    stamp_to_ns,
    state_from_odometry,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.nodes.reset import ResetFence, frame_refusal, offer_reset
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.plausibility import StampGate
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation.vehicle import OVERSIZED_SPEED_FACTOR

# [s] A pose this old still goes with an IMU sample (pose_imu): a motion-capture pose at 100 Hz comes
# within 10 ms of every sample, and the attitude of 25 ms before is another moment's in a manoeuvre.
POSE_MAX_AGE_S = 0.025
# Messages kept while a callback runs: a simulator running faster than real time publishes in bursts,
# and a dropped state or rotor-speed message is a gap in the data.
QUEUE_DEPTH = 100
# Where diagnostic_aggregator reads every node's statuses (module docstring).
AGGREGATOR_TOPIC = "/diagnostics"
LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR}
# rotor_effectiveness is published at once when an estimate moves more than this, or its std more than
# the second (module docstring); a healthy rotor's std wanders by about 0.01 from sample to sample.
EFFECTIVENESS_STEP = 0.02
EFFECTIVENESS_STD_STEP = 0.05

_DETECTION_HELP = {
    "k_sigma": ("alarm when a rotor's loss estimate exceeds this many of its standard deviations", "-"),
    "min_loss": ("... and at least this share of the rotor's thrust", "-"),
    "persistence_s": ("the alarm condition must hold this long", "s"),
    "clear_s": ("an alarm clears after this long below half its threshold", "s"),
    "warmup_s": ("residual noise learnt before any alarm", "s"),
    "noise_time_constant_s": ("memory of the residual noise estimate", "s"),
    "baseline_time_constant_s": ("memory of the residual's steady bias", "s"),
    "noise_floor_fraction": ("noise floor, as a share of a stopped rotor's residual", "-"),
    "effectiveness_time_constant_s": ("averaging of the effectiveness estimate after an alarm", "s"),
    "ambiguity_chi2": ("coaxial partners closer than this misfit are both named", "-"),
    "error_below_effectiveness": ("ERROR below this remaining effectiveness, WARN above", "-"),
    "relearn_s": ("after a gap or restart, residual noise learnt again for this long before any alarm", "s"),
}


def identifier_parameters() -> list[NodeParameter]:
    """The identifier's parameters; ``detection.*`` may change at run time, the others are read-only."""
    defaults = DetectionSettings()
    online = OnlineSettings()
    observer = ObserverSettings()
    monitor = MonitorSettings()
    specs = [
        NodeParameter("airframe", "x8_octorotor", "airframe config name or YAML path", read_only=True),
        NodeParameter(
            "effects",
            "",
            "effects to fit, comma-separated ids of effects.md; '' = the airframe's "
            "own fittable effects, 'none' = the thrust constant only",
            read_only=True,
        ),
        NodeParameter("input", "odom", "state source: 'odom' or 'pose_imu'", read_only=True),
        NodeParameter(
            "window_s", online.window_s, "samples kept for the refit", "s", 1.0, 3600.0, read_only=True
        ),
        NodeParameter(
            "refit_period_s",
            online.refit_period_s,
            "time between refits of the window",
            "s",
            0.1,
            3600.0,
            read_only=True,
        ),
        NodeParameter(
            "forgetting", online.forgetting, "RLS forgetting factor per sample", "-", 0.9, 1.0, read_only=True
        ),
        NodeParameter(
            "sample_rate_hz",
            monitor.sample_rate_hz,
            "state samples processed per second at most",
            "Hz",
            10.0,
            1000.0,
            read_only=True,
        ),
        NodeParameter(
            "max_gap_s",
            monitor.max_gap_s,
            "data missing for longer is a gap: observer restarted, residual noise learnt again",
            "s",
            0.001,
            60.0,
            read_only=True,
        ),
        NodeParameter(
            "pose_max_age_s",
            POSE_MAX_AGE_S,
            "input pose_imu: a pose older than this does not go with an IMU sample",
            "s",
            0.001,
            10.0,
            read_only=True,
        ),
        NodeParameter(
            "max_wait_s",
            monitor.max_wait_s,
            "a state sample waits at most this long (of stamps) for the rotor speeds of its time",
            "s",
            0.001,
            10.0,
            read_only=True,
        ),
        NodeParameter(
            "observer_convergence_time_s",
            observer.convergence_time_s,
            "super-twisting observer: time to follow a stopped rotor",
            "s",
            0.01,
            10.0,
            read_only=True,
        ),
        NodeParameter(
            "observer_filter_time_constant_s",
            observer.filter_time_constant_s,
            "low-pass on the observer's estimate",
            "s",
            0.0,
            1.0,
            read_only=True,
        ),
        NodeParameter(
            "future_stamp_tolerance_s",
            0.5,
            "a message stamped further ahead of this node's clock is refused",
            "s",
            0.0,
            60.0,
            read_only=True,
        ),
        NodeParameter(
            "input_timeout_s",
            1.0,
            "an input silent this long (node's clock or wall time) is reported as silent",
            "s",
            0.05,
            3600.0,
            read_only=True,
        ),
        NodeParameter(
            "publish_rate_hz",
            10.0,
            "rate of identified_parameters and diagnostics",
            "Hz",
            0.1,
            100.0,
            read_only=True,
        ),
        NodeParameter(
            "record_path", "", "directory of the record (resumed at start); '' = no record", read_only=True
        ),
    ]
    for f in fields(DetectionSettings):
        meaning, unit = _DETECTION_HELP[f.name]
        specs.append(
            NodeParameter(f"detection.{f.name}", float(getattr(defaults, f.name)), meaning, unit, 0.0, 1e6)
        )
    return specs


class IdentifierNode(Node):
    """Online identification and diagnosis of one vehicle; see the module docstring."""

    # Reads /clock itself (nodes/clock.py NodeTime): it may spin on the EventsExecutor, which carries a
    # lockstep simulator's state messages at its pace (entry.make_executor).
    KEEPS_ITS_OWN_SIMULATED_TIME = True

    def __init__(self, **kwargs: Any):
        super().__init__("identifier", **kwargs)
        specs = identifier_parameters()
        self._specs = {spec.name: spec for spec in specs}
        p = declare_parameters(self, specs)
        self.airframe = load_airframe(p["airframe"])
        n = self.airframe.n_rotors
        if p["input"] not in ("odom", "pose_imu"):
            raise ValueError(f"parameter input must be 'odom' or 'pose_imu', got {p['input']!r}")
        own = [spec["id"] for spec in self.airframe.effect_specs()]
        effect_ids = fittable_effects(own) if p["effects"] == "" else parse_effect_list(p["effects"])
        record = None
        if p["record_path"]:
            try:
                record = FlightRecord(p["record_path"], self.airframe.name, n)
            except RecordError as error:
                raise ValueError(str(error)) from error
        self._params = p
        self._effect_ids = effect_ids
        self.monitor = self._new_monitor(record, resume=True)
        self._speed_limit = OVERSIZED_SPEED_FACTOR * self.airframe.rotor_speed_max_rad_s
        logger = self.get_logger()
        self._refused = {
            "motor_speeds": RefusalCounter(logger.warning, "motor_speeds"),
            "state": RefusalCounter(logger.warning, "odom" if p["input"] == "odom" else "pose/imu"),
        }
        self._skipped = RefusalCounter(logger.warning, "state samples (unusable)")
        self._internal_errors = RefusalCounter(
            logger.error, "a callback's work (internal error; the node goes on)"
        )
        self._stamps = self._new_stamp_gates()
        self._last_stamp_ns = 0
        self._published_effectiveness: tuple[FloatArray, FloatArray] | None = None
        self._alarmed_rotor: int | None = None  # 0-based, as last logged
        self._reset_fence = ResetFence(p["future_stamp_tolerance_s"])
        inputs = ["motor_speeds", *(["odom"] if p["input"] == "odom" else ["pose", "imu"])]
        self._input_topics = inputs
        self._inputs = InputWatch(inputs, p["input_timeout_s"])
        self._clock_ns: int | None = None  # the node's clock at the last message, to see it go back
        self._used: dict[str, Any] = {}  # per topic, the last message used: the same again is a resend
        self._state_frame = ""  # frame_id of the state messages used (odom or pose), for simulation_reset
        self._newest_input_ns: dict[str, int] = {}  # per input topic, the newest stamp taken in (~/progress)
        self._progress_ns = -1

        self._residuals_pub = self.create_publisher(Vector3Stamped, "residuals", 10)
        self._parameters_pub = self.create_publisher(DiagnosticArray, "identified_parameters", 10)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        # At the root namespace both names are /diagnostics: one publisher carries both forms.
        self._aggregated_pub = (
            self._diagnostics_pub
            if self.resolve_topic_name("diagnostics") == AGGREGATOR_TOPIC
            else self.create_publisher(DiagnosticArray, AGGREGATOR_TOPIC, 10)
        )
        self._aggregated_prefix = self.get_fully_qualified_name().lstrip("/") + ": "
        self._vehicle = self.get_namespace().strip("/") or self.airframe.name
        self._effectiveness_pub = self.create_publisher(Float64MultiArray, "rotor_effectiveness", 10)
        self._progress_pub = self.create_publisher(Header, "~/progress", 10)
        subscribe(self, JointState, "motor_speeds", self._input(self._on_motor_speeds), QUEUE_DEPTH)
        if p["input"] == "odom":
            subscribe(self, Odometry, "odom", self._input(self._on_odometry), QUEUE_DEPTH)
        else:
            self._fusion = self._new_fusion()
            # Best effort, as sensor data is published, but a deep queue: a dropped sample is a gap.
            sensor_qos = QoSProfile(
                depth=QUEUE_DEPTH,
                reliability=ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.VOLATILE,
            )
            subscribe(self, PoseStamped, "pose", self._input(self._on_pose), sensor_qos)
            subscribe(self, Imu, "imu", self._input(self._on_imu), sensor_qos)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        wall = steady_clock()
        self.create_timer(1.0 / p["publish_rate_hz"], self._guarded(self._publish_status), clock=wall)
        # Four checks per timeout: a check later than two periods means this node itself stalled.
        self.create_timer(p["input_timeout_s"] / 4, self._guarded(self._check_inputs), clock=wall)
        self.create_timer(1.0, self._guarded(self._flush_record), clock=wall)
        offer_reset(
            self, self._reset, self._reset_refusal, p["future_stamp_tolerance_s"], self._reset_clock_ns
        )
        self._time = NodeTime(self)
        for note in self.monitor.notes:
            logger.info(f"record: {note}")
        logger.info(
            f"{self.airframe.name}: fitting {', '.join(effect_ids) or 'the thrust constant only'} "
            f"from {p['input']}" + (", recording" if p["record_path"] else "")
        )
        logger.debug(
            f"window {p['window_s']:g} s, refit every {p['refit_period_s']:g} s"
            + (f", record in {p['record_path']}" if p["record_path"] else "")
        )

    def _new_monitor(self, record: FlightRecord | None, resume: bool) -> FlightMonitor:
        """A monitor as at start, with the parameters as they are now (``detection.*`` may have changed)."""
        p = self._params
        return FlightMonitor(
            self.airframe,
            self._effect_ids,
            OnlineSettings(
                window_s=p["window_s"], refit_period_s=p["refit_period_s"], forgetting=p["forgetting"]
            ),
            ObserverSettings(p["observer_convergence_time_s"], p["observer_filter_time_constant_s"]),
            self._detection_settings(p),
            MonitorSettings(p["sample_rate_hz"], p["max_gap_s"], p["max_wait_s"]),
            record,
            resume,
        )

    def _new_stamp_gates(self) -> dict[str, StampGate]:
        # One gate per topic: the topics' stamps need not be in order with each other.
        tolerance_s = self._params["future_stamp_tolerance_s"]
        return {topic: StampGate(tolerance_s) for topic in ("motor_speeds", "odom", "pose", "imu")}

    # ------------------------------------------------------------------ parameters

    @staticmethod
    def _detection_settings(p: dict[str, Any]) -> DetectionSettings:
        return DetectionSettings(
            **{f.name: float(p[f"detection.{f.name}"]) for f in fields(DetectionSettings)}
        )

    def _check_parameters(self, parameters: list[Any]) -> Any:
        result = check_parameters(self._specs, parameters)
        if result.successful:
            candidate = dict(self._params)
            candidate.update({p.name: p.value for p in parameters if p.name in self._specs})
            try:
                self._detection_settings(candidate)
            except ValueError as error:
                result.successful = False
                result.reason = str(error)
        return result

    def _apply_parameters(self, parameters: list[Any]) -> None:
        for parameter in parameters:
            if parameter.name == "use_sim_time":
                self._time.set_simulated(bool(parameter.value))
        changed = {p.name: p.value for p in parameters if p.name in self._specs}
        self._params.update(changed)
        if any(name.startswith("detection.") for name in changed):
            self.monitor.set_detection_settings(self._detection_settings(self._params))
            self.get_logger().info(f"detection thresholds changed: {changed}")

    # ------------------------------------------------------------------ inputs

    def _guarded(self, work: Callable[..., None]) -> Callable[..., None]:
        """``work`` such that an exception it raises is counted and logged (once per kind), not fatal.

        Bad input is refused before it gets here; an exception is a bug, and one bug must not stop the
        identification of a flying vehicle.
        """

        def run(*args: Any) -> None:
            try:
                work(*args)
            except Exception as error:  # noqa: BLE001 (see the docstring)
                self._internal_errors.refuse(
                    f"{type(error).__name__} in {work.__name__}", f"{error}\n{traceback.format_exc()}"
                )

        return run

    def _input(self, handle: Callable[[Any], None]) -> Callable[[Any], None]:
        """An input topic's callback: ``handle`` (guarded), then the progress it made (module docstring)."""
        guarded = self._guarded(handle)

        def run(message: Any) -> None:
            guarded(message)
            if len(self._newest_input_ns) < len(self._input_topics):
                return
            handled_ns = min(self._newest_input_ns.values())
            if handled_ns > self._progress_ns:
                self._progress_ns = handled_ns
                self._progress_pub.publish(Header(stamp=stamp_from_ns(handled_ns)))

        return run

    def _new_fusion(self) -> PoseImuFusion:
        return PoseImuFusion(
            self.monitor.diagnoser.model.gravity_m_s2,
            self._params["max_gap_s"],
            self._params["pose_max_age_s"],
            limits=self.monitor.limits,
        )

    def _arrived(self, topic: str, message: Any) -> bool:
        """Note a message of ``topic``; False for a resend of the last one used (ignored, only counted).

        Every other message is noted, refused or not: for the input watch (a peer sending bad messages
        is not silent) and to see the node's clock go back. A resend (a lockstep simulator sends its
        newest odometry again while it waits for a command) is no new data, no error either; nor is a
        message stamped before a simulation reset (the old vehicle's, still queued: nodes/reset.py).
        """
        stamp_ns = stamp_to_ns(message.header.stamp)
        tolerance_ns = round(self._params["future_stamp_tolerance_s"] * 1e9)
        now_ns = self._time.now_to_judge(stamp_ns, tolerance_ns)
        if not self._time.running:
            return False  # no time yet to judge a stamp by (simulated time before the first /clock)
        back_ns = (self._clock_ns or 0) - now_ns
        if back_ns > tolerance_ns:
            self._start_new_time_line(back_ns * 1e-9)
        self._clock_ns = now_ns
        if self._used.get(topic) == message:
            self._inputs.resent(topic)
            return False
        # The simulator sends a state before the clock of its time: a stamp up to the tolerance ahead of
        # this node's clock is handled as it is; one further ahead is refused below, and counts as no later.
        taken_ns = min(stamp_ns, now_ns + tolerance_ns)
        self._newest_input_ns[topic] = max(taken_ns, self._newest_input_ns.get(topic, taken_ns))
        back = self._inputs.heard(topic, now_ns, time.monotonic_ns())
        if back is not None:
            self.get_logger().info(back)
        return not self._reset_fence.stale(stamp_ns, now_ns)

    def _refusal(self, topic: str, parsed: object, stamp: Any) -> Refusal | None:
        """Why a new message of ``topic`` is refused (the parser's reason, or its stamp's), or None."""
        if isinstance(parsed, Refusal):
            return parsed
        # The stamp gate: in the future by the node's clock, or older than the newest.
        assert self._clock_ns is not None
        return self._stamps[topic].check(stamp_to_ns(stamp), self._clock_ns, topic)

    def _start_new_time_line(self, back_s: float) -> None:
        """The clock went back (a restarted simulator): stamps start over, and so does the monitor."""
        self.get_logger().warning(
            f"the clock went back by {back_s:.3f} s (a restarted simulator?): new time line, estimates kept"
        )
        self.get_logger().debug("observer restarted, residual noise learnt again before any alarm")
        self.monitor.restart()
        self._used.clear()
        self._newest_input_ns.clear()
        self._progress_ns = -1
        if self._params["input"] == "pose_imu":
            self._fusion = self._new_fusion()

    def _on_motor_speeds(self, message: JointState) -> None:
        if not self._arrived("motor_speeds", message):
            return
        result = rotor_speeds_from_joint_state(message, self.airframe.n_rotors, self._speed_limit)
        refusal = self._refusal("motor_speeds", result, message.header.stamp)
        if refusal is not None:
            self._refused["motor_speeds"].refuse(refusal.reason, refusal.detail)
            return
        assert not isinstance(result, Refusal)
        outcome = self.monitor.rotor_speeds(result.stamp_ns, result.speeds_rad_s)
        if isinstance(outcome, Refused):
            self._refused["motor_speeds"].refuse(outcome.reason, outcome.detail)
            return
        self._used["motor_speeds"] = message
        for step in outcome:
            self._report(step)

    def _on_odometry(self, message: Odometry) -> None:
        if not self._arrived("odom", message):
            return
        state = state_from_odometry(message)
        refusal = self._refusal("odom", state, message.header.stamp)
        if refusal is not None:
            self._refused["state"].refuse(refusal.reason, refusal.detail)
            return
        assert not isinstance(state, Refusal)
        if self._take(StateSample(stamp_to_ns(message.header.stamp), *state)):
            self._used["odom"] = message
            self._state_frame = message.header.frame_id

    def _on_pose(self, message: PoseStamped) -> None:
        if not self._arrived("pose", message):
            return
        pose = pose_from_message(message)
        refusal = self._refusal("pose", pose, message.header.stamp)
        if refusal is None:
            assert not isinstance(pose, Refusal)
            refusal = self._fusion.pose(stamp_to_ns(message.header.stamp), *pose)
        if refusal is not None:
            self._refused["state"].refuse(refusal.reason, refusal.detail)
            return
        self._used["pose"] = message
        self._state_frame = message.header.frame_id
        self._take_fused()

    def _on_imu(self, message: Imu) -> None:
        if not self._arrived("imu", message):
            return
        imu = imu_from_message(message)
        refusal = self._refusal("imu", imu, message.header.stamp)
        if refusal is not None:
            self._refused["state"].refuse(refusal.reason, refusal.detail)
            return
        assert not isinstance(imu, Refusal)
        refusal = self._fusion.imu(stamp_to_ns(message.header.stamp), *imu)
        if refusal is not None:
            self._refused["state"].refuse(refusal.reason, refusal.detail)
            return
        self._used["imu"] = message  # taken: its sample may wait for its pose (ident/pose_imu.py)
        self._take_fused()

    def _take_fused(self) -> None:
        """Give the monitor the IMU messages the fusion has decided (pose_imu input)."""
        for sample in self._fusion.decided():
            if isinstance(sample, Unpaired):
                self._skipped.refuse(sample.reason, sample.detail)
            else:
                self._take(sample)

    def _take(self, sample: StateSample) -> bool:
        """Give a state sample to the monitor; whether it took it."""
        outcome = self.monitor.state(
            sample.stamp_ns, sample.p_WB_W, sample.v_WB_W, sample.q_WB, sample.w_WB_B, sample.a_WB_W
        )
        if isinstance(outcome, Refused):
            self._refused["state"].refuse(outcome.reason, outcome.detail)
            return False
        for step in outcome:
            self._report(step)
        return True

    # ------------------------------------------------------------------ outputs

    def _report(self, result: StepResult) -> None:
        for warning in result.warnings:
            self.get_logger().warning(warning, throttle_duration_sec=5.0)
        for event in result.events:
            self.get_logger().info(event)
        if result.skipped is not None and not result.skipped_as_expected:
            self._skipped.refuse(result.skipped, result.skipped_detail)
        if result.accel_residual_W is not None:
            self._last_stamp_ns = result.stamp_ns
            message = Vector3Stamped()
            message.header.stamp = stamp_from_ns(result.stamp_ns)
            message.header.frame_id = "odom"
            message.vector.x, message.vector.y, message.vector.z = (float(v) for v in result.accel_residual_W)
            self._residuals_pub.publish(message)
        if result.refit is not None:
            refit = result.refit
            # Routine (every refit_period_s of stamps): the estimates are on identified_parameters.
            self.get_logger().debug(
                f"refit at t = {self.monitor.since_start_s(refit.t):.1f} s over {refit.n_samples} samples "
                f"in {1e3 * refit.duration_s:.1f} ms: "
                + ", ".join(
                    f"{e.name} = {e.value:.4g} ± {e.std:.2g}"
                    if e.identifiable
                    else f"{e.name} = {e.value:.4g} (held: the window cannot tell it)"
                    for e in refit.estimates
                )
            )
        if result.detection is not None:
            self._log_fault_change(result.detection, result.t)
            self._publish_effectiveness(only_if_changed=True)

    def _log_fault_change(self, detection: DetectorOutput, t: float) -> None:
        """One line when a rotor fault is found (ERROR or WARN, as its status) and one when it clears."""
        rotor = int(detection.rotor[0]) if detection.alarm[0] else None
        if rotor == self._alarmed_rotor:
            return
        t_s = self.monitor.since_start_s(t)
        if self._alarmed_rotor is not None:
            self.get_logger().info(
                f"rotor fault cleared at t = {t_s:.2f} s: rotor {self._alarmed_rotor + 1} OK"
            )
        self._alarmed_rotor = rotor
        if rotor is not None:
            report = self.monitor.reports()[rotor]
            log = self.get_logger().error if report.level == "ERROR" else self.get_logger().warning
            log(f"rotor fault at t = {t_s:.2f} s: {report.summary}")
            self.get_logger().debug(report.message)

    def _publish_effectiveness(self, only_if_changed: bool = False) -> None:
        estimate, std = self.monitor.effectiveness()
        if only_if_changed and self._published_effectiveness is not None:
            published_estimate, published_std = self._published_effectiveness
            if np.all(np.abs(estimate - published_estimate) <= EFFECTIVENESS_STEP) and np.all(
                np.abs(std - published_std) <= EFFECTIVENESS_STD_STEP
            ):
                return
        self._effectiveness_pub.publish(rotor_effectiveness_message(estimate, std))
        self._published_effectiveness = (estimate, std)

    def _check_inputs(self) -> None:
        for silent in self._inputs.check(self._time.now_ns(), time.monotonic_ns()):
            self.get_logger().warning(silent)

    def _publish_status(self) -> None:
        header = Header(stamp=stamp_from_ns(self._last_stamp_ns))
        self._parameters_pub.publish(self._parameters_message(header.stamp))
        inputs = self._inputs.status()
        reports = self.monitor.reports()
        # The spec's diagnostics: the inputs' status in an array of its own, then one status per rotor.
        inputs_status, *rotors = self._statuses(inputs, reports, "", self.airframe.name)
        self._diagnostics_pub.publish(DiagnosticArray(header=header, status=[inputs_status]))
        self._diagnostics_pub.publish(DiagnosticArray(header=header, status=rotors))
        # The aggregator's: every status in one array, named after this node, the vehicle as hardware.
        aggregated = self._statuses(inputs, reports, self._aggregated_prefix, self._vehicle)
        self._aggregated_pub.publish(DiagnosticArray(header=header, status=aggregated))
        self._publish_effectiveness()

    @staticmethod
    def _statuses(
        inputs: InputsStatus, reports: list[RotorReport], prefix: str, hardware_id: str
    ) -> list[DiagnosticStatus]:
        """The ``inputs`` status and one per rotor, their names after ``prefix``."""
        return [
            DiagnosticStatus(
                level=LEVELS[level],
                name=prefix + name,
                message=message,
                hardware_id=hardware_id,
                values=[KeyValue(key=k, value=v) for k, v in values.items()],
            )
            for level, name, message, values in [
                (inputs.level, "inputs", inputs.message, inputs.values),
                *((r.level, r.name, r.message, r.values) for r in reports),
            ]
        ]

    def _parameters_message(self, stamp: Any) -> DiagnosticArray:
        message = DiagnosticArray()
        message.header.stamp = stamp
        identifier = self.monitor.identifier
        refit = identifier.last_refit
        held = {(e.effect_id, e.name) for e in refit.estimates if not e.identifiable} if refit else set()
        by_effect: dict[str, list[Any]] = {}
        for estimate in self.monitor.estimates():
            by_effect.setdefault(estimate.effect_id, []).append(estimate)
        for effect_id, estimates in by_effect.items():
            unclear = [e.name for e in estimates if (e.effect_id, e.name) in held]
            bounded = [e.name for e in estimates if e.at_bound]
            text = f"running estimate over {identifier.n_samples} samples"
            if identifier.n_gated:
                text += f" ({identifier.n_gated} more dropped: force residual beyond the innovation gate)"
            if refit is not None:
                refit_s = refit.t + self.monitor.clock_offset_s
                text += f"; last refit at t = {refit_s:.1f} s over {refit.n_samples} samples"
            if unclear:
                text += f"; not identifiable from the window (value held): {', '.join(unclear)}"
            if bounded:
                text += f"; at a physical bound: {', '.join(bounded)}"
            values = []
            for e in estimates:
                values.append(KeyValue(key=e.name, value=f"{e.value:.6g}"))
                values.append(KeyValue(key=f"{e.name}_std", value=f"{e.std:.3g}"))
            message.status.append(
                DiagnosticStatus(
                    level=DiagnosticStatus.WARN if unclear or bounded else DiagnosticStatus.OK,
                    name=effect_id,
                    message=text,
                    hardware_id=self.airframe.name,
                    values=values,
                )
            )
        return message

    # ------------------------------------------------------------------ reset

    def _reset(self, cause: str, reset_stamp_ns: int | None) -> str:
        """Forget and start over (nodes/reset.py): as if just started, with the parameters as they are.

        Dropped: the estimates, the refit window, the observer, the detector's learnt noise and any fault
        finding, the pairing of samples and the stamps seen. With a record, the samples so far are
        written and a new segment starts, and the learnt state written next is the fresh one: a node
        restarted after a reset does not resume what the reset forgot. Kept: the parameters, the input
        watch (a reset does not silence a peer) and the refusal counts.
        """
        record = self.monitor.record
        note = ""
        if record is not None:
            try:
                record.start_new_segment()
            except OSError as error:
                note = f"; record: cannot write ({error})"
        self.monitor = self._new_monitor(record, resume=False)
        self._stamps = self._new_stamp_gates()
        self._used.clear()
        if self._params["input"] == "pose_imu":
            self._fusion = self._new_fusion()
        self._published_effectiveness = None
        self._alarmed_rotor = None
        if reset_stamp_ns is None:
            self._reset_fence.open()
        else:
            self._reset_fence.close(reset_stamp_ns, self._time.now_ns())
        line = f"reset by {cause}: estimates and fault findings dropped, starting over{note}"
        self.get_logger().info(line)
        return line

    def _reset_refusal(self, message: Header) -> Refusal | None:
        return frame_refusal(message, self._state_frame)

    def _reset_clock_ns(self) -> int | None:
        return self._time.now_ns() if self._time.running else None

    def _flush_record(self) -> None:
        try:
            self.monitor.flush_record()
        except OSError as error:
            self.get_logger().error(f"record: cannot write ({error}); will retry", throttle_duration_sec=10.0)

    def destroy_node(self) -> None:
        """Write what the record still holds before going."""
        try:
            self.monitor.flush_record()
        except OSError as error:
            self.get_logger().error(f"record: cannot write at shutdown ({error})")
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros identifier`` and ``multirotor node identifier``."""
    return run_node(IdentifierNode, args)
