"""The body cavity around a scene's organs, drawn and never simulated: its wall (the
parietal peritoneum, ``[environment.cavity]``) and the patches of the supporting
planes (``[[environment.planes]]``). A laparoscope looks into a closed cavity, so
every ray of its view ends on tissue. Units are metres.
"""

from __future__ import annotations

import numpy as np
import trimesh

from taichi_lap.core.geometry import TriangleMesh

WALL_SUBDIVISIONS = 4
"""Icosphere subdivisions of the wall: 2562 vertices, 5120 triangles (its bulges,
tens of centimetres across, need no more; shading is per pixel)."""
WALL_WAVES = 8
"""Smooth waves summed for the wall's bulges."""
PATCH_SEGMENTS = 48
"""Segments around a plane's disc."""


def wall_bulge(directions: np.ndarray, seed: int = 0) -> np.ndarray:
    """A smooth field over unit ``directions`` (n, 3) in [-1, 1]: the mean of
    :data:`WALL_WAVES` waves cos(f d·k + φ) of random directions k, frequencies f in
    [2, 5] and phases φ (fixed by ``seed``), a few bulges per half turn."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(WALL_WAVES, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    frequency = rng.uniform(2.0, 5.0, WALL_WAVES)
    phase = rng.uniform(0.0, 2.0 * np.pi, WALL_WAVES)
    waves = np.cos(directions @ axes.T * frequency + phase)
    return waves.mean(axis=1) * np.sqrt(2.0)  # about unit amplitude


def cavity_wall(center, radii, relief: float, seed: int = 0) -> TriangleMesh:
    """The closed wall of an ellipsoidal cavity of semi-axes ``radii`` around
    ``center``, bulging in and out by up to about ``relief`` of the radii
    (:func:`wall_bulge`, clipped so that it never folds through the centre)."""
    sphere = trimesh.creation.icosphere(subdivisions=WALL_SUBDIVISIONS)
    directions = np.asarray(sphere.vertices, np.float64)
    scale = 1.0 + relief * np.clip(wall_bulge(directions, seed), -1.0, 1.0)
    vertices = np.asarray(center, float) + directions * scale[:, None] * np.asarray(radii, float)
    return TriangleMesh(vertices, np.asarray(sphere.faces))


def plane_patch(point, normal, extent: float) -> TriangleMesh:
    """A disc of radius ``extent`` in the plane through ``point`` with ``normal``,
    centred on the point: a fan of :data:`PATCH_SEGMENTS` triangles."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.eye(3)[np.argmin(np.abs(n))]
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    angle = np.linspace(0.0, 2.0 * np.pi, PATCH_SEGMENTS, endpoint=False)
    ring = np.asarray(point, float) + extent * (
        np.outer(np.cos(angle), u) + np.outer(np.sin(angle), v)
    )
    k = np.arange(PATCH_SEGMENTS)
    triangles = np.stack([np.zeros_like(k), 1 + k, 1 + (k + 1) % PATCH_SEGMENTS], axis=1)
    return TriangleMesh(np.vstack([point, ring]), triangles)
