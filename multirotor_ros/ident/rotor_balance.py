"""The balance of the rotors: what each rotor must give to keep the vehicle level, and what changed.

A flight controller hides a weak rotor from the translational motion: it raises that rotor's command
until the torques balance again. The evidence is in the commands. Over a flight whose attitude stays
bounded, the net torque averages to zero (the angular momentum cannot grow), so the time-averaged
thrusts f_k that the rotors actually give satisfy, with W the weight and r the centre of gravity,

    sum_k f_k = W,   sum_k f_k y_k = W r_y,   sum_k f_k x_k = W r_x,   sum_k c_k f_k = 0   (yaw),

where c_k is rotor k's drag torque per newton of thrust, signed by its spin. The log gives the
commanded thrusts F_k = k_f omega_k^2 (through the motor map when only commands are logged). A
manoeuvre loads all rotors alike (the thrust is the mass times the specific force |a + g e_z|), so
each sample's thrusts are scaled to 1 g by g / |a + g e_z| when the log has accelerations: flights
with different manoeuvres then compare like hovers.

**Baseline** (:func:`rotor_baseline`, from flights of the vehicle in its normal state): the mean
commanded thrust of each rotor over the flights, its flight-to-flight scatter, and what it implies:
the weight carried, the centre of gravity, and the yaw balance (real rotors are not identical: a
Crazyflie's cw rotors carry 10-20 % less than its ccw ones, so the cw drag ratio is taken from the
baseline as the one that balances yaw, c_cw / c_ccw = sum of ccw thrusts / sum of cw thrusts).

**Suspect** (:func:`diagnose`), three explanations of how its mean commands F_k moved from the
baseline's mu_k:

- ``rotor_effectiveness``: rotor k gives e_k F_k (thrust and drag torque). The vehicle is unchanged,
  so the thrusts it needs are the baseline's and e_k = mu_k / F_k. Its standard deviation combines the
  baseline mean's uncertainty, the scatter one flight shows about the vehicle's state (the baseline's
  flight-to-flight scatter) and the suspect's own standard error (1 s block means).
- ``mass_offset`` with ``cg_offset`` (a payload): the rotors are unchanged and the thrusts move to carry
  the new weight about the new centre of gravity, keeping the yaw balance: F = mu + P (dW, dW r_y,
  dW r_x), P the minimum-norm response of the balance above. A payload cannot move the yaw balance;
  a weak rotor must (its neighbours of the other spin take up its drag torque).
- ``none``: no rotor's e_k is below 1 by more than :data:`SIGNIFICANT_Z` standard deviations and the
  commands are where the baseline's scatter puts them.

The rotors of one spin share the yaw balance: when the commands of two rotors rise alike (a change of
weight, or of a rotor's drag torque, moves both), their e_k cannot tell which is weaker. Rotors whose e_k
is within :data:`DISTINCT_Z` standard deviations of the weakest's are named with it as look-alikes
(``indistinct_rotors``) instead of being left out.

Each explanation is fitted by weighted least squares and judged by its residual (chi-square with its
degrees of freedom, tail probability p): ``none`` when it holds and no rotor is flagged; otherwise the
explanation with the larger p, and the other as a look-alike (the log cannot tell them apart) unless
its p is under 1/:data:`DECISIVE_P_RATIO` of the better one's or under :data:`REJECT_P`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe
from multirotor_ros.model.rotation import FloatArray

# A rotor is flagged when its effectiveness is below 1 by more than this many standard deviations.
SIGNIFICANT_Z = 3.0
# An explanation is rejected when its residual is this improbable under the noise (chi-square tail).
REJECT_P = 1e-3
# A rotor cannot be told from the weakest when their e_k differ by less than this many standard deviations
# of the difference (about 95 % two-sided).
DISTINCT_Z = 2.0
# Two explanations that both hold are look-alikes unless the better one's residual is this many times
# more probable (chi-square tail probabilities) than the other's.
DECISIVE_P_RATIO = 10.0
# Airborne: the commanded thrust carries at least this share of the airframe's weight, the vehicle is
# tilted less than MAX_TILT_DEG (one on its side is crashed, not balancing), and the first and last
# TRIM_S of each airborne stretch (take-off and landing transients) are left out.
AIRBORNE_WEIGHT_SHARE = 0.5
MAX_TILT_DEG = 45.0
TRIM_S = 0.5
BLOCK_S = 1.0
MIN_AIRBORNE_S = 3.0


class RotorBalanceError(ValueError):
    """A log or a baseline that cannot give a rotor balance; the message says which and why."""


@dataclass(frozen=True)
class FlightBalance:
    """One flight's time-averaged commanded thrust per rotor [N] over its airborne samples."""

    source: str
    thrust_N: FloatArray
    std_error_N: FloatArray
    airborne_s: float
    scaled_to_1g: bool

    def to_json(self) -> dict[str, Any]:
        """Plain data for reports."""
        return {
            "source": self.source,
            "thrust_N": self.thrust_N.tolist(),
            "std_error_N": self.std_error_N.tolist(),
            "airborne_s": self.airborne_s,
            "scaled_to_1g": self.scaled_to_1g,
        }


def _airborne_stretches(t: FloatArray, airborne: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of consecutive airborne samples, trimmed by TRIM_S at both ends."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], airborne.astype(int), [0]])))
    stretches = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        first = int(np.searchsorted(t, t[start] + TRIM_S))
        last = int(np.searchsorted(t, t[stop - 1] - TRIM_S, side="right"))
        if last > first:
            stretches.append((first, last))
    return stretches


def flight_balance(log: FlightLog, airframe: Airframe) -> FlightBalance:
    """The mean commanded thrust of each rotor while airborne, with its standard error."""
    source = str(log.source_path or log.metadata.get("converted_from", "<log>"))
    if log.n_rotors != airframe.n_rotors:
        raise RotorBalanceError(
            f"{source}: {log.n_rotors} rotors in the log, {airframe.n_rotors} in {airframe.name}"
        )
    thrust = airframe.k_f_N_s2 * log.rotor_speeds(airframe.motor_map) ** 2
    weight = airframe.mass_kg * GRAVITY_M_S2
    airborne = np.all(np.isfinite(thrust), axis=1) & (
        np.nansum(thrust, axis=1) >= AIRBORNE_WEIGHT_SHARE * weight
    )
    if "landed" in log.columns:
        airborne &= ~(log.columns["landed"] > 0.5)
    with np.errstate(invalid="ignore"):
        tilt_cos = np.cos(log.column("roll")) * np.cos(log.column("pitch"))
        airborne &= tilt_cos > math.cos(math.radians(MAX_TILT_DEG))
    scaled = log.has_group("acceleration")
    if scaled:
        specific = np.linalg.norm(log.group("acceleration") + [0.0, 0.0, GRAVITY_M_S2], axis=1)
        plausible = (specific > 0.5 * GRAVITY_M_S2) & (specific < 2.0 * GRAVITY_M_S2)
        airborne &= plausible
        thrust = thrust * (GRAVITY_M_S2 / np.where(plausible, specific, GRAVITY_M_S2))[:, None]
    stretches = _airborne_stretches(log.t, airborne)
    rows = np.concatenate([np.arange(a, b) for a, b in stretches]) if stretches else np.arange(0)
    dt = float(np.median(np.diff(log.t))) if log.t.size > 1 else math.nan
    airborne_s = rows.size * dt
    if not airborne_s >= MIN_AIRBORNE_S:
        raise RotorBalanceError(
            f"{source}: {airborne_s:.1f} s airborne (rotors carrying at least {AIRBORNE_WEIGHT_SHARE:.0%} of "
            f"{airframe.name}'s weight, tilt under {MAX_TILT_DEG:g} deg); the rotor balance needs "
            f"{MIN_AIRBORNE_S:g} s"
        )
    per_block = max(1, round(BLOCK_S / dt))
    blocks = [
        thrust[start : start + per_block].mean(axis=0)
        for a, b in stretches
        for start in range(a, b - per_block + 1, per_block)
    ]
    mean = thrust[rows].mean(axis=0)
    if len(blocks) >= 2:
        std_error = np.std(blocks, axis=0, ddof=1) / math.sqrt(len(blocks))
    else:
        std_error = np.std(thrust[rows], axis=0, ddof=1) / math.sqrt(rows.size)
    return FlightBalance(source, mean, std_error, airborne_s, scaled)


@dataclass(frozen=True)
class RotorBaseline:
    """The vehicle's rotor balance in its normal state, from one or more flights."""

    thrust_N: FloatArray  # (N,) mean over flights of each rotor's mean commanded thrust
    scatter_N: FloatArray  # (N,) flight-to-flight standard deviation (each flight's own error if one flight)
    n_flights: int
    sources: tuple[str, ...]

    def to_section(self) -> dict[str, Any]:
        """The airframe YAML section ``rotor_balance`` (units in the keys, like every airframe number)."""
        return {
            "thrust_N": [float(f"{v:.6g}") for v in self.thrust_N],
            "scatter_N": [float(f"{v:.6g}") for v in self.scatter_N],
            "flights": self.n_flights,
            "sources": list(self.sources),
        }

    @classmethod
    def of_airframe(cls, airframe: Airframe) -> RotorBaseline | None:
        """The baseline in an identified airframe's ``rotor_balance`` section (validated on load)."""
        section = airframe.sections.get("rotor_balance")
        if section is None:
            return None
        return cls(
            np.asarray(section["thrust_N"], dtype=float),
            np.asarray(section["scatter_N"], dtype=float),
            int(section["flights"]),
            tuple(section["sources"]),
        )


def rotor_baseline(balances: Sequence[FlightBalance]) -> tuple[RotorBaseline, list[str]]:
    """The baseline from flights in the normal state, and warnings (a single flight has no scatter)."""
    if not balances:
        raise RotorBalanceError("a rotor baseline needs at least one flight")
    thrust = np.array([b.thrust_N for b in balances])
    warnings = []
    if len(balances) == 1:
        scatter = balances[0].std_error_N * math.sqrt(balances[0].airborne_s / BLOCK_S)
        warnings.append(
            "rotor balance from one flight: the flight-to-flight scatter is unknown and taken as the "
            "flight's own 1 s variation; give several normal flights (--log repeated) for standard "
            "deviations that hold"
        )
    else:
        scatter = thrust.std(axis=0, ddof=1)
    return RotorBaseline(
        thrust.mean(axis=0), scatter, len(balances), tuple(b.source for b in balances)
    ), warnings


def cw_drag_ratio(airframe: Airframe, baseline_thrust_N: FloatArray) -> float:
    """c_cw / c_ccw that balances the baseline's yaw: its ccw rotors' thrust over its cw rotors'."""
    spin = airframe.spin_signs
    return float(baseline_thrust_N[spin < 0].sum() / baseline_thrust_N[spin > 0].sum())


def yaw_weights(airframe: Airframe, baseline_thrust_N: FloatArray) -> FloatArray:
    """c_k up to scale: the spin sign, with the cw rotors' ratio set so that the baseline balances yaw."""
    return np.where(airframe.spin_signs < 0, -1.0, cw_drag_ratio(airframe, baseline_thrust_N))


def balance_rows(airframe: Airframe, baseline_thrust_N: FloatArray) -> FloatArray:
    """(4, N): weight, roll moment, pitch moment and yaw balance of the thrusts f (the module's equations)."""
    positions = airframe.rotor_positions_m
    return np.vstack(
        [
            np.ones(airframe.n_rotors),
            positions[:, 1],
            positions[:, 0],
            yaw_weights(airframe, baseline_thrust_N),
        ]
    )


@dataclass(frozen=True)
class BaselineState:
    """What the baseline's thrusts say about the vehicle (with every rotor as the map says)."""

    weight_N: float
    mass_kg: float
    cg_m: tuple[float, float]
    cw_drag_ratio: float

    @classmethod
    def of(cls, airframe: Airframe, thrust_N: FloatArray) -> BaselineState:
        """Weight, centre of gravity and yaw ratio from mean rotor thrusts."""
        positions = airframe.rotor_positions_m
        weight = float(thrust_N.sum())
        return cls(
            weight,
            weight / GRAVITY_M_S2,
            (float(positions[:, 0] @ thrust_N / weight), float(positions[:, 1] @ thrust_N / weight)),
            cw_drag_ratio(airframe, thrust_N),
        )

    def as_vector(self) -> FloatArray:
        """(mass, r_x, r_y, cw/ccw drag ratio), the order of :func:`baseline_state_std`."""
        return np.array([self.mass_kg, self.cg_m[0], self.cg_m[1], self.cw_drag_ratio])


def baseline_state_std(airframe: Airframe, baseline: RotorBaseline) -> FloatArray:
    """Standard deviations of (mass, r_x, r_y, cw/ccw drag ratio) of the baseline's mean thrusts.

    First-order propagation of each rotor's mean uncertainty, its flight-to-flight scatter / sqrt(flights).
    """
    sigma = baseline.scatter_N / math.sqrt(baseline.n_flights)
    centre = BaselineState.of(airframe, baseline.thrust_N).as_vector()
    step = 1e-6 * baseline.thrust_N
    jacobian = np.column_stack(
        [
            (
                BaselineState.of(
                    airframe, baseline.thrust_N + step[k] * np.eye(airframe.n_rotors)[k]
                ).as_vector()
                - centre
            )
            / step[k]
            for k in range(airframe.n_rotors)
        ]
    )
    return np.sqrt((jacobian**2) @ (sigma**2))


@dataclass(frozen=True)
class Explanation:
    """One fitted explanation of the suspect's commands: its parameters, residual and verdict."""

    effect: str
    parameters: dict[str, float]
    std: dict[str, float]
    chi2: float
    dof: int

    @property
    def p_value(self) -> float:
        """Chance of a residual this large if the explanation is right (1 when nothing is left to test)."""
        return 1.0 if self.dof == 0 else float(stats.chi2.sf(self.chi2, self.dof))

    @property
    def holds(self) -> bool:
        """The residual is within the noise."""
        return self.p_value >= REJECT_P

    def to_json(self) -> dict[str, Any]:
        """Plain data for reports."""
        return {
            "effect": self.effect,
            "parameters": self.parameters,
            "std": self.std,
            "chi2": self.chi2,
            "dof": self.dof,
            "p_value": self.p_value,
        }


@dataclass
class RotorDiagnosis:
    """What the suspect flight's rotor balance says, against the baseline."""

    named: str  # "none", "rotor_effectiveness" or "mass_offset+cg_offset"
    effectiveness: FloatArray
    effectiveness_std: FloatArray
    flagged: list[int]  # rotors (1-based) with e_k below 1 by more than SIGNIFICANT_Z std
    explanations: dict[str, Explanation]
    ambiguous_with: list[str]
    suspect: FlightBalance
    notes: list[str] = field(default_factory=list)
    # Rotors (1-based, not flagged) whose e_k cannot be told from the weakest rotor's.
    indistinct_rotors: list[int] = field(default_factory=list)

    @property
    def z_scores(self) -> FloatArray:
        """(e_k - 1) / std_k."""
        return (self.effectiveness - 1.0) / self.effectiveness_std

    def headline(self) -> str:
        """One line: the verdict and the rotors' effectiveness."""
        rotors = ", ".join(
            f"e_{k + 1} = {e:.3f} +/- {s:.3f}"
            for k, (e, s) in enumerate(zip(self.effectiveness, self.effectiveness_std, strict=True))
        )
        if self.named == "none":
            verdict = (
                "rotor balance: none (no rotor below 1 by 3 std, commands within the baseline's scatter)"
            )
        elif self.named == "rotor_effectiveness":
            weakest = (
                ", ".join(f"rotor {k}" for k in self.flagged)
                or f"rotor {int(np.argmin(self.effectiveness)) + 1}"
            )
            verdict = f"rotor balance: rotor_effectiveness, {weakest} weakened"
            if self.indistinct_rotors:
                lowest = int(np.argmin(self.effectiveness))
                verdict += (
                    " (or "
                    + ", ".join(
                        f"rotor {k}: e_{k} - e_{lowest + 1} = "
                        f"{self.effectiveness[k - 1] - self.effectiveness[lowest]:+.3f}"
                        for k in self.indistinct_rotors
                    )
                    + f", within {DISTINCT_Z:g} std: this log cannot tell which is weaker)"
                )
        else:
            payload = self.explanations[self.named].parameters
            verdict = (
                f"rotor balance: {self.named} (payload {payload['dm_kg'] * 1e3:+.1f} g at "
                f"r_x = {payload['r_x'] * 1e3:+.1f} mm, r_y = {payload['r_y'] * 1e3:+.1f} mm)"
            )
        if self.ambiguous_with:
            verdict += f" or {' or '.join(self.ambiguous_with)}: this log cannot tell them apart"
        return f"{verdict}; {rotors}"

    def to_json(self) -> dict[str, Any]:
        """Plain data for report.json."""
        return {
            "named": self.named,
            "ambiguous_with": self.ambiguous_with,
            "effectiveness": self.effectiveness.tolist(),
            "effectiveness_std": self.effectiveness_std.tolist(),
            "flagged_rotors": self.flagged,
            "indistinct_rotors": self.indistinct_rotors,
            "explanations": {name: e.to_json() for name, e in self.explanations.items()},
            "suspect": self.suspect.to_json(),
            "notes": self.notes,
        }


def _weighted_fit(
    design: FloatArray, residual: FloatArray, sigma: FloatArray
) -> tuple[FloatArray, FloatArray, float]:
    """Least squares of residual ~ design @ theta weighted by 1/sigma: theta, its std, chi-square."""
    weighted = design / sigma[:, None]
    target = residual / sigma
    theta, *_ = np.linalg.lstsq(weighted, target, rcond=None)
    covariance = np.linalg.pinv(weighted.T @ weighted)
    chi2 = float(np.sum((target - weighted @ theta) ** 2))
    return theta, np.sqrt(np.clip(np.diag(covariance), 0.0, None)), chi2


def diagnose(airframe: Airframe, baseline: RotorBaseline, suspect: FlightBalance) -> RotorDiagnosis:
    """Compare a suspect flight's rotor balance with the baseline (module docstring)."""
    mu, n = baseline.thrust_N, baseline.n_flights
    F = suspect.thrust_N
    # A single flight scatters about the vehicle's state as the baseline flights did; the baseline
    # mean is itself uncertain by scatter / sqrt(n).
    sigma = np.sqrt(baseline.scatter_N**2 * (1.0 + 1.0 / n) + suspect.std_error_N**2)
    effectiveness = mu / F
    effectiveness_std = effectiveness * sigma / F
    z = (effectiveness - 1.0) / effectiveness_std
    flagged = [int(k) + 1 for k in np.flatnonzero(z < -SIGNIFICANT_Z)]
    change = F - mu
    state = BaselineState.of(airframe, baseline.thrust_N)

    explanations: dict[str, Explanation] = {}
    chi2_none = float(np.sum((change / sigma) ** 2))
    explanations["none"] = Explanation("none", {}, {}, chi2_none, airframe.n_rotors)

    weakened = flagged or [int(np.argmin(effectiveness)) + 1]
    columns = np.eye(airframe.n_rotors)[:, [k - 1 for k in weakened]]
    _, _, chi2_rotor = _weighted_fit(columns, change, sigma)
    explanations["rotor_effectiveness"] = Explanation(
        "rotor_effectiveness",
        {f"e_{k + 1}": float(e) for k, e in enumerate(effectiveness)},
        {f"e_{k + 1}": float(s) for k, s in enumerate(effectiveness_std)},
        chi2_rotor,
        airframe.n_rotors - len(weakened),
    )

    # Payload: the balance's minimum-norm response to (dW, d(W r_y), d(W r_x)) with yaw unchanged.
    response = np.linalg.pinv(balance_rows(airframe, mu))[:, :3]
    theta, theta_std, chi2_payload = _weighted_fit(response, change, sigma)
    d_weight, d_moment_y, d_moment_x = theta
    new_weight = state.weight_N + d_weight
    r_y = (state.weight_N * state.cg_m[1] + d_moment_y) / new_weight - state.cg_m[1]
    r_x = (state.weight_N * state.cg_m[0] + d_moment_x) / new_weight - state.cg_m[0]
    explanations["mass_offset+cg_offset"] = Explanation(
        "mass_offset+cg_offset",
        {"dm_kg": float(d_weight / GRAVITY_M_S2), "r_x": float(r_x), "r_y": float(r_y)},
        {
            "dm_kg": float(theta_std[0] / GRAVITY_M_S2),
            "r_x": float(theta_std[2] / new_weight),
            "r_y": float(theta_std[1] / new_weight),
        },
        chi2_payload,
        airframe.n_rotors - 3,
    )

    notes = [
        f"baseline: {n} flight(s); weight carried {state.mass_kg * 1e3:.1f} g, centre of gravity "
        f"({state.cg_m[0] * 1e3:+.2f}, {state.cg_m[1] * 1e3:+.2f}) mm, "
        f"cw/ccw drag ratio {state.cw_drag_ratio:.3f}"
    ]
    if explanations["none"].holds and not flagged:
        named, ambiguous = "none", []
    else:
        best, other = sorted(
            ("rotor_effectiveness", "mass_offset+cg_offset"), key=lambda name: -explanations[name].p_value
        )
        if not explanations[best].holds:
            notes.append(
                f"neither a weakened rotor nor a payload explains the commands within the noise; "
                f"{best} comes closest (p = {explanations[best].p_value:.2g})"
            )
        runner_up = explanations[other].p_value
        look_alike = explanations[other].holds and runner_up * DECISIVE_P_RATIO >= explanations[best].p_value
        named, ambiguous = best, [other] if look_alike else []
    lowest = int(np.argmin(effectiveness))
    indistinct = [
        k + 1
        for k in range(airframe.n_rotors)
        if k != lowest
        and k + 1 not in flagged
        and effectiveness[k] - effectiveness[lowest]
        < DISTINCT_Z * math.hypot(effectiveness_std[k], effectiveness_std[lowest])
    ]
    return RotorDiagnosis(
        named,
        effectiveness,
        effectiveness_std,
        flagged,
        explanations,
        ambiguous,
        suspect,
        notes,
        indistinct if named == "rotor_effectiveness" else [],
    )
