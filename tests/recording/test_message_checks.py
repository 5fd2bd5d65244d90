"""The checks a live node makes on a message before using it: each fault has a kind, so each kind is reported once."""

from __future__ import annotations

import math
from types import SimpleNamespace

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
