"""The one name for values that are arbitrary JSON: API bodies and answers, events, raw config documents.

Such a value is checked where it is read (a config by `drivers.config.reader`, an answer by the
code that takes a field out of it); everything with a known shape has its own type instead.
"""
from __future__ import annotations

from typing import Any, TypeAlias

JSON: TypeAlias = Any  # null, bool, number, string, array or object, nested to any depth
JSONObject: TypeAlias = dict[str, JSON]
