"""Instrument meshes in the tool frame of :class:`~taichi_lap.sim.control.Control`:
the shaft as a capsule, and for graspers and scissors two jaws past the tip."""

from __future__ import annotations

import numpy as np
import trimesh

from taichi_lap.core.instruments import JAW_KINDS, JAW_LENGTH

SHAFT_SECTIONS = 16


def _jaws(radius: float) -> list[trimesh.Trimesh]:
    """Two closed jaws: flat boxes ahead of the tip, one above the other; their
    vertices are not shared, so their faces shade flat."""
    jaws = []
    for side in (-1.0, 1.0):
        jaw = trimesh.creation.box(extents=(1.4 * radius, 0.8 * radius, JAW_LENGTH * radius))
        jaw.apply_translation((0.0, side * 0.45 * radius, -0.5 * JAW_LENGTH * radius))
        jaw.unmerge_vertices()
        jaws.append(jaw)
    return jaws


def instrument_mesh(tool: dict) -> trimesh.Trimesh:
    """The mesh of one scene tool (``kind``, ``radius``, ``length`` [m]) with the
    tip at the origin and the shaft along +z."""
    radius, length = float(tool["radius"]), float(tool["length"])
    shaft = trimesh.creation.capsule(
        height=length, radius=radius, count=[SHAFT_SECTIONS, SHAFT_SECTIONS]
    )
    shaft.apply_translation((0.0, 0.0, 0.5 * length))
    parts = [shaft]
    if tool["kind"] in JAW_KINDS:
        parts += _jaws(radius)
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
