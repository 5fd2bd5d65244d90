"""core.settings: one declaration per setting, read, written, flattened and replaced as declared."""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import pytest

from monodock.core.config import Fields, yaml_text
from monodock.core.settings import (
    Policy,
    check_fields,
    flat,
    from_flat,
    from_mapping,
    inherited,
    nested,
    replace,
    section,
    setting,
    settings_of,
    to_mapping,
)
from monodock.errors import ConfigError, InputError


@dataclass(frozen=True)
class Gains:
    SETTINGS: ClassVar[Policy] = Policy(what="gadget")

    k_lateral: float = setting(4.0, positive=True, help="lateral gain")
    k_heading: float = setting(2.5, non_negative=True)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Noise:
    sigma: float = setting(0.01, unit="m", help="range noise")
    seeded: bool = setting(False)


@dataclass(frozen=True)
class Planner:
    standoff: float = setting(1.0, unit="m")
    legs: int = setting(3)
    noise: Noise = section(Noise)

    def __post_init__(self) -> None:
        if self.legs == 7:
            raise ConfigError("planner: seven legs is unlucky")


@dataclass(frozen=True)
class Gadget:
    """A settings class of the docking config's kind: unknown keys refused, rules checked whenever it is built."""

    SETTINGS: ClassVar[Policy] = Policy(
        what="gadget",
        unknown="refuse",
        checks="construct",
        culprit=True,
        numbers=(0.0, 100.0),
        counts=(0, 10),
        units_in_errors=False,
        live=True,
    )

    planner: Planner = section(Planner)
    speed: float = setting(0.2, unit="m/s", positive=True, help="cruise speed")
    gains: Gains = section(Gains, key="")
    offset: float = setting(0.0, signed=True, unit="m")
    tries: int = setting(2, live=False)
    acquire: bool = setting(True)
    name: str = setting("dock")

    def __post_init__(self) -> None:
        check_fields(self)
        if self.offset > self.speed:
            raise ConfigError("gadget: offset must not exceed speed")


@dataclass(frozen=True)
class Mount:
    """A settings class of the robot file's kind: unknown keys warned about, ranges with units, required keys."""

    SETTINGS: ClassVar[Policy] = Policy(what="robot", ignore=("survey",))

    x: float = setting(0.0, range=(-5.0, 5.0), unit="m", required=True)
    yaw: float = setting(0.0, range=(-math.pi, math.pi), unit="rad", omit_default=True)
    size: float | None = setting(None, range=(0.005, 2.0), unit="m", omit_default=True, aliases=("side",))
    scale: float = setting(1.0, positive=True)
    tags: tuple[str, ...] = setting((), omit_default=True)
    start: tuple[float, float, float] = setting((0.0, 0.0, 0.0))


def read(cls: type[Any], data: Any, source: str = "g.yaml") -> Any:
    return from_mapping(cls, data, source)


def error_of(cls: type[Any], data: Any, source: str = "g.yaml") -> str:
    with pytest.raises(ConfigError) as caught:
        from_mapping(cls, data, source)
    return str(caught.value)


# --- names and declaration ---------------------------------------------------------------------------------------


def test_flat_names_follow_declaration_order_with_spread_sections_in_place() -> None:
    names = [s.key for s in settings_of(Gadget)]
    assert names == [
        "planner.standoff",
        "planner.legs",
        "planner.noise.sigma",
        "planner.noise.seeded",
        "speed",
        "k_lateral",
        "k_heading",
        "offset",
        "tries",
        "acquire",
        "name",
    ]
    by_key = {s.key: s for s in settings_of(Gadget)}
    assert by_key["k_lateral"].path == ("gains", "k_lateral")
    assert by_key["planner.noise.sigma"].meta.unit == "m"
    assert by_key["speed"].default == 0.2
    assert by_key["speed"].meta.help == "cruise speed"
    assert by_key["speed"].live  # the Policy's, unless the field says
    assert not by_key["tries"].live


def test_a_name_declared_twice_is_a_programming_error() -> None:
    @dataclass(frozen=True)
    class Twice:
        speed: float = setting(1.0)
        gains: Gains = section(Gains, key="")
        k_lateral: float = setting(1.0)

    with pytest.raises(TypeError, match="k_lateral"):
        settings_of(Twice)


def test_a_type_without_a_reader_needs_a_codec() -> None:
    @dataclass(frozen=True)
    class Odd:
        when: complex = setting(1j)

    with pytest.raises(TypeError, match="codec"):
        from_mapping(Odd, {"when": 1}, "odd.yaml")


# --- reading ---------------------------------------------------------------------------------------------------


def test_a_file_sets_what_it_names_and_the_rest_keeps_its_defaults() -> None:
    got = read(Gadget, {"speed": 0.5, "k_heading": 1, "planner": {"noise": {"seeded": True}}, "tries": 4})
    assert got == Gadget(speed=0.5, gains=Gains(k_heading=1.0), planner=Planner(noise=Noise(seeded=True)), tries=4)
    assert isinstance(got.gains.k_heading, float)  # an integer serves a real, and is one afterwards
    assert read(Gadget, {}) == Gadget()


def test_an_unknown_key_is_refused_naming_the_known_keys_of_its_mapping() -> None:
    assert error_of(Gadget, {"k_laterl": 1.0}) == (
        "g.yaml: k_laterl: unknown key (known: planner, speed, k_lateral, k_heading, offset, tries, acquire, name)"
    )
    assert error_of(Gadget, {"planner": {"stand_off": 1.0}}) == (
        "g.yaml: planner.stand_off: unknown key (known: standoff, legs, noise)"
    )


def test_an_unknown_key_is_only_a_warning_where_the_policy_says(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="monodock.config"):
        got = read(Mount, {"x": 0.1, "colour": "red", "survey": {"any": 1}}, "robot.yaml")
    assert got == Mount(x=0.1)
    assert [r.getMessage() for r in caplog.records] == [
        "robot.yaml: unknown key 'colour' is ignored (known: x, yaw, size, scale, tags, start, side, survey)"
    ]


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"speed": 1e6}, "g.yaml: speed: must be within 0 to 100, got 1000000.0"),  # no unit: units_in_errors=False
        ({"offset": -1e6}, "g.yaml: offset: must be within -100 to 100, got -1000000.0"),  # signed
        ({"speed": "fast"}, "g.yaml: speed: expected a number, got 'fast'"),
        ({"speed": math.nan}, "g.yaml: speed: expected a finite number, got nan"),
        ({"acquire": "yes"}, "g.yaml: acquire: expected true or false, got 'yes'"),
        ({"tries": 11}, "g.yaml: tries: must be at most 10, got 11"),
        ({"tries": 10**50}, "g.yaml: tries: must be at most 10, got an integer of about 51 digits"),
        ({"tries": 2.0}, "g.yaml: tries: expected an integer, got 2.0"),
        ({"name": 3}, "g.yaml: name: expected a string, got 3"),
        ({"planner": 3}, "g.yaml: planner: expected a mapping, got int"),
        ({"planner": {"noise": {"sigma": -1.0}}}, "g.yaml: planner.noise.sigma: must be within 0 to 100, got -1.0"),
    ],
)
def test_each_bad_value_is_one_line_naming_the_file_and_the_key(data: dict[str, Any], message: str) -> None:
    assert error_of(Gadget, data) == message


def test_a_construct_time_rule_holds_for_code_and_files_alike_and_the_file_names_its_key() -> None:
    with pytest.raises(ConfigError, match=r"^gadget: speed must be positive, got 0.0$"):
        Gadget(speed=0.0)
    with pytest.raises(ConfigError, match=r"^gadget: k_lateral must be positive, got -1.0$"):
        Gains(k_lateral=-1.0)
    # A declared rule broken in a file: its key and the rule, as a read-time error says them.
    assert error_of(Gadget, {"speed": 0.0}) == "g.yaml: speed: must be positive, got 0.0"
    assert error_of(Gadget, {"k_lateral": 0}) == "g.yaml: k_lateral: must be positive, got 0.0"
    with pytest.raises(ConfigError, match=r"^gadget: k_heading must not be negative, got -0.5$"):
        Gains(k_heading=-0.5)
    # A rule across fields: the key is the one value that breaks it among the defaults.
    assert error_of(Gadget, {"offset": 0.5}) == "g.yaml: offset: offset must not exceed speed"
    # ... and none when no single value does.
    assert error_of(Gadget, {"offset": 0.15, "speed": 0.1}) == "g.yaml: offset must not exceed speed"
    # A nested section's own rule: its key under the section's, the section's name not said twice.
    assert error_of(Gadget, {"planner": {"legs": 7}}) == "g.yaml: planner.legs: seven legs is unlucky"


def test_check_fields_walks_the_sections_and_names_their_flat_keys() -> None:
    @dataclass(frozen=True)
    class Wheel:
        width: float = setting(0.3, positive=True)
        turns: int = setting(1, range=(1, 4))

    @dataclass(frozen=True)
    class Base:
        wheel: Wheel = section(Wheel)
        spread: Wheel = section(Wheel, key="x")

        def __post_init__(self) -> None:
            check_fields(self, "base")

    Wheel(width=0.0)  # no rule of its own
    with pytest.raises(ConfigError, match=r"^base: wheel.width must be positive, got 0.0$"):
        Base(wheel=Wheel(width=0.0))
    with pytest.raises(ConfigError, match=r"^base: x.turns must be within 1 to 4, got 5$"):
        Base(spread=Wheel(turns=5))


def test_a_spread_sections_name_as_a_key_says_where_its_keys_go() -> None:
    assert error_of(Gadget, {"gains": {"k_lateral": 1.0}}) == (
        "g.yaml: gains: not a key of this file: write its keys (k_lateral, k_heading) at the top level"
    )


def test_a_section_checked_by_its_parent_names_the_file_key_of_the_broken_rule() -> None:
    @dataclass(frozen=True)
    class Wheel:
        width: float = setting(0.3, positive=True)

    @dataclass(frozen=True)
    class Base:
        SETTINGS: ClassVar[Policy] = Policy(what="base", checks="construct", culprit=True)
        wheel: Wheel = section(Wheel)

        def __post_init__(self) -> None:
            check_fields(self)

    assert error_of(Base, {"wheel": {"width": 0.0}}, "b.yaml") == "b.yaml: wheel.width: must be positive, got 0.0"


def test_an_inherited_setting_keeps_every_rule_of_the_base_but_what_it_changes() -> None:
    @dataclass(frozen=True)
    class Base:
        rate: float = setting(10.0, range=(1.0, 50.0), unit="Hz", help="frames a second")

    @dataclass(frozen=True)
    class Node(Base):
        rate: float = inherited(Base, "rate", help="detections a second")

    (base,), (node,) = settings_of(Base), settings_of(Node)
    assert node.meta == dataclasses.replace(base.meta, help="detections a second")
    assert node.default == 10.0
    assert error_of(Node, {"rate": 60.0}, "n.yaml") == "n.yaml: rate: must be within 1 to 50 Hz, got 60.0"
    with pytest.raises(TypeError, match="has no setting 'speed'"):
        inherited(Base, "speed")


def test_integer_rules_hold_when_a_file_is_read() -> None:
    @dataclass(frozen=True)
    class Counts:
        tries: int = setting(3, positive=True)
        spare: int = setting(0, non_negative=True)

    assert error_of(Counts, {"tries": 0}, "c.yaml") == "c.yaml: tries: must be positive, got 0"
    assert error_of(Counts, {"spare": -1}, "c.yaml") == "c.yaml: spare: must not be negative, got -1"
    assert from_mapping(Counts, {"tries": 1, "spare": 0}, "c.yaml") == Counts(1, 0)


def test_settings_of_a_class_whose_section_has_no_default_uses_the_sections_own_defaults() -> None:
    @dataclass(frozen=True)
    class Arm:
        name: str
        mount: Noise

    assert [(s.key, s.default) for s in settings_of(Arm)] == [
        ("name", dataclasses.MISSING),
        ("mount.sigma", 0.01),
        ("mount.seeded", False),
    ]


def test_read_time_rules_ranges_with_units_required_keys_and_aliases() -> None:
    assert error_of(Mount, {"x": 6.0}, "robot.yaml") == "robot.yaml: x: must be within -5 to 5 m, got 6.0"
    assert error_of(Mount, {"x": 0.0, "yaw": 4.0}, "robot.yaml") == (
        "robot.yaml: yaw: must be within -3.14159 to 3.14159 rad, got 4.0"
    )
    assert error_of(Mount, {}, "robot.yaml") == "robot.yaml: missing field 'x'"  # required although it has a default
    assert error_of(Mount, {"x": 0.0, "scale": 0}, "robot.yaml") == "robot.yaml: scale: must be positive, got 0"
    assert read(Mount, {"x": 0.0, "side": 0.1}).size == 0.1
    assert error_of(Mount, {"x": 0.0, "start": [1, 2]}, "r.yaml") == (
        "r.yaml: start: expected a list of 3 numbers, got [1, 2]"
    )
    assert read(Mount, {"x": 0.0, "start": [1, 2, 3], "tags": ["a"]}) == Mount(start=(1.0, 2.0, 3.0), tags=("a",))
    assert error_of(Mount, {"x": 0.0, "tags": [1]}, "r.yaml") == "r.yaml: tags: expected a list of strings, got [1]"


def test_a_rule_of_its_own_and_a_codec() -> None:
    class Percent:
        def read(self, fields: Fields, key: str) -> float:
            text = fields.string(key)
            if not text.endswith("%"):
                raise fields.error(key, f"expected a percentage, got {text!r}")
            return float(text[:-1]) / 100

        def write(self, value: float) -> str:
            return f"{value * 100:g}%"

    @dataclass(frozen=True)
    class Print:
        dictionary: str = setting("DICT_4X4_50", check=lambda v: None if v.startswith("DICT_") else f"no {v!r}")
        scale: float = setting(1.0, codec=Percent())

    assert read(Print, {"scale": "50%"}) == Print(scale=0.5)
    assert error_of(Print, {"scale": "0.5"}) == "g.yaml: scale: expected a percentage, got '0.5'"
    assert error_of(Print, {"dictionary": "ARUCO"}) == "g.yaml: dictionary: no 'ARUCO'"
    assert to_mapping(Print(scale=0.25)) == {"dictionary": "DICT_4X4_50", "scale": "25%"}


def test_a_policy_may_raise_its_own_error_type() -> None:
    @dataclass(frozen=True)
    class Target:
        SETTINGS: ClassVar[Policy] = Policy(what="target", error=InputError)
        side: float = setting(0.2, range=(0.05, 5.0), unit="m")

    with pytest.raises(InputError, match=r"^t.yaml: side: must be within 0.05 to 5 m, got 9$"):
        from_mapping(Target, {"side": 9}, "t.yaml")


def test_an_error_of_the_dataclass_names_the_source_once() -> None:
    @dataclass(frozen=True)
    class Pair:
        low: float = setting(0.0)
        high: float = setting(1.0)

        def __post_init__(self) -> None:
            if self.low > self.high:
                raise ConfigError(f"low {self.low} is above high {self.high}")

    assert error_of(Pair, {"low": 2.0}, "p.yaml") == "p.yaml: low 2.0 is above high 1.0"


# --- writing, flat names, replace --------------------------------------------------------------------------------


def test_the_writer_keeps_declaration_order_spreads_sections_and_round_trips() -> None:
    config = Gadget(speed=1, gains=Gains(k_lateral=3.0), planner=Planner(legs=4))
    written = to_mapping(config)
    assert list(written) == ["planner", "speed", "k_lateral", "k_heading", "offset", "tries", "acquire", "name"]
    assert written["planner"] == {"standoff": 1.0, "legs": 4, "noise": {"sigma": 0.01, "seeded": False}}
    assert isinstance(written["speed"], float)  # an integer given for a real is written as one
    assert read(Gadget, written) == config
    assert yaml_text(written).startswith("planner:\n  standoff: 1.0\n  legs: 4\n")


def test_the_writer_leaves_out_defaults_where_declared_and_refuses_non_finite_values() -> None:
    assert to_mapping(Mount(x=0.1)) == {"x": 0.1, "scale": 1.0, "start": [0.0, 0.0, 0.0]}
    assert to_mapping(Mount(x=0.1, yaw=0.2, size=0.1, tags=("a",)))["tags"] == ["a"]
    with pytest.raises(ConfigError, match=r"^robot: cannot write a non-finite value \(inf\)$"):
        to_mapping(Mount(scale=math.inf))


def test_flat_and_nested_are_the_ros_names_and_the_file_mapping() -> None:
    values = flat(Gadget())
    assert list(values) == [s.key for s in settings_of(Gadget)]
    assert values["planner.noise.sigma"] == 0.01
    assert values["k_lateral"] == 4.0
    assert nested({"a.b": 1, "a.c.d": 2, "e": 3}) == {"a": {"b": 1, "c": {"d": 2}}, "e": 3}
    with pytest.raises(ConfigError, match=r"^parameter a.b: a is a value, not a section$"):
        nested({"a": 1, "a.b": 2})
    assert from_flat(Gadget, {"planner.legs": 5, "k_lateral": 1.0}, "ROS parameters") == Gadget(
        planner=Planner(legs=5), gains=Gains(k_lateral=1.0)
    )
    assert from_flat(Gadget, flat(Gadget()), "ROS parameters") == Gadget()


def test_replace_by_flat_name_goes_through_the_sections() -> None:
    config = replace(Gadget(), {"planner.noise.sigma": 0.5}, k_lateral=1.0, speed=0.3)
    assert config == Gadget(planner=Planner(noise=Noise(sigma=0.5)), gains=Gains(k_lateral=1.0), speed=0.3)
    with pytest.raises(ConfigError, match="speed must be positive"):
        replace(Gadget(), speed=0.0)
    with pytest.raises(KeyError, match="k_laterl"):
        replace(Gadget(), k_laterl=1.0)
    assert replace(Gadget(), planner=Planner(legs=4)).planner.legs == 4  # a keyed section, whole
    assert replace(Gadget(), {"planner.noise": Noise(seeded=True)}).planner.noise.seeded
