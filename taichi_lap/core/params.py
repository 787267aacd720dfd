"""Typed parameters and the checking of values read from files against them.

Every value a scene file, a script or a generator takes is described by a
:class:`Param` (kind, default, range, choices). :func:`check_table` validates one
TOML table against such a description: unknown keys, wrong types and out-of-range
values raise :class:`InputError` naming the file and the dotted key, and saying what
was expected and what was found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from taichi_lap.core.errors import InputError

KINDS = ("float", "int", "bool", "str", "strlist", "vec3", "vec3list", "intlist")

REQUIRED = object()
"""Marks a :class:`Param` default that must be given in the file."""


@dataclass(frozen=True)
class Param:
    """One parameter: ``kind`` is one of :data:`KINDS`; ``lo``/``hi`` bound numbers
    (and every component of vectors) inclusively; ``choices`` lists the allowed
    strings; ``unit`` is shown in the docs (``m``, ``rad``, ...)."""

    kind: str
    default: Any
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    unit: str = ""


def describe(value: Any) -> str:
    """A short description of a TOML value for error messages."""
    names = {
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "an array",
        dict: "a table",
    }
    kind = names.get(type(value), type(value).__name__)
    text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{kind} {text}" if not isinstance(value, dict) else kind


def _number(file: str, key: str, value: Any, param: Param, integer: bool) -> float | int:
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok:
        expected = "an integer" if integer else "a number"
        raise InputError(file, key, f"{expected} was expected, found {describe(value)}")
    if not math.isfinite(value):
        raise InputError(file, key, f"a finite number was expected, found {value!r}")
    _check_range(file, key, value, param)
    return int(value) if integer else float(value)


def _check_range(file: str, key: str, value: float, param: Param):
    unit = f" {param.unit}" if param.unit else ""
    if param.lo is not None and value < param.lo or param.hi is not None and value > param.hi:
        lo = "-inf" if param.lo is None else f"{param.lo:g}"
        hi = "inf" if param.hi is None else f"{param.hi:g}"
        raise InputError(file, key, f"a value in [{lo}, {hi}]{unit} was expected, found {value!r}")


def _vec3(file: str, key: str, value: Any, param: Param) -> list[float]:
    if not isinstance(value, list) or len(value) != 3:
        raise InputError(file, key, f"an array of 3 numbers was expected, found {describe(value)}")
    return [_number(file, f"{key}[{k}]", v, param, integer=False) for k, v in enumerate(value)]


def check_value(file: str, key: str, value: Any, param: Param) -> Any:
    """Return ``value`` converted to the param's kind, or raise :class:`InputError`."""
    kind = param.kind
    if kind == "float":
        return _number(file, key, value, param, integer=False)
    if kind == "int":
        return _number(file, key, value, param, integer=True)
    if kind == "bool":
        if not isinstance(value, bool):
            raise InputError(file, key, f"true or false was expected, found {describe(value)}")
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise InputError(file, key, f"a string was expected, found {describe(value)}")
        if param.choices is not None and value not in param.choices:
            raise InputError(
                file, key, f"one of {', '.join(param.choices)} was expected, found {value!r}"
            )
        return value
    if kind == "strlist":
        if not isinstance(value, list):
            raise InputError(
                file, key, f"an array of strings was expected, found {describe(value)}"
            )
        for k, item in enumerate(value):
            if not isinstance(item, str):
                raise InputError(
                    file, f"{key}[{k}]", f"a string was expected, found {describe(item)}"
                )
        return list(value)
    if kind == "vec3":
        return _vec3(file, key, value, param)
    if kind == "vec3list":
        if not isinstance(value, list) or not value:
            raise InputError(
                file,
                key,
                f"a non-empty array of [x, y, z] points was expected, found {describe(value)}",
            )
        return [_vec3(file, f"{key}[{k}]", v, param) for k, v in enumerate(value)]
    if kind == "intlist":
        if not isinstance(value, list) or not value:
            raise InputError(
                file, key, f"a non-empty array of integers was expected, found {describe(value)}"
            )
        return [_number(file, f"{key}[{k}]", v, param, integer=True) for k, v in enumerate(value)]
    raise ValueError(f"unknown parameter kind {kind!r}")


def check_table(
    file: str, prefix: str, table: Any, params: dict[str, Param], *, ignore: tuple[str, ...] = ()
) -> dict[str, Any]:
    """Validate ``table`` against ``params``; return a complete dict with defaults.

    Keys in ``ignore`` are left for the caller. A default of :data:`REQUIRED` makes
    the key mandatory; a default of ``None`` means "optional, no value"."""
    where = prefix or "(top level)"
    if not isinstance(table, dict):
        raise InputError(file, prefix, f"a table was expected, found {describe(table)}")
    for key in table:
        if key not in params and key not in ignore:
            known = ", ".join(sorted(params)) or "none"
            raise InputError(
                file, _join(prefix, key), f"unknown key in {where}; expected one of: {known}"
            )
    out = {}
    for key, param in params.items():
        if key in table:
            out[key] = check_value(file, _join(prefix, key), table[key], param)
        elif param.default is REQUIRED:
            raise InputError(file, _join(prefix, key), f"this key is required ({param.doc})")
        else:
            out[key] = param.default
    return out


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key
