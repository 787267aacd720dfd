"""Geometry records passed from the anatomy generators and mesh files to the builder.

Units are metres. Arrays are NumPy: positions float64 ``(N, 3)``, triangles
int64 ``(M, 3)`` counter-clockwise seen from outside (normals point out of a
closed surface).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

SignedDistance = Callable[[np.ndarray], np.ndarray]
"""Maps points ``(K, 3)`` [m] to signed distances ``(K,)`` [m], negative inside."""


@dataclass
class TriangleMesh:
    """A triangle surface: a closed organ skin, a tube, or an open sheet."""

    vertices: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64).reshape(-1, 3)


@dataclass
class Solid:
    """A closed region of space to be filled with tetrahedra.

    ``sdf`` gives exact signed distances (procedural organs); ``surface`` is an
    explicit closed skin (a user mesh, or a tube mesh for a vessel). At least one is
    set. Where ``surface`` is set it is the render surface and is bound to the
    tetrahedra barycentrically; where only ``sdf`` is set the render surface is
    the boundary of the tetrahedral mesh, snapped onto the zero level set.
    ``bounds`` is ``(lo, hi)``, each ``(3,)``, enclosing the region.
    """

    bounds: tuple[np.ndarray, np.ndarray]
    sdf: SignedDistance | None = None
    surface: TriangleMesh | None = None

    def __post_init__(self):
        if self.sdf is None and self.surface is None:
            raise ValueError("a Solid needs an sdf or a surface")
        lo, hi = self.bounds
        self.bounds = (np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64))


@dataclass
class SpringSheet:
    """Rows of mass points linked by springs (seed 001 §3.2, Fig. 6).

    ``rows`` is ``(R, C, 3)``: row 0 is the free border (the intestine), row
    ``R - 1`` the root attached to the main vessel. ``row_radius`` ``(R,)`` is the
    collision/render radius of each row's points [m] (the intestine's 2 cm for
    row 0, the mesentery half-thickness elsewhere).
    """

    rows: np.ndarray
    row_radius: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        self.rows = np.ascontiguousarray(self.rows, dtype=np.float64)
        if self.rows.ndim != 3 or self.rows.shape[2] != 3:
            raise ValueError("rows must be (R, C, 3)")
        self.row_radius = np.asarray(self.row_radius, dtype=np.float64).reshape(-1)


Geometry = TriangleMesh | Solid | SpringSheet


def arc_length(points) -> np.ndarray:
    """Cumulative arc length ``(n,)`` [m] of a polyline ``(n, 3)`` [m], starting at 0."""
    seg = np.linalg.norm(np.diff(np.asarray(points, float), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])
