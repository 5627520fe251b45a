"""Config sections with presets: `model:` names a set of typical values, each key given overrides one.

A section with presets has a `model` field and one Optional field per value (None: the
preset's); the values themselves are a frozen dataclass of the same field names, one instance
per preset. `resolve(section, presets)` gives the values the section stands for.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

P = TypeVar("P")


def resolve(section: Any, presets: Mapping[str, P]) -> P:
    """The preset `section.model` names, each of its fields the section gives (not None) replaced."""
    preset = presets[section.model]
    given = {f.name: getattr(section, f.name) for f in dataclasses.fields(preset)  # type: ignore[arg-type]
             if getattr(section, f.name, None) is not None}
    resolved: P = dataclasses.replace(preset, **given)  # type: ignore[type-var]
    return resolved
