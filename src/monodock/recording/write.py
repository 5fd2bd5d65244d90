"""Writing a simulated drive as a rosbag2 recording, the way ``ros2 bag record`` would have recorded it.

Topics (ROS 2 Humble types):

- ``/camera/image_raw`` sensor_msgs/Image (mono8 or bgr8), or ``/camera/image_raw/compressed``
  sensor_msgs/CompressedImage (png or jpeg, image_transport's format string), frame ``camera_optical_frame``;
- ``/camera/camera_info`` sensor_msgs/CameraInfo with every image, same stamp;
- ``/scan`` sensor_msgs/LaserScan at each scan stamp, frame ``laser``;
- ``/tf_static`` tf2_msgs/TFMessage once at the start (transient local, as the recorder stores it);
- ``/monodock/ground_truth`` geometry_msgs/PoseStamped per image: the DockPose in base_link. Training never
  reads it; evaluation does.

Messages carry their sensor's stamp in the header; the bag's own (receive) time is a little later, as on a
robot, so that a reader which uses the bag time instead of the header stamp is caught by the tests.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from tqdm import tqdm

from monodock.core.atomic import atomic_directory, check_writable
from monodock.core.parallel import map_with_state
from monodock.core.scan import LaserScan
from monodock.errors import ConfigError
from monodock.recording import messages as m
from monodock.sim.drive import Stop
from monodock.sim.simulator import SimFrame, Simulator

__all__ = [
    "BASE_FRAME",
    "CAMERA_FRAME",
    "CAMERA_INFO_TOPIC",
    "COMPRESSED_IMAGE_TOPIC",
    "IMAGE_TOPIC",
    "LASER_FRAME",
    "SCAN_TOPIC",
    "STORAGES",
    "TF_STATIC_TOPIC",
    "TRUTH_TOPIC",
    "RecordingSummary",
    "write_recording",
]

IMAGE_TOPIC = "/camera/image_raw"
COMPRESSED_IMAGE_TOPIC = "/camera/image_raw/compressed"
CAMERA_INFO_TOPIC = "/camera/camera_info"
SCAN_TOPIC = "/scan"
TF_STATIC_TOPIC = "/tf_static"
TRUTH_TOPIC = "/monodock/ground_truth"
BASE_FRAME = "base_link"
CAMERA_FRAME = "camera_optical_frame"
LASER_FRAME = "laser"

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}

# Transport delay from the sensor's stamp to the recorder's receive time.
_IMAGE_LATENCY_S = 0.030
_SCAN_LATENCY_S = 0.004

# The offered QoS that `ros2 bag record` (Humble) stores: history and depth are not discoverable (UNKNOWN, 0),
# durations "infinite". /tf_static is reliable and transient local, so that late subscribers get it on replay.
_INFINITE = QosTime(2147483647, 4294967295)


def _qos(reliability: QosReliability, durability: QosDurability) -> Qos:
    return Qos(
        QosHistory.UNKNOWN, 0, reliability, durability, _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False
    )


_LATCHED = _qos(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
_SENSOR = _qos(QosReliability.BEST_EFFORT, QosDurability.VOLATILE)
_RELIABLE = _qos(QosReliability.RELIABLE, QosDurability.VOLATILE)


@dataclass(frozen=True)
class RecordingSummary:
    """What a written recording holds: its folder, the number of images and scans, time span and size."""

    path: Path
    images: int
    scans: int
    duration_s: float
    bytes: int


# --- rendering (in worker processes when jobs > 1) --------------------------------------------------


def _render_stop(sim: Simulator, task: tuple[Stop, int]) -> tuple[int, SimFrame, list[LaserScan]]:
    """The stop's camera frame (seed (seed, index), as export.render_frames) and its scans (seed (seed, index, k))."""
    stop, seed = task
    frame = sim.frame(stop.pose, stop.image_stamp, np.random.default_rng([seed, stop.index]))
    scans = [
        sim.scan(stop.pose, stamp=t, rng=np.random.default_rng([seed, stop.index, k]))
        for k, t in enumerate(stop.scan_stamps)
    ]
    return stop.index, frame, scans


def _rendered(
    sim: Simulator, stops: Sequence[Stop], seed: int, jobs: int
) -> Iterator[tuple[int, SimFrame, list[LaserScan]]]:
    """Rendered stops in order; the same whatever ``jobs``, since every draw comes from the stop's own seeds."""
    yield from map_with_state(_render_stop, sim, [(s, seed) for s in stops], jobs=jobs, chunksize=2)


# --- writing ----------------------------------------------------------------------------------------


def _ns(stamp: float) -> int:
    return round(stamp * 1e9)


def _lift_bag(tmp: Path, bag: Path) -> None:
    """Move the bag's files from ``tmp/bag`` up into ``tmp`` (rosbags' Writer insists on creating its folder)."""
    for f in bag.iterdir():
        os.replace(f, tmp / f.name)
    bag.rmdir()


def write_recording(
    out: str | os.PathLike[str],
    sim: Simulator,
    stops: Sequence[Stop],
    *,
    seed: int,
    jobs: int = 1,
    storage: str = "mcap",
    encoding: str = "mono8",
    force: bool = False,
    progress: bool = True,
    on_frame: Callable[[int, SimFrame], None] | None = None,
) -> RecordingSummary:
    """Render the stops of a drive and write them as a rosbag2 folder (metadata.yaml + .mcap or .db3), atomically.

    The bag is built in a temporary folder beside ``out`` and renamed at the end; an existing ``out`` is
    replaced only with ``force``. Frames stream through the writer, so memory does not grow with the number
    of stops; each is handed to ``on_frame(index, frame)`` (to preview it, or estimate on it) and dropped.
    Stop i's image draws its noise from seed (seed, i), as export.render_frames does, and its k-th scan from
    (seed, i, k), so the bag does not depend on ``jobs``. ``on_frame`` gets the SimFrame as rendered: its
    ``scan`` is the simulator's scan at the image stamp, not one of the recorded scans.

    Args:
        out: the recording's folder.
        sim: the simulator (camera, robot, world, nuisances).
        stops: the drive, from plan_drive.
        seed: seed of every random draw.
        jobs: worker processes for rendering.
        storage: "mcap" or "sqlite3".
        encoding: "mono8" or "bgr8" (sensor_msgs/Image), "png" or "jpeg" (sensor_msgs/CompressedImage).
        force: replace an existing ``out``.
        progress: show a progress bar.
        on_frame: called with each stop's index and rendered frame, in order.

    Returns:
        The summary of what was written.

    Raises:
        ConfigError: unknown storage or encoding.
        InputError: ``out`` exists (without ``force``) or cannot be written.
    """
    if storage not in STORAGES:
        raise ConfigError(f"storage '{storage}' is unknown ({', '.join(STORAGES)})")
    if encoding not in m.IMAGE_ENCODINGS:
        raise ConfigError(f"image encoding '{encoding}' is unknown ({', '.join(m.IMAGE_ENCODINGS)})")
    out_path = check_writable(out, force=force)
    compressed = encoding in ("png", "jpeg")
    image_topic = COMPRESSED_IMAGE_TOPIC if compressed else IMAGE_TOPIC
    image_type = m.COMPRESSED_IMAGE if compressed else m.IMAGE
    ts = m.humble_typestore()
    n_images = n_scans = 0
    first: float | None = None
    last: float | None = None
    bar = tqdm(total=len(stops), desc="record", unit="stop", disable=None if progress else True, leave=False)
    try:
        with atomic_directory(out_path, force=force) as tmp:
            bag = tmp / out_path.name
            # Version 8 stores QoS as the integers Humble's rosbag2 reads; version 9 switched to names.
            with Writer(bag, version=8, storage_plugin=STORAGES[storage]) as writer:

                def connect(topic: str, msgtype: str, qos: Qos) -> Connection:
                    return writer.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=[qos])

                tf_conn = connect(TF_STATIC_TOPIC, m.TF_MESSAGE, _LATCHED)
                image_conn = connect(image_topic, image_type, _SENSOR)
                info_conn = connect(CAMERA_INFO_TOPIC, m.CAMERA_INFO, _SENSOR)
                scan_conn = connect(SCAN_TOPIC, m.LASER_SCAN, _SENSOR)
                truth_conn = connect(TRUTH_TOPIC, m.POSE_STAMPED, _RELIABLE)

                def put(conn: Connection, msgtype: str, msg: Any, receive: float) -> None:
                    writer.write(conn, _ns(receive), ts.serialize_cdr(msg, msgtype))

                if stops:
                    first = min([stops[0].image_stamp, *stops[0].scan_stamps])
                    put(tf_conn, m.TF_MESSAGE, m.tf_static_msg(sim.robot, first, camera_frame=CAMERA_FRAME), first)
                for (index, frame, scans), stop in zip(_rendered(sim, stops, seed, jobs), stops, strict=True):
                    t = stop.image_stamp
                    _, image_msg = m.encode_image(frame.image, encoding, t, CAMERA_FRAME)
                    batch: list[tuple[float, Connection, str, Any]] = [
                        (t + _IMAGE_LATENCY_S, image_conn, image_type, image_msg),
                        (
                            t + _IMAGE_LATENCY_S,
                            info_conn,
                            m.CAMERA_INFO,
                            m.camera_info_msg(sim.camera, t, CAMERA_FRAME),
                        ),
                        (t, truth_conn, m.POSE_STAMPED, m.pose_msg(stop.pose, t, BASE_FRAME)),
                    ]
                    batch += [(s.stamp + _SCAN_LATENCY_S, scan_conn, m.LASER_SCAN, m.scan_msg(s)) for s in scans]
                    # In receive order, as a recorder writes them.
                    for receive, conn, msgtype, msg in sorted(batch, key=lambda b: b[0]):
                        put(conn, msgtype, msg, receive)
                    last = max([t, *(s.stamp for s in scans)])
                    n_images += 1
                    n_scans += len(scans)
                    bar.update()
                    if on_frame is not None:
                        on_frame(index, frame)
            # The temporary folder is private (0700); give the recording the mode rosbags gave its folder
            # (0755 less the umask), as `ros2 bag record` would.
            tmp.chmod(bag.stat().st_mode & 0o777)
            _lift_bag(tmp, bag)
    finally:
        bar.close()
    size = sum(f.stat().st_size for f in out_path.iterdir() if f.is_file())
    duration = last - first if first is not None and last is not None else 0.0
    return RecordingSummary(out_path, n_images, n_scans, duration, size)
