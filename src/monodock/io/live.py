"""Live estimation (``monodock run``): frames from a camera, stream, video or recording to a row per frame.

Each frame's estimate is written as soon as it is made, one CSV or JSON line flushed at a time, so that a
consumer can follow the output while the robot drives; optionally also a rosbag2 of ``detected_dock_pose`` for
Nav2 (``io.nav2``), and pictures of every frame (an overlay video, a window), drawn by the caller's ``draw``.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.atomic import check_writable
from monodock.core.frame import Frame
from monodock.errors import InputError
from monodock.estimation.estimator import Estimator, FrameEstimates
from monodock.io.frames import VIDEO_SUFFIXES, FrameSource
from monodock.io.rows import RowWriter, estimate_row

if TYPE_CHECKING:
    from monodock.io.nav2 import PoseStampedBagWriter

__all__ = ["Draw", "LiveStats", "run_live"]

# What pictures a frame: the image and its estimates in, a BGR picture of the same size out.
Draw = Callable[[NDArray[np.uint8], FrameEstimates], NDArray[np.uint8]]


# --- pictures ------------------------------------------------------------------------------------


class _OverlayVideo:
    """The overlay frames into a video file: written beside it, renamed into place when the run ends."""

    def __init__(self, path: str, fps: float, *, force: bool) -> None:
        self.path = check_writable(path, force=force)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        suffix = self.path.suffix.lower()
        if suffix not in VIDEO_SUFFIXES:
            raise InputError(f"overlay video {path}: give a video file name ({', '.join(VIDEO_SUFFIXES)})")
        self.fourcc = cv2.VideoWriter.fourcc(*("MJPG" if suffix == ".avi" else "mp4v"))
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=suffix, dir=self.path.parent)
        os.close(fd)
        self.tmp = Path(tmp)
        self.fps = fps if fps > 0 else 15.0
        self.writer: Any = None
        self.size: tuple[int, int] | None = None

    def write(self, picture: NDArray[np.uint8]) -> None:
        if self.writer is None:
            self.size = (picture.shape[1], picture.shape[0])
            self.writer = cv2.VideoWriter(str(self.tmp), self.fourcc, self.fps, self.size)
            if not self.writer.isOpened():
                raise InputError(f"cannot write overlay video {self.path}: no encoder for {self.path.suffix}")
        if (picture.shape[1], picture.shape[0]) != self.size:
            picture = np.asarray(cv2.resize(picture, self.size), dtype=np.uint8)
        self.writer.write(picture)

    def close(self, *, keep: bool) -> None:
        if self.writer is not None:
            self.writer.release()
        if keep and self.writer is not None:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)


def _has_display() -> bool:
    """Whether a window can be opened: on Linux, an X11 or Wayland display (Qt aborts without one)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _show(picture: NDArray[np.uint8], title: str, say: Callable[[str], None]) -> bool:
    """Show a picture in the window; False (after one message) when this OpenCV cannot open windows."""
    try:
        cv2.imshow(f"monodock: {title}", picture)
    except cv2.error as exc:
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "no GUI support"
        say(f"cannot open a window for --show ({first.strip()}); running without it")
        return False
    return True


def _close_windows() -> None:
    with contextlib.suppress(cv2.error):
        cv2.destroyAllWindows()


def _plain(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """A frame as a BGR picture, for frames without a detection."""
    return image if image.ndim == 3 else np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))


# --- the run -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LiveStats:
    """What a live run did: rows written, valid ones, sustained rate, latency, dropped frames, why it stopped.

    ``fps`` is rows / wall time of the whole run (reading, estimating, writing). The latency runs from a
    frame's arrival (the moment the source handed it over) to its row being ready to write. ``dropped``
    counts the frames skipped to keep up with a ``realtime`` playback.
    """

    frames: int
    valid: int
    dropped: int
    wall_s: float
    fps: float
    latency_median_ms: float
    latency_p95_ms: float
    stop_reason: str = ""
    first_failure: str = ""

    def summary(self) -> str:
        """One line for people."""
        text = (
            f"{self.frames} frames, {self.valid} valid, {self.fps:.1f} fps, latency median "
            f"{self.latency_median_ms:.1f} ms, p95 {self.latency_p95_ms:.1f} ms"
        )
        if self.dropped:
            text += f", {self.dropped} dropped to keep up"
        if self.frames and not self.valid and self.first_failure:
            text += f" (no estimate: {self.first_failure})"
        return text


class _Pacer:
    """Plays a video or recording at its own pace: waits for frames that are early, drops the late ones."""

    def __init__(self, source: FrameSource, realtime: bool) -> None:
        self.active = realtime and source.paced_by_stamps
        self.period = 1.0 / source.fps if source.fps > 0 else 0.0
        self.t0: float | None = None
        self.stamp0 = 0.0

    def arrival(self, frame: Frame, first: bool) -> float | None:
        """The frame's effective arrival time, or None when it is dropped (a camera would have sent a newer one)."""
        if not (self.active and math.isfinite(frame.stamp)):
            return frame.arrival
        if self.t0 is None:
            self.t0, self.stamp0 = frame.arrival, frame.stamp
        due = self.t0 + (frame.stamp - self.stamp0)
        now = time.perf_counter()
        if now > due + max(self.period, 0.005) and not first:
            return None
        if now < due:
            time.sleep(due - now)
        return max(due, frame.arrival)


@dataclass
class _Tally:
    """The counts and latencies of a run so far."""

    latencies: list[float] = field(default_factory=list)
    valid: int = 0
    dropped: int = 0
    first_failure: str = ""

    def add(self, result: FrameEstimates, method: str, latency_ms: float) -> None:
        est = result.estimates[method]
        if est.valid:
            self.valid += 1
        elif not self.first_failure:
            self.first_failure = est.reason
        self.latencies.append(latency_ms)

    def stats(self, wall: float, stop_reason: str) -> LiveStats:
        lat = np.asarray(self.latencies, dtype=np.float64)
        return LiveStats(
            frames=len(self.latencies),
            valid=self.valid,
            dropped=self.dropped,
            wall_s=wall,
            fps=len(self.latencies) / wall if wall > 0 else math.nan,
            latency_median_ms=float(np.median(lat)) if lat.size else math.nan,
            latency_p95_ms=float(np.percentile(lat, 95)) if lat.size else math.nan,
            stop_reason=stop_reason,
            first_failure=self.first_failure,
        )


def _estimate(estimator: Estimator, frame: Frame) -> FrameEstimates:
    """Every method's estimate of a frame; a frame that cannot be read or used gives the reason, never an error."""
    if frame.image is None:
        return estimator.failed(frame.name, frame.stamp, frame.error or "unreadable frame")
    try:
        return estimator.estimate(frame.name, frame.stamp, frame.image)
    except InputError as exc:
        return estimator.failed(frame.name, frame.stamp, str(exc))


class _Pictures:
    """Where the pictures of the frames go: an overlay video, a window, or nowhere."""

    def __init__(
        self, source: FrameSource, draw: Draw | None, video: str | None, show: bool, force: bool, say: Any
    ) -> None:
        if (video or show) and draw is None:
            raise InputError("pictures of the frames (an overlay video or a window) need a draw function")
        self.draw, self.title, self.say = draw, source.name, say
        self.video = _OverlayVideo(video, source.fps, force=force) if video else None
        if show and not _has_display():
            say("no display for --show (DISPLAY is not set); running without a window")
            show = False
        self.show = show

    @property
    def wanted(self) -> bool:
        return self.video is not None or self.show

    def add(self, image: NDArray[np.uint8], result: FrameEstimates) -> bool:
        """Picture one frame; False when the user closed the window ('q' or Esc)."""
        assert self.draw is not None
        picture = self.draw(image, result) if result.detection is not None else _plain(image)
        if self.video is not None:
            self.video.write(picture)
        if self.show:
            self.show = _show(picture, self.title, self.say)
            if self.show and (cv2.waitKey(1) & 0xFF) in (ord("q"), 27):
                self.say("stopped from the window")
                return False
        return True

    def close(self, *, keep: bool) -> None:
        if self.video is not None:
            self.video.close(keep=keep)
        if self.show:
            _close_windows()


def run_live(
    source: FrameSource,
    estimator: Estimator,
    method: str,
    *,
    sink: IO[str] | None,
    output_format: str = "csv",
    bag: PoseStampedBagWriter | None = None,
    draw: Draw | None = None,
    overlay_video: str | None = None,
    force: bool = False,
    show: bool = False,
    realtime: bool = False,
    max_frames: int | None = None,
    on_row: Callable[[dict[str, str]], None] | None = None,
    on_message: Callable[[str], None] | None = None,
) -> LiveStats:
    """Estimate every frame of a source and stream one row per frame as it is made.

    A frame that cannot be read or used (no markers, wrong size) gives an invalid row with the reason, never
    an error.

    Args:
        source: from ``io.frames.open_frames`` (with ``skip_bad=True``, so that bad frames become rows).
        estimator: with ``method`` among its methods.
        method: the method whose estimate the rows carry.
        sink: text stream for the rows (None: no rows written), flushed after each row.
        output_format: "csv" (``io.rows.LIVE_COLUMNS``, header first) or "jsonl" (the same keys, typed values).
        bag: also publish the valid poses there (``io.nav2``), with their covariance when they have one.
        draw: pictures a frame with its estimates, for ``overlay_video`` and ``show``.
        overlay_video: also write the picture of every frame to this video file.
        force: replace an existing ``overlay_video``.
        show: show the pictures in a window ('q' or Esc stops the run); without a display, a message instead.
        realtime: play a video or recording at its own pace (frames it falls behind on are dropped);
            otherwise as fast as possible.
        max_frames: stop after this many frames.
        on_row: called with each row (the CSV strings) after it is written.
        on_message: what to tell the user (a source that stopped, no window), by default stderr.

    Returns:
        The run's LiveStats.
    """
    if method not in estimator.methods:
        raise InputError(f"method '{method}' is not one of the estimator's ({', '.join(estimator.methods)})")
    say = on_message or (lambda text: print(f"monodock run: {text}", file=sys.stderr))
    estimator.warm_up()
    writer = RowWriter(sink, output_format) if sink is not None else None
    pictures = _Pictures(source, draw, overlay_video, show, force, say)
    pacer, tally = _Pacer(source, realtime), _Tally()
    start = time.perf_counter()
    finished = False
    try:
        for frame in source:
            if max_frames is not None and len(tally.latencies) >= max_frames:
                break
            arrival = pacer.arrival(frame, first=not tally.latencies)
            if arrival is None:
                tally.dropped += 1
                continue
            result = _estimate(estimator, frame)
            latency_ms = (time.perf_counter() - arrival) * 1000.0
            row = estimate_row(result, method, latency_ms)
            if writer is not None:
                writer.write(row)
            tally.add(result, method, latency_ms)
            if bag is not None:
                bag.write_row(row)
            if on_row is not None:
                on_row(row)
            if pictures.wanted and frame.image is not None and not pictures.add(frame.image, result):
                break
        finished = True
    finally:
        pictures.close(keep=finished)
    stats = tally.stats(time.perf_counter() - start, source.stop_reason)
    if source.stop_reason:
        say(source.stop_reason)
    return stats
