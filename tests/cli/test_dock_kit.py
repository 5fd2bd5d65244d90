"""``monodock dock-kit``: the folder it writes, and its refusals (one line, exit 2, nothing written)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from monodock.cli.main import main
from monodock.core.layout import DockLayout
from monodock.core.settings import to_mapping


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err


def layout_file(folder: Path, **changes: object) -> Path:
    """The default layout as a file, with top-level keys changed or per-marker keys set (``center_size=...``)."""
    data = to_mapping(DockLayout.default())
    for key, value in changes.items():
        role, _, field = key.partition("_")
        if role in data["markers"]:
            data["markers"][role][field] = value
        else:
            data[key] = value
    path = folder / "layout.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_writes_both_papers_and_the_layout_and_replaces_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    layout = layout_file(tmp_path, right_size=0.09)
    out = tmp_path / "kit"
    code, printed, err = run(["dock-kit", "--layout", str(layout), "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["dock_kit_a4.pdf", "dock_kit_letter.pdf", "layout.yaml"]
    for pdf in ("dock_kit_a4.pdf", "dock_kit_letter.pdf"):
        assert (out / pdf).read_bytes().startswith(b"%PDF-")
    assert DockLayout.load(out / "layout.yaml") == DockLayout.load(layout)
    assert "100 %" in printed
    a4 = (out / "dock_kit_a4.pdf").read_bytes()

    code, _, err = run(["dock-kit", "--layout", str(layout), "--out", str(out)], capsys)
    assert_one_line_error(code, err, "exists", "--force")

    # Replaced whole: one paper asked for, one paper left; the same layout gives the same bytes.
    code, _, err = run(["dock-kit", "--layout", str(layout), "--out", str(out), "--paper", "a4", "--force"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["dock_kit_a4.pdf", "layout.yaml"]
    assert (out / "dock_kit_a4.pdf").read_bytes() == a4
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".kit.")]  # no temporary folder left


def test_a_missing_layout_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["dock-kit", "--layout", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "kit")], capsys)
    assert_one_line_error(code, err, "nope.yaml")
    assert not (tmp_path / "kit").exists()


def test_a_marker_too_large_for_the_paper_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    layout = layout_file(tmp_path, marker_size=0.18, left_y=0.3, right_y=-0.3)
    code, _, err = run(["dock-kit", "--layout", str(layout), "--out", str(tmp_path / "kit")], capsys)
    assert_one_line_error(code, err, "marker left", "180.0 mm", "A4", "printable area is 190 x 277 mm")
    assert not (tmp_path / "kit").exists()


def test_with_both_papers_a_kit_that_fits_only_letter_is_refused_saying_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 13.4 cm of DICT_4X4_50 with its margins: 186.7 mm, wider than A4's room for it (184 mm), narrower than
    # Letter's (189.9 mm).
    layout = layout_file(tmp_path, center_size=0.134)
    code, _, err = run(["dock-kit", "--layout", str(layout), "--out", str(tmp_path / "kit")], capsys)
    assert_one_line_error(code, err, "marker center", "134.0 mm", "A4", "fits on Letter", "--paper letter")
    assert not (tmp_path / "kit").exists()
