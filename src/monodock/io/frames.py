"""Reading the frames a user points monodock at: image files, folders of images, videos and recordings."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.errors import InputError

__all__ = [
    "IMAGE_SUFFIXES",
    "RECORDING_SUFFIXES",
    "VIDEO_SUFFIXES",
    "Frame",
    "is_recording",
    "iter_frames",
    "read_image",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v")
RECORDING_SUFFIXES = (".mcap", ".db3", ".bag")

_log = logging.getLogger("monodock")


@dataclass(frozen=True)
class Frame:
    """One image to process: its name (file name or frame index), timestamp in seconds, and pixels."""

    name: str
    stamp: float
    image: NDArray[np.uint8] | None
    error: str = ""


def read_image(path: str | Path) -> NDArray[np.uint8]:
    """An image file's pixels (mono or BGR), or InputError naming the file."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"image not found: {p}")
    data = np.fromfile(p, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError(f"cannot read image {p}: not an image or corrupt")
    return np.asarray(img)


def is_recording(path: str | Path) -> bool:
    """Whether a path looks like a recording: a rosbag2 folder (with metadata.yaml), an .mcap, .db3 or .bag file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in RECORDING_SUFFIXES


def _expand(inputs: Sequence[str | Path]) -> list[Path]:
    paths: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.exists() and is_recording(p):
            paths.append(p)
        elif p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"no images in folder {p}")
            paths += found
        elif p.exists():
            paths.append(p)
        else:
            raise InputError(f"input not found: {p}")
    return paths


def _recording_frames(
    path: Path, *, skip_bad: bool, image_topic: str | None, on_warning: Callable[[str], None]
) -> Iterator[Frame]:
    from monodock.recording import open_recording

    with open_recording(path, image_topic=image_topic) as rec:
        said = 0

        def tell() -> None:
            nonlocal said
            for text in rec.warnings[said:]:
                on_warning(text)
            said = len(rec.warnings)

        tell()  # what opening found (a bag cut short) is said before the frames, not after
        for frame in rec.images():
            if frame.image is None and not skip_bad:
                raise InputError(f"{frame.error} (pass --skip-bad to go on without it)")
            yield frame
        tell()


def iter_frames(
    inputs: Sequence[str | Path],
    *,
    skip_bad: bool = False,
    image_topic: str | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> Iterator[Frame]:
    """Frames of image files, folders (sorted by name), videos and recordings, in order.

    A recording (a rosbag2 folder with metadata.yaml, an .mcap, .db3 or ROS 1 .bag file) gives its images in
    stamp order, named by index, with their header stamps; ``image_topic`` picks one when it has several.
    An unreadable image raises InputError, or with ``skip_bad`` yields a Frame without pixels and the reason.
    What the reader has to say about a recording (e.g. that it was cut short) goes to ``on_warning``, by
    default the "monodock" logger.
    """
    warn = on_warning or _log.warning
    for p in _expand(inputs):
        if is_recording(p):
            yield from _recording_frames(p, skip_bad=skip_bad, image_topic=image_topic, on_warning=warn)
            continue
        if p.suffix.lower() in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(p))
            if not cap.isOpened():
                raise InputError(f"cannot open video {p}")
            index = 0
            try:
                while True:
                    ok, img = cap.read()
                    if not ok:
                        break
                    yield Frame(str(index), float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0, np.asarray(img))
                    index += 1
            finally:
                cap.release()
            if index == 0:
                raise InputError(f"video {p} has no readable frames")
            continue
        try:
            yield Frame(p.name, float("nan"), read_image(p))
        except InputError as exc:
            if not skip_bad:
                raise
            yield Frame(p.name, float("nan"), None, str(exc))
