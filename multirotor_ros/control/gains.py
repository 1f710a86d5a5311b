"""Gains of the seed 1 control law (eqs. 8-10) under the paper's names, read from an airframe's YAML.

Units follow from eq. 9 as printed, tau_phi = I_xx/g [sigma_py(k_py e_y) + sigma_dy(k_dy vy) -
sigma_pphi(k_pphi phi) - sigma_dphi(k_dphi dphi)]: the bracket divided by g is an angular acceleration,
so every term of the bracket, and every bound b, is in m/s^4 (rad counted as 1). Hence k_p(x|y) in 1/s^4,
k_d(x|y) in 1/s^3, k_p(theta|phi) in m/s^4 per rad, k_d(theta|phi) in m/s^3 per rad.
Reading the inner loop alone: d2phi/dt2 = -(k_pphi/g) phi - (k_dphi/g) dphi, a second-order loop of
natural frequency sqrt(k_pphi/g); the outer loop ends with d2y/dt2 = -(g/k_pphi)(k_py e_y + k_dy vy).

The altitude and yaw PIDs (eq. 8) act on accelerations: thrust = m (g + k_pz e_z - k_dz vz + k_iz int e_z)
/ (cos phi cos theta), tau_psi = I_zz (k_ppsi e_psi - k_dpsi dpsi + k_ipsi int e_psi). Anti-windup: what
is integrated is the error through a saturation of the paper's eq. 10, sigma_iz(e_z) and sigma_ipsi(e_psi)
(a climb of a metre would otherwise wind the integral up for an overshoot), each integral term is clamped
to ``i_limit_*``, and integration stops while the rotors cannot deliver what is asked.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

# name -> (unit, meaning); the order is the order of the dataclass fields below.
GAIN_UNITS: dict[str, tuple[str, str]] = {
    "k_px": ("1/s^4", "x position error gain (eq. 9, tau_theta)"),
    "k_dx": ("1/s^3", "x velocity gain"),
    "k_ptheta": ("m/s^4/rad", "pitch angle gain"),
    "k_dtheta": ("m/s^3/rad", "pitch rate gain"),
    "b_px": ("m/s^4", "bound of sigma_px"),
    "b_dx": ("m/s^4", "bound of sigma_dx"),
    "b_ptheta": ("m/s^4", "bound of sigma_ptheta"),
    "b_dtheta": ("m/s^4", "bound of sigma_dtheta"),
    "k_py": ("1/s^4", "y position error gain (eq. 9, tau_phi)"),
    "k_dy": ("1/s^3", "y velocity gain"),
    "k_pphi": ("m/s^4/rad", "roll angle gain"),
    "k_dphi": ("m/s^3/rad", "roll rate gain"),
    "b_py": ("m/s^4", "bound of sigma_py"),
    "b_dy": ("m/s^4", "bound of sigma_dy"),
    "b_pphi": ("m/s^4", "bound of sigma_pphi"),
    "b_dphi": ("m/s^4", "bound of sigma_dphi"),
    "k_pz": ("1/s^2", "altitude proportional gain (eq. 8)"),
    "k_dz": ("1/s", "altitude derivative gain"),
    "k_iz": ("1/s^3", "altitude integral gain"),
    "i_limit_z": ("m/s^2", "bound of the altitude integral term (anti-windup)"),
    "b_iz": ("m", "bound of sigma_iz, the saturated altitude error that is integrated (anti-windup)"),
    "k_ppsi": ("1/s^2", "yaw proportional gain (eq. 8)"),
    "k_dpsi": ("1/s", "yaw derivative gain"),
    "k_ipsi": ("1/s^3", "yaw integral gain"),
    "i_limit_psi": ("rad/s^2", "bound of the yaw integral term (anti-windup)"),
    "b_ipsi": ("rad", "bound of sigma_ipsi, the saturated yaw error that is integrated (anti-windup)"),
    "rate_hz": ("Hz", "rate at which the law runs and motor commands are sent"),
}


class GainError(ValueError):
    """A controller section that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class ControllerGains:
    """Every gain of the law; all must be finite and > 0 (the paper's gains are positive)."""

    k_px: float
    k_dx: float
    k_ptheta: float
    k_dtheta: float
    b_px: float
    b_dx: float
    b_ptheta: float
    b_dtheta: float
    k_py: float
    k_dy: float
    k_pphi: float
    k_dphi: float
    b_py: float
    b_dy: float
    b_pphi: float
    b_dphi: float
    k_pz: float
    k_dz: float
    k_iz: float
    i_limit_z: float
    b_iz: float
    k_ppsi: float
    k_dpsi: float
    k_ipsi: float
    i_limit_psi: float
    b_ipsi: float
    rate_hz: float

    def __post_init__(self) -> None:
        for name, value in self.as_dict().items():
            problem = gain_problem(name, value)
            if problem:
                raise GainError(f"controller.{name}: {problem}")

    def as_dict(self) -> dict[str, float]:
        """Name -> value, in the order of GAIN_UNITS."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def replace(self, **changes: float) -> ControllerGains:
        """A copy with some gains changed (validated)."""
        return ControllerGains(**{**self.as_dict(), **changes})


def gain_problem(name: str, value: Any) -> str | None:
    """None if ``value`` is a valid value of gain ``name``, else why not."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"expected a number [{GAIN_UNITS[name][0]}], got {value!r}"
    if not math.isfinite(value) or value <= 0:
        return f"must be a finite number > 0 [{GAIN_UNITS[name][0]}], got {value!r}"
    return None


def gains_from_section(section: Mapping[str, Any] | None, origin: str) -> ControllerGains:
    """Validate an airframe YAML's ``controller:`` mapping; errors name ``origin`` (the file) and the key."""
    if not isinstance(section, Mapping):
        raise GainError(f"{origin}: controller: expected a mapping of gains ({', '.join(GAIN_UNITS)})")
    unknown = sorted(set(section) - set(GAIN_UNITS))
    if unknown:
        raise GainError(
            f"{origin}: controller.{unknown[0]}: unknown key; the gains are {', '.join(GAIN_UNITS)}"
        )
    missing = [name for name in GAIN_UNITS if name not in section]
    if missing:
        raise GainError(
            f"{origin}: controller.{missing[0]}: missing ({GAIN_UNITS[missing[0]][0]}, "
            f"{GAIN_UNITS[missing[0]][1]})"
        )
    for name in GAIN_UNITS:
        problem = gain_problem(name, section[name])
        if problem:
            raise GainError(f"{origin}: controller.{name}: {problem}")
    return ControllerGains(**{name: float(section[name]) for name in GAIN_UNITS})


def airframe_gains(airframe: Any) -> ControllerGains:
    """The gains of an :class:`~multirotor_ros.model.airframe.Airframe` (its YAML's controller section)."""
    origin = str(airframe.source_path) if airframe.source_path is not None else airframe.name
    return gains_from_section(airframe.sections.get("controller"), origin)
