"""Rigid placement of geometry: rotate (Euler x, then y, then z, in degrees), then translate."""

from __future__ import annotations

import numpy as np

from taichi_lap.core.geometry import Geometry, Solid, SpringSheet, TriangleMesh


def rotation_matrix(degrees_xyz) -> np.ndarray:
    """R = Rz Ry Rx for angles [deg] about x, y, z."""
    ax, ay, az = np.radians(np.asarray(degrees_xyz, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def place(geometry: Geometry, rotate, translate) -> Geometry:
    """``geometry`` rotated by ``rotate`` [deg] about the origin, then moved by ``translate`` [m]."""
    rot = rotation_matrix(rotate)
    offset = np.asarray(translate, dtype=np.float64)
    if np.allclose(rot, np.eye(3)) and not offset.any():
        return geometry

    def move(points: np.ndarray) -> np.ndarray:
        return points @ rot.T + offset

    if isinstance(geometry, TriangleMesh):
        return TriangleMesh(move(geometry.vertices), geometry.triangles)
    if isinstance(geometry, SpringSheet):
        return SpringSheet(
            move(geometry.rows.reshape(-1, 3)).reshape(geometry.rows.shape), geometry.row_radius
        )
    lo, hi = geometry.bounds
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    moved = move(corners)
    sdf = None
    if geometry.sdf is not None:
        inner = geometry.sdf

        def moved_sdf(points: np.ndarray) -> np.ndarray:
            return inner((np.asarray(points) - offset) @ rot)

        sdf = moved_sdf

    surface = None if geometry.surface is None else place(geometry.surface, rotate, translate)
    return Solid(bounds=(moved.min(axis=0), moved.max(axis=0)), sdf=sdf, surface=surface)
