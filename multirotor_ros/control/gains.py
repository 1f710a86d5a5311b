"""Gains of the seed 1 control law (eqs. 8-10) under the paper's names: one set, overridden per airframe YAML.

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

The gains are defined once, in :data:`SEED1_GAINS` below; an airframe's YAML ``controller:`` section
holds only the gains that differ for that airframe, each with its reason.
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


# Seed 1 prints no gains: these are tuned here, by simulation of the X8 with motor lag, and used by every
# airframe. The law works in accelerations (torques are the inertia times them, thrust the mass times
# them), so the same numbers give the same closed loop on any airframe whose rotors follow their commands
# well inside the attitude loop's bandwidth (test_control.py checks every airframe in config/).
SEED1_GAINS = ControllerGains(
    # Inner attitude loop: d2phi/dt2 = -(k_pphi/g) phi - (k_dphi/g) dphi, i.e. 8 rad/s natural frequency,
    # damping 0.8: well inside the rotor lag's bandwidth (1/0.03 s = 33 rad/s for the slowest rotors in
    # config/) and the 250 Hz loop.
    k_ptheta=630.0,  # [m/s^4/rad] (8 rad/s)^2 * g
    k_dtheta=125.0,  # [m/s^3/rad] 2 * 0.8 * 8 rad/s * g
    b_ptheta=400.0,  # [m/s^4] above b_px + b_dx, so the attitude term can always balance them
    b_dtheta=500.0,  # [m/s^4] the pitch rate term saturates beyond 500/125 = 4 rad/s
    k_pphi=630.0,  # [m/s^4/rad] as pitch: the airframes in config/ are symmetric enough
    k_dphi=125.0,  # [m/s^3/rad]
    b_pphi=400.0,  # [m/s^4]
    b_dphi=500.0,  # [m/s^4]
    # Outer position loop: d2x/dt2 = -(g/k_ptheta)(k_px e_x + k_dx v_x): 1.6 rad/s, damping 0.9.
    k_px=165.0,  # [1/s^4] (1.6 rad/s)^2 * k_ptheta / g
    k_dx=185.0,  # [1/s^3] 2 * 0.9 * 1.6 rad/s * k_ptheta / g
    b_px=160.0,  # [m/s^4] at most 160/630 = 0.25 rad of tilt for position error (saturates beyond ~1 m)
    b_dx=190.0,  # [m/s^4] at most 0.3 rad for velocity; cruise speed b_px/k_dx = 0.86 m/s
    k_py=165.0,  # [1/s^4] as x
    k_dy=185.0,  # [1/s^3]
    b_py=160.0,  # [m/s^4]
    b_dy=190.0,  # [m/s^4]
    # Altitude PID (eq. 8) on vertical acceleration, gravity feed-forward.
    k_pz=9.0,  # [1/s^2] 3 rad/s
    k_dz=6.0,  # [1/s] damping 1
    k_iz=4.0,  # [1/s^3] removes a thrust shortfall (a lost rotor) within a few seconds
    i_limit_z=4.0,  # [m/s^2] 40 % of g: the X8 on seven rotors lacks 1/8 of its thrust, 12.5 % of g
    b_iz=0.1,  # [m] integrated error saturated, so a 1 m climb overshoots ~5 %
    # Yaw PID (eq. 8) on yaw acceleration.
    k_ppsi=16.0,  # [1/s^2] 4 rad/s
    k_dpsi=8.0,  # [1/s] damping 1
    k_ipsi=4.0,  # [1/s^3] cancels the drag torque imbalance of a lost rotor
    i_limit_psi=1.0,  # [rad/s^2]
    b_ipsi=0.2,  # [rad] integrated error saturated (anti-windup)
    rate_hz=250.0,  # [Hz] control and motor command rate
)


def gains_from_section(section: Mapping[str, Any] | None, origin: str) -> ControllerGains:
    """:data:`SEED1_GAINS` with an airframe YAML's ``controller:`` overrides (None: no overrides).

    Errors name ``origin`` (the file) and the key.
    """
    if section is None:
        return SEED1_GAINS
    if not isinstance(section, Mapping):
        raise GainError(f"{origin}: controller: expected a mapping of gains ({', '.join(GAIN_UNITS)})")
    unknown = sorted(set(section) - set(GAIN_UNITS))
    if unknown:
        raise GainError(
            f"{origin}: controller.{unknown[0]}: unknown key; the gains are {', '.join(GAIN_UNITS)}"
        )
    for name, value in section.items():
        problem = gain_problem(name, value)
        if problem:
            raise GainError(f"{origin}: controller.{name}: {problem}")
    return SEED1_GAINS.replace(**{name: float(value) for name, value in section.items()})


def airframe_gains(airframe: Any) -> ControllerGains:
    """An :class:`~multirotor_ros.model.airframe.Airframe`'s gains: :data:`SEED1_GAINS` and its overrides."""
    origin = str(airframe.source_path) if airframe.source_path is not None else airframe.name
    return gains_from_section(airframe.sections.get("controller"), origin)
