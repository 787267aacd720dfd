"""The tint grid of the vessels under the tissue (:mod:`taichi_lap.kernels.subsurface`),
made once per scene from the rest positions of its vessels' particles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from taichi_lap.scene.materials import SUBSURFACE_DEPTH, Material

TINT_CELL = 0.0015
"""[m] the grid's finest spacing: the scale of SUBSURFACE_DEPTH, so the trilinear
blend follows the fade."""
TINT_NODES = 1 << 19
"""The most nodes a grid has (8 MiB): over a larger region the spacing grows."""
TINT_REACH = 4.0
"""How far from a vessel the grid holds a weight, in SUBSURFACE_DEPTH (beyond it,
below exp(-4) = 2 %, the weight is 0)."""


@dataclass
class TintGrid:
    """``tint`` (X·Y·Z, 4) float32, row-major over ``shape`` (x slowest): the nearest
    vessel's albedo times its weight, and the weight; node (i, j, k) lies at
    ``origin`` + ``cell`` (i, j, k) [m]."""

    tint: np.ndarray
    shape: np.ndarray
    origin: np.ndarray
    cell: float

    @classmethod
    def empty(cls) -> "TintGrid":
        """A grid that tints nothing."""
        return cls(np.zeros((1, 4), np.float32), np.ones(3, np.int32), np.zeros(3), 1.0)


def vessel_tint_grid(
    rest: np.ndarray,
    tissue: list[np.ndarray],
    vessels: list[tuple[np.ndarray, Material]],
    cell: float = TINT_CELL,
) -> TintGrid:
    """The tint grid over the rest positions ``rest`` (N, 3) [m] of the ``tissue``
    particles (index arrays of the organs with ``subsurface``), padded by the reach,
    ``cell`` [m] apart (wider where the grid would have more than TINT_NODES),
    from the ``vessels`` (particle indices and material per vessel organ): each node
    takes the nearest vessel particle's albedo with weight exp(-d / SUBSURFACE_DEPTH)
    (d its distance [m]; 0 beyond TINT_REACH depths). Empty when either list is."""
    tissue = [t for t in tissue if len(t)]
    vessels = [(v, m) for v, m in vessels if len(v)]
    if not tissue or not vessels:
        return TintGrid.empty()
    reach = TINT_REACH * SUBSURFACE_DEPTH
    inside = rest[np.concatenate(tissue)]
    low, high = inside.min(axis=0) - reach, inside.max(axis=0) + reach
    cell = max(cell, float(np.prod(high - low) / TINT_NODES) ** (1.0 / 3.0))
    shape = np.ceil((high - low) / cell).astype(np.int64) + 1
    axes = [low[k] + cell * np.arange(shape[k]) for k in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    points = rest[np.concatenate([v for v, _ in vessels])]
    owner = np.repeat(np.arange(len(vessels)), [len(v) for v, _ in vessels])
    albedo = np.array([m.albedo for _, m in vessels], np.float64)
    distance, nearest = cKDTree(points).query(nodes, distance_upper_bound=reach, workers=-1)
    found = np.isfinite(distance)
    weight = np.zeros(len(nodes))
    weight[found] = np.exp(-distance[found] / SUBSURFACE_DEPTH)
    tint = np.zeros((len(nodes), 4))
    tint[found, :3] = albedo[owner[nearest[found]]] * weight[found, None]
    tint[:, 3] = weight
    return TintGrid(tint.astype(np.float32), shape.astype(np.int32), low, float(cell))
