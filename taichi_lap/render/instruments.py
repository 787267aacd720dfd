"""Instrument meshes in the tool frame of :class:`~taichi_lap.sim.control.Control`,
made of the tool's own shapes: what is drawn is what collides."""

from __future__ import annotations

import numpy as np
import trimesh

from taichi_lap.core.instruments import tool_geometry

SECTIONS = 16
"""Segments around a round shape's mesh."""


def _capsule(a: np.ndarray, b: np.ndarray, radius: float) -> trimesh.Trimesh:
    """A capsule mesh from ``a`` to ``b`` (a sphere when they meet) of ``radius`` [m]."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    mesh = trimesh.creation.capsule(height=length, radius=radius, count=[SECTIONS, SECTIONS])
    if length > 0.0:  # trimesh's capsule runs along z, centred on the origin
        mesh.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / length))
    mesh.apply_translation(0.5 * (a + b))
    return mesh


def instrument_mesh(tool: dict) -> trimesh.Trimesh:
    """The mesh of one scene tool (``kind``, ``radius``, ``length`` [m]) in its tool
    frame (tip at the origin, shaft along +z): exactly the shapes its contacts and
    haptics use (:func:`~taichi_lap.core.instruments.tool_geometry`)."""
    geometry = tool_geometry(tool)
    parts = [_capsule(a, b, r) for a, b, r in geometry.round_shapes()]
    for center, half in geometry.boxes():
        box = trimesh.creation.box(extents=2.0 * half)
        box.apply_translation(center)
        box.unmerge_vertices()  # flat faces
        parts.append(box)
    return trimesh.util.concatenate(parts)


def instrument_arrays(tools: list[dict]) -> dict[str, np.ndarray]:
    """All tools' meshes concatenated: ``position`` and ``normal`` (V, 3) in the
    tool frame, ``tool`` (V,) the tool index of each vertex, ``triangles`` (F, 3)."""
    positions, normals, owner, triangles, base = [], [], [], [], 0
    for index, tool in enumerate(tools):
        mesh = instrument_mesh(tool)
        positions.append(mesh.vertices)
        normals.append(mesh.vertex_normals)
        owner.append(np.full(len(mesh.vertices), index))
        triangles.append(mesh.faces + base)
        base += len(mesh.vertices)
    if not tools:
        return {
            "position": np.zeros((0, 3), np.float32),
            "normal": np.zeros((0, 3), np.float32),
            "tool": np.zeros(0, np.int32),
            "triangles": np.zeros((0, 3), np.int32),
        }
    return {
        "position": np.concatenate(positions).astype(np.float32),
        "normal": np.concatenate(normals).astype(np.float32),
        "tool": np.concatenate(owner).astype(np.int32),
        "triangles": np.concatenate(triangles).astype(np.int32),
    }
