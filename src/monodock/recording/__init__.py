"""Recordings: reading any robot's rosbag2 (MCAP, sqlite3) or ROS 1 bag, salvaging cut-short ones, writing rosbag2.

``read`` finds the topics by message type and gives images, scans, CameraInfo, /tf_static mounts and ground
truth; ``salvage`` reads what is there of a bag cut short; ``write`` writes a bag as ``ros2 bag record`` would;
``messages`` converts between monodock's values and ROS messages (no rclpy: rosbags' own message types).
"""

from __future__ import annotations

from monodock.recording.read import RECORDING_SUFFIXES, Recording, is_recording, open_recording, pair_nearest
from monodock.recording.write import (
    CAMERA_INFO_TOPIC,
    COMPRESSED_IMAGE_TOPIC,
    IMAGE_TOPIC,
    SCAN_TOPIC,
    TF_STATIC_TOPIC,
    TRUTH_TOPIC,
    BagWriter,
)

__all__ = [
    "CAMERA_INFO_TOPIC",
    "COMPRESSED_IMAGE_TOPIC",
    "IMAGE_TOPIC",
    "RECORDING_SUFFIXES",
    "SCAN_TOPIC",
    "TF_STATIC_TOPIC",
    "TRUTH_TOPIC",
    "BagWriter",
    "Recording",
    "is_recording",
    "open_recording",
    "pair_nearest",
]
