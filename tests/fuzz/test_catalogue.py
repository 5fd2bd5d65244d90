"""The hostile-input catalogue (``catalogue.py``), one test per case: each input is refused with one line and exit
2, or accepted with sane outputs, never an internal error, a traceback, a silently wrong number, a hang, a
half-written output or an input destroyed. The default run takes the issue's examples and every third other case
(``in_default_run``); the rest, the heavy cases and the interruptions (subprocesses) are marked slow."""

from __future__ import annotations

from pathlib import Path

import pytest

from fuzz.catalogue import CASES, Case, in_default_run, run_case
from fuzz.harness import dump, outcome
from fuzz.world import World


def _param(c: Case) -> object:
    """The issue's examples and every third other case in the default run; all of them with ``-m slow``."""
    return pytest.param(c, id=c.id, marks=[] if in_default_run(c) else [pytest.mark.slow, pytest.mark.timeout(180)])


@pytest.mark.timeout(90)
@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_hostile_input(case: Case, world: World, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    run, expect = run_case(case, world, tmp_path / "case", capfd=capfd if case.library is None else None)
    verdict, found = outcome(run, expect)
    assert not found, f"{case.family} / {case.name}: " + "; ".join(f"{k}: {d}" for k, d in found) + "\n" + dump(run)
    assert verdict in ("ok", "clean refusal")


def test_catalogue_covers_every_family_and_the_issue_examples() -> None:
    families = {c.family for c in CASES}
    from fuzz.catalogue import FAMILIES

    assert families == set(FAMILIES)
    names = " ".join(c.name for c in CASES)
    for example in (
        "header 60000x60000 (issue)",
        "16-bit PNG (issue: putText)",
        "non-UTF-8 file name (issue)",
        "k1 1e6 (issue: valid poses 49 m away, truth 1.85 m)",
        "yaml cx=.nan (issue: 'no PnP solution' instead of naming the file)",
        "marker_size 1e-300 (issue)",
        "y 1e308 (issue)",
        "simulate --seed -1 (issue)",
        "simulate --depth 1 inf (issue)",
        "simulate --gamma 0 (issue)",
        "camera-rate 1e-9 (issue)",
        "without metadata.layout (issue: KeyError)",
        "nested arrays 100,000 deep (issue)",
        "5,000-digit number (issue)",
        "metadata not JSON (issue)",
        "metadata a list (issue)",
        "a string column (issue)",
        "no rows (issue)",
        "garbage scans.npz (issue: BadZipFile)",
        "alias bomb in an unknown key, label (issue: expanded into the dataset)",
        "camera mount x 1e308 m (issue)",
        "camera pitch 1e300 rad (issue)",
        "unsealed camera mount moved 1 m (issue)",
        "simulate --yaw 1000 2000 (issue: unwrapped yaws)",
        "camera_info 1280x960, images 640x480 (issue: 0 rows labelled, exit 0)",
        "SIGTERM during simulate (issue: hidden .OUT.* folder left)",
        "--out = the input image --force (issue)",
        "--out a FIFO --force (issue: device node)",
        "(issue: checked only after training)",
    ):
        assert example in names, example
