"""The Nav2 recipe (config/nav2_docking_server*.yaml, docs/ros2.md "Nav2's docking server"), judged by the simulator.

No Nav2 runs here (no ros-kilted-* wheel carries it), so the docking server's arithmetic is transcribed, line by
line, from its source: ros-navigation/navigation2, branch ``kilted``, commit
71a1d84f49dc48e226c96619188ee12054824ff3 (2026-01-27). Paths below are relative to ``nav2_docking/opennav_docking/``
unless they name another package (``nav2_graceful_controller/``, ``nav2_util/``). The tf2 helpers it calls are
transcribed from ros2/geometry2 at 1b005c6556cf350d7670812ef30eefed8443a759 (``rolling``, 2024-10-15; Kilted has
the same code, its headers renamed ``.hpp``). Each transcribed line cites the file and lines it follows.

What the tests check, against the simulator's truth (never monodock against itself):

- the two params files load with rclpy's own params-file parser, every key is one the docking server declares,
  with the type it declares, and the values a docking with monodock's detector needs are set;
- images the simulator renders from robot poses 0.4-2 m before the dock, ±20°, estimated by monodock's
  estimator and pushed through SimpleChargingDock's getRefinedPose with the sim recipe's values, give a docking
  pose within a few millimetres and a fraction of a degree of the robot's true docked pose; the staging poses are
  where docs/ros2.md says;
- the final approach, with the docking server's loop, controller and plugin transcribed and the simulated robot
  driven by it, ends by charging, before ``external_detection_timeout`` runs out in the blind zone.

The pytest process never imports rclpy (tests/conftest.py): the parser runs in a child process.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.core.robot import RobotConfig
from monodock.dock.planner import PlannerConfig
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import make_estimator
from monodock.ros.sim_settings import CHARGING_CURRENT, DRAIN_CURRENT, SimSettings
from monodock.sim import Simulator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "config" / "nav2_docking_server.yaml"
SIM = ROOT / "config" / "nav2_docking_server_sim.yaml"
NODE = "docking_server"
EPOCH = 1.7e9  # s: ROS time at the simulated start (a stamp of 0 is a message never received)
DETECTOR_LATENCY = 0.03  # s from an image's arrival to its pose on detected_dock_pose (monodock-ros's estimation)

Quat = tuple[float, float, float, float]  # x, y, z, w, as geometry_msgs/Quaternion
Params = dict[str, tuple[str, Any]]  # name -> (rcl_interfaces ParameterType name, value)


# --- the params files, as a ROS 2 node reads them ---------------------------------------------------------------

_PARSE = """
import json, sys
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python
names = {v: k for k, v in vars(ParameterType).items() if k.startswith("PARAMETER_")}
out = {}
for path in sys.argv[2:]:
    params = parameter_dict_from_yaml_file(path, target_nodes=[sys.argv[1]])
    out[path] = {n: [names[p.value.type], parameter_value_to_python(p.value)] for n, p in params.items()}
print(json.dumps(out))
"""


def _rclpy_parse(*paths: Path) -> dict[str, Params]:
    """Each file's parameters for node docking_server by rclpy's params-file parser (in a child process)."""
    done = subprocess.run(
        [sys.executable, "-c", _PARSE, NODE, *map(str, paths)], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    parsed = json.loads(done.stdout)
    return {p: {k: (t, v) for k, (t, v) in parsed[str(p)].items()} for p in map(str, paths)}


def _flatten(tree: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


@functools.cache
def _parsed(path: Path) -> dict[str, Any]:
    if importlib.util.find_spec("rclpy") is not None:  # finds, does not import
        return {k: v for k, (_, v) in _rclpy_parse(path)[str(path)].items()}
    tree = yaml.safe_load(path.read_text(encoding="utf-8"))[NODE]["ros__parameters"]
    return dict(_flatten(tree))


def _values(path: Path) -> dict[str, Any]:
    """The file's values by name: rclpy's parser when rclpy is installed, else the same nesting rule by PyYAML."""
    return dict(_parsed(path))


# What the docking server declares, with the upstream default (its type is the type a params file must give), by
# the file and lines that declare it. A key not here is ignored by the node without a word, a key of another type
# makes it throw at start-up: both are checked.
_SERVER = {  # src/docking_server.cpp:32-45
    "controller_frequency": 50.0,
    "initial_perception_timeout": 5.0,
    "wait_charge_timeout": 5.0,
    "dock_approach_timeout": 30.0,
    "rotate_to_dock_timeout": 10.0,
    "undock_linear_tolerance": 0.05,
    "undock_angular_tolerance": 0.05,
    "max_retries": 3,
    "base_frame": "base_link",
    "fixed_frame": "odom",
    "dock_prestaging_tolerance": 0.5,
    "odom_topic": "odom",
    "rotation_angular_tolerance": 0.05,
    "enable_stamped_cmd_vel": True,  # nav2_util/include/nav2_util/twist_publisher.hpp:62-64
    "navigator_bt_xml": "",  # src/navigator.cpp:27-28
    "dock_plugins": ["name"],  # src/dock_database.cpp:156-158 (a string array, no default)
    "docks": ["name"],  # src/dock_database.cpp:217-219
    "dock_database": "",  # src/dock_database.cpp:198-200
    "use_sim_time": False,  # every ROS 2 node
}
_CONTROLLER = {  # src/controller.cpp:36-71, each "controller." + name
    "k_phi": 3.0,
    "k_delta": 2.0,
    "beta": 0.4,
    "lambda": 2.0,
    "v_linear_min": 0.1,
    "v_linear_max": 0.25,
    "v_angular_max": 0.75,
    "slowdown_radius": 0.25,
    "rotate_to_heading_angular_vel": 1.0,
    "rotate_to_heading_max_angular_accel": 3.2,
    "use_collision_detection": True,
    "costmap_topic": "local_costmap/costmap_raw",
    "footprint_topic": "local_costmap/published_footprint",
    "transform_tolerance": 0.1,
    "projection_time": 5.0,
    "simulation_time_step": 0.1,
    "dock_collision_threshold": 0.3,
}
_PLUGIN = {  # src/simple_charging_dock.cpp:37-86, each "<plugin name>." + name
    "plugin": "opennav_docking::SimpleChargingDock",  # nav2_util::get_plugin_type_param, src/dock_database.cpp:171
    "use_battery_status": True,
    "use_external_detection_pose": False,
    "external_detection_timeout": 1.0,
    "external_detection_translation_x": -0.20,
    "external_detection_translation_y": 0.0,
    "external_detection_rotation_yaw": 0.0,
    "external_detection_rotation_pitch": 1.57,
    "external_detection_rotation_roll": -1.57,
    "filter_coef": 0.1,
    "charging_threshold": 0.5,
    "use_stall_detection": False,
    "stall_joint_names": ["name"],
    "stall_velocity_threshold": 1.0,
    "stall_effort_threshold": 1.0,
    "docking_threshold": 0.05,
    "staging_x_offset": -0.7,
    "staging_yaw_offset": 0.0,
    "dock_direction": "forward",
    "rotate_to_dock": False,
}
_DOCK = {"frame": "map", "type": "name", "pose": [0.0, 0.0, 0.0], "id": ""}  # include/.../utils.hpp:117-159

_TYPE_OF = {bool: "PARAMETER_BOOL", int: "PARAMETER_INTEGER", float: "PARAMETER_DOUBLE", str: "PARAMETER_STRING"}


def _declared_type(default: Any) -> str:
    if isinstance(default, list):
        return {str: "PARAMETER_STRING_ARRAY", float: "PARAMETER_DOUBLE_ARRAY"}[type(default[0])]
    return _TYPE_OF[type(default)]


def _declared(params: Params) -> dict[str, Any]:
    """The default of each name the server declares, given the file's plugin and dock names."""
    out: dict[str, Any] = dict(_SERVER)
    out.update({f"controller.{k}": v for k, v in _CONTROLLER.items()})
    for plugin in params.get("dock_plugins", ("", []))[1]:
        out.update({f"{plugin}.{k}": v for k, v in _PLUGIN.items()})
    for dock in params.get("docks", ("", []))[1]:
        out.update({f"{dock}.{k}": v for k, v in _DOCK.items()})
    return out


def _sim_start() -> tuple[float, float, float]:
    """SimSettings.start's default: the simulated robot's start in the dock frame, odom's origin."""
    x, y, yaw = SimSettings().start
    return float(x), float(y), float(yaw)


def _sim_currents() -> tuple[float, float]:
    """BatteryState.current the sim publishes while charging and while not."""
    return CHARGING_CURRENT, DRAIN_CURRENT


def _true_docking_pose_in_odom(front_offset: float) -> Pose2D:
    """base_link docked (DockPose (front_offset, 0, 0): the front edge on the face, straight), in the sim's odom."""
    return Pose2D(*_sim_start()).inverse().compose(Pose2D(-front_offset, 0.0, 0.0))


@pytest.mark.skipif(importlib.util.find_spec("rclpy") is None, reason="rclpy is not installed (the ros extra)")
def test_both_recipes_load_with_rclpy_and_set_what_docking_with_monodock_needs() -> None:
    parsed = _rclpy_parse(REAL, SIM)
    front_offset = RobotConfig.default().front_offset
    for path, params in parsed.items():
        name = Path(path).name
        declared = _declared(params)
        unknown = sorted(set(params) - set(declared))
        assert unknown == [], f"{name}: keys the docking server never reads (misspelt?): {unknown}"
        wrong = {k: t for k, (t, _) in params.items() if t != _declared_type(declared[k])}
        assert wrong == {}, f"{name}: types the server refuses at start-up: {wrong}"
        v = {k: value for k, (_, value) in params.items()}
        assert v["fixed_frame"] == "odom"
        assert v["base_frame"] == "base_link"
        assert v["enable_stamped_cmd_vel"] is True  # Kilted's default, and monodock's sim's
        assert v["controller.use_collision_detection"] is False  # no costmap in the recipe
        (plugin,) = v["dock_plugins"]
        p = {k.removeprefix(f"{plugin}."): value for k, value in v.items() if k.startswith(f"{plugin}.")}
        assert p["plugin"] == "opennav_docking::SimpleChargingDock"
        assert p["use_external_detection_pose"] is True
        assert p["external_detection_translation_x"] == pytest.approx(-front_offset)
        assert p["external_detection_translation_y"] == 0.0
        for axis in ("roll", "pitch", "yaw"):  # set: the defaults (-1.57, 1.57, 0) are an AprilTag's
            assert p[f"external_detection_rotation_{axis}"] == 0.0
        assert p["staging_x_offset"] == pytest.approx(-PlannerConfig().standoff)
        assert p["dock_direction"] == "forward"
        assert p["external_detection_timeout"] > 1.0  # the blind zone (test_the_final_approach_...)
        (dock,) = v["docks"]
        assert v[f"{dock}.type"] == plugin
        assert len(v[f"{dock}.pose"]) == 3
    real, sim = ({k: value for k, (_, value) in parsed[str(f)].items()} for f in (REAL, SIM))
    assert real["charger.frame"] == "map"  # with a navigation stack's localisation
    assert not real.get("use_sim_time", False)
    assert sim["charger.frame"] == "odom"  # no map in the sim
    assert sim["use_sim_time"] is True  # the sim's stamps are its /clock
    truth = _true_docking_pose_in_odom(front_offset)
    assert sim["charger.pose"] == pytest.approx([truth.x, truth.y, truth.theta], abs=1e-9)
    # Charging is the sim's BatteryState.current above the threshold (simple_charging_dock.cpp:126-132).
    charging, not_charging = _sim_currents()
    assert sim["monodock_charger.use_battery_status"] is True
    assert not_charging < sim["monodock_charger.charging_threshold"] < charging


# --- tf2 and angles, transcribed ----------------------------------------------------------------------------------


def set_euler(yaw: float, pitch: float, roll: float) -> Quat:
    """tf2::Quaternion::setEuler(yaw about Y, pitch about X, roll about Z): tf2/LinearMath/Quaternion.h:62-82."""
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    return (
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        sr * cp * cy - cr * sp * sy,
        cr * cp * cy + sr * sp * sy,
    )


def yaw_quaternion(yaw: float) -> Quat:
    """A rotation by yaw about z, as simple_charging_dock.cpp builds one (setEuler(0, 0, yaw), :181-182, :239-240)."""
    return set_euler(0.0, 0.0, yaw)


def get_yaw(q: Quat) -> float:
    """tf2::getYaw: tf2/include/tf2/impl/utils.h:139-166."""
    x, y, z, w = q
    sqx, sqy, sqz, sqw = x * x, y * y, z * z, w * w
    sarg = -2 * (x * z - w * y) / (sqx + sqy + sqz + sqw)
    if sarg <= -0.99999:
        return -2 * math.atan2(y, x)
    if sarg >= 0.99999:
        return 2 * math.atan2(y, x)
    return math.atan2(2 * (x * y + w * z), sqw + sqx - sqy - sqz)


def quat_mul(a: Quat, b: Quat) -> Quat:
    """The rotation of a frame product a * b (KDL::Frame product in doTransform, tf2_geometry_msgs.hpp:404-425)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotate(q: Quat, v: tuple[float, float, float]) -> tuple[float, float, float]:
    x, y, z, _ = quat_mul(quat_mul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return x, y, z


def slerp(a: Quat, b: Quat, t: float) -> Quat:
    """tf2::Quaternion::slerp: Quaternion.h:318-342, with angleShortestPath, Quaternion.h:217-225 (acos of
    dot(+-q) / s, times 2, halved again by slerp; the argument is clamped to 1 here, where rounding could pass it)."""
    dot = sum(i * j for i, j in zip(a, b, strict=True))
    s = math.sqrt(sum(i * i for i in a) * sum(j * j for j in b))
    theta = math.acos(min(1.0, abs(dot) / s))
    if theta == 0.0:
        return a
    d = 1.0 / math.sin(theta)
    s0, s1 = math.sin((1.0 - t) * theta), math.sin(t * theta)
    sign = -1.0 if dot < 0 else 1.0
    x, y, z, w = ((ai * s0 + sign * bi * s1) * d for ai, bi in zip(a, b, strict=True))
    return x, y, z, w


def normalize_angle(angle: float) -> float:
    """angles::normalize_angle (ros/angles, angles.h): into [-pi, pi]."""
    result = math.fmod(angle + math.pi, 2.0 * math.pi)
    return result + math.pi if result <= 0.0 else result - math.pi


@dataclass(frozen=True)
class PoseStamped:
    frame_id: str
    stamp: float
    position: tuple[float, float, float]
    orientation: Quat

    @classmethod
    def planar(cls, frame_id: str, stamp: float, pose: Pose2D) -> PoseStamped:
        return cls(frame_id, stamp, (pose.x, pose.y, 0.0), yaw_quaternion(pose.theta))

    def pose2d(self) -> Pose2D:
        return Pose2D(self.position[0], self.position[1], get_yaw(self.orientation))


class Tf:
    """The odom -> base_link transforms the base publishes on /tf (the sim: with each odometry, 50 Hz), looked up as
    tf2's buffer does: at a stamp, between the two around it, position linearly and rotation by slerp
    (tf2/src/cache.cpp:184-205); stamp None is tf2's time 0, the latest."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, Pose2D]] = []

    def add(self, stamp: float, odom_T_base: Pose2D) -> None:
        self.samples.append((stamp, odom_T_base))

    def odom_T_base(self, stamp: float | None) -> Pose2D:
        if stamp is None or len(self.samples) == 1:
            return self.samples[-1][1]
        assert self.samples[0][0] <= stamp <= self.samples[-1][0], "tf2 would not extrapolate"
        for (t0, p0), (t1, p1) in zip(self.samples[:-1], self.samples[1:], strict=True):
            if t0 <= stamp <= t1:
                f = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
                q = slerp(yaw_quaternion(p0.theta), yaw_quaternion(p1.theta), f)
                return Pose2D(p0.x + f * (p1.x - p0.x), p0.y + f * (p1.y - p0.y), get_yaw(q))
        raise AssertionError("unreachable")

    def transform(self, pose: PoseStamped, target: str, stamp: float | None) -> PoseStamped:
        """tf2_ros::Buffer::transform: lookupTransform(target, pose's frame, stamp), then doTransform
        (tf2_geometry_msgs.hpp:404-425: position T * p, rotation q_T * q)."""
        T = self.odom_T_base(stamp)
        if (pose.frame_id, target) == ("odom", "base_link"):
            T = T.inverse()
        else:
            assert (pose.frame_id, target) == ("base_link", "odom"), (pose.frame_id, target)
        q_T = yaw_quaternion(T.theta)
        rx, ry, rz = rotate(q_T, pose.position)
        return PoseStamped(target, pose.stamp, (T.x + rx, T.y + ry, rz), quat_mul(q_T, pose.orientation))


# --- opennav_docking's SimpleChargingDock, transcribed -----------------------------------------------------------


class PoseFilter:
    """src/pose_filter.cpp:22-64."""

    def __init__(self, coef: float, timeout: float) -> None:
        self.coef, self.timeout = coef, timeout
        self.pose = PoseStamped("", 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))  # :26, stamp 0

    def update(self, m: PoseStamped) -> PoseStamped:
        if self.coef <= 0.0:  # :32-35
            return m
        if m.stamp - self.pose.stamp > self.timeout or self.pose.frame_id != m.frame_id:  # :37-40
            self.pose = m
        else:  # :41-56: filter(filt, meas) = (1 - coef) * filt + coef * meas (:61-64); slerp the rotation
            c = self.coef
            position = tuple((1 - c) * f + c * n for f, n in zip(self.pose.position, m.position, strict=True))
            x, y, z = position
            self.pose = PoseStamped(m.frame_id, m.stamp, (x, y, z), slerp(self.pose.orientation, m.orientation, c))
        return self.pose


class SimpleChargingDock:
    """src/simple_charging_dock.cpp, the parts a docking with external detection runs."""

    def __init__(self, values: dict[str, Any], name: str, tf: Tf) -> None:
        def param(key: str) -> Any:  # declare_parameter_if_not_declared with the upstream default, :37-86
            return values.get(f"{name}.{key}", _PLUGIN[key])

        self.tf = tf
        self.use_battery_status = bool(param("use_battery_status"))  # :88
        assert param("use_external_detection_pose"), "this transcription follows the external-detection branch"
        self.timeout = float(param("external_detection_timeout"))  # :90
        self.tx = float(param("external_detection_translation_x"))  # :91-92
        self.ty = float(param("external_detection_translation_y"))  # :93-94
        yaw = float(param("external_detection_rotation_yaw"))  # :96-98
        pitch = float(param("external_detection_rotation_pitch"))
        roll = float(param("external_detection_rotation_roll"))
        self.rotation = set_euler(pitch, roll, yaw)  # :99, the argument order as upstream writes it
        self.charging_threshold = float(param("charging_threshold"))  # :100
        self.docking_threshold = float(param("docking_threshold"))  # :103
        self.base_frame = str(values.get("base_frame", _SERVER["base_frame"]))  # :104
        self.staging_x_offset = float(param("staging_x_offset"))  # :105
        self.staging_yaw_offset = float(param("staging_yaw_offset"))  # :106
        assert param("dock_direction") == "forward", "the transcription follows forward docking"
        assert not param("use_stall_detection"), "the transcription follows docking_threshold's isDocked"
        self.filter = PoseFilter(float(param("filter_coef")), self.timeout)  # :121-124
        self.is_charging_ = False  # :30
        self.detected = PoseStamped("", 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))  # :135, stamp 0
        self.dock_pose: PoseStamped | None = None  # dock_pose_, its frame_id empty until refined

    def on_battery(self, current: float) -> None:
        self.is_charging_ = current > self.charging_threshold  # :129-131

    def on_detection(self, pose: PoseStamped) -> None:
        self.detected = pose  # :138-140: the latest message, no queue

    def get_staging_pose(self, pose: Pose2D, frame: str, now: float) -> PoseStamped:
        """:162-188 (external detection: dock_pose_ is left alone, :166-171)."""
        yaw = pose.theta  # :174
        x = pose.x + math.cos(yaw) * self.staging_x_offset  # :178-179
        y = pose.y + math.sin(yaw) * self.staging_x_offset  # :180
        return PoseStamped(frame, now, (x, y, 0.0), set_euler(0.0, 0.0, yaw + self.staging_yaw_offset))  # :181-183

    def get_refined_pose(self, pose: PoseStamped, now: float) -> PoseStamped | None:
        """:190-257; None where upstream returns false (and leaves ``pose`` as it was)."""
        detected = self.detected  # :200
        if now - detected.stamp > self.timeout:  # :203-207
            return None
        if detected.frame_id != pose.frame_id:  # :212-226, at the detection's stamp
            detected = self.tf.transform(detected, pose.frame_id, detected.stamp)
        detected = self.filter.update(detected)  # :229
        just_orientation = quat_mul(detected.orientation, self.rotation)  # :233-237
        orientation = set_euler(0.0, 0.0, get_yaw(just_orientation))  # :239-241
        yaw = get_yaw(orientation)  # :246
        x = detected.position[0] + math.cos(yaw) * self.tx - math.sin(yaw) * self.ty  # :247-248
        y = detected.position[1] + math.sin(yaw) * self.tx + math.cos(yaw) * self.ty  # :249-250
        self.dock_pose = PoseStamped(detected.frame_id, detected.stamp, (x, y, 0.0), orientation)  # :244-251
        return self.dock_pose  # :255-256

    def is_docked(self) -> bool:
        """:259-287, without stall detection."""
        if self.dock_pose is None:  # :266-269
            return False
        base = self.tf.transform(PoseStamped.planar(self.base_frame, 0.0, Pose2D(0, 0, 0)), "odom", None)  # :272-280
        d = math.hypot(base.position[0] - self.dock_pose.position[0], base.position[1] - self.dock_pose.position[1])
        return d < self.docking_threshold  # :283-286

    def is_charging(self) -> bool:
        return self.is_charging_ if self.use_battery_status else self.is_docked()  # :289-292


def _estimator(sim: Simulator, method: str) -> Estimator:
    return make_estimator(method=method, camera=sim.camera, layout=sim.layout, robot=sim.robot)


def _detection(est: Estimator, image: np.ndarray, stamp: float) -> PoseStamped | None:
    """What monodock-ros publishes for an image: the estimate as a planar PoseStamped in base_link, at the image's
    stamp (src/monodock/ros/detector.py, _publish)."""
    e = est.estimate_pose(image)
    return None if e.pose is None else PoseStamped.planar("base_link", stamp, Pose2D(e.pose.x, e.pose.y, e.pose.yaw))


# --- the docking pose Nav2 steers to, against the truth -----------------------------------------------------------

# Robot poses before the dock: front edge 0.4-2 m from the face, off the axis, turned up to 20 degrees (the dock
# in view). (gap m, lateral m, heading deg) of base_link in the dock frame.
_STANDS = [
    (0.4, 0.0, 0.0),
    (0.4, 0.08, -20.0),
    (0.7, -0.10, 20.0),
    (1.0, 0.15, -10.0),
    (1.0, -0.20, 15.0),
    (1.5, 0.25, -20.0),
    (2.0, 0.0, 0.0),
    (2.0, -0.30, 20.0),
]


@dataclass(frozen=True)
class _Errors:
    along: float  # m, the docking pose's error along the docked heading (+: past the true pose)
    across: float  # m, to its left
    yaw: float  # rad


def _refine_at_stands(
    values: dict[str, Any], method: str, stands: list[tuple[float, float, float]], frames: int = 2, seed: int = 5
) -> list[_Errors]:
    """For each stand: the sim renders ``frames`` images (15 fps, the robot still), the estimator estimates them,
    SimpleChargingDock refines each (at 50 Hz, as the server's loop calls it); the last refined pose against the
    true docking pose, both in the sim's odom. The TF is the true odom pose (no wheel drift)."""
    sim = Simulator(seed=11)
    est = _estimator(sim, method)
    front_offset = sim.robot.front_offset
    start = Pose2D(*_sim_start())
    truth = _true_docking_pose_in_odom(front_offset)
    rng = np.random.default_rng(seed)
    out = []
    (plugin,) = values["dock_plugins"]
    for gap, lateral, heading_deg in stands:
        robot = Pose2D(-(front_offset + gap), lateral, math.radians(heading_deg))  # base_link in the dock frame
        tf = Tf()
        tf.add(EPOCH, start.inverse().compose(robot))
        dock = SimpleChargingDock(values, plugin, tf)
        pose = PoseStamped.planar("odom", 0.0, Pose2D(*values["charger.pose"]))  # docking_server.cpp:288-289
        refined = None
        for i in range(frames):
            stamp = EPOCH + i / 15.0
            image = sim.frame(DockPose.from_robot_in_dock(*robot), stamp - EPOCH, rng).image
            detection = _detection(est, image, stamp)
            assert detection is not None, f"no detection at {gap} m, {lateral} m, {heading_deg} deg"
            dock.on_detection(detection)
            for k in range(3):  # the control loop runs ~3 times per frame, on the same detection
                refined = dock.get_refined_pose(pose, stamp + 0.05 + k / 50.0) or refined
        assert refined is not None
        err = truth.inverse().compose(refined.pose2d())
        out.append(_Errors(err.x, err.y, err.theta))
    return out


@pytest.mark.parametrize("method", ["fused", "board"])
def test_the_docking_pose_nav2_steers_to_is_the_true_docked_pose(method: str) -> None:
    """getRefinedPose's docking pose (what the controller aims at and isDocked measures against) from monodock's
    detections, against base_link where the simulated robot is docked: DockPose (front_offset, 0, 0)."""
    values = _values(SIM)
    stands = _STANDS if method == "fused" else [s for s in _STANDS if s[0] <= 1.0]  # board: not past 1 m
    errors = _refine_at_stands(values, method, stands)
    worst = max(max(abs(e.along), abs(e.across)) for e in errors)
    worst_yaw = max(abs(e.yaw) for e in errors)
    print(f"{method}: docking pose vs truth, worst {worst * 1000:.2f} mm, {math.degrees(worst_yaw):.3f} deg")
    position_tol = 0.003 if method == "fused" else 0.005
    assert worst < position_tol, errors
    assert worst_yaw < math.radians(0.5), errors


def test_a_wrong_offset_would_be_caught() -> None:
    """The same check with the translation's sign flipped (the docking pose lands 2 * front_offset = 68 cm inside
    the charger), or the rotations left at their AprilTag defaults (it turns a right angle and lands ~48 cm off):
    the transcription does use the file's values, and a wrong one shows."""
    values = _values(SIM)
    stand = [(0.7, -0.10, 20.0)]
    flipped = dict(values, **{"monodock_charger.external_detection_translation_x": 0.34})
    (e,) = _refine_at_stands(flipped, "fused", stand, frames=1)
    assert abs(e.along - 2 * RobotConfig.default().front_offset) < 0.01
    defaults = {k: v for k, v in values.items() if "external_detection_rotation" not in k}
    (e,) = _refine_at_stands(defaults, "fused", stand, frames=1)
    assert abs(abs(e.yaw) - math.pi / 2) < math.radians(2)
    assert math.hypot(e.along, e.across) > 0.3


def test_the_staging_poses_are_where_the_docs_say() -> None:
    """Docking: the staging pose comes from the dock database's pose (types.hpp:34-37, docking_server.cpp:268 and
    :302, used to back off before a retry): base_link front_offset + planner.standoff before the face, facing it
    (Point A). Undocking: from the robot's docked pose (docking_server.cpp:699-710): the same place."""
    values = _values(SIM)
    front_offset = RobotConfig.default().front_offset
    standoff = PlannerConfig().standoff
    start = Pose2D(*_sim_start())
    tf = Tf()
    tf.add(0.0, start.inverse().compose(Pose2D(-front_offset, 0.0, 0.0)))  # docked
    dock = SimpleChargingDock(values, "monodock_charger", tf)
    point_a = Pose2D(-(front_offset + standoff), 0.0, 0.0)  # base_link in the dock frame
    for pose in (Pose2D(*values["charger.pose"]), tf.odom_T_base(None)):
        staging = dock.get_staging_pose(pose, "odom", 0.0).pose2d()
        in_dock = start.compose(staging)
        assert in_dock.distance(point_a) < 1e-9, in_dock
        assert abs(in_dock.theta) < 1e-9, in_dock


# --- the final approach: the server's loop, its controller and the plugin, driving the simulated robot ------------


def control_law(target: Pose2D, values: dict[str, Any]) -> tuple[float, float]:
    """SmoothControlLaw::calculateRegularVelocity(target, backward=false), the robot at the origin:
    nav2_graceful_controller/src/smooth_control_law.cpp:53-90 and :114-123, with EgocentricPolarCoordinates,
    nav2_graceful_controller/include/nav2_graceful_controller/ego_polar_coords.hpp:54-68 (floats there)."""

    def c(key: str) -> float:
        return float(values.get(f"controller.{key}", _CONTROLLER[key]))

    k_phi, k_delta, beta, lam = c("k_phi"), c("k_delta"), c("beta"), c("lambda")
    v_min, v_max, w_max, slowdown = c("v_linear_min"), c("v_linear_max"), c("v_angular_max"), c("slowdown_radius")
    dx, dy = target.x, target.y  # ego_polar_coords.hpp:59-60
    line_of_sight = math.atan2(-dy, dx)  # :63
    r = math.sqrt(dx * dx + dy * dy)  # :65
    phi = normalize_angle(target.theta + line_of_sight)  # :66
    delta = normalize_angle(0.0 + line_of_sight)  # :67
    prop = k_delta * (delta - math.atan(-k_phi * phi))  # smooth_control_law.cpp:118
    feedback = (1.0 + (k_phi / (1.0 + (k_phi * phi) ** 2))) * math.sin(delta)  # :120
    curvature = -1.0 / r * (prop + feedback)  # :122
    v = v_max / (1.0 + beta * abs(curvature) ** lam)  # :66
    v = min(v_max * (r / slowdown), v)  # :69
    v = min(max(v, v_min), v_max)  # :73
    w = curvature * v  # :79
    w_bound = min(max(w, -w_max), w_max)  # :81
    v = w_bound / curvature if curvature != 0.0 else v  # :83
    return v, w_bound


@dataclass
class _Run:
    outcome: str  # "charging", or the exception upstream would throw
    end: float  # when approachDock returned, s
    last_detection: float  # stamp of the last detection getRefinedPose used, s
    last_detection_gap: float  # the true front gap at that stamp, m
    robot: SimulatedRobot


def _dock_final_approach(values: dict[str, Any], start: Pose2D, seed: int) -> _Run:
    """DockingServer::dockRobot from the initial perception on (navigate_to_staging_pose false):
    src/docking_server.cpp:287-334 with doInitialPerception (:426-445), approachDock (:484-548) and waitForCharge
    (:550-580), at controller_frequency; the robot is monodock-sim-ros's (SimulatedRobot, its camera at 15 fps),
    the detections monodock-ros's (fused, published DETECTOR_LATENCY after the image arrives), the battery the
    sim's BatteryState.current, and the base stops ``cmd_vel_timeout`` after the last command, as the sim's does."""
    sim = Simulator(seed=seed)
    est = _estimator(sim, "fused")
    # blank_undetectable: frames in which every marker is cut by the image's border are not rendered (ArUco finds
    # nothing in them either way); the detector gets the sensor's noise on white, as dock-sim does.
    robot = SimulatedRobot(sim, start, DiffDriveConfig(), np.random.default_rng(seed), blank_undetectable=True)
    charging_current, idle_current = _sim_currents()
    tf = Tf()
    tf.add(EPOCH + robot.t, robot.odom)
    dock = SimpleChargingDock(values, "monodock_charger", tf)
    dt = 1.0 / float(values.get("controller_frequency", _SERVER["controller_frequency"]))
    cmd_vel_timeout = 0.5  # monodock-sim-ros's cmd_vel_timeout: the base stops this long after the last command
    last_cmd = -math.inf
    seen = -math.inf
    pending: list[tuple[float, PoseStamped]] = []  # (when published, the detection)

    def now() -> float:  # ROS time: monodock-sim-ros stamps the wall clock at its start plus simulated time
        return EPOCH + robot.t

    def tick() -> None:  # one control period of the world: physics, /tf, battery, the detector's output
        nonlocal seen
        robot.sleep(dt)
        tf.add(now(), robot.odom)
        dock.on_battery(charging_current if robot.charging() else idle_current)
        while pending and pending[0][0] <= robot.t:
            dock.on_detection(pending.pop(0)[1])
        frame = robot.latest_frame()
        if frame is not None and frame.stamp > seen:
            seen = frame.stamp
            detection = _detection(est, frame.image, EPOCH + frame.stamp)
            if detection is not None:
                pending.append((robot.t + DETECTOR_LATENCY, detection))

    def gap_at(stamp: float) -> float:
        sample = min(robot.truth, key=lambda s: abs(EPOCH + s.t - stamp))
        return robot.front_gap(sample.pose)

    dock_pose = PoseStamped.planar("odom", 0.0, Pose2D(*values["charger.pose"]))  # :288-289
    begin = now()
    while (refined := dock.get_refined_pose(dock_pose, now())) is None:  # :432
        if now() - begin > float(values["initial_perception_timeout"]):  # :433-435
            return _Run("FailedToDetectDock (initial)", now(), math.nan, math.nan, robot)
        tick()
    dock_pose, used = refined, refined.stamp
    begin = now()
    while True:  # approachDock
        if dock.is_docked() or dock.is_charging():  # :495-497
            break
        refined = dock.get_refined_pose(dock_pose, now())  # :507-509
        if refined is None:
            robot.send_velocity(0.0, 0.0)  # a retry would follow: publishZeroVelocity, resetApproach
            return _Run("FailedToDetectDock", now(), used, gap_at(used), robot)
        dock_pose = refined
        used = dock.detected.stamp
        target = PoseStamped(  # :512-522, backward_projection 0.25 m
            "odom",
            0.0,
            (
                dock_pose.position[0] + math.cos(get_yaw(dock_pose.orientation)) * 0.25,
                dock_pose.position[1] + math.sin(get_yaw(dock_pose.orientation)) * 0.25,
                0.0,
            ),
            dock_pose.orientation,
        )
        in_base = tf.transform(target, "base_link", None).pose2d()  # :523
        v, w = control_law(in_base, values)  # :535, controller.cpp:119-126 (no collision check)
        robot.send_velocity(v, w)  # :538
        last_cmd = now()
        if now() - begin > float(values["dock_approach_timeout"]):  # :540-543
            return _Run("FailedToControl", now(), used, gap_at(used), robot)
        tick()
    end = now()
    while not dock.is_charging():  # waitForCharge, :560-579: no command; the base stops on its own time-out
        if now() - end > float(values["wait_charge_timeout"]):
            return _Run("FailedToCharge", end, used, gap_at(used), robot)
        if last_cmd < now() - cmd_vel_timeout < last_cmd + dt:
            robot.send_velocity(0.0, 0.0)
        tick()
    robot.send_velocity(0.0, 0.0)  # :330
    return _Run("charging", end, used, gap_at(used), robot)


def test_the_final_approach_ends_by_charging_before_the_detection_times_out() -> None:
    """The blind zone: marker 2 leaves the image ~8 cm before the face, and from then on getRefinedPose fails once
    ``external_detection_timeout`` has passed since the last detection's stamp (simple_charging_dock.cpp:203-207),
    which aborts the approach (docking_server.cpp:507-509). The approach loop checks isDocked and isCharging
    first (:495-497), so the robot must be charging (or within docking_threshold of the docking pose) before then.
    With the sim recipe's values, by the sim's truth: the robot charges, square on the contacts, in time."""
    values = _values(SIM)
    front_offset = RobotConfig.default().front_offset
    # From the staging pose (front edge 1 m from the face: Point A), 5 cm and 5 degrees off, as a robot may stand
    # there after navigating.
    start = Pose2D(-(front_offset + PlannerConfig().standoff), -0.05, math.radians(-5.0))
    run = _dock_final_approach(values, start, seed=21)
    robot = run.robot
    blind = run.end - run.last_detection
    timeout = values["monodock_charger.external_detection_timeout"]
    sim = robot.sim
    zone = blind_gap(sim.camera, sim.layout, sim.robot)
    print(
        f"last detection {run.last_detection_gap * 100:.1f} cm from the face (blind_gap {zone * 100:.1f} cm), "
        f"charging {blind:.2f} s after its stamp (timeout {timeout} s); final lateral {robot.pose.y * 1000:.1f} mm, "
        f"heading {math.degrees(robot.pose.theta):.2f} deg, impact {robot.impact_speed:.3f} m/s"
    )
    assert run.outcome == "charging", run
    assert robot.charging()  # the sim's truth: contacts pressed, within 15 mm and 4 degrees, for 0.3 s
    assert blind < timeout
    # The detector sees the dock up to the blind zone: the last detection is within a frame's travel of it.
    assert run.last_detection_gap < zone + 0.03


def test_the_upstream_detection_timeout_would_abort_in_the_blind_zone() -> None:
    """Why the recipe raises external_detection_timeout: with upstream's 1 s, the approach fails detection at the
    face, before the charger's current comes (FailedToDetectDock; the server would back off and retry)."""
    values = dict(_values(SIM), **{"monodock_charger.external_detection_timeout": 1.0})
    front_offset = RobotConfig.default().front_offset
    start = Pose2D(-(front_offset + 0.2), 0.01, math.radians(2.0))  # 20 cm out: quicker, the same last 8 cm
    run = _dock_final_approach(values, start, seed=21)
    assert run.outcome == "FailedToDetectDock", run
    assert run.robot.front_gap() < 0.005  # at the face, in the blind zone
