"""``monodock-dock-ros`` (node ``monodock_dock``): docking and undocking on request, for as long as it runs.

Services (std_srvs/Trigger; the reply says accepted or why not, the mission runs after it):

- ``~/dock``: dock from wherever the robot stands (the mission of ``monodock.dock.controller``);
- ``~/undock``: back out straight to the staging pose;
- ``~/cancel``: stop the running mission. A ``~/dock`` or ``~/undock`` call while one runs cancels it too.

Topics: ``~/state`` (std_msgs/String, transient-local: the state's name on every change, ``idle`` before the
first mission), ``~/result`` (diagnostic_msgs/DiagnosticStatus, transient-local: OK when the mission succeeded,
ERROR with the failure and its Nav2 error code otherwise; the robot's own estimate of the final lateral_cm,
gap_cm, heading_deg, and retries, re-seats, recoveries, duration), and the dock filter's pose on
``detected_dock_pose`` (PoseStamped) and ``detected_dock_pose_with_covariance`` in base_link while it tracks the
dock, for Nav2's docking server. It drives by ``cmd_vel`` from ``odom``, the camera ``image`` (``camera_info``
when no camera file is given), ``battery_state`` (charging), ``contact`` and ``rear_range``.

The docking config is ROS parameters of the same names as the config file's keys (``planner.standoff``,
``max_reseats``, ...; ``config`` loads a file first); each mission reads them when it starts, so they may change
between missions. Every exit of a mission commands zero velocity, a shutdown (SIGINT, SIGTERM) included; if the
node dies outright, the base's own ``cmd_vel`` time-out stops the robot.

Missions run in a thread of their own; the main thread spins the node, so services and sensor callbacks are
served while the robot moves. Needs rclpy (monodock.ros._rclpy says how to get it).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from monodock.core.camera import CameraModel
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import docking_config_from_dict, docking_config_to_dict, load_docking_config
from monodock.dock.controller import (
    DockingConfig,
    DockingMission,
    FailureReason,
    MissionResult,
    blind_gap,
    make_perceive,
    run_mission,
)
from monodock.dock.interface import CameraFrame, Odometry
from monodock.dock.pose_filter import MeasurementNoise
from monodock.errors import InputError, MonodockError
from monodock.estimation.estimator import Estimator
from monodock.recording import messages as m
from monodock.ros._rclpy import Node, rclpy
from monodock.ros.dock_actions import DOCK_ACTION, UNDOCK_ACTION, DockActions
from monodock.ros.options import ESTIMATOR_PARAMETERS, EstimatorOptions
from monodock.ros.parameters import (
    Parameter,
    declare,
    declare_options,
    flatten,
    refuse_unknown_overrides,
    unflatten,
)
from monodock.ros.shutdown import ShutdownFlag
from monodock.ros.tf import CameraMountFromTF

__all__ = ["PARAMETERS", "DockNode", "DockOptions", "Ros2Robot", "run_dock"]

# spin_once calls after odometry is first seen stale before it counts as lost: enough for the executor to take the
# callbacks that were already waiting (the clock's, the odometry's and the sensors') in one round.
STALE_SPINS = 8


@dataclass(frozen=True)
class DockOptions(EstimatorOptions):
    """The node's fixed settings (its command-line flags, which set the parameters' defaults)."""

    image_topic: str = "image"
    camera_info_topic: str = "camera_info"
    odom_topic: str = "odom"
    cmd_vel_topic: str = "cmd_vel"
    battery_topic: str = "battery_state"
    contact_topic: str = "contact"
    rear_range_topic: str = "rear_range"
    pose_topic: str = "detected_dock_pose"
    pose_covariance_topic: str = "detected_dock_pose_with_covariance"
    frame_id: str = "base_link"
    config: str = ""
    odom_timeout: float = 1.0
    sensor_timeout: float = 1.0
    dock_id: str = "dock"
    dock_type: str = "monodock"


# One per DockOptions field, of the same name, all read once at start-up (the docking config's keys are parameters
# too, declared with the config's values as defaults: DockNode._declare_config).
PARAMETERS: dict[str, Parameter] = {
    **ESTIMATOR_PARAMETERS,
    "robot": Parameter(
        "robot YAML: mounts, front_offset, speed limits (needed without a model; overrides the model's)"
    ),
    "camera_info_topic": Parameter("sensor_msgs/CameraInfo, used when no camera file is given"),
    "odom_topic": Parameter("nav_msgs/Odometry of the base"),
    "cmd_vel_topic": Parameter("geometry_msgs/Twist to the base"),
    "battery_topic": Parameter(
        "sensor_msgs/BatteryState: CHARGING or FULL confirms docking (empty: no charging signal)"
    ),
    "contact_topic": Parameter("std_msgs/Bool, true on contact with the charger (empty: none)"),
    "rear_range_topic": Parameter("sensor_msgs/Range behind the robot, watched while reversing (empty: none)"),
    "pose_topic": Parameter("PoseStamped of the dock filter's estimate in base_link (for Nav2's docking server)"),
    "pose_covariance_topic": Parameter("the same with its covariance (PoseWithCovarianceStamped)"),
    "frame_id": Parameter("the robot's base frame"),
    "config": Parameter("docking config YAML read before the parameters (docs/docking.md); empty: the defaults"),
    "odom_timeout": Parameter("a mission fails with odometry-lost when odometry is older than this, s", positive=True),
    "sensor_timeout": Parameter(
        "battery, contact and rear range readings older than this count as absent, s", positive=True
    ),
    "dock_id": Parameter("this dock's name for Nav2's DockRobot goals (use_dock_id: true with it, or empty)"),
    "dock_type": Parameter("this dock's type for DockRobot and UndockRobot goals (it, or empty)"),
}


class _Latest:
    """The newest message of a topic with its arrival time (monotonic), written by callbacks, read by the mission."""

    def __init__(self) -> None:
        self.value: Any = None
        self.at = -math.inf

    def set(self, value: Any) -> None:
        self.value, self.at = value, time.monotonic()

    def fresh(self, max_age: float) -> Any:
        return self.value if time.monotonic() - self.at <= max_age else None


class Ros2Robot:
    """The controller's robot interface over ROS 2 topics, safe to call from the mission thread.

    Callbacks (the node's executor thread) store the newest message; images are decoded there only while a mission
    runs, so a node that is not docking decodes nothing.
    """

    def __init__(self, node: Node, options: DockOptions) -> None:
        from geometry_msgs.msg import Twist  # type: ignore[import-not-found, unused-ignore]
        from nav_msgs.msg import Odometry as OdometryMsg  # type: ignore[import-not-found, unused-ignore]
        from rclpy.qos import qos_profile_sensor_data  # type: ignore[import-not-found, unused-ignore]
        from sensor_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            BatteryState,
            CompressedImage,
            Image,
            Range,
        )
        from std_msgs.msg import Bool  # type: ignore[import-not-found, unused-ignore]

        self.node, self.options = node, options
        self._twist = Twist
        self._charging_states = {BatteryState.POWER_SUPPLY_STATUS_CHARGING, BatteryState.POWER_SUPPLY_STATUS_FULL}
        self.odom, self.battery, self.contact_msg, self.rear = (_Latest() for _ in range(4))
        self._frame: CameraFrame | None = None
        self.image_frame_id = ""  # the newest image's frame, for the camera mount from /tf_static
        self.active = False  # a mission is running: decode images (an idle node decodes nothing)
        compressed = options.image_is_compressed
        self._msgtype = m.COMPRESSED_IMAGE if compressed else m.IMAGE
        self._cmd = node.create_publisher(Twist, options.cmd_vel_topic, 10)
        sensor = qos_profile_sensor_data  # best effort subscribers match best-effort and reliable publishers
        node.create_subscription(OdometryMsg, options.odom_topic, self.odom.set, sensor)
        image_type = CompressedImage if compressed else Image
        node.create_subscription(image_type, options.subscribed_image_topic, self._on_image, sensor)
        if options.battery_topic:
            node.create_subscription(BatteryState, options.battery_topic, self.battery.set, sensor)
        if options.contact_topic:
            node.create_subscription(Bool, options.contact_topic, self.contact_msg.set, sensor)
        if options.rear_range_topic:
            node.create_subscription(Range, options.rear_range_topic, self.rear.set, sensor)

    def now(self) -> float:
        return float(self.node.get_clock().now().nanoseconds) * 1e-9

    def send_velocity(self, linear: float, angular: float) -> None:
        msg = self._twist()
        msg.linear.x, msg.angular.z = float(linear), float(angular)
        self._cmd.publish(msg)

    def stop_and_flush(self, timeout: float = 1.0) -> None:
        """Command zero and wait until the subscribers have it: a node that exits right after publishing would
        otherwise take its last message down with it."""
        from rclpy.duration import Duration  # type: ignore[import-not-found, unused-ignore]

        self.send_velocity(0.0, 0.0)
        self._cmd.wait_for_all_acked(Duration(seconds=timeout))

    def odometry_age(self) -> float:
        """How old the odometry is: the lesser of the time since it arrived (wall clock) and the node's clock minus
        its stamp. Both grow when odometry stops; a simulation that stalls (its /clock stalls too) or a robot whose
        clocks disagree by a little makes only one of them grow."""
        msg = self.odom.value
        if msg is None:
            return math.inf
        arrived = time.monotonic() - self.odom.at
        return min(arrived, max(0.0, self.now() - m.header_stamp(msg)))

    def wait_for_odometry(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while self.odom.value is None and time.monotonic() < end:
            time.sleep(0.01)
        return self.odom.value is not None

    def odometry(self) -> Odometry:
        msg = self.odom.value
        if msg is None:
            raise InputError(f"no odometry on {self.options.odom_topic}")
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
        self._frame = frame

    def latest_frame(self) -> CameraFrame | None:
        return self._frame

    def watch(self, on: bool) -> None:
        """Start or stop decoding images; a new mission never sees a frame from before it began."""
        self._frame = None
        self.active = on

    def contact(self) -> bool | None:
        msg = self.contact_msg.fresh(self.options.sensor_timeout)
        return None if msg is None else bool(msg.data)

    def charging(self) -> bool | None:
        msg = self.battery.fresh(self.options.sensor_timeout)
        return None if msg is None else msg.power_supply_status in self._charging_states

    def rear_range(self) -> float | None:
        msg = self.rear.fresh(self.options.sensor_timeout)
        if msg is None:
            return None
        r = float(msg.range)
        return math.inf if math.isinf(r) and r > 0 else (r if math.isfinite(r) else None)

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))  # the executor thread serves callbacks meanwhile


class DockNode(Node):  # type: ignore[misc, unused-ignore]
    """The long-running docking node: services in, one mission at a time in a thread, state and result out."""

    def __init__(self, options: DockOptions) -> None:
        super().__init__("monodock_dock")
        from diagnostic_msgs.msg import DiagnosticStatus  # type: ignore[import-not-found, unused-ignore]
        from geometry_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            PoseStamped,
            PoseWithCovarianceStamped,
        )
        from rclpy.qos import DurabilityPolicy, QoSProfile  # type: ignore[import-not-found, unused-ignore]
        from sensor_msgs.msg import CameraInfo  # type: ignore[import-not-found, unused-ignore]
        from std_msgs.msg import String  # type: ignore[import-not-found, unused-ignore]
        from std_srvs.srv import Trigger  # type: ignore[import-not-found, unused-ignore]

        self._msgs = {"String": String, "DiagnosticStatus": DiagnosticStatus, "PoseStamped": PoseStamped}
        self._pose_cov = PoseWithCovarianceStamped
        self.options = declare_options(self, options, PARAMETERS)
        base = load_docking_config(self.options.config) if self.options.config else DockingConfig()
        self._config_names = list(flatten(docking_config_to_dict(base)))
        self._config_base = base
        self._config_declared = False
        self.estimator: Estimator | None = None
        self.method = ""
        self._file_robot: RobotConfig | None = None  # the robot file's (or the bundle's), before /tf_static
        self._tf_waited = False  # the first mission waits for /tf_static's camera chain
        self.spins = 0  # the executor's spin_once calls, counted by run_dock: see _odometry_lost
        self._stale_at_spin: int | None = None
        self._camera_info = _Latest()
        if self.options.model or self.options.camera:
            self._make_estimator(None)
        else:
            _check_calibration(self.options)
            self.create_subscription(
                CameraInfo, self.options.camera_info_topic, self._camera_info.set, rclpy.qos.qos_profile_sensor_data
            )
        self._declare_config()
        self.docking_config()  # a bad value in the parameters or the config file: refused before anything runs
        refuse_unknown_overrides(self)
        self.add_on_set_parameters_callback(self._check_new_parameters)
        self.robot = Ros2Robot(self, self.options)
        o = self.options
        tolerance = (o.mount_tolerance_m, o.mount_tolerance_deg)
        self.mount = CameraMountFromTF(self, o.frame_id, source=o.camera_mount_source, tolerance=tolerance)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_state = self.create_publisher(String, "~/state", latched)
        self.pub_result = self.create_publisher(DiagnosticStatus, "~/result", latched)
        self.pub_pose = self.create_publisher(PoseStamped, self.options.pose_topic, 10)
        self.pub_pose_cov = self.create_publisher(PoseWithCovarianceStamped, self.options.pose_covariance_topic, 10)
        self.create_service(Trigger, "~/dock", lambda _req, res: self._start("dock", res))
        self.create_service(Trigger, "~/undock", lambda _req, res: self._start("undock", res))
        self.create_service(Trigger, "~/cancel", self._on_cancel)
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._mission: DockingMission | None = None
        self._cancel: str | None = None  # why the running mission must stop, set by another thread
        self._on_done: Callable[[MissionResult | None, str], None] | None = None  # the running mission's caller
        self._state = ""
        self._publish_state("idle")
        self.actions = self._action_servers()

    def _action_servers(self) -> DockActions | None:
        """Nav2's DockRobot/UndockRobot servers, when the interfaces were built at install time."""
        try:
            return DockActions(self, self.start_mission, self.cancel_mission)
        except ImportError as exc:
            self.get_logger().warning(
                f"no {DOCK_ACTION}/{UNDOCK_ACTION} action servers: {exc} (nav2_msgs is built when monodock is "
                "installed; interfaces/README.md). The ~/dock and ~/undock services work."
            )
            return None

    # --- set-up -----------------------------------------------------------------------------

    def _declare_config(self) -> None:
        """The docking config's keys as parameters, defaulting to the config file's (or the built-in) values.

        The measurement noise defaults to the method's own (``MeasurementNoise.for_method``) unless the config file
        sets it; the method is known once the estimator is.
        """
        base = self._config_base
        if not self.options.config and self.method:
            base = dataclasses.replace(base, measurement=MeasurementNoise.for_method(self.method))
        for name, default in flatten(docking_config_to_dict(base)).items():
            declare(self, name, Parameter(f"docking config: {name} (docs/docking.md)", read_only=False), default)
        self._config_declared = True

    def docking_config(self) -> DockingConfig:
        """The docking config of the parameters as they are now (checked like a config file)."""
        values = {name: self.get_parameter(name).value for name in self._config_names}
        return docking_config_from_dict(unflatten(values), "ROS parameters")

    def _check_new_parameters(self, parameters: list[Any]) -> Any:
        """Refuse a live change that would make the docking config invalid (it would only fail at the next ~/dock)."""
        from rcl_interfaces.msg import SetParametersResult  # type: ignore[import-not-found, unused-ignore]

        values = {name: self.get_parameter(name).value for name in self._config_names}
        values.update({p.name: p.value for p in parameters if p.name in values})
        try:
            docking_config_from_dict(unflatten(values), "ROS parameters")
        except MonodockError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _make_estimator(self, camera: CameraModel | None, robot: RobotConfig | None = None) -> None:
        self.estimator = self.options.estimator(camera, robot)
        self.method = self.estimator.method
        self.estimator.warm_up()
        if robot is None:
            self._file_robot = self.estimator.robot

    def _mount_from_tf(self) -> None:
        """The estimator with the camera mount /tf_static gives the images' frame (``camera_mount_source``). Before
        the first mission it waits a little for the first image, whose frame it needs, and for /tf_static's chain
        to that frame (latched, it may come just after the node starts); a robot without one waits only then."""
        assert self.estimator is not None
        assert self._file_robot is not None
        if not self._tf_waited:
            self._tf_waited = True
            end = time.monotonic() + self.options.sensor_timeout
            while time.monotonic() < end and not (
                self.robot.image_frame_id
                and self.mount.lookup(self.options.frame_id, self.robot.image_frame_id) is not None
            ):
                time.sleep(0.02)
        robot = self.mount.robot(self._file_robot, self.robot.image_frame_id)
        if robot != self.estimator.robot:
            self._make_estimator(self.estimator.camera, robot)

    # --- services ---------------------------------------------------------------------------

    def _start(self, task: str, response: Any) -> Any:
        """A Trigger request: a call while a mission runs cancels it (and starts nothing)."""
        if self.cancel_mission(f"cancelled by a {task} request"):
            response.success, response.message = True, f"cancelled the running {self._mission_task()} mission"
            return response
        try:
            self.start_mission(task)
        except MonodockError as exc:
            response.success, response.message = False, str(exc)
            return response
        response.success, response.message = True, f"{task} started"
        return response

    def start_mission(self, task: str, on_done: Callable[[MissionResult | None, str], None] | None = None) -> None:
        """Start a dock or undock mission in its thread; ``on_done(result, error)`` is called when it ends.

        Raises:
            InputError: a mission runs already, the docking config is invalid, or an undock while not docked.
        """
        # A cancelled mission reports its end (on_done) just before its thread ends: a caller that waited for that
        # report (a preempting goal) must not find the thread still alive.
        ending = self._thread
        if ending is not None and ending.is_alive() and self._cancel is not None:
            ending.join(timeout=5.0)
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise InputError(f"a {self._mission_task()} mission is running: cancel it first")
            config = self.docking_config()
            if task == "undock" and not self._docked():
                raise InputError("not docked: no docking mission ended docked and the charger does not report charging")
            self._cancel = None
            self._on_done = on_done
            self._thread = threading.Thread(target=self._run, args=(task, config), name=f"monodock-{task}")
            self._thread.start()

    def cancel_mission(self, why: str) -> bool:
        """Ask the running mission to stop (it commands zero velocity and ends CANCELLED); False if none runs."""
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                return False
            self._cancel = why
            return True

    def _on_cancel(self, _request: Any, response: Any) -> Any:
        if not self.cancel_mission("cancelled by request"):
            response.success, response.message = False, "no mission is running"
            return response
        response.success, response.message = True, f"cancelled the running {self._mission_task()} mission"
        return response

    def _docked(self) -> bool:
        """Whether the robot stands on the dock: the last mission docked it, or the charger says it is charging."""
        return self._state == "docked" or self.robot.charging() is True

    def _mission_task(self) -> str:
        return self._mission.task if self._mission is not None else "starting"

    def _ensure_estimator(self) -> None:
        """The estimator, with the camera from camera_info when no camera file was given (waits a little for it)."""
        if self.estimator is not None:
            return
        end = time.monotonic() + max(2.0, 3 * self.options.sensor_timeout)
        camera = None
        while camera is None and time.monotonic() < end:
            msg = self._camera_info.value
            camera = None if msg is None else m.camera_from_msg(msg, rectified=self.options.image_is_rectified)
            if camera is None:
                time.sleep(0.02)
        if camera is None:
            raise InputError(f"no calibrated camera_info on {self.options.camera_info_topic}")
        self._make_estimator(camera)
        self.get_logger().info(f"camera {camera.width}x{camera.height} from camera_info; docking with {self.method}")

    # --- the mission ------------------------------------------------------------------------

    def _run(self, task: str, config: DockingConfig) -> None:
        """One mission, start to end, in the mission thread; zero velocity whatever happens."""
        robot = self.robot
        result: MissionResult | None = None
        error = ""
        try:
            self._ensure_estimator()
            self._mount_from_tf()
            estimator = self.estimator
            assert estimator is not None
            if not robot.wait_for_odometry(max(2.0, self.options.odom_timeout)) or robot.now() <= 0.0:
                error = f"no odometry on {self.options.odom_topic}"
                self._publish_result(task, None, error)
                return
            blind = blind_gap(estimator.camera, estimator.layout, estimator.robot)
            mission = DockingMission(config, estimator.robot, blind, task=task)
            self._stale_at_spin = None
            self._mission = mission
            self._publish_state(mission.state.value)
            robot.watch(True)
            track = (lambda: mission.track) if config.predicted_markers else None
            perceive = make_perceive(estimator, self.method, track=track)
            result = run_mission(robot, perceive, mission, on_tick=self._on_tick)
            self._publish_result(task, result, "")
        except MonodockError as exc:
            error = str(exc)
            self._publish_result(task, None, error)
        finally:
            robot.watch(False)
            robot.send_velocity(0.0, 0.0)
            on_done, self._on_done = self._on_done, None
            if on_done is not None:
                on_done(result, error)

    def _on_tick(self, mission: DockingMission, odom: Odometry) -> None:
        """After each control step: stop on cancel or lost odometry; publish the state and the dock filter's pose."""
        now = self.robot.now()
        if self._cancel is not None:
            mission.abort(now, FailureReason.CANCELLED, self._cancel)
        elif self._odometry_lost():
            age = self.robot.odometry_age()
            mission.abort(now, FailureReason.ODOMETRY_LOST, f"no odometry for {age:.2f} s")
        if mission.state.value != self._state:
            self._publish_state(mission.state.value)
        self._publish_pose(mission, odom)
        if self.actions is not None:
            self.actions.feedback(mission)

    def _odometry_lost(self) -> bool:
        """Odometry older than odom_timeout, and still so after the executor has taken what was already waiting.

        At the end of a stall (a busy machine) the sim publishes its /clock and the odometry of the same instant
        together; the executor takes /clock's subscription first, and a tick in between would see an odometry
        1.4 s old on both clocks. A few spins later the waiting odometry has been taken or none was waiting."""
        if self.robot.odometry_age() <= self.options.odom_timeout:
            self._stale_at_spin = None
            return False
        if self._stale_at_spin is None:
            self._stale_at_spin = self.spins
        return self.spins - self._stale_at_spin >= STALE_SPINS

    def _publish_state(self, state: str) -> None:
        self._state = state
        msg = self._msgs["String"]()
        msg.data = state
        self.pub_state.publish(msg)

    def _publish_pose(self, mission: DockingMission, odom: Odometry) -> None:
        placed = mission.track.dock_at(odom.stamp)  # the filtered dock in base_link at this odometry
        if placed is None:
            return
        dock, cov = placed
        out = self._msgs["PoseStamped"]()
        out.header.stamp.sec, out.header.stamp.nanosec = m.split_stamp(odom.stamp)
        out.header.frame_id = self.options.frame_id
        out.pose.position.x, out.pose.position.y = dock.x, dock.y
        out.pose.orientation.z, out.pose.orientation.w = math.sin(0.5 * dock.yaw), math.cos(0.5 * dock.yaw)
        self.pub_pose.publish(out)
        with_cov = self._pose_cov()
        with_cov.header = out.header
        with_cov.pose.pose = out.pose
        full = np.zeros((6, 6))
        index = [0, 1, 5]  # x, y, yaw in ROS's (x, y, z, roll, pitch, yaw)
        full[np.ix_(index, index)] = cov
        with_cov.pose.covariance = [float(v) for v in full.ravel()]
        self.pub_pose_cov.publish(with_cov)

    def _publish_result(self, task: str, result: MissionResult | None, error: str) -> None:
        status = self._msgs["DiagnosticStatus"]()
        status.name = f"monodock_dock: {task}"
        status.hardware_id = self.options.frame_id
        values: dict[str, str] = {"task": task}
        if result is None:
            status.level, status.message = status.ERROR, error
            values["state"] = "failed"
        else:
            ok = result.succeeded
            status.level = status.OK if ok else status.ERROR
            status.message = result.state.value if ok else f"{result.failure}: {result.reason}"
            values.update(_result_values(result, self.estimator.robot.front_offset if self.estimator else 0.0))
        status.values = [_key_value(k, v) for k, v in values.items()]
        self.pub_result.publish(status)
        self._publish_state(values["state"])
        if status.level == status.OK:
            self.get_logger().info(f"{task}: {status.message}")
        else:
            self.get_logger().error(f"{task}: {status.message}")

    def stop(self, why: str) -> None:
        """Cancel a running mission, wait for its thread, and command zero velocity."""
        with self._lock:
            thread = self._thread
            if thread is not None and thread.is_alive():
                self._cancel = why
        if thread is not None:
            thread.join(timeout=5.0)
        self.robot.stop_and_flush()
        if self.actions is not None:
            self.actions.shutdown()


def _result_values(result: MissionResult, front_offset: float) -> dict[str, str]:
    """The result's key/values: the final pose by the robot's own estimate, counts and the failure."""
    out = {
        "state": result.state.value,
        "failure": result.failure.value if result.failure else "",
        "nav2_error_code": str(result.failure.nav2_error_code if result.failure else 0),
        "retries": str(result.retries),
        "recoveries": str(result.recoveries),
        "reseats": str(result.reseats),
        "duration_s": f"{result.duration:.2f}",
        "charging": "" if result.charging is None else str(result.charging).lower(),
    }
    final = result.estimated_final
    if final is not None:
        out["lateral_cm"] = f"{100 * final.y:.2f}"
        out["gap_cm"] = f"{100 * (-final.x - front_offset):.2f}"  # front edge to the face, + short of it
        out["heading_deg"] = f"{math.degrees(final.theta):.2f}"
    return out


def _key_value(key: str, value: str) -> Any:
    from diagnostic_msgs.msg import KeyValue  # type: ignore[import-not-found, unused-ignore]

    return KeyValue(key=key, value=value)


def _check_calibration(options: DockOptions) -> None:
    if options.method == "regression":
        raise InputError(f"the {options.method} method needs a model bundle (model:=BUNDLE)")
    missing = [k for k in ("layout", "robot") if not getattr(options, k)]
    if missing:
        raise InputError(f"without a model bundle, give {' and '.join(missing)} (and a camera, or camera_info)")


def run_dock(options: DockOptions, argv: Sequence[str]) -> int:
    """Run the node until shut down; ``argv`` carries the ROS arguments. 0 on shutdown, 2 on bad options."""
    from rclpy.executors import SingleThreadedExecutor  # type: ignore[import-not-found, unused-ignore]
    from rclpy.signals import SignalHandlerOptions  # type: ignore[import-not-found, unused-ignore]

    # monodock handles SIGINT and SIGTERM itself: rclpy's handlers would shut the context down before the last
    # zero velocity could be published.
    rclpy.init(args=list(argv), signal_handler_options=SignalHandlerOptions.NO)
    stop = ShutdownFlag()
    node: DockNode | None = None
    try:
        node = DockNode(options)
        node.get_logger().info(f"ready: docking with {node.method or 'the camera from camera_info'}")
        # One executor for the node's life: rclpy.spin_once(node) adds and removes the node on every call, and
        # odometry, the clock and the sensors bring a few hundred callbacks a second.
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
            node.spins += 1
    except MonodockError as exc:
        print(f"monodock-dock-ros: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # a Ctrl-C before the flag was installed
        pass
    finally:
        if node is not None:
            node.stop("cancelled: the node is shutting down")
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
