"""The lock file CI and the quick start install: it pins every package pyproject.toml asks for, inside its range.

A dependency added to pyproject.toml without a refreshed lock would be installed floating by `pip install -c`
(a constraints file only constrains what it names): this test catches it before CI's green run can hide it.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]


def _pins() -> dict[str, str]:
    text = (ROOT / "requirements" / "lock.txt").read_text(encoding="utf-8")
    pins = {}
    for line in text.splitlines():
        m = re.fullmatch(r"([A-Za-z0-9_.\-]+)==(\S+)", line.strip())
        if m:
            pins[canonicalize_name(m[1])] = m[2]
    return pins


def _requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    wanted = [*project["dependencies"], *(r for extra in project["optional-dependencies"].values() for r in extra)]
    return [r for r in map(Requirement, wanted) if canonicalize_name(r.name) != "monodock"]


def test_every_requirement_is_pinned_inside_its_range() -> None:
    pins = _pins()
    missing = [str(r) for r in _requirements() if canonicalize_name(r.name) not in pins]
    outside = [
        f"{r} (locked {pins[canonicalize_name(r.name)]})"
        for r in _requirements()
        if canonicalize_name(r.name) in pins
        and not r.specifier.contains(pins[canonicalize_name(r.name)], prereleases=True)
    ]
    assert missing == [], "not in requirements/lock.txt: run bash requirements/refresh"
    assert outside == [], "locked outside pyproject.toml's range: run bash requirements/refresh"


def test_every_line_of_the_lock_is_an_exact_pin() -> None:
    lines = [
        s
        for s in (line.strip() for line in (ROOT / "requirements" / "lock.txt").read_text().splitlines())
        if s and not s.startswith("#")
    ]
    assert len(lines) > 100  # ROS 2's wheels alone are dozens
    assert [s for s in lines if not re.fullmatch(r"[A-Za-z0-9_.\-]+(\[[^\]]+\])?==\S+", s)] == []


def test_ci_and_the_quick_start_install_the_lock() -> None:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert '-c requirements/lock.txt -e ".[test]"' in ci
    assert re.search(r"pip install -c requirements/lock\.txt -e \"\.\[test\]\" && \.venv/bin/python -m pytest", readme)
    assert re.search(r"^uv==\S+$", (ROOT / "requirements" / "tools.txt").read_text(), flags=re.M)
