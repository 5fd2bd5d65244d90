"""The checks a live node makes on a message before using it: each fault has a kind, so each kind is reported once."""

from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from monodock.core.camera import CameraModel
from monodock.recording import messages as m


def raw(width: int = 4, height: int = 3, encoding: str = "mono8", step: int = 4, size: int | None = None) -> object:
    data = np.arange(step * height if size is None else size, dtype=np.uint8) % 251
    return SimpleNamespace(width=width, height=height, encoding=encoding, step=step, is_bigendian=0, data=data)


def test_a_well_formed_raw_image_passes_and_decodes_to_its_pixels() -> None:
    msg = raw(step=6)  # two bytes of padding a row
    m.check_raw_image(msg)
    image = m.decode_image(msg, m.IMAGE)
    assert image.shape == (3, 4)
    np.testing.assert_array_equal(image[1], [6, 7, 8, 9])


@pytest.mark.parametrize(
    ("msg", "kind", "says"),
    [
        (raw(encoding="yuv422_yuy2"), "encoding", "'yuv422_yuy2' is not supported"),
        (raw(size=11), "size", "11 bytes of data, expected step x height = 12"),
        (raw(size=13), "size", "13 bytes"),  # more than declared: decode_image would accept it, a live node not
        (raw(step=3), "size", "step 3 is less than"),
        (raw(width=0), "size", "0x3 is empty"),
        (raw(encoding="bgr8"), "size", "step 4 is less than width x bytes per pixel = 12"),
    ],
)
def test_a_raw_image_that_is_not_what_it_says_is_refused_with_its_kind(msg: object, kind: str, says: str) -> None:
    with pytest.raises(m.DecodeError, match=says) as info:
        m.check_raw_image(msg)
    assert info.value.kind == kind


def test_decode_errors_carry_their_kind() -> None:
    with pytest.raises(m.DecodeError) as info:
        m.decode_image(raw(size=5), m.IMAGE)
    assert info.value.kind == "size"
    broken = SimpleNamespace(format="jpeg", data=np.array([1, 2, 3], dtype=np.uint8))
    with pytest.raises(m.DecodeError) as info:
        m.decode_image(broken, m.COMPRESSED_IMAGE)
    assert info.value.kind == "compressed"


def info_msg(camera: CameraModel, **changes: object) -> SimpleNamespace:
    msg = SimpleNamespace(
        width=camera.width, height=camera.height, distortion_model=camera.distortion_model, k=list(camera.K)
    )
    msg.d = list(camera.D)
    msg.__dict__.update(changes)
    return msg


def test_camera_info_round_trip_uncalibrated_and_invalid() -> None:
    camera = CameraModel.default()
    back = m.camera_from_msg(info_msg(camera))
    assert back is not None
    assert (back.size, back.K, back.D) == (camera.size, camera.K, camera.D)
    assert m.camera_from_msg(info_msg(camera, k=[0.0] * 9)) is None  # uncalibrated, by ROS convention
    for changes in ({"k": [*camera.K[:2], math.nan, *camera.K[3:]]}, {"d": [math.inf, 0.0, 0.0, 0.0, 0.0]}):
        with pytest.raises(m.DecodeError, match="NaN or infinite") as info:
            m.camera_from_msg(info_msg(camera, **changes))
        assert info.value.kind == "calibration"
    with pytest.raises(m.DecodeError, match="width: must be at least 1") as info:
        m.camera_from_msg(info_msg(camera, width=0))
    assert info.value.kind == "calibration"


def test_a_rectified_camera_is_p_without_distortion() -> None:
    # A wide lens, and image_proc's rectified image of it (P from OpenCV's optimal new camera matrix): points seen
    # through the lens and then rectified are where the rectified camera projects them.
    lens = CameraModel(640, 480, CameraModel.default().K, (-0.25, 0.07, 0.001, -0.001, 0.0), "plumb_bob")
    new_K, _ = cv2.getOptimalNewCameraMatrix(lens.matrix, lens.dist, lens.size, 0.0)
    P = np.zeros((3, 4))
    P[:, :3] = new_K
    msg = info_msg(lens, p=list(P.ravel()))
    rectified = m.camera_from_msg(msg, rectified=True)
    assert rectified is not None
    assert not any(rectified.D)
    grid = np.array([[x, y, 2.0] for x in np.linspace(-0.9, 0.9, 7) for y in np.linspace(-0.7, 0.7, 5)])
    seen = lens.project(grid)
    rectified_pixels = cv2.undistortPoints(seen.reshape(-1, 1, 2), lens.matrix, lens.dist, P=new_K).reshape(-1, 2)
    np.testing.assert_allclose(rectified.project(grid), rectified_pixels, atol=0.01)
    # Not rectified, the same message is the lens itself.
    unrectified = m.camera_from_msg(msg)
    assert unrectified is not None
    np.testing.assert_allclose(unrectified.project(grid), seen, atol=1e-9)
    # Rectified images with no valid P are refused, of the calibration kind.
    for p in ([0.0] * 12, [math.nan] * 12, [1.0] * 5):
        with pytest.raises(m.DecodeError, match="no valid projection matrix P") as info:
            m.camera_from_msg(info_msg(lens, p=p), rectified=True)
        assert info.value.kind == "calibration"
