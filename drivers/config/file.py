"""Reading a config file: the one way a YAML file becomes plain data for the typed reader.

Kept apart from the reader (`drivers.config.reader`), which takes plain mappings from wherever they
come: this module is about bytes and YAML. `read_yaml_file(path)` reads at most
`MAX_FILE_BYTES`, UTF-8 only (a UTF-16 or UTF-32 file is named as such, a NUL character
refused), through PyYAML's safe loader with duplicate keys refused (naming the key path and
both lines), nesting bounded (`MAX_DEPTH`, aliases expanded), values bounded (`MAX_VALUES`,
aliases expanded) and integers of at most `MAX_INT_CHARS` characters. Every failure is a
`ConfigError` naming the file and the line, column or key path. `read_bounded` reads any small
file (a token file) without reading past its bound.
"""
from __future__ import annotations

import codecs
import os
import typing
from collections.abc import Iterable
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from drivers.config.messages import Shown, join_key, key_text, quoted_key, where
from drivers.errors import ConfigError

MAX_FILE_BYTES = 1 << 20  # 1 MiB; a head's config is a few kB
MAX_DEPTH = 32  # nesting levels, aliases expanded; a head's config uses 5
MAX_VALUES = 100_000  # values (scalars, lists, mappings), aliases expanded; a head's config has a few hundred
MAX_INT_CHARS = 40  # characters of an integer; int64 needs 20


class _YamlRefused(Exception):
    """What the loader refuses in a well-formed document: a duplicate key, nesting too deep,
    too many values. Carries the key path and the position."""

    def __init__(self, key_path: str, message: str, value: Any = None, expected: str | None = None) -> None:
        super().__init__(message)
        self.key_path, self.message, self.value, self.expected = key_path, message, value, expected


def _at(mark: Any) -> str:
    return f"line {mark.line + 1}, column {mark.column + 1}"


if yaml.__with_libyaml__:
    from yaml._yaml import CParser

    class _SafeLoader(yaml.composer.Composer, yaml.constructor.SafeConstructor, yaml.resolver.Resolver, CParser):
        """PyYAML's safe loader with libyaml's scanner and parser (six times faster) under
        PyYAML's own composer, which `_StrictLoader` extends (libyaml's composes in C)."""

        def __init__(self, text: str) -> None:
            CParser.__init__(self, text)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)
            yaml.composer.Composer.__init__(self)
else:  # pragma: no cover - PyYAML built without libyaml
    _SafeLoader = yaml.SafeLoader  # type: ignore[misc,assignment]


class _StrictLoader(_SafeLoader):
    """PyYAML's safe loader refusing duplicate keys, deep nesting and very long integers, and
    keeping each mapping's key path for messages."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self._path: list[str] = []
        self.key_paths: dict[Node, str] = {}

    @staticmethod
    def joined(segments: Iterable[str]) -> str:
        path = ""
        for segment in segments:
            path = path + segment if segment.startswith("[") or not path else f"{path}.{segment}"
        return path

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        if parent is None:
            segment = None
        elif isinstance(index, int):
            segment = f"[{index}]"
        elif isinstance(index, ScalarNode):
            segment = key_text(index.value)
        else:
            segment = "(key)"  # inside a mapping's key, or a key that is itself a list or mapping
        if segment is not None:
            self._path.append(segment)
        try:
            if len(self._path) > MAX_DEPTH:
                shown_path = self.joined(self._path[:8]) + "..."
                event = typing.cast(Any, self).peek_event()  # PyYAML's parser is unannotated
                raise _YamlRefused(shown_path, f"nested deeper than {MAX_DEPTH} levels at "
                                               f"{_at(event.start_mark)} (a head's config needs 5)")
            node = super().compose_node(parent, index)
            if isinstance(node, MappingNode) and node not in self.key_paths:
                self.key_paths[node] = self.joined(self._path)
            return node
        finally:
            if segment is not None:
                self._path.pop()

    def construct_object(self, node: Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep)
        except (ValueError, OverflowError, TypeError) as err:  # a date out of range, an odd tag's value
            raise yaml.constructor.ConstructorError(None, None, f"cannot read this value ({err})",
                                                    node.start_mark) from None

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        # Explicit keys once each; keys merged in with `<<` may be overridden, as YAML says.
        seen: dict[Any, Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:  # an unhashable key: SafeConstructor refuses it, located
                continue
            if first is not None:
                path = self.key_paths.get(node, "")
                raise _YamlRefused(
                    join_key(path, key), "duplicate key",
                    value=Shown(f"a second {quoted_key(key)} key at {_at(key_node.start_mark)} (the first is at "
                                f"{_at(first.start_mark)})"),
                    expected=f"each key once in {where(path)} (YAML would silently keep the last)")
            seen[key] = key_node
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node: ScalarNode) -> int:
        if len(node.value) > MAX_INT_CHARS:
            raise yaml.constructor.ConstructorError(
                None, None, f"an integer of {len(node.value)} characters (at most {MAX_INT_CHARS})", node.start_mark)
        value: int = super().construct_yaml_int(node)
        return value


# Its own table (as `add_constructor` would make it), with the bounded int.
_StrictLoader.yaml_constructors = {**_StrictLoader.yaml_constructors,
                                   "tag:yaml.org,2002:int": _StrictLoader.construct_yaml_int}


def _check_expansion(loader: _StrictLoader, root: Node) -> None:
    """Refuse a document whose aliases make it deeper than MAX_DEPTH, larger than MAX_VALUES
    values, or recursive; aliases are followed as the reader will follow them."""
    sizes: dict[Node, tuple[int, int]] = {}  # node -> (values, height), aliases expanded
    active: set[Node] = set()

    def children(node: Node) -> list[Node]:
        if isinstance(node, SequenceNode):
            return list(node.value)
        if isinstance(node, MappingNode):
            return [n for pair in node.value for n in pair]
        return []

    def measure(node: Node, depth: int) -> tuple[int, int]:
        known = sizes.get(node)
        if known is None:
            if node in active:
                raise _YamlRefused(loader.key_paths.get(node, ""),
                                   f"a recursive alias at {_at(node.start_mark)} (an anchor used inside itself)")
            if depth > MAX_DEPTH:
                raise _YamlRefused("", f"aliases nest deeper than {MAX_DEPTH} levels at {_at(node.start_mark)}")
            active.add(node)
            count, height = 1, 1
            for child in children(node):
                child_count, child_height = measure(child, depth + 1)
                count += child_count
                height = max(height, child_height + 1)
                if count > MAX_VALUES:
                    raise _YamlRefused("", f"more than {MAX_VALUES} values (aliases expanded) at "
                                           f"{_at(node.start_mark)} (a head's config has a few hundred)")
            active.discard(node)
            known = sizes[node] = (count, height)
        if depth + known[1] - 1 > MAX_DEPTH:
            raise _YamlRefused("", f"aliases nest deeper than {MAX_DEPTH} levels at {_at(node.start_mark)}")
        return known

    measure(root, 1)


def parse_yaml(text: str, file: Any = None) -> Any:
    """The plain data of one YAML document, read strictly (see the module's docstring);
    `ConfigError` naming `file` and the line, column or key path."""
    loader: _StrictLoader | None = None
    try:
        loader = _StrictLoader(text)  # the reader checks every character here
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(loader, node)
        return loader.construct_document(node)
    except _YamlRefused as err:
        if err.expected is not None:
            raise ConfigError(key_path=err.key_path, value=err.value, expected=err.expected, file=file) from None
        raise ConfigError(err.message, key_path=err.key_path or None, file=file) from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f" at {_at(mark)}" if mark is not None else ""
        context = ""
        if err.context and err.context_mark is not None and err.context_mark is not mark:
            context = f" ({err.context} at {_at(err.context_mark)})"
        raise ConfigError(f"not valid YAML{where}: {err.problem or err.context}{context}", file=file) from None
    except yaml.reader.ReaderError as err:
        # A position in the UTF-8 bytes (libyaml) or in the characters (PyYAML's reader).
        before = text.encode("utf-8", errors="surrogatepass")[:err.position].decode("utf-8", errors="replace") \
            if yaml.__with_libyaml__ else text[:err.position]
        line = before.count("\n") + 1
        column = len(before) - (before.rfind("\n") + 1) + 1
        raise ConfigError(f"not valid YAML at line {line}, column {column}: character U+{err.character:04X} is "
                          "not allowed in YAML (a control character)", file=file) from None
    except yaml.YAMLError as err:
        raise ConfigError(f"not valid YAML: {err}", file=file) from None
    except UnicodeError as err:  # text that is not Unicode (a lone surrogate) given by a caller
        raise ConfigError(f"not valid text: {err}", file=file) from None
    finally:
        if loader is not None:
            loader.dispose()


def decode_utf8(raw: bytes, file: Any = None) -> str:
    """`raw` as UTF-8 text (a leading byte order mark dropped); ConfigError naming `file` and
    where the first byte that is not UTF-8 text lies."""
    for bom, name in ((codecs.BOM_UTF32_LE, "UTF-32"), (codecs.BOM_UTF32_BE, "UTF-32"),
                      (codecs.BOM_UTF16_LE, "UTF-16"), (codecs.BOM_UTF16_BE, "UTF-16")):
        if raw.startswith(bom):
            raise ConfigError(f"not UTF-8: {name} text (it starts with a {name} byte order mark); save it as UTF-8",
                              file=file)
    if raw.startswith(codecs.BOM_UTF8):
        raw = raw[len(codecs.BOM_UTF8):]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        line_start = raw.rfind(b"\n", 0, err.start) + 1
        column = len(raw[line_start:err.start].decode("utf-8", errors="replace")) + 1
        raise ConfigError(f"not UTF-8: byte 0x{raw[err.start]:02x} at line {line}, column {column} is not UTF-8 "
                          "text; save the file as UTF-8", file=file) from None
    nul = text.find("\0")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        column = nul - (text.rfind("\n", 0, nul) + 1) + 1
        raise ConfigError(f"not UTF-8 text: a NUL character at line {line}, column {column} (UTF-16 without a byte "
                          "order mark?); save the file as UTF-8", file=file)
    return text


def read_bounded(path: str | os.PathLike[str], max_bytes: int) -> bytes | None:
    """The bytes of a file, or None when it holds more than `max_bytes`: it is read no
    further, so a device or an endless file costs nothing. OSError when it cannot be read
    (a path holding a NUL included)."""
    try:
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
    except ValueError as err:  # a NUL in the path
        raise OSError(str(err)) from None
    return raw if len(raw) <= max_bytes else None


def read_yaml_file(path: str | os.PathLike[str], *, max_bytes: int = MAX_FILE_BYTES) -> Any:
    """The document of a YAML config file as plain data: at most `max_bytes`, UTF-8, parsed
    strictly (`parse_yaml`). `ConfigError` naming the file (and the line, column or key path)."""
    try:
        raw = read_bounded(path, max_bytes)
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror or err}", file=path) from None
    if raw is None:
        raise ConfigError(f"larger than {max_bytes} bytes ({max_bytes / 1048576:g} MiB): not a config file "
                          "(a head's config is a few kB)", file=path)
    return parse_yaml(decode_utf8(raw, path), path)
