"""Compiled fast path of :meth:`Model.derivative` + RK4 for the effects of effects.md.

Why a second form of the same physics: a single vehicle at 1 kHz must run thousands of times faster
than real time inside a node, and numpy's per-call overhead (about 1 us per operation, ~300 operations
per RK4 step) makes that impossible for B = 1; a batch of 10,000 vehicles must reach 10^7 vehicle-steps
per second on two cores. The numpy :class:`Model` stays the reference (readable, composable, used by
identification on whole logs); ``test_effects.py`` checks that both give the same derivative for every
effect, so a formula changed in one place and not the other fails the suite. Models with an effect this
kernel does not know use the numpy path.

Design: one lane kernel serves every batch size. Vehicles are cut into chunks of up to ``LANES``
vehicles ("lanes"); a chunk's state, command and parameters are transposed into structure-of-arrays form
(row after row of LANES values), and the chunk runs all its steps while its arrays stay in cache. Every
formula is written once, as the body of a loop over lanes (rotors are an outer loop, lanes the inner
one), which LLVM turns into AVX2 code stepping four vehicles per instruction. Lane bodies have no branch
that depends on the lane (selects instead of ``if``; ``error_model="numpy"`` so that a division carries
no zero check); what the whole chunk shares (motor lag, ground effect, whether the rotor sums change
within a step) is decided once per chunk or step, outside the lane loops. Chunks run in parallel
threads. A single vehicle is a chunk of one lane: the same code, whose lane loops run once. It runs
about as fast as a scalar per-vehicle kernel did (up to 1,900x real time in CPU time on the 2-core
reference machine, bench/bench_model.py; 1,000x is required), so there is no scalar twin of the physics
to keep in step with this one.

Parameters are packed per vehicle into one row (see ``PARAMETER_LAYOUT``), neutral values meaning
"effect absent" (drag 0, eta 1, no ground effect radius 0, no motor lag tau 0, no fault motor 0).
Presence of motor lag and of ground effect is a property of the model, hence the same for every vehicle.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from multirotor_ros.model import state as S
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

PARAMETER_LAYOUT: dict[str, int] = {
    name: index
    for index, name in enumerate(
        (
            "mass_kg",
            "gravity_m_s2",
            "k_f",
            "k_t",
            "c_x",
            "c_y",
            "c_z",
            "k_h",
            "k_f1",
            "eta_lower",
            "rotor_radius_m",
            "k_v",
            "tau_s",
            "f_x",
            "f_y",
            "f_z",
            "motor",
            "effectiveness",
            "t_fault_s",
            "j_r",
            "r_x",
            "r_y",
        )
    )
}
NEUTRAL = {"eta_lower": 1.0, "effectiveness": 1.0}
SUPPORTED_EFFECTS = frozenset(
    {
        "quadratic_drag",
        "rotor_drag",
        "thrust_speed_dependence",
        "coaxial_loss",
        "ground_effect",
        "inflow_thrust_loss",
        "motor_lag",
        "mass_offset",
        "constant_force",
        "actuator_fault",
        "gyroscopic",
        "cg_offset",
    }
)
GROUND_MIN_HEIGHT_IN_RADII = 0.5  # as GroundEffect.MIN_HEIGHT_IN_RADII

# Vehicles per chunk: 64 lanes keep a chunk's working arrays (about 60 kB for an X8) in L1/L2 and give
# the vector loops long runs; 10,000 vehicles make 157 chunks to share between the threads.
LANES = 64
# Threads pay off only when there are at least two chunks: below that, starting them costs more.
PARALLEL_MIN_BATCH = 2 * LANES

# A chunk's arrays are flat, row after row of LANES values, and the kernels index them as
# ``array[ROW + lane]`` with ROW = row * LANES a compile-time constant: LLVM then sees every row of an
# array at a constant distance from the others and needs one overlap check per pair of arrays (a
# run-time row length makes it one per pair of rows, hundreds, and it gives up vectorising).
L = LANES
# State rows (multirotor_ros.model.state): position z, velocity, quaternion w x y z, body rate, rotors.
_P_Z = 2 * L
_V_X, _V_Y, _V_Z = 3 * L, 4 * L, 5 * L
_Q_W, _Q_X, _Q_Y, _Q_Z = 6 * L, 7 * L, 8 * L, 9 * L
_W_X, _W_Y, _W_Z = 10 * L, 11 * L, 12 * L
_OMEGA = S.ROTORS_START * L
# Parameter rows (numba reads module-level ints as constants, not the dict).
_MASS = PARAMETER_LAYOUT["mass_kg"] * L
_GRAVITY = PARAMETER_LAYOUT["gravity_m_s2"] * L
_K_F = PARAMETER_LAYOUT["k_f"] * L
_K_T = PARAMETER_LAYOUT["k_t"] * L
_C_X = PARAMETER_LAYOUT["c_x"] * L
_C_Y = PARAMETER_LAYOUT["c_y"] * L
_C_Z = PARAMETER_LAYOUT["c_z"] * L
_K_H = PARAMETER_LAYOUT["k_h"] * L
_K_F1 = PARAMETER_LAYOUT["k_f1"] * L
_ETA_LOWER = PARAMETER_LAYOUT["eta_lower"] * L
_RADIUS = PARAMETER_LAYOUT["rotor_radius_m"] * L
_K_V = PARAMETER_LAYOUT["k_v"] * L
_TAU = PARAMETER_LAYOUT["tau_s"] * L
_F_X = PARAMETER_LAYOUT["f_x"] * L
_F_Y = PARAMETER_LAYOUT["f_y"] * L
_F_Z = PARAMETER_LAYOUT["f_z"] * L
_MOTOR = PARAMETER_LAYOUT["motor"] * L
_EFFECTIVENESS = PARAMETER_LAYOUT["effectiveness"] * L
_T_FAULT = PARAMETER_LAYOUT["t_fault_s"] * L
_J_R = PARAMETER_LAYOUT["j_r"] * L
_R_X = PARAMETER_LAYOUT["r_x"] * L
_R_Y = PARAMETER_LAYOUT["r_y"] * L
# Columns of the (batch, P) parameter rows that decide what a whole batch integrates.
_TAU_COLUMN = PARAMETER_LAYOUT["tau_s"]
_RADIUS_COLUMN = PARAMETER_LAYOUT["rotor_radius_m"]
# Work rows: the rotor sums (total thrust, the three body torques, sum of speeds, signed rotor momentum
# per J_r), what the rotor loop needs of the attitude, and the current rotor's ground-effect factor.
_TOTAL, _TAU_X, _TAU_Y, _TAU_Z, _OMEGA_SUM, _SPIN_MOMENTUM, _R20, _R21, _R22, _CLIMB, _GROUND_FACTOR = (
    row * L for row in range(11)
)
_N_SUMS = 6
_WORK_ROWS = 11

_jit = njit(cache=True, error_model="numpy")
# The lane functions are inlined where they are called: a numba call passes every array with a
# reference-count increment and decrement, which would cost more than a one-lane body.
_lane = njit(cache=True, error_model="numpy", inline="always")


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


@_lane
def _rotor_sums(t, y, u, prm, positions, spin, lower, lag, ground, lanes, work):
    """Per-rotor thrust and drag torque summed over the rotors, into the sum rows of ``work``."""
    for lane in range(lanes):
        qw, qx, qy, qz = y[_Q_W + lane], y[_Q_X + lane], y[_Q_Y + lane], y[_Q_Z + lane]
        r02 = 2 * (qx * qz + qw * qy)
        r12 = 2 * (qy * qz - qw * qx)
        r22 = 1 - 2 * (qx * qx + qy * qy)
        work[_R20 + lane] = 2 * (qx * qz - qw * qy)
        work[_R21 + lane] = 2 * (qy * qz + qw * qx)
        work[_R22 + lane] = r22
        work[_CLIMB + lane] = y[_V_X + lane] * r02 + y[_V_Y + lane] * r12 + y[_V_Z + lane] * r22
        for row in range(_N_SUMS):
            work[row * L + lane] = 0.0
    for i in range(positions.shape[0]):
        # Without motor lag the rotors turn at the held command.
        omega = _OMEGA + i * L
        source = y if lag else u
        speed_row = omega if lag else i * L
        p_x, p_y, p_z = positions[i, 0], positions[i, 1], positions[i, 2]
        sign = spin[i]
        is_lower = lower[i]
        number = i + 1.0
        if ground:
            # A loop of its own, so that models without ground effect pay none of its divisions.
            for lane in range(lanes):
                radius = prm[_RADIUS + lane]
                height = (
                    y[_P_Z + lane]
                    + work[_R20 + lane] * p_x
                    + work[_R21 + lane] * p_y
                    + work[_R22 + lane] * p_z
                )
                height = max(height, GROUND_MIN_HEIGHT_IN_RADII * radius)
                ratio = radius / (4.0 * height)
                work[_GROUND_FACTOR + lane] = 1.0 / (1.0 - ratio * ratio)
        for lane in range(lanes):
            w = source[speed_row + lane]
            thrust = (
                prm[_K_F + lane] * w * w
                + prm[_K_F1 + lane] * w * w * w
                - prm[_K_V + lane] * w * work[_CLIMB + lane]
            )
            eta = prm[_ETA_LOWER + lane]
            factor = (eta if is_lower else 1.0) * work[_GROUND_FACTOR + lane]
            faulty = (prm[_MOTOR + lane] == number) & (t >= prm[_T_FAULT + lane])
            effectiveness = prm[_EFFECTIVENESS + lane]
            torque_factor = effectiveness if faulty else 1.0
            thrust *= factor * torque_factor
            work[_TOTAL + lane] += thrust
            work[_TAU_X + lane] += thrust * p_y
            work[_TAU_Y + lane] -= thrust * p_x
            work[_TAU_Z + lane] += sign * prm[_K_T + lane] * w * w * torque_factor
            work[_OMEGA_SUM + lane] += w
            work[_SPIN_MOMENTUM + lane] -= sign * w


@_lane
def _rigid_body(y, prm, inertia, inertia_inv, lanes, work, k):
    """Rows 0..12 of dx/dt given the rotor sums: forces in world, torques in body, quaternion kinematics."""
    i00, i01, i02 = inertia[0, 0], inertia[0, 1], inertia[0, 2]
    i10, i11, i12 = inertia[1, 0], inertia[1, 1], inertia[1, 2]
    i20, i21, i22 = inertia[2, 0], inertia[2, 1], inertia[2, 2]
    j00, j01, j02 = inertia_inv[0, 0], inertia_inv[0, 1], inertia_inv[0, 2]
    j10, j11, j12 = inertia_inv[1, 0], inertia_inv[1, 1], inertia_inv[1, 2]
    j20, j21, j22 = inertia_inv[2, 0], inertia_inv[2, 1], inertia_inv[2, 2]
    for lane in range(lanes):
        qw, qx, qy, qz = y[_Q_W + lane], y[_Q_X + lane], y[_Q_Y + lane], y[_Q_Z + lane]
        r00 = 1 - 2 * (qy * qy + qz * qz)
        r01 = 2 * (qx * qy - qw * qz)
        r02 = 2 * (qx * qz + qw * qy)
        r10 = 2 * (qx * qy + qw * qz)
        r11 = 1 - 2 * (qx * qx + qz * qz)
        r12 = 2 * (qy * qz - qw * qx)
        r20 = 2 * (qx * qz - qw * qy)
        r21 = 2 * (qy * qz + qw * qx)
        r22 = 1 - 2 * (qx * qx + qy * qy)
        vx, vy, vz = y[_V_X + lane], y[_V_Y + lane], y[_V_Z + lane]
        wx, wy, wz = y[_W_X + lane], y[_W_Y + lane], y[_W_Z + lane]
        total = work[_TOTAL + lane]
        # Forces in world: thrust along body z, drags, constant force.
        fx = total * r02 - prm[_C_X + lane] * vx * abs(vx) + prm[_F_X + lane]
        fy = total * r12 - prm[_C_Y + lane] * vy * abs(vy) + prm[_F_Y + lane]
        fz = total * r22 - prm[_C_Z + lane] * vz * abs(vz) + prm[_F_Z + lane]
        # -k_h omega_sum R P R^T v: body-horizontal part of the velocity (adds exactly 0 when k_h = 0).
        bx = r00 * vx + r10 * vy + r20 * vz
        by = r01 * vx + r11 * vy + r21 * vz
        gain = -prm[_K_H + lane] * work[_OMEGA_SUM + lane]
        fx += gain * (r00 * bx + r01 * by)
        fy += gain * (r10 * bx + r11 * by)
        fz += gain * (r20 * bx + r21 * by)
        # Torques in body: propeller gyroscope and a moved centre of gravity.
        h = prm[_J_R + lane] * work[_SPIN_MOMENTUM + lane]
        tau_x = work[_TAU_X + lane] - wy * h - prm[_R_Y + lane] * total
        tau_y = work[_TAU_Y + lane] + wx * h + prm[_R_X + lane] * total
        tau_z = work[_TAU_Z + lane]
        k[0 * L + lane] = vx
        k[1 * L + lane] = vy
        k[_P_Z + lane] = vz
        inverse_mass = 1.0 / prm[_MASS + lane]
        k[_V_X + lane] = fx * inverse_mass
        k[_V_Y + lane] = fy * inverse_mass
        k[_V_Z + lane] = fz * inverse_mass - prm[_GRAVITY + lane]
        k[_Q_W + lane] = 0.5 * (-qx * wx - qy * wy - qz * wz)
        k[_Q_X + lane] = 0.5 * (qw * wx + qy * wz - qz * wy)
        k[_Q_Y + lane] = 0.5 * (qw * wy - qx * wz + qz * wx)
        k[_Q_Z + lane] = 0.5 * (qw * wz + qx * wy - qy * wx)
        lx = i00 * wx + i01 * wy + i02 * wz
        ly = i10 * wx + i11 * wy + i12 * wz
        lz = i20 * wx + i21 * wy + i22 * wz
        mx = tau_x - (wy * lz - wz * ly)
        my = tau_y - (wz * lx - wx * lz)
        mz = tau_z - (wx * ly - wy * lx)
        k[_W_X + lane] = j00 * mx + j01 * my + j02 * mz
        k[_W_Y + lane] = j10 * mx + j11 * my + j12 * mz
        k[_W_Z + lane] = j20 * mx + j21 * my + j22 * mz


@_lane
def _derivative(
    t, y, u, prm, inertia, inertia_inv, positions, spin, lower, lag, ground, sums_current, lanes, work, k
):
    """dx/dt of the first ``lanes`` lanes into ``k``; its rotor rows stay zero without motor lag.

    ``sums_current``: the rotor sums in ``work`` are still valid (see ``_sums_steady``): not recomputed.
    """
    if not sums_current:
        _rotor_sums(t, y, u, prm, positions, spin, lower, lag, ground, lanes, work)
    _rigid_body(y, prm, inertia, inertia_inv, lanes, work, k)
    if lag:
        for i in range(positions.shape[0]):
            omega = _OMEGA + i * L
            for lane in range(lanes):
                k[omega + lane] = (u[i * L + lane] - y[omega + lane]) / prm[_TAU + lane]


@_lane
def _sums_steady(t, dt, prm, lag, ground, lanes):
    """Whether the rotor sums of every lane are the same at the four RK4 stages of [t, t + dt].

    They are when they depend on the held command only: no motor lag, no inflow, no ground effect
    and no fault starting inside the step. Then they are computed once per step.
    """
    if lag or ground:
        return False
    for lane in range(lanes):
        fault_starts = prm[_MOTOR + lane] > 0 and t < prm[_T_FAULT + lane] <= t + dt
        if prm[_K_V + lane] != 0.0 or fault_starts:
            return False
    return True


@_jit
def _load_chunk(x, u, prm, first, lanes, rotors_at_command, xs, us, ps):
    """Vehicles first.. into lanes 0..lanes-1; lanes past the batch's end copy vehicle ``first``."""
    batch = x.shape[0]
    for lane in range(lanes):
        b = first + lane if first + lane < batch else first
        for j in range(x.shape[1]):
            xs[j * L + lane] = x[b, j]
        for i in range(u.shape[1]):
            us[i * L + lane] = u[b, i]
            # Without motor lag the rotor speeds are not integrated: they equal the held command.
            if rotors_at_command:
                xs[_OMEGA + i * L + lane] = u[b, i]
        for j in range(prm.shape[1]):
            ps[j * L + lane] = prm[b, j]


@_lane
def _lane_is_finite(xs, size, lane):
    for j in range(size):
        if not np.isfinite(xs[j * L + lane]):
            return False
    return True


@_lane
def _rk4_stage_update(first, h, lanes, rows, xs, ks, acc, ys):
    """After RK4 stage 1 (``first``), 2 or 3: ``acc`` = k1 + 2 k2 + 2 k3 so far, ``ys`` = next stage's input.

    ``rows``: the integrated rows, 13 without motor lag (the rotor speeds are then the held command).
    """
    for lane in range(lanes):
        # A constant trip count: LLVM unrolls this loop and vectorises the one over lanes.
        for row in range(0, S.ROTORS_START * L, L):
            k = ks[row + lane]
            acc[row + lane] = k if first else acc[row + lane] + 2.0 * k
            ys[row + lane] = xs[row + lane] + h * k
    for row in range(S.ROTORS_START * L, rows * L, L):
        for lane in range(lanes):
            k = ks[row + lane]
            acc[row + lane] = k if first else acc[row + lane] + 2.0 * k
            ys[row + lane] = xs[row + lane] + h * k


@_lane
def _rk4_step_end(dt, lanes, rows, use_ground, ground_height, xs, ks, acc):
    """After RK4 stage 4: the new state in ``xs``, unit quaternions, ground contact.

    Returns whether some lane became non-finite: a NaN or an infinity gives v - v != 0 (inf - inf is
    NaN), one flag for the chunk, its lanes looked at only when it is raised.
    """
    sixth_dt = dt / 6
    broken = False
    for lane in range(lanes):
        for row in range(0, S.ROTORS_START * L, L):
            value = xs[row + lane] + sixth_dt * (acc[row + lane] + ks[row + lane])
            xs[row + lane] = value
            broken |= (value - value) != 0.0
        qw, qx, qy, qz = xs[_Q_W + lane], xs[_Q_X + lane], xs[_Q_Y + lane], xs[_Q_Z + lane]
        norm = np.sqrt(qw**2 + qx**2 + qy**2 + qz**2)
        for row in range(_Q_W, _Q_Z + 1, L):
            xs[row + lane] /= norm
        # Ground contact: no sinking; while resting, the ground holds the vehicle still.
        below = use_ground & (xs[_P_Z + lane] < ground_height)
        xs[_P_Z + lane] = ground_height if below else xs[_P_Z + lane]
        for row in (_V_X, _V_Y, _V_Z, _W_X, _W_Y, _W_Z):
            xs[row + lane] = 0.0 if below else xs[row + lane]
    for row in range(S.ROTORS_START * L, rows * L, L):
        for lane in range(lanes):
            value = xs[row + lane] + sixth_dt * (acc[row + lane] + ks[row + lane])
            xs[row + lane] = value
            broken |= (value - value) != 0.0
    return broken


@_jit
def _rk4_chunk(
    t0,
    xs,
    us,
    ps,
    inertia,
    inertia_inv,
    positions,
    spin,
    lower,
    dt,
    steps,
    use_ground,
    ground_height,
    lanes,
    valid,
    failed,
):
    """RK4 ``steps`` times for the lanes of one chunk; ``failed[lane]`` = first step that went non-finite."""
    size = S.ROTORS_START + positions.shape[0]
    lag = ps[_TAU] > 0
    ground = ps[_RADIUS] > 0
    rows = size if lag else S.ROTORS_START
    ys = np.empty(size * L)
    ks = np.zeros(size * L)
    acc = np.empty(size * L)
    work = np.ones(_WORK_ROWS * L)
    half_dt = dt / 2
    alive = valid
    for step in range(steps):
        t = t0 + step * dt
        steady = _sums_steady(t, dt, ps, lag, ground, lanes)
        # One call site per lane function: each is inlined once.
        for stage in range(4):
            offset = 0.0 if stage == 0 else (half_dt if stage < 3 else dt)
            _derivative(
                t + offset,
                xs if stage == 0 else ys,
                us,
                ps,
                inertia,
                inertia_inv,
                positions,
                spin,
                lower,
                lag,
                ground,
                stage > 0 and steady,
                lanes,
                work,
                ks,
            )
            if stage < 3:
                _rk4_stage_update(stage == 0, half_dt if stage < 2 else dt, lanes, rows, xs, ks, acc, ys)
        if _rk4_step_end(dt, lanes, rows, use_ground, ground_height, xs, ks, acc):
            for lane in range(valid):
                if failed[lane] < 0 and not _lane_is_finite(xs, size, lane):
                    failed[lane] = step
                    alive -= 1
            if alive == 0:
                break


def _advance(
    t0, x, u, prm, inertia, inertia_inv, positions, spin, lower, dt, steps, use_ground, ground_height
):
    """RK4 ``steps`` times for every vehicle, in place.

    Returns per vehicle the index of the first step that went non-finite (-1 if none).
    """
    batch, size = x.shape
    lanes = min(L, batch)
    chunks = (batch + lanes - 1) // lanes
    failed = np.full(batch, -1)
    for chunk in prange(chunks):
        first = chunk * lanes
        valid = min(lanes, batch - first)
        xs = np.empty(size * L)
        us = np.empty(u.shape[1] * L)
        ps = np.empty(prm.shape[1] * L)
        _load_chunk(x, u, prm, first, lanes, prm[0, _TAU_COLUMN] <= 0, xs, us, ps)
        _rk4_chunk(
            t0,
            xs,
            us,
            ps,
            inertia,
            inertia_inv,
            positions,
            spin,
            lower,
            dt,
            steps,
            use_ground,
            ground_height,
            lanes,
            valid,
            failed[first : first + valid],
        )
        for lane in range(valid):
            for j in range(size):
                x[first + lane, j] = xs[j * L + lane]
    return failed


_advance_serial = _jit(_advance)
_advance_parallel = njit(cache=True, error_model="numpy", parallel=True)(_advance)


@_jit
def _derivative_batch(t, x, u, prm, inertia, inertia_inv, positions, spin, lower, out):
    """dx/dt of every vehicle, chunk after chunk."""
    batch, size = x.shape
    xs = np.empty(size * L)
    us = np.empty(u.shape[1] * L)
    ps = np.empty(prm.shape[1] * L)
    ks = np.zeros(size * L)
    work = np.ones(_WORK_ROWS * L)
    lag = prm[0, _TAU_COLUMN] > 0
    ground = prm[0, _RADIUS_COLUMN] > 0
    for first in range(0, batch, L):
        lanes = min(L, batch - first)
        _load_chunk(x, u, prm, first, lanes, False, xs, us, ps)
        _derivative(
            t, xs, us, ps, inertia, inertia_inv, positions, spin, lower, lag, ground, False, lanes, work, ks
        )
        for lane in range(lanes):
            for j in range(size):
                out[first + lane, j] = ks[j * L + lane]


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
        out = np.empty_like(x, dtype=float)
        _derivative_batch(
            float(t),
            np.ascontiguousarray(x, dtype=float),
            np.ascontiguousarray(u, dtype=float),
            self.parameters,
            *self._geometry,
            out,
        )
        return out

    def advance(
        self, t: float, x: FloatArray, u: FloatArray, dt: float, steps: int, ground_height_m: float | None
    ) -> FloatArray:
        """State after ``steps`` RK4 steps of ``dt`` with u held; FloatingPointError if one blows up."""
        x_next = np.array(x, dtype=float, order="C")
        kernel = _advance_parallel if self.batch >= PARALLEL_MIN_BATCH else _advance_serial
        failed = kernel(
            float(t),
            x_next,
            np.ascontiguousarray(u, dtype=float),
            self.parameters,
            *self._geometry,
            float(dt),
            int(steps),
            ground_height_m is not None,
            float(ground_height_m or 0.0),
        )
        if np.any(failed >= 0):
            vehicle = int(np.argmax(failed >= 0))
            when = t + (failed[vehicle] + 1) * dt
            raise FloatingPointError(f"the state of vehicle {vehicle} became non-finite at t = {when:.6f} s")
        return x_next


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel once: serial, parallel and the derivative."""
    from multirotor_ros.model import state as S
    from multirotor_ros.model.airframe import load_airframe

    model = Model(load_airframe("x8_octorotor"))
    for batch in (1, PARALLEL_MIN_BATCH):
        stepper = CompiledStepper(model, batch)
        x = S.make_state(model.n_rotors, batch=batch, position_m=(0.0, 0.0, 1.0))
        u = np.full((batch, model.n_rotors), model.hover_speed_rad_s())
        stepper.advance(0.0, x, u, 1e-3, 1, 0.0)
        stepper.derivative(0.0, x, u)
