"""YAML text written node by node, so that a test can write what a YAML library would refuse to:
a key twice in one mapping, a raw scalar such as `.nan` or `!!binary`. For the hostile configs
(`tests/headctl/config/test_hostile.py`, `benchmarks/hostile/configs.py`)."""
from __future__ import annotations

import json
import math
from typing import Any


class Map(list):
    """A mapping as (key, value) pairs: a key may appear twice."""


class Raw(str):
    """YAML text written as it is."""


def tree(value: Any) -> Any:
    if isinstance(value, dict):
        return Map((k, tree(v)) for k, v in value.items())
    if isinstance(value, list):
        return [tree(v) for v in value]
    return value


def emit(node: Any) -> str:
    if isinstance(node, Raw):
        return str(node)
    if isinstance(node, Map):
        return "{" + ", ".join(f"{emit(k)}: {emit(v)}" for k, v in node) + "}"
    if isinstance(node, list):
        return "[" + ", ".join(emit(v) for v in node) + "]"
    if node is None:
        return "null"
    if isinstance(node, bool):
        return "true" if node else "false"
    if isinstance(node, float):
        if math.isnan(node):
            return ".nan"
        if math.isinf(node):
            return ".inf" if node > 0 else "-.inf"
        return repr(node)
    if isinstance(node, int):
        return str(node)
    return json.dumps(node)  # a double-quoted YAML scalar
