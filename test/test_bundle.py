"""Fleet bundles (nodes/bundle.py): what one writes the other reads, and broken ones are refused."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import MultiArrayDimension, UInt8MultiArray

from multirotor_ros.nodes.bundle import OdometryBundleWriter, bundle_cdr, bundle_entries
from multirotor_ros.nodes.cdr import OdometryWriter, odometry_fields_from_cdr
from multirotor_ros.nodes.messages import odometry_values_of_state, stamp_from_ns
from multirotor_ros.refusals import Refusal
from multirotor_ros.simulation.pacing import NS_PER_S

VEHICLES = 12
entries_strategy = st.lists(
    st.tuples(st.integers(0, VEHICLES - 1), st.binary(max_size=300)), max_size=VEHICLES
)


@given(entries_strategy)
def test_a_bundle_gives_back_its_entries_in_order(entries: list[tuple[int, bytes]]) -> None:
    assert bundle_entries(bundle_cdr(entries), VEHICLES) == entries


@given(entries_strategy)
def test_a_bundle_is_a_uint8_multi_array_as_rclpy_reads_and_writes_it(
    entries: list[tuple[int, bytes]],
) -> None:
    written = bundle_cdr(entries)
    message = deserialize_message(written, UInt8MultiArray)
    assert list(message.layout.dim) == [] and message.layout.data_offset == 0
    assert serialize_message(message) == written
    # What rclpy writes of the same array (ros2 topic pub, another language's node) reads the same.
    assert bundle_entries(serialize_message(UInt8MultiArray(data=bytes(message.data))), VEHICLES) == entries


def test_an_array_with_a_layout_is_read_through_rclpy() -> None:
    payload = bytes(deserialize_message(bundle_cdr([(2, b"abc")]), UInt8MultiArray).data)
    message = UInt8MultiArray(data=payload)
    message.layout.dim = [MultiArrayDimension(label="entries", size=1, stride=len(payload))]
    assert bundle_entries(serialize_message(message), VEHICLES) == [(2, b"abc")]


@pytest.mark.parametrize(
    ("payload", "vehicles", "said"),
    [
        (struct.pack("<II", 0, 4) + b"ab", 3, "entry at byte 0 says 4 bytes, 2 are left"),
        (struct.pack("<II", 3, 0), 3, "vehicle index 3 at byte 0; 3 vehicles"),
        (struct.pack("<II", 0, 0) + b"\x01\x02", 3, "2 bytes left at byte 8, no whole entry"),
    ],
)
def test_a_broken_bundle_is_refused_with_where_it_broke(payload: bytes, vehicles: int, said: str) -> None:
    refusal = bundle_entries(serialize_message(UInt8MultiArray(data=payload)), vehicles)
    assert isinstance(refusal, Refusal) and refusal.reason == "malformed bundle"
    assert refusal.detail == said


@given(st.binary(max_size=64))
def test_any_bytes_are_read_or_refused_never_raise(data: bytes) -> None:
    result = bundle_entries(data, VEHICLES)
    assert isinstance(result, (list, Refusal))


def test_bytes_that_are_no_uint8_multi_array_are_refused_as_such() -> None:
    refusal = bundle_entries(b"\x00\x01\x00\x00\xff\xff\xff\xff", VEHICLES)
    assert isinstance(refusal, Refusal) and refusal.detail.startswith("not a UInt8MultiArray")


def test_the_odometry_bundle_is_the_vehicles_own_odometries_bundled() -> None:
    writers = []
    for name in ("uav1", "uav10", "a"):  # frame names of different lengths: entries of different sizes
        template = Odometry()
        template.header.frame_id, template.child_frame_id = f"{name}/odom", f"{name}/base_link"
        template.pose.covariance[0] = 0.01
        writers.append(OdometryWriter(template))
    rng = np.random.default_rng(3)
    bundle_writer = OdometryBundleWriter(writers)
    for t_ns in (0, 4_000_000, 7 * NS_PER_S + 123):
        states = list(rng.standard_normal((3, 13)))
        stamp = stamp_from_ns(t_ns)
        own = [
            writer.write(stamp, odometry_values_of_state(x))
            for writer, x in zip(writers, states, strict=True)
        ]
        written = bundle_writer.write(stamp, states)
        assert written == bundle_cdr(enumerate(own))
        entries = bundle_entries(written, 3)
        assert not isinstance(entries, Refusal)
        for (_, message), x in zip(entries, states, strict=True):
            fields = odometry_fields_from_cdr(message)
            assert not isinstance(fields, Refusal) and fields.stamp_ns == t_ns
            assert fields.values == odometry_values_of_state(x)
