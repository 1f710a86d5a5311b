"""The thresholds of the model-discrepancy workflow, in one documented value.

    from multirotor_ros.discrepancy import DiscrepancySettings, find_discrepancy
    strict = DiscrepancySettings(z_critical=4.0)
    report = find_discrepancy("x8_octorotor", "flight.csv", [], settings=strict)

The defaults are the values the hidden-effect sweep (test/test_discrepancy_sweep.py) was tuned with:
every hidden effect named at two strengths and two noise levels, and nothing named when nothing is hidden.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from multirotor_ros.ident.settings import FitSettings


@dataclass(frozen=True)
class DiscrepancySettings:
    """When a candidate effect counts as found, how the log is split to test it, and what the report shows."""

    # -- significance
    # [standard deviations of noise] a held-out improvement must reach (:func:`improvement_z`); 3 keeps the
    # candidates that only fit noise out of a dozen tried per round.
    z_critical: float = 3.0
    # [m/s^2] RMS over the worst second of flight that a named effect's force must reach: below it an effect
    # changes nothing a controller or a simulation would notice.
    negligible_acceleration_m_s2: float = 0.05
    # [m/s^2] below this peak an effect must also explain something a constant accelerometer bias cannot:
    # good IMUs keep a few mg (0.05 m/s^2) after calibration, three times that is beyond any bias flown with.
    bias_check_below_m_s2: float = 0.15
    # [s] window of the peak RMS above: long enough to average sensor noise, short enough for a fault or a
    # pass near the ground to stand out of the rest of the flight.
    peak_window_s: float = 1.0
    # [s] of usable flight an actuator fault needs before its onset: without flight before it, "stopped at
    # the start" is no fault onset but a rotor weak for the whole log (rotor_effectiveness, which the rotor
    # balance tells), and a vehicle that took off on it flew with its allocation planning on that rotor.
    min_flight_before_fault_s: float = 1.0

    # -- cross-validation
    # [-] folds of interleaved blocks: each fold is predicted by a fit on the other 80 % of the log.
    folds: int = 5
    # [-] fewest blocks a log must cut into; fewer leaves each fold one or two blocks, too few to judge.
    min_blocks: int = 10
    # [s] longest block: about the correlation time of closed-loop residuals, so blocks are nearly
    # independent.
    max_block_s: float = 2.0
    # [s] shortest block (for short logs): below it residuals correlate across neighbouring blocks.
    min_block_s: float = 0.5

    # -- look-alikes
    # [-] a competitor scoring at least this share of the best's score is fitted together with it to tell
    # which of the two explains the other.
    lookalike_score_ratio: float = 0.5
    # [-] competitors so compared per round: each costs a cross-validated pair fit.
    max_lookalikes: int = 2
    # [-] fewest samples with a measured angular acceleration for the torque balance to be evidence.
    min_torque_samples: int = 100

    # -- report
    # [-] the "where" windows are at least one block long and cut the log into at most this many.
    where_windows_per_log: int = 30
    # [-] time windows listed under "where"; regimes listed under "regimes".
    where_limit: int = 6
    regimes_listed: int = 4

    # How the log is prepared and when a fitted parameter is believed: the samples carry them into every fit
    # (baseline, candidates, folds).
    fit: FitSettings = field(default_factory=FitSettings)
