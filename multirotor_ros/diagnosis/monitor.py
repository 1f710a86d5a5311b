"""The identifier node's logic without ROS: checked samples in, estimates, residuals and diagnosis out.

:class:`FlightMonitor` takes rotor speeds and the vehicle's state as they arrive (stamps in integer
nanoseconds, already converted to SI, ENU/FLU) and

1. checks them: a stamp that repeats or goes back is refused (with the reason a node counts), and so
   is a state that is not physically plausible (:class:`~multirotor_ros.plausibility.StateLimits`),
   or not consistent with the last accepted state (see below), and rotor speeds above the airframe's
   maximum (the simulator clamps up to twice the maximum, but such a report is not the rotor's speed);
   a refused message is missing data, for the identifier and the observer alike (one missing sample,
   the observer steps over the longer interval; a longer silence is a gap), and so is a sample that
   passes these checks but surprises the observer far beyond its noise, e.g. with rotor speeds that
   are not the rotors' (:class:`~multirotor_ros.diagnosis.residuals.InnovationGate`: isolated ones
   only, a surprise that persists is a fault). Each state sample is paired
   with the rotor speeds in force at
   its stamp (the newest reported at or before it), waiting for them if they come later; a sample
   without rotor speeds at most ``motor_speed_max_age_s`` old is skipped and counted; a gap longer
   than ``max_gap_s`` is reported as a warning and restarts the observer (no derivative is taken
   across it);
2. diagnoses every sample (:class:`~multirotor_ros.diagnosis.diagnoser.RotorDiagnoser`) taken in
   flight: while the vehicle rests (on the ground, held, or lying on its side) nothing is identified or
   diagnosed, since the ground's reaction is in no model. The rule: it does not move, and its rotors
   do not hold it as they would in flight, i.e. their thrust (with the configured thrust constant, so
   that a wrong estimate cannot make a hover look like rest) is below 0.9 times the weight, or it is
   tilted more than 30° whatever its thrust (still in the air, the thrust balances the weight: 30° of
   tilt would take a side force of 58 % of the weight; a vehicle on its side is not flying);
3. identifies (:class:`~multirotor_ros.ident.rls.OnlineIdentifier`) from each sample with the
   acceleration measured by the IMU, or else the central difference of the velocity over the two
   neighbouring samples (so the identifier runs one sample behind), gated on its force residual
   (ident/rls.py); not while the detector suspects a
   fault, so that a fault is not learnt as a new thrust constant; every ``refit_period_s`` it refits the
   window and the diagnosis switches to the refitted model;
4. records what it used (:class:`~multirotor_ros.diagnosis.record.FlightRecord`) and resumes from it.

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

from multirotor_ros.diagnosis.detection import DetectionSettings, DetectorOutput
from multirotor_ros.diagnosis.diagnoser import RotorDiagnoser, RotorReport, rotor_reports
from multirotor_ros.diagnosis.record import FlightRecord, window_samples
from multirotor_ros.diagnosis.residuals import InnovationGate, ObserverSettings
from multirotor_ros.ident.rls import Estimate, OnlineIdentifier, OnlineSettings, RefitResult, RlsError
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import FloatArray, quat_to_matrix
from multirotor_ros.model.state import StateBatch
from multirotor_ros.plausibility import StateLimits, format_vector, jump_refusal

NS = 1_000_000_000
# Resting (module docstring): slower than these, and thrust below this share of the weight or tilted
# further than this from level.
RESTING_SPEED_M_S = 0.1
RESTING_RATE_RAD_S = 0.1
RESTING_THRUST_SHARE = 0.9
RESTING_TILT_RAD = math.radians(30.0)
# Sensor noise on top of the physical bounds of the consistency check (module docstring).
ATTITUDE_NOISE_RAD = 0.05
BODY_RATE_NOISE_RAD_S = 0.5
# ESC speed reports are noisy (the simulated ones by 2 rad/s): up to this factor above the airframe's
# maximum, a report is a rotor at its maximum; beyond it, not a speed the rotor can have.
SPEED_REPORT_MARGIN = 1.02


@dataclass(frozen=True)
class MonitorSettings:
    """Sample handling of the identifier node."""

    sample_rate_hz: float = 100.0  # [Hz] state samples processed per second, on average
    max_gap_s: float = 0.1  # [s] a longer silence in the state messages is a gap
    motor_speed_max_age_s: float = 0.05  # [s] rotor speeds older than this do not go with a state sample
    max_wait_s: float = 0.5  # [s] (of stamps) a state sample waits at most this long for its rotor speeds

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value!r}")


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
    ):
        self.airframe = airframe
        self.settings = settings or MonitorSettings()
        self.limits = StateLimits()
        self._angular_acceleration_max = angular_acceleration_limit(airframe)
        self.identifier = OnlineIdentifier(airframe, effect_ids, online)
        self.diagnoser = RotorDiagnoser(self.identifier.model(), 1, observer, detection)
        self._innovation_gate = InnovationGate()
        self.record = record
        self._speeds: deque[tuple[int, FloatArray]] = deque(maxlen=64)
        self._last_state_ns: int | None = None
        self._last_accepted: _Accepted | None = None
        self._jumped_position: tuple[int, FloatArray] | None = None  # the last position refused as a jump
        self._last_processed: _Sample | None = None
        self._previous: _Sample | None = None  # two samples back, for the central difference
        self._origin_ns: int | None = None
        self._next_due_ns = 0
        self._waiting: deque[_Sample] = deque()  # state samples waiting for their rotor speeds
        self._was_resting = False
        self._warnings: list[str] = []  # said with the next result
        self.notes: list[str] = []
        if record is not None:
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
            return Refused(kind, f"motor_speeds stamp {stamp_ns} ns, previous {self._speeds[-1][0]} ns")
        omega = np.asarray(speeds, dtype=float).copy()
        highest = SPEED_REPORT_MARGIN * self.airframe.rotor_speed_max_rad_s
        if omega.shape != (self.airframe.n_rotors,) or not np.all((omega >= 0) & (omega <= highest)):
            return Refused(
                "rotor speed outside the airframe's range",
                f"speeds {format_vector(omega)} rad/s; the rotors turn at 0 .. "
                f"{self.airframe.rotor_speed_max_rad_s:g} rad/s (not learnt from)",
            )
        self._speeds.append((stamp_ns, omega))
        return self._drain()

    def _speeds_for(self, stamp_ns: int) -> FloatArray | None:
        """The speeds in force at ``stamp_ns``: the newest reported at or before it, if recent enough."""
        for stamp, speeds in reversed(self._speeds):
            if stamp <= stamp_ns:
                return speeds if (stamp_ns - stamp) * 1e-9 <= self.settings.motor_speed_max_age_s else None
        return None

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
            return Refused(kind, f"state stamp {stamp_ns} ns, previous {self._last_state_ns} ns")
        values = [np.asarray(x, dtype=float) for x in (p_WB_W, v_WB_W, q_WB, w_WB_B)]
        if a_W is not None:
            values.append(np.asarray(a_W, dtype=float))
        refusal = self._implausible(stamp_ns, values)
        if refusal is not None:
            return refusal
        self._warnings += [] if self._origin_ns is not None else self._start_clock(stamp_ns)
        self._last_state_ns = stamp_ns
        q_WB = values[2] / np.linalg.norm(values[2])
        self._last_accepted = _Accepted(stamp_ns, values[0], values[1], q_WB, values[3])
        if stamp_ns < self._next_due_ns:
            return []
        # Due times on a grid of the sample period, so that 250 Hz odometry gives 100 samples per second
        # on average (8 and 12 ms apart) rather than one every 12 ms.
        period_ns = round(NS / self.settings.sample_rate_hz)
        self._next_due_ns = max(self._next_due_ns + period_ns, stamp_ns + period_ns // 2)
        assert self._origin_ns is not None
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
        what = f"state at {stamp_ns} ns"
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
            results.append(self._process(sample))
        if results and self._warnings:
            results[0].warnings[:0] = self._warnings
            self._warnings = []
        return results

    def _process(self, waiting: _Sample) -> StepResult:
        result = StepResult(waiting.t, waiting.stamp_ns)
        omega = self._speeds_for(waiting.stamp_ns)
        if omega is None:
            result.skipped = "no recent motor_speeds"
            result.skipped_detail = (
                f"state at {waiting.stamp_ns} ns has no rotor speeds within "
                f"{self.settings.motor_speed_max_age_s:g} s"
            )
            return result
        sample = _Sample(waiting.stamp_ns, waiting.state.with_omega(omega[None]))
        resting = self._resting(sample.state)
        if resting is not None:
            if not self._was_resting:
                result.events.append(
                    f"resting at t = {sample.stamp_ns * 1e-9:.2f} s (not moving, {resting}): "
                    "no identification or detection until it flies"
                )
            self._was_resting = True
            self._last_processed = self._previous = None
            result.skipped = "resting"
            return result
        if self._was_resting:
            self._was_resting = False
            self.diagnoser.restart_observer(sample.t)
            result.events.append(f"flying from t = {sample.stamp_ns * 1e-9:.2f} s: observer restarted")
        last = self._last_processed
        dt = 0.0 if last is None else (sample.stamp_ns - last.stamp_ns) * 1e-9
        if last is not None and dt > self.settings.max_gap_s:
            result.warnings.append(
                f"gap of {dt:.3f} s in the state messages before t = {sample.stamp_ns * 1e-9:.3f} s: "
                "observer restarted, "
                "no derivative taken across it"
            )
            self.diagnoser.restart_observer(sample.t)
            self._previous = None
            last = None
        innovation = self.diagnoser.residuals.innovation(sample.state, dt) if last is not None else None
        if innovation is not None and not self._innovation_gate.admit(innovation[0]):
            result.skipped = "inconsistent with the model"
            result.skipped_detail = (
                f"state at {sample.stamp_ns} ns surprises the observer by {format_vector(innovation[0])} "
                "stopped rotors (x, y, z world; x, y, z body): held back as missing data"
            )
            return result
        self._diagnose(sample, dt, result)
        self._identify(sample, last, result)
        self._previous = last
        self._last_processed = sample
        return result

    def _resting(self, state: StateBatch) -> str | None:
        """Why the vehicle rests (module docstring's rule), or None in flight.

        The ground's reaction is in no model: samples taken then would teach the identifier a wrong
        thrust and show the detector a thrust loss that is the ground's doing.
        """
        still = (
            float(np.linalg.norm(state.v_WB_W)) < RESTING_SPEED_M_S
            and float(np.linalg.norm(state.w_WB_B)) < RESTING_RATE_RAD_S
        )
        if not still:
            return None
        model = self.diagnoser.model
        weight = float(np.atleast_1d(model.mass_kg)[0]) * model.gravity_m_s2
        share = self.airframe.k_f_N_s2 * float(np.sum(state.omega**2)) / weight
        tilt = math.acos(min(max(float(state.R_WB[0, 2, 2]), -1.0), 1.0))
        if share >= RESTING_THRUST_SHARE and tilt <= RESTING_TILT_RAD:
            return None
        return f"thrust {100 * share:.0f} % of the weight, tilted {math.degrees(tilt):.0f} deg"

    def _start_clock(self, stamp_ns: int) -> list[str]:
        """Times are seconds since the record's origin (resumed) or the first sample."""
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
                f"stamps restart before the end of the record ({stamp_ns} <= {record.last_stamp_ns} ns): "
                "the clock "
                "went back (a restarted simulator?); new record segment, refit window cleared, estimates kept"
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
            dv_W = sample.state.v_WB_W - previous.state.v_WB_W
            a_W = dv_W / ((sample.stamp_ns - previous.stamp_ns) * 1e-9)
            target = _Sample(last.stamp_ns, dataclasses.replace(last.state, a_WB_W=a_W))
        if bool(self.diagnoser.any_suspicion[0]):
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

    @property
    def clock_offset_s(self) -> float:
        """Stamp [s] of time 0 of the monitor's times (t of results, refits, the record)."""
        return (self._origin_ns or 0) * 1e-9

    def set_detection_settings(self, settings: DetectionSettings) -> None:
        """Change the thresholds at run time (``ros2 param set``)."""
        self.diagnoser.set_detection_settings(settings)
