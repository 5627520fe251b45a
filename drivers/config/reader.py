"""The one config reader of every layer: a typed frozen dataclass out of a plain mapping.

A config section is a frozen dataclass. Its type hints say what each key takes; `setting()`
(a `dataclasses.field` with metadata) adds bounds, choices, the text of what is expected,
the YAML key when it differs from the field name, and whether the value is a secret.
`read_config(cls, data, key_path)` gives the instance or raises ONE error type,
`drivers.errors.ConfigError` (or the subclass a section names in its `CONFIG_ERROR` class
variable, inherited by the sections inside it), with the key path (`servo_bus.joints.pan.
min_angle`), the value and what was expected; `file` is set by whoever knows the file.

Types read: int (bool refused), float (finite; an int is taken; bool refused), str
(non-empty), bool, pathlib.Path (a non-empty string), Literal, unions (Optional), tuples
(fixed length and `tuple[X, ...]`), nested dataclasses (a null section is an empty one),
Mapping[str, X], and Any (taken as is). Unknown keys are refused, naming the keys the
section takes; a required key (a field without a default) that is missing is refused.

Checks across fields belong in the dataclass's `__post_init__`: a `ConfigError` whose
key_path is relative to the section (`min_angle`, `joints.tilt.id`) or a plain ValueError
whose message starts with a field name (`calib_free`'s parameter classes, which cannot
import this module) is raised again under the section's key path. A `__post_init__` that
calls `check_settings(self)` applies the declared bounds to direct construction too.

A secret field's value (an API token) never appears in a message: `<hidden>` does, also
where a whole section is shown, and for a key a section holding a secret does not know (a
misspelt secret key). A value longer than `MAX_SHOWN` characters is shown abbreviated
(`drivers.config.messages`).

Rules for the fields of a dataclass that cannot import this module (`calib_free`'s parameter
classes) are declared from outside with `declare_settings(cls, field=config_meta(...))`.

Bounds every value meets whatever its field declares: an integer lies within +-2**63 (numpy
and C take it), a number is finite, a string holds text (no NUL character, no lone surrogate).

A config file becomes the plain data read here through `drivers.config.file.read_yaml_file`.
"""
from __future__ import annotations

import collections.abc
import dataclasses
import functools
import math
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

from drivers.config.messages import HIDDEN, join_key, quoted_key, shown, where
from drivers.errors import ConfigError

T = TypeVar("T")

# Where a field's value comes from: the section's key in the mapping (the default), the key
# path the section was read at, the file (`read_config(file=...)`), or the set of keys the
# mapping gave (for an init=False field, set after construction).
Source = Literal["mapping", "key_path", "file", "given_keys"]

_META = "drivers.config.reader"  # the key of this module's metadata in a field's metadata

INT_LIMIT = 2**63  # integers within +-INT_LIMIT: what numpy's int64 and C take on the way to a device


@dataclasses.dataclass(frozen=True)
class _Rules:
    """What `setting()` declares about one field."""

    lo: float | None = None
    hi: float | None = None
    above: float | None = None
    choices: tuple[Any, ...] | None = None
    check: Callable[[Any], bool] | None = None
    expected: str | None = None
    secret: bool = False
    key: str | None = None
    keys: tuple[str, ...] | None = None
    inline: type | None = None
    exclude: tuple[str, ...] = ()
    source: Source = "mapping"

    @property
    def has_checks(self) -> bool:
        return any(x is not None for x in (self.lo, self.hi, self.above, self.choices, self.check))


def config_meta(*, lo: float | None = None, hi: float | None = None, above: float | None = None,
                choices: Iterable[Any] | None = None, check: Callable[[Any], bool] | None = None,
                expected: str | None = None, secret: bool = False, key: str | None = None,
                keys: Iterable[str] | None = None, inline: type | None = None, exclude: Iterable[str] = (),
                source: Source = "mapping") -> dict[str, Any]:
    """The metadata of a dataclass field saying what the reader checks beyond its type:
    `dataclasses.field(metadata=config_meta(...))` (a required field: type checkers see that
    it has no default), or through `setting()`.

    `lo`/`hi`: inclusive bounds; `above`: an exclusive lower bound; `choices`: the values
    allowed; `check`: a predicate on the typed value; `expected`: the text of what is
    expected when one of those fails (else one is composed). None (an Optional's null) is
    not checked. `secret`: never shown. `key`: the YAML key when it is not the field name.
    `keys`: for a Mapping field, the keys it must have, all of them. `inline`: a dataclass
    whose fields (less `exclude`) are keys of this section itself; a field of that type is
    built from them, a Mapping field holds the typed values of those given (overrides).
    `source`: where the value comes from (`Source`).
    """
    rules = _Rules(lo=lo, hi=hi, above=above, choices=None if choices is None else tuple(choices), check=check,
                   expected=expected, secret=secret, key=key, keys=None if keys is None else tuple(keys),
                   inline=inline, exclude=tuple(exclude), source=source)
    return {_META: rules}


def setting(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING,
            lo: float | None = None, hi: float | None = None, above: float | None = None,
            choices: Iterable[Any] | None = None, check: Callable[[Any], bool] | None = None,
            expected: str | None = None, secret: bool = False, key: str | None = None,
            keys: Iterable[str] | None = None, inline: type | None = None, exclude: Iterable[str] = (),
            source: Source = "mapping", init: bool = True, repr: bool = True, compare: bool = True) -> Any:
    """A dataclass field with a default (or a default factory) and the rules of `config_meta`."""
    meta = config_meta(lo=lo, hi=hi, above=above, choices=choices, check=check, expected=expected, secret=secret,
                       key=key, keys=keys, inline=inline, exclude=exclude, source=source)
    field: Any = dataclasses.field(default=default, default_factory=default_factory, init=init, repr=repr,
                                   compare=compare, metadata=meta)
    return field


# --- the plan of a section --------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _Field:
    name: str
    key: str
    type: Any
    rules: _Rules
    required: bool
    inline_keys: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class _Plan:
    fields: tuple[_Field, ...]
    keys: tuple[str, ...]  # the mapping keys the section takes, in field order
    by_name: Mapping[str, _Field]
    secret_keys: frozenset[str]


# Rules declared from outside for fields of classes that cannot import this module.
_DECLARED: dict[type, dict[str, _Rules]] = {}


def declare_settings(cls: type, **rules: Mapping[str, Any]) -> None:
    """Declare what the reader checks for fields of dataclass `cls` that cannot declare it
    themselves (`calib_free`'s parameter classes cannot import this module): each keyword
    names a field, its value is `config_meta(...)`. A field's own metadata wins."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(rules) - names)
    if unknown:
        raise TypeError(f"{cls.__name__} has no field {unknown[0]!r}")
    _DECLARED.setdefault(cls, {}).update({name: meta[_META] for name, meta in rules.items()})
    _plan.cache_clear()


@functools.cache
def _plan(cls: type) -> _Plan:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    fields: list[_Field] = []
    keys: list[str] = []
    declared = _DECLARED.get(cls, {})
    for f in dataclasses.fields(cls):
        rules: _Rules = f.metadata[_META] if _META in f.metadata else declared.get(f.name, _Rules())
        if not f.init and rules.source != "given_keys":
            continue
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        inline_keys: tuple[str, ...] = ()
        if rules.inline is not None:
            inline_keys = tuple(k for k in _plan(rules.inline).keys if k not in rules.exclude)
            keys.extend(inline_keys)
        elif rules.source == "mapping":
            keys.append(rules.key or f.name)
        fields.append(_Field(f.name, rules.key or f.name, hints[f.name], rules, required, inline_keys))
    secret = frozenset(fl.key for fl in fields if fl.rules.secret)
    return _Plan(tuple(fields), tuple(keys), {fl.name: fl for fl in fields}, secret)


def config_keys(cls: type) -> tuple[str, ...]:
    """The keys a section (dataclass) takes in its mapping, in field order."""
    return _plan(cls).keys


def secret_keys(cls: type) -> frozenset[str]:
    """The keys of secret fields anywhere in section `cls` and the sections inside it: what
    is hidden wherever a mapping is shown whole."""
    found: set[str] = set()
    seen: set[type] = set()

    def walk(tp: Any) -> None:
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            if tp in seen:
                return
            seen.add(tp)
            plan = _plan(tp)
            found.update(plan.secret_keys)
            for f in plan.fields:
                walk(f.rules.inline if f.rules.inline is not None else f.type)
        else:
            for arg in typing.get_args(tp):
                walk(arg)

    walk(cls)
    return frozenset(found)


def _error_class(cls: type, inherited: type[ConfigError]) -> type[ConfigError]:
    declared = getattr(cls, "CONFIG_ERROR", None)
    return declared if isinstance(declared, type) and issubclass(declared, ConfigError) else inherited


# --- what is expected, in words --------------------------------------------------------------
def _num(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def describe(tp: Any) -> str:
    """What a value of type `tp` looks like in a config, in words ("an integer", "a list of 2 (...)")."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Literal:
        return " or ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(describe(a) for a in args if a is not type(None))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of ({describe(args[0])})"
        return f"a list of {len(args)} ({', '.join(describe(a) for a in args)})"
    if origin in (collections.abc.Mapping, dict):
        return f"a mapping of names to ({describe(args[1])})" if len(args) == 2 else "a mapping"
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return f"a mapping with keys {', '.join(config_keys(tp))}"
    names = {int: "an integer", float: "a number", str: "a non-empty string", bool: "true or false",
             Path: "a path (a non-empty string)"}
    if tp is Any:
        return "any value"
    return names.get(tp, str(tp))


def _bounds_text(rules: _Rules) -> str:
    lo = rules.lo if rules.lo is not None else rules.above
    left = "[" if rules.lo is not None else "("
    if lo is not None and rules.hi is not None:
        return f"in {left}{_num(lo)}, {_num(rules.hi)}]"
    if lo is not None:
        return f"{'>=' if rules.lo is not None else '>'} {_num(lo)}"
    if rules.hi is not None:
        return f"<= {_num(rules.hi)}"
    return ""


def _expected(tp: Any, rules: _Rules, *, type_failed: bool) -> str:
    """What a field expects: its type when the type was wrong, else the declared rule."""
    base = describe(tp)
    if rules.expected is not None:
        return f"{base} ({rules.expected})" if type_failed else rules.expected
    if rules.choices is not None:
        return f"one of {', '.join(str(c) for c in rules.choices)}"
    bounds = _bounds_text(rules)
    if bounds:
        scalar = describe(_non_none(tp))
        return f"{scalar} {bounds}"
    return base


def _non_none(tp: Any) -> Any:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(options) == 1:
            return options[0]
    return tp


# --- reading ---------------------------------------------------------------------------------
def _shown(data: Any, secret_keys: Iterable[str]) -> Any:
    """`data` as a message may show it: the values of secret keys hidden."""
    secret = set(secret_keys)
    if isinstance(data, Mapping) and secret:
        return {k: HIDDEN if k in secret else v for k, v in data.items()}
    return data


def _check_keys(data: Mapping[Any, Any], allowed: tuple[str, ...], key_path: str,
                error: type[ConfigError], hide: bool = False) -> None:
    """Refuse keys not in `allowed`; with `hide` (a section holding a secret) without showing
    the value, which may be a secret under a misspelt key."""
    for key in data:
        if key not in allowed:
            raise error(key_path=join_key(key_path, key), value=HIDDEN if hide else data[key],
                        expected=f"a known key ({where(key_path)} takes {', '.join(allowed)}); "
                                 f"{quoted_key(key)} is an unknown key")


def read_config(cls: type[T], data: Any, key_path: str = "", *, file: Any = None) -> T:
    """An instance of dataclass `cls` from the mapping `data` read at `key_path`.

    Raises `ConfigError` (or the section's `CONFIG_ERROR`), its `file` set to `file` when
    given; a field declared with `source="file"` receives `file`.
    """
    try:
        return typing.cast(T, _read_section(cls, data, key_path, _error_class(cls, ConfigError), file))
    except ConfigError as err:
        if file is not None and err.file is None:
            err.file = file
        err.value = shown(err.value, secret_keys(cls))
        raise


def _read_section(cls: type, data: Any, key_path: str, error: type[ConfigError], file: Any) -> Any:
    plan = _plan(cls)
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise error(key_path=key_path, value=data, expected=describe(cls))
    _check_keys(data, plan.keys, key_path, error, hide=bool(plan.secret_keys))
    values: dict[str, Any] = {}
    for f in plan.fields:
        if f.rules.source == "key_path":
            values[f.name] = key_path
        elif f.rules.source == "file":
            if file is not None:
                values[f.name] = file
        elif f.rules.source == "given_keys":
            continue
        elif f.rules.inline is not None:
            given = {k: data[k] for k in f.inline_keys if k in data}
            if typing.get_origin(f.type) in (collections.abc.Mapping, dict):
                values[f.name] = _read_fields(f.rules.inline, given, key_path, error, f.rules.exclude)
            else:
                values[f.name] = _read_section(f.rules.inline, given, key_path,
                                               _error_class(f.rules.inline, error), file)
        elif f.key in data:
            values[f.name] = _read_field(f, data[f.key], join_key(key_path, f.key), error, file)
        elif f.required:
            raise error(key_path=join_key(key_path, f.key), missing=True,
                        expected=_expected(f.type, f.rules, type_failed=True))
    instance = _construct(cls, values, key_path, error)
    for f in plan.fields:
        if f.rules.source == "given_keys":
            object.__setattr__(instance, f.name, frozenset(data))
    return instance


def _read_field(f: _Field, value: Any, key_path: str, error: type[ConfigError], file: Any) -> Any:
    try:
        if f.rules.keys is not None and isinstance(value, Mapping):
            _check_keys(value, f.rules.keys, key_path, error)
            missing = [k for k in f.rules.keys if k not in value]
            if missing:
                raise error(key_path=join_key(key_path, missing[0]), missing=True,
                            expected=f"every one of {', '.join(f.rules.keys)} under {key_path} "
                                     f"(missing: {', '.join(missing)})")
            value = {k: value[k] for k in f.rules.keys}  # in the declared order, whatever the file's
        typed = _read_value(value, f.type, key_path, error, file, f.rules)
        _check_value(typed, f.type, f.rules, key_path, error)
        return typed
    except ConfigError as err:
        if f.rules.secret and err.key_path is not None and err.key_path.startswith(key_path):
            err.value = HIDDEN
        raise


def _check_value(value: Any, tp: Any, rules: _Rules, key_path: str, error: type[ConfigError]) -> None:
    """Raise unless the typed `value` meets the field's declared rules."""
    if value is None or not rules.has_checks:
        return
    ok = True
    if rules.choices is not None:
        ok = value in rules.choices
    if ok and rules.lo is not None:
        ok = value >= rules.lo
    if ok and rules.above is not None:
        ok = value > rules.above
    if ok and rules.hi is not None:
        ok = value <= rules.hi
    if ok and rules.check is not None:
        ok = bool(rules.check(value))
    if not ok:
        raise error(key_path=key_path, value=HIDDEN if rules.secret else value,
                    expected=_expected(tp, rules, type_failed=False))


def read_value(value: Any, tp: Any, key_path: str) -> Any:
    """`value` as type `tp` (any type this module reads), or a `ConfigError` naming `key_path`."""
    return _read_value(value, tp, key_path, ConfigError, None, _Rules())


def _read_value(value: Any, tp: Any, key_path: str, error: type[ConfigError], file: Any, rules: _Rules) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    def fail() -> ConfigError:
        return error(key_path=key_path, value=value, expected=_expected(tp, rules, type_failed=True))

    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:  # Optional[X]: X's own error, which may lie deeper (a section's key)
            try:
                return _read_value(value, options[0], key_path, error, file, _Rules())
            except ConfigError as err:
                if err.key_path == key_path:
                    raise fail() from None
                raise
        for option in options:
            try:
                return _read_value(value, option, key_path, error, file, _Rules())
            except ConfigError:
                continue
        raise fail()
    if origin is Literal:
        if any(type(value) is type(a) and value == a for a in args):
            return value
        raise fail()
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise fail()
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_read_value(v, args[0], f"{key_path}[{i}]", error, file, _Rules())
                         for i, v in enumerate(value))
        if len(value) != len(args):
            raise fail()
        return tuple(_read_value(v, a, f"{key_path}[{i}]", error, file, _Rules())
                     for i, (v, a) in enumerate(zip(value, args)))
    if origin in (collections.abc.Mapping, dict):
        if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
            raise fail()
        item_type = args[1] if len(args) == 2 else Any
        return {k: _read_value(v, item_type, join_key(key_path, k), error, file, _Rules()) for k, v in value.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _read_section(tp, value, key_path, _error_class(tp, error), file)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise fail()
    if tp is int:
        # bool is an int in Python; `true` for a count is a config mistake, not 1.
        if isinstance(value, int) and not isinstance(value, bool):
            if -INT_LIMIT <= value < INT_LIMIT:
                return value
            raise error(key_path=key_path, value=value, expected=f"{describe(tp)} within +-2**63")
        raise fail()
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # an int beyond any float
                raise fail() from None
            if math.isfinite(number):
                return number
        raise fail()
    if tp is str or tp is Path:
        if isinstance(value, str) and value:
            if not _is_text(value):
                raise error(key_path=key_path, value=value,
                            expected=f"{describe(tp)} of text (no NUL character, no lone surrogate)")
            return value if tp is str else Path(value)
        raise fail()
    raise TypeError(f"{key_path}: the config reader cannot read type {tp!r}")


def _is_text(value: str) -> bool:
    """True when `value` can name a file and be printed: no NUL, valid Unicode."""
    if "\0" in value:
        return False
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def read_fields(cls: type, data: Any, key_path: str, *, exclude: Iterable[str] = ()) -> dict[str, Any]:
    """Typed values for the keys `data` gives of dataclass `cls`'s fields (not all of them:
    overrides), unknown keys and `exclude`d fields refused."""
    return _read_fields(cls, data, key_path, _error_class(cls, ConfigError), tuple(exclude))


def _read_fields(cls: type, data: Any, key_path: str, error: type[ConfigError],
                 exclude: tuple[str, ...]) -> dict[str, Any]:
    plan = _plan(cls)
    if data is None:
        data = {}
    allowed = tuple(k for k in plan.keys if k not in exclude)
    if not isinstance(data, Mapping):
        raise error(key_path=key_path, value=data, expected=f"a mapping with keys {', '.join(allowed)}")
    _check_keys(data, allowed, key_path, error, hide=bool(plan.secret_keys))
    by_key = {f.key: f for f in plan.fields}
    return {by_key[k].name: _read_field(by_key[k], v, join_key(key_path, k), error, None) for k, v in data.items()}


# --- errors from a dataclass's own checks ------------------------------------------------------
_LEADING_NAME = re.compile(r"^([A-Za-z_]\w*)(.*)$", re.DOTALL)


def _construct(cls: type, values: dict[str, Any], key_path: str, error: type[ConfigError]) -> Any:
    # `from None`: the original message may hold a secret the new one hides.
    try:
        return cls(**values)
    except ConfigError as err:
        if err.key_path is None or err.expected is None:
            raise config_error_from(err, key_path, values, cls=cls, error=error) from None
        raise _rerooted(err, cls, key_path, error) from None
    except ValueError as err:
        raise config_error_from(err, key_path, values, cls=cls, error=error) from None


def _rerooted(err: ConfigError, cls: type, key_path: str, error: type[ConfigError]) -> ConfigError:
    """`err` (key path relative to a section of `cls`) under the section's key path."""
    plan = _plan(cls)
    match = _LEADING_NAME.match(err.key_path or "")
    relative = err.key_path or ""
    value = err.value
    if match:
        name, rest = match.groups()
        field = plan.by_name.get(name)
        if field is not None:
            relative = field.key + rest
            if field.rules.secret:
                value = HIDDEN
    new_path = join_key(key_path, relative)
    if isinstance(err, error):
        err.key_path, err.value = new_path, value
        return err
    return error(key_path=new_path, value=value, expected=err.expected, missing=err.missing, file=err.file)


def config_error_from(err: ValueError, key_path: str, values: Mapping[str, Any], *, cls: type | None = None,
                      error: type[ConfigError] = ConfigError) -> ConfigError:
    """A `ConfigError` for a ValueError a section's dataclass raised on `values`.

    A message that starts with the name of one of `values` (`confidence_floor must be in
    [0, 1], got 2.0`) names that key; any other names the section, its values shown.
    """
    plan = _plan(cls) if cls is not None else None
    secret = set() if plan is None else {f.name for f in plan.fields if f.rules.secret} | plan.secret_keys
    text = str(err)
    for name in secret:
        if isinstance(values.get(name), str) and values[name]:
            text = text.replace(values[name], repr(HIDDEN))
    match = _LEADING_NAME.match(text)
    if match and match.group(1) in values:
        name, rest = match.groups()
        expected = re.sub(r",\s*got .*$", "", rest.strip(), flags=re.DOTALL)
        expected = re.sub(r"^(?::\s*|\((\w+)\)\s*)?(?:must be |should be )?", "", expected) or text
        field = plan.by_name.get(name) if plan is not None else None
        key = field.key if field is not None else name
        hidden = field is not None and field.rules.secret
        return error(key_path=join_key(key_path, key), value=HIDDEN if hidden else values[name], expected=expected)
    return error(key_path=key_path, value=_shown(dict(values), secret), expected=f"valid settings ({text})")


def check_settings(instance: Any) -> None:
    """Apply the bounds `setting()` declared to a constructed section (call it in `__post_init__`).

    Raises the section's `CONFIG_ERROR` (default `ConfigError`) naming the field."""
    cls: type = type(instance)
    error = _error_class(cls, ConfigError)
    for f in _plan(cls).fields:
        if f.rules.source == "mapping" and f.rules.inline is None:
            _check_value(getattr(instance, f.name), f.type, f.rules, f.name, error)
