"""Writing a simulated data set to a folder: PNG images, LiDAR scans, calibration files, ground truth.

Layout of the folder (documented in the README)::

    images/frame_000000.png ...   mono8 camera images
    scans.npz                     LaserScan fields; ranges shape (frames, beams), NaN/inf as in REP 117
    camera.yaml                   ROS camera_info YAML
    robot.yaml, layout.yaml       the robot description and dock layout used
    ground_truth.csv              one row per frame: DockPose, robot pose, true corners, visibility
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from monodock.compute import map_with_state
from monodock.core.atomic import atomic_directory
from monodock.core.images import encode_png
from monodock.core.layout import ROLE_NUMBER, ROLES
from monodock.core.pose import DockPose
from monodock.core.scan import LaserScan
from monodock.sim.simulator import FrameTruth, SimFrame, Simulator

__all__ = ["GROUND_TRUTH_COLUMNS", "FrameInfo", "FrameRecord", "render_frames", "write_frame_folder"]

_CORNERS = ("tl", "tr", "br", "bl")


def _gt_columns() -> list[str]:
    cols = [
        "frame",
        "index",
        "stamp",
        "x_m",
        "y_m",
        "yaw_deg",
        "depth_m",
        "robot_x_m",
        "robot_y_m",
        "robot_yaw_deg",
    ]
    for role in ROLES:
        m = f"m{ROLE_NUMBER[role]}"
        cols += [f"{m}_in_view", f"{m}_visible_fraction"]
        cols += [f"{m}_{c}_{a}" for c in _CORNERS for a in ("u", "v")]
    return cols


GROUND_TRUTH_COLUMNS: tuple[str, ...] = tuple(_gt_columns())


@dataclass(frozen=True)
class FrameInfo:
    """What stays of a written frame: its place in the set and its truth (the pixels are on disk)."""

    index: int
    name: str
    stamp: float
    truth: FrameTruth


@dataclass(frozen=True)
class FrameRecord:
    """A rendered frame with its place in the set."""

    index: int
    name: str
    stamp: float
    frame: SimFrame


def _render_one(sim: Simulator, task: tuple[int, DockPose, float, int]) -> tuple[int, SimFrame]:
    index, pose, stamp, seed = task
    return index, sim.frame(pose, stamp, np.random.default_rng([seed, index]))


def render_frames(
    sim: Simulator,
    poses: Sequence[DockPose],
    *,
    seed: int,
    rate_hz: float = 10.0,
    jobs: int = 1,
    progress: bool = True,
) -> Iterator[FrameRecord]:
    """Render frames for the poses, in order; frame i draws its noise from seed (seed, i) whatever ``jobs``."""
    tasks = [(i, p, i / rate_hz, seed) for i, p in enumerate(poses)]
    bar = tqdm(total=len(tasks), desc="simulate", unit="frame", disable=None if progress else True, leave=False)
    try:
        for index, frame in map_with_state(_render_one, sim, tasks, jobs=jobs, chunksize=4):
            bar.update()
            yield FrameRecord(index, f"frame_{index:06d}.png", tasks[index][2], frame)
    finally:
        bar.close()


def _gt_row(rec: FrameRecord, sim: Simulator) -> list[object]:
    t = rec.frame.truth
    rx, ry, ryaw = t.pose.robot_in_dock()
    row: list[object] = [
        rec.name,
        rec.index,
        f"{rec.stamp:.6f}",
        f"{t.pose.x:.6f}",
        f"{t.pose.y:.6f}",
        f"{math.degrees(t.pose.yaw):.6f}",
        f"{t.pose.x - sim.robot.camera_mount.x:.6f}",
        f"{rx:.6f}",
        f"{ry:.6f}",
        f"{math.degrees(ryaw):.6f}",
    ]
    for role in ROLES:
        row += [int(t.in_view[role]), f"{t.visible_fraction[role]:.4f}"]
        row += [f"{v:.5f}" for v in t.corners[role].ravel()]
    return row


def write_frame_folder(
    out: str | Path,
    sim: Simulator,
    poses: Sequence[DockPose],
    *,
    seed: int,
    jobs: int = 1,
    force: bool = False,
    progress: bool = True,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> list[FrameInfo]:
    """Render the poses and write the folder atomically.

    Frames stream through: each image is written and handed to ``on_frame`` (to estimate on it, or draw a
    preview) and then dropped, so memory does not grow with the number of frames. Returns each frame's
    name, stamp and truth.
    """
    infos: list[FrameInfo] = []
    with atomic_directory(out, force=force) as tmp:
        (tmp / "images").mkdir()
        ranges = []
        first_scan: LaserScan | None = None
        gt = io.StringIO()
        writer = csv.writer(gt, lineterminator="\n")
        writer.writerow(GROUND_TRUTH_COLUMNS)
        for rec in render_frames(sim, poses, seed=seed, jobs=jobs, progress=progress):
            (tmp / "images" / rec.name).write_bytes(encode_png(rec.frame.image))
            first_scan = first_scan or rec.frame.scan
            ranges.append(rec.frame.scan.ranges)
            writer.writerow(_gt_row(rec, sim))
            infos.append(FrameInfo(rec.index, rec.name, rec.stamp, rec.frame.truth))
            if on_frame is not None:
                on_frame(rec)
        (tmp / "ground_truth.csv").write_text(gt.getvalue(), encoding="utf-8")
        if first_scan is not None:
            s = first_scan
            np.savez_compressed(
                tmp / "scans.npz",
                frame=np.array([i.name for i in infos]),
                stamp=np.array([i.stamp for i in infos]),
                ranges=np.stack(ranges).astype(np.float32),
                frame_id=np.array(s.frame_id),
                angle_min=np.float64(s.angle_min),
                angle_max=np.float64(s.angle_max),
                angle_increment=np.float64(s.angle_increment),
                time_increment=np.float64(s.time_increment),
                scan_time=np.float64(s.scan_time),
                range_min=np.float64(s.range_min),
                range_max=np.float64(s.range_max),
            )
        sim.camera.save(tmp / "camera.yaml")
        sim.robot.save(tmp / "robot.yaml")
        sim.layout.save(tmp / "layout.yaml")
    return infos
