"""The docking config file: a round trip keeps every field, a partial file sets only its keys, and every bad
value or key is refused with one line naming the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from monodock.core import settings
from monodock.core.settings import settings_of
from monodock.dock.config import DockingConfig, docking_config_to_dict, load_docking_config, save_docking_config
from monodock.errors import ConfigError


def _write(tmp_path: Path, data: object) -> Path:
    path = tmp_path / "docking.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_a_saved_config_loads_back_equal_and_refuses_to_overwrite(tmp_path: Path) -> None:
    config = settings.replace(DockingConfig(), approach_speed=0.08, max_retries=4, acquire=False)
    path = tmp_path / "docking.yaml"
    save_docking_config(config, path)
    assert load_docking_config(path) == config
    names = (Path(__file__).parents[1] / "data" / "settings" / "docking_names.txt").read_text(encoding="utf-8")
    assert set(yaml.safe_load(path.read_text())) == {name.split(".")[0] for name in names.split()}
    with pytest.raises(Exception, match="exists"):
        save_docking_config(DockingConfig(), path)


def test_a_partial_file_sets_only_its_keys_nested_ones_included(tmp_path: Path) -> None:
    path = _write(tmp_path, {"k_lateral": 3, "planner": {"standoff": 0.8}, "track": {"odometry": {"track_width": 0.5}}})
    config = load_docking_config(path)
    default = DockingConfig()
    assert config.approach.k_lateral == 3.0
    assert isinstance(config.approach.k_lateral, float)
    assert config.planner.standoff == 0.8
    assert config.planner.arrive_tolerance == default.planner.arrive_tolerance
    assert config.track.odometry.track_width == 0.5
    assert config.track.gate_chi2 == default.track.gate_chi2
    changed = {k for k, v in docking_config_to_dict(config).items() if v != docking_config_to_dict(default)[k]}
    assert changed == {"k_lateral", "planner", "track"}


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"k_laterl": 3.0}, r"docking.yaml: k_laterl: unknown key \(known: planner, control_period"),
        ({"planner": {"standof": 1.0}}, r"docking.yaml: planner.standof: unknown key"),
        ({"cruise_speed": "fast"}, r"docking.yaml: cruise_speed: expected a number, got 'fast'"),
        ({"cruise_speed": float("nan")}, r"docking.yaml: cruise_speed: expected a finite number"),
        ({"cruise_speed": -0.1}, r"docking.yaml: cruise_speed: must be within 0 to 10000, got -0.1"),
        ({"cruise_speed": 0.0}, r"docking.yaml: cruise_speed: must be positive, got 0.0"),
        ({"cruise_speed": 1e300}, r"docking.yaml: cruise_speed: must be within 0 to 10000, got 1e\+300"),
        (
            {"max_retries": 10**40},
            r"docking.yaml: max_retries: must be at most 1000, got an integer of about 41 digits",
        ),
        ({"min_speed": 0.5}, r"docking.yaml: min_speed: min_speed must not exceed approach_speed"),
        ({"max_retries": 1.5}, r"docking.yaml: max_retries: expected an integer, got 1.5"),
        ({"max_retries": -1}, r"docking.yaml: max_retries: must be at least 0"),
        ({"acquire": "yes"}, r"docking.yaml: acquire: expected true or false, got 'yes'"),
        ({"planner": 3}, r"docking.yaml: planner: expected a mapping, got int"),
        ({"planner": {"standoff": 0}}, r"docking.yaml: planner.standoff: the stand-off of Point A must be positive"),
        ([1, 2], r"expected a YAML mapping at the top level"),
    ],
)
def test_bad_values_and_keys_are_refused_naming_the_key(tmp_path: Path, data: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        load_docking_config(_write(tmp_path, data))
    assert "\n" not in str(info.value)


def test_dock_sim_runs_with_a_config_file_and_reports_its_tolerances(tmp_path: Path) -> None:
    """The tolerances are settings: a file that widens the heading tolerance to the papers' 3.07 deg is what the
    summary states; a flag given beside it wins; a bad file is one line and exit 2 before anything runs."""
    import json

    from monodock.cli.main import main

    config = _write(tmp_path, {"tolerance_heading_deg": 3.07, "planner": {"standoff": 0.8}})
    out = tmp_path / "run"
    argv = ["dock-sim", "--cases", "1", "--trials", "1", "--method", "board", "--jobs", "1", "--out", str(out)]
    assert main([*argv, "--config", str(config), "--standoff", "0.9", "--planner", "papers"]) == 0
    settings = json.loads((out / "summary.json").read_text())["settings"]
    assert settings["tolerances"]["heading_deg"] == 3.07
    assert settings["tolerances"]["lateral_cm"] == 2.0  # the file left it alone
    assert settings["standoff_m"] == 0.9
    assert settings["planner"] == "papers"

    bad = tmp_path / "bad.yaml"
    bad.write_text("tolerance_heading: 3\n", encoding="utf-8")
    assert main([*argv[:-1], str(tmp_path / "run2"), "--config", str(bad)]) == 2
    assert not (tmp_path / "run2").exists()


def test_every_setting_is_documented_as_declared() -> None:
    """docs/docking.md's config table has a row per setting, whose unit, default and words are
    the declaration's (a new setting is one declaration and this row)."""
    docs = Path(__file__).parents[2] / "docs"
    rows = {}
    for line in (docs / "docking.md").read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0].startswith("`") and cells[0].endswith("`"):
            rows[cells[0].strip("`")] = cells
    declared = settings_of(DockingConfig)
    assert set(rows) == {s.key for s in declared}
    for s in declared:
        _, unit, documented, what = rows[s.key]
        assert unit == (s.meta.unit or "–"), s.key
        assert what == s.meta.help, s.key
        if isinstance(s.default, bool):
            assert documented == str(s.default).lower(), s.key
        elif isinstance(s.default, (int, float)):
            assert float(documented) == pytest.approx(float(s.default)), s.key
        else:
            assert documented == str(s.default), s.key


def test_the_shipped_example_is_every_default() -> None:
    docs = Path(__file__).parents[2] / "docs"
    assert load_docking_config(docs / "docking.yaml") == DockingConfig()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--planner", "papers,foo"], "unknown planner 'foo'"),
        (["--faults", "all,occlusion"], "'all' stands alone"),
        (["--faults", "rain"], "unknown fault 'rain'"),
        (["--frame-drop-rate", "2"], "must be within 0-1"),
        (["--exposure", "-1"], "--exposure: must be a number in [0, 1), got -1"),
        (["--exposure", "0.1"], "--exposure must be within 0 and one frame"),
    ],
)
def test_dock_sim_refuses_bad_docking_options_in_one_line(
    args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from monodock.cli.main import main

    try:
        code = main(["dock-sim", "--method", "board", *args])
    except SystemExit as exc:  # argparse's usage errors exit; monodock's own return 2
        code = exc.code  # type: ignore[assignment]
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert says in err[0]
