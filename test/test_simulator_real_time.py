"""The simulator in real time integrates a period as soon as its commands are in and publishes it, early.

A real simulator node in this process, its wall clock replaced by one the test moves: what matters is
which readings go out at which wall time, and that the physics is that of the commands in force.
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.context import Context
from rclpy.parameter import Parameter

import multirotor_ros.nodes.simulator as simulator_module
from multirotor_ros.nodes.cdr import RotorCommandWriter
from multirotor_ros.nodes.simulator import SimulatorNode
from multirotor_ros.simulation.pacing import NS_PER_S, RealTimePacer
from multirotor_ros.simulation.vehicle import VehicleSimulator

pytestmark = pytest.mark.ros
PERIOD_NS = 4_000_000  # control_period_s and publish_rate_hz by default: 250 Hz
MS = 1_000_000


def test_the_pacer_tells_the_simulated_time_of_a_wall_time_without_re_anchoring() -> None:
    pacer = RealTimePacer(2.0, max_lag_s=0.25)
    assert pacer.now_ns(123) is None
    pacer.anchor(wall_ns=1_000, sim_ns=5 * MS)
    assert pacer.now_ns(1_000 + NS_PER_S) == 5 * MS + 2 * NS_PER_S
    assert pacer.fell_behind == 0 and pacer.now_ns(1_000) == 5 * MS


def test_a_period_whose_command_is_in_is_integrated_and_published_at_once_up_to_a_period_early(
    rclpy_context: Context, monkeypatch: pytest.MonkeyPatch
) -> None:
    wall_ns = [10**15]
    monkeypatch.setattr(simulator_module.time, "monotonic_ns", lambda: wall_ns[0])
    node = SimulatorNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("real_time_factor", value=1.0),
            Parameter("publish_clock", value=True),
            Parameter("initial_z", value=1.0),
            Parameter("airframe", value="quad_x"),
        ],
    )
    try:
        published: list[tuple[str, int]] = []
        publish = node._publish
        monkeypatch.setattr(
            node,
            "_publish",
            lambda readings: (published.extend((r.kind, r.t_ns) for r in readings), publish(readings)),
        )
        node._start()
        node._on_timer()  # anchors real time at the state of t = 0
        assert node.sim.t_ns == 0 and ("odom", 0) in published
        wall_ns[0] += PERIOD_NS
        node._on_timer()  # the state of the first tick, 4 ms: no command yet, nothing runs ahead
        assert node.sim.t_ns == PERIOD_NS and ("odom", PERIOD_NS) in published
        n = node.airframe.n_rotors
        hover = np.full(n, 0.9 * node.airframe.rotor_speed_max_rad_s)

        wall_ns[0] += 2 * MS  # the controller answers 2 ms after the state
        node.on_command(node.vehicles[0], RotorCommandWriter(n).write(PERIOD_NS, hover.tolist()))
        assert node.sim.t_ns == 2 * PERIOD_NS  # the period it covers, integrated at once
        assert ("odom", 2 * PERIOD_NS) in published  # and its state out, 2 ms before its wall time
        assert node._timing[0].on_time == 1 and node._timing[0].late == 0
        x_ahead = node.sim.x.copy()

        # The next command at 6.5 ms covers up to 12 ms, but the physics stays within a publish period
        # of the wall clock (whole steps: up to 11 ms); the tick at 8 ms takes it to 12 ms, a period early.
        wall_ns[0] += MS // 2
        node.on_command(node.vehicles[0], RotorCommandWriter(n).write(2 * PERIOD_NS, hover.tolist()))
        assert node.sim.t_ns == 11 * MS and ("odom", 3 * PERIOD_NS) not in published
        wall_ns[0] += 3 * MS // 2
        node._on_timer()
        assert node.sim.t_ns == 3 * PERIOD_NS and ("odom", 3 * PERIOD_NS) in published

        # No command for the period from 12 ms: nothing runs ahead, and the tick past its end (16 ms of
        # wall time) finds it late.
        wall_ns[0] += PERIOD_NS
        node._on_timer()
        assert node.sim.t_ns == 3 * PERIOD_NS and node._timing[0].late == 0
        wall_ns[0] += PERIOD_NS
        node._on_timer()
        assert node.sim.t_ns == 4 * PERIOD_NS and node._timing[0].late == 1
        assert node._timing[0].on_time == 2
    finally:
        node.destroy_node()

    # The physics of the period is that of its command from its start, as if integrated at the tick.
    reference = VehicleSimulator(
        node.airframe,
        rng=np.random.default_rng(0),
        physics_rate_hz=1000,
        motor_lag=node._params["motor_lag"],
        initial_position_m=[(0.0, 0.0, 1.0)],
    )
    reference.run_until(PERIOD_NS)
    reference.set_command(hover)
    reference.run_until(2 * PERIOD_NS)
    np.testing.assert_array_equal(reference.x, x_ahead)
