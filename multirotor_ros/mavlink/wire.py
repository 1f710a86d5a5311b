"""MAVLink on sockets: a codec that never raises on bad bytes, TCP and UDP endpoints, refusal counts.

Everything here is non-blocking and driven by one :class:`selectors.BaseSelector` (see
:mod:`multirotor_ros.mavlink.bridge`): an endpoint registers its sockets with a callback and the
bridge's loop calls it when bytes arrive.

Bad input is dropped and counted, never raised: corrupt bytes between packets, a bad CRC, a packet
cut short, an unknown message id, a refused signature (:mod:`multirotor_ros.mavlink.signing`), a
second peer on a port that already has one. A :class:`~multirotor_ros.refusals.RefusalCounter`
holds the counts and logs the first of each reason, then throttled summaries.
"""

from __future__ import annotations

import logging
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.messages import fit_to_wire
from multirotor_ros.mavlink.signing import SigningPolicy
from multirotor_ros.refusals import RefusalCounter

_LOGGER = logging.getLogger(__name__)

Message = Any  # a pymavlink MAVLink_message; pymavlink has no useful static types for its messages


class _Collector:
    """The file-like object pymavlink's MAVLink writes packed bytes to."""

    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data = bytes(data)


def _new_parser() -> mavlink2.MAVLink:
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True  # bad bytes come back as BAD_DATA messages instead of exceptions
    return parser


class MavlinkCodec:
    """Bytes <-> MAVLink 2 messages for one link, with signing (both ways) and refusal counting."""

    def __init__(
        self,
        system_id: int,
        component_id: int,
        refusals: RefusalCounter,
        signing: SigningPolicy | None = None,
        link_id: int = 0,
    ):
        self.refusals = refusals
        self.signing = signing or SigningPolicy(None)
        self._parser = _new_parser()
        self._sink = _Collector()
        self._packer = mavlink2.MAVLink(self._sink, system_id, component_id)
        if self.signing.key is not None:
            self._packer.signing.secret_key = self.signing.key
            self._packer.signing.sign_outgoing = True
            self._packer.signing.link_id = link_id
        self.messages_in = 0
        self.messages_out = 0
        self.values_clamped = 0

    @property
    def mav(self) -> mavlink2.MAVLink:
        """The pymavlink object whose ``*_encode`` methods build messages for :meth:`encode`."""
        return self._packer

    def encode(self, message: Message) -> bytes:
        """The wire bytes of one message (signed when a key is set), every field fitted to its range."""
        clamped = fit_to_wire(message)
        if clamped and not self.values_clamped:
            _LOGGER.warning(
                "%s: a value outside its MAVLink field's range was clamped (further ones are only counted)",
                message.get_type(),
            )
        self.values_clamped += clamped
        if self.signing.enabled:
            self._packer.signing.timestamp = max(
                self._packer.signing.timestamp, self.signing.outgoing_timestamp()
            )
        self._packer.send(message)
        self.messages_out += 1
        return self._sink.data

    def decode(self, data: bytes, whole_datagram: bool = False) -> list[Message]:
        """The good messages in ``data``; everything else is refused and counted.

        A stream (TCP) keeps an incomplete packet for the next call. A datagram (UDP,
        ``whole_datagram``) must hold whole packets: a partial one at its end is a truncated packet.
        """
        accepted = []
        try:
            parsed = self._parser.parse_buffer(data) or []
        except mavlink2.MAVError as error:  # robust parsing reports almost everything as BAD_DATA instead
            self.refusals.refuse("corrupt bytes", str(error))
            self._parser = _new_parser()
            parsed = []
        for message in parsed:
            kind = message.get_type()
            if kind == "BAD_DATA":
                reason = message.reason
                if "CRC" in reason:
                    self.refusals.refuse("bad CRC", reason)
                elif "length" in reason:
                    self.refusals.refuse("truncated packet", reason)
                else:
                    self.refusals.refuse("corrupt bytes", f"{reason} ({len(message.data)} bytes)")
                continue
            if kind.startswith("UNKNOWN_"):
                self.refusals.refuse("unknown message id", f"message id {message.get_msgId()}")
                continue
            verdict = self.signing.check(message.get_msgbuf(), message.get_msgId())
            if not verdict.accepted:
                self.refusals.refuse(verdict.reason, verdict.detail)
                continue
            self.messages_in += 1
            accepted.append(message)
        if whole_datagram and self._parser.buf_len() > 0:
            self.refusals.refuse(
                "truncated packet", f"{self._parser.buf_len()} bytes left at the end of a datagram"
            )
            self._parser = _new_parser()
        return accepted

    def reset(self) -> None:
        """Forget a partial packet (a new connection starts a new byte stream)."""
        self._parser = _new_parser()


@dataclass
class SocketCallbacks:
    """What a TCP server endpoint tells its owner."""

    on_connect: Callable[[tuple[str, int]], None]
    on_data: Callable[[bytes], None]
    on_disconnect: Callable[[str], None]


class TcpServerEndpoint:
    """Listens on host:port and serves one peer at a time; a second peer is refused (closed at once)."""

    SEND_TIMEOUT_S = 2.0

    def __init__(self, host: str, port: int, callbacks: SocketCallbacks, refusals: RefusalCounter):
        self.callbacks = callbacks
        self.refusals = refusals
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((host, port))
        except OSError as error:
            self.listener.close()
            raise OSError(f"cannot listen on TCP {host}:{port}: {error.strerror}") from error
        self.listener.listen(4)
        self.listener.setblocking(False)
        self.peer: socket.socket | None = None
        self.peer_address: tuple[str, int] | None = None
        self._register: Callable[[socket.socket, Callable[[], None]], None] | None = None
        self._unregister: Callable[[socket.socket], None] | None = None

    @property
    def port(self) -> int:
        """The port actually bound (useful when 0 was asked for)."""
        return int(self.listener.getsockname()[1])

    def attach(
        self,
        register: Callable[[socket.socket, Callable[[], None]], None],
        unregister: Callable[[socket.socket], None],
    ) -> None:
        """Hook the sockets into the bridge's selector."""
        self._register, self._unregister = register, unregister
        register(self.listener, self._accept)

    def _accept(self) -> None:
        try:
            connection, address = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        if self.peer is not None:
            connection.close()
            self.refusals.refuse(
                "second peer", f"{address[0]}:{address[1]} while {self.peer_address} is connected"
            )
            return
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # Blocking, with the kernel's send timeout rather than Python's socket timeout: Python polls
        # before every call on a socket with a timeout (two system calls per send, per step). Reads
        # only happen when the selector says there is data; a peer that stops reading for
        # SEND_TIMEOUT_S makes sendall fail, and counts as gone.
        connection.setblocking(True)
        seconds = int(self.SEND_TIMEOUT_S)
        microseconds = int((self.SEND_TIMEOUT_S - seconds) * 1e6)
        connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", seconds, microseconds))
        self.peer, self.peer_address = connection, address
        assert self._register is not None
        self._register(connection, self._read)
        self.callbacks.on_connect(address)

    def _read(self) -> None:
        assert self.peer is not None
        try:
            data = self.peer.recv(65536)
        except OSError as error:
            self.drop_peer(f"receive failed: {error}")
            return
        if not data:
            self.drop_peer("peer closed the connection")
            return
        self.callbacks.on_data(data)

    def send(self, data: bytes) -> bool:
        """Send to the peer; False (and the peer dropped) if there is none or it does not take the bytes."""
        if self.peer is None:
            return False
        try:
            self.peer.sendall(data)
        except OSError as error:
            self.drop_peer(f"send failed: {error}")
            return False
        return True

    def drop_peer(self, why: str) -> None:
        """Close the peer's connection and tell the owner."""
        if self.peer is None:
            return
        if self._unregister is not None:
            self._unregister(self.peer)
        self.peer.close()
        self.peer, self.peer_address = None, None
        self.callbacks.on_disconnect(why)

    def close(self) -> None:
        """Close the peer and the listening socket."""
        if self.peer is not None:
            if self._unregister is not None:
                self._unregister(self.peer)
            self.peer.close()
            self.peer = None
        if self._unregister is not None:
            self._unregister(self.listener)
        self.listener.close()


# Linux's SO_TIMESTAMPNS (asm-generic/socket.h; Python does not name it) and the struct timespec it
# delivers on 64-bit Linux: seconds, nanoseconds.
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("qq")
_TIMESTAMP_SPACE = socket.CMSG_SPACE(_TIMESPEC.size)


def _arrival_ns(ancillary: list[tuple[int, int, bytes]]) -> int:
    """The kernel's receive time [ns, CLOCK_REALTIME] in recvmsg's ancillary data (0 if absent)."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            seconds, nanoseconds = _TIMESPEC.unpack(data[: _TIMESPEC.size])
            return seconds * 1_000_000_000 + nanoseconds
    return 0


class UdpEndpoint:
    """A bound UDP socket; ``on_datagram(data, address)`` for every datagram received.

    With ``arrival_times`` the kernel stamps each datagram as it arrives (SO_TIMESTAMPNS, CLOCK_REALTIME
    nanoseconds, :attr:`arrival_ns` while ``on_datagram`` runs): the time an answer took counts from
    there, including any wait in the socket's queue while the loop was busy.
    """

    def __init__(
        self,
        host: str,
        port: int,
        on_datagram: Callable[[bytes, tuple[str, int]], None],
        arrival_times: bool = False,
    ):
        self.on_datagram = on_datagram
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.bind((host, port))
        except OSError as error:
            self.socket.close()
            raise OSError(f"cannot bind UDP {host}:{port}: {error.strerror}") from error
        self.socket.setblocking(False)
        self.arrival_times = arrival_times
        if arrival_times:
            self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.arrival_ns = 0
        self._unregister: Callable[[socket.socket], None] | None = None

    @property
    def port(self) -> int:
        """The port actually bound."""
        return int(self.socket.getsockname()[1])

    def attach(
        self,
        register: Callable[[socket.socket, Callable[[], None]], None],
        unregister: Callable[[socket.socket], None],
    ) -> None:
        """Hook the socket into the bridge's selector."""
        self._unregister = unregister
        register(self.socket, self._read)

    def _read(self) -> None:
        # Drain what is queued: a burst of datagrams costs one wake-up.
        for _ in range(64):
            if not self._receive_one():
                return

    def _receive_one(self) -> bool:
        """Handle what is queued first (a datagram, or an error to skip); False when nothing is."""
        try:
            if self.arrival_times:
                data, ancillary, _, address = self.socket.recvmsg(65536, _TIMESTAMP_SPACE)
                self.arrival_ns = _arrival_ns(ancillary)
            else:
                data, address = self.socket.recvfrom(65536)
        except (BlockingIOError, InterruptedError):
            return False
        except OSError:
            # e.g. ECONNREFUSED reported for an earlier send to a closed port: not input, skip it.
            return True
        self.on_datagram(data, address)
        return True

    def wait_briefly(self, seconds: float) -> bool:
        """Poll for a datagram for up to ``seconds`` without sleeping; handle it and return True if one came.

        For a peer known to answer within microseconds (a lockstep flight stack): waking from the
        selector's sleep costs more than the peer's own turn.
        """
        deadline = time.perf_counter() + seconds
        while not self._receive_one():
            if time.perf_counter() > deadline:
                return False
        return True

    def send(self, data: bytes, address: tuple[str, int]) -> bool:
        """Send one datagram; False when the system refuses (nobody listening is not an error for UDP)."""
        try:
            self.socket.sendto(data, address)
        except OSError:
            return False
        return True

    def close(self) -> None:
        """Close the socket."""
        if self._unregister is not None:
            self._unregister(self.socket)
        self.socket.close()
