"""How config errors show what they name: secrets hidden, long values abbreviated, keys printable.

Shared by the typed reader (`drivers.config.reader`), the config file reader (`drivers.config.file`)
and the service's config (`headctl.config.api`), so that a value, a mapping key or a key path
looks the same in every config error: a secret's value is `HIDDEN` (`<hidden>`), a value whose
repr is longer than `MAX_SHOWN` characters is abbreviated (`shown`, a `Shown`), and a key in a
key path is printable and short (`key_text`).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

MAX_SHOWN = 200  # characters of a value a message shows; a longer one is abbreviated


class _Hidden:
    """Stands for a secret's value in errors and in sections shown in a message."""

    def __repr__(self) -> str:
        return "<hidden>"


HIDDEN: Any = _Hidden()


class Shown:
    """A value as a message shows it where that is not the value's repr: abbreviated, or said
    in words ("a second 'min_angle' key on line 12")."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def key_text(key: Any) -> str:
    """A mapping key as a key path shows it: as written when it is a short printable name,
    else its (abbreviated) repr, so that a key path never carries control characters."""
    if isinstance(key, str) and key and key.isprintable() and len(key) <= 64:
        return key
    try:
        text = repr(key)
    except ValueError:  # an int beyond the interpreter's digit limit
        text = f"<{type(key).__name__}>"
    return text if len(text) <= 64 else f"{text[:60]}...{text[-1]}"


def quoted_key(key: Any) -> str:
    """A key quoted for a sentence: 'pan', or the repr `key_text` already gave an odd key."""
    text = key_text(key)
    return repr(text) if text == key else text


def join_key(key_path: str, key: Any) -> str:
    """`key_path` with `key` appended (`servo_bus.joints` + `pan`)."""
    text = key_text(key)
    return f"{key_path}.{text}" if key_path else text


def where(key_path: str) -> str:
    """A key path as a sentence names its place: the empty one is "the top level"."""
    return key_path or "the top level"


def _hide(value: Any, secret: frozenset[str], depth: int = 0) -> Any:
    """`value` with the values of `secret` keys hidden at any depth; `value` itself when
    nothing is hidden."""
    if depth > 64:
        return value
    if isinstance(value, Mapping):
        items = {k: HIDDEN if k in secret else _hide(v, secret, depth + 1) for k, v in value.items()}
        return items if any(items[k] is not v for k, v in value.items()) else value
    if isinstance(value, (list, tuple)):
        hidden = [_hide(v, secret, depth + 1) for v in value]
        return type(value)(hidden) if any(h is not v for h, v in zip(hidden, value)) else value
    return value


def shown(value: Any, secret: Iterable[str] = ()) -> Any:
    """`value` as a message shows it: the values of `secret` keys hidden at any depth, and
    abbreviated (a `Shown`) when its repr is longer than `MAX_SHOWN` characters."""
    if value is HIDDEN or isinstance(value, Shown):
        return value
    value = _hide(value, frozenset(secret))
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # an int beyond the digit limit, a structure too deep
        return Shown(f"<{type(value).__name__}>")
    if len(text) <= MAX_SHOWN:
        return value
    return Shown(f"{text[:MAX_SHOWN]}... ({len(text)} characters)")
