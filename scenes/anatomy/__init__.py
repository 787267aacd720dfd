"""Procedural anatomy: the registry of geometry generators scenes refer to by name.

``GENERATORS[name].build(params)`` returns a :mod:`taichi_lap.core.geometry`
record; ``params`` holds every parameter of ``GENERATORS[name].params`` (the scene
loader fills in defaults and checks ranges). Units are metres, y is up.
"""

from __future__ import annotations

from taichi_lap.core.params import Param

from . import intestine, liver, primitives, rectum
from .generator import Generator

GENERATORS: dict[str, Generator] = {
    g.name: g for module in (liver, intestine, rectum, primitives) for g in module.GENERATORS
}


def defaults(name: str) -> dict:
    """The default parameter values of generator ``name``."""
    return {key: p.default for key, p in GENERATORS[name].params.items()}


__all__ = ["GENERATORS", "Generator", "Param", "defaults"]
