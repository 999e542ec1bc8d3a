"""A tiny validator for the subset of JSON Schema our schema files use (no new dependency).

Supported: type (name or list), properties, required, additionalProperties (bool or schema),
propertyNames, items, minItems, maxItems, enum, const, oneOf, minimum, maximum, pattern.
Annotations (title, description, $comment, $schema, $id) are ignored. A schema using anything
else is refused, so a keyword is never silently skipped.
"""

from __future__ import annotations

import re
from functools import cache
from typing import Any

from rgtbus.errors import RgtbusError

KEYWORDS = frozenset(
    {
        "type",
        "properties",
        "required",
        "additionalProperties",
        "propertyNames",
        "items",
        "minItems",
        "maxItems",
        "enum",
        "const",
        "oneOf",
        "minimum",
        "maximum",
        "pattern",
    }
)
ANNOTATIONS = frozenset({"title", "description", "$comment", "$schema", "$id"})


def _is(value: Any, t: str) -> bool:
    # bool is an int in Python, never a number in JSON
    if t == "object":
        return isinstance(value, dict)
    if t == "array":
        return isinstance(value, list | tuple)
    if t == "string":
        return isinstance(value, str)
    if t == "boolean":
        return isinstance(value, bool)
    if t == "null":
        return value is None
    if t == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if t == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    raise RgtbusError(f"schema type {t!r} not supported by the validator")


def _type_name(value: Any) -> str:
    for t in ("null", "boolean", "integer", "number", "string", "array", "object"):
        if _is(value, t):
            return t
    return type(value).__name__


@cache
def _regex(pattern: str) -> re.Pattern[str]:
    return re.compile(pattern)


def check_schema(schema: Any, where: str = "schema") -> None:
    """Refuse schema keywords the validator does not implement."""
    if not isinstance(schema, dict):
        raise RgtbusError(f"{where}: a schema must be an object")
    unknown = sorted(set(schema) - KEYWORDS - ANNOTATIONS)
    if unknown:
        raise RgtbusError(f"{where}: unsupported keyword(s) {', '.join(unknown)}")
    for name, sub in schema.get("properties", {}).items():
        check_schema(sub, f"{where}.properties.{name}")
    for key in ("items", "propertyNames"):
        if key in schema:
            check_schema(schema[key], f"{where}.{key}")
    if isinstance(schema.get("additionalProperties"), dict):
        check_schema(schema["additionalProperties"], f"{where}.additionalProperties")
    for i, sub in enumerate(schema.get("oneOf", ())):
        check_schema(sub, f"{where}.oneOf[{i}]")


def errors(value: Any, schema: dict[str, Any], path: str = "$") -> list[str]:
    """Every way ``value`` breaks ``schema``, one line each (empty when valid)."""
    out: list[str] = []
    if "type" in schema:
        types = [schema["type"]] if isinstance(schema["type"], str) else schema["type"]
        if not any(_is(value, t) for t in types):
            return [f"{path}: expected {' or '.join(types)}, got {_type_name(value)}"]
    if "const" in schema and not (
        value == schema["const"] and _type_name(value) == _type_name(schema["const"])
    ):
        out.append(f"{path}: expected {schema['const']!r}, got {value!r}")
    if "enum" in schema and value not in schema["enum"]:
        out.append(f"{path}: {value!r} not one of {schema['enum']!r}")
    if "oneOf" in schema:
        n = sum(not errors(value, sub, path) for sub in schema["oneOf"])
        if n != 1:
            out.append(f"{path}: {value!r} matches {n} of the oneOf alternatives, not exactly 1")
    if _is(value, "number"):
        if "minimum" in schema and value < schema["minimum"]:
            out.append(f"{path}: {value!r} below minimum {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            out.append(f"{path}: {value!r} above maximum {schema['maximum']}")
    if (
        isinstance(value, str)
        and "pattern" in schema
        and not _regex(schema["pattern"]).search(value)
    ):
        out.append(f"{path}: {value!r} does not match {schema['pattern']!r}")
    if _is(value, "array"):
        if "minItems" in schema and len(value) < schema["minItems"]:
            out.append(f"{path}: {len(value)} items, at least {schema['minItems']} needed")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            out.append(f"{path}: {len(value)} items, at most {schema['maxItems']} allowed")
        if "items" in schema:
            for i, item in enumerate(value):
                out += errors(item, schema["items"], f"{path}[{i}]")
    if isinstance(value, dict):
        props = schema.get("properties", {})
        for key in schema.get("required", ()):
            if key not in value:
                out.append(f"{path}: missing required field {key!r}")
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            if not isinstance(key, str):
                out.append(f"{path}: key {key!r} is not a string")
                continue
            if "propertyNames" in schema:
                out += errors(key, schema["propertyNames"], f"{path} key {key!r}")
            if key in props:
                out += errors(item, props[key], f"{path}.{key}")
            elif extra is False:
                out.append(f"{path}: unexpected field {key!r}")
            elif isinstance(extra, dict):
                out += errors(item, extra, f"{path}.{key}")
    return out
