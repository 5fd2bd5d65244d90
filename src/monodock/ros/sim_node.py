"""``monodock-sim-ros`` (node ``monodock_sim``): the simulator as a robot on a ROS 2 graph.

The simulated differential drive (``monodock.sim.diffdrive``) runs in real time (``monodock.sim.realtime``): its
camera publishes every frame ``camera_latency`` after the exposure, stamped with the exposure time; odometry,
the rear range, the contact switch, the battery's charging state and the ground truth go out every control
period (50 Hz), ``/clock`` with them. It drives by ``cmd_vel`` (TwistStamped, or Twist with
``enable_stamped_cmd_vel: false``) through the base's latency, lag and slip, and
stops when ``cmd_vel`` falls silent for ``cmd_vel_timeout`` simulated seconds, as real bases do. Its stamps are the
wall clock at the start plus the simulated time. Real-time pacing keeps the two together on an idle machine; on a
busy one the simulation runs slower than the wall clock and never catches up in a burst (``monodock.sim.realtime``),
so nodes that time sensor data against their own clock run with ``use_sim_time`` on the ``/clock`` it publishes, as
with any simulator. Its real-time factor goes to ``/diagnostics`` every second, and into the log (once) when it
falls below ``REAL_TIME_WARNING``.

Faults on demand: ``~/silence_camera`` and ``~/silence_odometry`` (std_srvs/SetBool) stop and restart those
topics.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.interface import CameraFrame, Odometry
from monodock.errors import MonodockError
from monodock.recording.messages import split_stamp
from monodock.ros._rclpy import Node, rclpy
from monodock.ros.parameters import Parameter, declare_settings, parameters_of
from monodock.ros.shutdown import ShutdownFlag
from monodock.ros.sim_settings import CHARGING_CURRENT, DRAIN_CURRENT, SimSettings
from monodock.ros.tf import set_transform
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.nuisance import Nuisances
from monodock.sim.realtime import RealTimeRunner
from monodock.sim.simulator import Simulator

__all__ = [
    "PARAMETERS",
    "SimNode",
    "run_sim",
]


# SimSettings' parameters: read once, at start-up (writable as they always were, though a change does nothing).
PARAMETERS: dict[str, Parameter] = parameters_of(SimSettings)


# A real-time factor below this is said once in the log (and again after it recovers above REAL_TIME_RECOVERED).
REAL_TIME_WARNING = 0.9
REAL_TIME_RECOVERED = 0.98


def _stamp(msg_time: Any, seconds: float) -> Any:
    msg_time.sec, msg_time.nanosec = split_stamp(seconds)
    return msg_time


def _quaternion(q: Any, yaw: float) -> Any:
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)
    return q


class SimNode(Node):  # type: ignore[misc, unused-ignore]
    """Publishes the simulated robot's sensors and drives it by ``cmd_vel``."""

    def __init__(self) -> None:
        super().__init__("monodock_sim")
        from geometry_msgs.msg import PoseStamped, Twist, TwistStamped  # type: ignore[import-not-found, unused-ignore]
        from nav_msgs.msg import Odometry as OdometryMsg  # type: ignore[import-not-found, unused-ignore]
        from rosgraph_msgs.msg import Clock  # type: ignore[import-not-found, unused-ignore]
        from sensor_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            BatteryState,
            CameraInfo,
            Image,
            Range,
        )
        from std_msgs.msg import Bool  # type: ignore[import-not-found, unused-ignore]

        self.msgs = {
            "PoseStamped": PoseStamped,
            "Odometry": OdometryMsg,
            "Clock": Clock,
            "BatteryState": BatteryState,
            "CameraInfo": CameraInfo,
            "Image": Image,
            "Range": Range,
            "Bool": Bool,
        }
        self.settings = declare_settings(self, SimSettings())
        s = self.settings
        sim = Simulator(
            layout=DockLayout.load(s.layout) if s.layout else DockLayout.default(),
            camera=CameraModel.load(s.camera) if s.camera else CameraModel.default(),
            robot=RobotConfig.load(s.robot) if s.robot else RobotConfig.default(),
            seed=s.seed,
            nuisances=Nuisances.clean() if s.nuisances == "clean" else Nuisances(),
        )
        self.robot = SimulatedRobot(
            sim, Pose2D(*s.start), DiffDriveConfig(camera_rate=s.camera_rate), np.random.default_rng(s.seed)
        )
        self.epoch = time.time()  # ROS time = this + simulated time
        self.last_cmd: tuple[float, float, float] | None = None  # (simulated time, v, w)
        self.stop: ShutdownFlag | None = None  # SIGINT/SIGTERM, checked between steps
        qos_sensor = rclpy.qos.qos_profile_sensor_data
        self.pub_image = self.create_publisher(Image, "image", qos_sensor)
        self.pub_info = self.create_publisher(CameraInfo, "camera_info", qos_sensor)
        self.pub_odom = self.create_publisher(OdometryMsg, "odom", 10)
        self.pub_truth = self.create_publisher(PoseStamped, "ground_truth", 10)
        self.pub_battery = self.create_publisher(BatteryState, "battery_state", 10)
        self.pub_contact = self.create_publisher(Bool, "contact", 10)
        self.pub_range = self.create_publisher(Range, "rear_range", qos_sensor)
        self.pub_clock = self.create_publisher(Clock, "/clock", 10)
        from diagnostic_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            DiagnosticArray,
            DiagnosticStatus,
            KeyValue,
        )

        self.msgs.update(DiagnosticArray=DiagnosticArray, DiagnosticStatus=DiagnosticStatus, KeyValue=KeyValue)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.slow = False  # the real-time factor is below REAL_TIME_WARNING (said once)
        self.worst_factor = math.inf
        twist = TwistStamped if s.enable_stamped_cmd_vel else Twist
        self.create_subscription(twist, "cmd_vel", self._on_cmd_vel, 1)  # the latest command wins: no backlog
        self.pub_tf = self._tf_publishers(sim.robot)
        # Faults on demand (std_srvs/SetBool, true silences): a camera or an odometry that stops publishing.
        from std_srvs.srv import SetBool  # type: ignore[import-not-found, unused-ignore]

        self.silenced: set[str] = set()
        for name in ("camera", "odometry"):
            self.create_service(SetBool, f"~/silence_{name}", self._silencer(name))
        from rclpy.executors import (  # type: ignore[import-not-found, unused-ignore]
            ExternalShutdownException,
            ShutdownException,
            SingleThreadedExecutor,
            TimeoutException,
        )

        self._executor = SingleThreadedExecutor()  # its own: rclpy.spin_once adds and removes the node every call
        self._executor.add_node(self)
        self._nothing_ready = (TimeoutException, ShutdownException, ExternalShutdownException)

    def _tf_publishers(self, robot: RobotConfig) -> Any:
        """/tf (odom -> base_link, with each odometry) and, latched, /tf_static (base_link -> camera_link -> the
        optical frame, from the robot file the simulator renders with); None without tf2_msgs (built at install)."""
        try:
            from tf2_msgs.msg import TFMessage  # type: ignore[import-not-found, unused-ignore]
        except ImportError as exc:
            self.get_logger().warning(f"no /tf: {exc} (tf2_msgs is built when monodock is installed)")
            return None
        from geometry_msgs.msg import TransformStamped  # type: ignore[import-not-found, unused-ignore]
        from rclpy.qos import DurabilityPolicy, QoSProfile  # type: ignore[import-not-found, unused-ignore]

        self.msgs.update(TFMessage=TFMessage, TransformStamped=TransformStamped)
        s = self.settings
        link_T_optical = np.eye(4)
        link_T_optical[:3, :3] = np.linalg.inv(robot.base_T_camera_link()[:3, :3]) @ robot.base_T_optical()[:3, :3]
        static = TFMessage()
        for parent, child, T in (
            (s.frame_id, s.camera_frame, robot.base_T_camera_link()),
            (s.camera_frame, s.camera_frame_id, link_T_optical),
        ):
            static.transforms.append(set_transform(TransformStamped(), parent, child, T, self.epoch))
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.create_publisher(TFMessage, "/tf_static", latched).publish(static)
        return self.create_publisher(TFMessage, "/tf", 100)

    def _silencer(self, name: str) -> Any:
        def on_request(request: Any, response: Any) -> Any:
            (self.silenced.add if request.data else self.silenced.discard)(name)
            response.success, response.message = True, f"{name} {'silenced' if request.data else 'publishing'}"
            self.get_logger().info(response.message)
            return response

        return on_request

    def _on_cmd_vel(self, msg: Any) -> None:
        twist = msg.twist if self.settings.enable_stamped_cmd_vel else msg
        v, w = float(twist.linear.x), float(twist.angular.z)
        if math.isfinite(v) and math.isfinite(w):
            self.last_cmd = (self.robot.t, v, w)  # simulated time: callbacks run between physics steps

    def command(self, t: float, _odom: Odometry) -> tuple[float, float]:
        """The latest cmd_vel, or a stop once it is older than the timeout (what real bases do).

        Timed on the simulated clock, as the physics: on a busy machine the simulation falls behind the wall clock,
        and a wall-clock time-out would stop a base whose commands are on time in its own (and /clock's) time.
        """
        if not rclpy.ok() or self.stop:
            raise KeyboardInterrupt  # shut down: leave the runner (raised here, in Python, between steps)
        self._take_messages()
        if self.last_cmd is None or t - self.last_cmd[0] > self.settings.cmd_vel_timeout:
            return (0.0, 0.0)
        return (self.last_cmd[1], self.last_cmd[2])

    def _take_messages(self, most: int = 8) -> None:
        """Run the callbacks of what has arrived (cmd_vel, the silencing services), up to ``most``, and return as
        soon as nothing is ready: one look at the wait set in the usual control period, where spinning a fixed
        eight times cost eight (a fifth of a core at 50 Hz, measured)."""
        for _ in range(most):
            try:
                handler, _, _ = self._executor.wait_for_ready_callbacks(timeout_sec=0.0)
            except self._nothing_ready:
                return
            handler()  # as rclpy's own spin_once does
            error: BaseException | None = handler.exception()
            if error is not None:
                raise error

    def report_real_time(self, factor: float) -> None:
        """The last second's real-time factor: on /diagnostics, and in the log when it drops (and recovers)."""
        self.worst_factor = min(self.worst_factor, factor)
        if factor < REAL_TIME_WARNING and not self.slow:
            self.slow = True
            self.get_logger().warning(
                f"the simulation runs slower than real time: real-time factor {factor:.2f} (the machine is busy); "
                "simulated time goes on at that pace, nodes on use_sim_time keep up with it"
            )
        elif factor >= REAL_TIME_RECOVERED and self.slow:
            self.slow = False
            self.get_logger().info(f"back to real time: real-time factor {factor:.2f}")
        m = self.msgs
        status = m["DiagnosticStatus"]()
        status.name = f"{self.get_fully_qualified_name().lstrip('/')}: real time"
        status.hardware_id = "monodock_sim"
        status.level = status.WARN if factor < REAL_TIME_WARNING else status.OK
        status.message = f"real-time factor {factor:.2f}"
        values = {"real_time_factor": f"{factor:.3f}", "worst_real_time_factor": f"{self.worst_factor:.3f}"}
        status.values = [m["KeyValue"](key=k, value=v) for k, v in values.items()]
        array = m["DiagnosticArray"]()
        _stamp(array.header.stamp, self.ros_seconds(self.robot.t))
        array.status = [status]
        self.pub_diagnostics.publish(array)

    def ros_seconds(self, t: float) -> float:
        return self.epoch + t

    def publish_frame(self, frame: CameraFrame) -> None:
        if "camera" in self.silenced:
            return
        m = self.msgs
        camera = self.robot.sim.camera
        stamp = self.ros_seconds(frame.stamp)
        image = m["Image"]()
        _stamp(image.header.stamp, stamp)
        image.header.frame_id = self.settings.camera_frame_id
        image.height, image.width = int(frame.image.shape[0]), int(frame.image.shape[1])
        image.encoding, image.is_bigendian, image.step = "mono8", 0, int(frame.image.shape[1])
        image.data = np.ascontiguousarray(frame.image).tobytes()
        info = m["CameraInfo"]()
        info.header = image.header
        info.width, info.height = camera.width, camera.height
        info.distortion_model = camera.distortion_model
        info.d = [float(v) for v in np.asarray(camera.dist).ravel()]
        info.k = [float(v) for v in np.asarray(camera.matrix).ravel()]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        projection = np.zeros((3, 4))
        projection[:, :3] = camera.matrix
        info.p = [float(v) for v in projection.ravel()]
        self.pub_image.publish(image)
        self.pub_info.publish(info)

    def publish_state(self, odom: Odometry) -> None:
        m = self.msgs
        stamp = self.ros_seconds(odom.stamp)
        clock = m["Clock"]()
        _stamp(clock.clock, stamp)
        self.pub_clock.publish(clock)
        if "odometry" not in self.silenced:
            self._publish_odometry(odom, stamp)
        self._publish_truth_and_sensors(stamp)

    def _publish_odometry(self, odom: Odometry, stamp: float) -> None:
        o = self.msgs["Odometry"]()
        _stamp(o.header.stamp, stamp)
        o.header.frame_id, o.child_frame_id = self.settings.odom_frame, self.settings.frame_id
        o.pose.pose.position.x, o.pose.pose.position.y = odom.pose.x, odom.pose.y
        _quaternion(o.pose.pose.orientation, odom.pose.theta)
        o.twist.twist.linear.x, o.twist.twist.angular.z = odom.linear, odom.angular
        self.pub_odom.publish(o)
        if self.pub_tf is not None:
            t = self.msgs["TransformStamped"]()
            t.header = o.header
            t.child_frame_id = o.child_frame_id
            t.transform.translation.x, t.transform.translation.y = odom.pose.x, odom.pose.y
            t.transform.rotation = o.pose.pose.orientation
            self.pub_tf.publish(self.msgs["TFMessage"](transforms=[t]))

    def _publish_truth_and_sensors(self, stamp: float) -> None:
        m, robot = self.msgs, self.robot
        truth = robot.dock_pose()
        gt = m["PoseStamped"]()
        _stamp(gt.header.stamp, stamp)
        gt.header.frame_id = self.settings.frame_id
        gt.pose.position.x, gt.pose.position.y = truth.x, truth.y
        _quaternion(gt.pose.orientation, truth.yaw)
        self.pub_truth.publish(gt)
        contact = m["Bool"]()
        contact.data = bool(robot.touching)
        self.pub_contact.publish(contact)
        battery = m["BatteryState"]()
        _stamp(battery.header.stamp, stamp)
        battery.present = True
        charging = robot.charging()
        battery.power_supply_status = (
            battery.POWER_SUPPLY_STATUS_CHARGING if charging else battery.POWER_SUPPLY_STATUS_DISCHARGING
        )
        # Positive current while charging, as Nav2's SimpleChargingDock reads it (current > charging_threshold).
        battery.current = CHARGING_CURRENT if charging else DRAIN_CURRENT
        self.pub_battery.publish(battery)
        rear = robot.rear_range()
        if rear is not None:
            r = m["Range"]()
            _stamp(r.header.stamp, stamp)
            r.header.frame_id = self.settings.rear_range_frame
            r.radiation_type = r.ULTRASOUND
            r.field_of_view = math.radians(robot.config.rear_fov_deg)
            r.min_range, r.max_range = 0.0, robot.config.rear_range_max
            r.range = float(rear) if math.isfinite(rear) else math.inf
            self.pub_range.publish(r)


def run_sim(argv: Sequence[str], duration: float = math.inf) -> int:
    """Run the node until shut down (or ``duration`` simulated seconds)."""
    from rclpy.exceptions import ParameterException  # type: ignore[import-not-found, unused-ignore]
    from rclpy.signals import SignalHandlerOptions  # type: ignore[import-not-found, unused-ignore]

    # SIGINT and SIGTERM end the run loop here, before the context goes (rclpy's handlers would invalidate the
    # publishers mid-step).
    rclpy.init(args=list(argv), signal_handler_options=SignalHandlerOptions.NO)
    stop = ShutdownFlag()
    try:
        node = SimNode()
    except (MonodockError, ValueError, TypeError, ParameterException) as exc:  # a bad parameter or file: one line
        print(f"monodock-sim-ros: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    node.stop = stop
    try:
        runner = RealTimeRunner(node.robot)
        node.robot.sim.render(node.robot.dock_pose())  # load the compiled renderer before the clock starts
        node.epoch = time.time() - node.robot.t  # ROS time starts with the physics, not with the node's set-up
        # One run: the runner paces simulated time by the wall clock; behind it, it goes on at its pace.
        runner.run(
            duration if math.isfinite(duration) else 1e12,
            command=node.command,
            on_frame=node.publish_frame,
            on_odometry=node.publish_state,
            on_real_time_factor=node.report_real_time,
        )
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
