"""The MAVLink bridge without ROS: one flight-stack link, one ground-station link, one event loop.

:class:`MavlinkBridge` owns the sockets (:mod:`.wire`), the flight-stack session (:mod:`.px4` or
:mod:`.ardupilot`), the ground-station link (:mod:`.gcs`) and a :class:`~.vehicle.Simulation`. Its
:meth:`~MavlinkBridge.run` loop waits on every socket at once with a selector and wakes for the next
periodic message; nothing in it blocks on ROS. The node (:mod:`multirotor_ros.nodes.mavlink_bridge`)
runs that loop in a thread of its own and connects the callbacks to topics; tests and the benchmark
drive the same class without ROS.

See :mod:`multirotor_ros.mavlink` for the two modes (internal physics / external physics).
"""

from __future__ import annotations

import logging
import math
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import ArduPilotConfig, ArduPilotSession
from multirotor_ros.mavlink.gcs import GroundStationConfig, GroundStationLink, Setpoint
from multirotor_ros.mavlink.px4 import Px4Config, Px4Session
from multirotor_ros.mavlink.sensors import Home, SensorModel
from multirotor_ros.mavlink.signing import SigningPolicy
from multirotor_ros.mavlink.vehicle import Physics, Simulation, VehicleState
from multirotor_ros.model.airframe import GRAVITY_M_S2
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.realtime import start_up_frozen
from multirotor_ros.refusals import RefusalCounter

_LOGGER = logging.getLogger(__name__)

FlightStack = Literal["px4", "ardupilot", "none"]
FLIGHT_STACKS: tuple[FlightStack, ...] = ("px4", "ardupilot", "none")
# Deferred work (:meth:`MavlinkBridge.defer`) waits for a moment without input, but never more than this
# many items: a flight stack that always has its next frame waiting still gets the graph's messages.
MAX_DEFERRED = 16


@dataclass(frozen=True)
class BridgeConfig:
    """Which flight stack, where everything listens, and the ground station (None = no ground station)."""

    flight_stack: FlightStack = "px4"
    px4: Px4Config = Px4Config()
    ardupilot: ArduPilotConfig = ArduPilotConfig()
    ground_station: GroundStationConfig | None = GroundStationConfig()
    home: Home = Home()

    def __post_init__(self) -> None:
        if self.flight_stack not in FLIGHT_STACKS:
            raise ValueError(f"flight_stack {self.flight_stack!r}: choose one of {', '.join(FLIGHT_STACKS)}")


@dataclass
class BridgeOutputs:
    """Where the bridge's results go (the node: publishers; tests: recorders)."""

    motor_command: Callable[[FloatArray, float], None]  # rotor speed commands [rad/s], simulated time [s]
    vehicle_state: Callable[[VehicleState], None]  # internal physics: every new state, after its answer
    setpoint: Callable[[Setpoint], None]  # from the ground station, world ENU


class MavlinkBridge:
    """See the module docstring.

    One thread runs the loop; other threads may call update_external_state() and run_in_loop().
    """

    def __init__(
        self,
        config: BridgeConfig,
        channels: RotorChannels,
        physics: Physics | None,
        outputs: BridgeOutputs,
        refusals: RefusalCounter | None = None,
        signing: SigningPolicy | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        if physics is not None and config.flight_stack == "none":
            raise ValueError(
                "internal physics needs a flight stack to step it: use external physics without one"
            )
        self.config = config
        self.clock = clock
        self.refusals = refusals or RefusalCounter()
        self.sensors = SensorModel(config.home)
        self.simulation = Simulation(
            channels.airframe.n_rotors, GRAVITY_M_S2, physics, outputs.motor_command, outputs.vehicle_state
        )
        self._selector = selectors.DefaultSelector()
        self._wake_reader, self._wake_writer = socket.socketpair()
        self._wake_reader.setblocking(False)
        self._wake_writer.setblocking(False)
        self._register(self._wake_reader, self._on_wake)
        self._pending_lock = threading.Lock()
        self._pending_state: VehicleState | None = None
        self._pending_work: list[Callable[[], None]] = []
        self._deferred: deque[Callable[[], None]] = deque()
        self.px4: Px4Session | None = None
        self.ardupilot: ArduPilotSession | None = None
        self.gcs: GroundStationLink | None = None
        try:
            if config.flight_stack == "px4":
                self.px4 = Px4Session(
                    config.px4, self.simulation, channels, self.sensors, self.refusals, clock
                )
                self.px4.endpoint.attach(self._register, self._unregister)
            elif config.flight_stack == "ardupilot":
                self.ardupilot = ArduPilotSession(
                    config.ardupilot,
                    self.simulation,
                    channels,
                    self.refusals,
                    self._on_flight_stack_restart,
                    clock,
                )
                self.ardupilot.endpoint.attach(self._register, self._unregister)
            if config.ground_station is not None:
                self.gcs = GroundStationLink(
                    config.ground_station,
                    self.sensors,
                    channels.airframe.n_rotors,
                    signing or SigningPolicy(None),
                    self.refusals,
                    outputs.setpoint,
                    clock,
                )
                # Armed: a rotor turns clearly faster than idle (5 % of the range: above ESC noise).
                idle = float(channels.idle_speeds_rad_s.max())
                top = channels.motor_map.speed_max_rad_s
                self.gcs.set_armed_speed(idle + 0.05 * (top - idle))
                self.gcs.endpoint.attach(self._register, self._unregister)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ sockets

    def _register(self, sock: socket.socket, callback: Callable[[], None]) -> None:
        self._selector.register(sock, selectors.EVENT_READ, callback)

    def _unregister(self, sock: socket.socket) -> None:
        try:
            self._selector.unregister(sock)
        except (KeyError, ValueError):
            pass  # already gone (closed twice on shutdown)

    @property
    def flight_stack_port(self) -> int | None:
        """The port the flight stack connects to (useful when 0 was configured)."""
        if self.px4 is not None:
            return self.px4.endpoint.port
        if self.ardupilot is not None:
            return self.ardupilot.endpoint.port
        return None

    # ------------------------------------------------------------------ external state

    def update_external_state(self, state: VehicleState) -> None:
        """A new state from the simulator node (external mode); safe to call from any thread."""
        with self._pending_lock:
            self._pending_state = state
        self._wake()

    def run_in_loop(self, work: Callable[[], None]) -> None:
        """Have the loop's thread run ``work`` between two messages (it owns the physics); any thread."""
        with self._pending_lock:
            self._pending_work.append(work)
        self._wake()

    def defer(self, work: Callable[[], None]) -> None:
        """Have the loop run ``work`` once no input waits (from the loop's thread: the outputs' callbacks).

        For what must not hold up the flight stack's next frame: the node publishing to ROS after an
        answer (an odom message costs more than SITL's own frame) runs while the flight stack works on
        its frame, and when that frame arrives first it is answered before the rest is published.
        """
        self._deferred.append(work)

    def _wake(self) -> None:
        try:
            self._wake_writer.send(b"\0")
        except (BlockingIOError, InterruptedError):
            pass  # the loop has wake-ups queued already and will find what is pending

    def _on_wake(self) -> None:
        try:
            while self._wake_reader.recv(4096):
                pass
        except (BlockingIOError, InterruptedError):
            pass
        with self._pending_lock:
            state, self._pending_state = self._pending_state, None
            work, self._pending_work = self._pending_work, []
        for item in work:
            self._guarded(item, default=None)
        if state is None or self.simulation.internal:
            return
        self.simulation.update(state)
        if self.px4 is not None:
            self.px4.on_external_state(state)
        if self.ardupilot is not None:
            self.ardupilot.on_external_state(state)

    def _on_flight_stack_restart(self) -> None:
        if self.px4 is not None:
            self.px4.restart_time()

    # ------------------------------------------------------------------ loop

    def spin_once(self, max_wait_s: float = 0.1) -> None:
        """Do what is due, then wait up to ``max_wait_s`` for input and handle it."""
        now = self.clock()
        next_due = math.inf
        if self.px4 is not None:
            next_due = min(next_due, self._guarded(self.px4.poll, now, default=now + max_wait_s))
        if self.gcs is not None and self.simulation.known:
            next_due = min(
                next_due, self._guarded(self.gcs.poll, now, self.simulation.latest, default=now + max_wait_s)
            )
        timeout = min(max(next_due - self.clock(), 0.0), max_wait_s)
        if self.ardupilot is not None and self.ardupilot.busy_wait_left_s() > 0.0:
            # SITL's next frame is expected within the busy wait: look without sleeping, then poll below.
            timeout = 0.0
        for key, _ in self._selector.select(timeout):
            self._guarded(key.data, default=None)
        deferred = self._deferred
        while deferred and (len(deferred) > MAX_DEFERRED or not self._selector.select(0)):
            self._guarded(deferred.popleft(), default=None)
        if self.ardupilot is not None:
            self._guarded(self.ardupilot.wait_for_next_frame, default=None)

    def _guarded(self, work: Callable[..., Any], *args: Any, default: Any) -> Any:
        try:
            return work(*args)
        except Exception as error:  # noqa: BLE001 - one failure must not end the loop
            # A bug, not bad input: say so with the traceback, count it, keep serving the links.
            _LOGGER.exception("MAVLink bridge: internal error")
            self.refusals.refuse("internal error", f"{type(error).__name__}: {error}")
            return default

    def run(self, stop: threading.Event, max_wait_s: float = 0.1) -> None:
        """Loop until ``stop`` is set."""
        with start_up_frozen():  # a full collection would take tens of milliseconds mid-lockstep
            while not stop.is_set():
                self.spin_once(max_wait_s)

    def close(self) -> None:
        """Close every socket."""
        for link in (self.px4, self.ardupilot, self.gcs):
            if link is not None:
                link.close()
        self._unregister(self._wake_reader)
        self._wake_reader.close()
        self._wake_writer.close()
        self._selector.close()


class BridgeThread:
    """Runs a bridge's loop in a thread of its own (``with BridgeThread(bridge):``); closes it at the end."""

    def __init__(self, bridge: MavlinkBridge, name: str = "mavlink"):
        self.bridge = bridge
        self._stop = threading.Event()
        self._thread = threading.Thread(target=bridge.run, args=(self._stop,), name=name, daemon=True)

    def start(self) -> BridgeThread:
        """Start the loop."""
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the loop and close the bridge's sockets."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        self.bridge.close()

    def __enter__(self) -> MavlinkBridge:
        self.start()
        return self.bridge

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
