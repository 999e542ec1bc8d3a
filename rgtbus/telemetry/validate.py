"""Validating messages against the topics' JSON Schemas, with two libraries.

``errors(value, schema)`` lists every way a message breaks its schema, one line each, in the
project's words (``$.samples[1]: expected number, got string``). Validation is on a hot path
(``MemoryRecorder``, and ``McapRecorder(validate=True)``, check every message a run writes,
and a large run writes many), so a message is first checked by a ``fastjsonschema`` validator
compiled once per schema (fast); only a message that breaks its schema is then taken apart
by ``jsonschema``, which names every error. ``check_schema`` refuses a schema that is not valid
JSON Schema (draft 2020-12), or that uses a keyword outside the subset our schema files keep to
(the one ``topics_markdown`` renders into docs/topics.md; ``format``, for one, would only be an
annotation), so a keyword is never silently skipped.

Types are JSON Schema's: ``true`` is no integer and no number; ``1.0`` is an integer.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from rgtbus.errors import RgtbusError

# fastjsonschema is loaded when the first message is validated (a run that validates nothing
# never needs it), jsonschema (slower to import) only when a message breaks its schema
if TYPE_CHECKING:
    from jsonschema import ValidationError

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
        raise RgtbusError(f"{where}: a schema must be an object")
    from jsonschema import Draft202012Validator
    from jsonschema.exceptions import SchemaError

    _check_keywords(schema, where)
    try:
        Draft202012Validator.check_schema(schema)
    except SchemaError as e:
        path = "".join(f".{p}" if isinstance(p, str) else f"[{p}]" for p in e.path)
        raise RgtbusError(f"{where}{path}: not a valid JSON Schema: {e.message}") from None


def _check_keywords(schema: Any, where: str) -> None:
    if not isinstance(schema, dict):
        raise RgtbusError(f"{where}: a schema must be an object")
    unknown = sorted(set(schema) - KEYWORDS - ANNOTATIONS)
    if unknown:
        raise RgtbusError(f"{where}: unsupported keyword(s) {', '.join(unknown)}")
    for name, sub in schema.get("properties", {}).items():
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
    from jsonschema import Draft202012Validator

    out: list[str] = []
    found = Draft202012Validator(schema).iter_errors(value)
    for err in sorted(found, key=lambda err: _order(err, value)):
        for line in _lines(err, path):
            if line not in out:
                out.append(line)
    return out or [first]


def _order(e: ValidationError, value: Any) -> list[int]:
    """Where ``e`` lies in the message, in the message's own order (fields as they come)."""
    out = []
    for step in e.path:
        if isinstance(value, dict):
            out.append(list(value).index(step) if step in value else -1)
            value = value.get(step)
        elif isinstance(value, list) and isinstance(step, int) and step < len(value):
            out.append(step)
            value = value[step]
    return out


def _where(e: ValidationError, root: str) -> str:
    return root + "".join(f".{p}" if isinstance(p, str) else f"[{p}]" for p in e.path)


def _lines(e: ValidationError, root: str) -> list[str]:
    """``e`` in the project's words (the library's own message for a keyword not named)."""
    path = _where(e, root)
    value: Any = e.instance
    want: Any = e.validator_value
    kind = e.validator
    schema_path = list(e.relative_schema_path)
    if len(schema_path) >= 2 and schema_path[-2] == "propertyNames":  # a key breaks it
        path = f"{path} key {value!r}"
    if kind == "type":
        types = [want] if isinstance(want, str) else list(want)
        return [f"{path}: expected {' or '.join(types)}, got {_type_name(value)}"]
    if kind == "required":
        return [f"{path}: missing required field {k!r}" for k in want if k not in value]
    if kind == "additionalProperties":
        known = e.schema.get("properties", {}) if isinstance(e.schema, dict) else {}
        return [f"{path}: unexpected field {k!r}" for k in value if k not in known]
    if kind == "const":
        return [f"{path}: expected {want!r}, got {value!r}"]
    if kind == "enum":
        return [f"{path}: {value!r} not one of {want!r}"]
    if kind == "oneOf":
        from jsonschema import Draft202012Validator

        n = sum(Draft202012Validator(sub).is_valid(value) for sub in want)
        fields = [sub["required"] for sub in want if set(sub) == {"required"}]
        if isinstance(value, dict) and len(fields) == len(want):  # exactly one of some fields
            names = " or ".join("+".join(f) for f in fields)
            return [f"{path}: holds {n} of {names}, not exactly 1"]
        return [f"{path}: {value!r} matches {n} of the oneOf alternatives, not exactly 1"]
    if kind == "minimum":
        return [f"{path}: {value!r} below minimum {want}"]
    if kind == "maximum":
        return [f"{path}: {value!r} above maximum {want}"]
    if kind == "pattern":
        return [f"{path}: {value!r} does not match {want!r}"]
    if kind == "minItems":
        return [f"{path}: {len(value)} items, at least {want} needed"]
    if kind == "maxItems":
        return [f"{path}: {len(value)} items, at most {want} allowed"]
    return [f"{path}: {e.message}"]
