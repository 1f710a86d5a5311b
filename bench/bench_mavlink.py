"""Lockstep speed: steps per second with a PX4-like peer over MAVLink, and the same loop in pure ROS.

    .venv/bin/python bench/bench_mavlink.py [--seconds 10] [--rounds 3] [--airframe quad_x] [--skip-ros]

One lockstep step = the flight stack sends rotor commands, the physics advances 4 ms (250 Hz, quad_x
by default, 1 kHz integration, sensor noise on) and answers with the sensors of that step; the flight
stack runs its hover controller on the answer and sends the next commands. Each side is its own
process, as PX4 and the simulator are. Three measurements:

1. physics alone: ``SimulatorPhysics.advance_to`` in a loop, no I/O (the floor for everything else);
2. MAVLink: ``MavlinkBridge`` (internal physics) and ``Px4LikePeer`` over TCP, lockstep as PX4's
   simulator_mavlink runs it (as SIH, PX4's own simulation, steps at PX4's rate): HIL_ACTUATOR_CONTROLS
   in, HIL_SENSOR (+ HIL_GPS, HIL_STATE_QUATERNION when due) out. Per step, the bridge's answer (the
   actuator message read to the sensors sent) beside the PX4-like peer's own turn (sensors sent to the
   next actuator message read), p50 / p95 / p99; the bridge's CPU time per step minus the physics'
   gives its own per-step cost;
3. pure ROS: a physics node steps the same core once per ``motor_speed_cmd`` and publishes ``odom`` and
   ``imu``; a controller node runs the same hover controller on them and publishes the next command.

Both loops fly the same controller (HoverController, 2 m hover) for the same simulated time. The
ROS processes use a random ROS_DOMAIN_ID on localhost only. Results go to stdout (and --json FILE).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

STEP_S = 0.004


def _physics(airframe_name: str):
    from multirotor_ros.mavlink.physics import SimulatorPhysics
    from multirotor_ros.model.airframe import load_airframe

    airframe = load_airframe(airframe_name)
    return airframe, SimulatorPhysics.for_airframe(airframe, seed=1)


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def physics_alone(airframe_name: str, steps: int) -> dict[str, float]:
    _, physics = _physics(airframe_name)
    command = np.full(physics.n_rotors, 0.9 * physics.hover_speed_rad_s)
    step_ns = round(STEP_S * 1e9)
    start, cpu = time.perf_counter(), _cpu_s()
    for k in range(1, steps + 1):
        physics.advance_to(command, k * step_ns)
    wall = time.perf_counter() - start
    return {"steps_per_s": steps / wall, "cpu_ms_per_step": (_cpu_s() - cpu) / steps * 1e3}


# ---------------------------------------------------------------------------------------------- MAVLink


def mavlink_loop(airframe_name: str, seconds: float) -> dict[str, float]:
    from multirotor_ros.mavlink.actuators import RotorChannels
    from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, MavlinkBridge
    from multirotor_ros.mavlink.px4 import Px4Config

    airframe, physics = _physics(airframe_name)
    outputs = BridgeOutputs(lambda speeds, t: None, lambda state: None, lambda setpoint: None)
    config = BridgeConfig(
        "px4", px4=Px4Config(port=0, step_s=STEP_S, measure_timing=True), ground_station=None
    )
    bridge = MavlinkBridge(config, RotorChannels(airframe), physics, outputs)
    peer = subprocess.Popen(
        [sys.executable, __file__, "--role", "px4-peer", "--port", str(bridge.flight_stack_port),
         "--airframe", airframe_name, "--seconds", str(seconds)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        while not bridge.px4.connected:
            bridge.spin_once(0.05)
        steps_before, cpu = bridge.simulation.steps, _cpu_s()
        while peer.poll() is None:
            bridge.spin_once(0.05)
        cpu_per_step = (_cpu_s() - cpu) / max(1, bridge.simulation.steps - steps_before)
    finally:
        bridge.close()
    result = json.loads(peer.stdout.read().strip().splitlines()[-1])
    assert bridge.px4 is not None and bridge.px4.times is not None
    result |= bridge.px4.times.summary_ms()
    result["bridge_cpu_ms_per_step"] = cpu_per_step * 1e3
    result["altitude_m"] = float(physics.state.p_WB_W[2])
    return result


def px4_peer(port: int, airframe_name: str, seconds: float) -> None:
    from multirotor_ros.mavlink.actuators import RotorChannels
    from multirotor_ros.mavlink.peers import HoverController, Px4LikePeer
    from multirotor_ros.model.airframe import load_airframe

    channels = RotorChannels(load_airframe(airframe_name))
    peer = Px4LikePeer(port, HoverController(channels), keep_messages=False, timeout_s=30.0)
    peer.fly(0.2)  # connection, free-running start, switch to lockstep: not what is measured
    start, steps = time.perf_counter(), peer.record.actuator_messages
    peer.fly(0.2 + seconds)
    wall = time.perf_counter() - start
    peer.close()
    steps = peer.record.actuator_messages - steps
    print(json.dumps({"steps": steps, "wall_s": wall, "steps_per_s": steps / wall}), flush=True)


# ---------------------------------------------------------------------------------------------- pure ROS


def ros_physics(airframe_name: str) -> None:
    import rclpy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    from multirotor_ros.nodes.messages import imu_message, odometry_message, stamp_from_ns

    _, physics = _physics(airframe_name)
    rclpy.init(args=None)
    node = rclpy.create_node("bench_physics")
    odom = node.create_publisher(Odometry, "odom", 10)
    imu = node.create_publisher(Imu, "imu", 10)

    def on_command(message: JointState) -> None:
        state = physics.advance_to(np.asarray(message.velocity), physics.t_ns + round(STEP_S * 1e9))
        stamp = stamp_from_ns(round(state.t_s * 1e9))
        imu.publish(imu_message(stamp, "base_link", state.q_WB, state.imu_specific_force_B, state.imu_w_WB_B,
                                accel_var=0.0, gyro_var=0.0, orientation_var=0.0))  # fmt: skip
        odom.publish(odometry_message(physics.simulator.state, stamp))

    node.create_subscription(JointState, "motor_speed_cmd", on_command, 10)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def ros_controller(airframe_name: str, seconds: float) -> None:
    import rclpy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
    from multirotor_ros.mavlink.actuators import RotorChannels
    from multirotor_ros.mavlink.peers import HoverController
    from multirotor_ros.model.airframe import load_airframe
    from multirotor_ros.nodes.messages import joint_state_from_rotor_speeds, stamp_to_ns, state_from_odometry

    airframe = load_airframe(airframe_name)
    controller = HoverController(RotorChannels(airframe))
    rclpy.init(args=None)
    node = rclpy.create_node("bench_controller")
    command = node.create_publisher(JointState, "motor_speed_cmd", 10)
    latest: dict[str, object] = {}
    progress = {"steps": 0, "t_s": 0.0, "start": None, "start_step": 0, "sent_at": 0.0}

    def send(speeds: np.ndarray) -> None:
        command.publish(joint_state_from_rotor_speeds(speeds, node.get_clock().now().to_msg()))
        progress["sent_at"] = time.perf_counter()

    def on_imu(message: Imu) -> None:
        latest["imu"] = message

    def on_odom(message: Odometry) -> None:
        p, v, q, _ = state_from_odometry(message)
        imu = latest.get("imu")
        w = np.zeros(3) if imu is None else np.array([imu.angular_velocity.x, imu.angular_velocity.y,
                                                      imu.angular_velocity.z])  # fmt: skip
        progress["steps"] += 1
        progress["t_s"] = stamp_to_ns(message.header.stamp) * 1e-9
        if progress["start"] is None and progress["t_s"] >= 0.2:
            progress["start"], progress["start_step"] = time.perf_counter(), progress["steps"]
        if progress["t_s"] < 0.5:  # disarmed at first, as the PX4-like peer
            send(np.zeros(airframe.n_rotors))
            return
        send(controller.speeds(enu_to_ned(p), enu_to_ned(v), quat_enu_flu_to_ned_frd(q), flu_to_frd(w)))

    node.create_subscription(Imu, "imu", on_imu, 10)
    node.create_subscription(Odometry, "odom", on_odom, 10)
    deadline = time.monotonic() + 30.0
    while command.get_subscription_count() < 1 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)  # let discovery settle both ways before the first command
    send(np.zeros(airframe.n_rotors))
    stalls = 0
    while progress["t_s"] < 0.2 + seconds:
        rclpy.spin_once(node, timeout_sec=0.5)
        if time.perf_counter() - progress["sent_at"] > 0.5:  # a lost message would stop lockstep
            stalls += 1
            send(np.zeros(airframe.n_rotors))
    wall = time.perf_counter() - progress["start"]
    steps = progress["steps"] - progress["start_step"]
    print(
        json.dumps({"steps": steps, "wall_s": wall, "steps_per_s": steps / wall, "stalls": stalls}),
        flush=True,
    )
    node.destroy_node()
    rclpy.try_shutdown()


def ros_loop(airframe_name: str, seconds: float) -> dict[str, float]:
    environment = dict(
        os.environ, ROS_DOMAIN_ID=str(random.randint(1, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"
    )
    role = [sys.executable, __file__, "--airframe", airframe_name, "--role"]
    physics = subprocess.Popen([*role, "ros-physics"], env=environment)
    try:
        controller = subprocess.run(
            [*role, "ros-controller", "--seconds", str(seconds)],
            env=environment, stdout=subprocess.PIPE, text=True, check=True, timeout=600,
        )  # fmt: skip
    finally:
        physics.send_signal(2)
        physics.wait(10)
    return json.loads(controller.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per loop")
    parser.add_argument("--airframe", default="quad_x")
    parser.add_argument("--skip-ros", action="store_true", help="only the physics and the MAVLink loop")
    parser.add_argument("--rounds", type=int, default=3, help="alternating runs of each loop")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument(
        "--role", choices=["px4-peer", "ros-physics", "ros-controller"], help=argparse.SUPPRESS
    )
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "px4-peer":
        px4_peer(args.port, args.airframe, args.seconds)
        return 0
    if args.role == "ros-physics":
        ros_physics(args.airframe)
        return 0
    if args.role == "ros-controller":
        ros_controller(args.airframe, args.seconds)
        return 0

    steps = round(args.seconds / STEP_S)
    physics = physics_alone(args.airframe, steps)
    # The loops alternate, round after round, so that a machine whose load changes over the run
    # (other jobs) biases neither; the medians are reported.
    runs: dict[str, list[dict[str, float]]] = {"mavlink_px4_lockstep": [], "pure_ros_lockstep": []}
    for _ in range(args.rounds):
        runs["mavlink_px4_lockstep"].append(mavlink_loop(args.airframe, args.seconds))
        if not args.skip_ros:
            runs["pure_ros_lockstep"].append(ros_loop(args.airframe, args.seconds))

    def median(kind: str, key: str) -> float:
        return float(np.median([run[key] for run in runs[kind]]))

    physics_ms = physics["cpu_ms_per_step"]
    mavlink_rate = median("mavlink_px4_lockstep", "steps_per_s")
    bridge_ms = median("mavlink_px4_lockstep", "bridge_cpu_ms_per_step")
    load = os.getloadavg()[0]
    print(f"{args.airframe}, {STEP_S * 1e3:g} ms steps, {args.seconds:g} s simulated per loop, medians of "
          f"{args.rounds} rounds, load average {load:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(
        f"  physics alone           {physics['steps_per_s']:8.0f} steps/s  ({physics_ms:.3f} ms CPU per step)"
    )
    each = ", ".join(f"{run['steps_per_s']:.0f}" for run in runs["mavlink_px4_lockstep"])
    answer = "/".join(
        f"{median('mavlink_px4_lockstep', f'answer_{p}_ms'):.3f}" for p in ("p50", "p95", "p99")
    )
    turn = "/".join(
        f"{median('mavlink_px4_lockstep', f'flight_stack_{p}_ms'):.3f}" for p in ("p50", "p95", "p99")
    )
    print(f"  MAVLink (PX4-like peer) {mavlink_rate:8.0f} steps/s  ({mavlink_rate * STEP_S:.2f}x real time; "
          f"rounds: {each}; bridge CPU {bridge_ms:.3f} ms per step, {bridge_ms - physics_ms:.3f} ms of it "
          f"outside the physics)")  # fmt: skip
    print(f"    per step: bridge answer p50/p95/p99 {answer} ms, PX4-like peer's turn {turn} ms")
    if runs["pure_ros_lockstep"]:
        ros_rate = median("pure_ros_lockstep", "steps_per_s")
        each = ", ".join(f"{run['steps_per_s']:.0f}" for run in runs["pure_ros_lockstep"])
        stalls = sum(run["stalls"] for run in runs["pure_ros_lockstep"])
        print(f"  pure ROS (two nodes)    {ros_rate:8.0f} steps/s  ({ros_rate * STEP_S:.2f}x real time; "
              f"rounds: {each}; {stalls} lost messages resent)")  # fmt: skip
        print(f"  MAVLink / ROS: {mavlink_rate / ros_rate:.2f}")
    if args.json:
        args.json.write_text(json.dumps({"physics_alone": physics, **runs}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
