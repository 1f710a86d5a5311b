"""Compiled fast path of :meth:`Model.derivative` + RK4 for the effects of effects.md.

Why a second form of the same physics: a single vehicle at 1 kHz must run thousands of times faster
than real time inside a node, and numpy's per-call overhead (about 1 us per operation, ~300 operations
per RK4 step) makes that impossible for B = 1. This module evaluates the identical equations per vehicle
in scalar code compiled by numba, looping over the batch in parallel. The numpy :class:`Model` stays the
reference (readable, composable, used by identification on whole logs); ``test_compiled.py`` checks
that both give the same derivative for every effect, so a formula changed in one place and not the
other fails the suite. Models with an effect this kernel does not know use the numpy path.

Parameters are packed per vehicle into one row (see ``PARAMETER_LAYOUT``), neutral values meaning
"effect absent" (drag 0, eta 1, no ground effect radius 0, no motor lag tau 0, no fault motor 0).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

PARAMETER_LAYOUT: dict[str, int] = {
    name: index
    for index, name in enumerate(
        (
            "mass_kg", "gravity_m_s2", "k_f", "k_t", "c_x", "c_y", "c_z", "k_h", "k_f1", "eta_lower",
            "rotor_radius_m", "k_v", "tau_s", "f_x", "f_y", "f_z", "motor", "effectiveness", "t_fault_s",
            "j_r", "r_x", "r_y",
        )
    )
}
NEUTRAL = {"eta_lower": 1.0, "effectiveness": 1.0}
SUPPORTED_EFFECTS = frozenset(
    {
        "quadratic_drag", "rotor_drag", "thrust_speed_dependence", "coaxial_loss", "ground_effect",
        "inflow_thrust_loss", "motor_lag", "mass_offset", "constant_force", "actuator_fault", "gyroscopic",
        "cg_offset",
    }
)
GROUND_MIN_HEIGHT_IN_RADII = 0.5  # as GroundEffect.MIN_HEIGHT_IN_RADII


def supports(model: Model) -> bool:
    """Whether every effect of ``model`` is implemented here."""
    return all(effect.id in SUPPORTED_EFFECTS for effect in model.effects)


def pack_parameters(model: Model, batch: int) -> FloatArray:
    """(batch, P) parameter rows of ``model``; per-vehicle effect parameters broadcast over the batch."""
    rows = np.zeros((batch, len(PARAMETER_LAYOUT)))
    for name, value in NEUTRAL.items():
        rows[:, PARAMETER_LAYOUT[name]] = value
    rows[:, PARAMETER_LAYOUT["mass_kg"]] = np.broadcast_to(model.mass_kg, (batch,))
    rows[:, PARAMETER_LAYOUT["gravity_m_s2"]] = model.gravity_m_s2
    rows[:, PARAMETER_LAYOUT["k_f"]] = model.airframe.k_f_N_s2
    rows[:, PARAMETER_LAYOUT["k_t"]] = model.airframe.k_t_N_m_s2
    for effect in model.effects:
        for name, value in effect.parameters.items():
            if name in PARAMETER_LAYOUT and name != "mass_kg":
                rows[:, PARAMETER_LAYOUT[name]] = np.broadcast_to(value, (batch,))
    return rows


# Rotor sums: total thrust, the three body torques, sum of speeds, signed rotor momentum per J_r.
N_SUMS = 6


@njit(cache=True)
def _rotor_sums(t, x, u, prm, positions, spin, lower, sums):
    """Per-rotor thrust and drag torque, summed; also d(omega)/dt of the rotor states (motor lag)."""
    n = positions.shape[0]
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    r02 = 2 * (qx * qz + qw * qy)
    r12 = 2 * (qy * qz - qw * qx)
    r20 = 2 * (qx * qz - qw * qy)
    r21 = 2 * (qy * qz + qw * qx)
    r22 = 1 - 2 * (qx * qx + qy * qy)
    k_f, k_t, k_f1, eta_lower = prm[2], prm[3], prm[8], prm[9]
    radius, k_v, tau = prm[10], prm[11], prm[12]
    fault_motor, effectiveness, t_fault = int(prm[16]), prm[17], prm[18]
    climb = x[3] * r02 + x[4] * r12 + x[5] * r22
    total = 0.0
    tau_x = 0.0
    tau_y = 0.0
    tau_z = 0.0
    omega_sum = 0.0
    spin_momentum = 0.0
    for i in range(n):
        w = x[13 + i] if tau > 0 else u[i]
        thrust = k_f * w * w + k_f1 * w * w * w - k_v * w * climb
        factor = eta_lower if lower[i] else 1.0
        if radius > 0:
            height = x[2] + r20 * positions[i, 0] + r21 * positions[i, 1] + r22 * positions[i, 2]
            height = max(height, GROUND_MIN_HEIGHT_IN_RADII * radius)
            ratio = radius / (4.0 * height)
            factor *= 1.0 / (1.0 - ratio * ratio)
        torque_factor = 1.0
        if fault_motor == i + 1 and t >= t_fault:
            factor *= effectiveness
            torque_factor = effectiveness
        thrust *= factor
        total += thrust
        tau_x += thrust * positions[i, 1]
        tau_y -= thrust * positions[i, 0]
        tau_z += spin[i] * k_t * w * w * torque_factor
        omega_sum += w
        spin_momentum -= spin[i] * w
    sums[0] = total
    sums[1] = tau_x
    sums[2] = tau_y
    sums[3] = tau_z
    sums[4] = omega_sum
    sums[5] = spin_momentum


@njit(cache=True)
def _rotor_sums_vary_within_step(t, dt, prm):
    """Whether the rotor sums depend on the state or change time inside [t, t + dt]."""
    fault_starts = int(prm[16]) > 0 and t < prm[18] <= t + dt
    return prm[12] > 0 or prm[11] != 0.0 or prm[10] > 0 or fault_starts


@njit(cache=True)
def _rigid_body(x, u, prm, inertia, inertia_inv, sums, out):
    """dx/dt given the rotor sums: forces in world, torques in body, quaternion kinematics, rotor lag."""
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    r00 = 1 - 2 * (qy * qy + qz * qz)
    r01 = 2 * (qx * qy - qw * qz)
    r02 = 2 * (qx * qz + qw * qy)
    r10 = 2 * (qx * qy + qw * qz)
    r11 = 1 - 2 * (qx * qx + qz * qz)
    r12 = 2 * (qy * qz - qw * qx)
    r20 = 2 * (qx * qz - qw * qy)
    r21 = 2 * (qy * qz + qw * qx)
    r22 = 1 - 2 * (qx * qx + qy * qy)
    vx, vy, vz = x[3], x[4], x[5]
    wx, wy, wz = x[10], x[11], x[12]
    mass, gravity = prm[0], prm[1]
    c_x, c_y, c_z, k_h, tau = prm[4], prm[5], prm[6], prm[7], prm[12]
    j_r, r_x, r_y = prm[19], prm[20], prm[21]
    total, tau_x, tau_y, tau_z, omega_sum, spin_momentum = sums[0], sums[1], sums[2], sums[3], sums[4], sums[5]
    if tau > 0:
        for i in range(x.shape[0] - 13):
            out[13 + i] = (u[i] - x[13 + i]) / tau
    else:
        out[13:] = 0.0
    # Forces in world: thrust along body z, drags, constant force.
    fx = total * r02 - c_x * vx * abs(vx) + prm[13]
    fy = total * r12 - c_y * vy * abs(vy) + prm[14]
    fz = total * r22 - c_z * vz * abs(vz) + prm[15]
    if k_h != 0.0:
        # -k_h omega_sum R P R^T v: body-horizontal part of the velocity.
        bx = r00 * vx + r10 * vy + r20 * vz
        by = r01 * vx + r11 * vy + r21 * vz
        gain = -k_h * omega_sum
        fx += gain * (r00 * bx + r01 * by)
        fy += gain * (r10 * bx + r11 * by)
        fz += gain * (r20 * bx + r21 * by)
    # Torques in body: propeller gyroscope and a moved centre of gravity.
    h = j_r * spin_momentum
    tau_x += -(wy * h) - r_y * total
    tau_y += wx * h + r_x * total
    out[0] = vx
    out[1] = vy
    out[2] = vz
    inverse_mass = 1.0 / mass
    out[3] = fx * inverse_mass
    out[4] = fy * inverse_mass
    out[5] = fz * inverse_mass - gravity
    out[6] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[7] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[8] = 0.5 * (qw * wy - qx * wz + qz * wx)
    out[9] = 0.5 * (qw * wz + qx * wy - qy * wx)
    lx = inertia[0, 0] * wx + inertia[0, 1] * wy + inertia[0, 2] * wz
    ly = inertia[1, 0] * wx + inertia[1, 1] * wy + inertia[1, 2] * wz
    lz = inertia[2, 0] * wx + inertia[2, 1] * wy + inertia[2, 2] * wz
    mx = tau_x - (wy * lz - wz * ly)
    my = tau_y - (wz * lx - wx * lz)
    mz = tau_z - (wx * ly - wy * lx)
    out[10] = inertia_inv[0, 0] * mx + inertia_inv[0, 1] * my + inertia_inv[0, 2] * mz
    out[11] = inertia_inv[1, 0] * mx + inertia_inv[1, 1] * my + inertia_inv[1, 2] * mz
    out[12] = inertia_inv[2, 0] * mx + inertia_inv[2, 1] * my + inertia_inv[2, 2] * mz


@njit(cache=True)
def _derivative(t, x, u, prm, inertia, inertia_inv, positions, spin, lower, out):
    sums = np.empty(N_SUMS)
    _rotor_sums(t, x, u, prm, positions, spin, lower, sums)
    _rigid_body(x, u, prm, inertia, inertia_inv, sums, out)


def _advance(t0, x, u, prm, inertia, inertia_inv, positions, spin, lower, dt, steps, use_ground, ground_height):
    """RK4 ``steps`` times for every vehicle; returns the first step index that went non-finite (-1 if none).

    Without motor lag, inflow, ground effect or a fault starting inside the step, the rotor sums are
    the same at the four RK4 stages (they depend on the held command only): computed once per step.
    """
    batch, size = x.shape
    failed = np.full(batch, -1)
    for b in prange(batch):
        k1 = np.empty(size)
        k2 = np.empty(size)
        k3 = np.empty(size)
        k4 = np.empty(size)
        tmp = np.empty(size)
        sums = np.empty(N_SUMS)
        xb = x[b]
        ub = u[b]
        pb = prm[b]
        # Without motor lag the rotor speeds are not integrated: they equal the held command.
        integrated = size if pb[12] > 0 else 13
        for step in range(steps):
            t = t0 + step * dt
            varying = _rotor_sums_vary_within_step(t, dt, pb)
            _rotor_sums(t, xb, ub, pb, positions, spin, lower, sums)
            _rigid_body(xb, ub, pb, inertia, inertia_inv, sums, k1)
            for j in range(integrated):
                tmp[j] = xb[j] + 0.5 * dt * k1[j]
            if varying:
                _rotor_sums(t + 0.5 * dt, tmp, ub, pb, positions, spin, lower, sums)
            _rigid_body(tmp, ub, pb, inertia, inertia_inv, sums, k2)
            for j in range(integrated):
                tmp[j] = xb[j] + 0.5 * dt * k2[j]
            if varying:
                _rotor_sums(t + 0.5 * dt, tmp, ub, pb, positions, spin, lower, sums)
            _rigid_body(tmp, ub, pb, inertia, inertia_inv, sums, k3)
            for j in range(integrated):
                tmp[j] = xb[j] + dt * k3[j]
            if varying:
                _rotor_sums(t + dt, tmp, ub, pb, positions, spin, lower, sums)
            _rigid_body(tmp, ub, pb, inertia, inertia_inv, sums, k4)
            checksum = 0.0
            for j in range(integrated):
                xb[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
                checksum += xb[j]
            norm = np.sqrt(xb[6] ** 2 + xb[7] ** 2 + xb[8] ** 2 + xb[9] ** 2)
            for j in range(6, 10):
                xb[j] /= norm
            if pb[12] <= 0:
                for i in range(size - 13):
                    xb[13 + i] = ub[i]
            if use_ground and xb[2] < ground_height:
                xb[2] = ground_height
                for j in range(3, 6):
                    xb[j] = 0.0
                for j in range(10, 13):
                    xb[j] = 0.0
            # A NaN or an infinity anywhere makes the sum non-finite (inf - inf is NaN too).
            if not np.isfinite(checksum):
                failed[b] = step
                break
    return failed


# Threads pay off only for many vehicles: for a few, starting them costs more than the steps.
_advance_serial = njit(cache=True)(_advance)
_advance_parallel = njit(cache=True, parallel=True)(_advance)
PARALLEL_MIN_BATCH = 64


class CompiledStepper:
    """RK4 steps of a supported :class:`Model` for a fixed batch size, in compiled code."""

    def __init__(self, model: Model, batch: int):
        self.model = model
        self.batch = batch
        self.parameters = pack_parameters(model, batch)
        airframe = model.airframe
        self._geometry = (
            np.ascontiguousarray(model.inertia_kg_m2, dtype=float),
            np.ascontiguousarray(np.linalg.inv(model.inertia_kg_m2)),
            np.ascontiguousarray(airframe.rotor_positions_m),
            np.ascontiguousarray(airframe.spin_signs, dtype=float),
            np.ascontiguousarray(airframe.lower_rotor_mask),
        )

    def derivative(self, t: float, x: FloatArray, u: FloatArray) -> FloatArray:
        """dx/dt for each vehicle, from the compiled formulas (used to test them against the numpy model)."""
        out = np.empty_like(x)
        for b in range(x.shape[0]):
            _derivative(float(t), x[b], u[b], self.parameters[b], *self._geometry, out[b])
        return out

    def advance(self, t: float, x: FloatArray, u: FloatArray, dt: float, steps: int,
                ground_height_m: float | None) -> FloatArray:
        """x after ``steps`` RK4 steps of ``dt`` with u held; raises FloatingPointError if a state blows up."""
        x_next = np.array(x, dtype=float, order="C")
        kernel = _advance_parallel if self.batch >= PARALLEL_MIN_BATCH else _advance_serial
        failed = kernel(
            float(t), x_next, np.ascontiguousarray(u, dtype=float), self.parameters, *self._geometry,
            float(dt), int(steps), ground_height_m is not None, float(ground_height_m or 0.0),
        )
        if np.any(failed >= 0):
            vehicle = int(np.argmax(failed >= 0))
            when = t + (failed[vehicle] + 1) * dt
            raise FloatingPointError(f"the state of vehicle {vehicle} became non-finite at t = {when:.6f} s")
        return x_next

