"""The ``rotor_effectiveness`` topic (std_msgs/Float64MultiArray) <-> numpy; bad content is a Refusal.

Layout: ``dim[0]`` label ``"field"`` size 2, ``dim[1]`` label ``"rotor"`` size N, ``data_offset`` 0,
row-major (strides 2N and N). Row 0 holds each rotor's estimated remaining effectiveness (share of its
nominal thrust and drag torque, 1 = healthy), row 1 its standard deviation (1.0 when nothing is known).
The identifier publishes it, the controller reads it (nodes/identifier.py, nodes/controller.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.plausibility import format_vector
from multirotor_ros.refusals import Refusal

FIELDS = ("estimate", "std")
# Beyond this an effectiveness is no rotor's (the allocator refuses it too): a corrupt message.
EFFECTIVENESS_MAX = 1.5


def rotor_effectiveness_message(estimate: ArrayLike, std: ArrayLike) -> Float64MultiArray:
    """The message of (N,) estimates and their (N,) standard deviations."""
    rows = np.vstack([np.asarray(estimate, dtype=float), np.asarray(std, dtype=float)])
    n_rotors = rows.shape[1]
    message = Float64MultiArray()
    message.layout.dim = [
        MultiArrayDimension(label="field", size=len(FIELDS), stride=len(FIELDS) * n_rotors),
        MultiArrayDimension(label="rotor", size=n_rotors, stride=n_rotors),
    ]
    message.layout.data_offset = 0
    message.data = rows.ravel().tolist()
    return message


def effectiveness_from_message(message: Any, n_rotors: int) -> tuple[FloatArray, FloatArray] | Refusal:
    """(estimate, std), each (N,), of a message with the layout above, or why it is refused.

    Refused: another layout or rotor count, non-finite values, an estimate outside [0, 1.5], a negative
    standard deviation.
    """
    dims = [(d.label, d.size, d.stride) for d in message.layout.dim]
    expected = [("field", 2, 2 * n_rotors), ("rotor", n_rotors, n_rotors)]
    if dims != expected or message.layout.data_offset != 0:
        shown = [(label[:20], size, stride) for label, size, stride in dims[:3]]
        return Refusal(
            "wrong layout",
            f"dims (label, size, stride) {shown}{' ...' if len(dims) > 3 else ''} with data_offset "
            f"{message.layout.data_offset}; "
            f"expected {expected} with data_offset 0",
        )
    data = np.asarray(message.data, dtype=float)
    if data.shape != (2 * n_rotors,):
        return Refusal("wrong size", f"{data.size} values; the layout says {2 * n_rotors}")
    if not np.all(np.isfinite(data)):
        return Refusal("non-finite value", format_vector(data))
    estimate, std = data[:n_rotors], data[n_rotors:]
    if np.any((estimate < 0.0) | (estimate > EFFECTIVENESS_MAX)):
        return Refusal("effectiveness out of range", f"{format_vector(estimate)}; must be in [0, 1.5]")
    if np.any(std < 0.0):
        return Refusal("negative standard deviation", format_vector(std))
    return estimate, std
