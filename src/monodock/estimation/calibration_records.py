"""The calibration records a labelled dataset's and a model bundle's metadata carry: camera, dock layout, robot.

Training writes the dataset's records into the bundle (``learning.pipeline.bundle_metadata``), so both read them
the same way: each record in its own file's format, checked by that file's reader.
"""

from __future__ import annotations

from typing import Any, Literal

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import from_mapping

__all__ = ["CalibrationRecords", "RecordKey"]

RecordKey = Literal["camera", "layout", "robot"]


class CalibrationRecords:
    """``camera()``, ``layout()`` and ``robot()`` read from the metadata (a mix-in of ``Dataset`` and ``Bundle``).

    A class using it says where a record is (``_meta``, which refuses a missing one naming its file) and how
    messages name it (``_record_name``).
    """

    def _meta(self, key: RecordKey) -> Any:
        raise NotImplementedError

    def _record_name(self, key: RecordKey) -> str:
        raise NotImplementedError

    def camera(self) -> CameraModel:
        """The camera (its camera_info, validated like a camera file): the one the features were measured with,
        or the models trained with."""
        return CameraModel.from_ros_dict(self._meta("camera"), self._record_name("camera"))

    def layout(self) -> DockLayout:
        """The dock layout the features were measured on, or the models trained for."""
        return from_mapping(DockLayout, self._meta("layout"), self._record_name("layout"))

    def robot(self) -> RobotConfig:
        """The robot's mounts the labels were made with, or the training drive recorded with."""
        return from_mapping(RobotConfig, self._meta("robot"), self._record_name("robot"))
