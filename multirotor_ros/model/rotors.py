"""The rotor wrench: what each rotor's thrust and drag torque do to the body, written once.

Rotor i at p_i (body FLU) with thrust T_i along body +z and drag-torque magnitude Q_i contributes

    (T_i,  T_i y_i,  -T_i x_i,  s_i Q_i)      (thrust [N]; tau_x, tau_y, tau_z [N m] in body FLU)

since p_i x (0, 0, T_i) = (T_i y_i, -T_i x_i, 0), and its reaction torque is s_i Q_i about +z with
s_i = -1 for a ccw rotor, +1 for a cw one (conventions.md). :func:`rotor_torque_terms` is plain
arithmetic, so the same function runs on scalars inside the compiled kernel and on arrays here; the
allocation matrix, the numpy model, the fault search and the observers all use :func:`rotor_signatures`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from multirotor_ros.model.rotation import FloatArray

if TYPE_CHECKING:
    from multirotor_ros.model.airframe import Airframe


def rotor_torque_terms(
    thrust: Any, drag_torque: Any, rotor_x: Any, rotor_y: Any, spin: Any
) -> tuple[Any, Any, Any]:
    """(tau_x, tau_y, tau_z) of one rotor in body FLU [N m]; scalars or arrays that broadcast."""
    return thrust * rotor_y, -thrust * rotor_x, spin * drag_torque


def rotor_signatures(airframe: Airframe, thrust: FloatArray, drag_torque: FloatArray) -> FloatArray:
    """(..., 4, N): each rotor's (thrust, tau_x, tau_y, tau_z) from its thrust and drag torque (..., N)."""
    positions = airframe.rotor_positions_m
    thrust, drag_torque = np.broadcast_arrays(
        np.asarray(thrust, dtype=float), np.asarray(drag_torque, dtype=float)
    )
    tau_x, tau_y, tau_z = rotor_torque_terms(
        thrust, drag_torque, positions[:, 0], positions[:, 1], airframe.spin_signs
    )
    return np.stack([thrust, tau_x, tau_y, tau_z], axis=-2)


def rotor_wrench(airframe: Airframe, thrust: FloatArray, drag_torque: FloatArray) -> FloatArray:
    """(..., 4): total thrust [N] and body torque [N m] of all rotors together."""
    return rotor_signatures(airframe, thrust, drag_torque).sum(axis=-1)
