"""The training report (report.training): the papers' Tables 1-3 and plots for a trained result."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.learning.train import TrainConfig, TrainingResult, TrainingSet, train
from monodock.report.training import training_tables, write_training_report

SET = "m1m2m3"


FEATURES = ("size", "ratio", "noise_a", "noise_b")


def synthetic_set(seed: int = 0) -> TrainingSet:
    """Rows from a known function: depth = 60 / size, yaw linear in a ratio whose slope grows with depth.

    Depths cover 25-60 cm (segments 0-6), with segment 3 nearly empty; farther segments have no rows.
    """
    rng = np.random.default_rng(seed)
    per_segment = [70, 70, 70, 10, 70, 70, 70]
    depth = np.concatenate([rng.uniform(0.25 + 0.05 * k, 0.30 + 0.05 * k, n) for k, n in enumerate(per_segment)])
    n = len(depth)
    yaw = rng.uniform(-30.0, 30.0, n)
    size = 60.0 / depth + rng.normal(0.0, 0.2, n)
    ratio = yaw * (0.01 + 0.02 * depth) + rng.normal(0.0, 0.01, n)
    X = np.column_stack([size, ratio, rng.normal(size=n), 50.0 * rng.normal(size=n)])
    return TrainingSet(SET, FEATURES, X, depth + rng.normal(0.0, 0.003, n), yaw, depth)


@pytest.fixture(scope="module")
def data() -> TrainingSet:
    return synthetic_set()


@pytest.fixture(scope="module")
def result(data: TrainingSet) -> TrainingResult:
    return train([data], TrainConfig(trials=2, jobs=1, seed=3), progress=False)


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
