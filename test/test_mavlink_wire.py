"""MAVLink codec, signing policy and sockets: bad input is dropped and counted, never raised."""

from __future__ import annotations

import hashlib
import selectors
import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.mavlink.signing import (
    SigningKeyError,
    SigningPolicy,
    parse_signing_key,
    signing_timestamp_now,
)
from multirotor_ros.mavlink.wire import MavlinkCodec, SocketCallbacks, TcpServerEndpoint
from multirotor_ros.refusals import RefusalCounter

KEY = parse_signing_key("correct horse")


class _Sink:
    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data = bytes(data)


def packer(key: bytes | None = None, system: int = 255, timestamp: int | None = None) -> mavlink2.MAVLink:
    """A pymavlink sender; with ``key`` it signs like a ground station does."""
    mav = mavlink2.MAVLink(_Sink(), system, 190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 1
        mav.signing.timestamp = signing_timestamp_now() if timestamp is None else timestamp
    return mav


def pack(mav: mavlink2.MAVLink, message: object) -> bytes:
    mav.send(message)
    return mav.file.data


def setpoint(mav: mavlink2.MAVLink) -> object:
    return mav.set_position_target_local_ned_encode(
        0, 1, 1, 1, 0b110111111000, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0
    )


def heartbeat(mav: mavlink2.MAVLink) -> object:
    return mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)


# ---------------------------------------------------------------- signing keys


def test_passphrase_key_is_what_mavproxy_derives():
    assert parse_signing_key("correct horse") == hashlib.sha256(b"correct horse").digest()


def test_hex_key_is_taken_as_it_is_and_empty_means_off():
    assert parse_signing_key("ab" * 32) == bytes([0xAB] * 32)
    assert parse_signing_key("") is None
    assert parse_signing_key("   ") is None


def test_key_that_cannot_be_typed_is_refused():
    with pytest.raises(SigningKeyError, match="passphrase"):
        parse_signing_key("caf\u00e9")


# ---------------------------------------------------------------- codec


def test_good_packets_pass_and_garbage_between_them_is_counted():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals)
    mav = packer()
    data = pack(mav, heartbeat(mav)) + b"\x00\x11garbage\x42" + pack(mav, setpoint(mav))
    messages = codec.decode(data)
    assert [m.get_type() for m in messages] == ["HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED"]
    assert refusals.counts == {"corrupt bytes": 1}


def test_bad_crc_is_counted_and_the_next_packet_still_parses():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals)
    mav = packer()
    bad = bytearray(pack(mav, setpoint(mav)))
    bad[-1] ^= 0xFF
    messages = codec.decode(bytes(bad) + pack(mav, heartbeat(mav)))
    assert [m.get_type() for m in messages] == ["HEARTBEAT"]
    assert refusals.counts == {"bad CRC": 1}


def test_truncated_datagram_is_counted_and_does_not_poison_the_next_one():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals)
    mav = packer()
    full = pack(mav, setpoint(mav))
    assert codec.decode(full[: len(full) // 2], whole_datagram=True) == []
    assert refusals.counts == {"truncated packet": 1}
    assert [m.get_type() for m in codec.decode(full, whole_datagram=True)] == [
        "SET_POSITION_TARGET_LOCAL_NED"
    ]


def test_stream_keeps_a_partial_packet_for_the_next_read():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals)
    mav = packer()
    full = pack(mav, setpoint(mav))
    assert codec.decode(full[:10]) == []
    assert [m.get_type() for m in codec.decode(full[10:])] == ["SET_POSITION_TARGET_LOCAL_NED"]
    assert refusals.total == 0


def test_unknown_message_id_is_counted():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals)
    mav = packer()
    packet = bytearray(pack(mav, heartbeat(mav)))
    # Message id 0 -> 60000 (no such message) with a CRC the parser accepts: unknown ids cannot be
    # checked (the CRC extra byte is per message type), so the parser reports them as unknown.
    packet[7:10] = (60000).to_bytes(3, "little")
    assert codec.decode(bytes(packet)) == []
    assert refusals.counts == {"unknown message id": 1}


def test_without_a_key_everything_is_accepted_signed_or_not():
    codec = MavlinkCodec(1, 1, RefusalCounter())
    signed = packer(KEY)
    assert len(codec.decode(pack(signed, setpoint(signed)) + pack(packer(), setpoint(packer())))) == 2


def test_with_a_key_commands_must_be_signed_with_it():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals, SigningPolicy(KEY))
    good = packer(KEY)
    wrong_key = packer(parse_signing_key("wrong"))
    unsigned = packer()
    assert [m.get_type() for m in codec.decode(pack(good, setpoint(good)))] == [
        "SET_POSITION_TARGET_LOCAL_NED"
    ]
    assert codec.decode(pack(unsigned, setpoint(unsigned))) == []
    assert codec.decode(pack(wrong_key, setpoint(wrong_key))) == []
    assert refusals.counts == {"unsigned command": 1, "bad signature": 1}


def test_with_a_key_an_unsigned_heartbeat_is_still_accepted():
    codec = MavlinkCodec(1, 1, RefusalCounter(), SigningPolicy(KEY))
    unsigned = packer()
    assert [m.get_type() for m in codec.decode(pack(unsigned, heartbeat(unsigned)))] == ["HEARTBEAT"]


def test_a_replayed_signed_packet_is_refused():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals, SigningPolicy(KEY))
    good = packer(KEY)
    packet = pack(good, setpoint(good))
    assert len(codec.decode(packet)) == 1
    assert codec.decode(packet) == []
    assert refusals.counts == {"replayed signature": 1}


def test_a_new_stream_from_long_ago_is_refused():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals, SigningPolicy(KEY))
    old = packer(KEY, timestamp=signing_timestamp_now() - 3600 * 100_000)  # an hour old
    assert codec.decode(pack(old, setpoint(old))) == []
    assert refusals.counts == {"replayed signature": 1}


def test_tampered_signed_packet_fails_its_crc_or_its_signature():
    refusals = RefusalCounter()
    codec = MavlinkCodec(1, 1, refusals, SigningPolicy(KEY))
    good = packer(KEY)
    packet = bytearray(pack(good, setpoint(good)))
    packet[-3] ^= 0x01  # inside the signature: CRC still good
    assert codec.decode(bytes(packet)) == []
    assert refusals.counts == {"bad signature": 1}


def test_outgoing_packets_are_signed_so_a_keyed_receiver_accepts_them():
    sender = MavlinkCodec(1, 1, RefusalCounter(), SigningPolicy(KEY))
    receiver = mavlink2.MAVLink(None)
    receiver.signing.secret_key = KEY  # pymavlink then refuses anything not signed with the key
    message = receiver.decode(bytearray(sender.encode(heartbeat(sender.mav))))
    assert message.get_type() == "HEARTBEAT"
    assert message._signed


# ---------------------------------------------------------------- TCP endpoint


def test_tcp_endpoint_serves_one_peer_and_refuses_a_second():
    refusals = RefusalCounter()
    events: list[str] = []
    received: list[bytes] = []
    endpoint = TcpServerEndpoint(
        "127.0.0.1",
        0,
        SocketCallbacks(
            lambda a: events.append("connect"), received.append, lambda why: events.append("gone")
        ),
        refusals,
    )
    selector = selectors.DefaultSelector()
    endpoint.attach(lambda s, cb: selector.register(s, selectors.EVENT_READ, cb), selector.unregister)

    def pump(seconds: float = 0.3) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            for key, _ in selector.select(0.02):
                key.data()

    try:
        first = socket.create_connection(("127.0.0.1", endpoint.port))
        pump()
        second = socket.create_connection(("127.0.0.1", endpoint.port))
        pump()
        assert second.recv(10) == b""  # closed by the endpoint
        first.sendall(b"hello")
        pump()
        assert received == [b"hello"] and refusals.counts == {"second peer": 1}
        first.close()
        pump()
        third = socket.create_connection(("127.0.0.1", endpoint.port))  # a reconnect is welcome
        pump()
        assert events == ["connect", "gone", "connect"]
        third.close()
        second.close()
    finally:
        endpoint.close()
        selector.close()
