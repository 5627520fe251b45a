"""Protobuf messages read by the schema a Foxglove server advertises, for the tests.

A channel's `schema` (protobuf encoding) is a base64 `FileDescriptorSet`; this reads the
descriptors in it (descriptor.proto's field numbers: a file's messages are field 4, a message's
name 1, fields 2 and nested messages 3; a field's name 1, number 3, label 4, type 5, type name 6)
and decodes a message by them into a dict of field names (repeated fields as lists, fields not
sent absent). Only what the Foxglove schemas use: no groups, no maps, no extensions.
"""
from __future__ import annotations

import base64
import struct
from dataclasses import dataclass
from typing import Any

_REPEATED = 3
_DOUBLE, _FLOAT, _MESSAGE, _STRING, _BYTES, _ENUM = 1, 2, 11, 9, 12, 14
_FIXED64 = {1: "<d", 6: "<Q", 16: "<q"}
_FIXED32 = {2: "<f", 7: "<I", 15: "<i"}


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = data[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, i


def wire_fields(data: bytes) -> list[tuple[int, int, Any]]:
    """(field number, wire type, raw value) of each field in `data`, in order."""
    out, i = [], 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 1:
            value, i = data[i:i + 8], i + 8
        elif wire == 2:
            n, i = _varint(data, i)
            value, i = data[i:i + n], i + n
        elif wire == 5:
            value, i = data[i:i + 4], i + 4
        else:
            raise ValueError(f"wire type {wire} (field {number}) is not read here")
        out.append((number, wire, value))
    return out


@dataclass(frozen=True)
class Field:
    name: str
    number: int
    repeated: bool
    type: int
    type_name: str  # ".package.Message" for messages and enums


def descriptors(schema_b64: str) -> dict[str, dict[int, Field]]:
    """Every message of a FileDescriptorSet: full name ("foxglove.JointStates") -> fields by number."""
    messages: dict[str, dict[int, Field]] = {}

    def message(raw: bytes, scope: str) -> None:
        parts = wire_fields(raw)
        name = next(v.decode() for n, _, v in parts if n == 1)
        full = f"{scope}.{name}" if scope else name
        fields: dict[int, Field] = {}
        for n, _, v in parts:
            if n == 2:
                f = {k: val for k, _, val in wire_fields(v)}
                fields[f[3]] = Field(f[1].decode(), f[3], f.get(4) == _REPEATED, f[5], f.get(6, b"").decode())
            elif n == 3:
                message(v, full)
        messages[full] = fields

    for n, _, file in wire_fields(base64.b64decode(schema_b64)):
        if n != 1:
            continue
        parts = wire_fields(file)
        package = next((v.decode() for k, _, v in parts if k == 2), "")
        for k, _, raw in parts:
            if k == 4:
                message(raw, package)
    return messages


def _scalar(field: Field, wire: int, raw: Any) -> Any:
    if wire == 0:
        if field.type in (17, 18):  # sint: zigzag
            return (raw >> 1) ^ -(raw & 1)
        if field.type in (3, 5) and raw >= 1 << 63:
            return raw - (1 << 64)
        return bool(raw) if field.type == 8 else raw
    if wire == 1:
        return struct.unpack(_FIXED64[field.type], raw)[0]
    if wire == 5:
        return struct.unpack(_FIXED32[field.type], raw)[0]
    raise ValueError(f"{field.name}: wire type {wire} for type {field.type}")


def decode(messages: dict[str, dict[int, Field]], name: str, data: bytes) -> dict[str, Any]:
    """The message `name` in `data`, by the descriptors."""
    fields = messages[name]
    out: dict[str, Any] = {}
    for number, wire, raw in wire_fields(data):
        field = fields.get(number)
        if field is None:
            continue
        if field.type == _MESSAGE:
            values = [decode(messages, field.type_name.lstrip("."), raw)]
        elif field.type == _STRING:
            values = [raw.decode()]
        elif field.type == _BYTES:
            values = [bytes(raw)]
        elif wire == 2:  # a packed repeated scalar
            values = []
            if field.type in _FIXED64 or field.type in _FIXED32:
                fmt = _FIXED64.get(field.type) or _FIXED32[field.type]
                values = [v for (v,) in struct.iter_unpack(fmt, raw)]
            else:
                i = 0
                while i < len(raw):
                    v, i = _varint(raw, i)
                    values.append(_scalar(field, 0, v))
        else:
            values = [_scalar(field, wire, raw)]
        if field.repeated:
            out.setdefault(field.name, []).extend(values)
        else:
            out[field.name] = values[-1]
    return out
