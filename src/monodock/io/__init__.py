"""Frames in and rows out: one frame source for images, folders, videos, cameras, streams and recordings; live
estimation."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.io.frames import FrameSource, open_frames, read_image
    from monodock.io.live import run_live
    from monodock.io.nav2 import write_pose_bag

__all__ = [
    "FrameSource",
    "open_frames",
    "read_image",
    "run_live",
    "write_pose_bag",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
