"""Writing rosbag2 recordings the way ``ros2 bag record`` would have recorded them: a generic ``BagWriter``.

The topics and frames of monodock's recordings (``sim.recording`` writes a simulated drive with them; Humble types):

- ``/camera/image_raw`` sensor_msgs/Image (mono8 or bgr8), or ``/camera/image_raw/compressed``
  sensor_msgs/CompressedImage (png or jpeg, image_transport's format string), frame ``camera_optical_frame``;
- ``/camera/camera_info`` sensor_msgs/CameraInfo with every image, same stamp;
- ``/scan`` sensor_msgs/LaserScan at each scan stamp, frame ``laser``;
- ``/tf_static`` tf2_msgs/TFMessage once at the start (transient local, as the recorder stores it);
- ``/monodock/ground_truth`` geometry_msgs/PoseStamped per image: the DockPose in base_link. Training never
  reads it; evaluation does;
- in a continuous drive (``sim.drive_recording``): ``/odom`` nav_msgs/Odometry (frame ``odom``, child
  ``base_link``) at the control rate, and ``/battery_state`` sensor_msgs/BatteryState (CHARGING on the contacts).

The bag is written in a temporary folder beside its path and renamed into place when the ``with`` block ends
without an error; its QoS profiles are stored as Humble's rosbag2 (version 8, integers) reads them.
"""

from __future__ import annotations

import contextlib
import os
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer

from monodock.core.atomic import atomic_directory, check_writable
from monodock.errors import ConfigError
from monodock.recording import messages as m

__all__ = [
    "BASE_FRAME",
    "BATTERY_TOPIC",
    "CAMERA_FRAME",
    "CAMERA_INFO_TOPIC",
    "COMPRESSED_IMAGE_TOPIC",
    "IMAGE_TOPIC",
    "LASER_FRAME",
    "LATCHED",
    "ODOMETRY_TOPIC",
    "ODOM_FRAME",
    "RELIABLE",
    "SCAN_TOPIC",
    "SENSOR",
    "STORAGES",
    "TF_STATIC_TOPIC",
    "TRUTH_TOPIC",
    "BagWriter",
]

IMAGE_TOPIC = "/camera/image_raw"
COMPRESSED_IMAGE_TOPIC = "/camera/image_raw/compressed"
CAMERA_INFO_TOPIC = "/camera/camera_info"
SCAN_TOPIC = "/scan"
TF_STATIC_TOPIC = "/tf_static"
TRUTH_TOPIC = "/monodock/ground_truth"
ODOMETRY_TOPIC = "/odom"
BATTERY_TOPIC = "/battery_state"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
CAMERA_FRAME = "camera_optical_frame"
LASER_FRAME = "laser"

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}

# The offered QoS that `ros2 bag record` (Humble) stores: history and depth are not discoverable (UNKNOWN, 0),
# durations "infinite". /tf_static is reliable and transient local, so that late subscribers get it on replay.
_INFINITE = QosTime(2147483647, 4294967295)


def _qos(reliability: QosReliability, durability: QosDurability) -> Qos:
    return Qos(
        QosHistory.UNKNOWN, 0, reliability, durability, _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False
    )


LATCHED = _qos(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
SENSOR = _qos(QosReliability.BEST_EFFORT, QosDurability.VOLATILE)
RELIABLE = _qos(QosReliability.RELIABLE, QosDurability.VOLATILE)


class BagWriter:
    """A rosbag2 folder being written; a context manager (see the module docstring).

    Args:
        path: the bag folder to write.
        storage: "mcap" or "sqlite3".
        force: replace an existing ``path``.

    Attributes:
        written: messages written so far.
    """

    def __init__(self, path: str | os.PathLike[str], *, storage: str = "mcap", force: bool = False) -> None:
        if storage not in STORAGES:
            raise ConfigError(f"storage '{storage}' is unknown ({', '.join(STORAGES)})")
        self.path = check_writable(path, force=force)
        self.storage, self.force = storage, force
        self.typestore = m.humble_typestore()
        self.written = 0
        self._stack: ExitStack | None = None
        self._writer: Any = None
        self._tmp: Path | None = None

    def __enter__(self) -> BagWriter:
        stack = ExitStack()
        try:
            self._tmp = stack.enter_context(atomic_directory(self.path, force=self.force))
            # Version 8 stores QoS as the integers Humble's rosbag2 reads; version 9 switched to names.
            writer = Writer(self._tmp / self.path.name, version=8, storage_plugin=STORAGES[self.storage])
            writer.open()
        except BaseException:
            stack.close()
            raise
        self._writer, self._stack = writer, stack
        return self

    def connect(self, topic: str, msgtype: str, qos: Qos) -> Connection:
        """A topic of ``msgtype`` offered with ``qos`` (LATCHED, SENSOR or RELIABLE)."""
        if self._writer is None:
            raise RuntimeError("BagWriter.connect outside its with block")
        connection: Connection = self._writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=[qos]
        )
        return connection

    def write(self, connection: Connection, msg: Any, receive: float) -> None:
        """One message, logged at the recorder's ``receive`` time (seconds; its header keeps the sensor's stamp)."""
        if self._writer is None:
            raise RuntimeError("BagWriter.write outside its with block")
        self._writer.write(connection, _ns(receive), self.typestore.serialize_cdr(msg, connection.msgtype))
        self.written += 1

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        stack, writer, tmp = self._stack, self._writer, self._tmp
        self._stack = self._writer = None
        if stack is None or tmp is None:
            return
        try:
            if exc is None:
                try:
                    writer.close()
                except BaseException:
                    # A full disk while the index and footer are written: the storage's file is closed all the same
                    # (rosbags' close leaves it open to the garbage collector).
                    with contextlib.suppress(Exception):
                        writer.abort()
                    raise
            else:
                writer.abort()  # an error in the with block: no index, no metadata; the folder is removed below
            if exc is None:
                bag = tmp / self.path.name
                # The temporary folder is private (0700); give the recording the mode rosbags gave its folder
                # (0755 less the umask), as `ros2 bag record` would.
                tmp.chmod(bag.stat().st_mode & 0o777)
                _lift_bag(tmp, bag)
        except BaseException as err:
            stack.__exit__(type(err), err, err.__traceback__)
            raise
        # Renames the folder into place, or (after an error in the with block) removes it.
        stack.__exit__(exc_type, exc, tb)

    def size_bytes(self) -> int:
        """The written bag's size on disk (after the with block)."""
        return sum(f.stat().st_size for f in self.path.iterdir() if f.is_file())


def _ns(stamp: float) -> int:
    return round(stamp * 1e9)


def _lift_bag(tmp: Path, bag: Path) -> None:
    """Move the bag's files from ``tmp/bag`` up into ``tmp`` (rosbags' Writer insists on creating its folder)."""
    for f in bag.iterdir():
        os.replace(f, tmp / f.name)
    bag.rmdir()
