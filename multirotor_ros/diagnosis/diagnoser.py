"""Rotor fault diagnosis end to end: residuals, detection, isolation, effectiveness, and words for people.

:class:`RotorDiagnoser` runs :class:`~multirotor_ros.diagnosis.residuals.WrenchResidualGenerator`,
:class:`~multirotor_ros.diagnosis.detection.FaultDetector` and the fast
:class:`~multirotor_ros.diagnosis.stopped.StoppedRotorTest` together on a batch of vehicles (one for
the identifier node, many for the fault campaign). A stop the fast test declares goes to the detector
at once (:meth:`~multirotor_ros.diagnosis.detection.FaultDetector.declare_stopped`), which then names
that rotor at effectiveness 0 instead of the partial loss the observer's residual shows on its way to
the step; the observer's residual is no evidence about it for ``settle_s``.

Whenever the observer (re)starts (the first sample, or after :meth:`RotorDiagnoser.restart_observer`:
a gap in the data), the detector sees nothing for ``settle_s`` (a few observer convergence times), so
that the observer's transient is not taken for a fault, and then learns the residual noise again
before it may alarm (:meth:`~multirotor_ros.diagnosis.detection.FaultDetector.relearn`).
:meth:`RotorDiagnoser.hold` keeps a shorter stretch of samples from the detector (the transient after
stepping over a few missing samples) without restarting anything. The fast test sees the samples the
detector sees, and forgets its window at every such break.

:func:`rotor_reports` turns one vehicle's state into one :class:`RotorReport` per rotor: the
``diagnostics`` topic's statuses (OK / WARN / ERROR, the estimated effectiveness, a message).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.diagnosis.detection import (
    DetectionSettings,
    DetectorOutput,
    FaultDetector,
    coaxial_partners,
)
from multirotor_ros.diagnosis.residuals import ObserverSettings, ResidualSample, WrenchResidualGenerator
from multirotor_ros.diagnosis.stopped import StoppedRotorTest, StopTestSettings
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import BoolArray, FloatArray
from multirotor_ros.model.state import StateBatch

Level = Literal["OK", "WARN", "ERROR"]
# Standard deviation of an effectiveness about which nothing is known (RotorDiagnoser.effectiveness).
UNKNOWN_EFFECTIVENESS_STD = 1.0


@dataclass(frozen=True)
class DiagnosisSample:
    """What one update produced: the residuals and the detector's view (None while settling)."""

    residuals: ResidualSample
    detection: DetectorOutput | None


class RotorDiagnoser:
    """Residual generator + detector for ``batch`` vehicles of one airframe (module docstring)."""

    def __init__(
        self,
        model: Model,
        batch: int = 1,
        observer: ObserverSettings | None = None,
        detection: DetectionSettings | None = None,
        stop_test: StopTestSettings | None = None,
    ):
        self.observer_settings = observer or ObserverSettings()
        self.residuals = WrenchResidualGenerator(model, self.observer_settings)
        self.partners = coaxial_partners(model.airframe)
        self.detector = FaultDetector(self.residuals.wrench_scale, self.partners, batch, detection)
        self.stop_test = StoppedRotorTest(self.residuals.wrench_scale, self.partners, batch, stop_test)
        self.batch = batch
        self.settle_s = 3.0 * self.observer_settings.convergence_time_s
        self._hold_until: float | None = None  # the detector sees no sample before this time
        self.last: DetectorOutput | None = None

    @property
    def model(self) -> Model:
        """The model residuals are computed from."""
        return self.residuals.model

    def set_model(self, model: Model) -> None:
        """Compute residuals from another (identified) model from the next sample on."""
        self.residuals.set_model(model)

    def set_detection_settings(self, settings: DetectionSettings) -> None:
        """New thresholds; the learnt noise, bias and alarms are kept."""
        self.detector.settings = settings
        self.detector.refresh_settings()

    def restart_observer(self) -> None:
        """After a gap: the next sample starts the observer again (module docstring: settling, noise)."""
        self.residuals.reset()

    def hold(self, until_t: float) -> None:
        """Keep the samples before ``until_t`` from the detector: they are no evidence, nor noise."""
        self._hold_until = until_t if self._hold_until is None else max(self._hold_until, until_t)
        self.detector.interrupt()
        self.stop_test.clear()

    def update(self, state: StateBatch, dt_s: float) -> DiagnosisSample:
        """One measurement of every vehicle, all taken at one time; ``dt_s`` since the previous one."""
        t = float(state.t[0])
        if not self.residuals.started:
            self._hold_until = t + self.settle_s
            self.detector.relearn()
            self.stop_test.clear()
        sample = self.residuals.update(state, dt_s)
        if sample.model_change_wrench is not None:
            self.detector.shift_baseline(sample.model_change_wrench)
        if self._hold_until is not None and t < self._hold_until - 1e-9:
            return DiagnosisSample(sample, None)
        self._hold_until = None
        if sample.raw_wrench is None:
            self.stop_test.clear()
        else:
            self._test_for_a_stop(t, dt_s, sample.raw_wrench, sample.signatures)
        self.last = self.detector.update(t, dt_s, sample.wrench, sample.signatures)
        return DiagnosisSample(sample, self.last)

    def _test_for_a_stop(self, t: float, dt_s: float, raw_wrench: FloatArray, signatures: FloatArray) -> None:
        """Run the fast test on this sample; hand the stops it declares to the detector."""
        detector = self.detector
        verdict = self.stop_test.update(
            t, dt_s, raw_wrench, signatures, detector.baseline, detector.calm, ~detector.learning
        )
        if verdict.stopped.any():
            detector.declare_stopped(
                t, verdict.stopped, verdict.rotor.astype(int), verdict.loss_std, self.settle_s
            )

    @property
    def any_suspicion(self) -> BoolArray:
        """(B,) detector in alarm or about to be: identification should not learn from that vehicle."""
        return self.detector.suspicious

    def effectiveness(self, vehicle: int = 0) -> tuple[FloatArray, FloatArray]:
        """(N,) estimated remaining effectiveness of each rotor of ``vehicle`` and (N,) its std.

        What the ``rotor_effectiveness`` topic carries and a fault-tolerant controller reads. Before the
        detector has learnt the residual noise (the observer converging), nothing is known: 1 with std
        ``UNKNOWN_EFFECTIVENESS_STD``. Then a healthy rotor is 1 with the standard deviation of one
        sample's loss estimate, and the rotor in alarm has the detector's averaged estimate with the RMS
        of that standard deviation over the samples that were evidence (the averaged estimate is surer:
        an upper bound; detection.py: a rotor left out to idle is no evidence), each at most
        ``UNKNOWN_EFFECTIVENESS_STD``. When the
        faulty rotor's coaxial partner fits almost as well, either may be the healthy one: both get a
        standard deviation of at least the estimated loss.
        """
        n = self.partners.size
        output = self.last
        if output is None or output.warming_up:
            return np.ones(n), np.full(n, UNKNOWN_EFFECTIVENESS_STD)
        estimate = output.effectiveness[vehicle].copy()
        std = np.minimum(
            np.nan_to_num(output.effectiveness_std[vehicle], nan=UNKNOWN_EFFECTIVENESS_STD),
            UNKNOWN_EFFECTIVENESS_STD,
        )
        if output.alarm[vehicle] and output.partner_ambiguous[vehicle]:
            faulty = int(output.rotor[vehicle])
            pair = [faulty, int(self.partners[faulty])]
            std[pair] = np.maximum(std[pair], 1.0 - estimate[faulty])
        return estimate, std


@dataclass(frozen=True)
class RotorReport:
    """One rotor's status for the ``diagnostics`` topic."""

    name: str  # rotor_k
    level: Level
    effectiveness: float  # estimated remaining share of thrust [0..1]
    message: str
    values: dict[str, str]
    summary: str  # the message without times and asides: what a log line says of it


def rotor_reports(
    output: DetectorOutput | None,
    n_rotors: int,
    partners: ArrayLike,
    error_below_effectiveness: float,
    vehicle: int = 0,
    clock_offset_s: float = 0.0,
) -> list[RotorReport]:
    """Per-rotor statuses of one vehicle in words a person can read (see the module docstring).

    Times are the detector's plus ``clock_offset_s``: the identifier node gives the stamp of its first
    sample, so that a detection time reads on the clock of the messages (simulated or wall time).
    """
    partner_of = np.asarray(partners, dtype=int)
    if output is None or output.warming_up:
        why = (
            "learning the residual noise (at the start, or again after a gap in the data)"
            if output is not None
            else "waiting for data"
        )
        return [
            RotorReport(f"rotor_{k + 1}", "OK", 1.0, message, {"effectiveness": "1.00"}, message)
            for k in range(n_rotors)
            for message in [f"rotor {k + 1}: no verdict yet, {why}"]
        ]
    reports = []
    faulty = int(output.rotor[vehicle]) if output.alarm[vehicle] else -1
    for k in range(n_rotors):
        loss = float(output.loss[vehicle, k])
        threshold = float(output.threshold[vehicle, k])
        values = {
            "effectiveness": f"{output.effectiveness[vehicle, k]:.2f}",
            "loss_estimate": f"{loss:.3f}",
            "loss_threshold": f"{threshold:.3f}",
        }
        if k == faulty:
            effectiveness = float(output.effectiveness[vehicle, k])
            onset = float(output.onset_t[vehicle]) + clock_offset_s
            level: Level = "ERROR" if effectiveness < error_below_effectiveness else "WARN"
            kind = "stopped or lost its propeller" if effectiveness < 0.1 else "is losing thrust"
            left = f"about {100 * effectiveness:.0f} % of its thrust left"
            summary = f"rotor {k + 1} {kind}, {left}"
            message = f"rotor {k + 1} {kind}: {left} (fault detected at t = {onset:.2f} s)"
            partner = int(partner_of[k])
            if partner >= 0 and output.partner_ambiguous[vehicle]:
                summary += f", or coaxial rotor {partner + 1}"
                message += (
                    f"; its coaxial partner rotor {partner + 1} fits almost as well (only the yaw torque "
                    "tells them apart), so check both"
                )
            values["detected_at_s"] = f"{onset:.3f}"
            reports.append(RotorReport(f"rotor_{k + 1}", level, effectiveness, message, values, summary))
            continue
        if output.also_stopped[vehicle, k]:
            message = f"rotor {k + 1} stopped or lost its propeller too: about 0 % of its thrust left"
            reports.append(RotorReport(f"rotor_{k + 1}", "ERROR", 0.0, message, values, message))
            continue
        if faulty >= 0:
            message = f"rotor {k + 1}: no fault of its own (rotor {faulty + 1} is faulty)"
        elif loss > 0.5 * threshold:
            share = 100 * loss / threshold
            message = f"rotor {k + 1}: OK, but its residual is at {share:.0f} % of the alarm threshold"
        else:
            message = f"rotor {k + 1}: OK"
        reports.append(RotorReport(f"rotor_{k + 1}", "OK", 1.0, message, values, message))
    return reports
