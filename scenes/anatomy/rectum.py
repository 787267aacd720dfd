"""Rectum scene pieces (seed 000): colon wall tube, polyp, fascia sheet.

Units are metres; y is up. The wall is a thick-walled closed tube (outer wall,
inner wall facing the lumen, annular ends) along a circular arc in the x-z plane.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.core.geometry import Solid, TriangleMesh
from taichi_lap.core.params import Param

from . import sdf as S
from . import tubes
from .generator import Generator


def tube_centreline(length: float, bend: float, rings: int) -> np.ndarray:
    """``rings`` points on an arc of ``length`` [m] turning by ``bend`` [rad] in the
    x-z plane, axis along x (``tube`` then centres the mesh's bounding box)."""
    u = np.linspace(-0.5, 0.5, int(rings))
    if abs(bend) < 1e-9:
        p = np.stack([length * u, 0 * u, 0 * u], axis=1)
    else:
        rho = length / bend
        psi = bend * u
        p = np.stack([rho * np.sin(psi), 0 * u, rho * (1.0 - np.cos(psi))], axis=1)
    return p


def _tube(params: dict) -> TriangleMesh:
    ro = float(params["outer_radius"])
    ri = ro - float(params["wall_thickness"])
    if ri <= 0.0:
        raise ValueError("wall_thickness must be smaller than outer_radius")
    p = tube_centreline(float(params["length"]), float(params["bend"]), int(params["rings"]))
    mesh = tubes.hollow_tube_mesh(p, ro, ri, int(params["segments_around"]))
    v = mesh.vertices
    return TriangleMesh(v - 0.5 * (v.min(0) + v.max(0)), mesh.triangles)  # bounding box centred


def polyp_sdf(radius: float, stalk_radius: float, stalk_length: float):
    """Head sphere centred at ``y = stalk_length + radius`` smoothly joined (blend
    width ``stalk_radius``) to a flat-based stalk cylinder rising from ``y = 0``."""
    top = stalk_length + radius

    def f(p):
        head = S.sphere(p, (0.0, top, 0.0), radius)
        stalk = S.capped_cylinder(p, 0.0, top, stalk_radius)
        return S.smooth_union(head, stalk, stalk_radius)

    return f


def _polyp(params: dict) -> Solid:
    r, rs, ls = (float(params[k]) for k in ("radius", "stalk_radius", "stalk_length"))
    m = 0.25 * rs + 1e-4  # the smooth union can swell by up to k/4
    w = max(r, rs) + m
    return Solid(
        bounds=(np.array([-w, -m, -w]), np.array([w, ls + 2 * r + m, w])), sdf=polyp_sdf(r, rs, ls)
    )


def _sheet(params: dict) -> TriangleMesh:
    """Grid in the x-z plane (triangles facing +y) with alternating diagonals and a
    ``sag * sin(2 pi x / width) * cos(pi z / depth)`` undulation in y."""
    w, d, sag = float(params["width"]), float(params["depth"]), float(params["sag"])
    nx, nz = int(params["resolution_x"]), int(params["resolution_z"])
    x, z = np.meshgrid(
        np.linspace(-w / 2, w / 2, nx + 1), np.linspace(-d / 2, d / 2, nz + 1), indexing="ij"
    )
    y = sag * np.sin(2 * np.pi * x / w) * np.cos(np.pi * z / d)
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    idx = np.arange((nx + 1) * (nz + 1)).reshape(nx + 1, nz + 1)
    v00, v10, v01, v11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    even = (np.arange(nx)[:, None] + np.arange(nz)[None, :]) % 2 == 0
    t_even = np.stack([np.stack([v00, v01, v11], -1), np.stack([v00, v11, v10], -1)], 2)
    t_odd = np.stack([np.stack([v00, v01, v10], -1), np.stack([v10, v01, v11], -1)], 2)
    tris = np.where(even[..., None, None], t_even, t_odd)
    return TriangleMesh(verts, tris.reshape(-1, 3))


GENERATORS = [
    Generator(
        "tube",
        _tube,
        {
            "length": Param("float", 0.15, "centreline length", 0.02, 0.5, unit="m"),
            "outer_radius": Param("float", 0.022, "outer wall radius", 0.003, 0.1, unit="m"),
            "wall_thickness": Param(
                "float", 0.005, "wall thickness (< outer_radius)", 0.0005, 0.05, unit="m"
            ),
            "bend": Param(
                "float", 0.4, "total bend of the axis in the x-z plane", -3.0, 3.0, unit="rad"
            ),
            "segments_around": Param("int", 24, "vertices around each ring", 6, 128),
            "rings": Param("int", 40, "rings along the length", 2, 1000),
        },
        "surface",
        "Rectum/colon wall: closed thick-walled tube along a bent axis (about x).",
    ),
    Generator(
        "polyp",
        _polyp,
        {
            "radius": Param("float", 0.008, "head radius", 0.002, 0.03, unit="m"),
            "stalk_radius": Param("float", 0.003, "stalk radius", 0.0005, 0.02, unit="m"),
            "stalk_length": Param(
                "float", 0.006, "stalk length below the head", 0.0, 0.03, unit="m"
            ),
        },
        "solid",
        "Pedunculated polyp growing along +y from its base at the origin.",
    ),
    Generator(
        "sheet",
        _sheet,
        {
            "width": Param("float", 0.12, "size along x", 0.01, 1.0, unit="m"),
            "depth": Param("float", 0.08, "size along z", 0.01, 1.0, unit="m"),
            "resolution_x": Param("int", 32, "quads along x", 1, 512),
            "resolution_z": Param("int", 24, "quads along z", 1, 512),
            "sag": Param("float", 0.004, "amplitude of the undulation in y", -0.05, 0.05, unit="m"),
        },
        "surface",
        "Fascia: open rectangular sheet in the x-z plane, centred at the origin.",
    ),
]
