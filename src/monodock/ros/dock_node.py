"""``monodock-dock-ros`` (node ``monodock_dock``): docking and undocking on request, a Nav2 lifecycle node.

Nav2's interface (``monodock.ros.dock_actions``): the ``dock_robot`` and ``undock_robot`` actions
(nav2_msgs/action/DockRobot, UndockRobot) with the goal semantics of Nav2's docking server, the dock database of its
parameters (``monodock.ros.dock_database``) and ``~/reload_database``. The node is a lifecycle node
(``monodock.ros.lifecycle``): ``nav2_lifecycle_manager`` configures and activates it and keeps a bond with it, or it
starts itself (``autostart_node``, true from the command line). Goals and requests are refused unless it is active.

monodock's own services (std_srvs/Trigger; the reply says accepted or why not, the mission runs after it):
``~/dock`` (dock from wherever the robot stands, at the node's default dock), ``~/undock`` (back out to the staging
pose), ``~/cancel`` (stop the running mission; a ``~/dock`` or ``~/undock`` call while one runs cancels it too).

Topics: ``~/state`` (std_msgs/String, transient-local: the state's name on every change, ``idle`` before the first
mission), ``~/result`` (diagnostic_msgs/DiagnosticStatus, transient-local: OK when the mission succeeded, ERROR with
the failure and its Nav2 error code otherwise; the robot's own estimate of the final lateral_cm, gap_cm, heading_deg,
and retries, re-seats, recoveries, duration), the dock filter's pose on ``detected_dock_pose`` (PoseStamped) and
``detected_dock_pose_with_covariance`` in base_link while it tracks the dock, and Nav2's debug topics in the odometry
frame: ``filtered_dock_pose`` (the dock's face), ``dock_pose`` (where base_link stands docked), ``staging_pose``
(in the dock's frame when the database gives it) and ``docking_trajectory`` (nav_msgs/Path: the plan to the dock). It
drives by ``cmd_vel`` (TwistStamped; Twist with ``enable_stamped_cmd_vel: false``) from ``odom``, the camera ``image``
(``camera_info`` when no camera file is given), ``battery_state`` (charging), ``contact`` and ``rear_range``.

The docking config is ROS parameters of the same names as the config file's keys (``planner.standoff``,
``max_reseats``, ...; ``config`` loads a file first); each mission reads them when it starts. Every exit of a mission
commands zero velocity, a shutdown (SIGINT, SIGTERM) included; if the node dies outright, the base's own ``cmd_vel``
time-out stops the robot. Needs rclpy (monodock.ros._rclpy says how to get it).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from monodock.core import settings
from monodock.core.camera import CameraModel
from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig, load_docking_config
from monodock.dock.controller import DockingMission
from monodock.dock.database import DockDatabase, DockType
from monodock.dock.extensions import Dock
from monodock.dock.interface import Odometry
from monodock.dock.pose_filter import MeasurementNoise
from monodock.dock.run import MissionResult, run_mission
from monodock.dock.states import FailureReason, State
from monodock.dock.tracking import make_perceive
from monodock.errors import ConfigError, InputError, MonodockError
from monodock.estimation.estimator import Estimator
from monodock.recording import messages as m
from monodock.ros._rclpy import LifecycleNode, rclpy
from monodock.ros.charging_dock import DockModel, already_docked, simple_charging_dock
from monodock.ros.dock_actions import DOCK_ACTION, UNDOCK_ACTION, DockActions
from monodock.ros.dock_database import declare_database, read_database
from monodock.ros.dock_options import DockOptions
from monodock.ros.lifecycle import ManagerBond, autostart
from monodock.ros.parameters import (
    config_from_parameters,
    declare_config,
    declare_settings,
    refuse_unknown_overrides,
)
from monodock.ros.ros2_robot import ChargingSignal, RobotTopics, Ros2Robot
from monodock.ros.shutdown import ShutdownFlag, spin
from monodock.ros.tf import CameraMountFromTF, TransformListener

__all__ = ["DockNode", "StopCheck", "run_dock"]

# spin_once calls after odometry is first seen stale before it counts as lost: enough for the executor to take the
# callbacks that were already waiting (the clock's, the odometry's and the sensors') in one round.
STALE_SPINS = 8

# Why a running mission must stop, asked of its caller every control step: (reason, words) or None to go on.
StopCheck = Callable[[DockingMission], tuple[FailureReason, str] | None]


class DockNode(LifecycleNode):  # type: ignore[misc, unused-ignore]
    """The long-running docking node: goals and requests in, one mission at a time, state and result out."""

    def __init__(self, options: DockOptions) -> None:
        super().__init__("monodock_dock")
        from sensor_msgs.msg import CameraInfo  # type: ignore[import-not-found, unused-ignore]

        self.options = declare_settings(self, options)
        base = load_docking_config(self.options.config) if self.options.config else DockingConfig()
        self._config_names = list(settings.flat(base))
        self._config_base = base
        self._estimators: dict[str, Estimator] = {}  # by layout file ("": the node's own)
        self.estimator: Estimator | None = None
        self.method = ""
        self._file_robot: RobotConfig | None = None  # the robot file's (or the bundle's), before /tf_static
        self._tf_waited = False  # the first mission waits for /tf_static's camera chain
        self.spins = 0  # the executor's spin_once calls, counted by run_dock: see _odometry_lost
        self._stale_at_spin: int | None = None
        self._camera_info: Any = None
        if self.options.model or self.options.camera:
            self._make_estimator(None)
        else:
            _check_calibration(self.options)
            self.create_subscription(
                CameraInfo,
                self.options.camera_info_topic,
                lambda msg: setattr(self, "_camera_info", msg),
                rclpy.qos.qos_profile_sensor_data,
            )
        self._declare_config()
        self.docking_config()  # a bad value in the parameters or the config file: refused before anything runs
        declare_database(self, self.options.dock_type)
        self.database: DockDatabase = read_database(self, self.options.dock_id)  # a bad one: refused here too
        refuse_unknown_overrides(self)
        self.add_on_set_parameters_callback(self._check_new_parameters)
        self._create_interfaces()
        self.active = False  # the lifecycle state is active: goals and requests are served
        self.closing = False  # the node is going away: nothing more is published
        self._publishing = threading.Lock()
        self.mission_lock = threading.Lock()  # held while a mission runs (one at a time)
        self._thread: threading.Thread | None = None  # a Trigger-started mission's thread
        self._mission: DockingMission | None = None
        self._cancel: str | None = None  # why the running mission must stop, set by another thread
        self._stop_check: StopCheck | None = None
        self._on_mission_tick: Callable[[DockingMission], None] | None = None
        self.docked_at: Pose2D | None = None  # where (odometry) the last successful docking ended
        self.docked_type: DockType | None = None
        self.dock_model: DockModel = simple_charging_dock  # another Dock plugs in here
        self._state = ""
        self._publish_state("idle")
        self.bond = ManagerBond(self, self.options.bond_heartbeat_period)
        self.actions = self._action_servers()
        if self.options.autostart_node:
            autostart(self)

    def _create_interfaces(self) -> None:
        """The robot's topics, TF, what the node publishes and monodock's services."""
        from diagnostic_msgs.msg import DiagnosticStatus  # type: ignore[import-not-found, unused-ignore]
        from geometry_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            PoseStamped,
            PoseWithCovarianceStamped,
        )
        from nav_msgs.msg import Path  # type: ignore[import-not-found, unused-ignore]
        from rclpy.qos import DurabilityPolicy, QoSProfile  # type: ignore[import-not-found, unused-ignore]
        from std_msgs.msg import String  # type: ignore[import-not-found, unused-ignore]
        from std_srvs.srv import Trigger  # type: ignore[import-not-found, unused-ignore]

        self._msgs = {"String": String, "DiagnosticStatus": DiagnosticStatus, "PoseStamped": PoseStamped, "Path": Path}
        self._pose_cov = PoseWithCovarianceStamped
        o = self.options
        self.robot = Ros2Robot(
            self,
            RobotTopics(
                odom=o.odom_topic,
                cmd_vel=o.cmd_vel_topic,
                image=o.subscribed_image_topic,
                image_is_compressed=o.image_is_compressed,
                battery=o.battery_topic,
                contact=o.contact_topic,
                rear_range=o.rear_range_topic,
                frame_id=o.frame_id,
                sensor_timeout=o.sensor_timeout,
                stamped_cmd_vel=o.enable_stamped_cmd_vel,
            ),
        )
        tolerance = (o.mount_tolerance_m, o.mount_tolerance_deg)
        self.mount = CameraMountFromTF(self, o.frame_id, source=o.camera_mount_source, tolerance=tolerance)
        self.tf = TransformListener(self)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_state = self.create_publisher(String, "~/state", latched)
        self.pub_result = self.create_publisher(DiagnosticStatus, "~/result", latched)
        self.pub_pose = self.create_publisher(PoseStamped, o.pose_topic, 10)
        self.pub_pose_cov = self.create_publisher(PoseWithCovarianceStamped, o.pose_covariance_topic, 10)
        # Nav2's debug topics (SimpleChargingDock's and the controller's names).
        self.pub_debug = {
            name: self.create_publisher(PoseStamped, name, 1)
            for name in ("dock_pose", "filtered_dock_pose", "staging_pose")
        }
        self.pub_trajectory = self.create_publisher(Path, "docking_trajectory", 1)
        from diagnostic_msgs.msg import DiagnosticArray, KeyValue  # type: ignore[import-not-found, unused-ignore]

        self._msgs.update(DiagnosticArray=DiagnosticArray, KeyValue=KeyValue)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_service(Trigger, "~/dock", lambda _req, res: self._start("dock", res))
        self.create_service(Trigger, "~/undock", lambda _req, res: self._start("undock", res))
        self.create_service(Trigger, "~/cancel", self._on_cancel)

    def _action_servers(self) -> DockActions | None:
        """Nav2's DockRobot/UndockRobot servers, when the interfaces were built at install time."""
        try:
            return DockActions(self)
        except ImportError as exc:
            self.get_logger().warning(
                f"no {DOCK_ACTION}/{UNDOCK_ACTION} action servers: {exc} (nav2_msgs is built when monodock is "
                "installed; interfaces/README.md). The ~/dock and ~/undock services work."
            )
            return None

    # --- lifecycle ----------------------------------------------------------------------------

    def on_configure(self, _state: Any) -> Any:
        """Read the docking config and the dock database again (they may have changed since the node started)."""
        from rclpy.lifecycle import TransitionCallbackReturn  # type: ignore[import-not-found, unused-ignore]

        try:
            self.docking_config()
            self.database = read_database(self, self.options.dock_id)
        except MonodockError as exc:
            self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        types, docks = len(self.database.types), len(self.database.docks)
        self.get_logger().info(f"Configured: {types} dock type(s) and {docks} dock(s) available.")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, _state: Any) -> Any:
        from rclpy.lifecycle import TransitionCallbackReturn  # type: ignore[import-not-found, unused-ignore]

        self.active = True
        self.bond.create()
        self.get_logger().info(f"Activated: docking with {self.method or 'the camera from camera_info'}")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, _state: Any) -> Any:
        return self._stand_down("cancelled: the node is being deactivated")

    def on_cleanup(self, _state: Any) -> Any:
        from rclpy.lifecycle import TransitionCallbackReturn  # type: ignore[import-not-found, unused-ignore]

        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, _state: Any) -> Any:
        return self._stand_down("cancelled: the node is shutting down")

    def _stand_down(self, why: str) -> Any:
        """Deactivation and shutdown alike: stop serving, a running mission cancelled with ``why`` (the robot stops)
        before the node is inactive, and the bond to the lifecycle manager ended."""
        from rclpy.lifecycle import TransitionCallbackReturn  # type: ignore[import-not-found, unused-ignore]

        self.active = False
        self.halt(why)
        self.bond.destroy()
        return TransitionCallbackReturn.SUCCESS

    # --- set-up -------------------------------------------------------------------------------

    def _declare_config(self) -> None:
        """The docking config's keys as parameters, defaulting to the config file's (or the built-in) values.

        The measurement noise defaults to the method's own (``MeasurementNoise.for_method``) unless the config file
        sets it; the method is known once the estimator is.
        """
        base = self._config_base
        if not self.options.config and self.method:
            base = dataclasses.replace(base, measurement=MeasurementNoise.for_method(self.method))
        declare_config(self, base)

    def docking_config(self) -> DockingConfig:
        """The docking config of the parameters as they are now (checked like a config file)."""
        return config_from_parameters(self, DockingConfig, self._config_names)

    def _check_new_parameters(self, parameters: list[Any]) -> Any:
        """Refuse a live change that would make the docking config invalid (it would only fail at the next ~/dock)."""
        from rcl_interfaces.msg import SetParametersResult  # type: ignore[import-not-found, unused-ignore]

        try:
            config_from_parameters(self, DockingConfig, self._config_names, {p.name: p.value for p in parameters})
        except MonodockError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _make_estimator(self, camera: CameraModel | None, robot: RobotConfig | None = None) -> None:
        self.estimator = self.options.estimator(camera, robot)
        self.method = self.estimator.method
        self.estimator.warm_up()
        self._estimators = {"": self.estimator}
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

    def _ensure_estimator(self) -> None:
        """The estimator, with the camera from camera_info when no camera file was given (waits a little for it)."""
        if self.estimator is not None:
            return
        end = time.monotonic() + max(2.0, 3 * self.options.sensor_timeout)
        camera = None
        while camera is None and time.monotonic() < end:
            msg = self._camera_info
            camera = None if msg is None else m.camera_from_msg(msg, rectified=self.options.image_is_rectified)
            if camera is None:
                time.sleep(0.02)
        if camera is None:
            raise InputError(f"no calibrated camera_info on {self.options.camera_info_topic}")
        self._make_estimator(camera)
        self.get_logger().info(f"camera {camera.width}x{camera.height} from camera_info; docking with {self.method}")

    def estimator_for(self, layout: str) -> Estimator:
        """The estimator of a dock's layout file ("": the node's own), made once and kept.

        Raises:
            MonodockError: the layout cannot be read, or a model bundle was trained for another layout.
        """
        self._ensure_estimator()
        self._mount_from_tf()
        assert self.estimator is not None
        if not layout or layout == self.options.layout:
            return self.estimator
        found = self._estimators.get(layout)
        if found is None or found.robot != self.estimator.robot:
            found = dataclasses.replace(self.options, layout=layout).estimator(
                self.estimator.camera, self.estimator.robot
            )
            found.warm_up()
            self._estimators[layout] = found
        return found

    # --- the robot on its dock --------------------------------------------------------------

    def is_docked(self, dock_type: DockType) -> bool:
        """Whether the robot stands on a dock of ``dock_type`` (``already_docked``: charging by ``dock_for``'s dock,
        the contact switch closed, or within ``docking_threshold`` of where the last docking ended)."""
        return already_docked(self.dock_for(dock_type), self.robot, self.docked_at, dock_type.docking_threshold)

    def dock_for(self, dock_type: DockType, config: DockingConfig | None = None) -> Dock:
        """The model of a dock of ``dock_type`` by ``dock_model`` (Nav2's dock plugin; ``SimpleChargingDock``)."""
        robot = self.estimator.robot if self.estimator is not None else RobotConfig()
        return self.dock_model(dock_type, config or self.docking_config(), robot.front_offset)

    def now(self) -> float:
        """The node's clock (ROS time), in seconds."""
        return self.robot.now()

    # --- monodock's services ------------------------------------------------------------------

    def _start(self, task: str, response: Any) -> Any:
        """A Trigger request: a call while a mission runs cancels it (and starts nothing)."""
        if not self.active:
            response.success, response.message = False, "the node is not active (configure and activate it first)"
            return response
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

    def start_mission(self, task: str) -> None:
        """Start a dock or undock mission at the node's default dock, in a thread of its own.

        Raises:
            InputError: a mission runs already, the docking config is invalid, or an undock while not docked.
        """
        if self.mission_lock.locked():
            raise InputError(f"a {self._mission_task()} mission is running: cancel it first")
        first = next(iter(self.database.types.values()))
        dock_type, layout = self.docked_type or first, ""
        found = self.database.docks.get(self.options.dock_id)
        if task == "dock" and found is not None:  # the default dock: its type, its layout
            dock_type, layout = self.database.find_type(found.type) or first, found.layout
        self.docking_config()
        if task == "undock" and not self.is_docked(dock_type):
            raise InputError("not docked: no docking mission ended docked and the charger does not report charging")

        def run() -> None:
            with contextlib.suppress(MonodockError):  # published on ~/result and logged by run_mission
                self.run_mission(task, dock_type, layout)

        self._thread = threading.Thread(target=run, name=f"monodock-{task}")
        self._thread.start()
        end = time.monotonic() + 1.0
        while not self.mission_lock.locked() and self._thread.is_alive() and time.monotonic() < end:
            time.sleep(0.002)  # the reply says "started" once the mission holds the lock

    def cancel_mission(self, why: str) -> bool:
        """Ask the running mission to stop (it commands zero velocity and ends CANCELLED); False if none runs."""
        if not self.mission_lock.locked():
            return False
        self._cancel = why
        return True

    def _on_cancel(self, _request: Any, response: Any) -> Any:
        if not self.cancel_mission("cancelled by request"):
            response.success, response.message = False, "no mission is running"
            return response
        response.success, response.message = True, f"cancelled the running {self._mission_task()} mission"
        return response

    def _mission_task(self) -> str:
        return self._mission.task if self._mission is not None else "starting"

    # --- the mission ------------------------------------------------------------------------

    def run_mission(
        self,
        task: str,
        dock_type: DockType,
        layout: str = "",
        *,
        stop_check: StopCheck | None = None,
        on_tick: Callable[[DockingMission], None] | None = None,
    ) -> MissionResult:
        """One mission, start to end, in the caller's thread; zero velocity whatever happens. ``stop_check`` is
        asked every control step why the mission must stop, ``on_tick`` told of every step.

        Raises:
            MonodockError: a mission runs already, or it cannot start (no camera, no odometry, a bad config or
                layout); published on ~/result as well.
        """
        if not self.mission_lock.acquire(blocking=False):
            raise InputError(f"a {self._mission_task()} mission is running: cancel it first")
        robot = self.robot
        try:
            self._cancel = None
            config = self.docking_config()
            estimator = self.estimator_for(layout or dock_type.layout)
            if not robot.wait_for_odometry(max(2.0, self.options.odom_timeout)) or robot.now() <= 0.0:
                raise InputError(f"no odometry on {self.options.odom_topic}")
            robot.charging_signal = ChargingSignal(dock_type.charging_threshold, dock_type.use_battery_status)
            blind = blind_gap(estimator.camera, estimator.layout, estimator.robot)
            mission = DockingMission(config, estimator.robot, blind, task=task, dock=self.dock_for(dock_type, config))
            self._stale_at_spin = None
            self._mission, self._stop_check, self._on_mission_tick = mission, stop_check, on_tick
            self._publish_state(mission.state.value)
            robot.watch(True)
            track = (lambda: mission.track) if config.approach.predicted_markers else None
            perceive = make_perceive(estimator, estimator.method, track=track)

            def timed(stamp: float, image: np.ndarray) -> Any:
                started = time.perf_counter()
                observation = perceive(stamp, image)
                robot.camera_stats.on_perceived(time.perf_counter() - started, robot.now() - stamp)
                return observation

            result = run_mission(robot, timed, mission, on_tick=self._on_tick)
            if result.failure in _LOST_MARKERS:  # did the frames come and go unseen, or never come?
                explained = robot.camera_stats.explain(robot.now(), config.watch.lost_timeout)
                result = dataclasses.replace(result, reason=f"{result.reason}; {explained}")
            self._remember(result, dock_type)
            self._publish_result(task, result, "")
            return result
        except MonodockError as exc:
            self._publish_result(task, None, str(exc))
            raise
        finally:
            robot.watch(False)
            robot.send_velocity(0.0, 0.0)
            self._stop_check = self._on_mission_tick = None
            self.mission_lock.release()

    def _remember(self, result: MissionResult, dock_type: DockType) -> None:
        """Where the robot docked (for ``is_docked``), or that it left the dock."""
        if result.docked and self.robot.odom.value is not None:
            self.docked_at, self.docked_type = self.robot.odometry().pose, dock_type
        elif result.state is State.UNDOCKED:
            self.docked_at, self.docked_type = None, None

    def _on_tick(self, mission: DockingMission, odom: Odometry) -> None:
        """After each control step: stop on cancel, lost odometry or the caller's word; publish the state, the dock
        filter's pose and the debug topics."""
        now = self.robot.now()
        stop = self._stop_check(mission) if self._stop_check is not None else None
        if self._cancel is not None:
            mission.abort(now, FailureReason.CANCELLED, self._cancel)
        elif stop is not None:
            mission.abort(now, *stop)
        elif self._odometry_lost():
            age = self.robot.odometry_age()
            mission.abort(now, FailureReason.ODOMETRY_LOST, f"no odometry for {age:.2f} s")
        if mission.state.value != self._state:
            self._publish_state(mission.state.value)
        self._publish_pose(mission, odom)
        if self._on_mission_tick is not None:
            self._on_mission_tick(mission)

    def count_spin(self) -> None:
        """One more ``spin_once`` of the executor (run_dock's loop calls it after each)."""
        self.spins += 1

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

    # --- what it publishes --------------------------------------------------------------------

    def _publish(self, publisher: Any, msg: Any) -> None:
        """Publish unless the node is closing (a mission thread that outlives ``stop`` publishes nothing)."""
        with self._publishing:
            if not self.closing:
                publisher.publish(msg)

    def _publish_state(self, state: str) -> None:
        self._state = state
        msg = self._msgs["String"]()
        msg.data = state
        self._publish(self.pub_state, msg)

    def _stamped(self, frame: str, stamp: float, pose: Pose2D) -> Any:
        out = self._msgs["PoseStamped"]()
        out.header.stamp.sec, out.header.stamp.nanosec = m.split_stamp(stamp)
        out.header.frame_id = frame
        out.pose.position.x, out.pose.position.y = pose.x, pose.y
        out.pose.orientation.z, out.pose.orientation.w = math.sin(0.5 * pose.theta), math.cos(0.5 * pose.theta)
        return out

    def publish_staging_pose(self, frame: str, pose: Pose2D) -> None:
        """Nav2's ``staging_pose`` debug topic."""
        self._publish(self.pub_debug["staging_pose"], self._stamped(frame, self.now(), pose))

    def _publish_pose(self, mission: DockingMission, odom: Odometry) -> None:
        placed = mission.track.dock_at(odom.stamp)  # the filtered dock in base_link at this odometry
        if placed is None:
            return
        dock, cov = placed
        out = self._stamped(self.options.frame_id, odom.stamp, Pose2D(dock.x, dock.y, dock.yaw))
        self._publish(self.pub_pose, out)
        with_cov = self._pose_cov()
        with_cov.header = out.header
        with_cov.pose.pose = out.pose
        full = np.zeros((6, 6))
        index = [0, 1, 5]  # x, y, yaw in ROS's (x, y, z, roll, pitch, yaw)
        full[np.ix_(index, index)] = cov
        with_cov.pose.covariance = [float(v) for v in full.ravel()]
        self._publish(self.pub_pose_cov, with_cov)
        self._publish_debug(mission, odom)

    def _publish_debug(self, mission: DockingMission, odom: Odometry) -> None:
        """Nav2's debug topics in the odometry frame: the dock's face, where base_link stands docked, and the plan."""
        face = mission.track.mean
        if face is None:
            return
        frame = str(self.robot.odom.value.header.frame_id) if self.robot.odom.value is not None else "odom"
        docked = face.compose(Pose2D(-mission.robot.front_offset, 0.0, 0.0))
        self._publish(self.pub_debug["filtered_dock_pose"], self._stamped(frame, odom.stamp, face))
        self._publish(self.pub_debug["dock_pose"], self._stamped(frame, odom.stamp, docked))
        path = self._msgs["Path"]()
        path.header = self._stamped(frame, odom.stamp, docked).header
        waypoints = [odom.pose]
        if mission.manoeuvre is not None and mission.state.value.startswith(("moving1", "moving2")):
            waypoints.append(face.compose(mission.manoeuvre.point_a))
        waypoints.append(docked)
        path.poses = [self._stamped(frame, odom.stamp, p) for p in waypoints]
        self._publish(self.pub_trajectory, path)

    def _publish_diagnostics(self) -> None:
        """Every second: the state and what became of the camera's frames during the last (or running) mission:
        frames arrived, perceived and dropped, the time to perceive one and its age by then. WARN when most frames
        were dropped or perceived over half a second old (the node cannot keep up: a busy machine)."""
        m = self._msgs
        stats = self.robot.camera_stats.values()
        status = m["DiagnosticStatus"]()
        status.name = f"{self.get_fully_qualified_name().lstrip('/')}: docking"
        status.hardware_id = self.options.frame_id
        arrived, dropped = int(stats["frames_arrived"]), int(stats["frames_dropped"])
        lag = float(stats["lag_p95_ms"] or 0.0)
        behind = arrived > 10 and (dropped > arrived / 2 or lag > 500.0)
        status.level = status.WARN if behind else status.OK
        status.message = f"{self._state}" + (": perception falling behind" if behind else "")
        values = {"state": self._state, "mission": str(self.mission_lock.locked()).lower(), **stats}
        status.values = [m["KeyValue"](key=k, value=v) for k, v in values.items()]
        array = m["DiagnosticArray"]()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._publish(self.pub_diagnostics, array)

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
        self._publish(self.pub_result, status)
        self._publish_state(values["state"])
        if status.level == status.OK:
            self.get_logger().info(f"{task}: {status.message}")
        else:
            self.get_logger().error(f"{task}: {status.message}")

    # --- the end ------------------------------------------------------------------------------

    def halt(self, why: str, timeout: float = 5.0) -> None:
        """Cancel a running mission and wait (at most ``timeout``) until it has stopped the robot."""
        self.cancel_mission(why)
        end = time.monotonic() + timeout
        while self.mission_lock.locked() and time.monotonic() < end:
            time.sleep(0.01)

    def stop(self, why: str) -> None:
        """The node is going away: stop the actions, cancel a running mission, command zero velocity that reaches
        the base, and publish nothing more."""
        self.active = False
        if self.actions is not None:
            self.actions.stop_serving()
        self.halt(why)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.robot.stop_and_flush()
        with self._publishing:
            self.closing = True
        if self.actions is not None:
            self.actions.shutdown()
        self.bond.close()


_LOST_MARKERS = (FailureReason.MARKERS_LOST, FailureReason.DOCK_LOST, FailureReason.NOT_FOUND)


def _result_values(result: MissionResult, front_offset: float) -> dict[str, str]:
    """The result's key/values: the final pose by the robot's own estimate, counts and the failure."""
    out = {
        "state": result.state.value,
        "failure": result.failure.value if result.failure else "",
        "nav2_error_code": str(int(result.failure.nav2_error_code) if result.failure else 0),
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
    stop = ShutdownFlag()
    rclpy.init(args=list(argv), signal_handler_options=SignalHandlerOptions.NO)
    node: DockNode | None = None
    try:
        node = DockNode(options)
        state = "starting" if node.options.autostart_node else "waiting for a lifecycle manager to configure it"
        node.get_logger().info(f"ready ({state})")
        # One executor for the node's life: rclpy.spin_once(node) adds and removes the node on every call, and
        # odometry, the clock and the sensors bring a few hundred callbacks a second.
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin(executor, stop, each=node.count_spin)
    except (MonodockError, ConfigError) as exc:
        print(f"monodock-dock-ros: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.stop("cancelled: the node is shutting down")
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
