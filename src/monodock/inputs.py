"""Reading the frames a user points monodock at: image files, folders of images, videos."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.errors import InputError

__all__ = ["IMAGE_SUFFIXES", "Frame", "iter_frames", "read_image"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v")


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


def _expand(inputs: Sequence[str | Path]) -> list[Path]:
    paths: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"no images in folder {p}")
            paths += found
        elif p.exists():
            paths.append(p)
        else:
            raise InputError(f"input not found: {p}")
    return paths


def iter_frames(inputs: Sequence[str | Path], *, skip_bad: bool = False) -> Iterator[Frame]:
    """Frames of image files, folders (sorted by name) and videos, in order.

    An unreadable image raises InputError, or with ``skip_bad`` yields a Frame without pixels and the reason.
    """
    for p in _expand(inputs):
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
