"""The control law of seed 1 (Saied et al. 2015, §II-B), written for world ENU and body FLU.

- Altitude and yaw: PID, eq. 8, on acceleration, with gravity feed-forward and tilt compensation for
  the thrust (see gains.py for the exact form) and clamped integrals (anti-windup).
- x and y: the saturation law of eqs. 9-10 through pitch and roll, the attitude terms of the same
  bracket being the inner attitude loop. It is a sum of saturations, each term bounded separately ("each
  state is bounded separately", seed 1 §II-B), not nested saturations sigma_1(a + sigma_2(b + ...)):
  the bracket is bounded by the sum of the four bounds, and no term's saturation limits another's:

      tau_phi   = I_xx/g [ s_py(k_py e_y) + s_dy(k_dy v_y) - s_pphi(k_pphi phi) - s_dphi(k_dphi dphi)]
      tau_theta = I_yy/g [-s_px(k_px e_x) - s_dx(k_dx v_x) - s_pth(k_ptheta theta) - s_dth(k_dtheta dtheta)]

  (s_ for the paper's sigma_, the saturations of eq. 10)

  with e = p - p_d and v the velocity, both rotated into the heading frame (yaw removed) so that the
  law holds at any yaw. Signs: with R = Rz Ry Rx (ENU/FLU) a small roll phi accelerates the vehicle
  along -y (eq. 7, -C_psi S_phi) and a small pitch theta along +x (eq. 7, C_psi S_theta C_phi). The
  roll line is eq. 9 as printed. The pitch line of eq. 9 as printed, -I_yy/g [sigma_px + sigma_dx -
  sigma_ptheta - sigma_dtheta], feeds pitch back with a positive sign (an unstable inner loop in these
  axes); here the position terms carry the minus, because +theta moves the vehicle towards +x, and the
  attitude terms are the same damping as for roll. test_control.py checks both signs by simulation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.control.allocation import AllocationResult, Allocator
from multirotor_ros.control.gains import ControllerGains
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe
from multirotor_ros.model.rotation import FloatArray

# A short vector read element by element: the law runs at 250 Hz on one vehicle, where numpy calls
# dominate, so it takes tuples and lists as well as arrays and never converts them.
Components = Sequence[float] | FloatArray


def saturate(s: ArrayLike, bound: ArrayLike) -> FloatArray:
    """sigma_b(s) of seed 1 eq. 10: s inside (-b, b), else +-b."""
    b = np.asarray(bound, dtype=float)
    return np.clip(np.asarray(s, dtype=float), -b, b)


def _sat(s: float, bound: float) -> float:
    # Scalar form of saturate(): the law runs at 250 Hz on one vehicle, where numpy calls dominate.
    return bound if s > bound else -bound if s < -bound else s


def _euler(q_WB: Components) -> tuple[float, float, float]:
    # Scalar twin of rotation.quat_to_euler, for the same reason as _sat.
    w, x, y, z = (float(v) for v in q_WB)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(1.0, max(-1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def wrap_angle(angle_rad: float) -> float:
    """An angle in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def euler_rates(euler: Components, w_WB_B: Components) -> tuple[float, float, float]:
    """ZYX Euler angle rates (dphi, dtheta, dpsi) [rad/s] from body rates (p, q, r) in FLU."""
    phi, theta = float(euler[0]), float(euler[1])
    p, q, r = (float(v) for v in w_WB_B)
    s_phi, c_phi = math.sin(phi), math.cos(phi)
    c_theta = max(math.cos(theta), 1e-6)
    lateral = q * s_phi + r * c_phi
    return p + lateral * math.tan(theta), q * c_phi - r * s_phi, lateral / c_theta


@dataclass(frozen=True)
class ControlOutput:
    """One evaluation of the law: rotor speeds and what they were made from."""

    omega_cmd_rad_s: FloatArray  # (N,) rotor speed commands
    thrust_N: float  # wanted collective thrust
    torque_B: FloatArray  # (3,) wanted body torque [N m], FLU
    allocation: AllocationResult


class SaturationController:
    """Position and yaw control of one vehicle with the seed 1 law; pure (no ROS), stateful (integrals).

    ``update(t, p, v, q, w, p_d, yaw_d)`` with p_WB_W, v_WB_W in world ENU [m, m/s], q_WB (w, x, y, z),
    w_WB_B in FLU [rad/s], the wanted position [m] and yaw [rad]; returns rotor speed commands [rad/s].
    """

    def __init__(self, airframe: Airframe, gains: ControllerGains, gravity_m_s2: float = GRAVITY_M_S2):
        self.airframe = airframe
        self.gains = gains
        self.gravity_m_s2 = gravity_m_s2
        self.allocator = Allocator.for_airframe(airframe)
        self._inertia = np.diag(airframe.inertia_kg_m2).copy()
        self.reset()

    def reset(self) -> None:
        """Forget the integrals and the last update time (e.g. after landing or a long gap)."""
        self._integral_z = 0.0
        self._integral_psi = 0.0
        self._last_t: float | None = None

    def set_gains(self, gains: ControllerGains) -> None:
        """Change gains at run time; the integral terms are rescaled to keep the output continuous."""
        if self.gains.k_iz > 0:
            self._integral_z *= self.gains.k_iz / gains.k_iz
        if self.gains.k_ipsi > 0:
            self._integral_psi *= self.gains.k_ipsi / gains.k_ipsi
        self.gains = gains

    def update(
        self,
        t_s: float,
        p_WB_W: Components,
        v_WB_W: Components,
        q_WB: Components,
        w_WB_B: Components,
        p_desired_W: Components,
        yaw_desired_rad: float,
        effectiveness: ArrayLike | None = None,
    ) -> ControlOutput:
        """Rotor speed commands for the current state and the wanted position and yaw.

        ``effectiveness``: (N,) share of its nominal thrust each rotor gives (None = all healthy), passed
        to the allocator (B diag(e), dead rotors left out); the gains do not change with it.
        """
        g = self.gains
        gravity = self.gravity_m_s2
        p = [float(c) for c in p_WB_W]
        v = [float(c) for c in v_WB_W]
        p_d = [float(c) for c in p_desired_W]
        phi, theta, psi = _euler(q_WB)
        dphi, dtheta, dpsi = euler_rates((phi, theta, psi), w_WB_B)
        dt = self._step(t_s)

        # Heading frame: the x/y errors and velocities seen with the yaw removed.
        c_psi, s_psi = math.cos(psi), math.sin(psi)
        e_W = (p[0] - p_d[0], p[1] - p_d[1])
        e_x = c_psi * e_W[0] + s_psi * e_W[1]
        e_y = -s_psi * e_W[0] + c_psi * e_W[1]
        v_x = c_psi * v[0] + s_psi * v[1]
        v_y = -s_psi * v[0] + c_psi * v[1]

        alpha_phi = (
            _sat(g.k_py * e_y, g.b_py)
            + _sat(g.k_dy * v_y, g.b_dy)
            - _sat(g.k_pphi * phi, g.b_pphi)
            - _sat(g.k_dphi * dphi, g.b_dphi)
        ) / gravity
        alpha_theta = (
            -_sat(g.k_px * e_x, g.b_px)
            - _sat(g.k_dx * v_x, g.b_dx)
            - _sat(g.k_ptheta * theta, g.b_ptheta)
            - _sat(g.k_dtheta * dtheta, g.b_dtheta)
        ) / gravity

        # Eq. 8 for altitude: an acceleration, integral clamped (anti-windup), then thrust.
        e_z = p_d[2] - p[2]
        step_z = _sat(e_z, g.b_iz) * dt
        self._integral_z = _sat(self._integral_z + step_z, g.i_limit_z / g.k_iz)
        a_z = g.k_pz * e_z - g.k_dz * v[2] + g.k_iz * self._integral_z
        tilt = max(math.cos(phi) * math.cos(theta), 0.5)  # beyond 60 deg of tilt, do not chase altitude
        thrust = self.airframe.mass_kg * (gravity + a_z) / tilt

        # Eq. 8 for yaw.
        e_psi = wrap_angle(yaw_desired_rad - psi)
        step_psi = _sat(e_psi, g.b_ipsi) * dt
        self._integral_psi = _sat(self._integral_psi + step_psi, g.i_limit_psi / g.k_ipsi)
        alpha_psi = g.k_ppsi * e_psi - g.k_dpsi * dpsi + g.k_ipsi * self._integral_psi

        torque = self._inertia * np.array([alpha_phi, alpha_theta, alpha_psi])
        allocation = self.allocator.allocate(thrust, torque, effectiveness)
        # Anti-windup: while the rotors cannot give what is asked, integrating the error would only wind up.
        thrust_short = allocation.thrust_N < thrust - 1e-9 and e_z > 0
        thrust_over = allocation.thrust_N > thrust + 1e-9 and e_z < 0
        if thrust_short or thrust_over:
            self._integral_z -= step_z
        if allocation.yaw_fraction < 1.0 and e_psi * alpha_psi > 0:
            self._integral_psi -= step_psi
        return ControlOutput(allocation.omega_rad_s, thrust, torque, allocation)

    def _step(self, t_s: float) -> float:
        """Time since the last update [s], 0 on the first; a gap longer than 0.1 s counts as 0.1 s."""
        dt = 0.0 if self._last_t is None else min(max(t_s - self._last_t, 0.0), 0.1)
        self._last_t = t_s
        return dt
