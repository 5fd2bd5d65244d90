"""The docking mission's robot (``monodock.dock.interface.RobotInterface``) over ROS 2 topics: odometry, camera,
battery, contact switch and rear range in, ``cmd_vel`` out.

Every age is measured on the node's clock (ROS time: the simulator's ``/clock`` under ``use_sim_time``), so a robot
whose simulation slows down is not taken for one whose sensors stopped. ``cmd_vel`` is ``geometry_msgs/TwistStamped``
(Kilted's default, ``enable_stamped_cmd_vel``) or ``Twist``. Charging is read as Nav2's ``SimpleChargingDock`` reads
it: the battery's ``current`` above ``charging_threshold``; a battery that does not measure its current (NaN) is read
by its ``power_supply_status`` instead, and one that reports neither cannot tell (None), as one with no battery topic.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from monodock.core.pose2d import Pose2D
from monodock.dock.interface import CameraFrame, Odometry
from monodock.errors import InputError
from monodock.recording import messages as m

__all__ = ["CameraStats", "ChargingSignal", "RobotTopics", "Ros2Robot"]


@dataclass(frozen=True)
class RobotTopics:
    """Where the robot's topics are and how its messages are read."""

    odom: str = "odom"
    cmd_vel: str = "cmd_vel"
    image: str = "image"
    image_is_compressed: bool = False
    battery: str = "battery_state"
    contact: str = "contact"
    rear_range: str = "rear_range"
    frame_id: str = "base_link"
    sensor_timeout: float = 1.0  # s: battery, contact and rear range readings older than this are absent
    stamped_cmd_vel: bool = True


@dataclass(frozen=True)
class ChargingSignal:
    """How the battery says it charges (a dock type's ``charging_threshold`` and ``use_battery_status``)."""

    threshold: float = 0.5  # A
    use_battery_status: bool = True


class CameraStats:
    """What became of the camera's frames during a mission, on the node's clock: when each arrived, which the
    mission took (a frame that a newer one replaced before the mission looked was dropped), how long each took to
    perceive and how old it was by then. Written by the executor's and the mission's threads."""

    def __init__(self, keep: int = 3000) -> None:
        self._lock = threading.Lock()
        self.arrived: deque[float] = deque(maxlen=keep)
        self.taken: deque[float] = deque(maxlen=keep)
        self.processing: deque[float] = deque(maxlen=keep)  # wall seconds to perceive a frame
        self.lag: deque[float] = deque(maxlen=keep)  # the node's clock minus the frame's stamp when perceived
        self.arrived_total = self.taken_total = 0

    def reset(self) -> None:
        with self._lock:
            for kept in (self.arrived, self.taken, self.processing, self.lag):
                kept.clear()
            self.arrived_total = self.taken_total = 0

    def on_arrival(self, now: float) -> None:
        with self._lock:
            self.arrived.append(now)
            self.arrived_total += 1

    def on_taken(self, now: float) -> None:
        with self._lock:
            self.taken.append(now)
            self.taken_total += 1

    def on_perceived(self, seconds: float, lag: float) -> None:
        with self._lock:
            self.processing.append(seconds)
            self.lag.append(lag)

    def since(self, start: float) -> tuple[int, int]:
        """(frames arrived, frames taken) since ``start`` on the node's clock."""
        with self._lock:
            return sum(t >= start for t in self.arrived), sum(t >= start for t in self.taken)

    def explain(self, now: float, window: float) -> str:
        """Whether the frames of the last ``window`` seconds came and were dropped, or stopped coming: for a failure
        for lost markers. Frames stopped when none came in the last half of the window (one still in flight when the
        camera went silent does not make it a camera that kept sending)."""
        arrived, taken = self.since(now - window)
        with self._lock:
            last = self.arrived[-1] if self.arrived else -math.inf
        if now - last > window / 2:
            silent = f"{now - last:.1f} s" if math.isfinite(last) else "the whole mission"
            return f"no camera frame arrived in the last {silent} (the camera or the simulation stalled)"
        dropped = arrived - taken
        return f"in the last {window:.1f} s {arrived} camera frames arrived, {taken} were perceived" + (
            f" and {dropped} dropped while the node was behind" if dropped > 0 else " (the markers were not in them)"
        )

    def values(self) -> dict[str, str]:
        """For /diagnostics: the counts, and the median and 95th percentile of processing time and lag (ms)."""
        with self._lock:
            processing, lag = sorted(self.processing), sorted(self.lag)
            arrived, taken = self.arrived_total, self.taken_total

        def ms(values: list[float], q: float) -> str:
            return f"{1e3 * values[min(len(values) - 1, int(q * len(values)))]:.1f}" if values else ""

        return {
            "frames_arrived": str(arrived),
            "frames_perceived": str(taken),
            "frames_dropped": str(max(0, arrived - taken)),
            "processing_median_ms": ms(processing, 0.5),
            "processing_p95_ms": ms(processing, 0.95),
            "lag_median_ms": ms(lag, 0.5),
            "lag_p95_ms": ms(lag, 0.95),
        }


class _Latest:
    """The newest message of a topic with its arrival time on the node's clock, written by callbacks."""

    def __init__(self, clock: Any) -> None:
        self._clock = clock
        self.value: Any = None
        self.at = -math.inf

    def set(self, value: Any) -> None:
        self.value, self.at = value, _seconds(self._clock)

    def age(self) -> float:
        return _seconds(self._clock) - self.at if self.value is not None else math.inf

    def fresh(self, max_age: float) -> Any:
        return self.value if self.age() <= max_age else None


def _seconds(clock: Any) -> float:
    return float(clock.now().nanoseconds) * 1e-9


class Ros2Robot:
    """The controller's robot interface over ROS 2 topics, safe to call from the mission thread.

    Callbacks (the node's executor thread) store the newest message; images are decoded there only while a mission
    runs, so a node that is not docking decodes nothing.
    """

    def __init__(self, node: Any, topics: RobotTopics) -> None:
        from geometry_msgs.msg import Twist, TwistStamped  # type: ignore[import-not-found, unused-ignore]
        from nav_msgs.msg import Odometry as OdometryMsg  # type: ignore[import-not-found, unused-ignore]
        from rclpy.qos import qos_profile_sensor_data  # type: ignore[import-not-found, unused-ignore]
        from sensor_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            BatteryState,
            CompressedImage,
            Image,
            Range,
        )
        from std_msgs.msg import Bool  # type: ignore[import-not-found, unused-ignore]

        self.node, self.topics = node, topics
        self.clock = node.get_clock()
        self._twist = TwistStamped if topics.stamped_cmd_vel else Twist
        self._charging_states = {BatteryState.POWER_SUPPLY_STATUS_CHARGING, BatteryState.POWER_SUPPLY_STATUS_FULL}
        self._not_charging_states = {
            BatteryState.POWER_SUPPLY_STATUS_DISCHARGING,
            BatteryState.POWER_SUPPLY_STATUS_NOT_CHARGING,
        }
        self.charging_signal = ChargingSignal()
        self.odom, self.battery, self.contact_msg, self.rear = (_Latest(self.clock) for _ in range(4))
        self._frame: CameraFrame | None = None
        self._taken_stamp = -math.inf
        self.camera_stats = CameraStats()
        self.image_frame_id = ""  # the newest image's frame, for the camera mount from /tf_static
        self.active = False  # a mission is running: decode images (an idle node decodes nothing)
        self.enabled = True  # False once the node is going away: nothing more is published
        self._publishing = threading.Lock()  # a command is never sent while (or after) the node closes
        self._msgtype = m.COMPRESSED_IMAGE if topics.image_is_compressed else m.IMAGE
        self._cmd = node.create_publisher(self._twist, topics.cmd_vel, 10)
        sensor = qos_profile_sensor_data  # best effort subscribers match best-effort and reliable publishers
        node.create_subscription(OdometryMsg, topics.odom, self.odom.set, sensor)
        image_type = CompressedImage if topics.image_is_compressed else Image
        node.create_subscription(image_type, topics.image, self._on_image, sensor)
        if topics.battery:
            node.create_subscription(BatteryState, topics.battery, self.battery.set, sensor)
        if topics.contact:
            node.create_subscription(Bool, topics.contact, self.contact_msg.set, sensor)
        if topics.rear_range:
            node.create_subscription(Range, topics.rear_range, self.rear.set, sensor)

    def now(self) -> float:
        return _seconds(self.clock)

    def send_velocity(self, linear: float, angular: float) -> None:
        msg = self._twist()
        twist = msg.twist if self.topics.stamped_cmd_vel else msg
        if self.topics.stamped_cmd_vel:
            msg.header.stamp = self.clock.now().to_msg()
            msg.header.frame_id = self.topics.frame_id
        twist.linear.x, twist.angular.z = float(linear), float(angular)
        with self._publishing:
            if self.enabled:
                self._cmd.publish(msg)

    def stop_and_flush(self, timeout: float = 1.0) -> None:
        """Command zero and wait until the subscribers have it: a node that exits right after publishing would
        otherwise take its last message down with it. Nothing is published after this (a mission thread still
        running finds the robot closed, not a destroyed publisher)."""
        from rclpy.duration import Duration  # type: ignore[import-not-found, unused-ignore]

        self.send_velocity(0.0, 0.0)
        with self._publishing:
            self.enabled = False
        self._cmd.wait_for_all_acked(Duration(seconds=timeout))

    def odometry_age(self) -> float:
        """How old the odometry is on the node's clock: the lesser of the time since it arrived and the clock minus
        its stamp. Both grow when odometry stops; a robot whose clocks disagree by a little makes only one grow."""
        msg = self.odom.value
        if msg is None:
            return math.inf
        return min(self.odom.age(), max(0.0, self.now() - m.header_stamp(msg)))

    def wait_for_odometry(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while self.odom.value is None and time.monotonic() < end:
            time.sleep(0.01)
        return self.odom.value is not None

    def odometry(self) -> Odometry:
        msg = self.odom.value
        if msg is None:
            raise InputError(f"no odometry on {self.topics.odom}")
        p, q, t = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        return Odometry(m.header_stamp(msg), Pose2D(p.x, p.y, yaw), t.linear.x, t.angular.z)

    def _on_image(self, msg: Any) -> None:
        """Decode while a mission runs (only good frames are kept: a malformed image never hides the last good one)."""
        self.image_frame_id = str(msg.header.frame_id)
        if not self.active:
            return
        try:
            frame = CameraFrame(m.header_stamp(msg), m.decode_image(msg, self._msgtype))
        except m.DecodeError as exc:
            self.node.get_logger().warning(f"image skipped: {exc}", throttle_duration_sec=5.0)
            return
        self.camera_stats.on_arrival(self.now())
        self._frame = frame

    def latest_frame(self) -> CameraFrame | None:
        frame = self._frame
        if frame is not None and frame.stamp > self._taken_stamp:
            self._taken_stamp = frame.stamp
            self.camera_stats.on_taken(self.now())
        return frame

    def watch(self, on: bool) -> None:
        """Start or stop decoding images; a new mission never sees a frame from before it began (nor its counts)."""
        self._frame = None
        self._taken_stamp = -math.inf
        if on:
            self.camera_stats.reset()
        self.active = on

    def contact(self) -> bool | None:
        msg = self.contact_msg.fresh(self.topics.sensor_timeout)
        return None if msg is None else bool(msg.data)

    def charging(self, signal: ChargingSignal | None = None) -> bool | None:
        """Whether the battery charges (None: it cannot tell): its current above the threshold, else its status;
        by ``signal`` (a dock type's), else by the running mission's."""
        signal = signal or self.charging_signal
        if not signal.use_battery_status:
            return None
        msg = self.battery.fresh(self.topics.sensor_timeout)
        if msg is None:
            return None
        current = float(msg.current)
        if math.isfinite(current):
            return current > signal.threshold
        if msg.power_supply_status in self._charging_states:
            return True
        return False if msg.power_supply_status in self._not_charging_states else None

    def rear_range(self) -> float | None:
        msg = self.rear.fresh(self.topics.sensor_timeout)
        if msg is None:
            return None
        r = float(msg.range)
        return math.inf if math.isinf(r) and r > 0 else (r if math.isfinite(r) else None)

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))  # the executor thread serves callbacks meanwhile
