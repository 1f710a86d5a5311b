"""Ground contact that behaves like ground, and crashes (issue 16).

The ground holds a vehicle resting on it (no sliding, no turning) until its thrust lifts it; a touchdown
too fast or too tilted is a crash, reported once, after which the vehicle lies where it hit whatever it
is commanded, until a reset puts it back where it started while time goes on. Pure core: the integrator
(both backends) and VehicleSimulator, alone and in a fleet.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Backend, CrashLatch, Integrator
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import euler_to_quat
from multirotor_ros.simulation.vehicle import (
    CRASH_SPEED_M_S,
    CRASH_TILT_RAD,
    NS_PER_S,
    Crash,
    Reading,
    VehicleSimulator,
    vehicle_generators,
)

MS = 1_000_000
X8 = load_airframe("x8_octorotor")
TOP = X8.rotor_speed_max_rad_s
SPIN = X8.spin_signs
# Full speed on the right-hand rotors, half on the left ones: a strong roll torque with a lot of thrust.
ROLLING = np.where(X8.rotor_positions_m[:, 1] > 0, 0.5 * TOP, TOP)
HOVER = Model(X8).hover_speed_rad_s()


def make_sim(**options) -> VehicleSimulator:
    options.setdefault("rng", np.random.default_rng(0))
    options.setdefault("noise", False)
    options.setdefault("command_timeout_s", 0.0)
    return VehicleSimulator(X8, **options)


def tilt(sim: VehicleSimulator, vehicle: int, roll_rad: float, yaw_rad: float = 0.0) -> None:
    """Turn a vehicle (where it was placed) to ``roll_rad``."""
    sim.x[vehicle, S.QUATERNION] = euler_to_quat(np.array([[roll_rad, 0.0, yaw_rad]]))[0]


def fly(sim: VehicleSimulator, command, seconds: float, vehicle: int = 0) -> list[Reading]:
    """Command ``command`` every 10 ms for ``seconds``; the readings."""
    readings: list[Reading] = []
    for _ in range(round(seconds * 100)):
        sim.set_command(command, vehicle=vehicle)
        readings += sim.run_until(sim.t_ns + 10 * MS)
    return readings


def crashes(readings: list[Reading]) -> list[Reading]:
    return [r for r in readings if r.kind == "crash"]


def heights(readings: list[Reading], vehicle: int = 0) -> np.ndarray:
    return np.array([r.data[2] for r in readings if r.kind == "odom" and r.vehicle == vehicle])


# ------------------------------------------------------------------ the ground holds what rests on it


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
@pytest.mark.parametrize(
    ("roll_rad", "u"),
    [
        (math.pi, ROLLING),  # upside down, thrust into the ground, rolling
        (0.0, 0.93 * HOVER * (1.0 + 0.1 * SPIN)),  # upright below its weight, yawing
        (0.2, 1.2 * HOVER / TOP * ROLLING),  # landed tilted, below its weight, rolling
    ],
)
def test_the_ground_holds_a_vehicle_still_until_its_thrust_lifts_it(
    backend: Backend, roll_rad: float, u: np.ndarray
) -> None:
    # Holding only the velocities of a sunken state, and not its pose, made each step keep the motion it
    # had gained: under a torque a grounded vehicle turned at alpha dt / 2 and slid along its thrust.
    model = Model(X8)
    assert X8.k_f_N_s2 * np.sum(u**2) * math.cos(roll_rad) < model.mass_kg * model.gravity_m_s2
    x0 = S.make_state(8, euler_rad=(roll_rad, 0.0, 0.4), rotor_speed_rad_s=u)
    x = Integrator(model, 1e-3, backend=backend).advance(0.0, x0, u, 2000)
    np.testing.assert_array_equal(x[0, :13], x0[0, :13])


def test_a_resting_vehicle_commanded_to_yaw_below_its_weight_neither_slides_nor_turns() -> None:
    sim = make_sim(initial_position_m=(1.0, -2.0, 0.0), initial_yaw_rad=0.7)
    start = sim.state[:13].copy()
    readings = fly(sim, 0.93 * sim.hover_speed_rad_s * (1.0 + 0.1 * SPIN), 3.0)
    assert not crashes(readings) and not sim.crashed()
    np.testing.assert_array_equal(sim.state[:13], start)


# ------------------------------------------------------------------ touchdowns


@pytest.mark.parametrize(
    ("speed_m_s", "roll_deg", "crash"),
    [
        (0.5, 0.0, False),  # a normal landing
        (1.0, 8.0, False),  # a firm one, a little tilted
        (0.5, 30.0, False),  # within the gear's tolerance
        (3.5, 0.0, True),  # a drop from 0.6 m
        (0.5, 60.0, True),  # onto an arm
        (0.5, 180.0, True),  # upside down
    ],
)
def test_a_touchdown_too_fast_or_too_tilted_is_a_crash(
    speed_m_s: float, roll_deg: float, crash: bool
) -> None:
    sim = make_sim(initial_position_m=(2.0, 1.0, 0.005), initial_yaw_rad=0.3)
    tilt(sim, 0, math.radians(roll_deg), 0.3)
    sim.x[0, S.VELOCITY] = (0.0, 0.0, -speed_m_s)
    landing = fly(sim, np.full(8, 0.8 * sim.hover_speed_rad_s), 0.5)
    assert sim.state[2] == 0.0 and sim.crashed() == crash
    takeoff = fly(sim, np.full(8, 1.3 * sim.hover_speed_rad_s), 1.0)
    assert (heights(takeoff).max() > 0.2) != crash
    if not crash:
        assert not crashes(landing + takeoff)
        return
    [reading] = crashes(landing + takeoff)
    data = reading.data
    assert isinstance(data, Crash) and reading.vehicle == 0
    assert 0 < reading.t_ns <= 10 * MS  # it hits within 0.005 m / speed
    # Up to 10 ms of gravity, and of thrust if upside down, on top of the speed it was given.
    assert speed_m_s <= data.touchdown_speed_m_s < speed_m_s + 0.2
    assert data.tilt_rad == pytest.approx(math.radians(roll_deg), abs=0.01)
    np.testing.assert_array_equal(data.p_WB_W, sim.state[S.POSITION])
    assert data.p_WB_W[2] == 0.0 and np.allclose(data.p_WB_W[:2], (2.0, 1.0), atol=0.01)


def test_the_default_crash_limits_spare_normal_landings() -> None:
    assert CRASH_SPEED_M_S > 1.0 and math.radians(15) < CRASH_TILT_RAD < math.pi / 2


def test_an_upside_down_drop_is_one_crash_and_the_wreck_stays_down_with_full_thrust() -> None:
    sim = make_sim(initial_position_m=(0.0, 0.0, 1.0), motor_lag=True)
    tilt(sim, 0, math.pi)
    readings = fly(sim, np.full(8, TOP), 0.5)
    [crash] = crashes(readings)
    assert crash.data.tilt_rad > 2.0 and crash.data.touchdown_speed_m_s > CRASH_SPEED_M_S
    wreck = sim.state.copy()
    assert wreck[2] == 0.0
    np.testing.assert_array_equal(wreck[S.VELOCITY], 0.0)
    np.testing.assert_array_equal(wreck[S.BODY_RATE], 0.0)
    later = fly(sim, ROLLING, 4.0) + fly(sim, np.full(8, TOP), 1.0)
    assert not crashes(later)
    np.testing.assert_array_equal(sim.state[:13], wreck[:13])  # no rotation, no sliding, no take-off
    np.testing.assert_array_equal(heights(later), 0.0)
    # Its rotors were stopped at the crash (they spin down with the motors' time constant) and stay so.
    np.testing.assert_array_equal(sim.command_rad_s, 0.0)
    motor_speeds = np.array([r.data for r in later if r.kind == "motor_speeds"])
    assert np.all(motor_speeds[0] < 1.0) and np.all(motor_speeds[-1] < 1e-9)
    # Readings stay in time order, the crash among them.
    assert [r.t_ns for r in readings] == sorted(r.t_ns for r in readings)


def test_a_crashed_vehicle_needs_no_commands() -> None:
    sim = make_sim(initial_position_m=(0.0, 0.0, 1.0), command_timeout_s=0.2)
    readings = fly(sim, np.zeros(8), 1.0)  # rotors off: it falls 1 m, 4.4 m/s
    assert [r.kind for r in readings if r.kind in ("crash", "watchdog")] == ["crash"]
    assert not [r for r in sim.run_until(sim.t_ns + NS_PER_S) if r.kind in ("crash", "watchdog")]


# ------------------------------------------------------------------ backends and fleets


def test_the_backends_agree_on_touchdowns_and_crashes() -> None:
    model = Model(X8)
    hover = model.hover_speed_rad_s()
    landings = [(0.5, 0.0), (1.0, 0.3), (3.0, 0.0), (0.5, 1.2), (0.5, math.pi), (0.0, 0.0)]
    x0 = S.make_state(
        8,
        batch=len(landings),
        position_m=(0.0, 0.0, 0.02),
        euler_rad=[(roll, 0.0, 0.0) for _, roll in landings],
        velocity_m_s=[(0.3, 0.0, -speed) for speed, _ in landings],
        rotor_speed_rad_s=hover,
    )
    u = np.tile(np.where(SPIN > 0, 0.9, 0.95) * hover, (len(landings), 1))
    results = []
    for backend in ("numpy", "compiled"):
        latch = CrashLatch(len(landings), CRASH_SPEED_M_S, CRASH_TILT_RAD)
        x = Integrator(model, 1e-3, backend=backend).advance(0.0, x0, u, 300, latch)
        results.append((x, latch))
    (x_numpy, numpy_latch), (x_compiled, compiled_latch) = results
    np.testing.assert_allclose(x_compiled, x_numpy, rtol=1e-10, atol=1e-10)
    np.testing.assert_array_equal(compiled_latch.crashed, [False, False, True, True, True, False])
    np.testing.assert_array_equal(compiled_latch.crashed, numpy_latch.crashed)
    np.testing.assert_array_equal(compiled_latch.crash_step, numpy_latch.crash_step)
    np.testing.assert_allclose(
        compiled_latch.touchdown_speed_m_s, numpy_latch.touchdown_speed_m_s, rtol=1e-10
    )
    np.testing.assert_array_equal(x_compiled[:, 2], 0.0)


def test_in_a_fleet_only_the_crashed_vehicle_is_latched() -> None:
    fleet = make_sim(
        rng=vehicle_generators(4, 3),
        initial_position_m=[(0.0, 0.0, 1.0), (3.0, 0.0, 1.0), (6.0, 0.0, 0.0)],
    )
    tilt(fleet, 1, math.pi)
    hover = np.full(8, fleet.hover_speed_rad_s)
    readings: list[Reading] = []
    for _ in range(100):
        fleet.set_command(hover, vehicle=0)
        fleet.set_command(ROLLING, vehicle=1)
        fleet.set_command(1.3 * hover, vehicle=2)
        readings += fleet.run_until(fleet.t_ns + 10 * MS)
    assert [(r.kind, r.vehicle) for r in crashes(readings)] == [("crash", 1)]
    assert [fleet.crashed(k) for k in range(3)] == [False, True, False]
    np.testing.assert_allclose(fleet.x[0, S.POSITION], (0.0, 0.0, 1.0), atol=1e-6)  # hovers on
    assert fleet.x[1, 2] == 0.0 and fleet.x[2, 2] > 0.5  # the wreck lies; the third took off
    np.testing.assert_array_equal(fleet.commands_rad_s[1], 0.0)
    with pytest.raises(ValueError, match="vehicle 3 does not exist"):
        fleet.crashed(3)


# ------------------------------------------------------------------ reset


def test_reset_puts_a_crashed_vehicle_back_where_it_started_while_time_goes_on() -> None:
    fleet = make_sim(
        rng=vehicle_generators(5, 2),
        initial_position_m=[(0.0, 0.0, 1.0), (3.0, 0.0, 2.0)],
        initial_yaw_rad=[0.0, 1.0],
        command_timeout_s=0.3,
    )
    start = fleet.x.copy()
    start_commands = fleet.commands_rad_s.copy()
    fleet.inject_fault(motor=3, effectiveness=0.5, vehicle=1)
    tilt(fleet, 1, math.pi, 1.0)
    readings: list[Reading] = []
    for _ in range(60):
        fleet.set_command(np.full(8, fleet.hover_speed_rad_s), vehicle=0)
        fleet.set_command(ROLLING, vehicle=1)
        readings += fleet.run_until(fleet.t_ns + 10 * MS)
    assert fleet.crashed(1)
    vehicle_0 = fleet.x[0].copy()
    before_ns = fleet.t_ns

    fleet.reset(vehicle=1)
    assert fleet.t_ns == before_ns and not fleet.crashed(1)
    np.testing.assert_array_equal(fleet.x[1], start[1])  # upright: its initial yaw, not the crash's roll
    np.testing.assert_array_equal(fleet.commands_rad_s[1], start_commands[1])  # hovering, as at the start
    np.testing.assert_array_equal(fleet.x[0], vehicle_0)  # the other vehicle is left as it was
    np.testing.assert_array_equal(fleet.injected_effectiveness(1), [1, 1, 0.5, 1, 1, 1, 1, 1])

    # Its watchdog runs again from the reset: silent, it trips 0.3 s later (the other keeps flying).
    after: list[Reading] = []
    for _ in range(50):
        fleet.set_command(np.full(8, fleet.hover_speed_rad_s), vehicle=0)
        after += fleet.run_until(fleet.t_ns + 10 * MS)
    assert [(r.vehicle, r.t_ns) for r in after if r.kind == "watchdog"] == [(1, before_ns + 300 * MS)]
    assert min(r.t_ns for r in after) >= before_ns  # no reading goes back in time
    assert not crashes(after)

    fleet.reset()
    np.testing.assert_array_equal(fleet.x, start)
    assert fleet.t_ns == before_ns + 500 * MS and not fleet.watchdog_tripped.any()


def test_a_reset_vehicle_on_the_ground_flies_again() -> None:
    sim = make_sim()
    sim.x[0, S.POSITION] = (0.0, 0.0, 0.5)
    tilt(sim, 0, math.pi / 2)  # dropped on its side
    fly(sim, np.zeros(8), 1.0)
    assert sim.crashed()
    sim.reset()
    np.testing.assert_array_equal(sim.state, S.make_state(8)[0])
    np.testing.assert_array_equal(sim.command_rad_s, 0.0)
    assert heights(fly(sim, np.full(8, 1.3 * sim.hover_speed_rad_s), 1.0)).max() > 0.2


# ------------------------------------------------------------------ properties and refusals


@settings(max_examples=20, deadline=None)
@given(
    commands=st.lists(
        st.tuples(st.lists(st.floats(0.0, 2.0 * TOP), min_size=8, max_size=8), st.integers(1, 300)),
        min_size=1,
        max_size=6,
    ),
    roll_rad=st.floats(CRASH_TILT_RAD + 0.01, math.pi),
)
def test_after_a_crash_no_command_moves_the_wreck(commands, roll_rad: float) -> None:
    sim = make_sim(initial_position_m=(0.0, 0.0, 0.05))
    tilt(sim, 0, roll_rad)
    sim.run_until(200 * MS)
    assert sim.crashed()
    wreck = sim.state.copy()
    for speeds, milliseconds in commands:
        sim.set_command(speeds)
        assert not crashes(sim.run_until(sim.t_ns + milliseconds * MS))
        np.testing.assert_array_equal(sim.state[:13], wreck[:13])
        np.testing.assert_array_equal(sim.command_rad_s, 0.0)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"crash_speed_m_s": 0.0}, "crash_speed_m_s must be > 0"),
        ({"crash_speed_m_s": math.nan}, "crash_speed_m_s must be > 0"),
        ({"crash_tilt_rad": 0.0}, r"crash_tilt_rad must be in \(0, pi\]"),
        ({"crash_tilt_rad": 4.0}, r"crash_tilt_rad must be in \(0, pi\]"),
    ],
)
def test_impossible_crash_limits_are_refused(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_sim(**options)


def test_crash_tests_can_be_turned_off() -> None:
    sim = make_sim(initial_position_m=(0.0, 0.0, 1.0), crash_speed_m_s=math.inf, crash_tilt_rad=math.pi)
    tilt(sim, 0, math.pi)
    assert not crashes(fly(sim, np.zeros(8), 1.0)) and not sim.crashed()
    assert sim.state[2] == 0.0  # still the ground holds it


def test_the_mavlink_bridge_physics_latches_a_crash_and_reports_it_once() -> None:
    """The bridge steps the simulator's state in its own frames: the same latch holds the wreck there."""
    from multirotor_ros.mavlink.physics import SimulatorPhysics

    airframe = load_airframe("x8_octorotor")
    physics = SimulatorPhysics.for_airframe(airframe, noise=False)
    frame_ns = 2_500_000  # a flight stack's 400 Hz frames
    top = np.full(airframe.n_rotors, airframe.rotor_speed_max_rad_s)
    t_ns = 0
    for _ in range(400):  # 1 s at full thrust: several metres up
        t_ns += frame_ns
        physics.advance_to(top, t_ns)
    assert physics.state.p_WB_W[2] > 2.0
    crashes = []
    for _ in range(2400):  # rotors off: it falls, hits the ground, and full thrust again moves it no more
        t_ns += frame_ns
        physics.advance_to(np.zeros(airframe.n_rotors) if not crashes else top, t_ns)
        crashes += [r for r in physics.take_readings() if r.kind == "crash"]
    assert len(crashes) == 1
    assert crashes[0].data.touchdown_speed_m_s > CRASH_SPEED_M_S
    assert physics.simulator.crashed()
    assert physics.state.p_WB_W[2] == 0.0
