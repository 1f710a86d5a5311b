"""The test harness checked on its own, without the package's nodes.

If these fail, topic-level tests of the nodes cannot be trusted: the cause is the ROS installation,
DDS on this machine, or the harness, not the nodes.
"""

import sys
import textwrap

import pytest
from ros_harness import ManagedProcess, format_parameter, ros_arguments

# A minimal node in another process, started with the same --ros-args our nodes get.
TALKER = textwrap.dedent(
    """
    import sys

    import rclpy
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import String


    def refuse_empty(parameters):
        for parameter in parameters:
            if parameter.name == "greeting" and not parameter.value:
                return SetParametersResult(successful=False, reason="greeting must not be empty")
        return SetParametersResult(successful=True)


    def main():
        try:
            rclpy.init()
            node = rclpy.create_node("talker")
            node.declare_parameter("greeting", "hello")
            node.add_on_set_parameters_callback(refuse_empty)
            publisher = node.create_publisher(String, "chatter", 10)
            node.create_timer(
                0.05, lambda: publisher.publish(String(data=node.get_parameter("greeting").value))
            )
            rclpy.spin(node)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            rclpy.try_shutdown()
        return 0


    sys.exit(main())
    """
)


def test_parameters_are_formatted_as_rcl_parses_them():
    assert format_parameter(True) == "true"
    assert format_parameter(2.5) == "2.5"
    assert format_parameter(3) == "3"
    assert format_parameter("quad_x") == "quad_x"
    assert format_parameter("42") == '"42"'
    assert format_parameter("true") == '"true"'
    assert format_parameter([1.0, 2.0]) == "[1.0, 2.0]"
    with pytest.raises(TypeError, match="no ROS type"):
        format_parameter({"a": 1})


def test_ros_arguments_put_namespace_remaps_and_parameters_after_ros_args():
    assert ros_arguments("/uav1", {"rate": 5.0}, {"odom": "truth"}) == [
        "--ros-args",
        "-r",
        "__ns:=/uav1",
        "-r",
        "odom:=truth",
        "-p",
        "rate:=5.0",
    ]


def test_stop_reports_the_exit_status_and_the_log_of_a_failed_process(tmp_path):
    code = "import sys; print('no airframe named quad_y'); sys.exit(3)"
    process = ManagedProcess([sys.executable, "-c", code], tmp_path / "failing.log")
    process.process.wait(timeout=30)
    with pytest.raises(AssertionError, match=r"(?s)status 3.*no airframe named quad_y"):
        process.stop()
    assert process.stop(check=False) == 3


@pytest.mark.ros
def test_probe_receives_its_own_publication(ros_probe):
    from std_msgs.msg import String

    recorder = ros_probe.subscribe("/selfcheck/loop", String)
    publisher = ros_probe.publisher("/selfcheck/loop", String)
    ros_probe.wait_for_subscribers(publisher)
    publisher.publish(String(data="ping"))
    assert [m.data for m in recorder.wait_for(timeout=10.0)] == ["ping"]


@pytest.mark.ros
def test_probe_hears_and_configures_a_node_in_another_process(ros_probe, tmp_path):
    from std_msgs.msg import String

    chatter = ros_probe.subscribe("/selfcheck/chatter", String)
    command = [sys.executable, "-c", TALKER, *ros_arguments("/selfcheck", {"greeting": "42"})]
    with ManagedProcess(command, tmp_path / "talker.log") as talker:
        ros_probe.wait_for_node("/selfcheck/talker", timeout=30.0)
        # The string parameter "42" must arrive as a string, not as the integer 42.
        chatter.wait_for(lambda m: m.data == "42", timeout=30.0)

        results = ros_probe.set_parameters("/selfcheck/talker", {"greeting": "bonjour"})
        assert results["greeting"].successful, results["greeting"].reason
        chatter.wait_for(lambda m: m.data == "bonjour", timeout=10.0)

        refused = ros_probe.set_parameters("/selfcheck/talker", {"greeting": ""})["greeting"]
        assert not refused.successful
        assert "must not be empty" in refused.reason
        assert ros_probe.get_parameters("/selfcheck/talker", ["greeting"]) == {"greeting": "bonjour"}
        with pytest.raises(AssertionError, match="not declared"):
            ros_probe.get_parameters("/selfcheck/talker", ["greeting", "undeclared"])
        talker.assert_running()
    assert talker.process.returncode == 0
