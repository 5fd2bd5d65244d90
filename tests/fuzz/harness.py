"""Run a monodock command in-process on hostile input and judge it against issue 18's contract.

The contract: a command either succeeds (exit 0) with sane outputs, or refuses with exactly one stderr line
``monodock <cmd>: error: ...`` and exit 2. Never exit 1 (internal error), never a traceback or a library's own log
line, never a hang, never a ``valid=true`` estimate from a physically implausible file, never a half-written
output, never an input changed.

``run_cli`` runs ``monodock.cli.main.main`` in this process with file descriptors 1 and 2 captured (so that what
OpenCV, libpng or FFmpeg print from C is seen too) and an alarm against hangs; ``judge`` names every way the run
broke the contract, each as one of ``KINDS``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import re
import signal
import sys
import tempfile
import traceback
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "KINDS",
    "UNKNOWN_MARK",
    "Expect",
    "Run",
    "capture_fds",
    "judge",
    "outcome",
    "run_cli",
    "snapshot",
]

# How a run can break the contract (the columns of the catalogue's table, after "clean refusal" and "ok").
KINDS = ("internal error", "traceback/noise", "silent wrong", "hang", "half-written", "input destroyed")
# A key no monodock file knows: it may be warned about but must never reach an output.
UNKNOWN_MARK = "fuzz_unknown_key_7f3a"
# Outputs much bigger than this from inputs of a few kB are an expansion (an alias bomb written out).
MAX_OUTPUT_BYTES = 20_000_000
DEFAULT_TIMEOUT_S = 60.0

# The hidden temporary file or folder of an atomic write (``.NAME.<8 random characters>``).
_TEMP_NAME = re.compile(r"/\.[^/\s]+\.[A-Za-z0-9_]{8}(?![A-Za-z0-9_])")
_ONE_LINE = re.compile(r"^monodock(?: [a-z-]+)*: error: \S.*$")


class Hang(BaseException):
    """The command ran past its time limit (raised by the alarm; a BaseException so no handler eats it)."""


@dataclass(frozen=True)
class Expect:
    """What a case's input deserves.

    Attributes:
        refuse: the input is bad or physically implausible: exit 2 is the only right answer, except that
            ``estimate`` may also exit 0 with no ``valid=true`` row (the brief's "no valid row from an implausible
            file"); any other exit 0 is a silently wrong output.
        truth: exit 0 must give valid estimate rows within tolerance of the simulator's truth (x_m, y_m, yaw_deg),
            for inputs that still describe the true set-up.
        outputs: the output paths (files or folders); after a refusal none may exist (unless it existed before).
        inputs: the input paths; they must be byte-identical afterwards.
    """

    refuse: bool = False
    truth: tuple[float, float, float] | None = None
    outputs: tuple[Path, ...] = ()
    inputs: tuple[Path, ...] = ()
    implausible_ok_without_valid: bool = True


@dataclass
class Run:
    """One command run: exit code (None for an escaped exception or a hang), captured output, timings."""

    argv: list[str]
    code: int | None
    out: str
    err: str
    escaped: str = ""  # the traceback of an exception that escaped main()
    hung: bool = False
    seconds: float = 0.0
    before: dict[str, str] = field(default_factory=dict)
    after: dict[str, str] = field(default_factory=dict)
    existed: dict[str, bool] = field(default_factory=dict)


def _digest(p: Path) -> str:
    """A fingerprint of a path: the file type and bytes of a file, or every file under a folder."""
    try:
        st = p.lstat()
    except (FileNotFoundError, NotADirectoryError):
        return "absent"
    if p.is_symlink():
        return f"link:{os.readlink(p)}"
    if p.is_dir():
        h = hashlib.sha256()
        for sub in sorted(p.rglob("*")):
            h.update(str(sub.relative_to(p)).encode("utf-8", "surrogateescape"))
            if sub.is_file() and not sub.is_symlink():
                h.update(hashlib.sha256(sub.read_bytes()).digest())
        return "dir:" + h.hexdigest()
    if not p.is_file():
        return f"special:{st.st_mode:o}"
    return "file:" + hashlib.sha256(p.read_bytes()).hexdigest()


def snapshot(paths: Sequence[Path]) -> dict[str, str]:
    return {str(p): _digest(p) for p in paths}


@contextmanager
def capture_fds() -> Iterator[dict[str, str]]:
    """Capture file descriptors 1 and 2 (and sys.stdout/sys.stderr) into the yielded dict's "out" and "err"."""
    result: dict[str, str] = {}
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    files = {fd: tempfile.TemporaryFile(mode="w+b") for fd in (1, 2)}  # noqa: SIM115 - closed in the finally
    py = (sys.stdout, sys.stderr)
    for fd, f in files.items():
        os.dup2(f.fileno(), fd)
    sys.stdout = io.TextIOWrapper(open(1, "wb", closefd=False), encoding="utf-8", errors="backslashreplace")  # noqa: SIM115
    sys.stderr = io.TextIOWrapper(open(2, "wb", closefd=False), encoding="utf-8", errors="backslashreplace")  # noqa: SIM115
    try:
        yield result
    finally:
        for s in (sys.stdout, sys.stderr):
            s.flush()
        sys.stdout, sys.stderr = py
        for fd, old in saved.items():
            os.dup2(old, fd)
            os.close(old)
        for fd, f in files.items():
            f.seek(0)
            result["out" if fd == 1 else "err"] = f.read().decode("utf-8", "backslashreplace")
            f.close()


@contextmanager
def _alarm(seconds: float) -> Iterator[None]:
    """Raise Hang in the main thread after ``seconds`` (no alarm outside the main thread)."""
    import threading

    if seconds <= 0 or threading.current_thread() is not threading.main_thread():
        yield
        return

    def fire(_signum: int, _frame: Any) -> None:
        raise Hang

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextmanager
def _python_warnings(said: list[str]) -> Iterator[None]:
    """Python warnings raised during the run, as the lines a command line would print on stderr (pytest would
    otherwise swallow them into its own summary)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            yield
        finally:
            said.extend(warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught)


def run_cli(
    argv: Sequence[str],
    *,
    inputs: Sequence[Path] = (),
    outputs: Sequence[Path] = (),
    capfd: Any = None,
    timeout: float = DEFAULT_TIMEOUT_S,
) -> Run:
    """``monodock ARGV`` in this process: exit code, fd-level stdout/stderr, and the inputs before and after.

    With pytest's ``capfd`` the output is read from it; otherwise fds 1 and 2 are captured here.
    """
    import time

    from monodock.cli.main import main

    watched = [*inputs, *outputs]
    before = snapshot(watched)
    existed = {str(p): os.path.lexists(p) for p in outputs}
    code: int | None = None
    escaped = ""
    hung = False
    t0 = time.perf_counter()

    said: list[str] = []

    def call() -> None:
        nonlocal code, escaped, hung
        try:
            with _alarm(timeout), _python_warnings(said):
                try:
                    code = int(main(list(argv)))
                except SystemExit as exc:  # argparse's usage errors
                    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        except Hang:
            hung = True
        except BaseException:
            escaped = traceback.format_exc()

    if capfd is not None:
        capfd.readouterr()
        call()
        got = capfd.readouterr()
        out, err = got.out, got.err
    else:
        with capture_fds() as cap:
            call()
        out, err = cap["out"], cap["err"]
    seconds = time.perf_counter() - t0
    after = snapshot(watched)
    return Run(list(argv), code, out, "".join(said) + err, escaped, hung, seconds, before, after, existed)


def _csv_problems(path: Path, expect: Expect) -> list[tuple[str, str]]:
    """Silent-wrong findings in an EST.csv written on exit 0."""
    found: list[tuple[str, str]] = []
    rows = list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))))
    for r in rows:
        for key in ("x_m", "y_m", "yaw_deg", "reprojection_px", "tilt_deg"):
            v = r.get(key) or ""
            if v and not math.isfinite(float(v)):
                found.append(("silent wrong", f"{path.name}: {key}={v}"))
        if r.get("valid") != "true":
            continue
        if expect.refuse:
            found.append(
                (
                    "silent wrong",
                    f"valid=true row from an implausible input: x={r['x_m']} y={r['y_m']} yaw={r['yaw_deg']}",
                )
            )
        elif expect.truth is not None:
            from fuzz.world import TRUTH_TOLERANCE_DEG, TRUTH_TOLERANCE_M

            x, y, yaw = expect.truth
            dx, dy = float(r["x_m"]) - x, float(r["y_m"]) - y
            dyaw = (float(r["yaw_deg"]) - yaw + 180.0) % 360.0 - 180.0
            if abs(dx) > TRUTH_TOLERANCE_M or abs(dy) > TRUTH_TOLERANCE_M or abs(dyaw) > TRUTH_TOLERANCE_DEG:
                found.append(
                    (
                        "silent wrong",
                        f"{r['method']} x={r['x_m']} y={r['y_m']} yaw={r['yaw_deg']} (truth {x:.3f} {y:.3f} {yaw:.1f})",
                    )
                )
    return found


_NONFINITE_JSON = re.compile(rb"(?<![A-Za-z\"])(NaN|-?Infinity)(?![A-Za-z\"])")


def _file_problems(path: Path, expect: Expect) -> list[tuple[str, str]]:
    found: list[tuple[str, str]] = []
    size = path.stat().st_size
    if size > MAX_OUTPUT_BYTES:
        found.append(("silent wrong", f"{path.name} is {size / 1e6:.0f} MB"))
        return found
    data = path.read_bytes()
    if UNKNOWN_MARK.encode() in data:
        found.append(("silent wrong", f"unknown key copied into {path.name}"))
    if path.suffix == ".json" and _NONFINITE_JSON.search(data):
        found.append(("silent wrong", f"NaN/Infinity token in {path.name}"))
    if path.suffix == ".csv" and data.startswith(b"frame,stamp,method"):
        found += _csv_problems(path, expect)
    if path.name == "ground_truth.csv":
        for r in csv.DictReader(io.StringIO(data.decode("utf-8", "replace"))):
            for key, v in r.items():
                if key and key.endswith("yaw_deg") and v and not -180.0 <= float(v) <= 180.0:
                    found.append(("silent wrong", f"{path.name}: {key}={v} (not wrapped to +-180)"))
                    break
    if path.suffix in (".yaml", ".yml"):
        text = data.decode("utf-8", "replace")
        if re.search(r"(?<![\w])-?\.(nan|inf)\b", text, re.IGNORECASE):
            found.append(("silent wrong", f"non-finite number in {path.name}"))
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        meta = (pq.read_schema(path).metadata or {}).get(b"monodock", b"")
        if UNKNOWN_MARK.encode() in meta:
            found.append(("silent wrong", f"unknown key copied into {path.name}'s metadata"))
        if _NONFINITE_JSON.search(meta):
            found.append(("silent wrong", f"NaN/Infinity token in {path.name}'s metadata"))
    return found


def _outputs_problems(run: Run, expect: Expect) -> list[tuple[str, str]]:
    found: list[tuple[str, str]] = []
    for out in expect.outputs:
        if not out.exists() or run.existed.get(str(out)):
            continue
        files = [out] if out.is_file() else sorted(p for p in out.rglob("*") if p.is_file())
        for f in files:
            found += _file_problems(f, expect)
    return found


def _leftovers(expect: Expect) -> list[str]:
    """Hidden temp files or folders (``.NAME.*``) that an atomic write left beside an output."""
    left = []
    for out in expect.outputs:
        parent = out.parent
        if parent.is_dir():
            left += [p.name for p in parent.iterdir() if p.name.startswith(f".{out.name}.")]
    return left


def _exit_problems(run: Run, err_lines: list[str]) -> list[tuple[str, str]]:
    """How the run ended: a hang, an internal error, a traceback, a refusal of more than one clean line."""
    found: list[tuple[str, str]] = []
    if run.hung:
        found.append(
            ("hang", f"still running at its time limit (run {run.seconds:.0f} s; interrupted: 5 s after the signal)")
        )
    if run.escaped:
        last = run.escaped.strip().splitlines()[-1]
        found.append(("internal error", f"escaped (not a MonodockError): {last}"))
    elif run.code == 1 or (run.code not in (0, 2, None)):
        said = [line for line in err_lines if "internal error" in line]
        detail = (said or err_lines or [f"exit {run.code}"])[0]
        found.append(("internal error", f"exit {run.code}: {detail[:200]}"))
    if "Traceback" in run.err or "Traceback" in run.out:
        found.append(("traceback/noise", "a traceback"))
    if run.code == 2:
        good = [line for line in err_lines if _ONE_LINE.match(line) and "error::" not in line]
        if any(_TEMP_NAME.search(line) for line in err_lines):
            found.append(("traceback/noise", f"names a temporary path, not the user's: {err_lines[-1][:150]}"))
        if len(err_lines) != 1 or len(good) != 1:
            shown = " | ".join(line[:120] for line in err_lines[:3])
            found.append(("traceback/noise", f"{len(err_lines)} stderr lines: {shown}"))
    return found


def _success_problems(run: Run, expect: Expect, err_lines: list[str]) -> list[tuple[str, str]]:
    """A run that exited 0: library noise on stderr, an implausible input accepted, wrong outputs."""
    found: list[tuple[str, str]] = []
    noise = [line for line in err_lines if not line.startswith(("warning:", "note:", "monodock"))]
    if noise:
        found.append(("traceback/noise", f"library output on success: {noise[0][:120]}"))
    if expect.refuse:
        est = [o for o in expect.outputs if o.suffix == ".csv" and o.is_file()]
        if not (est and expect.implausible_ok_without_valid):
            found.append(("silent wrong", "accepted an implausible input (exit 0)"))
    return found + _outputs_problems(run, expect)


def _disk_problems(run: Run, expect: Expect) -> list[tuple[str, str]]:
    """What the run left on disk: outputs of a failed run, temporary files, inputs changed or replaced."""
    found: list[tuple[str, str]] = []
    if run.code != 0:
        for out in expect.outputs:
            if not run.existed.get(str(out)) and os.path.lexists(out):
                found.append(("half-written", f"{out.name} exists after a failed run"))
    for name in _leftovers(expect):
        found.append(("half-written", f"temporary {name} left behind"))
    for p in expect.inputs:
        if run.before.get(str(p)) != run.after.get(str(p)):
            found.append(
                ("input destroyed", f"{p.name} changed: {run.before.get(str(p))[:20]} -> {run.after.get(str(p))[:20]}")
            )
    for p in expect.outputs:
        b = run.before.get(str(p), "absent")
        if b.startswith("special:") and run.after.get(str(p)) != b:
            found.append(("input destroyed", f"{p.name} (not a regular file) was replaced"))
    return found


def judge(run: Run, expect: Expect) -> list[tuple[str, str]]:
    """Every way ``run`` broke the contract, as (kind, detail); empty when it held."""
    err_lines = [line for line in run.err.splitlines() if line.strip()]
    found = _exit_problems(run, err_lines)
    silent = [line for line in err_lines if line.startswith("silent: ")]
    if silent:
        found.append(("silent wrong", silent[0][8:]))
        err_lines = [line for line in err_lines if not line.startswith("silent: ")]
    if run.code == 0:
        found += _success_problems(run, expect, err_lines)
    found += _disk_problems(run, expect)
    # one finding per kind, first detail kept
    seen: dict[str, str] = {}
    for kind, detail in found:
        seen.setdefault(kind, detail)
    return list(seen.items())


def outcome(run: Run, expect: Expect) -> tuple[str, list[tuple[str, str]]]:
    """("clean refusal" | "ok" | "failed", findings)."""
    found = judge(run, expect)
    if found:
        return "failed", found
    return ("ok" if run.code == 0 else "clean refusal"), found


def dump(run: Run) -> str:
    """A run as text for an assertion message."""
    return json.dumps(
        {"argv": run.argv, "code": run.code, "stderr": run.err[-2000:], "escaped": run.escaped[-2000:]}, indent=1
    )


def run_library(call: Any, *, inputs: Sequence[Path] = (), timeout: float = DEFAULT_TIMEOUT_S) -> Run:
    """A library entry point judged like a command: returning is exit 0, a MonodockError is the one-line exit 2
    (``monodock lib: error: ...``, its text must be one line), any other exception escapes (an internal error).
    An AssertionError raised by ``call`` itself (a check on what it returned) counts as a silently wrong result.
    """
    import time

    from monodock.errors import MonodockError

    before = snapshot(inputs)
    noted: list[str] = []
    code: int | None = None
    err = ""
    escaped = ""
    hung = False
    t0 = time.perf_counter()
    with capture_fds() as cap:
        try:
            with _alarm(timeout), _python_warnings(noted):
                try:
                    call()
                    code = 0
                except MonodockError as exc:
                    code = 2
                    err = f"monodock lib: error: {exc}\n"
                except AssertionError as exc:
                    code = 0
                    err = f"silent: {exc}\n"
        except Hang:
            hung = True
        except BaseException:
            escaped = traceback.format_exc()
    err = "".join(noted) + cap["err"] + err
    run = Run(["<library>"], code, cap["out"], err, escaped, hung, time.perf_counter() - t0)
    run.before, run.after = before, snapshot(inputs)
    return run
