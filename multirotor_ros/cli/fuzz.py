"""``multirotor fuzz``: flood the input topics of a running node with hostile messages, count what happens.

The generator
    ``hostile_messages(kind, count, seed, valid=None, *, airframe=None) -> list[HostileMessage]`` for the
    kinds in :data:`KINDS`: "odometry" (nav_msgs/Odometry), "imu" (sensor_msgs/Imu), "pose" and "setpoint"
    (geometry_msgs/PoseStamped) and "joint_state" (sensor_msgs/JointState of rotor speeds, rotor_1..N).
    A seeded mix, the same for the same arguments: NaN, +-inf, 1e308, 1e200, 1e39 and 1e5 in each field,
    negative and oversized rotor speeds, wrong lengths, unknown or repeated joint names, zero and non-unit
    quaternions, stamps at 0, in the past, an hour ahead and at sec = 2^31 - 1, wrong frame ids, position
    jumps, far setpoints, bursts (runs of messages sent at once with one stamp) and about
    :data:`VALID_FRACTION` valid messages. Every bad message is a valid one (``valid()``, or hover at
    (0, 0, 1) in frame "odom" for the airframe's rotor count and hover speed) with one thing wrong.

    Each :class:`HostileMessage` carries ``.message``, ``.label`` (what is wrong: one of :data:`LABELS`,
    "valid" for a valid one; count refusals per label with it), ``.detail`` and its stamp rule: stamps
    are relative to the time of sending, so publish ``item.stamped(now_ns)``, not ``item.message``
    (``stamped`` leaves absolute stamps such as 0 and 2^31 - 1 s alone).

The command
    ``multirotor fuzz NODE [--namespace /uav1] [--count 10000] [--seed 1] [--rate 1000] [--pid PID]
    [--log FILE] [--gcs-port PORT]`` floods each input topic of the running node NODE in turn (the other
    inputs get a valid background stream meanwhile, so that the node keeps working), then prints per
    topic: messages sent, the node's refusals (from its /rosout lines: the first refusal of each reason
    plus the throttled summaries, which a last bad message after ``--settle`` seconds brings out), whether
    it crashed, non-finite values in its output topics (and, with ``--gcs-port``, in the MAVLink
    telemetry it sends to that ground-station port), log lines, tracebacks in ``--log``, and its resident
    memory (``--pid``) before and after.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from multirotor_ros.cli import CommandError
from multirotor_ros.cli.ros_session import background_node
from multirotor_ros.model.rotation import FloatArray

COMMAND = "fuzz"
HELP = "flood the input topics of a running node with hostile messages and report how it copes"

KINDS = ("odometry", "imu", "pose", "joint_state", "setpoint")
VALID = "valid"
LABELS = (
    VALID,
    "non-finite value",
    "huge value",
    "invalid quaternion",
    "stamp zero",
    "stamp in the past",
    "stamp an hour ahead",
    "stamp at 2^31-1 s",
    "wrong frame id",
    "position jump",
    "far setpoint",
    "negative speed",
    "oversized speed",
    "wrong length",
    "unknown joint name",
    "burst",
)
VALID_FRACTION = 0.2
BURST_PROBABILITY = 0.002  # per pick; a burst is 10 to 60 messages, about 7 % of all
BURST_LENGTHS = (10, 61)
NON_FINITE_VALUES = (math.nan, math.inf, -math.inf)
# 1e308 overflows any square; 1e200 overflows a product of two; 1e39 overflows float32; 1e5 is merely
# beyond every physical limit.
HUGE_VALUES = (1e308, -1e308, 1e200, 1e39, 1e5)
WRONG_FRAMES = ("map", "world", "", "uav2/odom", "base_link", "odom " + "x" * 300)
NS_PER_S = 1_000_000_000
HOVER_POSITION_M = (0.0, 0.0, 1.0)
GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class HostileMessage:
    """One message of a flood: what is wrong with it and how to stamp it when it is sent."""

    kind: str
    message: Any
    label: str
    detail: str = ""
    # Stamp = time of sending + this; None keeps the message's own (absolute) stamp.
    stamp_offset_ns: int | None = 0
    # Messages of one burst (same non-zero id) go out back to back with one stamp.
    burst: int = 0

    def stamped(self, now_ns: int) -> Any:
        """The message, stamped for sending at ``now_ns`` (the message object itself, restamped)."""
        if self.stamp_offset_ns is not None:
            sec, nanosec = divmod(max(now_ns + self.stamp_offset_ns, 0), NS_PER_S)
            self.message.header.stamp.sec = sec
            self.message.header.stamp.nanosec = nanosec
        return self.message


@dataclass(frozen=True)
class _Kind:
    """Where a message kind keeps what the corruptions change."""

    vectors: tuple[str, ...]  # attribute paths of Vector3/Point fields (x, y, z)
    quaternion: str | None
    position: str | None
    frames: tuple[str, ...]  # attribute paths of frame ids


_KIND_FIELDS = {
    "odometry": _Kind(
        ("pose.pose.position", "twist.twist.linear", "twist.twist.angular"),
        "pose.pose.orientation",
        "pose.pose.position",
        ("header.frame_id", "child_frame_id"),
    ),
    "imu": _Kind(("angular_velocity", "linear_acceleration"), "orientation", None, ("header.frame_id",)),
    "pose": _Kind(("pose.position",), "pose.orientation", "pose.position", ("header.frame_id",)),
    "setpoint": _Kind(("pose.position",), "pose.orientation", "pose.position", ("header.frame_id",)),
    "joint_state": _Kind((), None, None, ()),
}


@dataclass(frozen=True)
class _Rotors:
    count: int
    hover_rad_s: float
    max_rad_s: float


# A corruption changes a valid message in place and says (label, detail, stamp offset or None).
_Corruption = Callable[[np.random.Generator, Any, _Kind, _Rotors], tuple[str, str, int | None]]


def hostile_messages(
    kind: str,
    count: int,
    seed: int,
    valid: Callable[[], Any] | None = None,
    *,
    airframe: Any = None,
) -> list[HostileMessage]:
    """``count`` messages of ``kind``, a seeded mix of hostile and valid ones (see the module docstring).

    ``valid()`` makes one valid message (each call a new object); by default hover at (0, 0, 1) in frame
    "odom" (child "base_link"), with rotor speeds for ``airframe`` (an Airframe; x8_octorotor if None).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown message kind {kind!r}; choose one of {', '.join(KINDS)}")
    rotors = _rotors(airframe)
    make_valid = valid or (lambda: default_valid_message(kind, rotors.count, rotors.hover_rad_s))
    fields = _KIND_FIELDS[kind]
    corruptions = [c for c in _CORRUPTIONS if c.applies(fields, kind)]
    rng = np.random.default_rng(seed)
    items: list[HostileMessage] = []
    bursts = 0
    while len(items) < count:
        if rng.random() < BURST_PROBABILITY:
            bursts += 1
            length = min(int(rng.integers(*BURST_LENGTHS)), count - len(items))
            detail = f"{length} messages back to back with one stamp"
            items += [HostileMessage(kind, make_valid(), "burst", detail, 0, bursts) for _ in range(length)]
        elif rng.random() < VALID_FRACTION:
            items.append(HostileMessage(kind, make_valid(), VALID))
        else:
            corruption = corruptions[int(rng.integers(len(corruptions)))]
            message = make_valid()
            label, detail, offset_ns = corruption.apply(rng, message, fields, rotors)
            items.append(HostileMessage(kind, message, label, detail, offset_ns))
    return items


def default_valid_message(kind: str, n_rotors: int = 8, hover_speed_rad_s: float = 340.0) -> Any:
    """A valid message of ``kind``: hover at (0, 0, 1), level, at rest, in frame "odom" (stamp 0)."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    if kind == "odometry":
        odometry = Odometry()
        odometry.header.frame_id, odometry.child_frame_id = "odom", "base_link"
        _set_vector(odometry.pose.pose.position, HOVER_POSITION_M)
        odometry.pose.pose.orientation.w = 1.0
        return odometry
    if kind == "imu":
        imu = Imu()
        imu.header.frame_id = "base_link"
        imu.orientation.w = 1.0
        imu.linear_acceleration.z = GRAVITY_M_S2
        return imu
    if kind in ("pose", "setpoint"):
        pose = PoseStamped()
        pose.header.frame_id = "odom"
        _set_vector(pose.pose.position, HOVER_POSITION_M)
        pose.pose.orientation.w = 1.0
        return pose
    if kind == "joint_state":
        joints = JointState()
        joints.name = [f"rotor_{k}" for k in range(1, n_rotors + 1)]
        joints.velocity = [float(hover_speed_rad_s)] * n_rotors
        return joints
    raise ValueError(f"unknown message kind {kind!r}; choose one of {', '.join(KINDS)}")


def _rotors(airframe: Any) -> _Rotors:
    from multirotor_ros.model.airframe import load_airframe
    from multirotor_ros.model.effects import hover_speed_estimate

    frame = airframe if airframe is not None else load_airframe("x8_octorotor")
    return _Rotors(frame.n_rotors, hover_speed_estimate(frame), frame.rotor_speed_max_rad_s)


def _resolve(message: Any, path: str) -> Any:
    for name in path.split("."):
        message = getattr(message, name)
    return message


def _set_vector(vector: Any, values: Sequence[float] | FloatArray) -> None:
    vector.x, vector.y, vector.z = (float(v) for v in values)


def _choice(rng: np.random.Generator, options: Sequence[Any]) -> Any:
    return options[int(rng.integers(len(options)))]


def _scalar_paths(fields: _Kind) -> list[str]:
    vectors = [f"{path}.{axis}" for path in fields.vectors for axis in "xyz"]
    quaternion = [f"{fields.quaternion}.{axis}" for axis in "xyzw"] if fields.quaternion else []
    return vectors + quaternion


@dataclass(frozen=True)
class _CorruptionRule:
    apply: _Corruption
    applies: Callable[[_Kind, str], bool]


def _bad_number(values: Sequence[float], label: str) -> _Corruption:
    def corrupt(
        rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
    ) -> tuple[str, str, int]:
        value = float(_choice(rng, values))
        if not fields.vectors:  # rotor speeds
            k = int(rng.integers(rotors.count))
            speeds = list(message.velocity)
            speeds[k] = value
            message.velocity = speeds
            return label, f"velocity[{k}] = {value:g}", 0
        path = _choice(rng, _scalar_paths(fields))
        owner, _, attribute = path.rpartition(".")
        setattr(_resolve(message, owner), attribute, value)
        return label, f"{path} = {value:g}", 0

    return corrupt


def _bad_quaternion(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    assert fields.quaternion is not None
    q = rng.normal(size=4)
    norm = float(_choice(rng, (0.0, 1e-6, 0.5, 1.05, 2.0, 1e3)))
    q = q / np.linalg.norm(q) * norm
    quaternion = _resolve(message, fields.quaternion)
    quaternion.x, quaternion.y, quaternion.z, quaternion.w = (float(v) for v in q)
    return "invalid quaternion", f"{fields.quaternion} of norm {norm:g}", 0


def _bad_stamp(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int | None]:
    which = int(rng.integers(4))
    if which == 0:
        message.header.stamp.sec, message.header.stamp.nanosec = 0, 0
        return "stamp zero", "header.stamp = 0", None
    if which == 1:
        seconds_back = float(rng.uniform(0.05, 3600.0))
        return "stamp in the past", f"{seconds_back:.3f} s before sending", -round(seconds_back * NS_PER_S)
    if which == 2:
        return "stamp an hour ahead", "3600 s after sending", 3600 * NS_PER_S
    message.header.stamp.sec, message.header.stamp.nanosec = 2**31 - 1, 0
    return "stamp at 2^31-1 s", "header.stamp.sec = 2147483647", None


def _wrong_frame(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    path = _choice(rng, fields.frames)
    frame = _choice(rng, WRONG_FRAMES)
    owner, _, attribute = path.rpartition(".")
    setattr(_resolve(message, owner) if owner else message, attribute, frame)
    return "wrong frame id", f"{path} = {frame[:20]!r}", 0


def _moved(label: str, low_m: float, high_m: float) -> _Corruption:
    def corrupt(
        rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
    ) -> tuple[str, str, int]:
        assert fields.position is not None
        direction = rng.normal(size=3)
        offset = direction / np.linalg.norm(direction) * rng.uniform(low_m, high_m)
        position = np.array(HOVER_POSITION_M) + offset
        _set_vector(_resolve(message, fields.position), position)
        return label, f"{fields.position} {np.linalg.norm(offset):.0f} m from hover", 0

    return corrupt


def _negative_speed(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    k = int(rng.integers(rotors.count))
    speeds = list(message.velocity)
    speeds[k] = -float(_choice(rng, (1e-3, rotors.hover_rad_s, rotors.max_rad_s)))
    message.velocity = speeds
    return "negative speed", f"velocity[{k}] = {speeds[k]:g} rad/s", 0


def _oversized_speed(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    # Between the maximum and twice it (passes a loose gate) or far above it, on one rotor or on all.
    factor = float(_choice(rng, (rng.uniform(1.05, 1.99), 10.0)))
    speed = factor * rotors.max_rad_s
    if rng.random() < 0.5:
        message.velocity = [speed] * rotors.count
        return "oversized speed", f"every rotor at {factor:.2f} x the maximum", 0
    k = int(rng.integers(rotors.count))
    speeds = list(message.velocity)
    speeds[k] = speed
    message.velocity = speeds
    return "oversized speed", f"velocity[{k}] at {factor:.2f} x the maximum", 0


def _wrong_length(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    names, speeds = list(message.name), list(message.velocity)
    which = int(rng.integers(4))
    if which == 0:
        message.name, message.velocity = names[:-1], speeds[:-1]
        return "wrong length", f"{rotors.count - 1} rotors", 0
    if which == 1:
        message.name = [*names, f"rotor_{rotors.count + 1}"]
        message.velocity = [*speeds, speeds[0]]
        return "wrong length", f"{rotors.count + 1} rotors", 0
    if which == 2:
        message.velocity = speeds[: int(rng.integers(rotors.count))]
        return "wrong length", f"{len(message.velocity)} speeds for {rotors.count} names", 0
    message.name, message.velocity = [], []
    return "wrong length", "no rotors", 0


def _unknown_name(
    rng: np.random.Generator, message: Any, fields: _Kind, rotors: _Rotors
) -> tuple[str, str, int]:
    names = list(message.name)
    k = int(rng.integers(rotors.count))
    replacement = _choice(rng, ("rotor_0", f"rotor_{rotors.count + 1}", "motor_1", "", "rotor_01", "rotor_1"))
    if names[k] == replacement:  # rotor_1 in place of itself: repeat another name instead
        replacement = names[(k + 1) % rotors.count]
    names[k] = replacement
    message.name = names
    return "unknown joint name", f"name[{k}] = {replacement!r}", 0


_CORRUPTIONS = (
    _CorruptionRule(_bad_number(NON_FINITE_VALUES, "non-finite value"), lambda f, k: True),
    _CorruptionRule(_bad_number(HUGE_VALUES, "huge value"), lambda f, k: True),
    _CorruptionRule(_bad_quaternion, lambda f, k: f.quaternion is not None),
    _CorruptionRule(_bad_stamp, lambda f, k: True),
    _CorruptionRule(_wrong_frame, lambda f, k: bool(f.frames)),
    _CorruptionRule(_moved("position jump", 100.0, 5000.0), lambda f, k: k in ("odometry", "pose")),
    _CorruptionRule(_moved("far setpoint", 2e4, 1e5), lambda f, k: k == "setpoint"),
    _CorruptionRule(_negative_speed, lambda f, k: k == "joint_state"),
    _CorruptionRule(_oversized_speed, lambda f, k: k == "joint_state"),
    _CorruptionRule(_wrong_length, lambda f, k: k == "joint_state"),
    _CorruptionRule(_unknown_name, lambda f, k: k == "joint_state"),
)


# ------------------------------------------------------------------------------------------------
# Sending and watching (no ROS in these helpers: the session below plugs rclpy in)


def flood(
    items: Sequence[HostileMessage],
    publish: Callable[[Any], object],
    now_ns: Callable[[], int],
    rate_hz: float,
    background: Callable[[], object] | None = None,
    background_rate_hz: float = 50.0,
) -> None:
    """Publish every item stamped at its time of sending, ``rate_hz`` at most (bursts back to back).

    ``background()`` is called ``background_rate_hz`` times a second meanwhile (valid messages on the
    node's other inputs, so that it keeps working during the flood).
    """
    start_s = time.monotonic()
    paced = 0
    next_background_s = start_s
    burst, burst_now_ns = 0, 0
    for item in items:
        if item.burst:
            if item.burst != burst:
                burst, burst_now_ns = item.burst, now_ns()
            publish(item.stamped(burst_now_ns))
            continue
        delay_s = start_s + paced / rate_hz - time.monotonic()
        if delay_s > 0:
            time.sleep(delay_s)
        if background is not None and time.monotonic() >= next_background_s:
            background()
            next_background_s += 1.0 / background_rate_hz
        publish(item.stamped(now_ns()))
        paced += 1


_NON_FINITE_TEXT = re.compile(r"(?<![A-Za-z])[-+]?(nan|inf|infinity)(?![A-Za-z])", re.IGNORECASE)


def has_non_finite(value: Any) -> bool:
    """Whether a ROS message (or a part of it) holds a NaN or infinity, also as text (diagnostic values)."""
    if isinstance(value, float):
        return not math.isfinite(value)
    if isinstance(value, str):
        return _NON_FINITE_TEXT.search(value) is not None
    if isinstance(value, bool | int | bytes):
        return False
    if isinstance(value, np.ndarray):
        return value.dtype.kind == "f" and not bool(np.all(np.isfinite(value)))
    fields = getattr(value, "get_fields_and_field_types", None)
    if fields is not None:
        return any(has_non_finite(getattr(value, name)) for name in fields())
    try:
        return any(has_non_finite(element) for element in value)
    except TypeError:
        return False


_FIRST_REFUSAL = re.compile(r"\brefused (?!\d+ more )[^:]+: ")
_SUMMARY = re.compile(r"\brefused (\d+) more ")


def refusals_in_log(lines: Sequence[str]) -> int:
    """Refusals a RefusalCounter logged: one per first-of-its-reason line plus the count of each summary."""
    total = 0
    for line in lines:
        summary = _SUMMARY.search(line)
        if summary is not None:
            total += int(summary.group(1))
        elif _FIRST_REFUSAL.search(line):
            total += 1
    return total


def resident_memory_kb(pid: int) -> int | None:
    """VmRSS of a process [kB], None if it is gone (Linux /proc)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    match = re.search(r"^VmRSS:\s+(\d+) kB", status, re.MULTILINE)
    return int(match.group(1)) if match else None


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


# ------------------------------------------------------------------------------------------------
# Which node reads and writes what

NODE_INPUTS: dict[str, tuple[tuple[str, str], ...]] = {
    "simulator": (("motor_speed_cmd", "joint_state"),),
    "controller": (("odom", "odometry"), ("setpoint", "setpoint")),
    "identifier": (("motor_speeds", "joint_state"), ("odom", "odometry"), ("pose", "pose"), ("imu", "imu")),
    "mavlink_bridge": (("odom", "odometry"), ("imu", "imu"), ("motor_speeds", "joint_state")),
}
NODE_OUTPUTS: dict[str, tuple[str, ...]] = {
    "simulator": ("odom", "imu", "pose", "motor_speeds"),
    "controller": ("motor_speed_cmd",),
    "identifier": ("residuals", "identified_parameters", "diagnostics"),
    "mavlink_bridge": ("motor_speed_cmd", "setpoint"),
}


def _message_types() -> dict[str, type]:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    return {
        "odometry": Odometry,
        "imu": Imu,
        "pose": PoseStamped,
        "setpoint": PoseStamped,
        "joint_state": JointState,
        "odom": Odometry,
        "motor_speeds": JointState,
        "motor_speed_cmd": JointState,
        "residuals": Vector3Stamped,
        "identified_parameters": DiagnosticArray,
        "diagnostics": DiagnosticArray,
    }


@dataclass
class TopicReport:
    """What one flooded input topic did to the node."""

    node: str
    topic: str
    messages: int = 0
    refusals: int = 0
    crashed: bool = False
    non_finite_outputs: int = 0
    outputs: int = 0
    log_lines: int = 0
    tracebacks: int = 0
    rss_before_kb: int | None = None
    rss_after_kb: int | None = None
    labels: Counter[str] = field(default_factory=Counter)
    note: str = ""


class _OutputWatch:
    """Counts messages and non-finite ones on the node's outputs, and the node's /rosout lines."""

    def __init__(self, logger_name: str) -> None:
        self._lock = threading.Lock()
        self._logger_name = logger_name
        self.outputs = 0
        self.non_finite = 0
        self.log_lines: list[str] = []

    def output(self, message: Any) -> None:
        bad = has_non_finite(message)
        with self._lock:
            self.outputs += 1
            self.non_finite += bad

    def rosout(self, message: Any) -> None:
        if message.name == self._logger_name or message.name.startswith(self._logger_name + "."):
            with self._lock:
                self.log_lines.append(message.msg)

    def snapshot(self) -> tuple[int, int, int]:
        with self._lock:
            return self.outputs, self.non_finite, len(self.log_lines)

    def lines_since(self, start: int) -> list[str]:
        with self._lock:
            return self.log_lines[start:]


class _GroundStation:
    """A UDP socket where the MAVLink bridge sends its telemetry; counts messages with non-finite fields."""

    def __init__(self, port: int, watch: _OutputWatch) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.bind(("127.0.0.1", port))
        self._socket.settimeout(0.2)
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        self._watch = watch
        self._running = True
        self._thread = threading.Thread(target=self._receive, name="fuzz_gcs", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        while self._running:
            try:
                data = self._socket.recv(65535)
            except TimeoutError:
                continue
            except OSError:
                return
            for message in self._parser.parse_buffer(data) or []:
                self._watch.output(list(message.to_dict().values()))

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=2.0)
        self._socket.close()


def _topic_name(namespace: str, topic: str) -> str:
    return f"{namespace.rstrip('/')}/{topic}" if namespace.strip("/") else f"/{topic}"


def fuzz_node(
    node: str,
    *,
    namespace: str = "/",
    count: int = 10_000,
    seed: int = 1,
    rate_hz: float = 1000.0,
    pid: int | None = None,
    log_path: Path | None = None,
    gcs_port: int | None = None,
    settle_s: float = 11.0,
    discovery_timeout_s: float = 15.0,
) -> list[TopicReport]:
    """Flood each input topic of a running ``node`` in turn; one report per topic (module docstring)."""
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    if node not in NODE_INPUTS:
        raise CommandError(f"unknown node {node!r}; choose one of {', '.join(NODE_INPUTS)}")
    types = _message_types()
    logger_name = ".".join(part for part in (*namespace.strip("/").split("/"), node) if part)
    watch = _OutputWatch(logger_name)
    ground_station = _GroundStation(gcs_port, watch) if gcs_port else None
    reports: list[TopicReport] = []
    try:
        with background_node(f"multirotor_fuzz_{os.getpid()}") as probe:
            rosout_qos = QoSProfile(
                depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
            )
            probe.create_subscription(Log, "/rosout", watch.rosout, rosout_qos)
            for topic in NODE_OUTPUTS[node]:
                name = _topic_name(namespace, topic)
                probe.create_subscription(types[topic], name, watch.output, qos_profile_sensor_data)
            publishers = {
                topic: (kind, probe.create_publisher(types[kind], _topic_name(namespace, topic), 10))
                for topic, kind in NODE_INPUTS[node]
            }
            _wait_for_subscribers(publishers.values(), discovery_timeout_s)
            subscribed = {t: v for t, v in publishers.items() if v[1].get_subscription_count() > 0}
            if not subscribed:
                raise CommandError(
                    f"no subscriber on any input of {node} in namespace {namespace!r} "
                    f"within {discovery_timeout_s:g} s: is it running (and in this ROS domain)?"
                )

            def now_ns() -> int:
                return int(probe.get_clock().now().nanoseconds)

            for index, (topic, (kind, publisher)) in enumerate(publishers.items()):
                report = TopicReport(node, topic)
                reports.append(report)
                if topic not in subscribed:
                    report.note = "no subscriber (input not in use)"
                    continue
                items = hostile_messages(kind, count, seed + index)
                others = [(k, p) for t, (k, p) in subscribed.items() if t != topic]

                def background(others: list[tuple[str, Any]] = others) -> None:
                    for other_kind, other in others:
                        other.publish(
                            HostileMessage(other_kind, default_valid_message(other_kind), VALID).stamped(
                                now_ns()
                            )
                        )

                _flood_one(
                    report, items, publisher, now_ns, rate_hz, background, watch, pid, log_path, settle_s
                )
                if report.crashed:
                    break
    finally:
        if ground_station is not None:
            ground_station.close()
    return reports


def _wait_for_subscribers(publishers: Any, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(publisher.get_subscription_count() > 0 for _, publisher in publishers):
            return
        time.sleep(0.1)


def _flood_one(
    report: TopicReport,
    items: list[HostileMessage],
    publisher: Any,
    now_ns: Callable[[], int],
    rate_hz: float,
    background: Callable[[], None],
    watch: _OutputWatch,
    pid: int | None,
    log_path: Path | None,
    settle_s: float,
) -> None:
    report.rss_before_kb = resident_memory_kb(pid) if pid else None
    log_offset = log_path.stat().st_size if log_path and log_path.exists() else 0
    outputs_before, non_finite_before, lines_before = watch.snapshot()
    flood(items, publisher.publish, now_ns, rate_hz, background)
    report.messages = len(items)
    report.labels = Counter(item.label for item in items)
    # RefusalCounter summarises only when it refuses again after its period: wait, then one more NaN.
    time.sleep(settle_s)
    last = default_valid_message(items[0].kind)
    _poison(last, items[0].kind)
    publisher.publish(HostileMessage(items[0].kind, last, "non-finite value").stamped(now_ns()))
    time.sleep(1.0)
    outputs_after, non_finite_after, _ = watch.snapshot()
    lines = watch.lines_since(lines_before)
    report.outputs = outputs_after - outputs_before
    report.non_finite_outputs = non_finite_after - non_finite_before
    report.log_lines = len(lines)
    report.refusals = max(refusals_in_log(lines) - 1, 0)
    report.crashed = pid is not None and not process_alive(pid)
    report.rss_after_kb = resident_memory_kb(pid) if pid else None
    if log_path and log_path.exists():
        with open(log_path, "rb") as log:
            log.seek(log_offset)
            report.tracebacks = log.read().decode(errors="replace").count("Traceback")


def _poison(message: Any, kind: str) -> None:
    """Make a valid message certainly refused by every node: a NaN where each node reads."""
    if kind == "joint_state":
        message.velocity = [math.nan] * len(message.velocity)
    elif kind == "imu":
        message.angular_velocity.x = math.nan
    elif kind == "odometry":
        message.pose.pose.position.x = math.nan
    else:
        message.pose.position.x = math.nan


def format_table(reports: Sequence[TopicReport]) -> str:
    """The reports as a plain-text table, then the messages sent per label."""
    header = (
        "node",
        "topic",
        "messages",
        "refusals",
        "crashed",
        "tracebacks",
        "non-finite out",
        "outputs",
        "log lines",
        "RSS before [MB]",
        "RSS after [MB]",
    )
    rows = [header]
    rows += [
        (
            r.node,
            r.topic,
            str(r.messages),
            str(r.refusals),
            "yes" if r.crashed else "no",
            str(r.tracebacks),
            str(r.non_finite_outputs),
            str(r.outputs),
            str(r.log_lines),
            _megabytes(r.rss_before_kb),
            _megabytes(r.rss_after_kb),
        )
        for r in reports
        if not r.note
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = [
        "  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip() for row in rows
    ]
    lines += [f"{r.node}  {r.topic}: {r.note}" for r in reports if r.note]
    lines.append("")
    lines.append("messages sent per label:")
    for r in reports:
        if r.labels:
            parts = ", ".join(f"{label} {r.labels[label]}" for label in LABELS if r.labels[label])
            lines.append(f"  {r.node} {r.topic}: {parts}")
    return "\n".join(lines)


def _megabytes(kilobytes: int | None) -> str:
    return "-" if kilobytes is None else f"{kilobytes / 1024:.1f}"


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of the sub-command."""
    parser.add_argument("node", choices=tuple(NODE_INPUTS), help="which node runs (decides the topics)")
    parser.add_argument("--namespace", default="/", help="the node's namespace, e.g. /uav1")
    parser.add_argument("--count", type=int, default=10_000, help="messages per input topic")
    parser.add_argument("--seed", type=int, default=1, help="seed of the message mix")
    parser.add_argument("--rate", type=float, default=1000.0, help="messages per second (bursts excepted)")
    parser.add_argument("--pid", type=int, help="the node's process id: crash check and memory")
    parser.add_argument("--log", type=Path, help="the node's output file: tracebacks are counted in it")
    parser.add_argument("--gcs-port", type=int, help="listen here as the bridge's ground station (gcs_port)")
    parser.add_argument(
        "--settle", type=float, default=11.0, help="seconds to wait after each flood (the summary period)"
    )


def run(args: argparse.Namespace) -> int:
    """Flood, print the table; status 1 if the node crashed or emitted a non-finite value."""
    if args.count < 1 or not args.rate > 0:
        raise CommandError("--count must be at least 1 and --rate positive")
    reports = fuzz_node(
        args.node,
        namespace=args.namespace,
        count=args.count,
        seed=args.seed,
        rate_hz=args.rate,
        pid=args.pid,
        log_path=args.log,
        gcs_port=args.gcs_port,
        settle_s=args.settle,
    )
    print(format_table(reports))
    return int(any(r.crashed or r.non_finite_outputs or r.tracebacks for r in reports))
