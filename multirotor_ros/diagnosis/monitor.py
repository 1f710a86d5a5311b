"""The identifier node's logic without ROS: checked samples in, estimates, residuals and diagnosis out.

:class:`FlightMonitor` takes rotor speeds and the vehicle's state as they arrive (stamps in integer
nanoseconds, already converted to SI, ENU/FLU) and

1. checks them: a stamp that repeats or goes back is refused (with the reason a node counts), and so is
   a state that is not physically plausible (:class:`~multirotor_ros.plausibility.StateLimits`), or not
   consistent with the last accepted state (see below), and rotor speeds above the airframe's maximum
   (the simulator clamps up to twice the maximum, but such a report is not the rotor's speed); a refused
   message is missing data, for the identifier and the observer alike (see "Breaks" below), and so is a
   sample that passes these checks but surprises the observer far beyond its noise, e.g. with rotor
   speeds that are not the rotors' (:class:`~multirotor_ros.diagnosis.residuals.InnovationGate`:
   isolated ones only; the samples of a surprise that lasts are used, late). Each state sample is paired
   with the rotor speeds at its stamp (interpolated between the reports around it), waiting for them
   if they come later (up to ``max_wait_s`` of stamps); a sample whose rotor speeds are not known,
   because no report came after it or one is missing around it, is skipped and counted (the speeds of
   another moment are not its: in a manoeuvre the rotors change speed within their time constant,
   12–30 ms); one stamped before the time line's first report is skipped as expected, not as a fault of
   the input (:attr:`StepResult.skipped_as_expected`);
2. diagnoses every sample (:class:`~multirotor_ros.diagnosis.diagnoser.RotorDiagnoser`) taken in free
   flight: while something may hold the vehicle (the ground under it, a hand, lying on its side;
   :mod:`multirotor_ros.diagnosis.contact` gives the rules and their physics) nothing is identified or
   diagnosed, since no model has the support's force;
3. identifies (:class:`~multirotor_ros.ident.rls.OnlineIdentifier`) from each sample with the
   acceleration measured by the IMU, or else the central difference of the velocity over the two
   neighbouring samples (so the identifier runs one sample behind), gated on its force residual
   (ident/rls.py); not while the detector suspects a fault, so that a fault is not learnt as a new
   thrust constant, nor while it cannot tell after a break (held, or learning the noise again: a fault
   that came with a gap would otherwise be learnt for a second before it is found); every
   ``refit_period_s`` it refits the window and the diagnosis switches to the refitted model;
4. records what it used (:class:`~multirotor_ros.diagnosis.record.FlightRecord`) and resumes from it.

Breaks. A sample is missing when its state message never came or was refused, when it has no rotor
speeds of its time, or while the vehicle may be held. A loaded machine loses samples (a publisher or
this node starved, a queue overflowed); that is missing data, never evidence. The span from the last
sample that had data to the next one that has says what was lost:

- longer than ``max_gap_s`` (a few sample periods), a gap: the observer restarts (no derivative is
  taken across the gap), and the detector waits for it to settle and learns the residual noise again
  before it may alarm (diagnosis/diagnoser.py, detection.py). A warning says so (an event when the
  vehicle was held before: its take-off);
- longer than ``HOLE_PERIODS`` typical sample intervals (one or a few samples lost), a hole: the
  observer steps over it (and over any samples the innovation gate held since), but its sliding mode
  takes about twice the step to find its way back (on simulated X8 flights, stepping over 40 ms
  raised the largest loss estimate from 0.4 to 1.2 times the alarm threshold, back to 0.4 within
  80 ms; 130 ms steps took 300 ms). The samples of the next ``HOLD_SPANS`` steps are kept from the
  detector, as neither evidence nor noise, and an alarm's persistence starts again after them;
- a node whose clock goes back (a restarted simulator) calls :meth:`FlightMonitor.restart`: stamps of
  the old time line are forgotten and the observer restarts, as after a gap. Times in results go on
  from where they were, so that the identifier's window stays in order.

Samples the innovation gate holds back had data: they are no break. If the surprise lasts (a fault, a
manoeuvre harder than the model follows) they are used after all, in order; if it does not, they were
bad messages, dropped, and the observer steps over them without holding the detector (a fault's first
samples may be among them: measured on simulated X8 faults, holding doubled the slowest detections).
The typical sample interval is the
lower quartile of the last ``TYPICAL_MEMORY`` spans, at least 1/``sample_rate_hz``, so that slower
odometry is not a string of holes.

Consistent with the last accepted state means: it got there in the time between their stamps without
moving, turning or spinning up faster than physics allows. The velocity changed by at most
``StateLimits.acceleration_m_s2`` times that time, the attitude turned by at most
``StateLimits.body_rate_rad_s`` times it, the body rate changed by at most what the rotors' largest
torque about each axis can do, twice over (:func:`angular_acceleration_limit`), the position moved
by at most ``StateLimits.speed_m_s`` times it (two refused positions that agree with each other are
taken: the vehicle is there). A wrong attitude, rate or velocity in one sample would otherwise give the
observer a model derivative off by up to twice the gravity for one step, which its sliding mode turns
into a transient the size of a stopped rotor. The bounds widen with the time since the last accepted
state, so that a wrong state once accepted is outgrown within a fraction of a second. Since every
velocity step is bounded, so is the central difference the identifier learns from.

Samples are processed at ``sample_rate_hz`` on average: faster state messages are thinned out (a
250 Hz odometry is taken at 100 Hz, samples 8 or 12 ms apart), which bounds the CPU the node needs.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from multirotor_ros.diagnosis.contact import SupportWatch
from multirotor_ros.diagnosis.detection import DetectionSettings, DetectorOutput
from multirotor_ros.diagnosis.diagnoser import RotorDiagnoser, RotorReport, rotor_reports
from multirotor_ros.diagnosis.record import FlightRecord, window_samples
from multirotor_ros.diagnosis.residuals import InnovationGate, ObserverSettings
from multirotor_ros.ident.rls import Estimate, OnlineIdentifier, OnlineSettings, RefitResult, RlsError
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.effects import EFFECTS
from multirotor_ros.model.rotation import FloatArray, quat_to_matrix
from multirotor_ros.model.state import StateBatch
from multirotor_ros.plausibility import StateLimits, format_vector, jump_refusal

NS = 1_000_000_000
# Breaks (module docstring): a span longer than this many typical sample intervals is a hole, and the
# detector is kept from the samples of this many spans after it; typical over this many spans.
HOLE_PERIODS = 1.5
HOLD_SPANS = 2.5
TYPICAL_MEMORY = 50
# Sensor noise on top of the physical bounds of the consistency check (module docstring).
ATTITUDE_NOISE_RAD = 0.05
BODY_RATE_NOISE_RAD_S = 0.5
# ESC speed reports are noisy (the simulated ones by 2 rad/s): up to this factor above the airframe's
# maximum, a report is a rotor at its maximum; beyond it, not a speed the rotor can have.
SPEED_REPORT_MARGIN = 1.02


def lower_quartile(values: FloatArray) -> float:
    """``np.quantile(values, 0.25)`` to the bit (its linear method), without its overhead: once per sample."""
    position = (values.size - 1) * 0.25
    below = int(position)
    above = min(below + 1, values.size - 1)
    ordered = np.partition(values, (below, above))
    low, high, weight = float(ordered[below]), float(ordered[above]), position - below
    # numpy's interpolation, from the nearer end
    return high - (high - low) * (1 - weight) if weight >= 0.5 else low + (high - low) * weight


@dataclass(frozen=True)
class MonitorSettings:
    """Sample handling of the identifier node."""

    sample_rate_hz: float = 100.0  # [Hz] state samples processed per second, on average
    max_gap_s: float = 0.05  # [s] data missing for longer is a gap (module docstring: Breaks)
    max_wait_s: float = 0.5  # [s] (of stamps) a state sample waits at most this long for its rotor speeds

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value!r}")


def fittable_effects(airframe_effects: list[str]) -> list[str]:
    """The airframe's own effects that the online identifier can fit (those with a linear parameter)."""
    return [e for e in airframe_effects if any(p.linear for p in EFFECTS[e].parameter_list(None))]


def angular_acceleration_limit(airframe: Airframe) -> FloatArray:
    """(3,) [rad/s²] per body axis: twice what the rotors can do, all at full speed in the helping sense.

    Twice, for what the rotor model leaves out (gusts, a propeller strike); more is not a flight.
    """
    torque_N_m = np.abs(airframe.allocation[1:]).sum(axis=1) * airframe.rotor_speed_max_rad_s**2
    return 2.0 * torque_N_m / np.diag(airframe.inertia_kg_m2)


@dataclass(frozen=True)
class _Accepted:
    """The last accepted state message, which the next one must be consistent with."""

    stamp_ns: int
    p_WB_W: FloatArray
    v_WB_W: FloatArray
    q_WB: FloatArray  # unit
    w_WB_B: FloatArray


@dataclass(frozen=True)
class Refused:
    """A message the monitor refused: ``reason`` is the counting category, ``detail`` the specifics."""

    reason: str
    detail: str


@dataclass
class StepResult:
    """What one state sample produced (None fields: nothing new of that kind)."""

    t: float  # [s] since the first sample (or the record's origin); the stamp is the message clock
    stamp_ns: int
    accel_residual_W: FloatArray | None = None  # measured minus modelled force per unit mass [m/s²]
    detection: DetectorOutput | None = None
    refit: RefitResult | None = None
    warnings: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)  # worth a line in the log, not a warning
    skipped: str | None = None  # why the sample was not used (or not learnt from), as a counting reason
    skipped_detail: str = ""  # the specifics of ``skipped``

    @property
    def skipped_as_expected(self) -> bool:
        """Skipped for a reason that is no fault of the input: held on the ground, or before the speeds came.

        A state stamped before the first rotor-speed report of the time line has nothing to be paired
        with: every identifier that joins a running simulator gets one (odometry at 250 Hz, speeds at
        100 Hz), which is no news worth a warning.
        """
        return self.skipped in ("resting", "before the first motor_speeds")


@dataclass(frozen=True)
class _Sample:
    """A state message as one state; its rotor speeds are NaN until paired with those of its stamp."""

    stamp_ns: int
    state: StateBatch

    @property
    def t(self) -> float:
        """[s] since the monitor's time origin."""
        return float(self.state.t[0])


class FlightMonitor:
    """Identifier + diagnoser + record for one vehicle (module docstring)."""

    def __init__(
        self,
        airframe: Airframe,
        effect_ids: list[str],
        online: OnlineSettings | None = None,
        observer: ObserverSettings | None = None,
        detection: DetectionSettings | None = None,
        settings: MonitorSettings | None = None,
        record: FlightRecord | None = None,
        resume: bool = True,
    ):
        """``record``: where what is used goes; ``resume``: whether to start from what it holds."""
        self.airframe = airframe
        self.settings = settings or MonitorSettings()
        self.limits = StateLimits()
        self._angular_acceleration_max = angular_acceleration_limit(airframe)
        self.identifier = OnlineIdentifier(airframe, effect_ids, online)
        self.diagnoser = RotorDiagnoser(self.identifier.model(), 1, observer, detection)
        self.support = SupportWatch(airframe, self.diagnoser.model.gravity_m_s2)
        self._innovation_gate = InnovationGate()
        self.record = record
        self._speeds: deque[tuple[int, FloatArray]] = deque(maxlen=64)
        self._first_speeds_ns: int | None = None  # the stamp of the time line's first rotor-speed report
        self._last_state_ns: int | None = None
        self._last_accepted: _Accepted | None = None
        self._jumped_position: tuple[int, FloatArray] | None = None  # the last position refused as a jump
        self._last_processed: _Sample | None = None
        self._previous: _Sample | None = None  # two samples back, for the central difference
        self._origin_ns: int | None = None
        self._t_after_restart_s: float | None = None  # where times go on after restart()
        self._next_due_ns = 0
        self._waiting: deque[_Sample] = deque()  # state samples waiting for their rotor speeds
        self._last_data_ns: int | None = None  # the last sample that had data (module docstring: Breaks)
        self._spans_s: deque[float] = deque(maxlen=TYPICAL_MEMORY)
        self._hole_before_next = False  # samples were missing since the last one processed
        self._held: list[tuple[_Sample, StepResult]] = []  # held by the innovation gate, undecided
        self._was_resting = False
        self._warnings: list[str] = []  # said with the next result
        self._first_t: float | None = None  # t of the first sample taken: time 0 of since_start_s
        self.notes: list[str] = []
        if record is not None and resume:
            self._resume(record)

    # ------------------------------------------------------------------ resume and state

    def _resume(self, record: FlightRecord) -> None:
        resumed = record.resume()
        self.notes += resumed.notes
        if resumed.state is not None:
            self._restore(resumed.state)
        if resumed.log is not None:
            samples = window_samples(resumed.log, self.identifier.settings.window_s)
            if samples is not None:
                self.identifier.load_window(samples)
                self.notes.append(f"window refilled with {samples.size} recorded samples")
                self.diagnoser.set_model(self.identifier.model())

    def _restore(self, state: dict[str, FloatArray]) -> None:
        identifier_state = {k[11:]: v for k, v in state.items() if k.startswith("identifier_")}
        try:
            self.identifier.resume(identifier_state)
        except RlsError as error:
            self.notes.append(f"saved estimate not used: {error}")
        else:
            self.diagnoser.set_model(self.identifier.model())
            self.notes.append(f"estimate resumed after {self.identifier.rls.n_updates} samples")
        if "detector_baseline" in state and "detector_mad" in state:
            try:
                self.diagnoser.detector.resume(
                    {"baseline": state["detector_baseline"], "mad": state["detector_mad"]}
                )
                self.notes.append("detector resumed with its learnt noise (no warm-up)")
            except ValueError as error:
                self.notes.append(f"saved detector state not used: {error}")

    def learnt_state(self) -> dict[str, FloatArray]:
        """What the record keeps of the learnt state (identifier, detector noise and bias)."""
        state = {f"identifier_{key}": value for key, value in self.identifier.state().items()}
        if self.diagnoser.detector.warmed_up:
            learnt = self.diagnoser.detector.learnt()
            state["detector_baseline"] = learnt["baseline"]
            state["detector_mad"] = learnt["mad"]
        return state

    def flush_record(self) -> None:
        """Write what the record holds so far (the node does it every second)."""
        if self.record is not None:
            self.record.flush(self.learnt_state())

    # ------------------------------------------------------------------ inputs

    def rotor_speeds(self, stamp_ns: int, speeds: FloatArray) -> list[StepResult] | Refused:
        """Take a rotor-speed message (N speeds [rad/s]); refuse a repeated or older stamp or a bad speed.

        A speed that is not finite, negative or above the airframe's maximum is not learnt from.

        Returns what the state samples that waited for these speeds produced.
        """
        if self._speeds and stamp_ns <= self._speeds[-1][0]:
            kind = "duplicated stamp" if stamp_ns == self._speeds[-1][0] else "stamp out of order"
            return Refused(kind, self._stamp_detail("motor_speeds", stamp_ns, self._speeds[-1][0]))
        omega = np.asarray(speeds, dtype=float).copy()
        highest = SPEED_REPORT_MARGIN * self.airframe.rotor_speed_max_rad_s
        if omega.shape != (self.airframe.n_rotors,) or not np.all((omega >= 0) & (omega <= highest)):
            return Refused(
                "rotor speed outside the airframe's range",
                f"speeds {format_vector(omega)} rad/s; the rotors turn at 0 .. "
                f"{self.airframe.rotor_speed_max_rad_s:g} rad/s (not learnt from)",
            )
        self._speeds.append((stamp_ns, omega))
        if self._first_speeds_ns is None:
            self._first_speeds_ns = stamp_ns
        return self._drain()

    def restart(self) -> None:
        """Start a new time line: the caller's clock went back (a restarted simulator), the caller says so.

        Stamps of the old time line are forgotten (the new ones are older), waiting samples dropped, the
        observer restarted as after a gap (module docstring: Breaks); what was learnt is kept.
        """
        if self._origin_ns is not None and self._last_state_ns is not None:
            period_s = 1.0 / self.settings.sample_rate_hz
            self._t_after_restart_s = (self._last_state_ns - self._origin_ns) * 1e-9 + period_s
            self._origin_ns = None
        self._speeds.clear()
        self._first_speeds_ns = None
        self._waiting.clear()
        self._held.clear()
        self._last_state_ns = None
        self._last_accepted = None
        self._jumped_position = None
        self._last_processed = self._previous = None
        self._last_data_ns = None
        self._hole_before_next = False
        self._next_due_ns = 0
        self.diagnoser.restart_observer()

    def _speeds_for(self, stamp_ns: int) -> FloatArray | None:
        """The rotor speeds at ``stamp_ns``, or None when they are not known (module docstring, 1.).

        The report at ``stamp_ns``, or between the reports around it, linearly: the reported speeds are
        measured ones, continuous (rotors follow their commands with a lag), and in a manoeuvre the speeds
        of a report 8 ms old are another moment's (pairing each sample with the report before it gave the
        observer transients of a stopped rotor's size on steps, depending only on how the odometry's
        stamps fell between the reports). Not known without a report after it (a sample that waited
        ``max_wait_s`` for one: holding the report before it over raised false stopped-rotor alarms on
        steps, in real time on a loaded machine, where the speeds came late), nor when a report is missing
        between the two (more than ``HOLE_PERIODS`` typical report intervals apart).
        """
        later: tuple[int, FloatArray] | None = None
        for stamp, speeds in reversed(self._speeds):
            if stamp == stamp_ns:
                return speeds
            if stamp < stamp_ns:
                if later is None:
                    return None
                span_ns = later[0] - stamp
                if span_ns > HOLE_PERIODS * self._report_interval_ns():
                    return None
                return speeds + (later[1] - speeds) * ((stamp_ns - stamp) / span_ns)
            later = (stamp, speeds)
        return None

    def _report_interval_ns(self) -> float:
        """The typical interval between rotor-speed reports: the lower quartile of the recent ones."""
        stamps = np.fromiter((stamp for stamp, _ in self._speeds), dtype=float, count=len(self._speeds))
        return lower_quartile(np.diff(stamps))

    def state(
        self,
        stamp_ns: int,
        p_WB_W: FloatArray,
        v_WB_W: FloatArray,
        q_WB: FloatArray,
        w_WB_B: FloatArray,
        a_W: FloatArray | None = None,
    ) -> list[StepResult] | Refused:
        """Take a validated state sample (odometry, or pose + IMU with ``a_W``); see the module docstring.

        A sample waits until rotor speeds stamped at or after it have arrived (so that the two topics
        may arrive in any order and in bursts), or until it is ``max_wait_s`` older than the newest state;
        returns what the samples processed now produced (often one, none while waiting).
        """
        if self._last_state_ns is not None and stamp_ns <= self._last_state_ns:
            kind = "duplicated stamp" if stamp_ns == self._last_state_ns else "stamp out of order"
            return Refused(kind, self._stamp_detail("state", stamp_ns, self._last_state_ns))
        values = [np.asarray(x, dtype=float) for x in (p_WB_W, v_WB_W, q_WB, w_WB_B)]
        if a_W is not None:
            values.append(np.asarray(a_W, dtype=float))
        refusal = self._implausible(stamp_ns, values)
        if refusal is not None:
            return refusal
        self._warnings += [] if self._origin_ns is not None else self._start_clock(stamp_ns)
        assert self._origin_ns is not None
        if self._first_t is None:
            self._first_t = (stamp_ns - self._origin_ns) * 1e-9
        self._last_state_ns = stamp_ns
        q_WB = values[2] / np.linalg.norm(values[2])
        self._last_accepted = _Accepted(stamp_ns, values[0], values[1], q_WB, values[3])
        if stamp_ns < self._next_due_ns:
            return []
        # Due times on a grid of the sample period, so that 250 Hz odometry gives 100 samples per second
        # on average (8 and 12 ms apart) rather than one every 12 ms.
        period_ns = round(NS / self.settings.sample_rate_hz)
        self._next_due_ns = max(self._next_due_ns + period_ns, stamp_ns + period_ns // 2)
        state = StateBatch(
            t=np.array([(stamp_ns - self._origin_ns) * 1e-9]),
            p_WB_W=values[0][None],
            v_WB_W=values[1][None],
            R_WB=quat_to_matrix(q_WB)[None],
            w_WB_B=values[3][None],
            omega=np.full((1, self.airframe.n_rotors), np.nan),
            a_WB_W=values[4][None] if a_W is not None else None,
        )
        self._waiting.append(_Sample(stamp_ns, state))
        return self._drain()

    def _implausible(self, stamp_ns: int, values: list[FloatArray]) -> Refused | None:
        """Why a state (p, v, q, w[, a]) is not one a multirotor can be in, or None."""
        what = self._at("state", stamp_ns)
        refusal = self.limits.check(
            values[0], values[1], values[3], values[4] if len(values) > 4 else None, what=what
        )
        if refusal is not None:
            return Refused(refusal.reason, refusal.detail)
        norm = float(np.linalg.norm(values[2]))
        if not (math.isfinite(norm) and abs(norm - 1.0) <= self.limits.quaternion_norm_tolerance):
            return Refused("invalid orientation", f"{what}: quaternion {format_vector(values[2])}")
        return self._inconsistent(stamp_ns, values)

    def _inconsistent(self, stamp_ns: int, values: list[FloatArray]) -> Refused | None:
        """Why a plausible state cannot follow the last accepted one (module docstring), or None."""
        last = self._last_accepted
        if last is None:
            return None
        dt_s = (stamp_ns - last.stamp_ns) * 1e-9
        p_WB_W, v_WB_W, q_WB, w_WB_B = values[:4]
        refusal = jump_refusal(last.p_WB_W, p_WB_W, dt_s, self.limits)
        if refusal is not None:
            jumped, self._jumped_position = self._jumped_position, (stamp_ns, p_WB_W)
            agrees = jumped is not None and (
                jump_refusal(jumped[1], p_WB_W, (stamp_ns - jumped[0]) * 1e-9, self.limits) is None
            )
            if not agrees:
                return Refused(refusal.reason, refusal.detail)
        velocity_change = float(np.linalg.norm(v_WB_W - last.v_WB_W))
        if velocity_change > self.limits.acceleration_m_s2 * dt_s:
            return Refused(
                "implausible velocity jump",
                f"velocity changed by {velocity_change:.6g} m/s in {dt_s:.3f} s "
                f"(at most {self.limits.acceleration_m_s2:g} m/s^2)",
            )
        cosine = abs(float(np.dot(q_WB, last.q_WB))) / float(np.linalg.norm(q_WB))
        turn = 2.0 * math.acos(min(cosine, 1.0))
        if turn > self.limits.body_rate_rad_s * dt_s + ATTITUDE_NOISE_RAD:
            return Refused(
                "implausible attitude jump",
                f"attitude turned by {math.degrees(turn):.1f} deg in {dt_s:.3f} s "
                f"(at most {self.limits.body_rate_rad_s:g} rad/s)",
            )
        rate_change = np.abs(w_WB_B - last.w_WB_B)
        if np.any(rate_change > self._angular_acceleration_max * dt_s + BODY_RATE_NOISE_RAD_S):
            return Refused(
                "implausible body rate jump",
                f"body rate changed by {format_vector(rate_change)} rad/s in {dt_s:.3f} s "
                f"(at most {format_vector(self._angular_acceleration_max)} rad/s^2)",
            )
        return None

    def _drain(self) -> list[StepResult]:
        """Process the waiting state samples whose rotor speeds are known (or that waited long enough)."""
        results = []
        newest_speeds = self._speeds[-1][0] if self._speeds else None
        patience_ns = round(self.settings.max_wait_s * NS)
        while self._waiting:
            sample = self._waiting[0]
            ready = newest_speeds is not None and newest_speeds >= sample.stamp_ns
            assert self._last_state_ns is not None
            if not ready and self._last_state_ns - sample.stamp_ns <= patience_ns:
                break
            self._waiting.popleft()
            results += self._process(sample)
        if results and self._warnings:
            results[0].warnings[:0] = self._warnings
            self._warnings = []
        return results

    def _process(self, waiting: _Sample) -> list[StepResult]:
        """The results of this sample and of the samples the innovation gate held before it, if decided."""
        result = StepResult(waiting.t, waiting.stamp_ns)
        omega = self._speeds_for(waiting.stamp_ns)
        if omega is None and (self._first_speeds_ns is None or waiting.stamp_ns < self._first_speeds_ns):
            result.skipped = "before the first motor_speeds"
            result.skipped_detail = f"{self._at('state', waiting.stamp_ns)} came before any rotor speeds"
            return [result]
        if omega is None:
            result.skipped = "no recent motor_speeds"
            result.skipped_detail = (
                f"{self._at('state', waiting.stamp_ns)} has no rotor speeds of its time (no report at or "
                f"after it within {self.settings.max_wait_s:g} s, or one missing around it)"
            )
            return [result]
        sample = _Sample(waiting.stamp_ns, waiting.state.with_omega(omega[None]))
        support = self.support.support(sample.stamp_ns, sample.state)
        if support is not None:
            if not self._was_resting:
                result.events.append(
                    f"resting at t = {self.since_start_s(sample.t):.2f} s ({support}): "
                    "nothing learnt until it flies"
                )
            self._was_resting = True
            result.skipped = "resting"
            return [*self._drop_held(), result]
        last = self._last_processed
        if self._mind_the_break(sample, result) or last is None:  # the observer starts with this one
            return [*self._drop_held(), self._use(sample, result)]
        dt_s = (sample.stamp_ns - last.stamp_ns) * 1e-9
        innovation = self.diagnoser.residuals.innovation(sample.state, dt_s)
        assert innovation is not None  # the observer has run since it started on ``last``
        verdict = self._innovation_gate.judge(innovation[0])
        if verdict == "held":
            result.skipped = "inconsistent with the model"
            result.skipped_detail = (
                f"{self._at('state', sample.stamp_ns)} surprises the observer by "
                f"{format_vector(innovation[0])} stopped rotors (x, y, z world; x, y, z body): held back as "
                "missing data"
            )
            self._held.append((sample, result))
            return []
        if verdict == "lasting":  # the held samples were the vehicle's (residuals.InnovationGate)
            held, self._held = [held for held, _ in self._held], []
            used = [self._use(h, StepResult(h.t, h.stamp_ns)) for h in held]
            return [*used, self._use(sample, result)]
        return [*self._drop_held(), self._use(sample, result)]

    def _drop_held(self) -> list[StepResult]:
        """The samples the innovation gate held were bad messages (or are stale): their results."""
        dropped, self._held = [result for _, result in self._held], []
        return dropped

    def _use(self, sample: _Sample, result: StepResult) -> StepResult:
        """Diagnose and identify from a sample that had data and passed the gate."""
        last = self._last_processed
        dt = 0.0 if last is None else (sample.stamp_ns - last.stamp_ns) * 1e-9
        if self._hole_before_next:
            # The observer steps over all of dt (the hole, and any samples the gate dropped since).
            self.diagnoser.hold(sample.t + HOLD_SPANS * dt)
            self._hole_before_next = False
        self._diagnose(sample, dt, result)
        self._identify(sample, last, result)
        self._previous = last
        self._last_processed = sample
        return result

    def _mind_the_break(self, sample: _Sample, result: StepResult) -> bool:
        """Whether a gap before this sample restarted the observer; a hole is noted (module docstring)."""
        last_ns, self._last_data_ns = self._last_data_ns, sample.stamp_ns
        span_s = 0.0 if last_ns is None else (sample.stamp_ns - last_ns) * 1e-9
        gap = span_s > self.settings.max_gap_s
        if gap:
            self.diagnoser.restart_observer()
            self._last_processed = self._previous = None
            self._hole_before_next = False
        elif last_ns is not None:
            self._hole_before_next |= self._is_hole(span_s)
        restarted = "observer restarted, noise learnt again before any alarm"
        t_s = self.since_start_s(sample.t)
        if self._was_resting:
            flying = f"flying from t = {t_s:.2f} s"
            result.events.append(f"{flying}: {restarted}" if gap else flying)
        elif gap:
            result.warnings.append(f"gap of {span_s:.3f} s in the data before t = {t_s:.2f} s: {restarted}")
        self._was_resting = False
        return gap

    def _is_hole(self, span_s: float, remember: bool = True) -> bool:
        """Whether samples are missing in a span shorter than a gap (module docstring: Breaks).

        ``remember``: the span is one between samples that had data, part of the typical interval.
        """
        if remember:
            self._spans_s.append(span_s)
        typical_s = 1.0 / self.settings.sample_rate_hz
        if span_s <= HOLE_PERIODS * typical_s:  # the quartile only when it can matter
            return False
        return span_s > HOLE_PERIODS * max(typical_s, lower_quartile(np.array(self._spans_s)))

    def _start_clock(self, stamp_ns: int) -> list[str]:
        """Times are seconds since the record's origin (resumed) or the first sample, or go on (restart())."""
        if self._t_after_restart_s is not None:
            self._origin_ns = stamp_ns - round(self._t_after_restart_s * NS)
            self._t_after_restart_s = None
            return []
        record = self.record
        if record is None:
            self._origin_ns = stamp_ns
            return []
        if record.last_stamp_ns is not None and stamp_ns <= record.last_stamp_ns:
            record.start_new_segment()
            self.identifier.reset_window()
            self._origin_ns = stamp_ns
            record.stamp_origin_ns = stamp_ns
            return [
                "the clock went back before the record's end (a restarted simulator?): new record segment, "
                "refit window cleared"
            ]
        if record.stamp_origin_ns is None:
            record.stamp_origin_ns = stamp_ns
        self._origin_ns = record.stamp_origin_ns
        return []

    def _diagnose(self, sample: _Sample, dt: float, result: StepResult) -> None:
        out = self.diagnoser.update(sample.state, dt if dt > 0 else 1.0 / self.settings.sample_rate_hz)
        result.accel_residual_W = out.residuals.accel_W[0].copy()
        result.detection = out.detection

    def _identify(self, sample: _Sample, last: _Sample | None, result: StepResult) -> None:
        """Feed the identifier: this sample with the IMU acceleration, or the one before (speed change)."""
        if sample.state.a_WB_W is not None:
            target = sample
        else:
            previous = self._previous
            if last is None or previous is None:
                return
            # With a sample missing on either side the difference is not centred on ``last``: in a
            # manoeuvre it would teach the identifier another moment's acceleration.
            if self._is_hole((sample.stamp_ns - last.stamp_ns) * 1e-9, remember=False) or self._is_hole(
                (last.stamp_ns - previous.stamp_ns) * 1e-9, remember=False
            ):
                return
            dv_W = sample.state.v_WB_W - previous.state.v_WB_W
            a_W = dv_W / ((sample.stamp_ns - previous.stamp_ns) * 1e-9)
            target = _Sample(last.stamp_ns, dataclasses.replace(last.state, a_WB_W=a_W))
        unjudged = result.detection is None or result.detection.warming_up
        if bool(self.diagnoser.any_suspicion[0]) or (unjudged and self.diagnoser.detector.warmed_up):
            return
        self.identifier.add(target.state)
        if self.record is not None:
            self.record.append(target.stamp_ns, target.state)
        if self.identifier.refit_due(target.t):
            refit = self.identifier.refit()
            if refit is not None:
                result.refit = refit
                self.diagnoser.set_model(self.identifier.model())

    # ------------------------------------------------------------------ outputs

    def estimates(self) -> tuple[Estimate, ...]:
        """The running estimates with their standard deviations."""
        return self.identifier.estimates()

    def reports(self) -> list[RotorReport]:
        """One readable status per rotor."""
        return rotor_reports(
            self.diagnoser.last,
            self.airframe.n_rotors,
            self.diagnoser.partners,
            self.diagnoser.detector.settings.error_below_effectiveness,
            clock_offset_s=self.clock_offset_s,
        )

    def effectiveness(self) -> tuple[FloatArray, FloatArray]:
        """(N,) estimated remaining effectiveness of each rotor and (N,) its standard deviation.

        What the node publishes on ``rotor_effectiveness``; see ``RotorDiagnoser.effectiveness``.
        """
        return self.diagnoser.effectiveness()

    def _at(self, what: str, stamp_ns: int) -> str:
        """``what`` and the time of its stamp in the log's words (since_start_s), once there is a time."""
        if self._origin_ns is None:
            return what
        return f"{what} at t = {self.since_start_s((stamp_ns - self._origin_ns) * 1e-9):.3f} s"

    def _stamp_detail(self, what: str, stamp_ns: int, previous_ns: int) -> str:
        """Words for a stamp that repeats or goes back: how far behind the previous one it is."""
        if stamp_ns == previous_ns:
            return f"{self._at(what, stamp_ns)}: stamped as the previous one"
        behind_ms = (previous_ns - stamp_ns) * 1e-6
        return f"{self._at(what, stamp_ns)}: stamped {behind_ms:.3f} ms before the previous one"

    def since_start_s(self, t: float) -> float:
        """[s] a time of the monitor's (``t`` of results, refits, detections) since its first sample.

        How the identifier's log says times: seconds of the messages' clock since the first sample this
        monitor took (a resumed record's origin and a restart() of the time line do not move it).
        """
        return t - (self._first_t or 0.0)

    @property
    def clock_offset_s(self) -> float:
        """Stamp [s] of time 0 of the monitor's times (t of results, refits, the record)."""
        return (self._origin_ns or 0) * 1e-9

    def set_detection_settings(self, settings: DetectionSettings) -> None:
        """Change the thresholds at run time (``ros2 param set``)."""
        self.diagnoser.set_detection_settings(settings)
