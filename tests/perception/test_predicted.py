"""Markers found where the dock track predicts them (monodock.perception.predicted), against the simulator's truth.

Ground truth: FrameTruth.corners (each marker's exact corner pixels through the lens) of frames rendered with the
default nuisances and a 6 px motion blur (the heaviest level of the robustness axis), and the truth pose. Priors
are the truth moved by a few centimetres and degrees, as a track carried by odometry is. Checked: a marker the
detector misses is recovered to within 1 px of its true corners; a prior that points at a marker that is not there
(another id, a dock whose markers carry other ids, outside the image) gives nothing; the estimator given a prior
turns frames without a pose into frames with one near the truth, and leaves the detector's markers as they are;
``make_perceive`` passes the track's prediction; and (slow) a whole blurred approach keeps a pose on every frame
once the dock has been seen, without a single false accept.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.dock.tracking import make_perceive
from monodock.estimation.factory import make_estimator
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.perception.predicted import PredictedMarkers, Prior, predict_corners
from monodock.sim import Nuisances, Simulator
from monodock.sim.simulator import SimFrame

BLUR = Nuisances(motion_blur_px=6.0)
CAMERA_X = 0.17  # the default robot's camera mount x
SIGMA = np.diag([0.02**2, 0.02**2, math.radians(1.5) ** 2])


def _off(pose: DockPose, rng: np.random.Generator) -> DockPose:
    """The pose moved as a track's prediction might be: ~2 cm and ~1.5 deg."""
    return DockPose(
        pose.x + rng.normal(0, 0.02), pose.y + rng.normal(0, 0.02), pose.yaw + rng.normal(0, math.radians(1.5))
    )


def _far_blurred_frames(n: int, seed: int = 5) -> list[tuple[DockPose, SimFrame]]:
    sim = Simulator(nuisances=BLUR, seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        pose = DockPose(CAMERA_X + rng.uniform(1.9, 2.5), rng.uniform(-0.2, 0.2), math.radians(rng.uniform(-20, 20)))
        out.append((pose, sim.frame(pose, rng=np.random.default_rng([seed, k]))))
    return out


def test_predicted_corners_are_the_true_ones() -> None:
    sim = Simulator(nuisances=Nuisances.clean())
    pose = DockPose(1.4, 0.1, math.radians(12))
    want = sim.true_corners(pose)
    got = predict_corners(sim.camera, sim.layout, sim.robot, pose)
    for role in sim.layout.roles:
        assert np.max(np.abs(got[role] - want[role])) < 1e-6


def test_a_blurred_marker_the_detector_misses_is_recovered_within_a_pixel() -> None:
    sim = Simulator(nuisances=BLUR)
    detector = MarkerDetector(sim.layout)
    filler = PredictedMarkers(sim.camera, sim.layout, sim.robot)
    rng = np.random.default_rng(11)
    missed = recovered = 0
    worst = 0.0
    for pose, frame in _far_blurred_frames(12):
        gray = as_gray(frame.image)
        detection = detector.detect(gray)
        filled = filler.fill(gray, detection, Prior(_off(pose, rng), SIGMA))
        for role, obs in detection.observations.items():  # the detector's own are untouched
            assert filled.observations[role] is obs
        for role in sim.layout.roles:
            if role in detection.observations or not frame.truth.in_view[role]:
                continue
            missed += 1
            if role in filled.observations:
                recovered += 1
                assert role in filled.recovered
                err = np.linalg.norm(filled.observations[role].corners - frame.truth.corners[role], axis=1)
                worst = max(worst, float(err.max()))
    assert missed >= 5, "the frames should hold markers the detector misses under 6 px of blur"
    assert recovered >= 0.9 * missed
    assert worst <= 1.0


def test_a_marker_of_another_id_where_the_prior_points_is_rejected() -> None:
    sim = Simulator(nuisances=BLUR)
    filler = PredictedMarkers(sim.camera, sim.layout, sim.robot)
    _pose, frame = _far_blurred_frames(1, seed=8)[0]
    gray = as_gray(frame.image)
    truth = frame.truth.corners
    assert filler.find(gray, "center", truth["center"], 6.0) is not None  # the right id reads
    # The left marker predicted where the centre one is (the prior off by one spacing): its code is not left's.
    assert filler.find(gray, "left", truth["center"], 6.0) is None
    assert filler.find(gray, "right", truth["center"], 6.0) is None
    # Predicted on the bare face or wall beside the markers: nothing there.
    assert filler.find(gray, "center", truth["center"] + np.array([0.0, 60.0]), 6.0) is None
    # Predicted partly outside the image: not searched.
    assert filler.find(gray, "center", truth["center"] - truth["center"].min(axis=0) - 1.0, 6.0) is None


def test_a_dock_whose_markers_carry_other_ids_gives_nothing() -> None:
    sim = Simulator(nuisances=BLUR)
    layout = sim.layout
    other = DockLayout(
        **{
            **{f.name: getattr(layout, f.name) for f in dataclasses.fields(layout)},
            "markers": tuple(dataclasses.replace(m, id=m.id + 10) for m in layout.markers),
        }
    )
    detector = MarkerDetector(other)
    filler = PredictedMarkers(sim.camera, other, sim.robot)
    for pose, frame in _far_blurred_frames(4, seed=9):
        gray = as_gray(frame.image)
        detection = detector.detect(gray)
        assert not detection.observations
        assert not filler.fill(gray, detection, Prior(pose, SIGMA)).observations


def test_the_estimator_with_a_prior_turns_lost_frames_into_poses() -> None:
    sim = Simulator(nuisances=BLUR)
    est = make_estimator(method="fused", camera=sim.camera, layout=sim.layout, robot=sim.robot)
    rng = np.random.default_rng(3)
    lost = found = 0
    for pose, frame in _far_blurred_frames(16, seed=12):
        alone = est.estimate("", 0.0, frame.image).estimates["fused"]
        if alone.pose is not None:
            continue
        lost += 1
        p = est.estimate("", 0.0, frame.image, prior=Prior(_off(pose, rng), SIGMA)).estimates["fused"].pose
        if p is not None:
            found += 1
            assert abs(p.x - pose.x) < 0.03
            assert abs(p.y - pose.y) < 0.02
            assert abs(math.degrees(p.yaw - pose.yaw)) < 2.0
    assert lost >= 2, "some far blurred frames should have no pose from the detector alone"
    assert found == lost


class _Track:
    """A track that predicts the dock at the truth moved by a few cm (what the mission's DockTrack gives)."""

    def __init__(self, pose: DockPose) -> None:
        self.pose = pose
        self.asked: list[float] = []

    def dock_prior(self, stamp: float) -> tuple[DockPose, np.ndarray]:
        self.asked.append(stamp)
        return self.pose, SIGMA


def test_make_perceive_passes_the_tracks_prediction() -> None:
    sim = Simulator(nuisances=BLUR)
    est = make_estimator(method="fused", camera=sim.camera, layout=sim.layout, robot=sim.robot)
    rng = np.random.default_rng(4)
    lost = [
        (p, f)
        for p, f in _far_blurred_frames(16, seed=12)
        if est.estimate("", 0.0, f.image).estimates["fused"].pose is None
    ]
    assert lost, "no frame without a pose from the detector alone"
    pose, frame = lost[0]
    track = _Track(_off(pose, rng))
    without = make_perceive(est, "fused")(2.5, frame.image)
    with_track = make_perceive(est, "fused", track=lambda: track)(2.5, frame.image)  # type: ignore[arg-type,return-value]
    assert without.pose is None
    assert track.asked == [2.5]
    assert with_track.pose is not None
    assert abs(with_track.pose.x - pose.x) < 0.03
    # the observation says how many of its markers the fit found (dock-sim counts those frames)
    assert (without.predicted, 1 <= with_track.predicted <= with_track.markers) == (0, True)


def test_the_docks_own_pose_is_the_prior_with_a_taught_charging_pose() -> None:
    from monodock.dock.interface import Odometry
    from monodock.dock.pose_filter import FilterConfig, MeasurementNoise
    from monodock.dock.tracking import DockTrack

    target = Pose2D(0.05, 0.02, math.radians(3))
    track = DockTrack(FilterConfig(), MeasurementNoise(), target)
    track.move(Odometry(0.0, Pose2D(0.0, 0.0, 0.0), 0.0, 0.0))
    dock = DockPose(1.5, 0.1, math.radians(10))
    seen = Pose2D(dock.x, dock.y, dock.yaw).compose(target)
    track.seed([(Pose2D(0.0, 0.0, 0.0), DockPose(seen.x, seen.y, seen.theta), SIGMA)])
    prior = track.dock_prior(0.0)
    assert prior is not None
    assert abs(prior[0].x - dock.x) < 1e-6
    assert abs(prior[0].y - dock.y) < 1e-6
    assert abs(prior[0].yaw - dock.yaw) < 1e-6


@pytest.mark.slow
def test_a_blurred_approach_keeps_a_pose_on_every_frame_once_seen() -> None:
    """An approach from 2.5 m to 0.4 m at 15 Hz, 6 px blur on every frame, the prior the previous estimate carried
    by the true motion (odometry without error over one frame's 1.7 cm is within the track's sigma)."""
    sim = Simulator(nuisances=BLUR, seed=21)
    est = make_estimator(method="fused", camera=sim.camera, layout=sim.layout, robot=sim.robot)
    n = 120
    last: DockPose | None = None
    valid_alone = valid = seen = false = 0
    prev = None
    for k in range(n):
        s = k / (n - 1)
        truth = DockPose(CAMERA_X + 2.5 - 2.1 * s, 0.2 * (1 - s), math.radians(15) * (1 - s))
        here = Pose2D(truth.x, truth.y, truth.yaw).inverse()
        if last is not None and prev is not None:
            c = here.inverse().compose(prev).compose(Pose2D(last.x, last.y, last.yaw))
            last = DockPose(c.x, c.y, c.theta)
        prev = here
        frame = sim.frame(truth, rng=np.random.default_rng([21, k]))
        prior = None if last is None else Prior(last, SIGMA)
        alone = est.estimate("", 0.0, frame.image)
        fe = est.estimate("", 0.0, frame.image, prior=prior)
        assert fe.detection is not None
        for role in fe.detection.recovered:
            err = np.linalg.norm(fe.detection.observations[role].corners - frame.truth.corners[role], axis=1)
            false += int(err.max() > 2.0)
        p = fe.estimates["fused"].pose
        valid_alone += alone.estimates["fused"].pose is not None
        if last is not None or p is not None:
            seen += 1
            valid += p is not None
        if p is not None:
            last = p
    assert false == 0
    assert valid >= 0.99 * seen
    assert valid_alone < valid  # the detector alone does lose frames here
