"""The libraries' own messages (OpenCV's log, FFmpeg's, libpng's and libjpeg's warnings) kept off the CLI's stderr.

On bad input the CLI prints one line of its own (issue 18); the C libraries under OpenCV would print theirs first
("libpng warning: iCCP: known incorrect sRGB profile", "[ WARN:0@0.4] global grfmt_png.cpp ...", FFmpeg's
"moov atom not found", libjpeg's "Corrupt JPEG data: ..."). Two things keep them off:

- ``command_session`` (``monodock.cli.main`` runs every command inside it): OpenCV's log level to SILENT and
  FFmpeg's to quiet (``OPENCV_FFMPEG_LOGLEVEL``) for the command, both put back after it.
- ``library_output`` around each call that decodes a file or opens or reads a capture: libpng and libjpeg write
  straight to file descriptor 2, past any log level, so during the call fd 2 points at a temporary file, whose
  text the caller gets (libjpeg's "Corrupt JPEG data" on an image it still decoded marks it damaged). It only does so
  inside a command session (a library user, a ROS node with threads that log, keeps its stderr); outside one it
  holds OpenCV's log at ERROR while a capture opens, as before.

``monodock --debug`` keeps all of it: no level is changed, nothing is redirected.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator

import cv2

__all__ = ["Said", "command_session", "library_output"]

# FFmpeg's AV_LOG_QUIET; OpenCV's FFmpeg back end reads the variable each time it opens a file.
_FFMPEG_QUIET = "-8"
_state = {"session": False, "debug": False}


@contextlib.contextmanager
def command_session(*, debug: bool) -> Iterator[None]:
    """One CLI command: the libraries silent unless ``debug``; levels and environment put back at the end."""
    saved_state = dict(_state)
    saved_level = cv2.utils.logging.getLogLevel()
    saved_env = os.environ.get("OPENCV_FFMPEG_LOGLEVEL")
    _state.update(session=True, debug=debug)
    if not debug:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        os.environ["OPENCV_FFMPEG_LOGLEVEL"] = _FFMPEG_QUIET
    try:
        yield
    finally:
        _state.update(saved_state)
        cv2.utils.logging.setLogLevel(saved_level)
        if saved_env is None:
            os.environ.pop("OPENCV_FFMPEG_LOGLEVEL", None)
        else:
            os.environ["OPENCV_FFMPEG_LOGLEVEL"] = saved_env


class Said:
    """What the libraries wrote on fd 2 during a ``library_output`` block (inside a command session only)."""

    def __init__(self) -> None:
        self.text = ""


@contextlib.contextmanager
def library_output() -> Iterator[Said]:
    """Around a decode or a capture's open or read: what the C libraries write on fd 2 is kept off stderr (see
    above) and handed back in the yielded ``Said``, so that a caller can tell a damaged file by its complaint."""
    said = Said()
    if _state["debug"]:
        yield said
        return
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(min(level, cv2.utils.logging.LOG_LEVEL_ERROR))
    saved = -1
    sink = None
    if _state["session"]:
        with contextlib.suppress(ValueError, OSError):  # a closed or replaced sys.stderr: nothing to flush
            sys.stderr.flush()
        try:
            saved = os.dup(2)
            sink = tempfile.TemporaryFile()  # noqa: SIM115 - closed in the finally below
        except OSError:  # no fd 2 (a daemon) or no file descriptors left: the libraries may speak
            if saved >= 0:
                os.close(saved)
            saved = -1
        else:
            os.dup2(sink.fileno(), 2)
    try:
        yield said
    finally:
        if saved >= 0:
            os.dup2(saved, 2)
            os.close(saved)
        if sink is not None:
            sink.seek(0)
            said.text = sink.read(4096).decode("utf-8", "replace")
            sink.close()
        cv2.utils.logging.setLogLevel(level)
