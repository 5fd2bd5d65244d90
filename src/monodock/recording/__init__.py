"""Recordings: rosbag2 bags of a simulated drive, and a reader for any robot's rosbag2 or ROS 1 bags (DESIGN.md)."""

from __future__ import annotations

from monodock.recording.read import RECORDING_SUFFIXES, Recording, is_recording, open_recording, pair_nearest
from monodock.recording.write import (
    CAMERA_INFO_TOPIC,
    COMPRESSED_IMAGE_TOPIC,
    IMAGE_TOPIC,
    SCAN_TOPIC,
    TF_STATIC_TOPIC,
    TRUTH_TOPIC,
    RecordingSummary,
    write_recording,
)

__all__ = [
    "CAMERA_INFO_TOPIC",
    "COMPRESSED_IMAGE_TOPIC",
    "IMAGE_TOPIC",
    "RECORDING_SUFFIXES",
    "SCAN_TOPIC",
    "TF_STATIC_TOPIC",
    "TRUTH_TOPIC",
    "Recording",
    "RecordingSummary",
    "is_recording",
    "open_recording",
    "pair_nearest",
    "write_recording",
]
