"""The docs do what they say: every ``monodock`` command in them parses, every link resolves, and the user
guide's scripting example runs and finds the dock where the simulator put it."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import cv2
import numpy as np
import pytest

from monodock.cli.main import parser
from monodock.core.pose import DockPose
from monodock.sim import Simulator

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "bench" / "README.md"]


def _blocks(page: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)


def _commands(page: Path) -> list[str]:
    """The ``monodock ...`` command lines of a page's bash blocks, continuation lines joined."""
    out = []
    for block in _blocks(page, "bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words: list[str] = []
            for token in [*shlex.split(line, comments=True), ";"]:
                if token in ("&&", "||", "|", ";", "&"):  # one command of a pipeline or chain
                    if words and Path(words[0]).name == "monodock":
                        out.append(shlex.join(words[1:]))
                    words = []
                else:
                    words.append(token)
    return out


def test_every_monodock_command_in_the_docs_parses() -> None:
    commands = [(page.name, c) for page in PAGES for c in _commands(page)]
    assert len(commands) > 30  # the docs show every command
    bad = []
    for name, command in commands:
        with contextlib.redirect_stderr(io.StringIO()) as err, contextlib.redirect_stdout(io.StringIO()):
            try:
                parser().parse_args(shlex.split(command))
            except SystemExit as exc:  # --help exits 0; a usage error exits 2
                if exc.code != 0:
                    bad.append(f"{name}: monodock {command}: {err.getvalue().strip()}")
    assert bad == []


def test_every_relative_link_in_the_docs_resolves() -> None:
    broken = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.name}: {target}")
    assert broken == []


def test_the_scripting_example_finds_the_dock(work: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The user guide's example, as written, on a frame the simulator rendered with the bundle's set-up."""
    (example,) = [b for b in _blocks(ROOT / "docs" / "user-guide.md", "python") if "make_estimator" in b]
    truth = DockPose(1.3, 0.08, np.radians(8.0))
    sim = Simulator(seed=4)
    assert cv2.imwrite(str(tmp_path / "frame.png"), sim.frame(truth, 0.0, np.random.default_rng(4)).image)
    (tmp_path / "demo_report").symlink_to(work)
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(example, "user-guide.md", "exec"), {})
    found = re.fullmatch(r"dock (\S+) m ahead, (\S+) m left, yaw (\S+) deg\n", out.getvalue())
    assert found, out.getvalue()
    x, y, yaw = (float(v) for v in found.groups())
    assert abs(x - truth.x) < 0.01
    assert abs(y - truth.y) < 0.01
    assert abs(yaw - truth.yaw_deg) < 0.5
