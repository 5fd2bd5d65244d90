"""A simulated stop-and-go drive written as a rosbag2 recording, the way ``ros2 bag record`` would have recorded it.

Topics and frames are ``recording.write``'s: the camera image (raw or compressed) with its CameraInfo, the
LaserScan, ``/tf_static`` once at the start, and the simulator's ground truth (a PoseStamped DockPose in
base_link per image) on ``/monodock/ground_truth``, which training never reads and evaluation does.

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
from rosbags.interfaces import Connection
from tqdm import tqdm

from monodock.compute import map_with_state
from monodock.core.scan import LaserScan
from monodock.errors import ConfigError
from monodock.recording import messages as m
from monodock.recording.write import (
    BASE_FRAME,
    CAMERA_FRAME,
    CAMERA_INFO_TOPIC,
    COMPRESSED_IMAGE_TOPIC,
    IMAGE_TOPIC,
    LATCHED,
    RELIABLE,
    SCAN_TOPIC,
    SENSOR,
    TF_STATIC_TOPIC,
    TRUTH_TOPIC,
    BagWriter,
)
from monodock.sim.drive import Stop
from monodock.sim.simulator import SimFrame, Simulator

__all__ = ["RecordingSummary", "write_recording"]

# Transport delay from the sensor's stamp to the recorder's receive time.
_IMAGE_LATENCY_S = 0.030
_SCAN_LATENCY_S = 0.004


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
    if encoding not in m.IMAGE_ENCODINGS:
        raise ConfigError(f"image encoding '{encoding}' is unknown ({', '.join(m.IMAGE_ENCODINGS)})")
    compressed = encoding in ("png", "jpeg")
    image_topic = COMPRESSED_IMAGE_TOPIC if compressed else IMAGE_TOPIC
    image_type = m.COMPRESSED_IMAGE if compressed else m.IMAGE
    n_images = n_scans = 0
    first: float | None = None
    last: float | None = None
    bar = tqdm(total=len(stops), desc="record", unit="stop", disable=None if progress else True, leave=False)
    try:
        with BagWriter(out, storage=storage, force=force) as bag:
            tf_conn = bag.connect(TF_STATIC_TOPIC, m.TF_MESSAGE, LATCHED)
            image_conn = bag.connect(image_topic, image_type, SENSOR)
            info_conn = bag.connect(CAMERA_INFO_TOPIC, m.CAMERA_INFO, SENSOR)
            scan_conn = bag.connect(SCAN_TOPIC, m.LASER_SCAN, SENSOR)
            truth_conn = bag.connect(TRUTH_TOPIC, m.POSE_STAMPED, RELIABLE)
            if stops:
                first = min([stops[0].image_stamp, *stops[0].scan_stamps])
                bag.write(tf_conn, m.tf_static_msg(sim.robot, first, camera_frame=CAMERA_FRAME), first)
            for (index, frame, scans), stop in zip(_rendered(sim, stops, seed, jobs), stops, strict=True):
                t = stop.image_stamp
                _, image_msg = m.encode_image(frame.image, encoding, t, CAMERA_FRAME)
                batch: list[tuple[float, Connection, Any]] = [
                    (t + _IMAGE_LATENCY_S, image_conn, image_msg),
                    (t + _IMAGE_LATENCY_S, info_conn, m.camera_info_msg(sim.camera, t, CAMERA_FRAME)),
                    (t, truth_conn, m.pose_msg(stop.pose, t, BASE_FRAME)),
                ]
                batch += [(s.stamp + _SCAN_LATENCY_S, scan_conn, m.scan_msg(s)) for s in scans]
                # In receive order, as a recorder writes them.
                for receive, conn, msg in sorted(batch, key=lambda b: b[0]):
                    bag.write(conn, msg, receive)
                last = max([t, *(s.stamp for s in scans)])
                n_images += 1
                n_scans += len(scans)
                bar.update()
                if on_frame is not None:
                    on_frame(index, frame)
    finally:
        bar.close()
    duration = last - first if first is not None and last is not None else 0.0
    return RecordingSummary(bag.path, n_images, n_scans, duration, bag.size_bytes())
