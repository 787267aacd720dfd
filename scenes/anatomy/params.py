"""Typed parameters of the procedural anatomy generators.

Scene files name a generator and set some of its parameters; the scene loader
checks each value against the :class:`Param` here (type, range, choices) and fills
in the defaults, so a generator always receives a complete, valid ``dict``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

KINDS = ("float", "int", "bool", "str", "vec3", "vec3list", "intlist")


@dataclass(frozen=True)
class Param:
    """One generator parameter: ``kind`` is one of :data:`KINDS`; ``lo``/``hi``
    bound numbers (and every component of vectors) inclusively; ``choices`` lists
    the allowed strings; ``unit`` is shown in the docs (``m``, ``rad``, ...)."""

    kind: str
    default: Any
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    unit: str = ""


@dataclass(frozen=True)
class Generator:
    """A procedural geometry: ``build(params) -> Geometry`` (see
    :mod:`taichi_lap.build.geometry`), the parameters it takes and what it makes
    (``"solid"``, ``"surface"`` or ``"spring_sheet"``)."""

    name: str
    build: Callable[[dict], Any]
    params: dict[str, Param]
    produces: str
    doc: str
