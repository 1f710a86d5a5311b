"""MAVProxy, a real ground station, against the bridge: it sees the vehicle, and only signed commands fly it.

MAVProxy runs as a subprocess, non-interactively: ``--non-interactive`` with start-up commands
(``--cmd``): ``signing key PASSPHRASE`` (signed link) and ``repeat add 0.5 position X Y Z`` (a
SET_POSITION_TARGET_LOCAL_NED every half second; MAVProxy can only send once it has heard the
vehicle, so a one-shot command at start-up would be lost). What MAVProxy saw is read back from its
telemetry log (``--logfile``), which holds every packet it accepted.

The vehicle: the bridge's own physics flown in lockstep by a PX4-like peer whose position controller
plays the part of the package's controller node: the bridge's ``setpoint`` output becomes its target.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import MAVProxy  # noqa: F401  (fail, not skip, when the ground station is missing)
import numpy as np
from pymavlink import mavutil

from multirotor_ros.frames import enu_to_ned
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.gcs import GroundStationConfig, Setpoint
from multirotor_ros.mavlink.peers import HoverController, Px4LikePeer
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.px4 import Px4Config
from multirotor_ros.mavlink.signing import SigningPolicy, parse_signing_key
from multirotor_ros.model.airframe import load_airframe

PASSPHRASE = "multirotor-sim-test"
SIGNED_TARGET_NED = (1.0, 2.0, -3.0)
UNSIGNED_TARGET_NED = (5.0, 5.0, -1.0)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start_mavproxy(tmp_path: Path, name: str, master: str, commands: list[str]) -> subprocess.Popen:
    home = tmp_path / name
    home.mkdir()
    command = [
        sys.executable, "-m", "MAVProxy.mavproxy", f"--master={master}", "--non-interactive", "--nowait",
        f"--state-basedir={home}", "--logfile=flight.tlog", "--default-modules=link,signing,cmdlong,misc",
        f"--cmd={'; '.join(commands)}",
    ]  # fmt: skip
    environment = dict(os.environ, HOME=str(home), PYTHONUNBUFFERED="1")  # ~/.mavproxy stays in tmp_path
    log = open(home / "stdout.txt", "wb")  # noqa: SIM115 - closed with the process below
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environment, cwd=home)


def stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)  # MAVProxy's own quit handler: unloads modules, flushes the log
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def read_tlog(path: Path) -> list:
    log = mavutil.mavlink_connection(str(path))
    messages = []
    while (message := log.recv_match()) is not None:
        messages.append(message)
    return messages


def test_mavproxy_sees_the_vehicle_and_only_a_signed_setpoint_moves_it(tmp_path):
    airframe = load_airframe("quad_x")
    channels = RotorChannels(airframe)
    controller = HoverController(channels, altitude_m=2.0)
    setpoints: list[Setpoint] = []

    def fly_to(setpoint: Setpoint) -> None:
        setpoints.append(setpoint)
        controller.target_NED = enu_to_ned(setpoint.p_W_m)

    gcs_port = free_udp_port()
    config = BridgeConfig("px4", px4=Px4Config(port=0), ground_station=GroundStationConfig(port=gcs_port))
    physics = SimulatorPhysics.for_airframe(airframe, seed=5)
    bridge = MavlinkBridge(
        config, channels, physics, BridgeOutputs(lambda s, t: None, lambda s: None, fly_to),
        signing=SigningPolicy(parse_signing_key(PASSPHRASE)),
    )  # fmt: skip
    stop_flying = threading.Event()
    processes: list[subprocess.Popen] = []
    with BridgeThread(bridge):
        peer = Px4LikePeer(bridge.flight_stack_port, controller, arm_after_s=0.2)

        def fly() -> None:
            t_s = 0.0
            while not stop_flying.is_set():
                t_s += 0.25
                peer.fly(t_s)

        flight = threading.Thread(target=fly, daemon=True)
        flight.start()
        try:
            x, y, z = SIGNED_TARGET_NED
            processes.append(
                start_mavproxy(tmp_path, "signed", f"udpin:127.0.0.1:{gcs_port}",
                               [f"signing key {PASSPHRASE}", f"repeat add 0.5 position {x} {y} {z}"])
            )  # fmt: skip
            x, y, z = UNSIGNED_TARGET_NED
            processes.append(
                start_mavproxy(tmp_path, "unsigned", f"udpout:127.0.0.1:{bridge.gcs.local_port}",
                               [f"repeat add 0.5 position {x} {y} {z}"])
            )  # fmt: skip
            target_ENU = np.array([2.0, 1.0, 3.0])
            deadline = time.monotonic() + 40.0
            while time.monotonic() < deadline:
                arrived = np.linalg.norm(physics.state.p_WB_W - target_ENU) < 0.3
                if arrived and bridge.refusals.counts.get("unsigned command", 0) >= 2:
                    break
                assert all(p.poll() is None for p in processes), "MAVProxy exited early"
                time.sleep(0.2)
            time.sleep(1.0)  # MAVProxy sees the arrival
        finally:
            for process in processes:
                stop(process)
            stop_flying.set()
            flight.join(10)
            peer.close()

    # Only the signed setpoint was taken, and the vehicle flew there (NED (1, 2, -3) = ENU (2, 1, 3)).
    assert setpoints, "no setpoint from the signed MAVProxy arrived"
    assert {tuple(s.p_W_m) for s in setpoints} == {(2.0, 1.0, 3.0)}
    np.testing.assert_allclose(physics.state.p_WB_W, [2.0, 1.0, 3.0], atol=0.3)
    assert bridge.refusals.counts.get("unsigned command", 0) >= 2
    assert set(bridge.refusals.counts) <= {"unsigned command", "ground station not admitted"}

    # MAVProxy saw the vehicle, its attitude and its position, over the signed link.
    signed_output = (tmp_path / "signed" / "stdout.txt").read_text(errors="replace")
    assert "Detected vehicle 1:1" in signed_output and "online system 1" in signed_output
    seen = [m for m in read_tlog(tmp_path / "signed" / "flight.tlog") if m.get_srcSystem() == 1]
    kinds = {m.get_type() for m in seen}
    assert {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYS_STATUS"} <= kinds
    positions = [m for m in seen if m.get_type() == "LOCAL_POSITION_NED"]
    assert positions[0].z > -2.5  # where it started: hovering at 2 m
    last = positions[-1]
    np.testing.assert_allclose([last.x, last.y, last.z], SIGNED_TARGET_NED, atol=0.35)
    assert any(
        m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
        for m in read_tlog(tmp_path / "signed" / "flight.tlog")
    )

    # The unsigned MAVProxy, at an address of its own, is no peer: it got no telemetry at all.
    unsigned_seen = [m for m in read_tlog(tmp_path / "unsigned" / "flight.tlog") if m.get_srcSystem() == 1]
    assert unsigned_seen == []
