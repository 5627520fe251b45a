"""The one config reader (`drivers.config.reader`), the one config error type it raises, and reading a
config file strictly (`drivers.config.file`: size, encoding, duplicate keys, nesting)."""
from __future__ import annotations

import codecs
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import pytest

import headctl.errors
from drivers.config.reader import (
    check_settings,
    config_error_from,
    config_keys,
    config_meta,
    declare_settings,
    describe,
    read_config,
    read_fields,
    read_value,
    secret_keys,
    setting,
)
from drivers.config.file import read_yaml_file
from drivers.config.messages import HIDDEN, Shown, key_text
from drivers.errors import CameraConfigError, ConfigError, DriverError, ServoConfigError


@dataclass(frozen=True)
class Inner:
    x: int
    scale: float = setting(1.0, above=0.0, expected="a positive scale")


@dataclass(frozen=True)
class Every:
    """One field of each type the reader reads."""

    count: int = 0
    ratio: float = 0.5
    name: str = "n"
    on: bool = False
    mode: Literal["a", "b"] = "a"
    maybe: float | None = None
    device: str | int | None = None
    pair: tuple[int, int] = (1, 2)
    many: tuple[float, ...] = ()
    inner: Inner = field(default_factory=lambda: Inner(x=0))
    named: Mapping[str, Inner] = field(default_factory=dict)
    where: Path = Path("here")
    anything: Any = None


@dataclass(frozen=True)
class Bounded:
    servo_id: int = field(metadata=config_meta(key="id", lo=0, hi=252))
    direction: int = setting(1, choices=(1, -1))
    step_ms: int = setting(0, lo=0, hi=100, check=lambda ms: ms % 20 == 0, expected="a multiple of 20 in [0, 100]")
    low: float = -1.0
    high: float = 1.0
    where: str = setting("root", source="key_path")

    def __post_init__(self) -> None:
        check_settings(self)
        if self.low >= self.high:
            raise ConfigError(key_path="low", value=self.low, expected=f"less than high ({self.high})")


@dataclass(frozen=True)
class Api:
    host: str = "127.0.0.1"
    token: str | None = setting(None, secret=True, repr=False, check=lambda t: len(t) >= 16,
                                expected="at least 16 characters")
    port: int = 80

    def __post_init__(self) -> None:
        if self.port == 81:  # a check whose message names no field: the section is shown
            raise ValueError(f"reserved for this test: port 81 (and not {self.token})")


@dataclass(frozen=True)
class Library:
    """A parameter class as `calib_free` writes them: plain ValueErrors naming the field."""

    rate: float = 0.5
    width: int = 10

    def __post_init__(self) -> None:
        if not 0 < self.rate <= 1:
            raise ValueError(f"rate must be in (0, 1], got {self.rate}")


@dataclass(frozen=True)
class Flat:
    params: Library = setting(default_factory=Library, inline=Library)
    overrides: Mapping[str, Any] = setting(default_factory=dict, inline=Every, exclude=("inner", "named"))
    explore: bool = True
    given: frozenset[str] = setting(frozenset(), source="given_keys", init=False, compare=False)


@dataclass(frozen=True)
class Bus:
    joints: Mapping[str, Bounded] = field(metadata=config_meta(keys=("pan", "tilt")))

    CONFIG_ERROR: ClassVar[type[ConfigError]] = ServoConfigError


@dataclass(frozen=True)
class Head:
    path: Path = field(metadata=config_meta(source="file"))
    bus: Bus
    api: Api = field(default_factory=Api)


def error_of(cls: type, data: Any, key_path: str = "s", **kwargs: Any) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        read_config(cls, data, key_path, **kwargs)
    return err.value


# --- types ---------------------------------------------------------------------------------
def test_each_type_is_read_and_typed():
    config = read_config(Every, {
        "count": 3, "ratio": 2, "name": "x", "on": True, "mode": "b", "maybe": 1, "device": 0,
        "pair": [3, 4], "many": [1, 2.5], "inner": {"x": 5}, "named": {"p": {"x": 1, "scale": 3}},
        "where": "state", "anything": {"free": [1]},
    }, "every")
    assert config.count == 3 and config.ratio == 2.0 and isinstance(config.ratio, float)
    assert (config.name, config.on, config.mode, config.maybe, config.device) == ("x", True, "b", 1.0, 0)
    assert config.pair == (3, 4) and config.many == (1.0, 2.5)
    assert config.inner == Inner(x=5) and config.named == {"p": Inner(x=1, scale=3.0)}
    assert config.where == Path("state") and config.anything == {"free": [1]}
    assert read_config(Every, {"device": "/dev/video0", "maybe": None}).device == "/dev/video0"
    assert read_config(Every, None) == Every()  # a null section is an empty one


@pytest.mark.parametrize("data, key_path, expected", [
    ({"count": True}, "s.count", "an integer"),  # bool is an int in Python, never in a config
    ({"count": 1.5}, "s.count", "an integer"),
    ({"ratio": True}, "s.ratio", "a number"),
    ({"ratio": "1"}, "s.ratio", "a number"),
    ({"name": ""}, "s.name", "a non-empty string"),
    ({"name": 3}, "s.name", "a non-empty string"),
    ({"on": 1}, "s.on", "true or false"),
    ({"mode": "c"}, "s.mode", "'a' or 'b'"),
    ({"maybe": "x"}, "s.maybe", "a number"),
    ({"device": 1.5}, "s.device", "a non-empty string or an integer"),
    ({"device": False}, "s.device", "a non-empty string or an integer"),
    ({"pair": [1]}, "s.pair", "a list of 2 (an integer, an integer)"),
    ({"pair": "12"}, "s.pair", "a list of 2 (an integer, an integer)"),
    ({"pair": [1, "2"]}, "s.pair[1]", "an integer"),
    ({"many": 3}, "s.many", "a list of (a number)"),
    ({"many": [1, None]}, "s.many[1]", "a number"),
    ({"inner": 3}, "s.inner", "a mapping with keys x, scale"),
    ({"inner": {"x": "1"}}, "s.inner.x", "an integer"),
    ({"named": {"p": {"x": 1, "scale": 0}}}, "s.named.p.scale", "a positive scale"),
    ({"named": {1: {"x": 1}}}, "s.named", "a mapping of names to (a mapping with keys x, scale)"),
    ({"where": ""}, "s.where", "a path (a non-empty string)"),
])
def test_wrong_values_name_the_key_path_the_value_and_what_was_expected(data, key_path, expected):
    err = error_of(Every, data)
    value = data[key_path.split(".")[1].split("[")[0]]
    assert err.key_path == key_path and err.expected == expected
    if err.key_path == f"s.{next(iter(data))}":
        assert err.value == value or err.value is value
    assert str(err) == f"{key_path}: got {err.value!r}, expected {expected}"


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_are_refused(bad):
    err = error_of(Every, {"ratio": bad})
    assert err.key_path == "s.ratio" and err.expected == "a number"
    with pytest.raises(ConfigError, match=r"^x: got nan, expected a number$"):
        read_value(math.nan, float, "x")


def test_read_value_and_describe():
    assert read_value([1, 2], tuple[float, float], "p") == (1.0, 2.0)
    assert read_value(None, int | None, "p") is None
    assert describe(tuple[tuple[float, float], ...]) == "a list of (a list of 2 (a number, a number))"
    assert describe(Inner) == "a mapping with keys x, scale"
    assert config_keys(Bounded) == ("id", "direction", "step_ms", "low", "high")


# --- keys ----------------------------------------------------------------------------------
def test_unknown_keys_are_refused_naming_the_allowed_ones():
    err = error_of(Every, {"inner": {"x": 1, "y": 2}})
    assert (err.key_path, err.value) == ("s.inner.y", 2)
    assert err.expected == "a known key (s.inner takes x, scale); 'y' is an unknown key"
    err = error_of(Every, {"colour": 1}, key_path="")
    assert err.key_path == "colour" and "the top level takes count, ratio, " in err.expected


def test_missing_required_keys_are_refused():
    err = error_of(Bounded, {}, key_path="bus.joints.pan")
    assert (err.key_path, err.missing, err.value) == ("bus.joints.pan.id", True, None)
    assert str(err) == "bus.joints.pan.id: missing, expected an integer in [0, 252]"
    err = error_of(Bus, {"joints": {"pan": {"id": 1}}}, key_path="bus")
    assert err.key_path == "bus.joints.tilt" and err.missing
    assert err.expected == "every one of pan, tilt under bus.joints (missing: tilt)"
    err = error_of(Bus, {"joints": {"pan": {"id": 1}, "tilt": {"id": 2}, "roll": {}}}, key_path="bus")
    assert err.key_path == "bus.joints.roll" and "'roll' is an unknown key" in err.expected


def test_a_yaml_key_can_differ_from_the_field_name():
    config = read_config(Bounded, {"id": 7}, "bus.joints.pan")
    assert config.servo_id == 7 and config.where == "bus.joints.pan"  # source="key_path"
    assert error_of(Bounded, {"servo_id": 7}).key_path == "s.servo_id"  # the field name is not a key


# --- declared checks and the dataclass's own ---------------------------------------------------
@pytest.mark.parametrize("data, key_path, value, expected", [
    ({"id": 300}, "s.id", 300, "an integer in [0, 252]"),
    ({"id": 1, "direction": 2}, "s.direction", 2, "one of 1, -1"),
    ({"id": 1, "direction": True}, "s.direction", True, "one of 1, -1"),
    ({"id": 1, "step_ms": 30}, "s.step_ms", 30, "a multiple of 20 in [0, 100]"),
    ({"id": 1, "step_ms": "x"}, "s.step_ms", "x", "an integer (a multiple of 20 in [0, 100])"),
    ({"id": 1, "low": 2}, "s.low", 2.0, "less than high (1.0)"),  # __post_init__, re-rooted
])
def test_declared_bounds_and_post_init_checks(data, key_path, value, expected):
    err = error_of(Bounded, data)
    assert (err.key_path, err.value, err.expected) == (key_path, value, expected)


def test_declared_bounds_hold_for_direct_construction_too():
    with pytest.raises(ConfigError, match=r"^servo_id: got -1, expected an integer in \[0, 252\]$"):
        Bounded(servo_id=-1)


def test_a_plain_value_error_naming_a_field_names_its_key():
    err = error_of(Flat, {"rate": 2}, key_path="fixation")
    assert (err.key_path, err.value, err.expected) == ("fixation.rate", 2.0, "in (0, 1]")
    direct = config_error_from(ValueError("rate must be in (0, 1], got 2"), "gm", {"rate": 2})
    assert str(direct) == "gm.rate: got 2, expected in (0, 1]"
    other = config_error_from(ValueError("inconsistent"), "gm", {"rate": 2})
    assert str(other) == "gm: got {'rate': 2}, expected valid settings (inconsistent)"


def test_inline_fields_and_overrides_share_the_section():
    config = read_config(Flat, {"rate": 0.25, "count": 4, "explore": False}, "fixation")
    assert config.params == Library(rate=0.25) and config.overrides == {"count": 4} and not config.explore
    assert config.given == frozenset({"rate", "count", "explore"})  # source="given_keys"
    err = error_of(Flat, {"inner": {}}, key_path="fixation")
    assert err.key_path == "fixation.inner" and "'inner' is an unknown key" in err.expected
    assert read_fields(Every, {"count": 2}, "gm", exclude=("inner",)) == {"count": 2}
    assert error_of(Every, {"count": 2.5}, key_path="gm").key_path == "gm.count"


# --- the error type ----------------------------------------------------------------------------
def test_one_error_type_with_structured_fields_and_the_file():
    err = error_of(Head, {"bus": {"joints": {"pan": {"id": 1}, "tilt": {"id": 300}}}}, key_path="",
                   file=Path("/etc/head.yaml"))
    assert isinstance(err, ServoConfigError)  # the section's CONFIG_ERROR, inherited by the joints
    assert isinstance(err, ConfigError) and isinstance(err, DriverError) and isinstance(err, ValueError)
    assert (err.key_path, err.value, err.expected, err.file) == ("bus.joints.tilt.id", 300, "an integer in [0, 252]",
                                                                 Path("/etc/head.yaml"))
    assert str(err) == "/etc/head.yaml: bus.joints.tilt.id: got 300, expected an integer in [0, 252]"
    head = read_config(Head, {"bus": {"joints": {"pan": {"id": 1}, "tilt": {"id": 2}}}}, file=Path("h.yaml"))
    assert head.path == Path("h.yaml") and head.bus.joints["tilt"].where == "bus.joints.tilt"


def test_every_layer_raises_the_same_class():
    assert headctl.errors.ConfigError is ConfigError
    assert issubclass(ServoConfigError, ConfigError) and issubclass(CameraConfigError, ConfigError)
    plain = CameraConfigError("left: pixel_format 'Mono16' not offered")  # a backend's refusal
    assert str(plain) == "left: pixel_format 'Mono16' not offered"
    assert (plain.key_path, plain.value, plain.expected, plain.file) == (None, None, None, None)
    plain.file = "head.yaml"
    assert str(plain) == "head.yaml: left: pixel_format 'Mono16' not offered"
    assert str(ConfigError(key_path="", value=[1], expected="a mapping")) == "(top level): got [1], expected a mapping"


# --- secrets -----------------------------------------------------------------------------------
SECRET = "s3cret-s3cret-s3cret"


@pytest.mark.parametrize("data, expected", [
    ({"token": "short-secret"}, "at least 16 characters"),
    ({"token": ["s3cret-s3cret-s3cret"]}, "a non-empty string (at least 16 characters)"),
])
def test_a_secret_is_never_shown(data, expected):
    err = error_of(Api, data, key_path="api")
    assert (err.key_path, err.value, err.expected) == ("api.token", HIDDEN, expected)
    assert str(err) == f"api.token: got <hidden>, expected {expected}"
    assert "s3cret" not in str(err) and "s3cret" not in repr(err.args)


def test_a_secret_is_hidden_where_a_whole_section_is_shown():
    err = error_of(Api, {"token": SECRET, "port": 81}, key_path="api")
    assert err.key_path == "api" and SECRET not in str(err) and SECRET not in repr(err)
    assert "'token': <hidden>" in str(err) and "'port': 81" in str(err)
    assert err.expected == "valid settings (reserved for this test: port 81 (and not <hidden>))"
    assert err.__cause__ is None and err.__suppress_context__
    assert SECRET not in repr(read_config(Api, {"token": SECRET}))


def test_a_misspelt_secret_key_is_refused_without_its_value():
    err = error_of(Api, {"tokn": SECRET}, key_path="api")
    assert (err.key_path, err.value) == ("api.tokn", HIDDEN) and SECRET not in str(err)
    assert error_of(Every, {"tokn": "shown"}).value == "shown"  # a section without secrets shows it


def test_a_secret_is_hidden_at_any_depth_of_a_value_shown_whole():
    err = error_of(Head, [{"api": {"token": SECRET}}], key_path="", file=Path("h.yaml"))
    assert err.key_path == "" and SECRET not in str(err) and "'token': <hidden>" in str(err)
    err = error_of(Head, {"bus": {"joints": {}}, "apix": {"nested": [{"token": SECRET}]}}, key_path="")
    assert err.key_path == "apix" and SECRET not in str(err)
    assert secret_keys(Head) == frozenset({"token"})


# --- what every value meets ------------------------------------------------------------------
@pytest.mark.parametrize("data, key_path, expected", [
    ({"count": 2**63}, "s.count", "an integer within +-2**63"),
    ({"count": -2**63 - 1}, "s.count", "an integer within +-2**63"),
    ({"ratio": 10**400}, "s.ratio", "a number"),  # beyond any float: refused, not an OverflowError
    ({"name": "a\0b"}, "s.name", "a non-empty string of text (no NUL character, no lone surrogate)"),
    ({"name": "\ud800"}, "s.name", "a non-empty string of text (no NUL character, no lone surrogate)"),
    ({"where": "/tmp/\0"}, "s.where", "a path (a non-empty string) of text (no NUL character, no lone surrogate)"),
])
def test_integers_numbers_and_strings_are_bounded_whatever_the_field(data, key_path, expected):
    err = error_of(Every, data)
    assert (err.key_path, err.expected) == (key_path, expected)
    assert read_config(Every, {"count": 2**63 - 1}).count == 2**63 - 1


def test_a_long_value_is_shown_abbreviated_and_an_odd_key_as_its_repr():
    err = error_of(Every, {"count": list(range(10_000))})
    assert isinstance(err.value, Shown) and len(str(err)) < 400 and "characters)" in str(err)
    err = error_of(Every, {"bad\x1b[2Jkey": 1})
    assert err.key_path == "s.'bad\\x1b[2Jkey'" and "\x1b" not in str(err)
    assert err.expected.endswith("; 'bad\\x1b[2Jkey' is an unknown key")
    assert key_text("pan") == "pan" and key_text(3) == "3" and key_text("x" * 100).startswith("'xxx")


def test_settings_can_be_declared_for_a_class_that_cannot_declare_its_own():
    @dataclass(frozen=True)
    class Foreign:
        steps: int = 5
        size: tuple[int, int] = (3, 3)

    declare_settings(Foreign, steps=config_meta(lo=0, hi=100),
                     size=config_meta(check=lambda s: max(s) <= 10, expected="at most 10 x 10"))
    assert read_config(Foreign, {"steps": 100}).steps == 100
    assert (error_of(Foreign, {"steps": 101}).expected, error_of(Foreign, {"size": [3, 11]}).expected) == (
        "an integer in [0, 100]", "at most 10 x 10")
    with pytest.raises(TypeError, match="no field 'stesp'"):
        declare_settings(Foreign, stesp=config_meta(lo=0))


# --- YAML files ------------------------------------------------------------------------------
def yaml_error(tmp_path: Path, content: bytes | str) -> ConfigError:
    path = tmp_path / "head.yaml"
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    with pytest.raises(ConfigError) as err:
        read_yaml_file(path)
    assert str(err.value).startswith(f"{path}: ")
    return err.value


def test_a_yaml_file_is_read_as_plain_data(tmp_path):
    path = tmp_path / "head.yaml"
    path.write_bytes(codecs.BOM_UTF8 + b"base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  x: 3\nd: [*b, *b]\n")
    # A merged key may be overridden (YAML's merge), aliases are shared, a UTF-8 BOM is dropped.
    assert read_yaml_file(path) == {"base": {"x": 1, "y": 2}, "c": {"x": 3, "y": 2}, "d": [{"x": 1, "y": 2}] * 2}


@pytest.mark.parametrize("content, words", [
    (b"\x80\x81", "not UTF-8: byte 0x80 at line 1, column 1 is not UTF-8 text"),
    (b"a: 1\nb: caf\xe9\n", "not UTF-8: byte 0xe9 at line 2, column 7"),
    ("a: 1\n".encode("utf-16"), "not UTF-8: UTF-16 text (it starts with a UTF-16 byte order mark)"),
    ("a: 1\n".encode("utf-16-le"), "a NUL character at line 1, column 2 (UTF-16 without a byte order mark?)"),
    ("a: 1\n".encode("utf-32"), "not UTF-8: UTF-32 text"),
    ("a: \x07\n", "not valid YAML at line 1, column 4: character U+0007 is not allowed in YAML"),
    ("servo_bus: [\n", "not valid YAML at line 2, column 1: "),
    ("a: 1\n---\nb: 2\n", "not valid YAML at line 2, column 1"),
    ("a: !!python/object:os.system x\n", "not valid YAML at line 1, column 4: could not determine a constructor"),
    ("a: 2026-13-45\n", "not valid YAML at line 1, column 4: cannot read this value (month must be in 1..12)"),
    ("a: " + "9" * 5000 + "\n", "not valid YAML at line 1, column 4: an integer of 5000 characters (at most 40)"),
    ("a: *nowhere\n", "not valid YAML at line 1, column 4: found undefined alias 'nowhere'"),
    ("? [1, 2]\n: 3\n", "not valid YAML at line 1, column 3: found unhashable key"),
])
def test_a_file_that_is_not_utf8_or_not_yaml_is_refused_with_where(tmp_path, content, words):
    assert words in str(yaml_error(tmp_path, content))


def test_duplicate_keys_are_refused_naming_the_key_path_and_both_lines(tmp_path):
    err = yaml_error(tmp_path, "servo_bus:\n  joints:\n    pan: {id: 1, min_angle: -40}\n    tilt: {id: 2}\n"
                               "    pan: {id: 3, min_angle: -20}\n")
    assert err.key_path == "servo_bus.joints.pan"
    assert str(err).endswith("servo_bus.joints.pan: got a second 'pan' key at line 5, column 5 (the first is at "
                             "line 3, column 5), expected each key once in servo_bus.joints (YAML would silently "
                             "keep the last)")
    err = yaml_error(tmp_path, "a:\n  b: {min_angle: 1, max_angle: 2, min_angle: 3}\n")
    assert err.key_path == "a.b.min_angle" and "line 2, column 35 (the first is at line 2, column 7)" in str(err)
    assert yaml_error(tmp_path, "1: x\n01: y\n").key_path == "1"  # equal as integers: one key


@pytest.mark.parametrize("content, words", [
    ("a: " + "[" * 100 + "]" * 100, "a[0][0][0][0][0][0][0]...: nested deeper than 32 levels at line 1, column 36"),
    ("a: " + "[" * 5000 + "]" * 5000, "at line 1, column "),  # libyaml may refuse it first, as too deep too
    ("a: " + "{b: " * 100 + "1" + "}" * 100, "a.b.b.b.b.b.b.b...: nested deeper than 32 levels"),
    ("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{n}: &{n} [{', '.join([f'*{p}'] * 10)}]\n" for p, n in zip("abcde", "bcdef")),
     "more than 100000 values (aliases expanded) at line 5"),
    ("a: &a [1, *a]\n", "a recursive alias at line 1, column 4"),
    ("a: &a " + "[" * 20 + "]" * 20 + "\nb: " + "[" * 15 + "*a" + "]" * 15 + "\n",
     "aliases nest deeper than 32 levels"),
])
def test_nesting_and_size_are_bounded_aliases_expanded(tmp_path, content, words):
    assert words in str(yaml_error(tmp_path, content))


def test_a_file_is_read_no_further_than_its_bound(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * (1 << 20) + b"\n")
    with pytest.raises(ConfigError, match=r"big\.yaml: larger than 1048576 bytes \(1 MiB\)"):
        read_yaml_file(big)
    with pytest.raises(ConfigError, match=r"^/dev/zero: larger than 1048576 bytes"):
        read_yaml_file("/dev/zero")
    with pytest.raises(ConfigError, match=r"cannot read: Is a directory"):
        read_yaml_file(tmp_path)
    with pytest.raises(ConfigError, match=r"cannot read: embedded null byte"):
        read_yaml_file("a\0b")
