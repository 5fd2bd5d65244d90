"""The edge-based corner refiner against the simulator's true corners (and an exact blurred step).

Ground truth: FrameTruth.corners (each marker's exact corner pixels through the lens) of frames rendered with
the default nuisances (defocus, noise, vignetting, exposure jitter, clutter), over- and under-exposed, and, for
the edge fit alone, the analytic profile of a Gaussian-blurred step (math.erf). Thresholds are the issue's:
|mean outward error| <= 0.03 px and RMS 2D error <= 0.15 px, where OpenCV's SUBPIX corners sit ~0.2-0.5 px
inside; per frame, the corners' common outward error (a scale error for PnP) varies by < 0.02 px.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from monodock.core.camera import CameraModel
from monodock.core.layout import ROLES
from monodock.core.pose import DockPose
from monodock.errors import InputError
from monodock.perception.detect import Detection, MarkerDetector, MarkerObservation
from monodock.perception.features import marker_features
from monodock.perception.refine import _fit_edges, refine_detection, refine_marker
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.world import Surface, rectangle

CAMERA_X = 0.17  # the default robot's camera mount x: DockPose.x = depth + CAMERA_X
RANGES = {"near": (0.35, 0.7), "mid": (0.9, 1.5), "far": (1.9, 2.5)}
FRAMES = 6


@pytest.fixture(scope="module", autouse=True)
def _one_thread() -> Iterator[None]:
    """Rendering with threaded BLAS on a shared 2-core machine is several times slower, not faster."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    with threadpool_limits(1):
        yield
    cv2.setNumThreads(threads)


def _outward(corners: NDArray[np.float64], truth: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed error along the true centre -> corner direction (negative: inside the marker), px."""
    out = truth - marker_features(truth).centre
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return np.asarray(np.sum((corners - truth) * out, axis=1))


def _clipped(image: NDArray[np.uint8], truth: NDArray[np.float64], level: int) -> float:
    """Share of the pixels at ``level`` (255 or 0) in the box of a marker's true corners."""
    lo = np.maximum(np.floor(truth.min(axis=0)).astype(int), 0)
    hi = np.ceil(truth.max(axis=0)).astype(int)
    return float(np.mean(image[lo[1] : hi[1], lo[0] : hi[0]] == level))


def _measure(
    sim: Simulator, dist: PoseDistribution | None, frames: int, clip_level: int = 255
) -> dict[str, list[NDArray[np.float64]]]:
    """Outward and 2D errors of OpenCV SUBPIX and of the refiner, on the same in-view markers.

    Also, per marker, its share of pixels at ``clip_level`` (``clip``), and per frame the mean outward
    error of all its refined corners (``common``).
    """
    detector = MarkerDetector(sim.layout)
    keys = ("sub_out", "sub_2d", "ref_out", "ref_2d", "clip", "common")
    errs: dict[str, list[NDArray[np.float64]]] = {k: [] for k in keys}
    unrefined = 0
    for _ in range(frames):
        frame = sim.frame(sim.sample_pose(dist))
        det = detector.detect(frame.image)
        ref = refine_detection(frame.image, det, sim.camera)
        unrefined += len(ref.unrefined)
        common = []
        for role in det.roles_seen:
            if not frame.truth.in_view[role] or role in ref.unrefined:
                continue
            truth = frame.truth.corners[role]
            for key, c in (("sub", det.observations[role].corners), ("ref", ref.observations[role].corners)):
                errs[f"{key}_out"].append(_outward(c, truth))
                errs[f"{key}_2d"].append(np.linalg.norm(c - truth, axis=1))
            errs["clip"].append(np.array([_clipped(frame.image, truth, clip_level)]))
            common.append(float(np.mean(errs["ref_out"][-1])))
        if common:
            errs["common"].append(np.array([np.mean(common)]))
    assert unrefined <= 1, f"{unrefined} markers kept OpenCV's corners on unoccluded frames"
    return errs


def _summary(errs: dict[str, list[NDArray[np.float64]]], key: str) -> tuple[float, float, int]:
    out, d2 = np.concatenate(errs[f"{key}_out"]), np.concatenate(errs[f"{key}_2d"])
    return float(np.mean(out)), float(np.sqrt(np.mean(d2**2))), out.size


@pytest.mark.parametrize("name", list(RANGES))
def test_unbiased_and_accurate_at_default_nuisances(name: str) -> None:
    """Near, mid and far: no inward bias, sub-0.15 px RMS, and better than OpenCV SUBPIX on the same frames."""
    sim = Simulator(seed=100 + list(RANGES).index(name))
    errs = _measure(sim, PoseDistribution(depth=RANGES[name]), FRAMES)
    ref_mean, ref_rms, n = _summary(errs, "ref")
    sub_mean, sub_rms, _ = _summary(errs, "sub")
    assert n >= 40
    assert abs(ref_mean) <= 0.03, (ref_mean, sub_mean)
    assert ref_rms <= 0.15, (ref_rms, sub_rms)
    assert sub_mean < -0.1  # the bias being removed is there in these frames
    assert abs(ref_mean) < 0.3 * abs(sub_mean)
    assert ref_rms < 0.6 * sub_rms


@pytest.mark.parametrize(
    ("exposure", "noise"),
    [(1.4, True), (1.6, True), (1.8, True), (1.6, False)],
    ids=["1.4", "1.6", "1.8", "1.6-noise-free"],
)
def test_unbiased_when_the_white_clips(exposure: float, noise: bool) -> None:
    """Over-exposed (white paper 1.2-1.5x full scale): the face and the code's white cells read 255.

    With noise, the simulator's clipped pixels read 255 minus the read-out noise; noise-free, exactly 255
    (a camera that clips after the noise). Without the clipping correction these corners sat 0.2-0.48 px
    inside, all together.
    """
    nuisances = Nuisances(exposure=exposure, exposure_jitter=0.0)
    if not noise:
        nuisances = nuisances.updated(read_noise=0.0, shot_noise=0.0)
    errs = _measure(Simulator(nuisances=nuisances, seed=21), None, FRAMES)
    ref_mean, ref_rms, n = _summary(errs, "ref")
    assert n >= 40
    assert np.median(np.concatenate(errs["clip"])) > 0.05  # the code's white cells read 255 (noise: half of them)
    assert abs(ref_mean) <= 0.03, ref_mean
    assert ref_rms <= 0.15, ref_rms


def test_unbiased_when_the_black_clips() -> None:
    """Under-exposed (exposure 0.2: black ink at ~3 of 255): the border's noise is clipped at 0, no bias."""
    errs = _measure(Simulator(nuisances=Nuisances(exposure=0.2, exposure_jitter=0.0), seed=23), None, FRAMES, 0)
    ref_mean, ref_rms, n = _summary(errs, "ref")
    assert n >= 40
    assert np.mean(np.concatenate(errs["clip"])) > 0.01  # some of the black reads 0
    assert abs(ref_mean) <= 0.03, ref_mean
    assert ref_rms <= 0.15, ref_rms


def test_no_common_mode_from_the_exposure_jitter() -> None:
    """Default nuisances draw each frame's exposure (log-normal, sigma 0.15); the bright ones clip the white.

    Per frame, the mean outward error of all refined corners acts like a scale error on the whole frame;
    its spread over frames must stay < 0.02 px (0.023-0.055 px over 30 such frames before the clipping
    correction, 0.009-0.011 px after; ~0.01 px when the exposure does not vary). 60 frames: with the compiled
    sensor model's draws, seed 6's first 30 frames held only 4 markers in clipped white, too few to test it.
    """
    errs = _measure(Simulator(seed=6), None, 60)
    clipped = np.concatenate(errs["clip"]) > 0.05
    assert np.count_nonzero(clipped) >= 6  # several frames' markers sit in clipped white
    common = np.concatenate(errs["common"])
    assert common.size >= 56
    assert float(np.std(common)) < 0.02, np.std(common)
    assert abs(float(np.mean(common))) <= 0.03


def test_straight_sides_through_a_strong_barrel_lens() -> None:
    """k1 = -0.2: sides are curves in the raw image; near markers spread over the image, still unbiased."""
    camera = CameraModel.from_intrinsics(640, 480, 520.0, 520.0, 318.0, 243.0, (-0.2, 0.03, 0.0, 0.0, 0.0))
    sim = Simulator(camera=camera, seed=7)
    errs = _measure(sim, PoseDistribution(depth=(0.3, 0.6), lateral=(-0.3, 0.3)), FRAMES)
    ref_mean, ref_rms, n = _summary(errs, "ref")
    assert n >= 40
    assert abs(ref_mean) <= 0.03
    assert ref_rms <= 0.15
    assert np.max(np.concatenate(errs["ref_2d"])) < 0.4


@pytest.mark.parametrize(
    ("contrast", "levels"),
    [("high", (20.0, 230.0)), ("low", (110.0, 150.0)), ("dark-heavy", (5.0, 90.0))],
)
@pytest.mark.parametrize("sigma", [0.6, 1.0, 2.0])
def test_edge_fit_is_unbiased(contrast: str, levels: tuple[float, float], sigma: float) -> None:
    """The blurred-step fit on exact Gaussian-blurred steps: off-centre edges, any dark/bright levels."""
    dark, bright = levels
    rng = np.random.default_rng(int(sigma * 10) + len(contrast))
    grid = np.linspace(-1.0, 1.0, 14)
    reach = 4.0
    t = (reach * grid * (0.55 + 0.45 * grid**2)).astype(np.float32)
    true_e = rng.uniform(-0.8, 0.8, 2000).astype(np.float32)
    erf = np.vectorize(math.erf)
    clean = bright + (dark - bright) * 0.5 * (1.0 + erf((t[:, None] - true_e[None, :]) / (sigma * math.sqrt(2.0))))
    noise = rng.normal(0.0, 0.02 * (bright - dark), clean.shape)
    # Per profile, the fit stops once the typical step is under 0.02 px: individual edges are that close.
    for profile, tol_mean, tol_each in ((clean, 0.003, 0.05), (clean + noise, 0.01, None)):
        data = profile.astype(np.float32)[:, :, None]  # (samples, profiles, 1 side)
        w = np.ones_like(data)
        with np.errstate(over="ignore"):
            e, s, c, _ = _fit_edges(t[:, None, None], data, w, np.array([[reach]], np.float32))
        err = e[:, 0] - true_e
        assert abs(float(np.mean(err))) < tol_mean, (contrast, sigma, float(np.mean(err)))
        if tol_each is not None:
            assert float(np.max(np.abs(err))) < tol_each
            assert np.allclose(s[:, 0], sigma, rtol=0.1)
            assert np.allclose(c[:, 0], bright - dark, rtol=0.1)


def _partial_board(sim: Simulator, pose: DockPose, role: str, offset: float, width: float) -> Surface:
    """An upright grey board halfway to the marker, hiding a vertical strip of ``width`` (marker sizes)."""
    camera_centre = sim.world_T_optical(pose)[:3, 3]
    m = sim.layout.marker(role)
    target = np.array([0.0, m.y + offset * sim.layout.marker_size, m.z])
    centre = camera_centre + 0.5 * (target - camera_centre)
    to_cam = camera_centre - centre
    to_cam[2] = 0.0
    normal = to_cam / np.linalg.norm(to_cam)
    right = np.cross(np.array([0.0, 0.0, 1.0]), normal)
    w, h = 0.5 * width * sim.layout.marker_size, 1.5 * sim.layout.marker_size
    top_left = centre - right * w / 2 + np.array([0.0, 0.0, h / 2])
    return rectangle("occluder", top_left, right, (0, 0, -1), w, h, 0.3)


@pytest.mark.parametrize(("offset", "width"), [(0.0, 0.3), (0.0, 0.6), (-0.2, 0.25)])
def test_robust_to_a_partial_occluder(offset: float, width: float) -> None:
    """A board hides part of two sides: their lines still come from the visible edge only."""
    sim = Simulator(seed=11)
    pose = DockPose(CAMERA_X + 0.8, 0.05, math.radians(10.0))
    rng_seed = 1
    clean = sim.render(pose, rng=np.random.default_rng(rng_seed))
    world = sim.world.with_surfaces(_partial_board(sim, pose, "center", offset, width))
    occluded = sim.render(pose, world, rng=np.random.default_rng(rng_seed))
    assert np.count_nonzero(np.abs(occluded.astype(int) - clean.astype(int)) > 50) > 100  # it does hide something
    det = MarkerDetector(sim.layout).detect(clean)  # ArUco itself gives up on an occluded marker
    truth = sim.true_corners(pose)["center"]
    ref = refine_detection(occluded, det, sim.camera)
    assert "center" not in ref.unrefined
    err = np.linalg.norm(ref.observations["center"].corners - truth, axis=1)
    sub = np.linalg.norm(det.observations["center"].corners - truth, axis=1)
    assert np.max(err) < 0.1, err
    assert np.mean(err) < 0.5 * np.mean(sub)


def test_marker_cut_by_the_image_border_keeps_opencv_corners() -> None:
    """Profiles that would leave the image make a side unusable: no refinement, the role is listed."""
    sim = Simulator(nuisances=Nuisances.clean(), seed=2)
    pose = DockPose(CAMERA_X + 0.6, 0.08, 0.0)
    truth = sim.true_corners(pose)
    left = truth["left"]
    assert np.any(left[:, 0] < 0)  # really cut by the left border
    assert np.any(left[:, 0] > 0)
    image = sim.render(pose)
    assert refine_marker(image, left, sim.camera) is None
    det = MarkerDetector(sim.layout).detect(image)
    centre = det.observations["center"]
    cut = Detection({"left": MarkerObservation("left", 1, left.copy()), "center": centre}, (), det.image_size)
    ref = refine_detection(image, cut, sim.camera)
    assert ref.unrefined == ("left",)
    np.testing.assert_array_equal(ref.observations["left"].corners, left)
    assert np.linalg.norm(ref.observations["center"].corners - truth["center"], axis=1).max() < 0.1


def test_refine_detection_keeps_everything_else() -> None:
    """Ids, ignored ids and image size pass through; only the corners change; nothing seen, nothing done."""
    sim = Simulator(nuisances=Nuisances.clean(), seed=4)
    pose = DockPose(CAMERA_X + 1.0, 0.0, 0.0)
    image = sim.render(pose)
    det = MarkerDetector(sim.layout).detect(image)
    ref = refine_detection(image, det, sim.camera)
    assert ref.roles_seen == det.roles_seen == ROLES
    assert ref.unrefined == ()
    assert ref.ignored_ids == det.ignored_ids
    assert ref.image_size == det.image_size
    for role in ROLES:
        assert ref.observations[role].marker_id == det.observations[role].marker_id
    empty = Detection({}, (), det.image_size)
    assert refine_detection(image, empty, sim.camera) == empty


def test_a_marker_with_non_finite_corners_is_left_alone() -> None:
    """A NaN corner (a broken upstream detector) leaves that marker unrefined; the others still are."""
    sim = Simulator(nuisances=Nuisances.clean(), seed=4)
    pose = DockPose(CAMERA_X + 1.0, 0.05, math.radians(8.0))
    image = sim.render(pose)
    truth = sim.true_corners(pose)
    det = MarkerDetector(sim.layout).detect(image)
    broken = det.observations["center"].corners.copy()
    broken[2, 0] = np.nan
    observations = {**det.observations, "center": MarkerObservation("center", 2, broken)}
    ref = refine_detection(image, Detection(observations, (), det.image_size), sim.camera)
    assert ref.unrefined == ("center",)
    np.testing.assert_array_equal(ref.observations["center"].corners, broken)
    for role in ("left", "right"):
        refined = np.linalg.norm(ref.observations[role].corners - truth[role], axis=1)
        opencv = np.linalg.norm(det.observations[role].corners - truth[role], axis=1)
        assert refined.max() < 0.15
        assert refined.mean() < opencv.mean()


def test_bad_input_is_one_clear_error() -> None:
    camera = CameraModel.default()
    gray = np.zeros((camera.height, camera.width), np.uint8)
    corners = np.array([[100.0, 100.0], [150.0, 100.0], [150.0, 150.0], [100.0, 150.0]])
    with pytest.raises(InputError, match="8-bit single-channel"):
        refine_marker(np.zeros((camera.height, camera.width, 3), np.uint8), corners, camera)
    with pytest.raises(InputError, match="camera"):
        refine_marker(np.zeros((10, 10), np.uint8), corners, camera)
    with pytest.raises(InputError, match="corners"):
        refine_marker(gray, corners[:3], camera)
    with pytest.raises(InputError, match="corners"):
        refine_marker(gray, np.full((4, 2), np.nan), camera)
    assert refine_marker(gray, corners, camera) is None  # a blank image has no edge to find


@pytest.mark.parametrize("lens", ["default", "rational"])
def test_the_compiled_undistortion_inverts_the_lens(lens: str) -> None:
    """The anchors' undistortion (``_undistort``, OpenCV's iteration compiled): known normalised points through the
    lens to pixels (``core.lens.distort``) come back to 1e-9, over the whole image of the default camera and of a
    strong rational-polynomial lens; and it is what ``cv2.undistortPoints`` with the same criteria returns."""
    from monodock.core.lens import distort, lens_of
    from monodock.perception.refine import _undistort

    if lens == "default":
        camera = CameraModel.default()
    else:
        k = (400.0, 0.0, 320.0, 0.0, 400.0, 240.0, 0.0, 0.0, 1.0)
        camera = CameraModel(640, 480, k, (-0.3, 0.1, 1e-3, -5e-4, -0.02, 0.05, 0.01, 0.002), "rational_polynomial")
    rng = np.random.default_rng(3)
    xy = rng.uniform([-0.7, -0.5], [0.7, 0.5], (400, 2))
    u, v = distort(lens_of(camera), xy[:, 0], xy[:, 1])
    pixels = np.stack([u, v], axis=1)
    inside = (u > 0) & (u < camera.width) & (v > 0) & (v < camera.height)
    got = _undistort(lens_of(camera), pixels[inside])
    np.testing.assert_allclose(got, xy[inside], atol=1e-9)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
    opencv = cv2.undistortPoints(pixels[inside][:, None], camera.matrix, camera.dist, criteria=criteria).reshape(-1, 2)
    np.testing.assert_allclose(got, opencv, rtol=0.0, atol=1e-15)


def test_the_compiled_sampling_is_bilinear_and_opencvs() -> None:
    """The profiles' sampling (``_remap_linear``, compiled with the rest of a frame without clipped markers): on a
    ramp image, every sample is the bilinear blend of its four pixels, rounded; and on random images and places
    (beyond the border too: BORDER_REPLICATE) it is ``cv2.remap``'s answer to one level, all but a rare tie exactly."""
    from monodock.perception.refine import _remap_linear

    yy, xx = np.mgrid[0:480, 0:640]
    ramp = (20.0 + 0.3 * xx + 0.1 * yy).astype(np.uint8)  # below 256; stored per pixel, so blend those values
    rng = np.random.default_rng(9)
    mapx = rng.uniform(0.0, 639.0, (14, 2000)).astype(np.float32)
    mapy = rng.uniform(0.0, 479.0, (14, 2000)).astype(np.float32)
    x0, y0 = np.floor(mapx).astype(int), np.floor(mapy).astype(int)
    ax, ay = mapx - x0, mapy - y0
    x1, y1 = np.minimum(x0 + 1, 639), np.minimum(y0 + 1, 479)
    r = ramp.astype(np.float64)
    blend = (r[y0, x0] * (1 - ax) + r[y0, x1] * ax) * (1 - ay) + (r[y1, x0] * (1 - ax) + r[y1, x1] * ax) * ay
    got = _remap_linear(ramp, mapx, mapy)
    assert np.all(np.abs(got - blend) <= 0.5 + 1e-3)
    image = rng.integers(0, 256, (480, 640), dtype=np.uint8)
    mapx = rng.uniform(-3.0, 643.0, (14, 3000)).astype(np.float32)
    mapy = rng.uniform(-3.0, 483.0, (14, 3000)).astype(np.float32)
    opencv = cv2.remap(image, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    diff = np.abs(_remap_linear(image, mapx, mapy).astype(int) - opencv)
    assert diff.max() <= 1
    assert np.mean(diff > 0) < 1e-3


def test_the_compiled_row_sum_is_numpys_bit_for_bit() -> None:
    """``_bloom``'s mean over a marker's border cells (compiled since issue 24) adds them as numpy adds a row
    (pairwise, eight running sums from eight values on): the same clipping correction to the last bit, for
    every dictionary's cell count (4 (bits) per marker: 12 to 32) and beyond."""
    from monodock.perception.refine import _pairwise_sum

    rng = np.random.default_rng(4)
    for n in range(1, 41):
        rows = rng.normal(size=(200, n)) * rng.uniform(0.01, 100.0, size=(200, 1))
        rows[rng.random(rows.shape) < 0.3] = 0.0  # the cells left out add zeros
        numpy_sums = np.add.reduce(rows, axis=1)
        assert all(_pairwise_sum(row) == total for row, total in zip(rows, numpy_sums, strict=True)), n
