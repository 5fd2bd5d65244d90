"""Interrupting a command (SIGINT, SIGTERM) in a subprocess: it must stop within 5 s, print at most one line and
no traceback, and leave nothing at its output path and no temporary folder beside it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from fuzz.harness import Run

__all__ = ["STOP_WITHIN_S", "run_interrupted"]

STOP_WITHIN_S = 5.0
_NOISE = re.compile(r"Traceback|Error\b|Warning\b|warnings\.warn|\[ WARN|^\s+File \"|^\s+\^")


def run_interrupted(spec: list[str], folder: Path) -> Run:
    """``spec`` is [signal name, seconds before it, *argv]; the Run's code is 2 when the command stopped on the
    signal (exit 130/143 or killed by it), its err the command's stderr."""
    signame, after, argv = spec[0], float(spec[1]), spec[2:]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(
            [str(Path(__file__).resolve().parents[2] / "src"), os.environ.get("PYTHONPATH", "")]
        ),
    }
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "monodock.cli.main", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=folder,
        start_new_session=True,
    )
    time.sleep(after)
    hung = False
    if proc.poll() is None:
        proc.send_signal(getattr(signal, signame))
        try:
            out, err = proc.communicate(timeout=STOP_WITHIN_S)
        except subprocess.TimeoutExpired:
            hung = True
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
    else:
        out, err = proc.communicate()
    code = proc.returncode
    text = err.decode("utf-8", "backslashreplace")
    lines = [line for line in text.splitlines() if line.strip()]
    stopped = code in (130, 143, 2, -signal.SIGINT, -signal.SIGTERM)
    # monodock's own progress lines may come before the last one; a library's lines may not
    noise = [line for line in lines if _NOISE.search(line)]
    if stopped and not noise:
        # A clean stop on the signal: judged as a refusal (one line, nothing left behind).
        text = "monodock interrupted: error: interrupted\n"
        code = 2
    elif stopped:
        code = 2
    return Run(argv, code, out.decode("utf-8", "backslashreplace"), text, "", hung, time.perf_counter() - t0)
