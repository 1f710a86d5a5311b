"""Detection, isolation and effectiveness estimation from the wrench residual, with an adaptive threshold.

Each sample, for every rotor i, the loss of effectiveness that best explains the wrench residual r
alone is the weighted least-squares fit of r ≈ -δ_i s_i (s_i the rotor's signature,
:mod:`multirotor_ros.diagnosis.residuals`):

    δ_i = -(s_iᵀ W r) / (s_iᵀ W s_i),   std(δ_i) = (s_iᵀ W s_i)^-½,   W = diag(1 / σ_c²)

with σ_c the residual noise of channel c. The isolated rotor is the one whose δ_i stands furthest
above its own noise (largest δ_i / std(δ_i), i.e. the smallest weighted misfit among positive losses).

The threshold adapts to the noise: σ_c is an exponentially weighted mean absolute deviation of the
residual about a slowly adapting baseline (which absorbs a steady model error such as a slightly wrong
thrust constant), both updated only while no rotor is suspected, so that a fault does not teach the
detector to accept itself. A rotor is declared faulty when δ_i > max(``min_loss``, ``k_sigma`` std(δ_i))
has held for ``persistence_s``; the alarm clears after ``clear_s`` below half that threshold.

In alarm, the faulty rotor's remaining effectiveness is an average of its samples (time constant
``effectiveness_time_constant_s``), reported with the standard deviation of one sample (the RMS over
the same average: the averaged estimate is surer, so this is an upper bound). Only samples that are
evidence about the fault move the average, its standard deviation, the coaxial ambiguity and
the clearing clock: those in which a loss as large as the estimated one would stand above the
threshold. A rotor that a fault-tolerant controller has left out idles near its minimum speed; the
residual then says almost nothing about it (its loss's standard deviation grows a hundredfold), and
taking that silence as "healthy" would clear the alarm, report the stopped rotor OK and bring it back
into the allocation. So a diagnosis stands, as sure as its last evidence, until evidence changes it.
σ_c has a floor (``noise_floor_fraction`` of a stopped rotor's residual in that channel) so that a
noise-free simulation does not get an infinitely sensitive detector.

A stopped rotor can be declared from outside (:meth:`FaultDetector.declare_stopped`: the fast test of
:mod:`multirotor_ros.diagnosis.stopped`, which sees the step before the observer's residual has reached
it): the alarm names that rotor at effectiveness 0, as sure as the test's estimate, and the observer's
residual is no evidence about it until it has had time to follow the step (``no_evidence_s``): its ramp
towards the fault would otherwise pull the estimate back to a partial loss.

A second stopped rotor. The alarm names one rotor, but a vehicle of coaxial pairs whose alarm is a
declared stop may lose another rotor later (an X8 flies on with two rotors of different pairs stopped):
a stop then declared for a rotor of another coaxial pair is kept beside the alarm
(``DetectorOutput.also_stopped``, reported at effectiveness 0 with the test's std) until
:meth:`FaultDetector.reset`. A stopped rotor does not come back by itself, and once the allocation leaves
it idle no residual tells either way. Not taken: a stop of the alarm's coaxial partner (the two can
hardly be told apart, and naming both would take a healthy rotor out with the faulty one), nor a second
stop on an airframe without coaxial pairs. A hexarotor flying on one rotor short (its yaw given up)
gave the fast test false second stops of healthy rotors in 2 of 20 cases of the fault-tolerance campaign
(diagnosis/recovery.py, ``recovery_cases(6, 20, 0)``: seeds 3 and 9), which would take a healthy rotor
out. Partial losses stay one per vehicle (the alarm).

Breaks in the data are not evidence. :meth:`FaultDetector.interrupt` (the caller skipped samples, e.g.
an observer transient after stepping over missing ones) restarts the persistence and clearing clocks: an
alarm condition must hold on consecutive evidence. :meth:`FaultDetector.relearn` (after a gap or a
restart of the observer) also takes ``relearn_s`` of new residuals before any new alarm: the noise of
the data after a break (a loaded machine jitters) need not be the noise learnt before it. The bias
learnt before is kept (it is the model's error, which a break does not change); the noise becomes the
larger of the one learnt before and the new window's median absolute deviation (robust to a few odd
samples), unless the window's median stands off the bias like a fault judged by the noise learnt before:
then a fault came with the gap, and it is judged by that noise instead of being learnt as noise; the
window counts as the alarm's persistence, so that the alarm comes with its end. A vehicle in alarm keeps
its alarm and learns nothing: its residual is the fault's.

Coaxial pairs (the X8) share their position: the two rotors' signatures differ only in the sign of the
yaw drag torque, a tenth of the roll/pitch signal. Isolation within a pair rests on the yaw channel
alone; when the misfits of the two rotors differ by less than ``ambiguity_chi2`` (a chi-square with
one degree of freedom, in units of the noise), the diagnosis names both and says so.

Pure numpy, batched over B vehicles; times are seconds of the caller's clock (sim or wall).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import BoolArray, FloatArray

# Mean absolute deviation of a Gaussian is σ √(2/π).
_MAD_TO_SIGMA = float(np.sqrt(np.pi / 2))
# Its median absolute deviation is 0.6745 σ: this factor turns the median one into the mean one.
_MEDIAN_TO_MEAN_ABS = float(np.sqrt(2 / np.pi) / 0.6745)


@dataclass(frozen=True)
class DetectionSettings:
    """Detection thresholds (the identifier node exposes them as parameters ``detection.<name>``)."""

    k_sigma: float = 8.0  # alarm when the loss exceeds this many of its standard deviations ...
    min_loss: float = 0.2  # ... and at least this fraction of the rotor's thrust [-]
    persistence_s: float = 0.05  # [s] the condition must hold this long
    clear_s: float = 1.0  # [s] below half the threshold this long clears the alarm
    warmup_s: float = 1.0  # [s] noise learning before any alarm
    noise_time_constant_s: float = 5.0  # [s] memory of the noise estimate
    baseline_time_constant_s: float = 20.0  # [s] memory of the steady-bias estimate
    noise_floor_fraction: float = 0.01  # noise floor, as a fraction of a stopped rotor's residual
    effectiveness_time_constant_s: float = 0.1  # [s] averaging of the effectiveness estimate after alarm
    ambiguity_chi2: float = 4.0  # coaxial partners closer than this in misfit are both named
    error_below_effectiveness: float = 0.5  # ERROR below this remaining effectiveness, WARN above
    # [s] after a gap or restart, noise learnt again before any new alarm: 25 samples at 100 Hz for the
    # median; 0.5 s had no fewer false alarms on the loaded bench and judged 40 % of its flights, not 47 %.
    relearn_s: float = 0.25

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"detection setting {name} must be a finite number >= 0, got {value!r}")
        for name in ("k_sigma", "noise_time_constant_s", "baseline_time_constant_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"detection setting {name} must be > 0, got {getattr(self, name)!r}")
        if not 0 < self.min_loss < 1:
            raise ValueError(f"min_loss must be in (0, 1), got {self.min_loss}")


def coaxial_partners(airframe: Airframe) -> FloatArray:
    """(N,) index of each rotor's coaxial partner (same position), -1 where it has none."""
    positions = airframe.rotor_positions_m[:, :2]
    partners = np.full(airframe.n_rotors, -1)
    for i in range(airframe.n_rotors):
        same = np.flatnonzero(np.all(np.abs(positions - positions[i]) < 1e-9, axis=1))
        others = same[same != i]
        if others.size:
            partners[i] = others[0]
    return partners


@dataclass
class DetectorOutput:
    """The detector's view after one sample, batched over B (rotor indices are 0-based)."""

    t: float
    alarm: BoolArray  # (B,) a rotor is declared faulty
    rotor: FloatArray  # (B,) int: the faulty (or, without alarm, the most suspect) rotor
    partner_ambiguous: BoolArray  # (B,) its coaxial partner fits almost as well
    effectiveness: FloatArray  # (B, N): estimated remaining effectiveness, 1 for rotors not in alarm
    effectiveness_std: FloatArray  # (B, N): loss_std; the faulty rotor's averaged over its evidence
    loss: FloatArray  # (B, N): this sample's loss estimates δ_i
    loss_std: FloatArray  # (B, N): their standard deviations
    threshold: FloatArray  # (B, N): the adaptive loss threshold
    onset_t: FloatArray  # (B,) time the current alarm was raised (nan without alarm)
    also_stopped: BoolArray  # (B, N) stopped rotors declared beside the alarm's (module docstring)
    warming_up: bool = False  # every vehicle is learning the residual noise (first or again): no verdict


@dataclass
class _State:
    baseline: FloatArray
    mad: FloatArray
    pending_since: FloatArray
    quiet_since: FloatArray
    alarm: BoolArray
    rotor: FloatArray
    onset_t: FloatArray
    effectiveness: FloatArray
    evidence_variance: FloatArray  # (B,) loss_std² of the faulty rotor, averaged over its evidence
    ambiguous: BoolArray  # (B,) the alarm's coaxial partner fits almost as well (last evidence)
    relearning: BoolArray  # (B,) learning the noise again after a break (module docstring)
    evidence_from_t: FloatArray  # (B,) no sample before this time is evidence (after a declared stop)
    stop_declared: BoolArray  # (B,) the alarm is a stop declared by the fast test
    also_stopped: BoolArray  # (B, N) stopped rotors declared beside the alarm's
    also_stopped_std: FloatArray  # (B, N) the std of their declarations (nan where none)
    relearn_started_t: float | None = None
    started_t: float | None = None
    warmed_up: bool = False
    warm: list[FloatArray] = field(default_factory=list)  # residuals of the (re)learning window


class FaultDetector:
    """Adaptive-threshold detector and isolator for B vehicles with N rotors (see the module docstring)."""

    MAX_WARMUP_SAMPLES = 10_000

    def __init__(
        self,
        wrench_scale: Sequence[float] | FloatArray,
        partners: Sequence[int] | FloatArray,
        batch: int = 1,
        settings: DetectionSettings | None = None,
    ):
        self.settings = settings or DetectionSettings()
        self.wrench_scale = np.asarray(wrench_scale, dtype=float)
        if self.wrench_scale.shape != (4,) or np.any(self.wrench_scale <= 0):
            raise ValueError(f"wrench_scale must be 4 positive numbers, got {self.wrench_scale}")
        self.partners = np.asarray(partners, dtype=int)
        self.batch = int(batch)
        self.n_rotors = self.partners.size
        self.refresh_settings()
        self.reset()

    def refresh_settings(self) -> None:
        """Take changed :attr:`settings` into account (noise floor and filter gains depend on them)."""
        self._noise_floor = self.settings.noise_floor_fraction * self.wrench_scale
        self._blend_cache: tuple[float, tuple[float, float, float]] | None = None

    def reset(self) -> None:
        """Forget everything learnt: noise, baseline, alarms (a new flight)."""
        b, n = self.batch, self.n_rotors
        self._state = _State(
            baseline=np.zeros((b, 4)),
            mad=np.zeros((b, 4)),
            pending_since=np.full(b, np.nan),
            quiet_since=np.full(b, np.nan),
            alarm=np.zeros(b, dtype=bool),
            rotor=np.zeros(b, dtype=int),
            onset_t=np.full(b, np.nan),
            effectiveness=np.ones((b, n)),
            evidence_variance=np.full(b, np.nan),
            ambiguous=np.zeros(b, dtype=bool),
            relearning=np.zeros(b, dtype=bool),
            evidence_from_t=np.full(b, -np.inf),
            stop_declared=np.zeros(b, dtype=bool),
            also_stopped=np.zeros((b, n), dtype=bool),
            also_stopped_std=np.full((b, n), np.nan),
        )

    def interrupt(self) -> None:
        """The caller skips samples (module docstring): persistence and clearing start again afterwards."""
        self._state.pending_since[:] = np.nan
        self._state.quiet_since[:] = np.nan

    def relearn(self) -> None:
        """After a gap or a restart: learn the noise again before any new alarm (module docstring).

        During the first warm-up, the warm-up starts again: its samples before the break are dropped.
        """
        state = self._state
        self.interrupt()
        state.warm = []
        if not state.warmed_up:
            state.started_t = None
            return
        state.relearning = ~state.alarm
        state.relearn_started_t = None

    @property
    def noise_std(self) -> FloatArray:
        """(B, 4) current residual noise estimate per wrench channel (floored)."""
        return np.maximum(self._state.mad * _MAD_TO_SIGMA, self._noise_floor)

    @property
    def suspicious(self) -> BoolArray:
        """(B,) in alarm, or a suspect above threshold waiting for persistence."""
        return self._state.alarm | ~np.isnan(self._state.pending_since)

    @property
    def learning(self) -> BoolArray:
        """(B,) learning the residual noise (first warm-up, or again after a break): no alarm possible."""
        return np.full(self.batch, not self._state.warmed_up) | self._state.relearning

    @property
    def calm(self) -> BoolArray:
        """(B,) nothing suspected and the noise known: a sample that may teach the noise."""
        return ~self.suspicious & ~self.learning

    def declare_stopped(
        self, t: float, vehicles: BoolArray, rotor: FloatArray, std: FloatArray, no_evidence_s: float
    ) -> None:
        """Rotor ``rotor`` (B,) of the ``vehicles`` (B,) stopped at ``t``, its loss known to ``std`` (B,).

        The alarm names it at effectiveness 0 (onset ``t`` unless already in alarm on it), and the
        observer's residual is no evidence about it for ``no_evidence_s`` (module docstring). A vehicle in
        alarm on another rotor keeps that alarm; the stop is kept beside it when that alarm is a declared
        stop of another coaxial pair (module docstring: a second stopped rotor).
        """
        state = self._state
        second = (
            vehicles
            & state.alarm
            & state.stop_declared
            & (state.rotor != rotor)
            & (self.partners[rotor] >= 0)
            & (self.partners[state.rotor] != rotor)
        )
        if second.any():
            rows = np.flatnonzero(second)
            state.also_stopped[rows, rotor[rows]] = True
            state.also_stopped_std[rows, rotor[rows]] = std[rows]
        apply = vehicles & (~state.alarm | (state.rotor == rotor))
        if not apply.any():
            return
        rows = np.flatnonzero(apply)
        state.onset_t[rows] = np.where(state.alarm[rows], state.onset_t[rows], t)
        state.alarm[rows] = True
        state.rotor[rows] = rotor[rows]
        state.effectiveness[rows] = 1.0
        state.effectiveness[rows, rotor[rows]] = 0.0
        state.evidence_variance[rows] = std[rows] ** 2
        state.ambiguous[rows] = False
        state.pending_since[rows] = np.nan
        state.quiet_since[rows] = np.nan
        state.evidence_from_t[rows] = t + no_evidence_s
        state.stop_declared[rows] = True

    @property
    def warmed_up(self) -> bool:
        """Whether the noise has been learnt (the first ``warmup_s`` are over)."""
        return self._state.warmed_up

    def learnt(self) -> dict[str, FloatArray]:
        """What the detector learnt of the residual (bias and noise), to resume after a restart."""
        return {"baseline": self._state.baseline.copy(), "mad": self._state.mad.copy()}

    def resume(self, learnt: dict[str, FloatArray]) -> None:
        """Start from bias and noise learnt before (:meth:`learnt`) instead of a warm-up; no alarm."""
        baseline = np.asarray(learnt["baseline"], dtype=float)
        mad = np.asarray(learnt["mad"], dtype=float)
        shape = (self.batch, 4)
        if (
            baseline.shape != shape
            or mad.shape != shape
            or not (np.all(np.isfinite(baseline)) and np.all(mad >= 0))
        ):
            raise ValueError(f"saved detector state does not fit: expected finite {shape} arrays")
        self.reset()
        self._state.baseline = baseline.copy()
        self._state.mad = mad.copy()
        self._state.warmed_up = True

    @property
    def baseline(self) -> FloatArray:
        """(B, 4) current steady-bias estimate of the wrench residual."""
        return self._state.baseline

    def update(self, t: float, dt_s: float, wrench: FloatArray, signatures: FloatArray) -> DetectorOutput:
        """Fold in one residual sample: ``wrench`` (B, 4), ``signatures`` (B, 4, N); times in seconds."""
        s = self.settings
        state = self._state
        if state.started_t is None:
            state.started_t = t
        if not state.warmed_up:
            return self._warm_up(t, wrench)

        if state.relearning.any():
            self._relearn(t, wrench, signatures)
        learning = state.relearning.copy()

        centred = wrench - state.baseline
        projection, information = self._fit(centred, signatures)
        loss = -projection / information
        loss_std = 1.0 / np.sqrt(information)
        threshold = np.maximum(s.min_loss, s.k_sigma * loss_std)
        # Misfit of "rotor i alone lost δ_i": r'Wr - (s_i'Wr)² / (s_i'Ws_i); only positive losses count.
        explained = np.where(loss > 0, projection**2 / information, 0.0)
        best = np.argmax(explained, axis=1)
        rows = np.arange(self.batch)
        exceeds = (loss[rows, best] > threshold[rows, best]) & ~learning

        # Persistence before alarm; a new suspect restarts the clock.
        suspect_changed = best != state.rotor
        state.pending_since = np.where(
            exceeds & ~(suspect_changed & ~state.alarm), state.pending_since, np.nan
        )
        state.pending_since = np.where(exceeds & np.isnan(state.pending_since), t, state.pending_since)
        newly = ~state.alarm & exceeds & (t - state.pending_since >= s.persistence_s - 1e-9)
        state.rotor = np.where(state.alarm, state.rotor, best)
        state.onset_t = np.where(newly, t, state.onset_t)
        state.alarm = state.alarm | newly

        # The faulty rotor's effectiveness, averaged over the samples that are evidence (module docstring);
        # the others are reported healthy.
        faulty = state.rotor
        faulty_loss = np.clip(loss[rows, faulty], 0.0, 1.0)
        current = state.effectiveness[rows, faulty]
        evidence = (s.k_sigma * loss_std[rows, faulty] <= np.maximum(1.0 - current, s.min_loss)) & (
            t >= state.evidence_from_t
        )
        blend, noise_blend, base_blend = self._blends(dt_s)
        gain = np.where(evidence, blend, 0.0)  # a sample that is no evidence leaves both averages alone
        state.effectiveness[rows, faulty] = np.where(
            newly,
            1.0 - faulty_loss,
            np.where(state.alarm, current + gain * ((1.0 - faulty_loss) - current), 1.0),
        )
        variance = loss_std[rows, faulty] ** 2  # finite: _fit floors the information at 1e-300
        state.evidence_variance = np.where(
            newly, variance, state.evidence_variance + gain * (variance - state.evidence_variance)
        )

        # Clearing: the faulty rotor's loss below half its threshold for clear_s, on consecutive evidence.
        quiet = state.alarm & evidence & (loss[rows, faulty] < 0.5 * threshold[rows, faulty])
        state.quiet_since = np.where(
            quiet, np.where(np.isnan(state.quiet_since), t, state.quiet_since), np.nan
        )
        cleared = quiet & (t - state.quiet_since >= s.clear_s)
        if cleared.any():
            state.alarm = state.alarm & ~cleared
            state.onset_t = np.where(cleared, np.nan, state.onset_t)
            state.effectiveness[cleared] = 1.0
            state.quiet_since = np.where(cleared, np.nan, state.quiet_since)
            state.stop_declared = state.stop_declared & ~cleared
        state.effectiveness[~state.alarm] = 1.0

        # Learn noise and bias only while nothing is suspected; a relearning vehicle's noise comes from its
        # window at the end of it.
        calm = ~state.alarm & np.isnan(state.pending_since) & ~learning
        if calm.any():
            state.mad[calm] += noise_blend * (np.abs(centred[calm]) - state.mad[calm])
            state.baseline[calm] += base_blend * centred[calm]

        partner = self.partners[faulty]
        has_partner = partner >= 0
        misfit_gap = explained[rows, faulty] - np.where(
            has_partner, explained[rows, np.maximum(partner, 0)], -np.inf
        )
        ambiguous = has_partner & (misfit_gap < s.ambiguity_chi2)
        state.ambiguous = np.where(~state.alarm | newly | evidence, ambiguous, state.ambiguous)
        effectiveness_std = loss_std.copy()
        effectiveness_std[rows, faulty] = np.where(
            state.alarm, np.sqrt(state.evidence_variance), loss_std[rows, faulty]
        )
        also = state.also_stopped
        return DetectorOutput(
            t=t,
            alarm=state.alarm.copy(),
            rotor=faulty.copy(),
            partner_ambiguous=state.ambiguous.copy(),
            effectiveness=np.where(also, 0.0, state.effectiveness),
            effectiveness_std=np.where(also, state.also_stopped_std, effectiveness_std),
            loss=loss,
            loss_std=loss_std,
            threshold=threshold,
            onset_t=state.onset_t.copy(),
            also_stopped=also.copy(),
            warming_up=bool(learning.all()),
        )

    def _fit(self, centred: FloatArray, signatures: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(B, N) s_i' W r and s_i' W s_i of residuals ``centred`` (B, 4), weighted by the learnt noise."""
        weight = 1.0 / self.noise_std**2  # (B, 4)
        weighted_signatures = signatures * weight[:, :, None]
        information = np.maximum((weighted_signatures * signatures).sum(axis=1), 1e-300)
        projection = (weighted_signatures * centred[:, :, None]).sum(axis=1)
        return projection, information

    def _relearn(self, t: float, wrench: FloatArray, signatures: FloatArray) -> None:
        """Add a sample to the relearning window; at its end, take its noise unless it holds a fault.

        A window whose median stands off the bias like a fault (judged by the noise learnt before) has
        shown the fault for longer than ``persistence_s``: it counts as the persistence, so the alarm
        comes with this sample if it shows the fault too (module docstring).
        """
        state = self._state
        if state.relearn_started_t is None:
            state.relearn_started_t = t
        state.warm.append(wrench.copy())
        started_t = state.relearn_started_t
        if t - started_t < self.settings.relearn_s - 1e-9 and len(state.warm) < self.MAX_WARMUP_SAMPLES:
            return
        centred = np.stack(state.warm) - state.baseline  # (K, B, 4)
        typical = np.median(centred, axis=0)
        fresh_mad = _MEDIAN_TO_MEAN_ABS * np.median(np.abs(centred - typical), axis=0)
        projection, information = self._fit(typical, signatures)
        offset_loss = -projection / information
        threshold = np.maximum(self.settings.min_loss, self.settings.k_sigma / np.sqrt(information))
        faulty = state.relearning & np.any(offset_loss > threshold, axis=1)
        adopt = state.relearning & ~faulty
        state.mad[adopt] = np.maximum(state.mad[adopt], fresh_mad[adopt])
        state.pending_since[faulty] = started_t
        state.relearning[:] = False
        state.relearn_started_t = None
        state.warm = []

    def _blends(self, dt_s: float) -> tuple[float, float, float]:
        """First-order filter gains for this step (effectiveness, noise, baseline), cached per step."""
        if self._blend_cache is None or self._blend_cache[0] != dt_s:
            s = self.settings
            effectiveness = (
                1.0 - math.exp(-dt_s / s.effectiveness_time_constant_s)
                if s.effectiveness_time_constant_s > 0
                else 1.0
            )
            self._blend_cache = (
                dt_s,
                (
                    effectiveness,
                    1.0 - math.exp(-dt_s / s.noise_time_constant_s),
                    1.0 - math.exp(-dt_s / s.baseline_time_constant_s),
                ),
            )
        return self._blend_cache[1]

    def shift_baseline(self, delta: FloatArray) -> None:
        """Move the bias estimate by ``delta`` (B, 4): the residual moved for a known reason (a new model)."""
        state = self._state
        state.baseline = state.baseline + delta
        if state.warm:
            state.warm = [w + delta for w in state.warm]

    def _warm_up(self, t: float, wrench: FloatArray) -> DetectorOutput:
        """Collect the first ``warmup_s``; then bias = their mean, noise = their mean absolute deviation."""
        state = self._state
        assert state.started_t is not None
        state.warm.append(wrench.copy())
        if t - state.started_t >= self.settings.warmup_s - 1e-9 or len(state.warm) >= self.MAX_WARMUP_SAMPLES:
            samples = np.stack(state.warm)
            state.baseline = samples.mean(axis=0)
            state.mad = np.mean(np.abs(samples - state.baseline), axis=0)
            state.warm = []
            state.warmed_up = True
        b, n = self.batch, self.n_rotors
        return DetectorOutput(
            t=t,
            alarm=np.zeros(b, dtype=bool),
            rotor=np.zeros(b, dtype=int),
            partner_ambiguous=np.zeros(b, dtype=bool),
            effectiveness=np.ones((b, n)),
            effectiveness_std=np.full((b, n), np.nan),
            loss=np.zeros((b, n)),
            loss_std=np.full((b, n), np.nan),
            threshold=np.full((b, n), np.nan),
            onset_t=np.full(b, np.nan),
            also_stopped=np.zeros((b, n), dtype=bool),
            warming_up=True,
        )
