"""Marker detection (perception.detect) on simulated frames, against the true corners."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from monodock.core.layout import ROLES, DockLayout
from monodock.core.pose import DockPose
from monodock.errors import InputError
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.perception.features import FEATURE_NAMES, feature_vector
from monodock.sim import SimFrame, Simulator, World
from monodock.sim.world import marker_patch
from shared import CAMERA_X


def test_detects_three_roles_at_true_corners(sim: Simulator, frames: dict[str, SimFrame]) -> None:
    """All three dock markers are found with their layout ids, corners within 0.5 px of the true ones."""
    frame = frames["all"]
    assert all(frame.truth.in_view.values())

    detection = MarkerDetector(sim.layout).detect(frame.image)

    assert detection.roles_seen == ROLES
    assert detection.ignored_ids == ()
    assert detection.image_size == (sim.camera.width, sim.camera.height)
    for role in ROLES:
        obs = detection.observations[role]
        assert obs.marker_id == sim.layout.marker(role).id
        np.testing.assert_allclose(obs.corners, frame.truth.corners[role], atol=0.5)


def test_foreign_marker_is_ignored(sim: Simulator) -> None:
    """A marker of an id the layout does not carry, painted on the charger, is listed in ignored_ids only."""
    face_index = sim.world.surface_index("charger_face")
    face = sim.world.surfaces[face_index]
    # Face coordinates: s = half width - y, t = height - z. Put id 7 below marker 2, at z = 0.12.
    extra = marker_patch(sim.layout, 7, face.s_len / 2.0, face.t_len - 0.12)
    surfaces = list(sim.world.surfaces)
    surfaces[face_index] = face.with_patches(extra)
    world = World(tuple(surfaces), sim.world.no_hit_albedo)
    image = sim.render(DockPose(CAMERA_X + 0.8, 0.0, 0.0), world)

    detection = MarkerDetector(sim.layout).detect(image)

    assert detection.ignored_ids == (7,)
    assert detection.roles_seen == ROLES
    assert {o.marker_id for o in detection.observations.values()} == {1, 2, 3}


def test_left_marker_out_of_view(sim: Simulator, frames: dict[str, SimFrame]) -> None:
    """Left marker outside the image: not in roles_seen; m1 features NaN and m1_seen 0; m2, m3 present."""
    frame = frames["left_out"]
    assert frame.truth.in_view == {"left": False, "center": True, "right": True}

    detection = MarkerDetector(sim.layout).detect(frame.image)
    features = dict(zip(FEATURE_NAMES, feature_vector(detection, sim.camera), strict=True))

    assert detection.roles_seen == ("center", "right")
    assert features["m1_seen"] == 0.0
    m1 = [v for k, v in features.items() if k.startswith("m1_") and k != "m1_seen"]
    assert len(m1) == 14
    assert np.all(np.isnan(m1))
    assert features["m2_seen"] == 1.0
    assert features["m3_seen"] == 1.0
    tr = frame.truth.corners["right"]
    np.testing.assert_allclose([features["m3_tl_u"], features["m3_tl_v"]], tr[0], atol=0.5)
    np.testing.assert_allclose([features["m3_br_u"], features["m3_br_v"]], tr[2], atol=0.5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_as_gray_rejects_float_images(dtype: type) -> None:
    """Float images are not camera images: InputError."""
    with pytest.raises(InputError):
        as_gray(np.full((48, 64), 0.5, dtype=dtype))


def test_as_gray_converts_bgr_and_16bit() -> None:
    """BGR8 becomes its luminance (0.299 R + 0.587 G + 0.114 B); mono16's full scale maps onto 8 bits."""
    bgr = np.zeros((3, 5, 3), np.uint8)
    bgr[0, :, 0], bgr[1, :, 1], bgr[2, :, 2] = 200, 200, 200  # rows: blue, green, red
    np.testing.assert_allclose(as_gray(bgr)[:, 0], [0.114 * 200, 0.587 * 200, 0.299 * 200], atol=1.0)
    levels = np.array([[0, 257, 0x8000, 0xAB12, 0xFFFF]], np.uint16)
    gray = as_gray(levels)
    assert gray.dtype == np.uint8
    np.testing.assert_allclose(gray, levels * 255.0 / 65535.0, atol=1.0)
    assert (gray[0, 0], gray[0, -1]) == (0, 255)


def test_detector_leaves_callers_parameters_alone() -> None:
    """Parameters passed in keep their own refinement; the detector uses a copy with the caller's thresholds."""
    params = cv2.aruco.DetectorParameters()
    params.adaptiveThreshWinSizeMax = 31
    detector = MarkerDetector(DockLayout.default(), refinement="subpix", parameters=params)
    assert params.cornerRefinementMethod == cv2.aruco.CORNER_REFINE_NONE
    assert detector._detector.getDetectorParameters().adaptiveThreshWinSizeMax == 31
