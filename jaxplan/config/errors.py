"""pydantic's validation errors -> the contract's one-line messages
(``<file>: <key>: <problem>``, a :class:`ConfigError`)."""

from __future__ import annotations

import dataclasses
import difflib
import functools
import re
from typing import Any

from pydantic import (
    TypeAdapter,
    ValidationError,
    ValidationInfo,
)

from jaxplan.fields import (
    FieldProblem,
    show,
)

# ---------------------------------------------------------------------------------------
# Validation errors -> one line
# ---------------------------------------------------------------------------------------


class InvalidValue(Exception):
    """A problem found while parsing: the key path and the problem (no file yet)."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key
        self.message = message


def _join(prefix: str, key: str) -> str:
    if not prefix or not key:
        return prefix or key
    return prefix + key if key.startswith("[") else f"{prefix}.{key}"


def _key_path(prefix: str, loc: tuple) -> str:
    for part in loc:
        prefix = _join(prefix, f"[{part}]" if isinstance(part, int) else str(part))
    return prefix


def _bound(x: float | int) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


_COMPARISONS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="),
                "less_than": ("lt", "<"), "less_than_equal": ("le", "<=")}
_UNKNOWN_KEY = ("unexpected_keyword_argument", "extra_forbidden")
_WRONG_TYPE = {"float_type": "a number", "int_type": "an integer", "string_type": "a string",
               "finite_number": "a finite number"}


def unknown_key(key: str, allowed: tuple[str, ...]) -> tuple[str, str]:
    """(the key as a message shows it, the problem) of an unknown key."""
    near = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
    hint = f"; did you mean {near[0]!r}?" if near else f"; valid keys: {', '.join(allowed)}"
    return (key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else show(key)), f"unknown key{hint}"


def _unknown_key(key: str, allowed: tuple[str, ...], prefix: str) -> InvalidValue:
    shown, problem = unknown_key(key, allowed)
    return InvalidValue(_join(prefix, shown), problem)


def check_keys(table: dict, allowed: tuple[str, ...], prefix: str) -> None:
    for k in table:
        if k not in allowed:
            raise _unknown_key(k, allowed, prefix)


def as_table(v: Any, key: str) -> dict:
    if not isinstance(v, dict):
        raise InvalidValue(key, f"expected a table, got {show(v)}")
    for k in v:
        if not isinstance(k, str):
            raise InvalidValue(key, f"expected string keys, got {show(k)}")
    return v


def table_keys(t: dict, allowed: tuple[str, ...] | None = None) -> None:
    """Inside a section model's validator: every key of ``t`` is a string, in ``allowed``
    where given (else :class:`FieldProblem` naming it, with the nearest valid key)."""
    for k in t:
        if not isinstance(k, str):
            raise FieldProblem(f"expected string keys, got {show(k)}")
        if allowed is not None and k not in allowed:
            shown, problem = unknown_key(k, allowed)
            raise FieldProblem(problem, key=shown)


def _problem(error: dict, key: str, allowed: tuple[str, ...], missing: str,
             hints: dict[str, str]) -> InvalidValue:
    """One pydantic error (of a value at ``key``) in the config's own words (``hints``:
    the text for a missing field, by name; ``missing`` for any other)."""
    kind, v, loc = error["type"], error.get("input"), tuple(error["loc"])
    ctx = error.get("ctx") or {}
    if kind in _UNKNOWN_KEY:
        return _unknown_key(str(loc[-1]), allowed, _key_path(key, loc[:-1]))
    path = _key_path(key, loc)
    if kind == "value_error" and isinstance(ctx.get("error"), FieldProblem):
        return InvalidValue(_join(path, ctx["error"].key), str(ctx["error"]))
    if kind == "missing":
        return InvalidValue(path, hints.get(str(loc[-1]), missing) if loc else missing)
    if kind == "float_type" and isinstance(v, int) and not isinstance(v, bool):
        return InvalidValue(path, f"number out of range: {show(v)}")
    if kind in _WRONG_TYPE:
        return InvalidValue(path, f"expected {_WRONG_TYPE[kind]}, got {show(v)}")
    if kind == "bool_type":
        return InvalidValue(path, f"expected true or false, got {show(v)}")
    if kind in ("dataclass_type", "dict_type"):
        return InvalidValue(path, f"expected a table, got {show(v)}")
    if kind in _COMPARISONS:
        name, op = _COMPARISONS[kind]
        return InvalidValue(path, f"must be {op} {_bound(ctx[name])}, got {show(v)}")
    if kind == "multiple_of":
        return InvalidValue(path, f"must be a multiple of {ctx['multiple_of']}, got {show(v)}")
    return InvalidValue(path, f"{error['msg']}, got {show(v)}")  # pragma: no cover - a new type


def _priority(error: dict, missing_first: bool) -> int:
    """Unknown keys first, then (``missing_first``) missing ones, then the rest, each in
    declaration order."""
    if error["type"] in _UNKNOWN_KEY:
        return 0
    return 1 if missing_first and error["type"] == "missing" else 2


@functools.cache
def adapter_for(schema: Any) -> TypeAdapter:
    return TypeAdapter(schema)


def _first(schema: Any, value: Any, key: str, context: dict, missing: str,
           missing_first: bool) -> tuple[Any, InvalidValue | None]:
    try:
        return adapter_for(schema).validate_python(value, context=context), None
    except ValidationError as e:
        first = min(e.errors(include_url=False), key=lambda x: _priority(x, missing_first))
        # a section model may name the keys of its table (KEYS) and the text for each
        # missing one (MISSING) where they differ from its fields
        allowed = getattr(schema, "KEYS", None) or (
            tuple(f.name for f in dataclasses.fields(schema))
            if dataclasses.is_dataclass(schema) else ())
        return None, _problem(first, key, allowed, missing, getattr(schema, "MISSING", {}))


def validate_value(schema: Any, value: Any, key: str, *, dim: int | None = None,
                   context: dict | None = None, missing: str = "missing",
                   missing_first: bool = False) -> Any:
    """``value`` validated by ``schema`` (a model or an annotated type; ``dim``: the N
    vectors must have; ``context``: more of the validation context, e.g. the sections a
    model's defaults come from), or :class:`InvalidValue` with the first problem
    (``missing``: the text for a missing key)."""
    out, problem = _first(schema, value, key, {**(context or {}), "dim": dim}, missing,
                          missing_first)
    if problem is not None:
        raise problem from None
    return out


def sub_value(schema: Any, value: Any, key: str, info: ValidationInfo, *,
              dim: int | None = None, missing: str = "missing",
              missing_first: bool = False) -> Any:
    """Inside a section model's validator: ``value`` (at ``key`` within the section)
    validated by ``schema`` in the same context (``dim`` replacing its N where given),
    or :class:`FieldProblem` keyed from the section, which the section's own error then
    carries (the one-line message names the whole key path)."""
    context = dict(info.context or {})
    if dim is not None:
        context["dim"] = dim
    out, problem = _first(schema, value, key, context, missing, missing_first)
    if problem is not None:
        raise FieldProblem(problem.message, key=problem.key) from None
    return out
