"""The simulated base's sensors and faults against the simulator's ground truth.

Every expectation is computed here from geometry (the analytic distance to a cylinder, a densely sampled circle,
the true pose), never by calling the code under test a second way.
"""

from __future__ import annotations

import copy
import math

import cv2
import numpy as np
import pytest

from monodock.core.camera import CameraModel
from monodock.core.pose2d import Pose2D
from monodock.perception.detect import MarkerDetector
from monodock.sim import Nuisances, Simulator
from monodock.sim.diffdrive import DiffDriveConfig, Exposure, SimulatedRobot
from monodock.sim.faults import Obstacle
from monodock.sim.render import render_radiance

SIM = Simulator(nuisances=Nuisances.clean(), seed=1)
FRONT = SIM.robot.front_offset
REAR = DiffDriveConfig().rear_offset


def _robot(start: Pose2D, seed: int = 0, obstacles: tuple[Obstacle, ...] = (), **drive: object) -> SimulatedRobot:
    config = DiffDriveConfig(**drive)  # type: ignore[arg-type]
    return SimulatedRobot(SIM, start, config, np.random.default_rng(seed), obstacles=list(obstacles))


# --- rear range -------------------------------------------------------------------------------------------


def test_rear_range_reads_a_cylinder_straight_behind() -> None:
    robot = _robot(Pose2D(-1.0, 0.2, 0.0))
    back = -1.0 - REAR
    robot.obstacles.append(Obstacle(back - 0.8 - 0.1, 0.2, 0.1))
    reads = np.array([robot.rear_range() for _ in range(400)], dtype=float)
    assert abs(reads.mean() - 0.8) < 0.002
    assert 0.004 < reads.std() < 0.006  # the configured noise
    assert np.all(np.abs(reads - 0.8) < 0.03)


def test_rear_range_follows_a_turned_robot_and_a_partly_seen_cylinder() -> None:
    theta = 0.7
    robot = _robot(Pose2D(0.3, -0.4, theta), rear_range_noise_sd=0.0)
    ox, oy = 0.3 - REAR * math.cos(theta), -0.4 - REAR * math.sin(theta)  # the back edge's centre
    back = theta + math.pi
    # 25 degrees off the axis, big enough to reach into the 15-degree half cone: only part of it is seen.
    centre_dir, dist, r = back + math.radians(25.0), 1.0, 0.25
    cx, cy = ox + dist * math.cos(centre_dir), oy + dist * math.sin(centre_dir)
    robot.obstacles.append(Obstacle(cx, cy, r))
    phi = np.linspace(0.0, 2.0 * math.pi, 200_000)
    px, py = cx + r * np.cos(phi), cy + r * np.sin(phi)
    bearing = np.angle(np.exp(1j * (np.arctan2(py - oy, px - ox) - back)))
    inside = np.abs(bearing) <= math.radians(15.0)
    expected = float(np.hypot(px - ox, py - oy)[inside].min())
    assert expected > dist - r + 0.01  # the part it sees is not the part nearest to it
    assert robot.rear_range() == pytest.approx(expected, abs=1e-4)


def test_rear_range_is_inf_outside_the_cone_or_range_and_none_without_a_sensor() -> None:
    start = Pose2D(-1.0, 0.0, 0.0)
    back = -1.0 - REAR
    robot = _robot(start)
    assert robot.rear_range() == math.inf  # nothing there
    a = math.radians(30.0)
    robot.obstacles.append(Obstacle(back - 0.8 * math.cos(a), 0.8 * math.sin(a), 0.05))  # 30 deg off the axis
    robot.obstacles.append(Obstacle(back - 2.1 - 0.05, 0.0, 0.05))  # straight behind, 2.1 m: beyond range
    assert robot.rear_range() == math.inf
    assert _robot(start, rear_range_max=2.5).rear_range() == math.inf  # no obstacles in that one
    robot.obstacles.append(Obstacle(back - 1.0, 0.0, 0.1, appear=0.5, vanish=1.0))  # someone walks by
    assert robot.rear_range() == math.inf
    robot.sleep(0.6)
    assert robot.rear_range() == pytest.approx(0.9 - (robot.pose.x - start.x), abs=0.03)
    robot.sleep(0.5)
    assert robot.rear_range() == math.inf
    assert _robot(start, rear_sensor=False).rear_range() is None


# --- clearance and collision --------------------------------------------------------------------------------


def test_reversing_into_a_cylinder_is_a_collision() -> None:
    cx, r = -1.0 - REAR - 0.3 - 0.1, 0.1
    beside = Obstacle(-1.0, 0.2 + 0.15 + 0.05, 0.05)  # 15 cm off the robot's left side, never touched
    robot = _robot(Pose2D(-1.0, 0.0, 0.0), obstacles=(Obstacle(cx, 0.0, r), beside))
    assert robot.min_clearance == pytest.approx(0.15)
    robot.send_velocity(-0.2, 0.0)
    robot.sleep(1.0)
    p = robot.pose
    gap = math.hypot(*np.subtract(p.point(-REAR, 0.0), (cx, 0.0))) - r  # back edge's centre to the surface
    assert 0.05 < gap < 0.2
    assert robot.min_clearance == pytest.approx(min(gap, 0.15), abs=0.01)
    assert not robot.collided
    robot.sleep(1.5)
    assert robot.collided
    assert robot.min_clearance < 0.0
    assert robot.pose.x - REAR < cx + r  # it really is inside the cylinder by the truth


# --- charging -----------------------------------------------------------------------------------------------


def _press(lateral: float, heading_deg: float = 0.0, **drive: object) -> tuple[SimulatedRobot, list[bool | None]]:
    """Start 1 mm from the face, creep forward; what ``charging()`` said every 50 ms for 1 s."""
    theta = math.radians(heading_deg)
    half = 0.5 * DiffDriveConfig().footprint_width
    # Place the nearest front corner 1 mm off the face.
    x = -0.001 - FRONT * math.cos(theta) - half * abs(math.sin(theta))
    robot = _robot(Pose2D(x, lateral, theta), contact_sensor=True, **drive)
    assert robot.front_gap() == pytest.approx(0.001)
    robot.send_velocity(0.02, 0.0)
    said = []
    for _ in range(20):
        robot.sleep(0.05)
        said.append(robot.charging())
    return robot, said


def test_charging_on_the_pads_after_the_delay() -> None:
    robot, said = _press(0.01)
    assert robot.contact()
    assert robot.front_gap() < 1e-4
    assert abs(robot.pose.y) < 0.015
    assert abs(robot.pose.theta) < math.radians(4.0)
    assert not any(said[:5])  # 0.25 s: the charger's current sense has not reported yet
    assert all(said[6:])  # from 0.35 s on
    robot.send_velocity(-0.1, 0.0)
    robot.sleep(0.2)
    assert robot.front_gap() > 0.002
    assert robot.charging() is False


def test_no_charging_off_the_pads() -> None:
    robot, said = _press(0.03)
    assert robot.contact()  # it touches the face ...
    assert not any(said)  # ... but the springs miss the pads
    robot, said = _press(0.0, heading_deg=6.0)
    assert robot.contact()
    assert not any(said)


def test_charging_is_none_without_the_signal() -> None:
    _, said = _press(0.0, charging_signal=False)
    assert said == [None] * 20


# --- motion blur ----------------------------------------------------------------------------------------------

CLEAN = Simulator(nuisances=Nuisances.clean(), seed=1)  # no lens blur, no noise: a still edge is a pixel wide


def _turning(sim: Simulator, exposure: float, omega: float = 0.6) -> tuple[SimulatedRobot, Exposure]:
    """A robot turning on the spot 1 m before the charger, its steady speed reached; its newest arrived exposure."""
    robot = SimulatedRobot(
        sim, Pose2D(-1.0, 0.0, -0.25), DiffDriveConfig(exposure_time=exposure), np.random.default_rng(5)
    )
    robot.send_velocity(0.0, omega)
    robot.sleep(0.35)
    return robot, next(e for e in reversed(robot.exposure_log) if e.arrival <= robot.t)


def _edge_width(image: np.ndarray, corners: np.ndarray) -> float:
    """Contrast over the steepest step (px) across the marker's left outer edge, median over its middle rows:
    a box blur of b px gives b, a sharp edge about 1."""
    x = int(round(0.5 * (corners[0, 0] + corners[3, 0])))
    top, bottom = corners[0, 1], corners[3, 1]
    rows = range(int(top + 0.3 * (bottom - top)), int(top + 0.7 * (bottom - top)))
    widths = []
    for r in rows:
        profile = image[r, x - 10 : x + 11].astype(float)
        widths.append((profile.max() - profile.min()) / np.abs(np.diff(profile)).max())
    return float(np.median(widths))


def test_turning_blurs_the_markers_by_the_truths_streak() -> None:
    robot, e = _turning(CLEAN, 0.02)
    frame = robot.latest_frame()
    assert frame is not None
    assert frame.stamp == e.stamp
    still = CLEAN.render(robot.dock_pose(e.mid))  # the same pose, not moving
    corners = CLEAN.true_corners(robot.dock_pose(e.mid))
    box = np.concatenate(list(corners.values()))
    (x0, y0), (x1, y1) = np.floor(box.min(axis=0)).astype(int) - 5, np.ceil(box.max(axis=0)).astype(int) + 5

    def energy(image: np.ndarray) -> float:
        return float(np.sum(np.diff(image[y0:y1, x0:x1].astype(float), axis=1) ** 2))

    assert energy(frame.image) < 0.5 * energy(still)
    # The streak by the truth: how far the marker's corners moved in the image during the exposure.
    centre = corners["center"]
    moved = (
        CLEAN.true_corners(robot.dock_pose(e.end))["center"] - CLEAN.true_corners(robot.dock_pose(e.start))["center"]
    )
    streak = float(np.mean(np.abs(moved[:, 0])))
    omega = (e.end.theta - e.start.theta) / 0.02
    assert omega == pytest.approx(0.6, rel=0.15)  # the wheels are noisy step to step
    assert 0.8 < streak / (CLEAN.camera.fx * omega * 0.02) < 1.5  # f w T, plus the camera's sideways motion
    assert _edge_width(still, centre) < 2.0
    assert _edge_width(frame.image, centre) == pytest.approx(streak, rel=0.25)


def test_no_exposure_time_or_no_motion_renders_exactly_as_before() -> None:
    noisy = Simulator(seed=1)
    for exposure, omega in ((0.0, 0.6), (0.008, 0.0)):
        robot, e = _turning(noisy, exposure, omega)
        rng = copy.deepcopy(robot.rng)
        frame = robot.latest_frame()
        assert frame is not None
        assert frame.stamp == e.stamp
        assert np.array_equal(frame.image, noisy.render(robot.dock_pose(e.mid), rng=rng))


# --- frame faults -------------------------------------------------------------------------------------------

TINY = Simulator(camera=CameraModel.from_intrinsics(64, 48, 60.0, 60.0, 32.0, 24.0), nuisances=Nuisances.clean())


def _watch(robot: SimulatedRobot, until: float) -> list[tuple[float, float]]:
    """(stamp, when first seen) of every frame ``latest_frame`` hands over, polled every 10 ms."""
    seen: list[tuple[float, float]] = []
    while robot.t < until:
        robot.sleep(0.01)
        f = robot.latest_frame()
        if f is not None and (not seen or f.stamp != seen[-1][0]):
            seen.append((f.stamp, robot.t))
    return seen


def _tiny(**drive: object) -> SimulatedRobot:
    config = DiffDriveConfig(**drive)  # type: ignore[arg-type]
    return SimulatedRobot(TINY, Pose2D(-1.0, 0.0, 0.0), config, np.random.default_rng(7))


def test_dropped_frames_never_arrive() -> None:
    robot = _tiny()
    robot.drop_frames(1.0, 2.0)
    seen = _watch(robot, 3.0)
    stamps = [s for s, _ in seen]
    exposed = [e.stamp for e in robot.exposure_log if e.stamp + 0.05 < 2.99]
    assert stamps == [s for s in exposed if not 1.0 <= s < 2.0]
    assert all(t - s == pytest.approx(0.05, abs=0.011) for s, t in seen)

    robot = _tiny(frame_drop_rate=0.3)
    seen = _watch(robot, 6.0)
    exposed = [e.stamp for e in robot.exposure_log if e.stamp + 0.05 < 5.99]
    assert 0.55 < len(seen) / len(exposed) < 0.85


def test_late_frames_arrive_late_or_are_superseded() -> None:
    robot = _tiny()
    robot.delay_frames(1.0, 1.5, 0.3)
    seen = _watch(robot, 3.0)
    stamps = [s for s, _ in seen]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == len(stamps)
    late = [(s, t) for s, t in seen if 1.0 <= s < 1.5]
    assert late  # the first of them arrive before any newer frame ...
    assert all(t - s == pytest.approx(0.35, abs=0.011) for s, t in late)
    assert len(late) < sum(1.0 <= e.stamp < 1.5 for e in robot.exposure_log)  # ... the last are superseded
    assert all(t - s == pytest.approx(0.05, abs=0.011) for s, t in seen if not 1.0 <= s < 1.5)
    exposed = [e.stamp for e in robot.exposure_log if e.stamp + 0.05 < 2.99]
    assert set(exposed) - set(stamps) <= {s for s in exposed if 1.0 <= s < 1.5}

    robot = _tiny(latency_spike_rate=0.5, latency_spike=0.3)
    seen = _watch(robot, 4.0)
    stamps = [s for s, _ in seen]
    assert stamps == sorted(stamps)
    delays = np.array([t - s for s, t in seen])
    on_time = np.abs(delays - 0.05) < 0.011
    assert np.all(on_time | (np.abs(delays - 0.35) < 0.011))
    assert 0 < np.count_nonzero(~on_time) < np.count_nonzero(on_time)  # late ones are often superseded


# --- odometry faults ------------------------------------------------------------------------------------------


def test_an_odometry_jump_moves_odometry_not_the_robot() -> None:
    robot = _robot(Pose2D(-1.5, 0.1, 0.05))
    robot.sleep(0.1)
    odom, pose = robot.odometry().pose, robot.pose
    robot.jump_odometry(0.1, -0.05, 0.2)
    assert robot.odometry().pose == pytest.approx((odom.x + 0.1, odom.y - 0.05, odom.theta + 0.2))
    assert robot.pose == pose
    robot.send_velocity(0.2, 0.0)
    robot.sleep(1.0)
    o, p = robot.odometry().pose, robot.pose
    assert math.atan2(o.y - odom.y + 0.05, o.x - odom.x - 0.1) == pytest.approx(odom.theta + 0.2, abs=0.02)
    assert math.atan2(p.y - pose.y, p.x - pose.x) == pytest.approx(0.05, abs=0.02)


def test_a_slipping_wheel_turns_the_robot_behind_the_odometrys_back() -> None:
    robot = _robot(Pose2D(-2.5, 0.0, 0.0))
    robot.slip_wheel("left", 0.5, 1.0, 2.0)
    robot.send_velocity(0.2, 0.0)
    robot.sleep(1.0)
    assert abs(robot.pose.theta) < 0.02
    robot.sleep(2.0)
    # The left wheel at 0.1 m/s, the right at 0.2 m/s on a 0.4 m track: 0.25 rad/s for 1 s.
    assert robot.pose.theta == pytest.approx(0.25, abs=0.04)
    assert abs(robot.odometry().pose.theta) < 0.01
    with pytest.raises(ValueError, match="left"):
        robot.slip_wheel("front", 0.5, 0.0, 1.0)


# --- the blur's warps and frames nothing can be detected in ---------------------------------------------------


def _opencv_blur(radiance: np.ndarray, start: np.ndarray, end: np.ndarray, k: int) -> np.ndarray:
    """The blur as OpenCV computes it over the whole image: the shifts spread by cv2.resize, each warp's map by
    cv2.scaleAdd, sampled by cv2.remap, the mean of the k warps."""
    h, w = radiance.shape
    gh, gw = -(-h // 32), -(-w // 32)
    dense = [
        cv2.resize(s.reshape(gh, gw, 2).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        for s in (start, end)
    ]
    ix, iy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    identity = np.stack([ix, iy], axis=-1)
    total = np.zeros_like(radiance)
    for i in range(k):
        u = (i + 0.5) / k - 0.5
        if abs(u) < 1e-9:
            total += radiance
            continue
        where = cv2.scaleAdd(dense[u > 0], 2.0 * abs(u), identity)
        total += cv2.remap(radiance, where, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    total *= np.float32(1.0 / k)
    return total


@pytest.mark.parametrize(("omega", "speed"), [(0.0, 0.05), (0.6, 0.0), (2.5, 0.1), (-6.0, 0.2)])
def test_the_blur_warps_as_opencv_does_over_the_whole_image(omega: float, speed: float) -> None:
    """Only pixels near an edge are warped, by a compiled kernel: the image is OpenCV's whole-image warps' (bit for
    bit with OpenCV 5.1 on x86-64; a few float32 ulps allowed for another build), for short and long streaks."""
    noisy = Simulator(seed=1)
    robot = SimulatedRobot(
        noisy, Pose2D(-0.9, 0.05, -0.2), DiffDriveConfig(exposure_time=0.03), np.random.default_rng(5)
    )
    robot.send_velocity(speed, omega)
    robot.sleep(0.4)
    e = robot.exposure_log[-1]
    streak = robot._blur.streak(e)
    assert streak is not None
    radiance = render_radiance(noisy.world, noisy.camera, noisy.world_T_optical(robot.dock_pose(e.mid)))
    k = min(8, max(2, math.ceil(streak.length / 1.5)))
    expected = _opencv_blur(radiance, streak.start, streak.end, k)
    got = robot._blur.blur(radiance, streak)
    assert np.abs(got - expected).max() <= 1e-6
    assert np.mean(got == expected) > 0.999
    assert np.count_nonzero(expected != radiance) > 1000  # it did blur


def test_frames_with_every_marker_cut_by_the_border_are_blank_and_nothing_else_changes() -> None:
    """At the face the camera sees no marker whole: such a frame is delivered blank, says so, and draws the same
    random numbers as its render; farther out every frame is the render. Two robots from the same seed, one
    blanking, drive into the face alike."""
    noisy = Simulator(seed=1)
    start = Pose2D(-(FRONT + 0.12), 0.003, 0.01)

    def drive(blank: bool) -> tuple[SimulatedRobot, list[tuple[float, np.ndarray, bool]]]:
        robot = SimulatedRobot(noisy, start, DiffDriveConfig(), np.random.default_rng(3), blank_undetectable=blank)
        robot.send_velocity(0.05, 0.0)
        frames: list[tuple[float, np.ndarray, bool]] = []
        while robot.t < 2.5:
            robot.sleep(0.02)
            f = robot.latest_frame()
            if f is not None and (not frames or f.stamp != frames[-1][0]):
                frames.append((f.stamp, f.image, robot.undetectable(f.stamp)))
        return robot, frames

    plain, rendered = drive(False)
    blanking, delivered = drive(True)
    assert [s for s, _, _ in rendered] == [s for s, _, _ in delivered]
    assert plain.pose == blanking.pose
    assert plain.rng.bit_generator.state == blanking.rng.bit_generator.state
    blank = [i for i, (_, _, b) in enumerate(delivered) if b]
    assert 0 < len(blank) < len(delivered)
    assert blanking.frames_blank == len(blank)
    assert not any(b for _, _, b in rendered)
    poses = dict(blanking.exposures)
    detector = MarkerDetector(noisy.layout)
    for (stamp, image, is_blank), (_, render, _) in zip(delivered, rendered, strict=True):
        corners = noisy.true_corners(blanking.dock_pose(poses[stamp]))
        whole = [role for role, quad in corners.items() if noisy.in_view(quad)]
        if is_blank:
            assert not whole  # by the truth, no marker lies whole in the image
            assert detector.detect(render).observations == {}  # and the detector finds none in the render
        else:
            assert np.array_equal(image, render)


# With k = 8 samples the farthest warp moves a pixel 7/8 of the grid's shift: 8/7 px moves it one whole pixel.
@pytest.mark.parametrize("shift", [0.4, 8 / 7 - 1e-4, 8 / 7, 8 / 7 + 1e-4, 1.999, 16 / 7, 24 / 7 - 1e-4, 5.5])
@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, -1.0)])
def test_the_blurs_edge_mask_reaches_every_pixel_a_warp_reads(shift: float, direction: tuple[float, float]) -> None:
    """Only pixels within a warp's reach of an edge are warped, the tightest such box: lone bright pixels (each an
    edge on its own) streaked by whole pixels and by a hair under and over, along both axes and diagonals, both
    ways, must give OpenCV's whole-image warps. A pixel outside the box keeps its own value."""
    from monodock.sim.diffdrive import _Streak

    blur = _robot(Pose2D(-0.9, 0.0, 0.0))._blur
    h, w = SIM.camera.height, SIM.camera.width
    rng = np.random.default_rng(7)
    radiance = np.full((h, w), 0.2, dtype=np.float32)
    radiance[rng.integers(8, h - 8, 300), rng.integers(8, w - 8, 300)] = 0.9
    start = np.tile(shift * np.asarray(direction), (len(blur.grid), 1))  # the same shift everywhere: no smoothing
    k = 8
    streak = _Streak(start, -start, length=1.5 * k)  # k samples, as the robot's blur draws for this length
    expected = _opencv_blur(radiance, start, -start, k)
    got = blur.blur(radiance, streak)
    assert np.abs(got - expected).max() <= 1e-6
    assert np.count_nonzero(expected != radiance) > 300  # it did blur
