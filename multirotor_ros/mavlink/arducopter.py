"""The real ArduCopter SITL against the bridge, and a ground station that flies it (tests, benchmarks).

:class:`ArduCopterSitl` runs ArduPilot's ``arducopter`` built for SITL (``--model JSON``: it sends its
servo packets to the bridge's UDP port and waits for each answer) in a scratch directory, since it writes
``eeprom.bin``, ``logs/`` and ``terrain/`` where it runs, on ports no one else uses: ``-I N`` moves all of
its own (MAVLink on TCP 5760 + 10 N, RC input on UDP 5501 + 10 N, ...). Its defaults are ArduPilot's SITL
``copter.parm`` and a parameter file saying the frame the bridge derived for the airframe
(:mod:`.motor_order`: FRAME_CLASS and FRAME_TYPE), so SITL and bridge fly the same motor numbering.
The binary comes from ``$MULTIROTOR_ARDUCOPTER`` or the project's ``shared/flight_stacks/ardupilot``
(:func:`find_arducopter`); SOURCE.md there says how it was built.

:class:`GroundStation` speaks MAVLink to it as MAVProxy would: asks for the messages it needs at fixed
rates of simulated time, waits until ArduCopter reports its pre-arm checks passed (every check on, GPS
and EKF included), switches modes, arms, takes off, flies to a position, lands, and keeps the servo
outputs and positions it heard. Timeouts are wall-clock seconds.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.motor_order import Frame
from multirotor_ros.mavlink.sensors import Home

ARDUCOPTER_ENV = "MULTIROTOR_ARDUCOPTER"
SHARED_ARDUPILOT = Path(__file__).resolve().parents[3] / "shared" / "flight_stacks" / "ardupilot"
BASE_DEFAULTS = "copter.parm"  # ArduPilot's Tools/autotest/default_params/copter.parm, beside the binary
MAVLINK_BASE_PORT = 5760  # SERIAL0, TCP; SITL adds 10 per instance
RC_IN_BASE_PORT = 5501  # UDP
# SITL's gyro-rate pre-arm check wants about 720 Hz of frames or more; 1200 Hz is ArduCopter SITL's own.
SITL_RATE_HZ = 1200
DEFAULT_HOME = Home()  # PX4's and ArduPilot's usual SITL home; the bridge's default too
PREARM_CHECKS_PASS = mavlink2.MAV_SYS_STATUS_PREARM_CHECK  # SYS_STATUS health bit ArduPilot sets
# EKF_STATUS_REPORT flags GUIDED needs besides the pre-arm checks ("Arm: Need Position Estimate").
EKF_FLYING_FLAGS = (
    mavlink2.EKF_ATTITUDE
    | mavlink2.EKF_VELOCITY_HORIZ
    | mavlink2.EKF_VELOCITY_VERT
    | mavlink2.EKF_POS_HORIZ_ABS
    | mavlink2.EKF_POS_VERT_ABS
)


def find_arducopter() -> Path | None:
    """The SITL binary: ``$MULTIROTOR_ARDUCOPTER``, else the project's shared one; None if there is none."""
    given = os.environ.get(ARDUCOPTER_ENV)
    path = Path(given) if given else SHARED_ARDUPILOT / "arducopter"
    return path if path.is_file() and os.access(path, os.X_OK) else None


def free_instance(first: int = 30, last: int = 250) -> int:
    """A SITL instance number whose ports (TCP 5760..5763 + 10 N, UDP 5501 + 10 N) are free now.

    Tried in a random order: test runs started at the same moment then rarely pick the same one.
    """
    for instance in random.sample(range(first, last), last - first):
        if _free(MAVLINK_BASE_PORT + 10 * instance, 4, socket.SOCK_STREAM) and _free(
            RC_IN_BASE_PORT + 10 * instance, 1, socket.SOCK_DGRAM
        ):
            return instance
    raise RuntimeError(f"no SITL instance {first}..{last - 1} has its ports free")


def _free(port: int, count: int, kind: int) -> bool:
    for candidate in range(port, port + count):
        with socket.socket(socket.AF_INET, kind) as probe:
            try:
                probe.bind(("127.0.0.1", candidate))
            except OSError:
                return False
    return True


def frame_parameters(frame: Frame | None) -> dict[str, float]:
    """ArduPilot parameters that make SITL fly ``frame`` (FRAME_CLASS, FRAME_TYPE): a channel map's frame."""
    if frame is None or frame.flight_stack != "ardupilot":
        raise ValueError(f"{frame.title if frame else 'no frame'}: SITL needs an ArduPilot frame")
    return {name: float(value) for name, value in frame.parameters}


class ArduCopterSitl:
    """One ArduCopter SITL in ``workdir``, sending its frames to UDP ``json_port`` (module docstring)."""

    def __init__(
        self,
        binary: Path,
        workdir: Path,
        json_port: int,
        parameters: Mapping[str, float],
        *,
        speedup: float = 1.0,
        rate_hz: int = SITL_RATE_HZ,
        instance: int | None = None,
        home: Home = DEFAULT_HOME,
    ):
        self.binary = binary
        self.workdir = workdir
        self.json_port = json_port
        self.parameters = dict(parameters)
        self.speedup = speedup
        self.rate_hz = rate_hz
        self.instance = free_instance() if instance is None else instance
        self.home = home
        self.process: subprocess.Popen[bytes] | None = None
        self.starts = 0

    @property
    def mavlink_port(self) -> int:
        """SERIAL0: the ground station's TCP port."""
        return MAVLINK_BASE_PORT + 10 * self.instance

    @property
    def log_path(self) -> Path:
        """SITL's console output."""
        return self.workdir / "arducopter.log"

    def start(self, wipe: bool = True) -> ArduCopterSitl:
        """Start SITL; ``wipe`` forgets the parameters a previous run saved in eeprom.bin."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        shutil.copy(self.binary.parent / BASE_DEFAULTS, self.workdir / BASE_DEFAULTS)
        (self.workdir / "bridge.parm").write_text(
            "".join(f"{name} {value:g}\n" for name, value in self.parameters.items())
        )
        home = self.home
        command = [
            str(self.binary), "--model", "JSON:127.0.0.1", "--instance", str(self.instance),
            "--speedup", f"{self.speedup:g}", "--rate", str(self.rate_hz),
            "--sim-port-out", str(self.json_port), "--defaults", f"{BASE_DEFAULTS},bridge.parm",
            "--home", f"{home.latitude_deg},{home.longitude_deg},{home.altitude_m},0",
        ] + (["--wipe"] if wipe else [])  # fmt: skip
        with open(self.log_path, "ab") as log:
            self.process = subprocess.Popen(command, cwd=self.workdir, stdout=log, stderr=subprocess.STDOUT)
        self.starts += 1
        return self

    def stop(self, how: signal.Signals = signal.SIGTERM, timeout_s: float = 10.0) -> None:
        """End SITL (SIGKILL: as a crash would)."""
        process, self.process = self.process, None
        if process is None or process.poll() is not None:
            return
        process.send_signal(how)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout_s)

    def log_tail(self, lines: int = 30) -> str:
        """The end of SITL's console output (for failure messages)."""
        if not self.log_path.exists():
            return ""
        return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])

    def __enter__(self) -> ArduCopterSitl:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()


# Messages the ground station asks for, at rates of simulated time [Hz].
STREAMS_HZ = {
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mavlink2.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 2.0,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mavlink2.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 20.0,
}


@dataclass
class Heard:
    """What the ground station kept: (SITL time [s], message) per kind it records."""

    servo_outputs: list[tuple[float, Any]] = field(default_factory=list)
    positions: list[tuple[float, Any]] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)


class GroundStation:
    """ArduCopter's ground station over TCP; see the module docstring."""

    def __init__(self, port: int, timeout_s: float = 60.0):
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.link = mavutil.mavlink_connection(
                    f"tcp:127.0.0.1:{port}", source_system=255, retries=0, autoreconnect=False
                )
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        self.heard = Heard()
        self.latest: dict[str, Any] = {}
        self.wait(lambda: "HEARTBEAT" in self.latest, timeout_s, "a heartbeat")
        for message_id, rate_hz in STREAMS_HZ.items():
            self.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate_hz, check=False)

    # ------------------------------------------------------------------ receiving

    def _receive(self, wait_s: float) -> None:
        message = self.link.recv_match(blocking=True, timeout=wait_s)
        while message is not None:
            kind = message.get_type()
            self.latest[kind] = message
            if kind == "SERVO_OUTPUT_RAW":
                self.heard.servo_outputs.append((message.time_usec * 1e-6, message))
            elif kind == "GLOBAL_POSITION_INT":
                self.heard.positions.append((message.time_boot_ms * 1e-3, message))
            elif kind == "STATUSTEXT":
                self.heard.texts.append(message.text)
            message = self.link.recv_match(blocking=False)

    def wait(self, done: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Receive until ``done()``; TimeoutError naming ``what`` and the last texts otherwise."""
        deadline = time.monotonic() + timeout_s
        while not done():
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"no {what} within {timeout_s:g} s; ArduCopter said: {' | '.join(self.heard.texts[-8:])}"
                )
            self._receive(0.1)

    @property
    def time_s(self) -> float:
        """ArduCopter's time since boot [s] (simulated), from the newest position report."""
        return self.heard.positions[-1][0] if self.heard.positions else 0.0

    @property
    def relative_altitude_m(self) -> float:
        """Height above home [m] as ArduCopter estimates it."""
        position = self.latest.get("GLOBAL_POSITION_INT")
        return position.relative_alt * 1e-3 if position is not None else 0.0

    @property
    def armed(self) -> bool:
        """Whether the newest heartbeat says armed."""
        heartbeat = self.latest.get("HEARTBEAT")
        return bool(heartbeat and heartbeat.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)

    # ------------------------------------------------------------------ commanding

    def command(self, command: int, *params: float, check: bool = True, timeout_s: float = 10.0) -> int:
        """COMMAND_LONG; returns its COMMAND_ACK result (raises if ``check`` and not accepted)."""
        values = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.latest.pop("COMMAND_ACK", None)
        self.link.mav.command_long_send(
            self.link.target_system, self.link.target_component, command, 0, *values
        )
        self.wait(
            lambda: "COMMAND_ACK" in self.latest and self.latest["COMMAND_ACK"].command == command,
            timeout_s,
            f"answer to command {command}",
        )
        result = int(self.latest["COMMAND_ACK"].result)
        if check and result != mavlink2.MAV_RESULT_ACCEPTED:
            raise RuntimeError(
                f"command {command} refused ({result}); ArduCopter said: {' | '.join(self.heard.texts[-5:])}"
            )
        return result

    def wait_ready_to_arm(self, timeout_s: float) -> float:
        """Wait for the pre-arm checks (all on: GPS, EKF, ...) and an absolute EKF position; time then [s]."""

        def ready() -> bool:
            status, ekf = self.latest.get("SYS_STATUS"), self.latest.get("EKF_STATUS_REPORT")
            return bool(
                status
                and status.onboard_control_sensors_health & PREARM_CHECKS_PASS
                and ekf
                and ekf.flags & EKF_FLYING_FLAGS == EKF_FLYING_FLAGS
                and not ekf.flags & mavlink2.EKF_CONST_POS_MODE
            )

        self.wait(ready, timeout_s, "pre-arm checks passed")
        return self.time_s

    def set_mode(self, name: str, timeout_s: float = 10.0) -> None:
        """Switch flight mode (GUIDED, LAND, ...) and wait for the heartbeat to show it."""
        mode = self.link.mode_mapping()[name]
        self.command(mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)
        self.wait(lambda: self.latest["HEARTBEAT"].custom_mode == mode, timeout_s, f"mode {name}")

    def arm(self, timeout_s: float = 10.0) -> None:
        """Arm with every check on, and wait for the heartbeat to say armed."""
        self.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        self.wait(lambda: self.armed, timeout_s, "armed heartbeat")

    def take_off(self, altitude_m: float, timeout_s: float) -> float:
        """GUIDED take-off; returns ArduCopter's time [s] when within 0.1 m of ``altitude_m``."""
        self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
        self.wait(lambda: self.relative_altitude_m > altitude_m - 0.1, timeout_s, f"{altitude_m:g} m")
        return self.time_s

    def fly_to(self, north_m: float, east_m: float, altitude_m: float, yaw_ned_rad: float) -> None:
        """GUIDED: fly to a position from home (NED, altitude up) and face ``yaw_ned_rad``."""
        ignore_velocity_acceleration_yaw_rate = 0b0000_1001_1111_1000
        self.link.mav.set_position_target_local_ned_send(
            0, self.link.target_system, self.link.target_component, mavlink2.MAV_FRAME_LOCAL_NED,
            ignore_velocity_acceleration_yaw_rate, north_m, east_m, -altitude_m, 0, 0, 0, 0, 0, 0,
            yaw_ned_rad, 0,
        )  # fmt: skip

    def near(
        self, north_m: float, east_m: float, altitude_m: float, within_m: float, below_m_s: float
    ) -> bool:
        """Whether ArduCopter's estimate is within ``within_m`` of a position, slower than ``below_m_s``."""
        local = self.latest.get("LOCAL_POSITION_NED")
        if local is None:
            return False
        off = ((local.x - north_m) ** 2 + (local.y - east_m) ** 2 + (local.z + altitude_m) ** 2) ** 0.5
        speed = (local.vx**2 + local.vy**2 + local.vz**2) ** 0.5
        return off < within_m and speed < below_m_s

    def land(self, timeout_s: float) -> None:
        """LAND mode, and wait until ArduCopter disarms on the ground."""
        self.set_mode("LAND")
        self.wait(lambda: not self.armed, timeout_s, "disarm after landing")

    def close(self) -> None:
        """Close the connection."""
        with contextlib.suppress(OSError):
            self.link.close()


@dataclass(frozen=True)
class Mission:
    """The flight the tests and the benchmark fly: take off, hold, fly ``north_m`` turning, land."""

    altitude_m: float = 5.0  # [m] take-off height above home
    hold_s: float = 4.0  # [s] hover after reaching it
    north_m: float = 10.0  # [m] then this far north, at the same height,
    yaw_ned_rad: float = 1.5707963267948966  # turning to face east
    timeout_s: float = 120.0  # [s] wall clock, per phase


@dataclass(frozen=True)
class MissionTimes:
    """ArduCopter's times [s since its boot] at the end of each phase of a :class:`Mission`."""

    ready_s: float  # pre-arm checks passed
    armed_s: float  # armed in GUIDED, take-off commanded
    reached_s: float  # within 0.1 m of the take-off height
    held_s: float  # end of the hover
    arrived_s: float  # within 0.3 m of the target and slower than 0.2 m/s
    landed_s: float  # disarmed on the ground


def fly(station: GroundStation, mission: Mission = Mission()) -> MissionTimes:
    """Fly ``mission`` with ArduCopter's GUIDED and LAND modes; raise if a phase does not complete."""
    timeout = mission.timeout_s
    ready = station.wait_ready_to_arm(timeout)
    station.set_mode("GUIDED")
    station.arm()
    armed = station.time_s
    reached = station.take_off(mission.altitude_m, timeout)
    station.wait(lambda: station.time_s >= reached + mission.hold_s, timeout, "the end of the hover")
    held = station.time_s
    station.fly_to(mission.north_m, 0.0, mission.altitude_m, mission.yaw_ned_rad)
    station.wait(
        lambda: station.near(mission.north_m, 0.0, mission.altitude_m, 0.3, 0.2),
        timeout,
        f"arrival {mission.north_m:g} m north",
    )
    arrived = station.time_s
    station.land(timeout)
    return MissionTimes(ready, armed, reached, held, arrived, station.time_s)
