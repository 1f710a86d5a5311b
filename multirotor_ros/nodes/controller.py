"""The ``controller`` node: the seed 1 saturation law flying one vehicle (shared/spec/interfaces.md).

Wiring::

    odom (Odometry) --------> validate -> latest state --+
    setpoint (PoseStamped) -> validate -> latest target -+-> SaturationController (control/), every
    /clock (use_sim_time) --> ClockTicks ----------------+   1/rate_hz of the node's clock -> motor_speed_cmd
    rotor_effectiveness ----> validate -> latest -> EffectivenessFilter -+  (effectiveness of each rotor)
      (Float64MultiArray)                           (control/fault_tolerance.py)

The law runs every 1/``rate_hz`` of the node's clock and each command is stamped with the time it was
computed at: on wall time from a timer on the steady clock, on simulated time (``use_sim_time``) from
the ``/clock`` messages themselves (simulation/pacing.py ``ClockTicks``), at ``rate_hz`` of simulated
time; on simulated time the node's time is the newest ``/clock`` this subscription received, not rclpy's
time source. Neither a timer on the simulated clock nor the time source: the node may then spin on
rclpy's EventsExecutor (the single-threaded executor's wait sets halved the lockstep loop's speed,
bench/bench_closed_loop.py), whose timers manager, like rclcpp's, is not made for a ``/clock``-driven
clock (ros2/rclcpp#2457; nodes/entry.py ``make_executor``), and under which the time source's ``/clock``
subscription, made when the node is constructed, often never delivers when the clock was already
running before the node spun (7 controllers of 12 joining a running simulator read time 0 for good;
this one is made last, just before the spin). The clock and the
odometry of one instant come on two topics in either order: on simulated time a tick whose odometry is
due but not yet here waits for it (simulation/pacing.py ``StateForTick``), so that in lockstep every
command is computed from the state of its own instant and a flight is the same on any machine; and a
state stamped at the next tick, with the clock heard one period before it at most, is that tick at
once: its simulator publishes the /clock of that instant right after it, and waiting for it would put
one more delivery into every period of a lockstep loop (the /clock that follows then finds the tick
done).
A lockstep simulator that waits resends the state it stands at; the same state again, with a command
already sent for its instant, means that command was lost (a burst of other messages on
``motor_speed_cmd`` can overflow the simulator's queue), so it is sent again: without that the loop
would wait for ever.
Until the first setpoint the vehicle holds the pose of the first odometry it received. With no
odometry for ``odom_timeout_s`` the node stops sending commands (warning logged once) and the
simulator's watchdog stops the rotors.

Starting over (nodes/reset.py): the ``~/reset`` service (std_srvs/Trigger) and a ``simulation_reset``
message (the simulator put the vehicle back in its initial state) clear the law's integrals, the
setpoints waiting for their time, the setpoint in force and what the odometry check remembers (last
position, frames, stamps); until a new setpoint the vehicle holds the pose of the next odometry, as at
start, and a tick waits for that odometry (in lockstep the simulator resends its state: the loop goes
on). After a ``simulation_reset`` odometry stamped before the reset is dropped: it is the old vehicle's.
The rotor effectiveness in use is kept: it is the identifier's diagnosis, which the controller does not
own; a reset identifier says "nothing known", which the filter holds, so a rotor found stopped is not
put back into the allocation by a reset.
Gains: parameters under the paper's names, defaults from the airframe YAML's ``controller`` section,
settable at run time (validated; the integrals are rescaled so the output does not jump).

Fault-tolerant allocation (issue 15): the identifier's ``rotor_effectiveness`` (each rotor's estimated
remaining effectiveness and its standard deviation; layout in nodes/effectiveness_message.py) goes
through an ``EffectivenessFilter`` every period, whose output the allocator uses (B diag(e): a stopped
rotor is left out, thrust, roll and pitch first, yaw given up where it must). The filter moves with
first-order dynamics, so a diagnosis that appears or clears causes no jump in the commands; an
unconfident estimate holds what it had, a rotor confidently found stopped stays out until a confident
estimate shows it recovered, a confident healthy estimate restores the nominal allocation, and a rotor
not diagnosed as stopped stays above the floor, so that a wrong diagnosis cannot take a healthy rotor
away. The latest accepted message holds until the next, as the filter holds an unconfident one: it has
no stamp, the identifier republishes it several times a second, and a rotor found stopped does not
start again because the identifier fell silent. Parameter ``fault_tolerant_allocation`` (default true,
settable at run time): false feeds the filter a confident "all healthy" instead, i.e. the nominal
allocation, reached without a jump; the gains are the same either way. One short INFO line when
reallocation starts (a rotor's effectiveness in use drops below ``1 - REALLOCATION_NOTICE``) and when it
ends, naming the rotors and the effectiveness in use (the diagnosis behind it at DEBUG); one WARN per
reallocation when the allocator gives up yaw authority (keeps less than ``YAW_GIVEN_UP_FRACTION`` of the
wanted yaw torque).

Hostile input (issue 11): nothing refused reaches the law, so its integrals never see it. Every refusal
is counted per reason, logged once per reason, then summarised (refusals.py).

- odom: finite, a unit quaternion, position, velocity and body rate within ``StateLimits``; a position
  no farther from the last accepted one than the speed limit allows in the time (on this node's clock)
  since that one arrived: time between arrivals, not between stamps, which the sender chooses. The
  allowance grows with time. Its frame ids must be those of the last accepted one. After
  ``odom_timeout_s`` without accepted odometry neither is compared any more: a real jump or change of
  frame (a re-localised or restarted estimator) is accepted, and so is the valid odometry that follows a
  plausible but false first one. The stamp goes through a
  ``StampGate`` against this node's clock (simulated or wall time): a stamp more than 0.5 s ahead is
  refused alone and never kept, so the next valid odometry is accepted. On simulated time a ``/clock``
  that came but waits to be dispatched is heard before that judgement (nodes/clock.py
  ``NodeTime.now_to_judge``): a controller that was busy for a moment beside a simulator running faster
  than real time gets the newest odometry before the clock of its time. A zero stamp is refused as
  unstamped once this node's clock reads more than that tolerance; before (simulated time just
  started) it is a real stamp: the simulator's first odometry is stamped 0.
- rotor_effectiveness: the layout above with N rotors, finite, estimates in [0, 1.5], std >= 0. A
  refused message leaves the previous diagnosis in force.
- setpoint: finite, a unit (or all-zero) quaternion, a position within ``StateLimits.position_m`` (the
  MAVLink path's 10 km); the frame, if given, that of the odometry. A refused setpoint leaves the
  previous one in force. A setpoint stamped at or before this node's clock (0 included) takes effect at
  once; one stamped later waits for its time (control/setpoint_queue.py: a mission sent ahead in
  simulated time flies the same however its messages are delayed); more than an hour ahead, or beyond
  1000 waiting, it is refused.
- own output: a rotor speed that is not finite or negative is never published. The node publishes
  nothing that period (the simulator holds the last command; if it happens again and again its watchdog
  stops the rotors, which is right for a controller that cannot compute) and resets the law, whose
  integrals could hold the bad value. Re-sending the last good command instead would stamp an old
  command as new and keep the vehicle flying open-loop for as long as the fault lasts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from multirotor_ros.control.fault_tolerance import EffectivenessFilter
from multirotor_ros.control.gains import GAIN_UNITS, airframe_gains
from multirotor_ros.control.law import SaturationController
from multirotor_ros.control.setpoint_queue import SETPOINT_QUEUE_LENGTH, SetpointQueue
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import FloatArray, quat_to_euler
from multirotor_ros.nodes.cdr import OdometryFields, RotorCommandWriter, odometry_fields_from_cdr
from multirotor_ros.nodes.clock import NodeTime, steady_clock
from multirotor_ros.nodes.effectiveness_message import effectiveness_from_message
from multirotor_ros.nodes.entry import run_node
from multirotor_ros.nodes.messages import (
    setpoint_from_pose,
    stamp_to_ns,
    state_from_odometry_values,
)
from multirotor_ros.nodes.parameters import NodeParameter, check_parameters, declare_parameters
from multirotor_ros.nodes.reset import ResetFence, frame_refusal, offer_reset
from multirotor_ros.nodes.subscriptions import subscribe
from multirotor_ros.plausibility import NS_PER_S, StampGate, StateLimits, format_vector, jump_refusal
from multirotor_ros.refusals import Refusal, RefusalCounter
from multirotor_ros.simulation.pacing import ClockTicks, StateForTick

# (p_WB_W, v_WB_W, q_WB, w_WB_B): position and velocity in world ENU, attitude, body rates in FLU.
State = tuple[FloatArray, FloatArray, FloatArray, FloatArray]
# Reallocation is said to start when a rotor's effectiveness in use drops this far below 1 [-].
REALLOCATION_NOTICE = 0.05
# Yaw authority counts as given up below this share of the wanted yaw torque (a brief saturation of a
# few percent in a transient is no news).
YAW_GIVEN_UP_FRACTION = 0.9
# The filter's input when no diagnosis is known, or none new since the last period (one object, so that
# it is recognised as given already).
NOTHING_KNOWN: tuple[None, None] = (None, None)


def controller_parameters(gains: dict[str, float]) -> list[NodeParameter]:
    """Gains (defaults from the airframe YAML) and the node's own settings."""
    specs = [
        NodeParameter(name, value, meaning, unit, 0.0, 1e6, low_exclusive=True, read_only=name == "rate_hz")
        for name, value in gains.items()
        for unit, meaning in [GAIN_UNITS[name]]
    ]
    specs.append(
        NodeParameter(
            "fault_tolerant_allocation",
            True,
            "allocate with the rotor effectiveness the identifier diagnoses (rotor_effectiveness); "
            "false = the nominal allocation",
        )
    )
    specs.append(
        NodeParameter(
            "odom_timeout_s",
            0.5,
            "stop commanding when odometry is older than this",
            "s",
            0.0,
            60.0,
            low_exclusive=True,
        )
    )
    return specs


@dataclass
class OdometryCheck:
    """The odometry the controller may fly on (see the module docstring); keeps only what it accepts."""

    forget_after_ns: int  # after this long without an accepted odometry, its position is not compared
    limits: StateLimits = field(default_factory=StateLimits)
    gate: StampGate = field(default_factory=StampGate)
    # Arrival on this node's clock [ns], (frame_id, child_frame_id) and p_WB_W of the last accepted one.
    _last: tuple[int, tuple[str, str], FloatArray] | None = None

    def accept(self, odometry: OdometryFields, now_ns: int) -> State | Refusal:
        """The state of an odometry if it is plausible at ``now_ns`` (this node's clock), else why not."""
        state = state_from_odometry_values(odometry.values)
        if isinstance(state, Refusal):
            return state
        p_WB_W, v_WB_W, _, w_WB_B = state
        stamp_ns = odometry.stamp_ns
        frames = (odometry.frame_id, odometry.child_frame_id)
        refusal = (
            self.limits.check(p_WB_W=p_WB_W, v_WB_W=v_WB_W, w_WB_B=w_WB_B, what="odometry")
            or self._unstamped(stamp_ns, now_ns)
            or self._moved(now_ns, frames, p_WB_W)
            # Last: the gate remembers the stamp it accepts, and a refused message must leave no trace.
            or self.gate.check(stamp_ns, now_ns, "odometry")
        )
        if refusal is not None:
            return refusal
        self._last = (now_ns, frames, p_WB_W)
        return state

    def _unstamped(self, stamp_ns: int, now_ns: int) -> Refusal | None:
        if stamp_ns == 0 and now_ns > self.gate.future_tolerance_s * NS_PER_S:
            return Refusal(
                "unstamped odometry", f"stamp 0 while this node's clock reads {now_ns / NS_PER_S:.3f} s"
            )
        return None

    def _moved(self, now_ns: int, frames: tuple[str, str], p_WB_W: FloatArray) -> Refusal | None:
        if self._last is None or now_ns - self._last[0] > self.forget_after_ns:
            return None
        last_ns, last_frames, last_p_WB_W = self._last
        if frames != last_frames:
            return Refusal(
                "wrong frame",
                f"frame_id {frames[0][:40]!r}, child_frame_id {frames[1][:40]!r}; odometry so far in "
                f"{last_frames[0]!r}, {last_frames[1]!r}",
            )
        # A clock that went back (simulated time restarted) gives no time: only the margin is allowed.
        dt_s = max(now_ns - last_ns, 0) / NS_PER_S
        return jump_refusal(last_p_WB_W, p_WB_W, dt_s, self.limits, "odometry position")


class ControllerNode(Node):
    """Position and yaw control of one vehicle; see the module docstring."""

    # Reads /clock itself (module docstring): it may spin on the EventsExecutor (entry.make_executor).
    KEEPS_ITS_OWN_SIMULATED_TIME = True

    def __init__(
        self,
        *,
        clock_subscription: bool = True,
        bundled: Callable[[bytes], None] | None = None,
        **kwargs: Any,
    ):
        """``clock_subscription`` false: the process's SharedClock (nodes/clock.py) tells ``time`` instead.

        ``bundled``: the node is one of a fleet's (nodes/fleet_controller.py) that exchanges bundles: it
        neither subscribes to ``odom`` nor publishes ``motor_speed_cmd``; its fleet hands it each
        odometry (:meth:`on_odometry`) and ``bundled`` takes each serialised command.
        """
        super().__init__("controller", **kwargs)
        name = self.declare_parameter(
            "airframe",
            "x8_octorotor",
            NodeParameter(
                "airframe",
                "",
                "airframe config name or YAML path (its controller section gives the gains)",
                read_only=True,
            ).descriptor(),
        ).value
        self.airframe = load_airframe(name)
        gains = airframe_gains(self.airframe)
        specs = controller_parameters(gains.as_dict())
        self._specs = {spec.name: spec for spec in specs}
        values = declare_parameters(self, specs)
        self.law = SaturationController(self.airframe, gains.replace(**{k: values[k] for k in GAIN_UNITS}))
        self._odom_timeout_ns = round(values["odom_timeout_s"] * 1e9)
        self._odometry_check = OdometryCheck(forget_after_ns=self._odom_timeout_ns)
        self._state: State | None = None
        self._state_received_ns = 0
        self._target: tuple[FloatArray, float] | None = None
        self._scheduled = SetpointQueue()
        self._state_for_tick = StateForTick()
        self._clock_ticks = ClockTicks(round(1e9 / self.law.gains.rate_hz))
        self._odom_frame = ""
        self._stale = False
        self._odom_refusals = RefusalCounter(self.get_logger().warning, "odom")
        self._setpoint_refusals = RefusalCounter(self.get_logger().warning, "setpoint")
        self._output_refusals = RefusalCounter(self.get_logger().error, "own motor_speed_cmd")
        self._effectiveness_refusals = RefusalCounter(self.get_logger().warning, "rotor_effectiveness")
        self._fault_tolerant = bool(values["fault_tolerant_allocation"])
        self._effectiveness_filter = EffectivenessFilter(self.airframe.n_rotors)
        # A confident healthy diagnosis: what brings the filter back to the nominal allocation.
        self._all_healthy = (np.ones(self.airframe.n_rotors), np.zeros(self.airframe.n_rotors))
        self._diagnosis: tuple[FloatArray, FloatArray] | None = None  # latest accepted (estimate, std)
        self._diagnosis_given: tuple[Any, Any] | None = None  # the last one given to the filter
        self._reallocated: list[int] = []  # rotors (0-based) whose effectiveness in use is reduced
        self._yaw_warned = False
        self._command_writer = RotorCommandWriter(self.airframe.n_rotors)
        self._last_command: tuple[int, bytes] | None = None  # (stamp [ns], the command published)
        self._reset_fence = ResetFence(self._odometry_check.gate.future_tolerance_s)
        self._future_tolerance_ns = round(self._odometry_check.gate.future_tolerance_s * NS_PER_S)

        self._command_pub: Publisher | None = None
        self._send_command: Callable[[bytes], None]
        if bundled is None:
            self._command_pub = self.create_publisher(JointState, "motor_speed_cmd", 10)
            self._send_command = self._command_pub.publish
            # Depth 1: the law wants the newest state; a backlog would fly a starved controller on old ones.
            # Serialised: read by nodes/cdr.py in a fraction of what rclpy's Odometry object costs.
            subscribe(self, Odometry, "odom", self.on_odometry, 1, raw=True)
        else:
            self._send_command = bundled
        # As deep as the schedule: a mission sent at once must not lose its first setpoints to its last.
        subscribe(self, PoseStamped, "setpoint", self._on_setpoint, SETPOINT_QUEUE_LENGTH)
        subscribe(self, Float64MultiArray, "rotor_effectiveness", self._on_effectiveness, 10)
        self.add_on_set_parameters_callback(lambda params: check_parameters(self._specs, params))
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._wall_timer = self.create_timer(
            1.0 / self.law.gains.rate_hz, self._on_timer, clock=steady_clock()
        )
        offer_reset(
            self,
            self._reset,
            lambda message: frame_refusal(message, self._odom_frame),
            self._odometry_check.gate.future_tolerance_s,
            lambda: self.time.now_ns() if self.time.running else None,
        )
        self.time = NodeTime(self, self._on_simulated_clock, subscribe=clock_subscription)
        if self.time.simulated:
            self._wall_timer.cancel()
        self.get_logger().info(
            f"{self.airframe.name}: seed 1 saturation law at {self.law.gains.rate_hz:g} Hz"
        )

    def on_odometry(self, data: bytes) -> None:
        """A serialised Odometry of this vehicle (its ``odom`` topic, or its fleet's bundle)."""
        if not self.time.running:
            # No time yet to judge its stamp by; a lockstep simulator resends the state it waits at.
            return
        odometry = odometry_fields_from_cdr(data)
        if isinstance(odometry, Refusal):
            self._odom_refusals.refuse(odometry.reason, odometry.detail)
            return
        now_ns = self.time.now_to_judge(odometry.stamp_ns, self._future_tolerance_ns)
        if self._reset_fence.stale(odometry.stamp_ns, now_ns):
            return
        state = self._odometry_check.accept(odometry, now_ns)
        if isinstance(state, Refusal):
            self._odom_refusals.refuse(state.reason, state.detail)
            return
        self._state, self._state_received_ns = state, now_ns
        self._odom_frame = odometry.frame_id
        if self._target is None:
            self._target = (state[0].copy(), float(quat_to_euler(state[2])[2]))
        if self.time.simulated:
            stamp_ns = odometry.stamp_ns
            resent = stamp_ns == self._state_for_tick.newest_ns
            waiting_tick_ns = self._state_for_tick.state(stamp_ns)
            if waiting_tick_ns is not None:
                self._control(waiting_tick_ns)
            elif self._state_of_next_tick(stamp_ns):
                self._clock_ticks.clock(stamp_ns)
                self._tick(stamp_ns)
            elif resent and self._last_command is not None and self._last_command[0] == stamp_ns:
                self._send_command(self._last_command[1])

    def _state_of_next_tick(self, stamp_ns: int) -> bool:
        """Whether a state is stamped at the next tick, with the clock heard at most one period before it.

        That state is the tick (module docstring): its simulator has reached the tick's time and publishes
        the /clock that says so right after it. The one-period bound keeps a state stamped ahead of its
        simulator (a stray publisher) from moving the ticks off the clock.
        """
        clock_ns = self.time.simulated_now_ns
        return (
            clock_ns is not None
            and stamp_ns == self._clock_ticks.next_ns
            and stamp_ns - clock_ns <= self._clock_ticks.period_ns
        )

    def _on_setpoint(self, message: PoseStamped) -> None:
        frame = message.header.frame_id
        if frame and self._odom_frame and frame != self._odom_frame:
            self._setpoint_refusals.refuse(
                "wrong frame", f"frame_id {frame[:40]!r}, odometry is in {self._odom_frame!r}"
            )
            return
        target = setpoint_from_pose(message)
        if not isinstance(target, Refusal):
            target = self._odometry_check.limits.check(p_WB_W=target[0], what="setpoint") or target
        if isinstance(target, Refusal):
            self._setpoint_refusals.refuse(target.reason, target.detail)
            return
        stamp_ns, now_ns = stamp_to_ns(message.header.stamp), self.time.now_ns()
        if stamp_ns <= now_ns:
            self._target = target
            return
        refusal = self._scheduled.schedule(stamp_ns, target, now_ns)
        if refusal is not None:
            self._setpoint_refusals.refuse(refusal.reason, refusal.detail)

    def _activate_due_setpoints(self, now_ns: int) -> None:
        target = self._scheduled.due(now_ns)
        if target is not None:
            self._target = target

    def _on_effectiveness(self, message: Float64MultiArray) -> None:
        diagnosis = effectiveness_from_message(message, self.airframe.n_rotors)
        if isinstance(diagnosis, Refusal):
            self._effectiveness_refusals.refuse(diagnosis.reason, diagnosis.detail)
            return
        self._diagnosis = diagnosis

    def _effectiveness(self, t_s: float) -> FloatArray:
        """The effectiveness the allocator uses now (module docstring); logs when reallocation starts/ends."""
        diagnosis: tuple[FloatArray, FloatArray] | tuple[None, None]
        if not self._fault_tolerant:
            diagnosis = self._all_healthy
        elif self._diagnosis is None:
            diagnosis = NOTHING_KNOWN
        else:
            diagnosis = self._diagnosis
        given_already = diagnosis is self._diagnosis_given
        unchanged = given_already and self._effectiveness_filter.settled
        self._diagnosis_given = diagnosis
        # Given already: the filter holds it, at almost no cost once settled (EffectivenessFilter).
        given = NOTHING_KNOWN if given_already else diagnosis
        effectiveness = self._effectiveness_filter.update(t_s, *given)
        if unchanged:
            return effectiveness
        reallocated = [int(k) for k in np.flatnonzero(effectiveness < 1.0 - REALLOCATION_NOTICE)]
        if reallocated != self._reallocated:
            self._reallocated = reallocated
            self._yaw_warned = False
            self._log_reallocation(effectiveness)
        return effectiveness

    def _log_reallocation(self, effectiveness: FloatArray) -> None:
        if not self._reallocated:
            self.get_logger().info("fault-tolerant allocation ends: every rotor back, nominal allocation")
            return
        self.get_logger().info(
            "fault-tolerant allocation: reallocating around "
            + ", ".join(f"rotor {k + 1} (effectiveness {effectiveness[k]:.2f})" for k in self._reallocated)
        )
        if self._diagnosis is not None:
            estimate, std = self._diagnosis
            self.get_logger().debug(
                "diagnosed "
                + ", ".join(f"rotor {k + 1} {estimate[k]:.2f} ± {std[k]:.2f}" for k in self._reallocated)
                + f"; the effectiveness in use follows with {self._effectiveness_filter.time_constant_s:g} s"
            )

    def _on_simulated_clock(self, now_ns: int) -> None:
        if self._clock_ticks.clock(now_ns):
            self._tick(now_ns)

    def _on_timer(self) -> None:
        self._tick(self.time.now_ns())

    def _tick(self, now_ns: int) -> None:
        if self.time.simulated and not self._state_for_tick.tick(now_ns):
            return  # the odometry of this tick is on its way: computed when it arrives
        if self.time.simulated and self._state is None:
            # After a reset: no command until odometry comes, and in lockstep none comes (only resends)
            # until this tick has its command; so it waits for that odometry as for one on its way.
            self._state_for_tick.waiting_tick_ns = now_ns
            return
        self._control(now_ns)

    def _control(self, now_ns: int) -> None:
        """The law at ``now_ns`` (this node's clock) on the newest state; publishes its command."""
        self._activate_due_setpoints(now_ns)
        if self._state is None or self._target is None:
            return
        if now_ns - self._state_received_ns > self._odom_timeout_ns:
            if not self._stale:
                self.get_logger().warning("odometry is stale: no motor commands until it returns")
            self._stale = True
            return
        self._stale = False
        p, v, q, w = self._state
        t_s = now_ns * 1e-9
        output = self.law.update(t_s, p, v, q, w, *self._target, effectiveness=self._effectiveness(t_s))
        yaw_given_up = output.allocation.yaw_fraction < YAW_GIVEN_UP_FRACTION
        if self._reallocated and yaw_given_up and not self._yaw_warned:
            self._yaw_warned = True
            self.get_logger().warning(
                f"yaw authority given up: {100 * output.allocation.yaw_fraction:.0f} % of the wanted yaw "
                "torque kept; the heading may drift"
            )
        speeds = output.omega_cmd_rad_s.tolist()
        if not all(0.0 <= speed < math.inf for speed in speeds):  # NaN fails every comparison
            self._output_refusals.refuse(
                "non-finite or negative rotor speed",
                f"{format_vector(speeds)} rad/s from position {format_vector(p)} m, velocity "
                f"{format_vector(v)} m/s, body rate {format_vector(w)} rad/s: nothing published, law reset",
            )
            self.law.reset()
            return
        # Serialised here (nodes/cdr.py); kept: a lost command is sent again from it (on_odometry).
        self._last_command = (now_ns, self._command_writer.write(now_ns, speeds))
        self._send_command(self._last_command[1])

    def _reset(self, cause: str, reset_stamp_ns: int | None) -> str:
        """Start over (module docstring); one line saying what was dropped."""
        waiting = len(self._scheduled)
        self.law.reset()
        self._scheduled.clear()
        self._target = None
        self._state = None
        self._stale = False
        self._odometry_check = OdometryCheck(forget_after_ns=self._odom_timeout_ns)
        if reset_stamp_ns is None:
            self._reset_fence.open()
        else:
            self._reset_fence.close(reset_stamp_ns, self.time.now_ns())
        line = (
            f"reset by {cause}: integrals and {waiting} waiting setpoints cleared; "
            "holding the next odometry's pose"
        )
        self.get_logger().info(line)
        return line

    def _apply_parameters(self, parameters: list[Any]) -> None:
        changes = {p.name: float(p.value) for p in parameters if p.name in GAIN_UNITS}
        if changes:
            self.law.set_gains(self.law.gains.replace(**changes))
        for parameter in parameters:
            if parameter.name == "fault_tolerant_allocation":
                self._fault_tolerant = bool(parameter.value)
                self.get_logger().info(
                    "fault-tolerant allocation "
                    + ("on: allocating with rotor_effectiveness" if self._fault_tolerant else "off: nominal")
                )
            if parameter.name == "use_sim_time":
                self.time.set_simulated(bool(parameter.value))
                self._state_for_tick = StateForTick()
                self._clock_ticks = ClockTicks(self._clock_ticks.period_ns)
                if self.time.simulated:
                    self._wall_timer.cancel()
                else:
                    self._wall_timer.reset()
            if parameter.name == "odom_timeout_s":
                self._odom_timeout_ns = round(float(parameter.value) * 1e9)
                self._odometry_check.forget_after_ns = self._odom_timeout_ns


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run multirotor_ros controller`` and ``multirotor node controller``."""
    return run_node(ControllerNode, args)
