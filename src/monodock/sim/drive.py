"""A simulated stop-and-go data-collection drive: where the robot stops and when each sensor fires.

Like the papers' data collection, the robot stops at poses in front of the charger; at each stop the camera
records one frame while the LiDAR keeps scanning. The recorder is paused in transit (``ros2 bag`` can pause),
so only the stops end up in the recording. The camera and the LiDAR run on their own free-running clocks
with their own random phases, so an image and the scans around it never share a stamp: pairing them is the
reader's job, as with a real robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose import DockPose
from monodock.errors import ConfigError
from monodock.sim.simulator import PoseDistribution, Simulator

__all__ = [
    "DENSITIES",
    "PAPER_SEGMENT_COUNTS",
    "SEGMENTS",
    "SEGMENT_START_M",
    "SEGMENT_WIDTH_M",
    "DriveConfig",
    "Stop",
    "plan_drive",
    "segment_bounds",
    "segment_weights",
]

# The papers' 5 cm depth segments over 25-250 cm, depth measured from the camera.
SEGMENT_START_M = 0.25
SEGMENT_WIDTH_M = 0.05
SEGMENTS = 45

# N per segment from Table 2 of the Sensors 2025 paper, 25-30 cm first. The table stops at 240-245 cm;
# the last segment (245-250 cm) has no row and takes its neighbour's N (47).
PAPER_SEGMENT_COUNTS: tuple[int, ...] = (
    # 25-135 cm
    69, 276, 335, 431, 429, 428, 366, 460, 577, 494, 442, 338, 369, 469, 433, 957, 982, 853, 977, 934, 703, 909,
    # 135-245 cm
    705, 598, 396, 458, 193, 138, 117, 101, 23, 21, 18, 49, 83, 63, 61, 93, 49, 9, 7, 8, 10, 47,
    # 245-250 cm: no row in Table 2, the neighbour's value
    47,
)  # fmt: skip

DENSITIES = ("uniform", "paper")


def segment_bounds(k: int) -> tuple[float, float]:
    """Depth range (from the camera, metres) of segment ``k`` (0: 25-30 cm)."""
    lo = SEGMENT_START_M + SEGMENT_WIDTH_M * k
    return lo, lo + SEGMENT_WIDTH_M


@dataclass(frozen=True)
class DriveConfig:
    """How the simulated data-collection drive goes.

    Attributes:
        stops: number of stops, one camera frame each.
        depth: depth range from the camera, metres (DockPose.x minus the camera mount's x).
        lateral: DockPose y range, metres.
        yaw_deg: DockPose yaw range, degrees.
        density: stops per 5 cm segment: "uniform", "paper" (Table 2's N), or 45 non-negative weights.
        camera_rate_hz: the camera's frame rate.
        lidar_rate_hz: the LiDAR's scan rate.
        dwell_s: time at each stop; the LiDAR scans throughout (about 3 scans at 10 Hz).
        transit_s: range of the (unrecorded) driving time between two stops, seconds.
        scan_loss: chance that a LiDAR message is lost (exercises unpaired frames).
        start_s: stamp at which the drive starts, seconds (a wall-clock time, as a real recording has).
    """

    stops: int = 1000
    depth: tuple[float, float] = (0.25, 2.5)
    lateral: tuple[float, float] = (-0.4, 0.4)
    yaw_deg: tuple[float, float] = (-30.0, 30.0)
    density: str | tuple[float, ...] = "uniform"
    camera_rate_hz: float = 15.0
    lidar_rate_hz: float = 10.0
    dwell_s: float = 0.35
    transit_s: tuple[float, float] = (1.0, 4.0)
    scan_loss: float = 0.0
    start_s: float = 1_700_000_000.0

    def __post_init__(self) -> None:
        if self.stops < 1:
            raise ConfigError(f"drive: stops must be at least 1, got {self.stops}")
        for name in ("camera_rate_hz", "lidar_rate_hz", "dwell_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"drive: {name} must be positive, got {value}")
        for name in ("depth", "lateral", "yaw_deg", "transit_s"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ConfigError(f"drive: {name} must be a range (low, high) with low <= high, got ({lo}, {hi})")
        if self.transit_s[0] < 0:
            raise ConfigError(f"drive: transit_s must not be negative, got {self.transit_s}")
        if not self.depth[0] < self.depth[1]:
            raise ConfigError(f"drive: depth must be a range with low < high, got {self.depth}")
        if not 0.0 <= self.scan_loss <= 1.0:
            raise ConfigError(f"drive: scan_loss must be a probability in [0, 1], got {self.scan_loss}")
        if not math.isfinite(self.start_s):
            raise ConfigError(f"drive: start_s must be finite, got {self.start_s}")
        segment_weights(self.density)  # raises on an unknown name or bad weights


def segment_weights(density: str | tuple[float, ...]) -> NDArray[np.float64]:
    """Relative number of stops per 5 cm segment, shape (45,), of a DriveConfig density."""
    if isinstance(density, str):
        if density == "uniform":
            return np.ones(SEGMENTS)
        if density == "paper":
            return np.array(PAPER_SEGMENT_COUNTS, dtype=np.float64)
        raise ConfigError(f"drive: density '{density}' is unknown ({', '.join(DENSITIES)}, or {SEGMENTS} weights)")
    w = np.asarray(density, dtype=np.float64).ravel()
    if w.size != SEGMENTS:
        raise ConfigError(f"drive: density needs {SEGMENTS} weights (one per 5 cm segment), got {w.size}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ConfigError("drive: density weights must be finite and non-negative")
    return w


@dataclass(frozen=True)
class Stop:
    """One stop of the drive: the robot's DockPose, the camera frame's stamp and the LiDAR scans' stamps."""

    index: int
    pose: DockPose
    image_stamp: float
    scan_stamps: tuple[float, ...]


def _ticks(phase: float, period: float, t0: float, t1: float) -> NDArray[np.float64]:
    """Times ``phase + k * period`` (k integer) inside [t0, t1)."""
    k0 = math.ceil((t0 - phase) / period)
    k1 = math.ceil((t1 - phase) / period)
    return phase + period * np.arange(k0, k1, dtype=np.float64)


def plan_drive(sim: Simulator, config: DriveConfig, rng: np.random.Generator) -> list[Stop]:
    """The stops of a drive: poses by segment weight, and the stamps of each sensor on its own clock.

    Each stop draws its 5 cm segment by weight (segments cut by ``config.depth`` weighted by the part that is
    kept), then a pose whose depth is uniform inside the segment, with marker 2 in view. The camera and LiDAR
    clocks tick from random phases; the stop's image is one camera tick inside the dwell, its scans are all
    LiDAR ticks inside the dwell that are not lost. Stamps strictly increase, with a transit gap between stops.
    """
    lo_all, hi_all = config.depth
    weights = segment_weights(config.density)
    bounds = np.array([segment_bounds(k) for k in range(SEGMENTS)])
    kept_lo = np.maximum(bounds[:, 0], lo_all)
    kept_hi = np.minimum(bounds[:, 1], hi_all)
    overlap = np.clip(kept_hi - kept_lo, 0.0, None) / SEGMENT_WIDTH_M
    p = weights * overlap
    if not p.sum() > 0:
        raise ConfigError(
            f"drive: no stops possible: density gives zero weight to every 5 cm segment in depth {config.depth}"
        )
    p = p / p.sum()

    camera_period = 1.0 / config.camera_rate_hz
    lidar_period = 1.0 / config.lidar_rate_hz
    camera_phase = config.start_s + float(rng.uniform(0.0, camera_period))
    lidar_phase = config.start_s + float(rng.uniform(0.0, lidar_period))

    stops: list[Stop] = []
    arrive = config.start_s + float(rng.uniform(*config.transit_s))
    for index in range(config.stops):
        k = int(rng.choice(SEGMENTS, p=p))
        dist = PoseDistribution(
            depth=(float(kept_lo[k]), float(kept_hi[k])), lateral=config.lateral, yaw_deg=config.yaw_deg
        )
        try:
            pose = sim.sample_pose(dist, rng=rng)
        except RuntimeError:
            lo, hi = segment_bounds(k)
            raise ConfigError(
                f"drive: marker 2 is never in view at depth {lo * 100:.0f}-{hi * 100:.0f} cm with lateral "
                f"{config.lateral} m and yaw {config.yaw_deg} deg; narrow lateral/yaw or change depth"
            ) from None
        leave = arrive + config.dwell_s
        frames = _ticks(camera_phase, camera_period, arrive, leave)
        if frames.size == 0:  # a dwell shorter than one camera period: the first frame after arriving
            frames = _ticks(camera_phase, camera_period, arrive, arrive + camera_period)
        image_stamp = float(frames[rng.integers(frames.size)])
        scans = _ticks(lidar_phase, lidar_period, arrive, leave)
        kept = scans[rng.random(scans.size) >= config.scan_loss]
        stops.append(Stop(index, pose, image_stamp, tuple(float(s) for s in kept)))
        last = max(leave, image_stamp)
        arrive = last + max(float(rng.uniform(*config.transit_s)), 1e-3)
    return stops
