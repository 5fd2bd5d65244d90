"""core.records: dataclasses to their files' mappings and back, by the fields' types; old files stay readable."""

from __future__ import annotations

import enum
import json
from collections.abc import Mapping
from dataclasses import dataclass, field

import pytest

from monodock.core.records import file_key, from_record, to_record
from monodock.core.settings import setting
from monodock.errors import InputError


class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclass(frozen=True)
class Inner:
    a: float
    b: float | None


@dataclass(frozen=True)
class Outer:
    name: str
    colour: Colour
    span: tuple[int, int]
    inner: Inner
    by_case: Mapping[int, Inner]
    spread: Inner = field(metadata=file_key(""))
    total: int = setting(0, key="counts.total")  # the settings' key model, as file_key's
    most: int = field(default=0, metadata=file_key("counts.most"))
    tags: tuple[str, ...] = ()
    flag: bool = False


def _outer() -> Outer:
    return Outer(
        name="x",
        colour=Colour.BLUE,
        span=(25, 50),
        inner=Inner(1.5, None),
        by_case={3: Inner(0.25, 2.0)},
        spread=Inner(7.0, 8.0),
        total=4,
        most=2,
        tags=("p", "q"),
        flag=True,
    )


def test_a_record_has_the_files_layout_and_reads_back_equal() -> None:
    outer = _outer()
    record = to_record(outer)
    assert record == {
        "name": "x",
        "colour": "blue",
        "span": [25, 50],
        "inner": {"a": 1.5, "b": None},
        "by_case": {"3": {"a": 0.25, "b": 2.0}},
        "a": 7.0,  # the spread dataclass's keys sit beside its parent's
        "b": 8.0,
        "counts": {"total": 4, "most": 2},
        "tags": ["p", "q"],
        "flag": True,
    }
    back = from_record(Outer, json.loads(json.dumps(record)))
    assert back == outer
    assert isinstance(back.colour, Colour)
    assert list(back.by_case) == [3]  # JSON's string keys come back as the field's int keys


def test_a_file_written_before_a_field_existed_reads_with_its_default() -> None:
    record = to_record(_outer())
    del record["counts"], record["tags"], record["flag"]
    back = from_record(Outer, record)
    assert (back.total, back.most, back.tags, back.flag) == (0, 0, (), False)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda r: r.pop("name"), "Outer: 'name' is missing"),
        (lambda r: r["inner"].pop("a"), "Outer.inner: 'a' is missing"),
        (lambda r: r.update(colour="green"), "Outer.colour: unknown value 'green'"),
        (lambda r: r.update(span=[1, 2, 3]), "Outer.span: expected 2 values, got 3"),
        (lambda r: r["inner"].update(a="1.5"), "Outer.inner.a: expected a number, got '1.5'"),
        (lambda r: r.update(flag=1), "Outer.flag: expected true or false, got 1"),
        (lambda r: r["counts"].update(total=True), "Outer.counts.total: expected an integer, got True"),
        (lambda r: r.update(by_case={"three": {"a": 1.0, "b": None}}), "Outer.by_case: expected an integer key"),
        (lambda r: r.update(by_case={"3": {"a": 1.0, "b": None}, "4": {"a": "x", "b": None}}), "Outer.by_case.4.a:"),
        (lambda r: r["counts"].update(total="4"), "Outer.counts.total: expected an integer, got '4'"),
        (lambda r: r.update(inner=[1.0]), "Outer.inner: expected a mapping, got list"),
    ],
)
def test_a_bad_record_is_one_line_naming_the_key(change: object, message: str) -> None:
    record = to_record(_outer())
    change(record)  # type: ignore[operator]
    with pytest.raises(InputError) as err:
        from_record(Outer, record)
    assert str(err.value).startswith(message)
    assert "\n" not in str(err.value)


def test_a_dock_sim_summary_from_before_issue_16_reads_with_zero_counts() -> None:
    """A summary.json as written before the charging, redock and fault counts (and the papers' planner) existed."""
    from monodock.evaluation.dock_results import DockSimSummary

    group = {
        "runs": 2,
        "successes": 2,
        "success_rate": 1.0,
        **{k: {"mean": 0.1, "median": 0.1, "p95": 0.2, "max": 0.2} for k in ("final_lateral_cm", "time_s")},
        **{k: {"mean": None, "median": None, "p95": None, "max": None} for k in ("final_longitudinal_cm",)},
        "final_heading_deg": {"mean": 0.3, "median": 0.3, "p95": 0.4, "max": 0.4},
        "retries": {"total": 1, "max": 1},
        "impact_speed_mps": {"mean": None, "median": None, "p95": None, "max": None},
        "case_agreement": 1.0,
        "failures": {},
    }
    block = {"frames": 0, "filtered": None, "single_frame": None, "coasting_frames": 0, "coasting": None}
    old = {
        "method": "board",
        "methods": {"board": {"overall": group, "cases": {"1": group}}},
        "filter": {
            "board": {
                "bands": [{"depth_cm": [25, 50], **block, "nees_mean": None}],
                "all": {**block, "nees_mean": 3.1},
                "under_25cm": {**block, "nees_mean": None},
            }
        },
        "settings": {
            "trials_per_case": 1,
            "seed": 0,
            "distance_m": [1.0, 2.5],
            "max_heading_deg": 30.0,
            "standoff_m": 1.0,
            "tolerances": {"lateral_cm": 2.0, "longitudinal_cm": 2.0, "heading_deg": 3.07},
            "camera_rate_hz": 15.0,
            "supersample": 4,
        },
        "speed": {
            "runs": 2,
            "wall_s_per_run": 4.0,
            "render_s_per_run": 2.0,
            "perceive_s_per_run": 1.0,
            "frames_per_run": 200.0,
        },
    }
    summary = DockSimSummary.from_json(json.dumps(old))
    board = summary.methods["board"]
    assert board.overall.retries_total == 1
    assert (board.overall.charging, board.overall.redock_tried, board.overall.recoveries_total) == (0, 0, 0)
    assert board.executed == {}
    assert summary.settings.planner == "monodock"
    assert summary.filter["board"].all.nees_mean == 3.1
    assert summary.filter["board"].bands[0].depth_cm == (25, 50)


class Side(enum.Enum):
    LEFT = "left"
    RIGHT = "right"


@dataclass(frozen=True)
class Keyed:
    by_side: Mapping[Side, int]
    count: int
    ratio: float


def test_enum_keys_whole_floats_and_nan_round_trip() -> None:
    """Enum keys are written by value; an integer written as 2.0 by another tool reads; NaN is null and back."""
    keyed = Keyed({Side.LEFT: 1, Side.RIGHT: 2}, 3, float("nan"))
    record = to_record(keyed)
    assert record["by_side"] == {"left": 1, "right": 2}
    from monodock.core.config import json_text

    back = from_record(Keyed, json.loads(json_text({**record, "count": 3.0})))
    assert back.by_side == keyed.by_side
    assert back.count == 3
    assert back.ratio != back.ratio  # NaN


def test_a_type_the_converter_does_not_know_is_a_programming_error() -> None:
    @dataclass(frozen=True)
    class Odd:
        either: int | str

    @dataclass(frozen=True)
    class Spread:
        rest: Mapping[str, int] = field(metadata=file_key(""))

    with pytest.raises(TypeError):
        from_record(Odd, {"either": 1})
    with pytest.raises(TypeError):
        from_record(Spread, {"a": 1})
