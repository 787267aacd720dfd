"""User surface meshes: organs segmented in 3D Slicer, saved as OBJ, STL or PLY.

Seed 002 §3.2 reconstructs the liver capsule and vessels as triangle meshes from
CT; this module reads such a file, checks it and returns a
:class:`~taichi_lap.core.geometry.TriangleMesh` in metres. Every problem is an
:class:`~taichi_lap.errors.InputError` saying what was expected and what was found.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from taichi_lap.core.errors import InputError
from taichi_lap.core.geometry import TriangleMesh
from taichi_lap.core.mesh import (
    degenerate_triangles,
    edge_defects,
    enclosed_volume,
    inconsistent_edges,
)

MESH_EXTENSIONS = (".obj", ".stl", ".ply")


def load_surface_mesh(
    path, *, scene_file: str, key: str, scale: float = 1.0, watertight: bool
) -> TriangleMesh:
    """Read the triangle mesh at ``path`` named by ``key`` in ``scene_file``.

    Vertices are multiplied by ``scale`` (0.001 for a file in millimetres).
    Duplicate vertices are merged (STL repeats each corner per face). With
    ``watertight`` the mesh must be closed and manifold (every edge in exactly two
    faces); it is then oriented with outward normals.
    """
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(
            scene_file, key, f"a positive finite mesh scale was expected, found {scale}"
        )
    path = Path(path)
    vertices, triangles = _read(path, scene_file, key)
    where = str(path)
    bad_values = int(np.count_nonzero(~np.isfinite(vertices)))
    if bad_values:
        raise InputError(
            where,
            key,
            f"finite vertex coordinates were expected, found {bad_values} "
            f"non-finite values (NaN or infinity)",
        )
    vertices, triangles = _merge_vertices(vertices, triangles)
    degenerate = int(np.count_nonzero(degenerate_triangles(vertices, triangles)))
    if degenerate:
        raise InputError(
            where,
            key,
            f"non-degenerate triangles were expected, found {degenerate} "
            f"degenerate faces (repeated vertex or zero area)",
        )
    if watertight:
        open_edges, fins = edge_defects(triangles)
        if open_edges or fins:
            raise InputError(
                where,
                key,
                f"a watertight (closed, manifold) surface was expected, found "
                f"{open_edges} open edges and {fins} non-manifold edges",
            )
        flipped = inconsistent_edges(triangles)
        if flipped:
            raise InputError(
                where,
                key,
                f"consistently oriented faces were expected, found {flipped} "
                f"edges whose two faces run them the same way",
            )
    mesh = TriangleMesh(vertices * float(scale), triangles)
    if watertight and enclosed_volume(mesh.vertices, mesh.triangles) < 0:
        mesh.triangles = np.ascontiguousarray(mesh.triangles[:, ::-1])
    return mesh


def _read(path: Path, scene_file: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw vertices ``(V, 3)`` and triangles ``(M, 3)`` as stored in the file."""
    extension = path.suffix.lower()
    if extension not in MESH_EXTENSIONS:
        raise InputError(
            scene_file,
            key,
            f"a mesh file ending in {', '.join(MESH_EXTENSIONS)} was "
            f"expected, found {extension or 'no extension'} ({path})",
        )
    if not path.is_file():
        raise InputError(scene_file, key, f"mesh file {path} was expected, it does not exist")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)  # scenes are concatenated
    except OSError as exc:
        raise InputError(
            scene_file,
            key,
            f"mesh file {path} was expected, it cannot be read ({exc.strerror or exc})",
        ) from exc
    except Exception as exc:  # trimesh raises many types on malformed files
        raise InputError(
            str(path),
            key,
            f"a readable {extension[1:].upper()} mesh was expected, "
            f"parsing failed ({type(exc).__name__}: {exc})",
        ) from exc
    vertices = np.asarray(getattr(loaded, "vertices", ()), dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(getattr(loaded, "faces", ()), dtype=np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        raise InputError(
            str(path),
            key,
            "a mesh with triangles was expected, found none "
            f"({len(vertices)} vertices, 0 triangles)",
        )
    out_of_range = int(np.count_nonzero((triangles < 0) | (triangles >= len(vertices))))
    if out_of_range:
        raise InputError(
            str(path),
            key,
            f"face indices below the vertex count {len(vertices)} were "
            f"expected, found {out_of_range} out of range",
        )
    return vertices, triangles


def _merge_vertices(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with identical coordinates; drop vertices no face uses."""
    used = np.unique(triangles)
    unique, inverse = np.unique(vertices[used], axis=0, return_inverse=True)
    remap = np.zeros(len(vertices), dtype=np.int64)
    remap[used] = inverse.reshape(-1)
    return unique, remap[triangles]
