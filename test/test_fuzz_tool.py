"""The hostile-message generator and the helpers of `multirotor fuzz` (multirotor_ros/cli/fuzz.py), no DDS."""

from __future__ import annotations

import math
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped

from multirotor_ros.cli.fuzz import (
    KINDS,
    LABELS,
    NS_PER_S,
    VALID,
    HostileMessage,
    TopicReport,
    flood,
    format_table,
    has_non_finite,
    hostile_messages,
    refusals_in_log,
)
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.messages import (
    imu_from_message,
    pose_from_message,
    rotor_speeds_from_joint_state,
    setpoint_from_pose,
    stamp_to_ns,
    state_from_odometry,
)
from multirotor_ros.refusals import Refusal

COUNT = 3000
# Every kind gets the number corruptions, the four stamp cases, bursts and valid messages; the rest per kind.
COMMON_LABELS = {
    VALID,
    "burst",
    "non-finite value",
    "huge value",
    "stamp zero",
    "stamp in the past",
    "stamp an hour ahead",
    "stamp at 2^31-1 s",
}
EXPECTED_LABELS = {
    "odometry": COMMON_LABELS | {"invalid quaternion", "wrong frame id", "position jump"},
    "imu": COMMON_LABELS | {"invalid quaternion", "wrong frame id"},
    "pose": COMMON_LABELS | {"invalid quaternion", "wrong frame id", "position jump"},
    "setpoint": COMMON_LABELS | {"invalid quaternion", "wrong frame id", "far setpoint"},
    "joint_state": COMMON_LABELS
    | {"negative speed", "oversized speed", "wrong length", "unknown joint name"},
}
AIRFRAME = load_airframe("x8_octorotor")
SPEED_LIMIT_RAD_S = 2.0 * AIRFRAME.rotor_speed_max_rad_s


def convert(kind: str, message: object) -> object:
    """The node-side reader of a kind: a Refusal for content it refuses."""
    if kind == "odometry":
        return state_from_odometry(message)
    if kind == "imu":
        return imu_from_message(message)
    if kind == "pose":
        return pose_from_message(message)
    if kind == "setpoint":
        return setpoint_from_pose(message)
    return rotor_speeds_from_joint_state(message, AIRFRAME.n_rotors, SPEED_LIMIT_RAD_S)


@pytest.fixture(scope="module", params=KINDS)
def kind_and_items(request: pytest.FixtureRequest) -> tuple[str, list[HostileMessage]]:
    return request.param, hostile_messages(request.param, COUNT, seed=1, airframe=AIRFRAME)


def test_every_kind_has_its_corruptions_and_about_a_fifth_valid(kind_and_items):
    kind, items = kind_and_items
    assert len(items) == COUNT
    labels = {item.label for item in items}
    assert labels == EXPECTED_LABELS[kind]
    assert labels <= set(LABELS)
    valid_share = sum(item.label in (VALID, "burst") for item in items) / COUNT
    assert 0.15 < valid_share < 0.35
    assert all(item.kind == kind for item in items)


def test_seeded_means_reproducible():
    for kind in KINDS:
        first, again = (hostile_messages(kind, 500, seed=3) for _ in range(2))
        other = hostile_messages(kind, 500, seed=4)
        # repr, not ==: NaN fields are unequal to themselves.
        assert [(i.label, i.detail, repr(i.message)) for i in first] == [
            (i.label, i.detail, repr(i.message)) for i in again
        ]
        assert [i.detail for i in first] != [i.detail for i in other]


def test_valid_ones_pass_the_node_readers_and_number_corruptions_do_not(kind_and_items):
    kind, items = kind_and_items
    for item in items:
        if kind == "imu" and item.detail.startswith("orientation"):
            continue  # the nodes read rates and specific force of an Imu, not its orientation
        result = convert(kind, item.message)
        if item.label in (VALID, "burst"):
            assert not isinstance(result, Refusal), (item.detail, result)
        elif item.label in ("non-finite value", "wrong length", "unknown joint name", "negative speed"):
            assert isinstance(result, Refusal), item.detail


def test_stamps_are_relative_to_the_time_of_sending():
    now_ns = 1_700_000_000 * NS_PER_S
    by_label: dict[str, list[int]] = {}
    for item in hostile_messages("odometry", 2000, seed=1):
        by_label.setdefault(item.label, []).append(stamp_to_ns(item.stamped(now_ns).header.stamp))
    assert set(by_label["stamp zero"]) == {0}
    assert set(by_label["stamp at 2^31-1 s"]) == {(2**31 - 1) * NS_PER_S}
    assert set(by_label["stamp an hour ahead"]) == {now_ns + 3600 * NS_PER_S}
    assert all(0 < stamp < now_ns for stamp in by_label["stamp in the past"])
    assert set(by_label[VALID]) == {now_ns}


def test_a_caller_supplies_the_valid_message():
    from multirotor_ros.cli.fuzz import default_valid_message

    def valid():
        message = default_valid_message("setpoint")
        message.header.frame_id = "uav1/odom"
        return message

    items = hostile_messages("setpoint", 300, seed=2, valid=valid)
    assert {i.message.header.frame_id for i in items if i.label == VALID} == {"uav1/odom"}


def test_unknown_kind_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="joint_state"):
        hostile_messages("twist", 10, seed=0)


def test_flood_paces_and_sends_a_burst_with_one_stamp():
    items = [i for i in hostile_messages("joint_state", 2000, seed=5) if i.burst][:20]
    items += hostile_messages("joint_state", 50, seed=6)
    items = [i for i in items if i.label in (VALID, "burst")]
    sent: list[int] = []
    ticks = iter(range(10**6))
    background_calls = []
    start = time.monotonic()
    flood(
        items,
        lambda m: sent.append(stamp_to_ns(m.header.stamp)),
        lambda: next(ticks) * 1000,
        rate_hz=500.0,
        background=lambda: background_calls.append(1),
        background_rate_hz=100.0,
    )
    elapsed_s = time.monotonic() - start
    paced = sum(not i.burst for i in items)
    assert len(sent) == len(items)
    first_burst = [stamp for stamp, item in zip(sent, items, strict=True) if item.burst == items[0].burst]
    assert len(set(first_burst)) == 1
    assert elapsed_s >= (paced - 1) / 500.0 * 0.9
    assert 1 <= len(background_calls) <= elapsed_s * 100.0 + 2


def test_non_finite_values_are_found_in_nested_messages_and_diagnostic_text():
    vector = Vector3Stamped()
    assert not has_non_finite(vector)
    vector.vector.y = math.inf
    assert has_non_finite(vector)
    diagnostics = DiagnosticArray(status=[DiagnosticStatus(values=[KeyValue(key="k_f", value="1.7e-05")])])
    assert not has_non_finite(diagnostics)
    diagnostics.status[0].values.append(KeyValue(key="information", value="nan"))
    assert has_non_finite(diagnostics)
    assert has_non_finite([1.0, float("nan")])
    assert not has_non_finite(["information", 3, b"\x00"])


def test_refusals_are_counted_from_first_lines_and_summaries():
    log = [
        "refused odom: non-finite odometry: position (nan, 0, 1) (further refusals ... every 10 s)",
        "refused odom: stamp in the future: odometry stamped 3600.000 s ahead",
        "odometry is stale: no motor commands until it returns",
        "refused 41 more odom in the last 10 s (non-finite odometry: 30, stamp in the future: 11); total 43",
    ]
    assert refusals_in_log(log) == 43


def test_table_names_every_column_and_the_labels():
    report = TopicReport("controller", "odom", messages=10, refusals=8, rss_before_kb=2048, rss_after_kb=3072)
    report.labels.update({VALID: 2, "huge value": 8})
    table = format_table([report, TopicReport("identifier", "pose", note="no subscriber")])
    assert "non-finite out" in table and "RSS after [MB]" in table
    assert "controller  odom" in table and "3.0" in table
    assert "identifier  pose: no subscriber" in table
    assert "valid 2, huge value 8" in table
