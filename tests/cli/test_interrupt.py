"""Interruption, full disks and output paths (issue 18, item 4): real processes sent SIGINT/SIGTERM mid-work
stop within 5 s with one line and no traceback, leave nothing at the final path, no temp folder and no worker;
an output that is an input, a device, a FIFO or a socket is refused even with --force."""

from __future__ import annotations

import errno
import os
import signal
import socket
import stat
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

import monodock
from monodock.cli.main import main
from monodock.core import atomic
from monodock.core.atomic import atomic_directory, check_writable, write_bytes_atomic
from monodock.errors import InputError
from monodock.learning import pipeline
from monodock.sim import Nuisances, Simulator
from shared import pose_at

SRC = str(Path(monodock.__file__).resolve().parents[1])


# --- processes -------------------------------------------------------------------------------------------


def _children(pid: int) -> list[int]:
    out = []
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat_file.read_text()
        except OSError:
            continue
        if int(text[text.rfind(")") + 2 :].split()[1]) == pid:
            out.append(int(stat_file.parent.name))
    return out


def _descendants(pid: int) -> list[int]:
    todo, seen = [pid], []
    while todo:
        for c in _children(todo.pop()):
            seen.append(c)
            todo.append(c)
    return seen


def _alive(pid: int) -> bool:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return text[text.rfind(")") + 2] != "Z"


def _start(argv: list[str], err: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([SRC, os.environ.get("PYTHONPATH", "")])}
    with err.open("wb") as fh:
        # A session of its own: a signal to the group is what Ctrl-C in a terminal sends (workers get it too).
        return subprocess.Popen(
            [sys.executable, "-m", "monodock.cli.main", *argv],
            stdout=subprocess.DEVNULL,
            stderr=fh,
            env=env,
            start_new_session=True,
        )


def _wait_for(condition: object, proc: subprocess.Popen[bytes], timeout: float = 120.0) -> None:
    t0 = time.monotonic()
    while not condition():  # type: ignore[operator]
        assert proc.poll() is None, "the command ended before it could be interrupted"
        assert time.monotonic() - t0 < timeout, "the work never started"
        time.sleep(0.05)


def _has_open(pid: int, folder: Path) -> bool:
    """Whether the process has a file in ``folder`` open."""
    try:
        return any(os.readlink(fd).startswith(str(folder)) for fd in Path(f"/proc/{pid}/fd").iterdir())
    except OSError:
        return False


def _temps(out: Path) -> list[Path]:
    return list(out.parent.glob(f".{out.name}.*"))


def _interrupt_and_check(proc: subprocess.Popen[bytes], sig: int, group: bool, out: Path, err: Path) -> None:
    workers = _descendants(proc.pid)
    t0 = time.monotonic()
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    try:
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    took = time.monotonic() - t0
    # Workers die with the parent; resource trackers leave when its pipe closes: a moment after.
    deadline = time.monotonic() + 5.0
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [w for w in workers if _alive(w)]
    for w in left:
        os.kill(w, signal.SIGKILL)
    text = err.read_text(errors="replace")
    assert code == (143 if sig == signal.SIGTERM else 130), text
    assert took <= 5.0, f"{took:.1f} s from the signal to the exit"
    assert "Traceback" not in text
    assert len(text.strip().splitlines()) == 1, text
    assert ("terminated" if sig == signal.SIGTERM else "interrupted") in text
    assert not out.exists()
    assert _temps(out) == []
    assert left == [], "worker processes outlived the command"


@pytest.mark.parametrize(("sig", "group"), [(signal.SIGINT, True), (signal.SIGTERM, False)])
def test_simulate_with_workers_stops_cleanly(sig: int, group: bool, tmp_path: Path) -> None:
    """SIGTERM used to kill it at once, leaving the hidden .OUT.<random> folder of frames and orphan workers."""
    out, err = tmp_path / "frames", tmp_path / "err.txt"
    proc = _start(["simulate", "--out", str(out), "--frames", "400", "--jobs", "2"], err)
    # Rendering has started: the temp folder exists and the two workers are up.
    _wait_for(lambda: _temps(out) and len(_descendants(proc.pid)) >= 2, proc)
    time.sleep(1.0)
    _interrupt_and_check(proc, sig, group, out, err)


@pytest.mark.parametrize(("sig", "group"), [(signal.SIGINT, True), (signal.SIGTERM, False)])
def test_train_with_loky_workers_stops_cleanly(sig: int, group: bool, work: Path, tmp_path: Path) -> None:
    """Ctrl-C during train --jobs 2 hung in 2 of 7 tries, with tracebacks from the loky workers."""
    out, err = tmp_path / "bundle", tmp_path / "err.txt"
    argv = ["train", str(work / "train.parquet"), "--out", str(out), "--jobs", "2", "--trials", "60"]
    proc = _start(argv, err)
    # The bundle's temp folder exists (training is inside it) and the loky workers are up.
    _wait_for(lambda: _temps(out) and len(_descendants(proc.pid)) >= 3, proc)
    time.sleep(1.5)
    _interrupt_and_check(proc, sig, group, out, err)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_dock_sim_with_workers_stops_cleanly(sig: int, tmp_path: Path) -> None:
    out, err = tmp_path / "report", tmp_path / "err.txt"
    argv = ["dock-sim", "--method", "board", "--cases", "1", "--trials", "40", "--jobs", "2", "--out", str(out)]
    proc = _start([*argv, "--supersample", "2"], err)
    _wait_for(lambda: len(_descendants(proc.pid)) >= 3, proc)  # the resource tracker and two workers
    time.sleep(1.0)
    _interrupt_and_check(proc, sig, sig == signal.SIGINT, out, err)


def test_label_stops_cleanly_on_sigterm(work: Path, tmp_path: Path) -> None:
    """One process, no pool: SIGTERM is an exception like Ctrl-C, so nothing is half-written."""
    out, err = tmp_path / "ds.parquet", tmp_path / "err.txt"
    rec = work / "train_rec"
    proc = _start(["label", str(rec), "--layout", str(work / "layout.yaml"), "--out", str(out)], err)
    _wait_for(lambda: _has_open(proc.pid, rec), proc)  # reading the recording (for a second or two)
    _interrupt_and_check(proc, signal.SIGTERM, False, out, err)


# --- a full disk -----------------------------------------------------------------------------------------


def _full_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every atomic file write fails as on a full disk."""
    real = os.fdopen

    class Full:
        def __init__(self, fh: object) -> None:
            self.fh = fh

        def __enter__(self) -> Full:
            return self

        def __exit__(self, *exc: object) -> None:
            self.fh.close()  # type: ignore[attr-defined]

        def write(self, _data: bytes) -> int:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fdopen", lambda fd, mode: Full(real(fd, mode)))


def test_full_disk_while_training_leaves_nothing(
    work: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The bundle is assembled beside its final path: a full disk half-way through its report leaves nothing."""
    out = tmp_path / "bundle"
    real = pipeline.train  # one model type only: seconds, not minutes, before the bundle's files are written
    monkeypatch.setattr(pipeline, "train", lambda sets, cfg, **kw: real(sets, replace(cfg, models=("ridge",)), **kw))
    _full_disk(monkeypatch)
    argv = ["train", str(work / "train.parquet"), "--out", str(out), "--trials", "1", "--jobs", "1", "--sets", "m2"]
    code = main([*argv, "--fusion-holdout", "0"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "No space left on device" in err
    assert str(out) in err  # the user's path, not the temp folder's
    assert ".bundle." not in err
    assert not out.exists()
    assert _temps(out) == []


def test_full_disk_names_the_output_and_keeps_the_old_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    old = tmp_path / "report"
    old.mkdir()
    (old / "keep.txt").write_text("old")
    _full_disk(monkeypatch)
    with pytest.raises(OSError, match="No space") as info, atomic_directory(old, force=True) as tmp:
        write_bytes_atomic(tmp / "sub" / "figure.png", b"png")
    assert info.value.errno == errno.ENOSPC
    assert info.value.filename == str(old / "sub" / "figure.png")
    assert (old / "keep.txt").read_text() == "old"
    assert _temps(old) == []
    with pytest.raises(OSError, match="No space") as info:
        write_bytes_atomic(tmp_path / "a.csv", b"x")
    assert info.value.filename == str(tmp_path / "a.csv")
    assert list(tmp_path.glob(".a.csv.*")) == []


# --- output paths ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def image_and_calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("show")
    sim = Simulator(nuisances=Nuisances.clean(), seed=1)
    frame = sim.frame(pose_at(0.8, 0.05, 5.0), 0.0, np.random.default_rng(0))
    cv2.imwrite(str(folder / "frame.png"), frame.image)
    sim.camera.save(folder / "camera.yaml")
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return folder


def _show(folder: Path, out: Path | str, image: Path | None = None) -> list[str]:
    cal = [f"--{k}={folder / f'{k}.yaml'}" for k in ("camera", "layout", "robot")]
    return ["show", str(image or folder / "frame.png"), "--out", str(out), "--force", *cal]


def _one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err


@pytest.mark.parametrize("which", ["image", "camera", "layout", "robot", "symlink", "hardlink", "folder"])
def test_output_that_is_an_input_is_refused_even_with_force(
    which: str, image_and_calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = image_and_calibration
    image = tmp_path / "frame.png"
    image.write_bytes((folder / "frame.png").read_bytes())
    out: Path = {
        "image": image,
        "camera": folder / "camera.yaml",
        "layout": folder / "layout.yaml",
        "robot": folder / "robot.yaml",
        "symlink": tmp_path / "link.png",
        "hardlink": tmp_path / "hard.png",
        "folder": tmp_path,  # replacing the folder would delete the image in it
    }[which]
    if which == "symlink":
        out.symlink_to(image)
    if which == "hardlink":
        os.link(image, out)
    before = {p: p.read_bytes() for p in (image, *(folder / f"{k}.yaml" for k in ("camera", "layout", "robot")))}
    code = main(_show(folder, out, image))
    _one_line(code, capsys.readouterr().err, str(out), "input", "even with --force")
    assert {p: p.read_bytes() for p in before} == before
    assert not list(tmp_path.glob(".*"))
    assert not list(folder.glob(".*"))


def test_train_out_equal_to_its_dataset_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "ds.parquet"
    data.write_bytes(b"not read: the output is checked first")
    code = main(["train", str(data), "--out", str(tmp_path / "." / "ds.parquet"), "--force"])
    _one_line(code, capsys.readouterr().err, "it is the input", "even with --force")
    assert data.read_bytes() == b"not read: the output is checked first"


def _special_files(tmp_path: Path) -> dict[str, Path]:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock = tmp_path / "sock"
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(sock))
    server.close()
    files = {"fifo": fifo, "socket": sock}
    device = tmp_path / "null"
    try:
        os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        files["device"] = device
    except (PermissionError, OSError):
        pass
    return files


def test_special_files_as_output_are_refused_even_with_force(
    image_and_calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for kind, path in _special_files(tmp_path).items():
        mode = path.lstat().st_mode
        code = main(_show(image_and_calibration, path))
        _one_line(code, capsys.readouterr().err, str(path), "not a regular file")
        assert path.lstat().st_mode == mode, f"the {kind} was replaced"
    assert not list(tmp_path.glob(".*"))


def test_check_writable_refuses_dev_null_and_accepts_it_for_a_stream() -> None:
    # Only checked, never written: a regression must fail here, not replace the machine's /dev/null.
    with pytest.raises(InputError, match="character device"):
        check_writable("/dev/null", force=True)
    assert check_writable("/dev/null", force=False, stream=True) == Path("/dev/null")
    with pytest.raises(InputError, match="it is the input"):
        check_writable("/dev/null", force=True, inputs=("/dev/null",))
