"""The schema registry: field specs, ``Schema`` and ``define``; every concern module (sensor, nav, learn,
status) registers its schemas here, and ``zennav.messages.validate`` checks decoded maps against them.

Field specs: INT, FLOAT, STR, BOOL, MAP, ANY, ``VEC(n)`` a float list of length n, FLOATS a float list of any
length, INTS an int list, STRS a str list, ``OPT(spec)`` None (or absent) allowed. The header fields are
common to every schema.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

INT, FLOAT, STR, BOOL, MAP, ANY = "int", "float", "str", "bool", "map", "any"
FLOATS = ("floats",)
INTS = ("ints",)
STRS = ("strs",)


def VEC(n: int) -> tuple:
    return ("vec", n)


def OPT(spec) -> tuple:
    return ("opt", spec)


HEADER = {"schema": STR, "v": INT, "t_ns": INT, "src": STR, "seq": INT, "pub_ns": INT}
SENSOR = {"cseq": INT}


@dataclass(frozen=True)
class Schema:
    """name, version, fields (header included) and, where a schema needs more than per-field checks, ``check``:
    a function of the type-checked map that returns '' or 'code: detail'."""

    name: str
    version: int
    fields: dict
    doc: str = ""
    check: Callable[[dict], str] | None = None


SCHEMAS: dict[str, Schema] = {}


def define(schema_name: str, schema_version: int, doc: str, /, check=None, **spec) -> Schema:
    """Register a schema (header fields added) and return it."""
    s = SCHEMAS[schema_name] = Schema(schema_name, schema_version, {**HEADER, **spec}, doc, check)
    return s
