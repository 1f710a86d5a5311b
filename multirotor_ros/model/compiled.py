"""Compiled fast path of :meth:`Model.derivative` + RK4, generated from the effects' own formulas.

Why compiled code: a single vehicle at 1 kHz must run thousands of times faster than real time inside a
node, and numpy's per-call overhead (about 1 us per operation, ~300 operations per RK4 step) makes that
impossible for B = 1; a batch of 10,000 vehicles must reach 10^7 vehicle-steps per second on two cores.

One source of truth: no formula of an effect is written here. For the effects of a model, this module
writes the source of a kernel that calls each effect's formulas (:mod:`multirotor_ros.model.effects`,
compiled by numba and inlined) where the numpy :class:`Model` calls them on arrays, and the rotor torques
through the same :func:`~multirotor_ros.model.rotors.rotor_torque_terms`. The generated module is written
to a cache directory under a name that hashes its own text and the source of every module it calls, so
numba's on-disk cache is valid exactly as long as the physics is unchanged; a model with a new set of
effects compiles once (a few seconds) and is loaded from the cache afterwards.

Design: one lane kernel serves every batch size. Vehicles are cut into chunks of up to ``LANES`` vehicles
("lanes"); a chunk's state, command and parameters are transposed into structure-of-arrays form (row after
row of LANES values), and the chunk runs all its steps while its arrays stay in cache. Every formula is
called in the body of a loop over lanes (rotors are an outer loop, lanes the inner one), which LLVM turns
into AVX2 code stepping four vehicles per instruction. Lane bodies have no branch that depends on the
lane (formulas are written with arithmetic selects; ``error_model="numpy"`` so that a division carries no
zero check). Chunks run in parallel threads. A single vehicle is a chunk of one lane: the same code.
Because a kernel is generated per set of effects, a model pays only for the effects it has.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import math
import os
import sys
import tempfile
import textwrap
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from multirotor_ros.model import effects as effects_module
from multirotor_ros.model import rotors as rotors_module
from multirotor_ros.model import state as S
from multirotor_ros.model.effects import (
    ROTOR_FORMULAS,
    STATE_QUANTITIES,
    VEHICLE_QUANTITIES,
    Effect,
    formula_arguments,
)
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

if TYPE_CHECKING:
    from multirotor_ros.model.integrator import CrashLatch

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
# State rows (multirotor_ros.model.state): position, velocity, quaternion w x y z, body rate, rotors.
_P_X, _P_Y, _P_Z = 0, L, 2 * L
_V_X, _V_Y, _V_Z = 3 * L, 4 * L, 5 * L
_Q_W, _Q_X, _Q_Y, _Q_Z = 6 * L, 7 * L, 8 * L, 9 * L
_W_X, _W_Y, _W_Z = 10 * L, 11 * L, 12 * L
_OMEGA = S.ROTORS_START * L
# The parameter rows every model has; the effects' parameters follow (see :class:`ParameterLayout`).
BASE_PARAMETERS = ("mass_kg", "gravity_m_s2", "k_f", "k_t", "rotor_time_constant_s")
# Formulas of parameters only: the model evaluates them, and the kernel reads the result in a base row.
_PACKED_IN_BASE_ROWS = {"mass_delta_kg", "rotor_time_constant_s"}

_jit = njit(cache=True, error_model="numpy")
# Lane functions are inlined where they are called: a numba call passes every array with a
# reference-count increment and decrement, which would cost more than a one-lane body.
_lane = njit(cache=True, error_model="numpy", inline="always")


def supports(model: Model) -> bool:
    """Whether the compiled path can run ``model``: any model of effects from the registry can."""
    return all(type(effect) is effects_module.EFFECTS.get(effect.id) for effect in model.effects)


# ============================================================================ static lane functions


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
def _rigid_body_rows(
    y, inertia, inertia_inv, lane, k, fx, fy, fz, tau_x, tau_y, tau_z, inverse_mass, gravity
):
    """Rows 0..12 of dx/dt of one lane from its force (world) and torque (body)."""
    qw, qx, qy, qz = y[_Q_W + lane], y[_Q_X + lane], y[_Q_Y + lane], y[_Q_Z + lane]
    wx, wy, wz = y[_W_X + lane], y[_W_Y + lane], y[_W_Z + lane]
    k[_P_X + lane] = y[_V_X + lane]
    k[_P_Y + lane] = y[_V_Y + lane]
    k[_P_Z + lane] = y[_V_Z + lane]
    k[_V_X + lane] = fx * inverse_mass
    k[_V_Y + lane] = fy * inverse_mass
    k[_V_Z + lane] = fz * inverse_mass - gravity
    k[_Q_W + lane] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    k[_Q_X + lane] = 0.5 * (qw * wx + qy * wz - qz * wy)
    k[_Q_Y + lane] = 0.5 * (qw * wy - qx * wz + qz * wx)
    k[_Q_Z + lane] = 0.5 * (qw * wz + qx * wy - qy * wx)
    lx = inertia[0, 0] * wx + inertia[0, 1] * wy + inertia[0, 2] * wz
    ly = inertia[1, 0] * wx + inertia[1, 1] * wy + inertia[1, 2] * wz
    lz = inertia[2, 0] * wx + inertia[2, 1] * wy + inertia[2, 2] * wz
    mx = tau_x - (wy * lz - wz * ly)
    my = tau_y - (wz * lx - wx * lz)
    mz = tau_z - (wx * ly - wy * lx)
    k[_W_X + lane] = inertia_inv[0, 0] * mx + inertia_inv[0, 1] * my + inertia_inv[0, 2] * mz
    k[_W_Y + lane] = inertia_inv[1, 0] * mx + inertia_inv[1, 1] * my + inertia_inv[1, 2] * mz
    k[_W_Z + lane] = inertia_inv[2, 0] * mx + inertia_inv[2, 1] * my + inertia_inv[2, 2] * mz


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


# A chunk's ground-contact rows (see _rk4_step_end): the crash latch, and of a crash its falling speed
# and its step.
_CRASHED, _TOUCHDOWN, _CRASH_STEP = 0, L, 2 * L
CONTACT_ROWS = 3


@_lane
def _rk4_lane_end(sixth_dt, lane, xs, ks, acc):
    """Rows 0..12 of one lane after RK4 stage 4, unit quaternion; whether a value became non-finite.

    A NaN or an infinity gives v - v != 0 (inf - inf is NaN).
    """
    broken = False
    for row in range(0, S.ROTORS_START * L, L):
        value = xs[row + lane] + sixth_dt * (acc[row + lane] + ks[row + lane])
        xs[row + lane] = value
        broken |= (value - value) != 0.0
    qw, qx, qy, qz = xs[_Q_W + lane], xs[_Q_X + lane], xs[_Q_Y + lane], xs[_Q_Z + lane]
    norm = np.sqrt(qw**2 + qx**2 + qy**2 + qz**2)
    for row in range(_Q_W, _Q_Z + 1, L):
        xs[row + lane] /= norm
    return broken


@_jit
def _rk4_end_on_ground(sixth_dt, lanes, step, ground, xs, ks, acc, contact):
    """:func:`_rk4_step_end` of a chunk where some lane may touch the ground; whether one broke.

    Compiled apart, not inlined: inside the step loop its code, which a chunk in the air never runs,
    slowed the steps of such a chunk by 2-5 %; a chunk on the ground pays a call per step instead.
    """
    _, ground_height, crash_speed, cos_crash_tilt = ground
    broken = False
    for lane in range(lanes):
        p_x, p_y = xs[_P_X + lane], xs[_P_Y + lane]
        q_w, q_x, q_y, q_z = xs[_Q_W + lane], xs[_Q_X + lane], xs[_Q_Y + lane], xs[_Q_Z + lane]
        broken |= _rk4_lane_end(sixth_dt, lane, xs, ks, acc)
        touching = xs[_P_Z + lane] < ground_height
        falling = -xs[_V_Z + lane]
        was_crashed = contact[_CRASHED + lane] != 0.0
        cos_tilt = 1.0 - 2.0 * (q_x * q_x + q_y * q_y)
        crash = touching & (not was_crashed) & ((falling > crash_speed) | (cos_tilt < cos_crash_tilt))
        contact[_CRASHED + lane] = 1.0 if crash else contact[_CRASHED + lane]
        contact[_TOUCHDOWN + lane] = falling if crash else contact[_TOUCHDOWN + lane]
        contact[_CRASH_STEP + lane] = step if crash else contact[_CRASH_STEP + lane]
        held = touching | was_crashed
        xs[_P_X + lane] = p_x if held else xs[_P_X + lane]
        xs[_P_Y + lane] = p_y if held else xs[_P_Y + lane]
        xs[_P_Z + lane] = ground_height if held else xs[_P_Z + lane]
        xs[_Q_W + lane] = q_w if held else xs[_Q_W + lane]
        xs[_Q_X + lane] = q_x if held else xs[_Q_X + lane]
        xs[_Q_Y + lane] = q_y if held else xs[_Q_Y + lane]
        xs[_Q_Z + lane] = q_z if held else xs[_Q_Z + lane]
        for row in (_V_X, _V_Y, _V_Z, _W_X, _W_Y, _W_Z):
            xs[row + lane] = 0.0 if held else xs[row + lane]
    return broken


@_lane
def _rk4_step_end(dt, lanes, rows, step, ground, xs, ks, acc, contact):
    """After RK4 stage 4: the new state in ``xs``, unit quaternions, ground contact.

    ``ground``: (use_ground, height, crash speed, cos of the crash tilt). The ground contact of
    multirotor_ros.model.integrator (hold_on_ground and CrashLatch): a lane that ends the step below the
    ground, or has crashed, keeps its pose before the step, on the ground, at rest; a touchdown faster or
    more tilted than the crash limits latches the lane in ``contact``.
    Returns whether some lane became non-finite: one flag for the chunk, its lanes looked at only when it
    is raised.
    """
    use_ground, ground_height = ground[0], ground[1]
    sixth_dt = dt / 6
    # Holding a lane needs its pose before the step: a chunk where no lane can touch the ground (the usual
    # case, one height row looked at) takes the update alone.
    grounded = False
    if use_ground:
        for lane in range(lanes):
            height = xs[_P_Z + lane] + sixth_dt * (acc[_P_Z + lane] + ks[_P_Z + lane])
            grounded |= (height < ground_height) | (contact[_CRASHED + lane] != 0.0)
    broken = False
    if grounded:
        broken = _rk4_end_on_ground(sixth_dt, lanes, step, ground, xs, ks, acc, contact)
    else:
        for lane in range(lanes):
            broken |= _rk4_lane_end(sixth_dt, lane, xs, ks, acc)
    for row in range(S.ROTORS_START * L, rows * L, L):
        for lane in range(lanes):
            value = xs[row + lane] + sixth_dt * (acc[row + lane] + ks[row + lane])
            xs[row + lane] = value
            broken |= (value - value) != 0.0
    return broken


# ============================================================================ the parameter rows


class ParameterLayout:
    """Where each parameter of a model sits in a vehicle's packed parameter row.

    The base rows come first, then each effect's scalar parameters, then the per-rotor parameters
    (``n_rotors`` rows each), so that every row but the per-rotor ones has an index known at compile time.
    """

    def __init__(self, effects: tuple[type[Effect], ...]):
        self.effects = effects
        self.rows: dict[tuple[str, str], int] = {("", name): i for i, name in enumerate(BASE_PARAMETERS)}
        for cls in effects:
            for parameter in cls.PARAMETERS:
                self.rows[(cls.id, parameter.name)] = len(self.rows)
        self.per_rotor_first = len(self.rows)
        self.per_rotor_effects = tuple(cls for cls in effects if cls.PER_ROTOR_PARAMETER is not None)

    def size(self, n_rotors: int) -> int:
        """Row length for an airframe with ``n_rotors`` rotors."""
        return self.per_rotor_first + n_rotors * len(self.per_rotor_effects)

    def pack(self, model: Model, batch: int) -> FloatArray:
        """(batch, P) parameter rows of ``model``; per-vehicle parameters broadcast over the batch."""
        n = model.n_rotors
        rows = np.zeros((batch, self.size(n)))
        base: dict[str, FloatArray | float] = {
            "mass_kg": model.mass_kg,
            "gravity_m_s2": model.gravity_m_s2,
            "k_f": model.airframe.k_f_N_s2,
            "k_t": model.airframe.k_t_N_m_s2,
            "rotor_time_constant_s": 0.0
            if model.rotor_time_constant_s is None
            else model.rotor_time_constant_s,
        }
        for name, value in base.items():
            rows[:, self.rows[("", name)]] = np.broadcast_to(value, (batch,))
        for effect in model.effects:
            if type(effect) not in self.effects:
                continue  # acts through the base rows only (mass, rotor time constant)
            for parameter in type(effect).PARAMETERS:
                column = self.rows[(effect.id, parameter.name)]
                rows[:, column] = np.broadcast_to(effect[parameter.name], (batch,))
            if effect.PER_ROTOR_PARAMETER is not None:
                first = self.per_rotor_first + n * self.per_rotor_effects.index(type(effect))
                values = effect.per_rotor_values()
                assert values is not None
                rows[:, first : first + n] = np.broadcast_to(values, (batch, n))
        return rows


# ============================================================================ kernel generation


class _KernelWriter:
    """Writes the source of the kernel for one set of effects (see the module docstring)."""

    def __init__(self, effects: tuple[type[Effect], ...], lag: bool):
        self.effects = effects
        self.layout = ParameterLayout(effects)
        self.lag = lag
        hooks = [(cls, hook) for cls in effects for hook in cls.formulas()]
        self.rotor_hooks = [(cls, hook) for cls, hook in hooks if hook in ROTOR_FORMULAS]
        self.vehicle_hooks = [(cls, hook) for cls, hook in hooks if hook in ("force_W", "torque_B")]
        rotor_reads = {
            name for cls, hook in self.rotor_hooks for name in formula_arguments(getattr(cls, hook))
        }
        vehicle_reads = {
            name for cls, hook in self.vehicle_hooks for name in formula_arguments(getattr(cls, hook))
        }
        # Vehicle quantities the rotor formulas read, computed once per lane before the rotor loop.
        self.rotor_vehicle_quantities = sorted(
            name for name in rotor_reads if name in VEHICLE_QUANTITIES and name != "t"
        )
        if "rotor_height" in rotor_reads:
            self.rotor_vehicle_quantities = sorted(
                {*self.rotor_vehicle_quantities, "p_z", "r20", "r21", "r22"}
            )
        self.sums = ["total", "tau_x", "tau_y", "tau_z"]
        for name in ("omega_sum", "spin_momentum", "spin_momentum_rate"):
            if name in vehicle_reads or name in rotor_reads:
                self.sums.append(name)
        self.work_rows = self.sums + [f"q_{name}" for name in self.rotor_vehicle_quantities]
        # The rotor sums are the same at every RK4 stage of a step when they read nothing that moves
        # within it: then they are computed once per step.
        self.steady = not lag and not (rotor_reads & (STATE_QUANTITIES | {"rotor_height"}))

    @staticmethod
    def function_name(cls: type[Effect], hook: str) -> str:
        return f"_{cls.id}__{hook}"

    def parameter_row(self, cls: type[Effect], name: str) -> str:
        if cls.PER_ROTOR_PARAMETER is not None and name == cls.PER_ROTOR_PARAMETER.name:
            block = self.layout.per_rotor_effects.index(cls)
            return f"prm[({self.layout.per_rotor_first} + {block} * n_rotors + i) * L + lane]"
        return f"prm[{self.layout.rows[(cls.id, name)]} * L + lane]"

    def call(self, cls: type[Effect], hook: str, quantity: dict[str, str]) -> str:
        """The call of an effect's formula with its arguments bound by name."""
        parameters = {p.name for p in cls.PARAMETERS}
        if cls.PER_ROTOR_PARAMETER is not None:
            parameters.add(cls.PER_ROTOR_PARAMETER.name)
        arguments = [
            self.parameter_row(cls, name) if name in parameters else quantity[name]
            for name in formula_arguments(getattr(cls, hook))
        ]
        return f"{self.function_name(cls, hook)}({', '.join(arguments)})"

    def row(self, name: str) -> str:
        return f"{self.work_rows.index(name)} * L + lane"

    def rotor_sums(self) -> str:
        q = {
            "t": "t",
            "omega": "omega",
            "rotor_number": "rotor_number",
            "is_lower": "is_lower",
            "rotor_x": "rotor_x",
            "rotor_y": "rotor_y",
            "rotor_z": "rotor_z",
            "spin": "spin_i",
        }
        if "q_p_z" in self.work_rows:
            q["rotor_height"] = (
                f"(work[{self.row('q_p_z')}] + work[{self.row('q_r20')}] * rotor_x"
                f" + work[{self.row('q_r21')}] * rotor_y + work[{self.row('q_r22')}] * rotor_z)"
            )
        for name in self.rotor_vehicle_quantities:
            q[name] = f"work[{self.row('q_' + name)}]"
        lines = ["for lane in range(lanes):"]
        if self.rotor_vehicle_quantities:
            lines += ["    " + line for line in _attitude_lines()]
            for name in self.rotor_vehicle_quantities:
                lines.append(f"    work[{self.row('q_' + name)}] = {_vehicle_expression(name)}")
        lines += [f"    work[{self.row(name)}] = 0.0" for name in self.sums]
        lines += [
            "n_rotors = positions.shape[0]",
            "for i in range(n_rotors):",
            "    rotor_x, rotor_y, rotor_z = positions[i, 0], positions[i, 1], positions[i, 2]",
            "    spin_i = spin[i]",
            "    is_lower = 1.0 if lower[i] else 0.0",
            "    rotor_number = i + 1.0",
            "    for lane in range(lanes):",
            f"        omega = {'y[_OMEGA + i * L + lane]' if self.lag else 'u[i * L + lane]'}",
            "        thrust = prm[2 * L + lane] * omega * omega",
            "        drag = prm[3 * L + lane] * omega * omega",
            "        factor = 1.0",
            "        torque_factor = 1.0",
        ]
        for cls, hook in self.rotor_hooks:
            call = self.call(cls, hook, q)
            if hook == "rotor_thrust_term":
                lines.append(f"        thrust += {call}")
            elif hook == "rotor_drag_torque_term":
                lines.append(f"        drag += {call}")
            else:
                lines.append(f"        f = {call}")
                lines.append("        factor *= f")
                if cls.scales_rotor_torque:
                    lines.append("        torque_factor *= f")
        lines += [
            "        thrust *= factor",
            "        drag *= torque_factor",
            "        tx, ty, tz = rotor_torque_terms(thrust, drag, rotor_x, rotor_y, spin_i)",
            f"        work[{self.row('total')}] += thrust",
            f"        work[{self.row('tau_x')}] += tx",
            f"        work[{self.row('tau_y')}] += ty",
            f"        work[{self.row('tau_z')}] += tz",
        ]
        if "omega_sum" in self.sums:
            lines.append(f"        work[{self.row('omega_sum')}] += omega")
        if "spin_momentum" in self.sums:
            lines.append(f"        work[{self.row('spin_momentum')}] -= spin_i * omega")
        if "spin_momentum_rate" in self.sums and self.lag:
            lines.append(
                f"        work[{self.row('spin_momentum_rate')}] -= "
                "spin_i * (u[i * L + lane] - omega) / prm[4 * L + lane]"
            )
        body = textwrap.indent("\n".join(lines), "    ")
        return (
            "@_lane\n"
            "def _rotor_sums(t, y, u, prm, positions, spin, lower, lanes, work):\n"
            '    """Per-rotor thrust and drag torque summed over the rotors, into the rows of ``work``."""\n'
            f"{body}\n"
        )

    def rigid_body(self) -> str:
        sums = ("omega_sum", "spin_momentum", "spin_momentum_rate")
        q = {
            name: _vehicle_expression(name)
            for name in VEHICLE_QUANTITIES
            if name not in (*sums, "total_thrust")
        }
        q["total_thrust"] = "total"
        for name in sums:
            q[name] = f"work[{self.row(name)}]" if name in self.sums else "0.0"
        lines = ["for lane in range(lanes):"]
        lines += ["    " + line for line in _attitude_lines()]
        lines += [
            f"    total = work[{self.row('total')}]",
            "    fx = total * r02",
            "    fy = total * r12",
            "    fz = total * r22",
            f"    tau_x = work[{self.row('tau_x')}]",
            f"    tau_y = work[{self.row('tau_y')}]",
            f"    tau_z = work[{self.row('tau_z')}]",
        ]
        for cls, hook in self.vehicle_hooks:
            a, b, c = ("fx", "fy", "fz") if hook == "force_W" else ("tau_x", "tau_y", "tau_z")
            lines.append(f"    da, db, dc = {self.call(cls, hook, q)}")
            lines.append(f"    {a} += da")
            lines.append(f"    {b} += db")
            lines.append(f"    {c} += dc")
        lines.append(
            "    _rigid_body_rows(y, inertia, inertia_inv, lane, k, fx, fy, fz, tau_x, tau_y, tau_z,"
            " 1.0 / prm[0 * L + lane], prm[1 * L + lane])"
        )
        body = textwrap.indent("\n".join(lines), "    ")
        return (
            "@_lane\n"
            "def _rigid_body(t, y, prm, inertia, inertia_inv, lanes, work, k):\n"
            '    """Rows 0..12 of dx/dt given the rotor sums: forces in world, torques in body."""\n'
            f"{body}\n"
        )

    def source(self) -> str:
        formulas = "\n".join(
            f"{self.function_name(cls, hook)} = _lane(EFFECTS[{cls.id!r}].{hook})"
            for cls, hook in self.rotor_hooks + self.vehicle_hooks
        )
        header = (
            f'"""Generated by multirotor_ros.model.compiled for the effects: '
            f"{', '.join(cls.id for cls in self.effects) or 'none'}{' (motor lag)' if self.lag else ''}.\n\n"
            'Do not edit: it is written again whenever the physics changes."""\n\n'
            "import numpy as np\n"
            "from numba import njit, prange\n\n"
            "from multirotor_ros.model.compiled import (\n"
            "    CONTACT_ROWS, L, S, _CRASH_STEP, _CRASHED, _OMEGA, _P_Z, _Q_W, _Q_X, _Q_Y, _Q_Z,\n"
            "    _TOUCHDOWN, _V_X, _V_Y, _V_Z, _W_X, _W_Y, _W_Z, _jit, _lane, _lane_is_finite, _load_chunk,\n"
            "    _rigid_body_rows,\n"
            "    _rk4_stage_update, _rk4_step_end,\n"
            ")\n"
            "from multirotor_ros.model.effects import EFFECTS\n"
            "from multirotor_ros.model.rotors import rotor_torque_terms as _rotor_torque_terms_py\n\n"
            "rotor_torque_terms = _lane(_rotor_torque_terms_py)\n"
            f"{formulas}\n\n"
            f"LAG = {self.lag}\n"
            f"STEADY = {self.steady}\n"
            f"WORK_ROWS = {len(self.work_rows)}\n\n\n"
        )
        return header + self.rotor_sums() + "\n\n" + self.rigid_body() + "\n\n" + _CHUNK_LOOP


def _attitude_lines() -> list[str]:
    return [
        "qw, qx, qy, qz = y[_Q_W + lane], y[_Q_X + lane], y[_Q_Y + lane], y[_Q_Z + lane]",
        "r00 = 1 - 2 * (qy * qy + qz * qz)",
        "r01 = 2 * (qx * qy - qw * qz)",
        "r02 = 2 * (qx * qz + qw * qy)",
        "r10 = 2 * (qx * qy + qw * qz)",
        "r11 = 1 - 2 * (qx * qx + qz * qz)",
        "r12 = 2 * (qy * qz - qw * qx)",
        "r20 = 2 * (qx * qz - qw * qy)",
        "r21 = 2 * (qy * qz + qw * qx)",
        "r22 = 1 - 2 * (qx * qx + qy * qy)",
    ]


def _vehicle_expression(name: str) -> str:
    """A vehicle quantity inside a lane loop, after :func:`_attitude_lines`."""
    state_rows = {
        "p_x": "y[0 * L + lane]",
        "p_y": "y[1 * L + lane]",
        "p_z": "y[_P_Z + lane]",
        "v_x": "y[_V_X + lane]",
        "v_y": "y[_V_Y + lane]",
        "v_z": "y[_V_Z + lane]",
        "w_x": "y[_W_X + lane]",
        "w_y": "y[_W_Y + lane]",
        "w_z": "y[_W_Z + lane]",
        "t": "t",
        "climb": "(y[_V_X + lane] * r02 + y[_V_Y + lane] * r12 + y[_V_Z + lane] * r22)",
    }
    if name in state_rows:
        return state_rows[name]
    if len(name) == 3 and name[0] == "r" and name[1:].isdigit():
        return name
    raise KeyError(f"{name} is a rotor sum, not a state quantity")


# The chunk loop: the same for every set of effects; it calls the generated _rotor_sums and _rigid_body.
_CHUNK_LOOP = '''
@_lane
def _derivative(t, y, u, prm, inertia, inertia_inv, positions, spin, lower, sums_current, lanes, work, k):
    """dx/dt of the first ``lanes`` lanes into ``k``; its rotor rows stay zero without motor lag.

    ``sums_current``: the rotor sums in ``work`` are still valid (STEADY): not recomputed.
    """
    if not sums_current:
        _rotor_sums(t, y, u, prm, positions, spin, lower, lanes, work)
    _rigid_body(t, y, prm, inertia, inertia_inv, lanes, work, k)
    if LAG:
        for i in range(positions.shape[0]):
            omega = _OMEGA + i * L
            for lane in range(lanes):
                k[omega + lane] = (u[i * L + lane] - y[omega + lane]) / prm[4 * L + lane]


@_jit
def _rk4_chunk(
    t0, xs, us, ps, inertia, inertia_inv, positions, spin, lower, dt, steps, ground, contact, lanes, valid,
    failed,
):
    """RK4 ``steps`` times for the lanes of one chunk; ``failed[lane]`` = first step that went non-finite."""
    size = S.ROTORS_START + positions.shape[0]
    rows = size if LAG else S.ROTORS_START
    ys = np.empty(size * L)
    ks = np.zeros(size * L)
    acc = np.empty(size * L)
    work = np.ones(WORK_ROWS * L)
    half_dt = dt / 2
    alive = valid
    for step in range(steps):
        t = t0 + step * dt
        # One call site per lane function: each is inlined once.
        for stage in range(4):
            offset = 0.0 if stage == 0 else (half_dt if stage < 3 else dt)
            _derivative(
                t + offset, xs if stage == 0 else ys, us, ps, inertia, inertia_inv, positions, spin, lower,
                STEADY and stage > 0, lanes, work, ks,
            )
            if stage < 3:
                _rk4_stage_update(stage == 0, half_dt if stage < 2 else dt, lanes, rows, xs, ks, acc, ys)
        if _rk4_step_end(dt, lanes, rows, step, ground, xs, ks, acc, contact):
            for lane in range(valid):
                if failed[lane] < 0 and not _lane_is_finite(xs, size, lane):
                    failed[lane] = step
                    alive -= 1
            if alive == 0:
                break


def _advance(
    t0, x, u, prm, inertia, inertia_inv, positions, spin, lower, dt, steps, ground, crashed, touchdown,
    crash_step,
):
    """RK4 ``steps`` times for every vehicle, in place; per vehicle the first step that went non-finite.

    ``crashed``, ``touchdown``, ``crash_step``: the crash latch (integrator.CrashLatch), updated in place;
    ``crash_step`` tells the crashes of this call.
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
        _load_chunk(x, u, prm, first, lanes, not LAG, xs, us, ps)
        contact = np.zeros(CONTACT_ROWS * L)
        for lane in range(valid):
            contact[_CRASHED + lane] = 1.0 if crashed[first + lane] else 0.0
            contact[_TOUCHDOWN + lane] = touchdown[first + lane]
            contact[_CRASH_STEP + lane] = -1.0
        _rk4_chunk(
            t0, xs, us, ps, inertia, inertia_inv, positions, spin, lower, dt, steps, ground, contact, lanes,
            valid, failed[first : first + valid],
        )
        for lane in range(valid):
            for j in range(size):
                x[first + lane, j] = xs[j * L + lane]
            crashed[first + lane] = contact[_CRASHED + lane] != 0.0
            touchdown[first + lane] = contact[_TOUCHDOWN + lane]
            crash_step[first + lane] = int(contact[_CRASH_STEP + lane])
    return failed


advance_serial = _jit(_advance)
advance_parallel = njit(cache=True, error_model="numpy", parallel=True)(_advance)


@_jit
def derivative_batch(t, x, u, prm, inertia, inertia_inv, positions, spin, lower, out):
    """dx/dt of every vehicle, chunk after chunk."""
    batch, size = x.shape
    xs = np.empty(size * L)
    us = np.empty(u.shape[1] * L)
    ps = np.empty(prm.shape[1] * L)
    ks = np.zeros(size * L)
    work = np.ones(WORK_ROWS * L)
    for first in range(0, batch, L):
        lanes = min(L, batch - first)
        _load_chunk(x, u, prm, first, lanes, False, xs, us, ps)
        _derivative(t, xs, us, ps, inertia, inertia_inv, positions, spin, lower, False, lanes, work, ks)
        for lane in range(lanes):
            for j in range(size):
                out[first + lane, j] = ks[j * L + lane]
'''


def kernel_directory() -> Path:
    """Where generated kernels and their numba cache live: $MULTIROTOR_ROS_KERNEL_DIR or the user cache."""
    configured = os.environ.get("MULTIROTOR_ROS_KERNEL_DIR")
    if configured:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "multirotor_ros" / "kernels"


def _physics_fingerprint() -> str:
    """The source of everything a generated kernel calls: a change to any formula makes a new kernel."""
    digest = hashlib.sha256()
    for module in (effects_module, rotors_module, S, sys.modules[__name__]):
        digest.update(inspect.getsource(module).encode())
    return digest.hexdigest()


_KERNELS: dict[tuple[tuple[str, ...], bool], tuple[ModuleType, ParameterLayout]] = {}


def kernel_for(model: Model) -> tuple[ModuleType, ParameterLayout]:
    """The compiled kernel module for the effects of ``model`` (generated, written and imported once)."""
    classes = tuple(
        type(effect) for effect in model.effects if type(effect).formulas().keys() - _PACKED_IN_BASE_ROWS
    )
    lag = model.rotor_time_constant_s is not None
    key = (tuple(cls.id for cls in classes), lag)
    if key not in _KERNELS:
        writer = _KernelWriter(classes, lag)
        source = writer.source()
        digest = hashlib.sha256((source + _physics_fingerprint()).encode()).hexdigest()[:20]
        name = f"multirotor_ros_kernel_{digest}"
        directory = kernel_directory()
        path = directory / f"{name}.py"
        if not path.exists():
            directory.mkdir(parents=True, exist_ok=True)
            # Written whole and renamed, so that a process starting beside this one never reads half a file.
            with tempfile.NamedTemporaryFile("w", dir=directory, suffix=".tmp", delete=False) as handle:
                handle.write(source)
            os.replace(handle.name, path)
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        _KERNELS[key] = (module, writer.layout)
    return _KERNELS[key]


class CompiledStepper:
    """RK4 steps of a :class:`Model` for a fixed batch size, in compiled code."""

    def __init__(self, model: Model, batch: int):
        self.model = model
        self.batch = batch
        self._kernel, layout = kernel_for(model)
        self.parameters = layout.pack(model, batch)
        airframe = model.airframe
        self._geometry = (
            np.ascontiguousarray(model.inertia_kg_m2, dtype=float),
            np.ascontiguousarray(np.linalg.inv(model.inertia_kg_m2)),
            np.ascontiguousarray(airframe.rotor_positions_m),
            np.ascontiguousarray(airframe.spin_signs, dtype=float),
            np.ascontiguousarray(airframe.lower_rotor_mask),
        )
        # Without a crash latch the kernel still takes one; this one never latches (no crash limits).
        self._no_crashes = (
            np.zeros(batch, dtype=bool),
            np.full(batch, np.nan),
            np.full(batch, -1, dtype=np.int64),
        )

    def derivative(self, t: float, x: FloatArray, u: FloatArray) -> FloatArray:
        """dx/dt for each vehicle, from the compiled formulas (used to test them against the numpy model)."""
        out = np.empty_like(x, dtype=float)
        self._kernel.derivative_batch(
            float(t),
            np.ascontiguousarray(x, dtype=float),
            np.ascontiguousarray(u, dtype=float),
            self.parameters,
            *self._geometry,
            out,
        )
        return out

    def advance(
        self,
        t: float,
        x: FloatArray,
        u: FloatArray,
        dt: float,
        steps: int,
        ground_height_m: float | None,
        crashes: CrashLatch | None = None,
    ) -> FloatArray:
        """State after ``steps`` RK4 steps of ``dt`` with u held; FloatingPointError if one blows up.

        ``crashes``: latched and held as ``Integrator.advance`` does.
        """
        if crashes is not None and ground_height_m is None:
            raise ValueError("crashes need a ground: ground_height_m is None")
        x_next = np.array(x, dtype=float, order="C")
        kernel = (
            self._kernel.advance_parallel if self.batch >= PARALLEL_MIN_BATCH else self._kernel.advance_serial
        )
        failed = kernel(
            float(t),
            x_next,
            np.ascontiguousarray(u, dtype=float),
            self.parameters,
            *self._geometry,
            float(dt),
            int(steps),
            (
                ground_height_m is not None,
                float(ground_height_m or 0.0),
                math.inf if crashes is None else crashes.crash_speed_m_s,
                -math.inf if crashes is None else crashes.cos_crash_tilt,
            ),
            *(
                self._no_crashes
                if crashes is None
                else (crashes.crashed, crashes.touchdown_speed_m_s, crashes.crash_step)
            ),
        )
        # -1 = finite to the end. One vehicle (the MAVLink bridge, every frame): its entry, not a reduction
        # (max, a third of np.any's cost, still costs six times as much).
        if (failed[0] if self.batch == 1 else failed.max()) >= 0:
            vehicle = int(np.argmax(failed >= 0))
            when = t + (failed[vehicle] + 1) * dt
            raise FloatingPointError(f"the state of vehicle {vehicle} became non-finite at t = {when:.6f} s")
        return x_next


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels of the shipped airframes' own models."""
    from multirotor_ros.model.airframe import load_airframe

    for name in ("x8_octorotor", "hexarotor_f550", "quad_x"):
        model = Model(load_airframe(name))
        for batch in (1, PARALLEL_MIN_BATCH):
            stepper = CompiledStepper(model, batch)
            x = S.make_state(model.n_rotors, batch=batch, position_m=(0.0, 0.0, 1.0))
            u = np.full((batch, model.n_rotors), model.hover_speed_rad_s())
            stepper.advance(0.0, x, u, 1e-3, 1, 0.0)
            stepper.derivative(0.0, x, u)
