"""Live estimation (``monodock run``): frames from a camera, stream, video or recording to a row per frame.

Each frame's estimate is written as soon as it is made, one CSV or JSON line flushed at a time, so that a
consumer can follow the output while the robot drives; optionally also an overlay video, a window, and a
rosbag2 of ``detected_dock_pose`` for Nav2 (monodock.recording.nav2).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.atomic import check_writable
from monodock.errors import InputError
from monodock.estimation.estimator import COVARIANCE_COLUMNS, CSV_COLUMNS, Estimator, FrameEstimates, estimates_csv
from monodock.io.frames import VIDEO_SUFFIXES, is_recording

if TYPE_CHECKING:
    from monodock.recording.nav2 import PoseStampedBagWriter

__all__ = [
    "LIVE_COLUMNS",
    "FrameSource",
    "LiveFrame",
    "LiveStats",
    "add_parser",
    "open_source",
    "run_live",
]

# The EST.csv columns, and the milliseconds from the frame's arrival to its row being ready.
LIVE_COLUMNS = (*CSV_COLUMNS, "latency_ms")
_NUMERIC = ("stamp", "x_m", "y_m", "yaw_deg", "reprojection_px", "tilt_deg", *COVARIANCE_COLUMNS)
STALL_TIMEOUT_S = 2.0


class LiveFrame(NamedTuple):
    """One frame of a source: its index, stamp (s), pixels or None, why not, and its arrival (perf_counter)."""

    number: int
    stamp: float
    image: NDArray[np.uint8] | None
    error: str
    arrival: float


# --- sources -------------------------------------------------------------------------------------


class FrameSource:
    """Frames of a camera, stream, video file or recording, in order; a context manager (see open_source).

    Attributes:
        name: how messages name the source ("camera 0", "video drive.avi", ...).
        kind: "camera", "stream", "video" or "recording".
        fps: the video's frame rate (0 when unknown).
        stop_reason: why the frames ended early (a device that stopped delivering), "" otherwise.
        warnings: what the recording reader had to say (a bag cut short).
    """

    def __init__(
        self,
        name: str,
        kind: str,
        *,
        capture: Any = None,
        recording: Any = None,
        stall_timeout_s: float = STALL_TIMEOUT_S,
    ) -> None:
        self.name, self.kind = name, kind
        self._capture, self._recording = capture, recording
        self.stall_timeout_s = stall_timeout_s
        fps = float(capture.get(cv2.CAP_PROP_FPS)) if capture is not None else 0.0
        self.fps = fps if math.isfinite(fps) and 0.0 < fps < 1000.0 else 0.0
        self.stop_reason = ""
        self.warnings: list[str] = []

    @property
    def paced_by_stamps(self) -> bool:
        """Whether the stamps are a file's timeline (videos, recordings), which ``realtime`` plays back."""
        return self.kind in ("video", "recording")

    def __iter__(self) -> Iterator[LiveFrame]:
        if self._recording is not None:
            yield from self._recording_frames()
        else:
            yield from self._capture_frames()

    def _recording_frames(self) -> Iterator[LiveFrame]:
        rec = self._recording
        self.warnings += rec.warnings
        said = len(rec.warnings)
        index = -1
        for index, f in enumerate(rec.images()):
            yield LiveFrame(index, f.stamp, f.image, f.error, time.perf_counter())
        self.warnings += rec.warnings[said:]
        if index < 0:
            raise InputError(f"{self.name} has no images")

    def _capture_frames(self) -> Iterator[LiveFrame]:
        cap = self._capture
        index = 0
        last = time.monotonic()
        while True:
            ok, img = cap.read()
            if ok and img is not None:
                arrival = time.perf_counter()
                # A video's stamps are its timeline; a camera's or stream's, the moment the frame came.
                stamp = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0 if self.kind == "video" else time.time()
                yield LiveFrame(index, stamp, np.asarray(img, dtype=np.uint8), "", arrival)
                index += 1
                last = time.monotonic()
                continue
            if self.kind == "video":  # the end of the file
                if index == 0:
                    raise InputError(f"{self.name} has no readable frames")
                return
            waited = time.monotonic() - last
            if waited >= self.stall_timeout_s:
                if index == 0:
                    raise InputError(f"{self.name}: no frame for {self.stall_timeout_s:.1f} s; nothing received")
                self.stop_reason = f"{self.name}: no frame for {waited:.1f} s; stopping after {index} frames"
                return
            time.sleep(0.01)

    def close(self) -> None:
        """Release the device, file or recording."""
        if self._capture is not None:
            self._capture.release()
        if self._recording is not None:
            self._recording.close()

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _quietly(opener: Callable[[], Any]) -> Any:
    """Open a capture without OpenCV's own warnings on stderr: a failure is told once, as an InputError."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        return opener()
    finally:
        cv2.utils.logging.setLogLevel(level)


def open_source(
    spec: str,
    *,
    image_topic: str | None = None,
    size: tuple[int, int] | None = None,
    stall_timeout_s: float = STALL_TIMEOUT_S,
) -> FrameSource:
    """Open a frame source: a camera index ("0"), a video file, an rtsp:// or http(s):// URL, or a recording.

    Stamps are the capture time (time.time()) for cameras and URLs, the position in the file for videos, and
    the header stamps for recordings (rosbag2 folder, .mcap, .db3, ROS 1 .bag).

    Args:
        spec: what to open.
        image_topic: a recording's image topic, when it has several.
        size: (width, height) to ask a camera for (the calibrated size); devices may ignore it.
        stall_timeout_s: how long a camera or stream may go without a frame before the run stops.

    Raises:
        InputError: the source cannot be opened (one line naming it).
    """
    text = spec.strip()
    if text.isdigit():
        name, kind = f"camera {text}", "camera"
        cap = _quietly(lambda: cv2.VideoCapture(int(text)))
        if size is not None and cap.isOpened():
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
    elif "://" in text:
        name, kind = f"stream {text}", "stream"
        cap = _quietly(lambda: cv2.VideoCapture(text))
    else:
        path = Path(text)
        if path.exists() and is_recording(path):
            from monodock.recording import open_recording

            return FrameSource(
                f"recording {path}",
                "recording",
                recording=open_recording(path, image_topic=image_topic),
                stall_timeout_s=stall_timeout_s,
            )
        if not path.is_file():
            raise InputError(f"cannot open {text}: no such file, camera index or URL")
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise InputError(f"cannot open {text}: not a video ({', '.join(VIDEO_SUFFIXES)}) nor a recording")
        name, kind = f"video {text}", "video"
        cap = _quietly(lambda: cv2.VideoCapture(str(path)))
    if not cap.isOpened():
        cap.release()
        raise InputError(f"cannot open {name}")
    return FrameSource(name, kind, capture=cap, stall_timeout_s=stall_timeout_s)


# --- rows ----------------------------------------------------------------------------------------


def _row(result: FrameEstimates, method: str, latency_ms: float) -> dict[str, str]:
    """The EST.csv row of one frame and method (estimates_csv's own formatting) and its latency."""
    one = FrameEstimates(result.name, result.stamp, result.detection, {method: result.estimates[method]})
    _, values = csv.reader(io.StringIO(estimates_csv([one])))
    return {**dict(zip(CSV_COLUMNS, values, strict=True)), "latency_ms": f"{latency_ms:.2f}"}


def _typed(row: dict[str, str]) -> dict[str, object]:
    """A row for JSON: numbers as numbers (null when empty), ``valid`` as a boolean."""
    out: dict[str, object] = {}
    for k, v in row.items():
        if k == "valid":
            out[k] = v == "true"
        elif k in (*_NUMERIC, "latency_ms"):
            out[k] = float(v) if v else None
        else:
            out[k] = v
    return out


class _RowWriter:
    """Rows to a text stream as CSV (header first) or JSON lines, flushed one by one."""

    def __init__(self, stream: IO[str], output_format: str) -> None:
        if output_format not in ("csv", "jsonl"):
            raise InputError(f"output format '{output_format}' is unknown (csv, jsonl)")
        self.stream, self.format = stream, output_format
        self._csv = csv.writer(stream, lineterminator="\n")
        if output_format == "csv":
            self._csv.writerow(LIVE_COLUMNS)
            stream.flush()

    def write(self, row: dict[str, str]) -> None:
        if self.format == "csv":
            self._csv.writerow([row[k] for k in LIVE_COLUMNS])
        else:
            self.stream.write(json.dumps(_typed(row), allow_nan=False) + "\n")
        self.stream.flush()


# --- overlay and window --------------------------------------------------------------------------


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


def _picture(image: NDArray[np.uint8], result: FrameEstimates, method: str, estimator: Estimator) -> NDArray[np.uint8]:
    """The overlay of one frame at its own size (the raw frame when nothing was detected)."""
    if result.detection is None:
        return image if image.ndim == 3 else np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    from monodock.report.overlay import draw_overlay

    return draw_overlay(
        image,
        result.detection,
        estimator.layout,
        estimator.camera,
        estimator.robot,
        result.estimates[method],
        scale=1.0,
    )


def _has_display() -> bool:
    """Whether a window can be opened: on Linux, an X11 or Wayland display (Qt aborts without one)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


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


def run_live(
    source: FrameSource,
    estimator: Estimator,
    method: str,
    *,
    sink: IO[str] | None,
    output_format: str = "csv",
    bag: PoseStampedBagWriter | None = None,
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
        source: from open_source.
        estimator: with ``method`` among its methods.
        method: the method whose estimate the rows carry.
        sink: text stream for the rows (None: no rows written), flushed after each row.
        output_format: "csv" (LIVE_COLUMNS, header first) or "jsonl" (the same keys, typed values).
        bag: also publish the valid poses there (monodock.recording.nav2), with their covariance when they have one.
        overlay_video: also write the overlay of every frame to this video file.
        force: replace an existing ``overlay_video``.
        show: show the overlay in a window ('q' or Esc stops the run); without a display, a message instead.
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
    writer = _RowWriter(sink, output_format) if sink is not None else None
    video = _OverlayVideo(overlay_video, source.fps, force=force) if overlay_video else None
    if show and not _has_display():
        say("no display for --show (DISPLAY is not set); running without a window")
        show = False
    latencies: list[float] = []
    valid = dropped = 0
    first_failure = ""
    start = time.perf_counter()
    t0: float | None = None
    stamp0 = 0.0
    period = 1.0 / source.fps if source.fps > 0 else 0.0
    ok = False
    try:
        for frame in source:
            if max_frames is not None and len(latencies) >= max_frames:
                break
            if realtime and source.paced_by_stamps and math.isfinite(frame.stamp):
                if t0 is None:
                    t0, stamp0 = frame.arrival, frame.stamp
                due = t0 + (frame.stamp - stamp0)
                now = time.perf_counter()
                if now > due + max(period, 0.005) and latencies:
                    dropped += 1  # a camera would have sent a newer frame by now
                    continue
                if now < due:
                    time.sleep(due - now)
                arrival = max(due, frame.arrival)
            else:
                arrival = frame.arrival
            name = str(frame.number)
            if frame.image is None:
                result = estimator.failed(name, frame.stamp, frame.error or "unreadable frame")
            else:
                try:
                    result = estimator.estimate(name, frame.stamp, frame.image)
                except InputError as exc:
                    result = estimator.failed(name, frame.stamp, str(exc))
            est = result.estimates[method]
            if est.valid:
                valid += 1
            elif not first_failure:
                first_failure = est.reason
            latency_ms = (time.perf_counter() - arrival) * 1000.0
            row = _row(result, method, latency_ms)
            if writer is not None:
                writer.write(row)
            latencies.append(latency_ms)
            if bag is not None:
                bag.write_row(row)
            if on_row is not None:
                on_row(row)
            if (video is not None or show) and frame.image is not None:
                picture = _picture(frame.image, result, method, estimator)
                if video is not None:
                    video.write(picture)
                if show:
                    show = _show(picture, source.name, say)
                    if show and (cv2.waitKey(1) & 0xFF) in (ord("q"), 27):
                        say("stopped from the window")
                        break
        ok = True
    finally:
        if video is not None:
            video.close(keep=ok)
        if show:
            _close_windows()
    wall = time.perf_counter() - start
    lat = np.asarray(latencies, dtype=np.float64)
    if source.stop_reason:
        say(source.stop_reason)
    for text in source.warnings:
        say(text)
    return LiveStats(
        frames=len(latencies),
        valid=valid,
        dropped=dropped,
        wall_s=wall,
        fps=len(latencies) / wall if wall > 0 else math.nan,
        latency_median_ms=float(np.median(lat)) if lat.size else math.nan,
        latency_p95_ms=float(np.percentile(lat, 95)) if lat.size else math.nan,
        stop_reason=source.stop_reason,
        first_failure=first_failure,
    )


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


# --- command line --------------------------------------------------------------------------------


def _output_format(args: argparse.Namespace) -> str:
    if args.format:
        return str(args.format)
    return "jsonl" if str(args.out).lower().endswith((".jsonl", ".ndjson", ".json")) else "csv"


def _cmd_run(args: argparse.Namespace) -> int:
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be at least 1, got {args.max_frames}")
    to_stdout = args.out == "-"
    if not to_stdout:
        check_writable(args.out, force=args.force)
    if args.bag:
        check_writable(args.bag, force=args.force)
    if args.overlay_video:
        check_writable(args.overlay_video, force=args.force)
    from monodock.cli.main import build_estimator

    estimator, method = build_estimator(args)
    output_format = _output_format(args)
    with contextlib.ExitStack() as stack:
        source = stack.enter_context(open_source(args.source, image_topic=args.image_topic, size=estimator.camera.size))
        bag = None
        if args.bag:
            from monodock.recording.nav2 import PoseStampedBagWriter

            bag = stack.enter_context(PoseStampedBagWriter(args.bag, force=args.force))
        if to_stdout:
            sink: IO[str] = sys.stdout
        else:
            # Streamed into the named file itself, so that it can be followed (tail -f) during the run;
            # it was checked above not to replace anything without --force.
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            sink = stack.enter_context(open(args.out, "w", encoding="utf-8", newline=""))
        stats = run_live(
            source,
            estimator,
            method,
            sink=sink,
            output_format=output_format,
            bag=bag,
            overlay_video=args.overlay_video,
            force=args.force,
            show=args.show,
            realtime=args.realtime,
            max_frames=args.max_frames,
        )
    where = "" if to_stdout else f" -> {args.out}"
    if bag is not None:
        where += f"; {bag.written} poses -> {args.bag}"
        if bag.written_with_covariance:
            where += f" ({bag.written_with_covariance} with covariance)"
    print(f"{method} on {source.name}: {stats.summary()}{where}", file=sys.stderr if to_stdout else sys.stdout)
    return 0


def add_parser(subparsers: Any) -> None:
    """Add the ``run`` command to the ``monodock`` sub-command parsers (``argparse._SubParsersAction``)."""
    r = subparsers.add_parser(
        "run",
        help="live estimation from a camera, stream, video or recording: one row per frame as it comes",
    )
    r.add_argument(
        "--source",
        required=True,
        help="camera index (0, 1 ...), video file, rtsp:// or http:// URL, "
        "or recording (rosbag2 folder, .mcap, .db3, .bag)",
    )
    r.add_argument("--model", help="model bundle (carries its camera, layout and mounts; --camera may override)")
    r.add_argument(
        "--method",
        choices=("regression", "pnp", "board"),
        help="regression: the papers' models (default with --model); pnp: marker 2 alone; board: all visible "
        "markers (default without --model)",
    )
    r.add_argument("--out", default="-", help="rows to write: FILE.csv, FILE.jsonl, or - for stdout (default)")
    r.add_argument("--format", choices=("csv", "jsonl"), help="row format (default: from --out's suffix, else csv)")
    r.add_argument("--bag", metavar="OUT_BAG", help="also write the valid poses as a Nav2 detected_dock_pose rosbag2")
    r.add_argument("--overlay-video", metavar="OUT.mp4", help="also write the overlay of every frame to a video")
    r.add_argument("--show", action="store_true", help="show the overlay in a window ('q' stops)")
    r.add_argument(
        "--realtime",
        action="store_true",
        help="play a video or recording at its own rate (drops frames "
        "it cannot keep up with); default: as fast as possible",
    )
    r.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    r.add_argument("--image-topic", help="a recording's image topic, when it has several")
    r.add_argument(
        "--refinement", choices=("none", "subpix", "contour"), default="subpix", help="ArUco corner refinement"
    )
    r.add_argument("--camera", help="camera file: ROS camera_info YAML or OpenCV FileStorage")
    r.add_argument("--layout", help="dock layout YAML")
    r.add_argument("--robot", help="robot YAML (camera and LiDAR mounts, front_offset)")
    r.add_argument("--force", action="store_true", help="overwrite existing outputs")
    r.set_defaults(func=_cmd_run)
