"""Validating messages against the topics' JSON Schemas.

``errors(value, schema)`` lists every way a message breaks its schema, one line each, in the
project's words (``$.samples[1]: expected number, got string``). Validation is on a hot path
(``MemoryRecorder``, and ``McapRecorder(validate=True)``, check every message a run writes,
and a large run writes many; readers check what they read), so a message is checked by a
``fastjsonschema`` validator compiled once per schema; only a message that breaks its schema
is then walked (``_errors``) to name every error, in the order the message has its fields
(fastjsonschema stops at the first). The walk knows the keywords our schema files keep to
(``KEYWORDS``, the subset ``topics_markdown`` renders into docs/topics.md) and nothing else:
``check_schema`` refuses a schema that uses another (``format``, for one, would only be an
annotation) or gives one a value JSON Schema (draft 2020-12) would not take, so a keyword is
never silently skipped, and ``fastjsonschema`` compiles it too.

Types are JSON Schema's: ``true`` is no integer and no number; ``1.0`` is an integer.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from typing import Any

from rgtbus.errors import BadLog, RgtbusError

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


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list | tuple):
        return "array"
    if isinstance(value, dict):
        return "object"
    return type(value).__name__


def check_schema(schema: Any, where: str = "schema") -> None:
    """Refuse a schema that is no valid JSON Schema, or uses keywords outside our subset."""
    if not isinstance(schema, dict):
        raise BadLog(f"{where}: a schema must be an object")
    _check_keywords(schema, where)
    import fastjsonschema

    try:
        fastjsonschema.compile(schema)
    except fastjsonschema.JsonSchemaDefinitionException as e:
        raise BadLog(f"{where}: not a valid JSON Schema: {e}") from None


TYPES = ("array", "boolean", "integer", "null", "number", "object", "string")


def _bad(where: str, why: str) -> RgtbusError:
    return BadLog(f"{where}: not a valid JSON Schema: {why}")


def _check_values(schema: dict[str, Any], where: str) -> None:
    """Each keyword's value as draft 2020-12 takes it (the subschemas: ``_check_keywords``)."""
    kind = schema.get("type")
    if "type" in schema:
        kinds = kind if isinstance(kind, list) else [kind]
        bad = [k for k in kinds if k not in TYPES]
        if bad or not kinds or len(set(map(str, kinds))) != len(kinds):
            shown = bad[0] if bad else kind
            raise _bad(f"{where}.type", f"{shown!r} is not valid: a type is one of {TYPES}")
    for key in ("properties",):
        if key in schema and not isinstance(schema[key], dict):
            raise _bad(f"{where}.{key}", "must be an object of schemas")
    if "required" in schema:
        req = schema["required"]
        if not (isinstance(req, list) and all(isinstance(k, str) for k in req)):
            raise _bad(f"{where}.required", "must be a list of field names")
    for key in ("minItems", "maxItems"):
        if key in schema:
            n = schema[key]
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                raise _bad(f"{where}.{key}", f"{n!r} is not a count (an integer >= 0)")
    for key in ("minimum", "maximum"):
        if key in schema:
            n = schema[key]
            if isinstance(n, bool) or not isinstance(n, int | float) or not math.isfinite(n):
                raise _bad(f"{where}.{key}", f"{n!r} is not a number")
    if "enum" in schema and not isinstance(schema["enum"], list):
        raise _bad(f"{where}.enum", f"{schema['enum']!r} is not a list")
    if "oneOf" in schema and not (isinstance(schema["oneOf"], list) and schema["oneOf"]):
        raise _bad(f"{where}.oneOf", "must be a non-empty list of schemas")
    if "additionalProperties" in schema:
        extra = schema["additionalProperties"]
        if not isinstance(extra, bool | dict):
            raise _bad(f"{where}.additionalProperties", "must be a boolean or a schema")
    if "pattern" in schema:
        try:
            re.compile(schema["pattern"])
        except (re.error, TypeError) as e:
            why = f"{schema['pattern']!r} is no regular expression: {e}"
            raise _bad(f"{where}.pattern", why) from None


def _check_keywords(schema: Any, where: str) -> None:
    if not isinstance(schema, dict):
        raise BadLog(f"{where}: a schema must be an object")
    unknown = sorted(set(schema) - KEYWORDS - ANNOTATIONS)
    if unknown:
        raise BadLog(f"{where}: unsupported keyword(s) {', '.join(unknown)}")
    _check_values(schema, where)
    for name, sub in schema.get("properties", {}).items():  # a dict: _check_values
        _check_keywords(sub, f"{where}.properties.{name}")
    for key in ("items", "propertyNames"):
        if key in schema:
            _check_keywords(schema[key], f"{where}.{key}")
    if isinstance(schema.get("additionalProperties"), dict):
        _check_keywords(schema["additionalProperties"], f"{where}.additionalProperties")
    for i, sub in enumerate(schema.get("oneOf", ())):
        _check_keywords(sub, f"{where}.oneOf[{i}]")


# Per schema object (a topic's schema is loaded once: ``topics.load_schema``), the validator
# fastjsonschema compiled for it; each entry holds its schema, so the id stays that schema's.
_BUILT: dict[int, tuple[dict[str, Any], Callable[[Any], Any]]] = {}


def _compiled(schema: dict[str, Any]) -> Callable[[Any], Any]:
    hit = _BUILT.get(id(schema))
    if hit is None or hit[0] is not schema:
        if len(_BUILT) >= 256:
            _BUILT.clear()
        import fastjsonschema

        hit = (schema, fastjsonschema.compile(schema))
        _BUILT[id(schema)] = hit
    return hit[1]


def errors(value: Any, schema: dict[str, Any], path: str = "$") -> list[str]:
    """Every way ``value`` breaks ``schema``, one line each (empty when valid)."""
    validator = _compiled(schema)  # imports fastjsonschema
    try:
        validator(value)
        return []
    except sys.modules["fastjsonschema"].JsonSchemaValueException as e:
        first = f"{path}{e.message.removeprefix('data')}"
    out: list[str] = []
    for line in _errors(value, schema, path):
        if line not in out:
            out.append(line)
    return out or [first]


def _is_type(value: Any, kind: str) -> bool:
    """JSON Schema's types: a boolean is no number, a whole float is an integer."""
    if kind == "null":
        return value is None
    if kind == "boolean":
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if kind == "integer":
        return isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    if kind == "number":
        return isinstance(value, int | float)
    if kind == "string":
        return isinstance(value, str)
    if kind == "array":
        return isinstance(value, list | tuple)
    if kind == "object":
        return isinstance(value, dict)
    return False


def _same(a: Any, b: Any) -> bool:
    """JSON equality (``enum``, ``const``): ``true`` is not 1, 1.0 is 1."""
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, int | float) and isinstance(b, int | float):
        return a == b
    return type(a) is type(b) and bool(a == b)


def _is_valid(value: Any, schema: dict[str, Any]) -> bool:
    return not any(True for _ in _errors(value, schema, "$"))


def _errors(value: Any, schema: dict[str, Any], path: str) -> Any:
    """The lines of every way ``value`` breaks ``schema`` (our keywords), the value's own
    first, then its fields in the order it has them, then its items."""
    kind = schema.get("type")
    if kind is not None:
        kinds = [kind] if isinstance(kind, str) else list(kind)
        if not any(_is_type(value, k) for k in kinds):
            yield f"{path}: expected {' or '.join(kinds)}, got {_type_name(value)}"
            return
    if "const" in schema and not _same(value, schema["const"]):
        yield f"{path}: expected {schema['const']!r}, got {value!r}"
    if "enum" in schema and not any(_same(value, v) for v in schema["enum"]):
        yield f"{path}: {value!r} not one of {schema['enum']!r}"
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if number and "minimum" in schema and value < schema["minimum"]:
        yield f"{path}: {value!r} below minimum {schema['minimum']}"
    if number and "maximum" in schema and value > schema["maximum"]:
        yield f"{path}: {value!r} above maximum {schema['maximum']}"
    if isinstance(value, str) and "pattern" in schema and not re.search(schema["pattern"], value):
        yield f"{path}: {value!r} does not match {schema['pattern']!r}"
    if "oneOf" in schema:
        subs = schema["oneOf"]
        n = sum(_is_valid(value, sub) for sub in subs)
        if n != 1:
            fields = [sub["required"] for sub in subs if set(sub) == {"required"}]
            if isinstance(value, dict) and len(fields) == len(subs):  # one of some fields
                names = " or ".join("+".join(f) for f in fields)
                yield f"{path}: holds {n} of {names}, not exactly 1"
            else:
                yield f"{path}: {value!r} matches {n} of the oneOf alternatives, not exactly 1"
    if isinstance(value, dict):
        yield from _object_errors(value, schema, path)
    if isinstance(value, list | tuple):
        if "minItems" in schema and len(value) < schema["minItems"]:
            yield f"{path}: {len(value)} items, at least {schema['minItems']} needed"
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            yield f"{path}: {len(value)} items, at most {schema['maxItems']} allowed"
        items = schema.get("items")
        if isinstance(items, dict):
            for i, item in enumerate(value):
                yield from _errors(item, items, f"{path}[{i}]")


def _object_errors(value: dict[str, Any], schema: dict[str, Any], path: str) -> Any:
    known = schema.get("properties", {})
    for k in schema.get("required", ()):
        if k not in value:
            yield f"{path}: missing required field {k!r}"
    extra = schema.get("additionalProperties", True)
    if extra is False:
        for k in value:
            if k not in known:
                yield f"{path}: unexpected field {k!r}"
    names = schema.get("propertyNames")
    if isinstance(names, dict):
        for k in value:
            yield from _errors(k, names, f"{path} key {k!r}")
    for k, v in value.items():
        if k in known:
            yield from _errors(v, known[k], f"{path}.{k}")
        elif isinstance(extra, dict):
            yield from _errors(v, extra, f"{path}.{k}")
