"""TF for the nodes: the camera mount read from ``/tf_static``, the robot's pose in a fixed frame from ``/tf``, and
transforms written as tf2 messages.

A robot's URDF, published by robot_state_publisher, puts ``base_link → … → camera_optical_frame`` on ``/tf_static``
(latched). The detector and the docking node compose that chain to the frame their images name (the image's
``frame_id``) and, with ``camera_mount_source: tf`` (the default), estimate with it in place of the robot file's
``camera_mount``. When the two disagree beyond a tolerance they say so once, with both mounts, because a wrong mount
moves every pose without a trace in the images. ``camera_mount_source: robot`` keeps the robot file's mount (for
example one measured by ``monodock commission``, better than the URDF's) and still warns.

tf2_msgs is built from its upstream definitions when monodock is installed (interfaces/README.md); without it the
nodes run on the robot file alone and say so once.

The docking node also reads ``/tf`` (``TransformListener``), to know where the robot stands in a dock's frame (``map``
or ``odom``) before it sends Nav2 to the dock's staging pose. It keeps the latest transform of each frame, as a tf2
lookup at time 0 (the latest) does, which is what Nav2's docking server asks for there.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.robot import Mount, RobotConfig
from monodock.recording.messages import DecodeError, matrix_from_quaternion, split_stamp

__all__ = [
    "CameraMountFromTF",
    "TransformListener",
    "TransformTree",
    "mount_difference",
    "set_transform",
    "transform_matrix",
]


def transform_matrix(transform: Any) -> NDArray[np.float64]:
    """The 4x4 matrix of a geometry_msgs/Transform (a quaternion that is not unit length is normalised).

    Raises:
        DecodeError: its quaternion is zero or not finite, or its translation is not finite.
    """
    r, q = transform.translation, transform.rotation
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(q.x, q.y, q.z, q.w)
    T[:3, 3] = (r.x, r.y, r.z)
    if not np.all(np.isfinite(T)):
        raise DecodeError(f"translation ({r.x}, {r.y}, {r.z}) is not finite")
    return T


def set_transform(stamped: Any, parent: str, child: str, T: NDArray[np.float64], stamp: float | Any) -> Any:
    """``stamped`` (geometry_msgs/TransformStamped) set to ``T``, parent → child, at ``stamp`` (seconds, or a
    builtin_interfaces/Time to copy)."""
    if isinstance(stamp, float | int):
        stamped.header.stamp.sec, stamped.header.stamp.nanosec = split_stamp(float(stamp))
    else:
        stamped.header.stamp = stamp
    stamped.header.frame_id, stamped.child_frame_id = parent, child
    move = stamped.transform.translation
    move.x, move.y, move.z = (float(v) for v in T[:3, 3])
    q = stamped.transform.rotation
    q.x, q.y, q.z, q.w = transforms.quaternion_from_matrix(T[:3, :3])
    return stamped


def mount_difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[float, float]:
    """(metres, degrees) between two poses: how far apart their origins are, and the angle of the rotation between
    them."""
    distance = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    turn = a[:3, :3].T @ b[:3, :3]
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(turn)) - 1.0) / 2.0))))
    return distance, angle


def _describe(T: NDArray[np.float64]) -> str:
    mount = Mount.from_matrix(_camera_link(T))
    xyz = ", ".join(f"{v * 100:.1f}" for v in (mount.x, mount.y, mount.z))
    rpy = ", ".join(f"{math.degrees(v):.2f}" for v in (mount.roll, mount.pitch, mount.yaw))
    return f"camera_link at ({xyz}) cm, roll/pitch/yaw ({rpy})°"


def _camera_link(base_T_optical: NDArray[np.float64]) -> NDArray[np.float64]:
    """base_T_camera_link of an optical frame's pose (REP 103's fixed rotation undone)."""
    T = base_T_optical.copy()
    T[:3, :3] = T[:3, :3] @ transforms.LINK_R_OPTICAL.T
    return T


class TransformTree:
    """The latest transform of each child frame, composed between any two frames the tree joins; thread-safe."""

    def __init__(self) -> None:
        self._parents: dict[str, tuple[str, NDArray[np.float64]]] = {}  # child -> (parent, parent_T_child)
        self._lock = threading.Lock()
        self.version = 0  # counts the transforms set: what was worked out before one is still right until then

    def set(self, parent: str, child: str, parent_T_child: NDArray[np.float64]) -> None:
        with self._lock:
            self._parents[child.lstrip("/")] = (parent.lstrip("/"), parent_T_child)
            self.version += 1

    def lookup(self, parent: str, child: str) -> NDArray[np.float64] | None:
        """parent_T_child, or None when the two frames are not joined."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        with self._lock:
            up_child = self._chain(child)
            up_parent = self._chain(parent)
        common = next((frame for frame in up_child if frame in up_parent), None)
        if common is None:
            return None
        return transforms.invert(up_parent[common]) @ up_child[common]

    def _chain(self, frame: str) -> dict[str, NDArray[np.float64]]:
        """Every ancestor of ``frame`` (itself included), in order, with ancestor_T_frame."""
        chain = {frame: np.eye(4)}
        T = np.eye(4)
        while frame in self._parents and len(chain) <= len(self._parents):
            frame, parent_T = self._parents[frame]
            if frame in chain:  # a loop in a malformed tree
                break
            T = parent_T @ T
            chain[frame] = T
        return chain

    def take(self, msg: Any, on_bad: Any) -> None:
        """A tf2_msgs/TFMessage's transforms (one that does not decode goes to ``on_bad(child, parent, why)``)."""
        for t in msg.transforms:
            child = t.child_frame_id.lstrip("/")
            try:
                parent_T_child = transform_matrix(t.transform)
            except DecodeError as exc:
                on_bad(child, t.header.frame_id, exc)
                continue
            self.set(t.header.frame_id, child, parent_T_child)


class TransformListener:
    """``/tf`` and ``/tf_static`` on ``node``, for where the robot stands in a fixed frame. It subscribes at its first
    ``pose`` (a node that never asks never pays for decoding /tf at 50 Hz) and waits a little then for the transforms
    to come; ``available`` is False without tf2_msgs."""

    def __init__(self, node: Any) -> None:
        self.node, self.tree = node, TransformTree()
        self._subscribed = False
        try:
            import tf2_msgs.msg  # type: ignore[import-not-found, unused-ignore]  # noqa: F401
        except ImportError:
            self.available = False
        else:
            self.available = True

    def _subscribe(self) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile  # type: ignore[import-not-found, unused-ignore]
        from tf2_msgs.msg import TFMessage  # type: ignore[import-not-found, unused-ignore]

        latched = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(TFMessage, "/tf", self._on_tf, QoSProfile(depth=100))
        self.node.create_subscription(TFMessage, "/tf_static", self._on_tf, latched)
        self._subscribed = True

    def _on_tf(self, msg: Any) -> None:
        self.tree.take(msg, lambda *_: None)

    def pose(self, frame: str, base_frame: str, wait: float = 1.0) -> tuple[float, float, float] | None:
        """(x, y, yaw) of ``base_frame`` in ``frame`` on the floor, or None when TF does not join them (within
        ``wait`` seconds of the first call). Called from a thread other than the node's executor's."""
        if not self.available:
            return None
        if not self._subscribed:
            self._subscribe()
        end = time.monotonic() + wait
        while (T := self.tree.lookup(frame, base_frame)) is None and time.monotonic() < end:
            time.sleep(0.02)
        if T is None:
            return None
        return float(T[0, 3]), float(T[1, 3]), math.atan2(float(T[1, 0]), float(T[0, 0]))


class CameraMountFromTF:
    """The camera mount from ``/tf_static``: listens on ``node``, composes ``base_frame`` → the images' frame.

    ``robot(file_robot, frame_id)`` is the robot to estimate with; it is called from any thread.
    """

    def __init__(
        self,
        node: Any,
        base_frame: str,
        *,
        source: str = "tf",
        tolerance: tuple[float, float] = (0.01, 0.5),
        subscribe: bool = True,
    ) -> None:
        self.node, self.base_frame, self.source, self.tolerance = node, base_frame, source, tolerance
        self.tree = TransformTree()
        self._said: set[tuple[str, str]] = set()
        self._cached: tuple[tuple[Any, ...], RobotConfig] | None = None
        self.available = not subscribe or self._subscribe()

    def _subscribe(self) -> bool:
        """Listen on /tf_static; False (said once) without tf2_msgs."""
        try:
            from tf2_msgs.msg import TFMessage  # type: ignore[import-not-found, unused-ignore]
        except ImportError as exc:
            self.node.get_logger().warning(
                f"camera mount from the robot file only: no /tf_static ({exc}; tf2_msgs is built when monodock is "
                "installed)"
            )
            return False
        from rclpy.qos import DurabilityPolicy, QoSProfile  # type: ignore[import-not-found, unused-ignore]

        # tf2's static listener: transient local, deep enough for every latched publisher's message.
        latched = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(TFMessage, "/tf_static", self.on_tf_static, latched)
        return True

    def on_tf_static(self, msg: Any) -> None:
        """A /tf_static message: its transforms kept (a later one of a child replaces the earlier)."""

        def bad(child: str, parent: str, exc: Exception) -> None:
            self._say_once(("bad", child), f"/tf_static's {parent} -> {child} skipped: {exc}", warning=True)

        self.tree.take(msg, bad)

    def lookup(self, parent: str, child: str) -> NDArray[np.float64] | None:
        """parent_T_child composed over /tf_static, or None when the two frames are not joined there."""
        return self.tree.lookup(parent, child)

    def robot(self, file_robot: RobotConfig, frame_id: str) -> RobotConfig:
        """The robot to estimate with for images in ``frame_id``: the file's, with the camera mount from /tf_static
        when ``source`` is tf and the chain is there. Says once per frame when /tf_static and the file disagree,
        and once which mount is in use."""
        if not frame_id or not self.available:
            return file_robot
        # Called for every image: worked out again only when /tf_static, the frames or the file change.
        key = (self.tree.version, self.base_frame, frame_id, self.source, file_robot)
        cached = self._cached
        if cached is not None and cached[0] == key:
            return cached[1]
        robot = self._robot(file_robot, frame_id)
        self._cached = (key, robot)
        return robot

    def _robot(self, file_robot: RobotConfig, frame_id: str) -> RobotConfig:
        found = self.lookup(self.base_frame, frame_id)
        if found is None:
            return file_robot
        own = file_robot.base_T_optical()
        distance, angle = mount_difference(own, found)
        use_tf = self.source == "tf"
        chain = f"{self.base_frame} -> {frame_id}"
        if distance > self.tolerance[0] or angle > self.tolerance[1]:
            self._say_once(
                ("disagree", frame_id),
                f"the camera mount on /tf_static ({chain}: {_describe(found)}) and the robot file's "
                f"({_describe(own)}) are {distance * 100:.1f} cm and {angle:.2f}° apart; estimating with "
                + ("/tf_static's (camera_mount_source: robot keeps the file's)" if use_tf else "the robot file's"),
                warning=True,
            )
        elif use_tf:
            self._say_once(("using", frame_id), f"camera mount from /tf_static ({chain}), within the robot file's")
        if not use_tf:
            return file_robot
        return dataclasses.replace(file_robot, camera_mount=Mount.from_matrix(_camera_link(found)))

    def _say_once(self, key: tuple[str, str], text: str, *, warning: bool = False) -> None:
        if key in self._said:
            return
        self._said.add(key)
        logger = self.node.get_logger()
        (logger.warning if warning else logger.info)(text)
