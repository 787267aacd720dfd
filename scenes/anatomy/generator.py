"""The registry entry of a procedural anatomy generator.

Scene files name a generator and set some of its parameters; the scene loader
checks each value against the generator's :class:`~taichi_lap.core.params.Param`
table (type, range, choices) and fills in the defaults, so a generator always
receives a complete, valid ``dict``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from taichi_lap.core.params import Param


@dataclass(frozen=True)
class Generator:
    """A procedural geometry: ``build(params) -> Geometry`` (see
    :mod:`taichi_lap.core.geometry`), the parameters it takes and what it makes
    (``"solid"``, ``"surface"`` or ``"spring_sheet"``)."""

    name: str
    build: Callable[[dict], Any]
    params: dict[str, Param]
    produces: str
    doc: str
