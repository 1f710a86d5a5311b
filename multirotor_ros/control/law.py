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

Anti-windup takes an integral's step back whole while the rotors cannot give what is asked (before
2026-11-29 the unclamped step was taken back, which moved an integral at its limit away from it).

Cost: the law up to the wanted thrust and torque is one compiled scalar kernel (model/jit.py ``_law``),
the allocation another. It runs 250 times a second per vehicle, and a fleet controller runs it for every
vehicle of its process in each period: one update cost 26-32 us in Python, 16-18 us compiled
(allocation included; /tmp-script timing of 20,000 updates, best of 7, in alternation, 2026-11-29).
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
from multirotor_ros.model.jit import kernel
from multirotor_ros.model.rotation import FloatArray

# A short vector read element by element: the law runs at 250 Hz on one vehicle, where numpy calls
# dominate, so it takes tuples and lists as well as arrays and never converts them.
Components = Sequence[float] | FloatArray


def saturate(s: ArrayLike, bound: ArrayLike) -> FloatArray:
    """sigma_b(s) of seed 1 eq. 10: s inside (-b, b), else +-b."""
    b = np.asarray(bound, dtype=float)
    return np.clip(np.asarray(s, dtype=float), -b, b)


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
        self._gains = _gain_array(gains)
        self.reset()
        # The kernel compiled (or loaded from numba's cache) now, not in a first control period.
        self.update(
            0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0
        )
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
        self._gains = _gain_array(gains)

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
        p_x, p_y, p_z = p_WB_W
        v_x, v_y, v_z = v_WB_W
        q_w, q_x, q_y, q_z = q_WB
        w_x, w_y, w_z = w_WB_B
        p_dx, p_dy, p_dz = p_desired_W
        thrust, tau_x, tau_y, tau_z, e_z, step_z, e_psi, step_psi, alpha_psi = kernel(_law)(
            self._gains, self.gravity_m_s2, self.airframe.mass_kg, self._inertia,
            float(p_x), float(p_y), float(p_z), float(v_x), float(v_y), float(v_z),
            float(q_w), float(q_x), float(q_y), float(q_z), float(w_x), float(w_y), float(w_z),
            float(p_dx), float(p_dy), float(p_dz), float(yaw_desired_rad),
            self._step(t_s), self._integral_z, self._integral_psi,
        )  # fmt: skip
        self._integral_z, self._integral_psi = self._integral_z + step_z, self._integral_psi + step_psi
        allocation = self.allocator.allocate(thrust, (tau_x, tau_y, tau_z), effectiveness)
        # Anti-windup: while the rotors cannot give what is asked, integrating the error would only wind up.
        thrust_short = allocation.thrust_N < thrust - 1e-9 and e_z > 0
        thrust_over = allocation.thrust_N > thrust + 1e-9 and e_z < 0
        if thrust_short or thrust_over:
            self._integral_z -= step_z
        if allocation.yaw_fraction < 1.0 and e_psi * alpha_psi > 0:
            self._integral_psi -= step_psi
        return ControlOutput(allocation.omega_rad_s, thrust, np.array((tau_x, tau_y, tau_z)), allocation)

    def _step(self, t_s: float) -> float:
        """Time since the last update [s], 0 on the first; a gap longer than 0.1 s counts as 0.1 s."""
        dt = 0.0 if self._last_t is None else min(max(t_s - self._last_t, 0.0), 0.1)
        self._last_t = t_s
        return dt


# The gains :func:`_law` reads, in the order it unpacks them from its array (rate_hz is the caller's).
_LAW_GAINS = (
    "k_px", "k_dx", "k_ptheta", "k_dtheta", "b_px", "b_dx", "b_ptheta", "b_dtheta",
    "k_py", "k_dy", "k_pphi", "k_dphi", "b_py", "b_dy", "b_pphi", "b_dphi",
    "k_pz", "k_dz", "k_iz", "i_limit_z", "b_iz", "k_ppsi", "k_dpsi", "k_ipsi", "i_limit_psi", "b_ipsi",
)  # fmt: skip


def _gain_array(gains: ControllerGains) -> FloatArray:
    """The gains as :func:`_law` takes them: by name, in the order of :data:`_LAW_GAINS`."""
    return np.array([getattr(gains, name) for name in _LAW_GAINS])


def _law(
    gains: FloatArray,
    gravity: float,
    mass: float,
    inertia: FloatArray,
    p_x: float,
    p_y: float,
    p_z: float,
    v_x: float,
    v_y: float,
    v_z: float,
    q_w: float,
    q_x: float,
    q_y: float,
    q_z: float,
    w_x: float,
    w_y: float,
    w_z: float,
    p_dx: float,
    p_dy: float,
    p_dz: float,
    yaw_desired: float,
    dt: float,
    integral_z: float,
    integral_psi: float,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """One evaluation of the law (module docstring), up to the wanted thrust and torque. Compiled (jit.py).

    Returns (thrust [N], torque (3) [N m], e_z, the step of the altitude integral, e_psi, the step of
    the yaw integral, alpha_psi): the integral steps are already clamped, the caller takes them back for
    anti-windup when the rotors cannot deliver.
    """
    # In the order of _LAW_GAINS.
    (
        k_px, k_dx, k_ptheta, k_dtheta, b_px, b_dx, b_ptheta, b_dtheta,
        k_py, k_dy, k_pphi, k_dphi, b_py, b_dy, b_pphi, b_dphi,
        k_pz, k_dz, k_iz, i_limit_z, b_iz, k_ppsi, k_dpsi, k_ipsi, i_limit_psi, b_ipsi,
    ) = gains  # fmt: skip

    def sat(s: float, bound: float) -> float:  # saturate() on a scalar
        return bound if s > bound else -bound if s < -bound else s

    # ZYX Euler angles of the unit quaternion (model/rotation.py quat_to_euler) and their rates.
    phi = math.atan2(2 * (q_w * q_x + q_y * q_z), 1 - 2 * (q_x * q_x + q_y * q_y))
    theta = math.asin(min(1.0, max(-1.0, 2 * (q_w * q_y - q_z * q_x))))
    psi = math.atan2(2 * (q_w * q_z + q_x * q_y), 1 - 2 * (q_y * q_y + q_z * q_z))
    s_phi, c_phi = math.sin(phi), math.cos(phi)
    lateral = w_y * s_phi + w_z * c_phi
    dphi = w_x + lateral * math.tan(theta)
    dtheta = w_y * c_phi - w_z * s_phi
    dpsi = lateral / max(math.cos(theta), 1e-6)

    # Heading frame: the x/y errors and velocities seen with the yaw removed.
    c_psi, s_psi = math.cos(psi), math.sin(psi)
    e_x = c_psi * (p_x - p_dx) + s_psi * (p_y - p_dy)
    e_y = -s_psi * (p_x - p_dx) + c_psi * (p_y - p_dy)
    u_x = c_psi * v_x + s_psi * v_y
    u_y = -s_psi * v_x + c_psi * v_y
    alpha_phi = (
        sat(k_py * e_y, b_py) + sat(k_dy * u_y, b_dy) - sat(k_pphi * phi, b_pphi) - sat(k_dphi * dphi, b_dphi)
    ) / gravity
    alpha_theta = (
        -sat(k_px * e_x, b_px) - sat(k_dx * u_x, b_dx) - sat(k_ptheta * theta, b_ptheta)
        - sat(k_dtheta * dtheta, b_dtheta)
    ) / gravity  # fmt: skip

    # Eq. 8 for altitude: an acceleration, integral clamped (anti-windup), then thrust.
    e_z = p_dz - p_z
    step_z = sat(integral_z + sat(e_z, b_iz) * dt, i_limit_z / k_iz) - integral_z
    a_z = k_pz * e_z - k_dz * v_z + k_iz * (integral_z + step_z)
    tilt = max(math.cos(phi) * math.cos(theta), 0.5)  # beyond 60 deg of tilt, do not chase altitude
    thrust = mass * (gravity + a_z) / tilt

    # Eq. 8 for yaw, on the error wrapped into [-pi, pi): the short way round.
    e_psi = (yaw_desired - psi + math.pi) % (2.0 * math.pi) - math.pi
    step_psi = sat(integral_psi + sat(e_psi, b_ipsi) * dt, i_limit_psi / k_ipsi) - integral_psi
    alpha_psi = k_ppsi * e_psi - k_dpsi * dpsi + k_ipsi * (integral_psi + step_psi)
    torque_x, torque_y, torque_z = inertia[0] * alpha_phi, inertia[1] * alpha_theta, inertia[2] * alpha_psi
    return thrust, torque_x, torque_y, torque_z, e_z, step_z, e_psi, step_psi, alpha_psi
