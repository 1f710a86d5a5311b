"""Hostile input at volume: every node, every input topic and MAVLink port, at least 10,000 bad messages each.

    .venv/bin/python bench/bench_fuzz.py [--count 10000] [--rate 1000] [--seed 1] [--nodes controller ...]

Starts each node (simulator, controller, identifier, mavlink_bridge with flight_stack none) as a process
of its own, in a random ROS_DOMAIN_ID on localhost only, floods each of its input topics in turn with the
seeded mix of ``multirotor fuzz`` (the same code: ``multirotor_ros.cli.fuzz.fuzz_node``), and prints the
table: messages, refusals, crash, tracebacks, non-finite outputs, log lines, memory before and after.
The bridge sends its ground-station telemetry to a port this script listens on, so non-finite values in
MAVLink telemetry count as non-finite outputs too. Node output goes to --log-dir (a temporary directory
by default). Exit status 1 if any node crashed, printed a traceback or emitted a non-finite value.

The ``mavlink/...`` rows flood the bridge's MAVLink ports instead, each on free local ports, with
``--count`` seeded malformed frames of :func:`multirotor_ros.mavlink.malformed.malformed_frames` mixed
with valid traffic, at ``--rate``:

- ``mavlink/gcs``: flight_stack none, the ground-station UDP port (gcs_bind_port); one valid HEARTBEAT,
  TIMESYNC or setpoint after every :data:`MALFORMED_PER_VALID` bad frames, from the same socket; valid
  odom, imu and motor_speeds on the ROS side keep the telemetry going;
- ``mavlink/px4``: flight_stack px4, the TCP flight-stack port; a PX4-like peer flies a hover in
  lockstep on the same connection meanwhile (its writes and the flood's never interleave mid-packet);
- ``mavlink/ardupilot``: flight_stack ardupilot, the UDP servo port; the bad packets are built here
  (:func:`malformed_servo_packets`: wrong sizes, magic and frame rates, repeated frames, pulses out of
  range, JSON text, and the MAVLink frames above) among valid servo packets, all from one address.

Refusals are read from the node's output (first refusal of each reason plus the throttled summaries,
brought out by one more bad frame after ``--settle`` seconds); non-finite outputs count its ROS outputs,
its telemetry to a ground-station port this script listens on, and what the valid peer receives
(HIL_* messages, JSON answers). Afterwards a valid peer must still be answered: a new ground station's
TIMESYNC, the PX4-like peer's next steps, a new ArduPilot-like peer's hover.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

# Before anything imports rclpy: this run must not hear, or be heard by, other ROS graphs on the machine.
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 200))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

NAMESPACE = "/fuzz"
# (row name, executable, parameters): the identifier reads odom or pose + imu, so it runs once per input.
RUNS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("simulator", "simulator", {}),
    ("controller", "controller", {}),
    ("identifier", "identifier", {}),
    ("identifier/pose_imu", "identifier", {"input": "pose_imu"}),
    ("mavlink_bridge", "mavlink_bridge", {"flight_stack": "none"}),
)
# (row name, flight_stack): the bridge's MAVLink port flooded in that row.
MAVLINK_RUNS = (("mavlink/gcs", "none"), ("mavlink/px4", "px4"), ("mavlink/ardupilot", "ardupilot"))
MALFORMED_PER_VALID = 4
SETTLE_S = 11.0  # longer than the RefusalCounter summary period (10 s)
STARTUP_TIMEOUT_S = 30.0
PEER_TIMEOUT_S = 30.0
PX4_PEER_CHUNK_S = 0.04  # [s] simulated time the PX4-like peer flies between pauses
PX4_PEER_PAUSE_S = 0.02  # [s] wall time: keeps the lockstep near real time on a shared machine
SERVO_FRAME_RATE_HZ = 400
SERVO_CHANNELS = 16
SERVO_IDLE_US = 1000
SERVO_KINDS = (
    "random bytes",
    "wrong size",
    "bad magic",
    "bad frame rate",
    "repeated frame",
    "pulse out of range",
    "JSON text",
    "MAVLink frame",
)


def _free_port(kind: socket.SocketKind = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _start(node: str, parameters: dict[str, Any], log_path: Path) -> subprocess.Popen[bytes]:
    arguments = ["--ros-args", "-r", f"__ns:={NAMESPACE}"]
    for name, value in parameters.items():
        arguments += ["-p", f"{name}:={value}"]
    environment = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
    with open(log_path, "wb") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "multirotor_ros.cli", "node", node, *arguments],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=environment,
        )


def _stop(process: subprocess.Popen[bytes]) -> int | None:
    """SIGINT and wait; the exit status, or None if it had to be killed."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(15.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            return None
    return process.returncode


# ------------------------------------------------------------------------------------------------
# MAVLink ports

Frame = tuple[str, bytes]  # (what is wrong with it, or "valid"; the bytes of one datagram or write)
VALID_FRAME = "valid"
AIRFRAME = "x8_octorotor"  # the bridge's default: the peers mix rotor speeds for the same airframe
FLOODED_PORT_PARAMETER = {
    "none": "gcs_bind_port",
    "px4": "flight_stack_port",
    "ardupilot": "flight_stack_port",
}


def _mavlink_sender() -> Any:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    return mavlink2.MAVLink(None, 255, 190)


def valid_ground_station_frames() -> list[bytes]:
    """What a ground station sends: a HEARTBEAT, a TIMESYNC request, a setpoint 3 m above (1, 2)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = _mavlink_sender()
    position_only = 0b1101_1111_1000
    messages = (
        mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0),
        mav.timesync_encode(0, 1),
        mav.set_position_target_local_ned_encode(
            0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, position_only, 1.0, 2.0, -3.0, *[0.0] * 8
        ),
    )
    return [bytes(message.pack(mav)) for message in messages]


def malformed_ground_station_frames(count: int, seed: int) -> list[Frame]:
    """``count`` malformed frames with a valid one before every MALFORMED_PER_VALID of them."""
    from multirotor_ros.mavlink.malformed import malformed_frames

    valid = valid_ground_station_frames()
    frames: list[Frame] = []
    for index, frame in enumerate(malformed_frames(count, seed)):
        if index % MALFORMED_PER_VALID == 0:
            frames.append((VALID_FRAME, valid[(index // MALFORMED_PER_VALID) % len(valid)]))
        frames.append(frame)
    return frames


def malformed_servo_packets(count: int, seed: int) -> list[Frame]:
    """``count`` bad ArduPilot servo packets (:data:`SERVO_KINDS` in turn) among valid ones.

    A valid packet goes before every MALFORMED_PER_VALID bad ones, frame counts in the order one SITL
    would send them. Each bad kind is refused: wrong size, wrong magic, frame rate 0 or above 10 kHz,
    the last frame count again (answered with the last answer), a rotor's pulse outside 800..2200 us
    (the frame still steps), JSON text (of a servo packet's size or not) and the MAVLink frames of
    ``malformed_frames``.
    """
    from multirotor_ros.mavlink.ardupilot import (
        MAX_FRAME_RATE_HZ,
        SERVO_FORMAT_16,
        SERVO_FORMAT_32,
        SERVO_MAGIC_16,
        SERVO_MAGIC_32,
        encode_servo_packet,
    )
    from multirotor_ros.mavlink.malformed import malformed_frames
    from multirotor_ros.model.airframe import load_airframe

    rotor_channels = load_airframe(AIRFRAME).n_rotors  # channel k drives rotor k; others carry anything
    rng = np.random.default_rng(seed)
    mavlink_frames = iter(malformed_frames(count // len(SERVO_KINDS) + 1, seed))
    idle = [SERVO_IDLE_US] * SERVO_CHANNELS
    frame_count = 0

    def next_frame(pwm_us: list[int]) -> bytes:
        nonlocal frame_count
        frame_count += 1
        return encode_servo_packet(SERVO_FRAME_RATE_HZ, frame_count, pwm_us)

    def pick(options: tuple[Any, ...]) -> Any:
        return options[int(rng.integers(len(options)))]

    packets: list[Frame] = []
    for index in range(count):
        if index % MALFORMED_PER_VALID == 0:
            packets.append((VALID_FRAME, next_frame(idle)))
        kind = SERVO_KINDS[index % len(SERVO_KINDS)]
        upcoming = encode_servo_packet(SERVO_FRAME_RATE_HZ, frame_count + 1, idle)
        if kind == "random bytes":
            packet = rng.bytes(int(rng.integers(1, 301)))
        elif kind == "wrong size":
            cut = upcoming[: int(rng.integers(1, len(upcoming)))]
            packet = cut if rng.random() < 0.5 else upcoming + rng.bytes(int(rng.integers(1, 40)))
        elif kind == "bad magic":
            magic = pick((SERVO_MAGIC_32, 0, 0xFFFF, SERVO_MAGIC_16 ^ 1))
            packet = magic.to_bytes(2, "little") + upcoming[2:]
        elif kind == "bad frame rate":
            rate_hz = pick((0, MAX_FRAME_RATE_HZ + 1, 0xFFFF))
            packet = SERVO_FORMAT_16.pack(SERVO_MAGIC_16, rate_hz, frame_count + 1, *idle)
        elif kind == "repeated frame":
            packet = encode_servo_packet(SERVO_FRAME_RATE_HZ, frame_count, idle)
        elif kind == "pulse out of range":
            pwm_us = list(idle)
            pwm_us[int(rng.integers(rotor_channels))] = pick((1, 799, 2201, 0xFFFF))
            packet = next_frame(pwm_us)
        elif kind == "JSON text":
            text = json.dumps({"timestamp": pick((float("nan"), float("inf"), 1e308)), "pwm": idle})
            size = pick((SERVO_FORMAT_16.size, SERVO_FORMAT_32.size, int(rng.integers(1, 301))))
            packet = text.encode()[:size].ljust(size, b" ")
        else:
            packet = next(mavlink_frames)[1]
        packets.append((kind, packet))
    return packets


class _Port(Protocol):
    """One flooded MAVLink port, with the valid peer that shares it."""

    refused_frame: bytes  # certainly refused: brings out the last refusal summary

    @property
    def peer_messages(self) -> int:
        """Valid messages a peer sent besides the flood's own."""
        ...

    def send(self, frame: bytes) -> None: ...

    def answers_valid_peer(self) -> bool: ...

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped before the bridge read them (None: a stream drops nothing)."""
        ...

    def close(self) -> None: ...


def _bad_crc_heartbeat() -> bytes:
    damaged = bytearray(valid_ground_station_frames()[0])
    damaged[-1] ^= 0x55
    return bytes(damaged)


class _UdpPort:
    """Sends the flood to a UDP port from one local address; the valid traffic is in the flood."""

    def __init__(self, port: int, refused_frame: bytes) -> None:
        self.address = ("127.0.0.1", port)
        self.refused_frame = refused_frame
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.2)

    @property
    def peer_messages(self) -> int:
        return 0

    def send(self, frame: bytes) -> None:
        self.socket.sendto(frame, self.address)

    def kernel_drops(self) -> int | None:
        # /proc/net/udp: local address as hex IP:port, the socket's drop count last.
        for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
            fields = line.split()
            if int(fields[1].split(":")[1], 16) == self.address[1]:
                return int(fields[-1])
        return None

    def close(self) -> None:
        self.socket.close()


class _GroundStationPort(_UdpPort):
    """The ground-station port; afterwards a new station's TIMESYNC request must be answered."""

    def __init__(self, port: int) -> None:
        super().__init__(port, _bad_crc_heartbeat())

    def answers_valid_peer(self) -> bool:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        mav, parser = _mavlink_sender(), mavlink2.MAVLink(None)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as station:
            station.bind(("127.0.0.1", 0))
            station.settimeout(0.2)
            station.sendto(mav.timesync_encode(0, 42).pack(mav), self.address)
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline:
                try:
                    data = station.recv(65536)
                except TimeoutError:
                    continue
                if any(m.get_type() == "TIMESYNC" and m.ts1 == 42 for m in parser.parse_buffer(data) or []):
                    return True
        return False


def _json_numbers(value: Any) -> Iterator[Any]:
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, list):
        for element in value:
            yield from _json_numbers(element)
    else:
        yield value


class _ArduPilotPort(_UdpPort):
    """The servo port: the flood's JSON answers are outputs; afterwards a new SITL must be served."""

    def __init__(self, port: int, on_output: Callable[[Any], None]) -> None:
        super().__init__(port, b"\0")
        self._on_output = on_output
        self._running = True
        self._thread = threading.Thread(target=self._receive, name="ardupilot_answers", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        while self._running:
            try:
                data = self.socket.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                self._on_output(list(_json_numbers(json.loads(data))))
            except ValueError:
                self._on_output([float("nan")])  # an answer that is not JSON is as unusable as a NaN

    def answers_valid_peer(self) -> bool:
        """After the flood's address fell silent, a new SITL flies 0.2 s simulated (frames restart at 1)."""
        from multirotor_ros.mavlink.actuators import RotorChannels
        from multirotor_ros.mavlink.peers import ArduPilotLikePeer, HoverController
        from multirotor_ros.model.airframe import load_airframe

        controller = HoverController(RotorChannels(load_airframe(AIRFRAME)))
        peer = ArduPilotLikePeer(
            self.address[1], controller, frame_rate_hz=SERVO_FRAME_RATE_HZ, timeout_s=5.0
        )
        try:
            peer.fly(0.2)
        except (OSError, ValueError):
            return False
        finally:
            peer.close()
        return True

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=2.0)
        super().close()


class _LockedStream:
    """pymavlink's file for the PX4-like peer: its writes and the flood's never interleave."""

    def __init__(self, sock: socket.socket, lock: threading.Lock) -> None:
        self._socket = sock
        self._lock = lock

    def write(self, data: bytes) -> None:
        with self._lock:
            self._socket.sendall(data)


class _Px4Port:
    """The flight-stack TCP port: a PX4-like peer flies a hover in lockstep on the flooded connection."""

    def __init__(self, port: int) -> None:
        from multirotor_ros.mavlink.actuators import RotorChannels
        from multirotor_ros.mavlink.peers import HoverController, Px4LikePeer
        from multirotor_ros.model.airframe import load_airframe

        self.refused_frame = _bad_crc_heartbeat()
        controller = HoverController(RotorChannels(load_airframe(AIRFRAME)))
        self._peer = Px4LikePeer(port, controller, timeout_s=PEER_TIMEOUT_S, keep_messages=False)
        self._lock = threading.Lock()
        self._peer.mav.file = _LockedStream(self._peer.sock, self._lock)
        self._stop = threading.Event()
        self.error: OSError | None = None
        self._thread = threading.Thread(target=self._fly, name="px4_peer", daemon=True)
        self._thread.start()

    @property
    def peer_messages(self) -> int:
        return self._peer.record.actuator_messages

    def _fly(self) -> None:
        target_s = 0.0
        try:
            while not self._stop.is_set():
                target_s += PX4_PEER_CHUNK_S
                self._peer.fly(target_s)
                time.sleep(PX4_PEER_PAUSE_S)
        except OSError as error:  # also a closed connection and PEER_TIMEOUT_S of silence
            if not self._stop.is_set():
                self.error = error

    def send(self, frame: bytes) -> None:
        with self._lock:
            self._peer.sock.sendall(frame)

    def kernel_drops(self) -> int | None:
        return None

    def answers_valid_peer(self) -> bool:
        """The peer still flies: its lockstep advanced over the last 2 s."""
        steps_before = self.peer_messages
        time.sleep(2.0)
        return self.error is None and self.peer_messages > steps_before

    def close(self) -> None:
        self._stop.set()
        self._peer.close()
        self._thread.join(timeout=PEER_TIMEOUT_S)


@contextmanager
def _valid_ros_inputs(probe: Any, rate_hz: float = 50.0) -> Iterator[None]:
    """Valid odom, imu and motor_speeds for an external-physics bridge, so that its telemetry flows."""
    from multirotor_ros.cli.fuzz import NODE_INPUTS, VALID, HostileMessage, default_valid_message
    from multirotor_ros.cli.fuzz import _message_types as message_types

    types = message_types()
    publishers = [
        (kind, probe.create_publisher(types[kind], f"{NAMESPACE}/{topic}", 10))
        for topic, kind in NODE_INPUTS["mavlink_bridge"]
    ]

    def publish() -> None:
        now_ns = probe.get_clock().now().nanoseconds
        for kind, publisher in publishers:
            publisher.publish(HostileMessage(kind, default_valid_message(kind), VALID).stamped(now_ns))

    timer = probe.create_timer(1.0 / rate_hz, publish)
    try:
        yield
    finally:
        probe.destroy_timer(timer)


def _wait_for_publisher(probe: Any, topic: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while probe.count_publishers(topic) == 0:
        if time.monotonic() > deadline:
            raise TimeoutError(f"no publisher on {topic} within {timeout_s:g} s: did the bridge start?")
        time.sleep(0.1)
    time.sleep(1.0)  # discovery matches the subscriptions a moment after the graph shows the publisher


def _log_since(log_path: Path, offset: int) -> str:
    with open(log_path, "rb") as log:
        log.seek(offset)
        return log.read().decode(errors="replace")


@dataclass(frozen=True)
class PortResult:
    """What a MAVLink row reports besides the table's columns."""

    sent: Counter[str]  # messages per kind (what is wrong, or valid)
    answered: bool  # a valid peer was answered after the flood
    kernel_drops: int | None  # datagrams dropped before the bridge read them (UDP only)


def _open_port(flight_stack: str, port: int, on_output: Callable[[Any], None]) -> _Port:
    if flight_stack == "px4":
        return _Px4Port(port)
    if flight_stack == "ardupilot":
        return _ArduPilotPort(port, on_output)
    return _GroundStationPort(port)


def _frames(flight_stack: str, count: int, seed: int) -> list[Frame]:
    from multirotor_ros.mavlink.malformed import malformed_frames

    if flight_stack == "px4":
        return malformed_frames(count, seed)  # the valid traffic is the PX4-like peer's
    if flight_stack == "ardupilot":
        return malformed_servo_packets(count, seed)
    return malformed_ground_station_frames(count, seed)


def flood_mavlink_port(
    flight_stack: str,
    port: int,
    gcs_port: int,
    *,
    count: int,
    seed: int,
    rate_hz: float,
    pid: int,
    log_path: Path,
) -> tuple[Any, PortResult]:
    """Flood the bridge's port of ``flight_stack`` (module docstring).

    Returns its TopicReport and what goes beyond the table's columns.
    """
    from rclpy.qos import qos_profile_sensor_data

    from multirotor_ros.cli.fuzz import NODE_OUTPUTS, TopicReport, _GroundStation, _OutputWatch
    from multirotor_ros.cli.fuzz import _message_types as message_types
    from multirotor_ros.cli.ros_session import background_node

    frames = _frames(flight_stack, count, seed)
    types = message_types()
    outputs = NODE_OUTPUTS["mavlink_bridge"] + (
        () if flight_stack == "none" else ("odom", "imu", "motor_speeds")
    )
    watch = _OutputWatch(f"{NAMESPACE.strip('/')}.mavlink_bridge")  # its outputs; the log is the file
    station = _GroundStation(gcs_port, watch)
    report = TopicReport("mavlink_bridge", f"{'TCP' if flight_stack == 'px4' else 'UDP'} port {port}")
    try:
        with background_node(f"multirotor_fuzz_{os.getpid()}") as probe:
            for topic in outputs:
                name = f"{NAMESPACE}/{topic}"
                probe.create_subscription(types[topic], name, watch.output, qos_profile_sensor_data)
            _wait_for_publisher(probe, f"{NAMESPACE}/motor_speed_cmd", STARTUP_TIMEOUT_S)
            with _valid_ros_inputs(probe) if flight_stack == "none" else nullcontext():
                flooded = _open_port(flight_stack, port, watch.output)
                try:
                    answered = _flood(flooded, frames, report, watch, rate_hz, pid, log_path)
                    drops = flooded.kernel_drops()
                finally:
                    flooded.close()
    finally:
        station.close()
    sent = Counter(kind for kind, _ in frames)
    if report.messages > len(frames):
        sent["valid (PX4-like peer)"] = report.messages - len(frames)
    return report, PortResult(sent, answered, drops)


def _flood(
    flooded: _Port, frames: list[Frame], report: Any, watch: Any, rate_hz: float, pid: int, log_path: Path
) -> bool:
    """Send ``frames`` at ``rate_hz``, settle, count; whether a valid peer is answered afterwards."""
    from multirotor_ros.cli.fuzz import process_alive, refusals_in_log, resident_memory_kb

    report.rss_before_kb = resident_memory_kb(pid)
    log_offset = log_path.stat().st_size
    outputs_before, non_finite_before, _ = watch.snapshot()
    peer_before = flooded.peer_messages
    start_s = time.monotonic()
    for index, (_, frame) in enumerate(frames):
        delay_s = start_s + index / rate_hz - time.monotonic()
        if delay_s > 0:
            time.sleep(delay_s)
        flooded.send(frame)
    report.messages = len(frames) + flooded.peer_messages - peer_before
    # A RefusalCounter summarises only when it refuses again after its period: wait, then one more.
    time.sleep(SETTLE_S)
    flooded.send(flooded.refused_frame)
    time.sleep(1.0)
    lines = _log_since(log_path, log_offset).splitlines()
    report.log_lines = len(lines)
    report.refusals = max(refusals_in_log(lines) - 1, 0)
    answered = flooded.answers_valid_peer()
    outputs_after, non_finite_after, _ = watch.snapshot()
    report.outputs = outputs_after - outputs_before
    report.non_finite_outputs = non_finite_after - non_finite_before
    report.crashed = not process_alive(pid)
    report.rss_after_kb = resident_memory_kb(pid)
    report.tracebacks = _log_since(log_path, log_offset).count("Traceback")
    return answered


def _mavlink_row(
    name: str, flight_stack: str, port: int, gcs_port: int, notes: list[str], failed: list[str], **flood: Any
) -> list[Any]:
    """flood_mavlink_port as one row; what was sent and whether a valid peer was answered go to notes."""
    report, result = flood_mavlink_port(flight_stack, port, gcs_port, **flood)
    kinds = ", ".join(f"{kind} {number}" for kind, number in result.sent.items())
    drops = "" if result.kernel_drops is None else f"; datagrams the kernel dropped: {result.kernel_drops}"
    answered = "yes" if result.answered else "NO"
    notes.append(f"  {name}: {kinds}{drops}; a valid peer answered afterwards: {answered}")
    if not result.answered:
        failed.append(name)
    return [report]


def main(argv: list[str] | None = None) -> int:
    from multirotor_ros.cli.fuzz import TopicReport, format_table, fuzz_node

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=10_000, help="messages per input topic or port")
    parser.add_argument("--rate", type=float, default=1000.0, help="messages per second (bursts excepted)")
    parser.add_argument("--seed", type=int, default=1)
    topic_runs = {name: (node, parameters) for name, node, parameters in RUNS}
    port_runs = dict(MAVLINK_RUNS)
    names = [*topic_runs, *port_runs]
    parser.add_argument("--nodes", nargs="+", choices=names, default=names, help="which rows to run")
    parser.add_argument("--log-dir", type=Path, help="where node output goes (default: a temporary one)")
    args = parser.parse_args(argv)
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="bench_fuzz_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, node output in {log_dir}", flush=True)

    reports: list[TopicReport] = []
    failed: list[str] = []
    exit_notes: list[str] = []
    port_notes: list[str] = []
    for name in (name for name in names if name in args.nodes):
        log_path = log_dir / f"{name.replace('/', '_')}.log"
        gcs_port = _free_port()
        common = {"count": args.count, "seed": args.seed, "rate_hz": args.rate, "log_path": log_path}
        flood: Callable[..., list[TopicReport]]
        if name in topic_runs:
            node, parameters = topic_runs[name]
            if node == "mavlink_bridge":
                parameters = {**parameters, "gcs_port": gcs_port}
            flood = partial(
                fuzz_node,
                node,
                namespace=NAMESPACE,
                gcs_port=gcs_port if node == "mavlink_bridge" else None,
                discovery_timeout_s=30.0,
                **common,
            )
        else:
            node, flight_stack = "mavlink_bridge", port_runs[name]
            port = _free_port(socket.SOCK_STREAM if flight_stack == "px4" else socket.SOCK_DGRAM)
            parameters = {
                "flight_stack": flight_stack,
                "gcs_port": gcs_port,
                FLOODED_PORT_PARAMETER[flight_stack]: port,
            }
            flood = partial(_mavlink_row, name, flight_stack, port, gcs_port, port_notes, failed, **common)
        process = _start(node, parameters, log_path)
        started_s = time.monotonic()
        try:
            rows = flood(pid=process.pid)
        except Exception as error:  # one node failing to start must not hide the others' rows
            failed.append(name)
            rows = [TopicReport(name, "-", note=f"{type(error).__name__}: {error}")]
        for row in rows:
            row.node = name
        reports += rows
        status = _stop(process)
        exit_notes.append(
            f"{name}: {time.monotonic() - started_s:.0f} s, "
            f"{'killed 15 s after SIGINT' if status is None else f'exit status {status} after SIGINT'}"
        )
        print(f"{name} done", flush=True)

    print()
    print(format_table(reports))
    if port_notes:
        print("MAVLink messages sent per kind:")
        print("\n".join(port_notes))
    print()
    print("\n".join(exit_notes))
    return int(bool(failed) or any(r.crashed or r.tracebacks or r.non_finite_outputs for r in reports))


if __name__ == "__main__":
    sys.exit(main())
