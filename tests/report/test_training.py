"""The training report (report.training): the papers' Tables 1-3 and plots for a trained result."""

from __future__ import annotations

from pathlib import Path

import pytest

from monodock.errors import InputError
from monodock.learning.train import TrainingResult
from monodock.report.training import training_tables, write_training_report
from shared import SET


def test_training_report_has_the_papers_tables_and_plots(result: TrainingResult, tmp_path: Path) -> None:
    files = write_training_report(tmp_path / "report", result, title="Training")
    assert [p.name for p in files] == ["training.md", f"training_{SET}_depth.png", f"training_{SET}_yaw.png"]
    text = files[0].read_text()
    assert text.startswith("# Training")
    for needle in ("Table 1", "Table 2", "Table 3", "**Avg**", "Random Forest", "40–45 cm", "245–250 cm", "(±1)"):
        assert needle in text
    for png in files[1:]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tables = training_tables(result)
    assert len(tables) == 3
    depth_models, segments, segment_models = tables.values()
    assert all(title.startswith(f"Table {i}") and SET in title for i, title in enumerate(tables, start=1))
    assert "★" in depth_models
    assert len(segments.splitlines()) == 2 + 45 + 1
    assert len(segment_models.splitlines()) == 2 + 45
    with pytest.raises(InputError, match="exists"):
        write_training_report(tmp_path / "report", result, title="Training")
    assert (
        write_training_report(tmp_path / "report", result, title="Again", force=True)[0]
        .read_text()
        .startswith("# Again")
    )
