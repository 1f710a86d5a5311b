"""Whether something may be holding the vehicle: then its samples are no evidence of anything.

Every model here is of free flight: rotors, gravity and the air act on the vehicle, nothing else. What
holds it (the ground under its legs, a hand, a stand) adds a force and, through the legs, torques that
no model has; the residual is then the support, which the detector reads as rotors losing thrust (the
support unloads as the rotors spin up) and the identifier as a wrong thrust constant. So while the
vehicle may be held its samples are missing data: nothing is identified or diagnosed from them. Two
rules, from the physics of free flight, say when (:meth:`SupportWatch.support`):

1. Held, wherever it is: for ``HELD_CONFIRM_S`` it has not moved (speed below ``RESTING_SPEED_M_S``,
   body rate below ``RESTING_RATE_RAD_S``) while its rotors could not hold it in the air: their
   thrust below ``HELD_THRUST_SHARE`` of the weight, or tilted more than ``HELD_TILT_RAD`` whatever
   its thrust (in the air the thrust balances the weight: 30° of tilt would take a side
   force of 58 % of the weight; a vehicle on its side is not flying). The time is what tells a moment
   of free flight from support: at the top of a descent the speed is near zero and the thrust below
   the weight, but a 10 % thrust deficit accelerates a free vehicle downward at 1 m/s² or more, which
   leaves the speed bound within 0.1 s; 0.2 s of stillness is support.
2. On the ground, before take-off and after landing: within ``GROUND_RADII`` rotor radii of the ground
   height (where it was last held; before that z = 0, the odom frame's origin on the ground it starts
   from), come to a stop vertically (below ``RESTING_SPEED_M_S``), and the rotors' thrust along the world
   vertical at most ``LIFT_OFF_THRUST_SHARE`` of the weight. The ground pushes but cannot pull: with more
   thrust the vehicle lifts off and flies freely from that moment; with less the ground carries the
   difference, anything from nothing to the whole weight, changing as the controller's integrators move
   the rotors. Once on the ground it stays there until it lifts off or leaves the band, whatever vertical
   speed is measured meanwhile (without the thrust to leave, that is the sensors' noise: a pose
   differentiated into a velocity jitters by a few cm/s). A vehicle waiting on the ground for its first
   setpoint, its controller holding hover thrust, is exactly that, and the first rule does not see it (its
   thrust is near the weight). The 5 % above the weight covers the configured thrust constant's error and
   the ESCs' speed noise. Two rotor radii is where ground effect ends (Cheeseman and Bennett: the thrust
   at a height z over the ground is 1/(1 - (R/4z)²) of its free-air value, +1.6 % at 2R, +6.7 % at R):
   closer, even a vehicle in the air is not in free flight. (A vehicle held up by hand and let go counts
   as on the ground while it hovers within that band of where it was held: missing data, the cautious
   side.)

The thrust is computed with the airframe's configured thrust constant, not the identified one, so that
a poisoned estimate cannot make a hover look like support or support like a hover.

Take-off and landing follow: the samples on the ground are missing data, so the first one in free
flight comes after a gap, which restarts the observer; the detector then waits for the observer to
settle and learns the residual noise again before it may alarm (diagnosis/diagnoser.py), by which time
the vehicle has climbed clear of the ground. The transient of lift-off is never evidence.
"""

from __future__ import annotations

import math

import numpy as np

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.state import StateBatch

RESTING_SPEED_M_S = 0.1
RESTING_RATE_RAD_S = 0.1
HELD_CONFIRM_S = 0.2
HELD_THRUST_SHARE = 0.9
HELD_TILT_RAD = math.radians(30.0)
LIFT_OFF_THRUST_SHARE = 1.05
GROUND_RADII = 2.0


class SupportWatch:
    """The two rules of the module docstring for one vehicle (where it was held, whether on the ground)."""

    def __init__(self, airframe: Airframe, gravity_m_s2: float):
        self.k_f_N_s2 = airframe.k_f_N_s2
        self.weight_N = airframe.mass_kg * gravity_m_s2
        self.ground_band_m = GROUND_RADII * airframe.rotor_radius_m
        self.ground_z_m = 0.0
        self._held_since_ns: int | None = None  # since when the first rule's conditions hold
        self._on_ground = False  # the second rule held at the last sample

    def support(self, stamp_ns: int, state: StateBatch) -> str | None:
        """Why the vehicle may be held at this sample (words for a log), or None in free flight.

        ``state`` is one sample with its rotor speeds. Call it for every sample in stamp order: the
        first rule needs to know how long its conditions have held.
        """
        v_WB_W = state.v_WB_W[0]
        up = float(state.R_WB[0, 2, 2])  # body z along world z: the cosine of the tilt
        share = self.k_f_N_s2 * float(np.sum(state.omega[0] ** 2)) / self.weight_N
        tilt_rad = math.acos(min(max(up, -1.0), 1.0))
        load = f"thrust {100 * share:.0f} % of the weight, tilted {math.degrees(tilt_rad):.0f} deg"
        z_m = float(state.p_WB_W[0, 2])
        held_now = (
            float(np.linalg.norm(v_WB_W)) < RESTING_SPEED_M_S
            and float(np.linalg.norm(state.w_WB_B[0])) < RESTING_RATE_RAD_S
            and (share < HELD_THRUST_SHARE or tilt_rad > HELD_TILT_RAD)
        )
        if not held_now:
            self._held_since_ns = None
        elif self._held_since_ns is None or stamp_ns < self._held_since_ns:  # or a new time line
            self._held_since_ns = stamp_ns
        held_s = 0.0 if self._held_since_ns is None else (stamp_ns - self._held_since_ns) * 1e-9
        if held_s >= HELD_CONFIRM_S:
            self.ground_z_m = z_m
            return f"not moving for {held_s:.1f} s, {load}"
        self._on_ground = (
            abs(z_m - self.ground_z_m) <= self.ground_band_m
            and share * up <= LIFT_OFF_THRUST_SHARE
            and (self._on_ground or abs(float(v_WB_W[2])) < RESTING_SPEED_M_S)
        )
        return f"on the ground at z = {z_m:.2f} m, {load}" if self._on_ground else None
