"""Simple shapes: sphere and box solids, icosphere, ellipsoid gland, spline vessel.

Units are metres. Closed meshes are watertight with outward (counter-clockwise)
triangles. The gland and vessel serve the rectum scene (seed 000 §4, truss
structure for tubular/glandular tissue); the others are for tests and user scenes.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.core.geometry import Solid, TriangleMesh
from taichi_lap.core.mesh import unique_edges
from taichi_lap.core.params import Param

from . import sdf as S
from . import tubes
from .generator import Generator


def icosphere(subdivisions: int = 2, keep_volume: bool = True) -> TriangleMesh:
    """Unit sphere from an icosahedron split ``subdivisions`` times (each split
    quarters every triangle and pushes the new vertices onto the sphere). With
    ``keep_volume`` the vertices are then pushed out uniformly so the mesh encloses
    the sphere's volume 4 pi / 3 (by 1.2 % at 2 subdivisions), so masses come out right."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=np.float64,
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
        dtype=np.int64,
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(int(subdivisions)):
        uniq, inv = unique_edges(f, return_inverse=True)
        mid = v[uniq].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inv.reshape(-1, 3).T + len(v)  # midpoints of edges 01, 12, 20 per face
        a, b, c = f.T
        f = np.vstack(
            [
                np.stack([a, m[0], m[2]], 1),
                np.stack([m[0], b, m[1]], 1),
                np.stack([m[2], m[1], c], 1),
                np.stack([m[0], m[1], m[2]], 1),
            ]
        )
        v = np.vstack([v, mid])
    if keep_volume:
        vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
        v *= (4.0 * np.pi / 3.0 / vol) ** (1.0 / 3.0)
    return TriangleMesh(v, f)


def _sphere(params: dict) -> Solid:
    r = float(params["radius"])
    return Solid(bounds=(np.full(3, -r), np.full(3, r)), sdf=lambda p: S.sphere(p, (0, 0, 0), r))


def _box(params: dict) -> Solid:
    h = np.asarray(params["half_extents"], float)
    return Solid(bounds=(-h, h), sdf=lambda p: S.box(p, (0, 0, 0), h))


def _icosphere(params: dict) -> TriangleMesh:
    mesh = icosphere(params["subdivisions"])
    return TriangleMesh(mesh.vertices * float(params["radius"]), mesh.triangles)


def _ellipsoid(params: dict) -> TriangleMesh:
    """Gland: an icosphere scaled per axis by ``radii`` [m] (centred at the origin)."""
    mesh = icosphere(params["subdivisions"])
    return TriangleMesh(mesh.vertices * np.asarray(params["radii"], float), mesh.triangles)


def _vessel(params: dict) -> TriangleMesh:
    """Tube with round ends along the Catmull-Rom spline through ``points``."""
    p = np.asarray(params["points"], float).reshape(-1, 3)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-9])
    p = p[keep]
    if len(p) < 2:
        raise ValueError("vessel needs at least two distinct points")
    r = float(params["radius"])
    q, rad = tubes.resample(tubes.catmull_rom(p, 32), r, 1.0)
    return tubes.tube_mesh(q, rad, int(params["segments_around"]), "round")


_ARC = ((-0.06, 0.0, 0.0), (-0.02, 0.006, 0.0), (0.02, 0.006, 0.0), (0.06, 0.0, 0.0))

GENERATORS = [
    Generator(
        "sphere",
        _sphere,
        {"radius": Param("float", 0.03, "radius", 0.001, 1.0, unit="m")},
        "solid",
        "Sphere centred at the origin (exact sdf).",
    ),
    Generator(
        "box",
        _box,
        {
            "half_extents": Param(
                "vec3", (0.03, 0.02, 0.02), "half sizes along x, y, z", 0.001, 1.0, unit="m"
            )
        },
        "solid",
        "Axis-aligned box centred at the origin (exact sdf).",
    ),
    Generator(
        "icosphere",
        _icosphere,
        {
            "radius": Param("float", 0.03, "radius", 0.001, 1.0, unit="m"),
            "subdivisions": Param("int", 2, "icosahedron subdivisions (20 * 4^n triangles)", 0, 6),
        },
        "surface",
        "Closed sphere mesh centred at the origin.",
    ),
    Generator(
        "ellipsoid",
        _ellipsoid,
        {
            "radii": Param(
                "vec3", (0.015, 0.010, 0.012), "semi-axes along x, y, z", 0.001, 0.3, unit="m"
            ),
            "subdivisions": Param("int", 3, "icosahedron subdivisions", 0, 6),
        },
        "surface",
        "Gland: closed ellipsoid mesh centred at the origin.",
    ),
    Generator(
        "vessel",
        _vessel,
        {
            "points": Param(
                "vec3list", _ARC, "spline control points (at least two)", -2.0, 2.0, unit="m"
            ),
            "radius": Param("float", 0.003, "tube radius", 0.0005, 0.03, unit="m"),
            "segments_around": Param("int", 12, "vertices around each ring", 6, 64),
        },
        "surface",
        "Closed tube with round ends along a Catmull-Rom spline; rings about one radius apart.",
    ),
]
