"""One frame source for everything a user points monodock at: images, folders, videos, cameras, streams, recordings.

``open_frames`` takes what the user typed (one or more paths, a camera index, a URL) and gives a ``FrameSource``:
a context manager that yields ``Frame``s in order, each named and stamped by the one rule of ``core.frame.Frame``
(a recording's header stamp, a video's position in the file, a camera's or stream's capture time, NaN for an
image file). ``monodock estimate``, ``monodock run``, calibration and the tests all read frames through it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.closing import Closing
from monodock.core.frame import Frame
from monodock.core.images import ImageError, decode, printable
from monodock.core.quiet import library_output
from monodock.errors import InputError
from monodock.recording.read import Recording, is_recording, open_recording

__all__ = [
    "IMAGE_SUFFIXES",
    "STALL_TIMEOUT_S",
    "VIDEO_SUFFIXES",
    "FrameSource",
    "open_frames",
    "read_image",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v")
# How long a camera or stream may go without a frame before the source stops.
STALL_TIMEOUT_S = 2.0

# What the recording reader says about an input (a bag cut short): the CLI holds it until the command has not
# refused its input, so that a refusal stays one line.
_log = logging.getLogger("monodock.input")


def read_image(path: str | Path) -> NDArray[np.uint8]:
    """An image file's pixels as 8-bit mono or BGR (``core.images.decode``), or InputError naming the file."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{printable(str(p))} is a folder, not an image")
    if not p.is_file():
        raise InputError(f"image not found: {printable(str(p))}")
    data = np.fromfile(p, dtype=np.uint8)
    try:
        return decode(data)
    except ImageError as exc:
        raise InputError(f"cannot read image {printable(str(p))}: {exc}") from None


def _quietly(call: Callable[[], Any]) -> Any:
    """A capture's open or read without OpenCV's and FFmpeg's own lines on stderr (``core.quiet``)."""
    with library_output():
        return call()


def _open_video(path: Path) -> Any:
    cap = _quietly(lambda: cv2.VideoCapture(str(path)))
    if not cap.isOpened():
        cap.release()
        raise InputError(f"cannot open video {printable(str(path))}: not a video, or truncated or corrupt")
    return cap


def _expand(inputs: Sequence[str | Path]) -> list[Path]:
    """Image files, videos and recordings in order; a folder of images gives its images sorted by name."""
    paths: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.exists() and is_recording(p):
            paths.append(p)
        elif p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"no images in folder {printable(str(p))}")
            paths += found
        elif p.exists():
            paths.append(p)
        else:
            raise InputError(f"input not found: {printable(str(p))}")
    return paths


class FrameSource(Closing):
    """Frames of image files, folders, videos, a camera, a stream or recordings, in order; a context manager.

    Make one with ``open_frames`` (or ``FrameSource.of_capture`` for a capture object you already hold).

    Attributes:
        name: how messages name the source ("camera 0", "video drive.avi", "3 inputs", ...).
        kind: "camera", "stream", "video", "recording" or "files" (image files, or several inputs).
        fps: a lone video's or camera's frame rate (0 when unknown).
        stop_reason: why the frames ended early (a device that stopped delivering), "" otherwise.
        warnings: what the recording reader had to say (a bag cut short), also passed to ``on_warning``.
    """

    def __init__(
        self,
        name: str,
        kind: str,
        *,
        paths: Sequence[Path] = (),
        capture: Any = None,
        recording: Recording | None = None,
        skip_bad: bool = True,
        image_topic: str | None = None,
        stall_timeout_s: float = STALL_TIMEOUT_S,
        on_warning: Callable[[str], None] | None = None,
    ) -> None:
        self.name, self.kind = name, kind
        self._paths = list(paths)
        self._capture, self._recording = capture, recording
        self.skip_bad, self.image_topic = skip_bad, image_topic
        self.stall_timeout_s = stall_timeout_s
        self._on_warning = on_warning
        fps = float(capture.get(cv2.CAP_PROP_FPS)) if capture is not None else 0.0
        self.fps = fps if math.isfinite(fps) and 0.0 < fps < 1000.0 else 0.0
        self.stop_reason = ""
        self.warnings: list[str] = []

    @classmethod
    def of_capture(cls, name: str, kind: str, capture: Any, *, stall_timeout_s: float = STALL_TIMEOUT_S) -> FrameSource:
        """A source over an opened ``cv2.VideoCapture`` (or anything with its read/get/release methods)."""
        return cls(name, kind, capture=capture, stall_timeout_s=stall_timeout_s)

    @property
    def paced_by_stamps(self) -> bool:
        """Whether the stamps are a file's timeline (videos, recordings), which a real-time playback follows."""
        return self.kind in ("video", "recording")

    def __iter__(self) -> Iterator[Frame]:
        if self._capture is not None:
            yield from self._capture_frames(self._capture, live=self.kind in ("camera", "stream"))
        elif self._recording is not None:
            yield from self._recording_frames(self._recording)
        else:
            yield from self._file_frames()

    # --- the kinds of input ---------------------------------------------------------------------------------

    def _warn(self, text: str) -> None:
        self.warnings.append(text)
        (self._on_warning or _log.warning)(text)

    def _file_frames(self) -> Iterator[Frame]:
        for p in self._paths:
            if is_recording(p):
                with open_recording(p, image_topic=self.image_topic) as rec:
                    yield from self._recording_frames(rec)
            elif p.suffix.lower() in VIDEO_SUFFIXES:
                cap = _open_video(p)
                try:
                    yield from self._capture_frames(cap, live=False, label=f"video {p}")
                finally:
                    cap.release()
            else:
                try:
                    yield Frame(printable(p.name), math.nan, read_image(p), arrival=time.perf_counter())
                except InputError as exc:
                    if not self.skip_bad:
                        raise
                    yield Frame(printable(p.name), math.nan, None, str(exc), arrival=time.perf_counter())

    def _recording_frames(self, rec: Recording) -> Iterator[Frame]:
        said = 0

        def tell() -> None:
            nonlocal said
            for text in rec.warnings[said:]:
                self._warn(text)
            said = len(rec.warnings)

        tell()  # what opening found (a bag cut short) is said before the frames, not after
        count = 0
        for frame in rec.images():
            if frame.image is None and not self.skip_bad:
                raise InputError(f"{frame.error} (pass --skip-bad to go on without it)")
            count += 1
            yield dataclasses.replace(frame, arrival=time.perf_counter())
        tell()
        if count == 0:
            raise InputError(f"recording {rec.path} has no images")

    def _capture_frames(self, cap: Any, *, live: bool, label: str = "") -> Iterator[Frame]:
        label = label or self.name
        index = 0
        last = time.monotonic()
        while True:
            ok, img = _quietly(cap.read)
            if ok and img is not None:
                arrival = time.perf_counter()
                stamp = time.time() if live else float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
                yield Frame(str(index), stamp, np.asarray(img, dtype=np.uint8), arrival=arrival)
                index += 1
                last = time.monotonic()
                continue
            if not live:  # the end of the file
                if index == 0:
                    raise InputError(f"{label} has no readable frames")
                return
            waited = time.monotonic() - last
            if waited >= self.stall_timeout_s:
                if index == 0:
                    raise InputError(f"{label}: no frame for {self.stall_timeout_s:.1f} s; nothing received")
                self.stop_reason = f"{label}: no frame for {waited:.1f} s; stopping after {index} frames"
                return
            time.sleep(0.01)

    # --- context manager (Closing) ----------------------------------------------------------------------------

    def close(self) -> None:
        """Release the device, file or recording."""
        if self._capture is not None:
            self._capture.release()
        if self._recording is not None:
            self._recording.close()


def open_frames(
    inputs: str | Path | Sequence[str | Path],
    *,
    skip_bad: bool = False,
    image_topic: str | None = None,
    size: tuple[int, int] | None = None,
    stall_timeout_s: float = STALL_TIMEOUT_S,
    on_warning: Callable[[str], None] | None = None,
) -> FrameSource:
    """Open a frame source: image files, folders of images, videos, recordings, a camera index or a URL.

    Args:
        inputs: one spec or several. A camera index ("0") or an rtsp:// or http(s):// URL stands alone; paths
            may be image files, folders (their images, sorted by name), videos and recordings (a rosbag2
            folder with metadata.yaml, an .mcap, .db3 or ROS 1 .bag file).
        skip_bad: an unreadable image file or recording frame gives a Frame without pixels and the reason
            instead of an InputError.
        image_topic: a recording's image topic, when it has several.
        size: (width, height) to ask a camera for (the calibrated size); devices may ignore it.
        stall_timeout_s: how long a camera or stream may go without a frame before the source stops.
        on_warning: what to do with a recording reader's warnings (default: the "monodock" logger).

    Raises:
        InputError: a path that does not exist, a folder without images, a device, stream, video or
            recording that cannot be opened (one line naming it).
    """
    specs = [inputs] if isinstance(inputs, str | Path) else list(inputs)
    if not specs:
        raise InputError("no input given")
    text = str(specs[0]).strip()
    if len(specs) == 1 and (text.isdigit() or "://" in text):
        kind = "camera" if text.isdigit() else "stream"
        name = f"{kind} {text}"
        cap = _quietly(lambda: cv2.VideoCapture(int(text) if kind == "camera" else text))
        if not cap.isOpened():
            cap.release()
            raise InputError(f"cannot open {name}")
        if size is not None and kind == "camera":
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
        return FrameSource.of_capture(name, kind, cap, stall_timeout_s=stall_timeout_s)
    paths = _expand(specs)
    common: dict[str, Any] = {"skip_bad": skip_bad, "image_topic": image_topic, "on_warning": on_warning}
    if len(specs) == 1 and len(paths) == 1:
        p = paths[0]
        if is_recording(p):
            rec = open_recording(p, image_topic=image_topic)
            return FrameSource(f"recording {p}", "recording", recording=rec, **common)
        if p.suffix.lower() in VIDEO_SUFFIXES:
            return FrameSource(f"video {p}", "video", capture=_open_video(p), **common)
    return FrameSource(str(specs[0]) if len(specs) == 1 else f"{len(specs)} inputs", "files", paths=paths, **common)
