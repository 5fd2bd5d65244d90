"""The docking node's robot interface without a graph: charging read as Nav2's SimpleChargingDock reads it (battery
current above ``charging_threshold``), the power supply status when the current is not measured, the ages on the
node's clock, and cmd_vel as TwistStamped (Kilted's default) or Twist. The node is a stand-in: the test process
never loads rclpy."""

from __future__ import annotations

import math
import sys
import types
from typing import Any

import pytest

pytest.importorskip("sensor_msgs")


class _Clock:
    def __init__(self) -> None:
        self.seconds = 100.0

    def now(self) -> Any:
        seconds = self.seconds

        class _Time:
            nanoseconds = int(seconds * 1e9)

            def to_msg(self) -> Any:
                from builtin_interfaces.msg import Time

                return Time(sec=int(seconds), nanosec=int((seconds % 1) * 1e9))

        return _Time()


class _Node:
    def __init__(self) -> None:
        self.clock = _Clock()
        self.published: list[Any] = []
        self.subscriptions: dict[str, Any] = {}

    def get_clock(self) -> _Clock:
        return self.clock

    def create_publisher(self, kind: Any, topic: str, _qos: Any) -> Any:
        node = self

        class _Publisher:
            msg_type = kind

            def publish(self, msg: Any) -> None:
                node.published.append((topic, msg))

        return _Publisher()

    def create_subscription(self, _kind: Any, topic: str, callback: Any, _qos: Any) -> Any:
        self.subscriptions[topic] = callback
        return object()


@pytest.fixture(autouse=True)
def _rclpy_stand_ins(monkeypatch: pytest.MonkeyPatch) -> None:
    for name, values in {"rclpy": {}, "rclpy.qos": {"qos_profile_sensor_data": object()}}.items():
        module = types.ModuleType(name)
        module.__dict__.update(values)
        monkeypatch.setitem(sys.modules, name, module)


def _robot(**topics: Any) -> tuple[Any, _Node]:
    from monodock.ros.ros2_robot import RobotTopics, Ros2Robot

    node = _Node()
    return Ros2Robot(node, RobotTopics(**topics)), node


def _battery(current: float, status: int) -> Any:
    from sensor_msgs.msg import BatteryState

    return BatteryState(current=current, power_supply_status=status)


def test_charging_is_the_current_above_the_threshold_then_the_status() -> None:
    from sensor_msgs.msg import BatteryState

    from monodock.ros.ros2_robot import ChargingSignal

    robot, node = _robot()
    on_battery = node.subscriptions["battery_state"]
    assert robot.charging() is None  # no battery message: it cannot tell
    cases = [
        (1.5, BatteryState.POWER_SUPPLY_STATUS_UNKNOWN, True),  # a base that reports UNKNOWN but measures current
        (0.4, BatteryState.POWER_SUPPLY_STATUS_CHARGING, False),  # the current decides (upstream's isCharging)
        (-0.8, BatteryState.POWER_SUPPLY_STATUS_DISCHARGING, False),
        (0.0, BatteryState.POWER_SUPPLY_STATUS_FULL, False),  # full, no current: not charging, as upstream
        (math.nan, BatteryState.POWER_SUPPLY_STATUS_CHARGING, True),  # no current measured: the status
        (math.nan, BatteryState.POWER_SUPPLY_STATUS_FULL, True),
        (math.nan, BatteryState.POWER_SUPPLY_STATUS_NOT_CHARGING, False),
        (math.nan, BatteryState.POWER_SUPPLY_STATUS_UNKNOWN, None),  # neither: it cannot tell
    ]
    for current, status, charging in cases:
        on_battery(_battery(current, status))
        assert robot.charging() is charging, (current, status)
    on_battery(_battery(0.6, BatteryState.POWER_SUPPLY_STATUS_UNKNOWN))
    assert robot.charging() is True
    robot.charging_signal = ChargingSignal(threshold=1.0)  # a dock type's charging_threshold
    assert robot.charging() is False
    robot.charging_signal = ChargingSignal(use_battery_status=False)
    assert robot.charging() is None
    # An old reading (on the node's clock, ROS time) is no reading.
    robot.charging_signal = ChargingSignal()
    node.clock.seconds += 1.5
    assert robot.charging() is None


def test_cmd_vel_is_twist_stamped_by_default_and_twist_when_asked() -> None:
    from geometry_msgs.msg import Twist, TwistStamped

    robot, node = _robot(frame_id="base_footprint")
    robot.send_velocity(0.2, -0.1)
    topic, msg = node.published[-1]
    assert topic == "cmd_vel"
    assert isinstance(msg, TwistStamped)
    assert (msg.twist.linear.x, msg.twist.angular.z) == (0.2, -0.1)
    assert msg.header.frame_id == "base_footprint"
    assert msg.header.stamp.sec == 100
    robot, node = _robot(stamped_cmd_vel=False)
    robot.send_velocity(0.2, -0.1)
    _, msg = node.published[-1]
    assert isinstance(msg, Twist)
    assert (msg.linear.x, msg.angular.z) == (0.2, -0.1)
    robot.enabled = False  # the node is going away: nothing more goes out
    robot.send_velocity(0.3, 0.0)
    assert len(node.published) == 1


def test_a_lost_camera_is_told_from_a_node_that_fell_behind() -> None:
    from monodock.ros.ros2_robot import CameraStats

    stats = CameraStats()
    for i in range(30):  # 15 frames a second for 2 s; the mission took one in five
        stats.on_arrival(10.0 + i / 15)
        if i % 5 == 0:
            stats.on_taken(10.0 + i / 15)
            stats.on_perceived(0.004, 0.07)
    said = stats.explain(now=12.0, window=1.2)
    assert "18 camera frames arrived, 3 were perceived and 15 dropped while the node was behind" in said
    assert "no camera frame arrived in the last 8.1 s" in stats.explain(now=20.0, window=1.2)
    stats.on_arrival(19.3)  # one frame still in flight when the camera went silent
    assert "no camera frame arrived in the last 0.7 s" in stats.explain(now=20.0, window=1.2)
    values = stats.values()
    assert (values["frames_arrived"], values["frames_perceived"], values["frames_dropped"]) == ("31", "6", "25")
    assert (values["processing_median_ms"], values["lag_p95_ms"]) == ("4.0", "70.0")
    stats.reset()
    assert stats.values()["frames_arrived"] == "0"
