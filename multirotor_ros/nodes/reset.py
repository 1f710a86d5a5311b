"""Starting over: the ``~/reset`` service and the ``simulation_reset`` topic of the controller and identifier.

``~/reset`` (std_srvs/srv/Trigger) is a node's own "forget and start over"; the response says what was
dropped. ``simulation_reset`` (std_msgs/msg/Header, relative, reliable, depth 10) is what the simulator
publishes when its own ``~/reset`` puts the vehicle back in its initial state: ``stamp`` the simulated
time of the reset, ``frame_id`` the vehicle's odometry frame. A node does the same reset on it as on its
service, so that one call on the simulator starts vehicle, controller and identifier over.

A ``simulation_reset`` is refused (counted and logged once per reason, refusals.py) when its frame is
not the frame of the node's state input (another vehicle's reset, through a wrong remapping; no frame
seen yet or an empty ``frame_id`` are not compared), when it is stamped more than the node's stamp
tolerance ahead of its clock (its stamp decides which state messages are dropped, :class:`ResetFence`,
and one from the far future would starve the node), or before the last reset taken.

Safety: both nodes spin on one thread (nodes/entry.py ``make_executor``: the EventsExecutor or the
single-threaded executor), so a reset runs between two callbacks, never in the middle of a refit or of a
control period.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from multirotor_ros.nodes.messages import stamp_to_ns
from multirotor_ros.plausibility import NS_PER_S, StampGate
from multirotor_ros.refusals import Refusal, RefusalCounter

RESET_SERVICE = "~/reset"
SIMULATION_RESET_TOPIC = "simulation_reset"
SIMULATION_RESET_QOS = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)


class ResetFence:
    """Drops the state messages stamped before a simulation reset: the old vehicle's, still in the queues.

    The reset and the state come on different topics, in either order: without the fence the first
    "next odometry" after a reset could be one from before it, and the vehicle, put back at its start,
    would be held at the pose it left. The fence opens at the first message stamped at or after the
    reset, or when the node's clock goes back by more than ``clock_back_tolerance_s`` below its reading
    at the reset (the simulator restarted its time with the vehicle: then every stamp is older).
    """

    def __init__(self, clock_back_tolerance_s: float):
        self._tolerance_ns = round(clock_back_tolerance_s * NS_PER_S)
        self._closed: tuple[int, int] | None = None  # (reset stamp, node's clock at the reset) [ns]

    def close(self, reset_stamp_ns: int, now_ns: int) -> None:
        """A simulation reset stamped ``reset_stamp_ns`` arrived at ``now_ns`` of the node's clock."""
        self._closed = (reset_stamp_ns, now_ns)

    def open(self) -> None:
        """A reset without a stamp (the node's own service): nothing to drop."""
        self._closed = None

    def stale(self, stamp_ns: int, now_ns: int) -> bool:
        """Whether a state message stamped ``stamp_ns``, arriving at ``now_ns``, is from before the reset."""
        if self._closed is None:
            return False
        reset_ns, clock_at_reset_ns = self._closed
        if stamp_ns >= reset_ns or now_ns < clock_at_reset_ns - self._tolerance_ns:
            self._closed = None
            return False
        return True


def offer_reset(
    node: Node,
    reset: Callable[[str, int | None], str],
    check_reset: Callable[[Header], Refusal | None],
    future_tolerance_s: float,
    now_ns: Callable[[], int | None],
) -> None:
    """Give ``node`` its ``~/reset`` service and its ``simulation_reset`` subscription.

    ``reset(cause, stamp_ns)`` starts the node over (``stamp_ns``: the simulation reset's stamp, None for
    the service) and returns one short line saying what it dropped, which the caller logs at INFO and
    the service sends back. ``check_reset`` refuses a reset message that is not this vehicle's.
    ``now_ns``: the node's clock, None before it has a time (simulated time before the first ``/clock``:
    nothing has been taken yet, and the reset's stamp is neither judged nor used).
    """
    refusals = RefusalCounter(node.get_logger().warning, SIMULATION_RESET_TOPIC)
    gate = StampGate(future_tolerance_s)

    def run(cause: str, stamp_ns: int | None) -> tuple[bool, str]:
        try:
            return True, reset(cause, stamp_ns)
        except Exception as error:  # noqa: BLE001 (a bug in a reset must not end a flying node's spin)
            line = f"reset failed: {type(error).__name__}: {error}"
            node.get_logger().error(line)
            node.get_logger().debug(traceback.format_exc())
            return False, line

    def on_service(_: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = run(RESET_SERVICE, None)
        return response

    def on_message(message: Header) -> None:
        now = now_ns()
        refusal = check_reset(message)
        if refusal is None and now is not None:
            refusal = gate.check(stamp_to_ns(message.stamp), now, SIMULATION_RESET_TOPIC)
        if refusal is not None:
            refusals.refuse(refusal.reason, refusal.detail)
            return
        run(SIMULATION_RESET_TOPIC, None if now is None else stamp_to_ns(message.stamp))

    node.create_service(Trigger, RESET_SERVICE, on_service)
    node.create_subscription(Header, SIMULATION_RESET_TOPIC, on_message, SIMULATION_RESET_QOS)


def frame_refusal(message: Header, state_frame: str) -> Refusal | None:
    """Why a ``simulation_reset`` is not for the vehicle whose state is in ``state_frame`` ('' = unknown)."""
    if message.frame_id and state_frame and message.frame_id != state_frame:
        return Refusal(
            "wrong frame", f"frame_id {message.frame_id[:40]!r}, this node's state is in {state_frame!r}"
        )
    return None
