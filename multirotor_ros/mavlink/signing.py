"""MAVLink 2 message signing: the key, the check of every incoming packet, and the refusal policy.

A signed MAVLink 2 packet ends with a 13-byte block: link id (1 byte), a 48-bit timestamp in units of
10 us since 2015-01-01 00:00 UTC, and the first 6 bytes of SHA-256(secret_key + packet without those 6
bytes). A signature is good when that hash matches and the timestamp is newer than the last one seen
on the same stream (link id, system id, component id), which stops replays; a stream seen for the
first time is accepted when its timestamp is at most one minute older than the newest one this side
knows (the rule of the MAVLink signing specification).

Policy when a key is set: every command must be signed with it. Unsigned packets are accepted only for
HEARTBEAT and RADIO_STATUS, which command nothing (ArduPilot accepts unsigned RADIO_STATUS for the same
reason; HEARTBEAT lets a ground station without the key still show up as connected). A packet with a
bad or replayed signature is refused whatever its type. Without a key, everything is accepted.

The key: 64 hexadecimal digits are the 32-byte key itself; any other text is a passphrase whose
SHA-256 is the key, as MAVProxy's ``signing setup PASSPHRASE`` derives it.
"""

from __future__ import annotations

import hashlib
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

SIGNATURE_BLOCK_LEN = 13
INCOMPAT_FLAG_SIGNED = 0x01
MAVLINK2_MARKER = 0xFD
SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00:00 UTC
SIGNING_TICKS_PER_S = 100_000  # timestamp unit: 10 us
NEW_STREAM_TOLERANCE_TICKS = 60 * SIGNING_TICKS_PER_S

MSG_ID_HEARTBEAT = 0
MSG_ID_RADIO_STATUS = 109
UNSIGNED_ALLOWED = frozenset({MSG_ID_HEARTBEAT, MSG_ID_RADIO_STATUS})


class SigningKeyError(ValueError):
    """A signing key that cannot be used."""


def parse_signing_key(text: str) -> bytes | None:
    """The 32-byte key of a ``signing_key`` parameter ('' = signing off); see the module docstring."""
    text = text.strip()
    if not text:
        return None
    if len(text) == 64:
        try:
            return bytes.fromhex(text)
        except ValueError:
            pass
    if not text.isascii() or not text.isprintable():
        raise SigningKeyError("signing_key must be 64 hex digits or a printable ASCII passphrase")
    return hashlib.sha256(text.encode("ascii")).digest()


def signing_timestamp_now(wall_time_s: float | None = None) -> int:
    """The current signing timestamp [10 us since 2015-01-01] from the wall clock."""
    now = time.time() if wall_time_s is None else wall_time_s
    return max(0, int((now - SIGNING_EPOCH_UNIX_S) * SIGNING_TICKS_PER_S))


def is_signed(packet: bytes | bytearray) -> bool:
    """Whether a MAVLink packet carries a signature block (not whether the signature is good)."""
    return len(packet) > 2 and packet[0] == MAVLINK2_MARKER and bool(packet[2] & INCOMPAT_FLAG_SIGNED)


@dataclass(frozen=True)
class Verdict:
    """What the policy decided about one packet: accepted, or refused with a counting reason."""

    accepted: bool
    reason: str = ""
    detail: str = ""


ACCEPTED = Verdict(True)


class SigningPolicy:
    """Checks the signature of every incoming packet against the key (see the module docstring)."""

    def __init__(self, key: bytes | None, clock: Callable[[], float] = time.time):
        if key is not None and len(key) != 32:
            raise SigningKeyError(f"a MAVLink signing key has 32 bytes, got {len(key)}")
        self.key = key
        self._clock = clock
        self._newest_timestamp = signing_timestamp_now(clock())
        self._stream_timestamps: dict[tuple[int, int, int], int] = {}

    @property
    def enabled(self) -> bool:
        """Whether a key is set."""
        return self.key is not None

    def outgoing_timestamp(self) -> int:
        """A timestamp to sign outgoing packets from: never behind the clock or the newest one seen."""
        self._newest_timestamp = max(self._newest_timestamp, signing_timestamp_now(self._clock()))
        return self._newest_timestamp

    def check(self, packet: bytes | bytearray, message_id: int) -> Verdict:
        """Accept or refuse one complete MAVLink packet (CRC already checked) of type ``message_id``."""
        if self.key is None:
            return ACCEPTED
        if not is_signed(packet):
            if message_id in UNSIGNED_ALLOWED:
                return ACCEPTED
            return Verdict(False, "unsigned command", f"message id {message_id} arrived without a signature")
        if len(packet) < 10 + SIGNATURE_BLOCK_LEN + 2:
            return Verdict(False, "bad signature", "packet too short to carry a signature")
        signature = bytes(packet[-6:])
        expected = hashlib.sha256(self.key + bytes(packet[:-6])).digest()[:6]
        if signature != expected:
            return Verdict(
                False, "bad signature", f"message id {message_id}: signature does not match the key"
            )
        link_id = packet[-SIGNATURE_BLOCK_LEN]
        low, high = struct.unpack("<IH", bytes(packet[-12:-6]))
        timestamp = low + (high << 32)
        stream = (link_id, packet[5], packet[6])
        last = self._stream_timestamps.get(stream)
        if last is not None and timestamp <= last:
            return Verdict(
                False, "replayed signature", f"stream {stream}: timestamp {timestamp} not after {last}"
            )
        if last is None and timestamp + NEW_STREAM_TOLERANCE_TICKS < self._newest_timestamp:
            return Verdict(
                False, "replayed signature", f"new stream {stream} starts more than a minute in the past"
            )
        self._stream_timestamps[stream] = timestamp
        self._newest_timestamp = max(self._newest_timestamp, timestamp)
        return ACCEPTED
