"""Marching tetrahedra on kept/removed labels (seed 002 §3.3, Fig. 4): each of the 14
tet and 6 triangle configurations closes the kept part of a tet with outward
triangles, and on a block of tets any labelling closes the kept tissue."""

import numpy as np
import pytest

from taichi_lap.core.mesh import edge_defects, enclosed_volume, inconsistent_edges, tet_volumes
from taichi_lap.dissection.marching import (
    TET_CASES,
    TRIANGLE_CASES,
    clipped_triangles,
    wound_triangles,
)
from taichi_lap.core.mesh import TET_FACES
from tests.blocks import block


def closed_surface(points: np.ndarray, named: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions and triangles of the surface whose corners are named by particle
    pairs (the midpoint of a pair; a pair (p, p) is particle p)."""
    keys, triangles = np.unique(np.sort(named.reshape(-1, 2), axis=1), axis=0, return_inverse=True)
    return points[keys].mean(axis=1), triangles.reshape(-1, 3)


def assert_closed_outward(positions: np.ndarray, triangles: np.ndarray):
    assert edge_defects(triangles) == (0, 0)
    assert inconsistent_edges(triangles) == 0
    assert enclosed_volume(positions, triangles) > 0.0


@pytest.mark.parametrize("mask", range(1, 15))
def test_each_tet_configuration_closes_the_kept_part_outwards(mask):
    rng = np.random.default_rng(mask)
    points = rng.normal(size=(4, 3))
    tet = np.array([[0, 1, 2, 3]])
    if tet_volumes(points, tet)[0] < 0:
        points[[0, 1]] = points[[1, 0]]
    removed = np.array([mask >> k & 1 for k in range(4)], dtype=bool)
    wound, source = wound_triangles(tet, removed)
    faces, _ = clipped_triangles(tet[0][TET_FACES], removed)
    positions, triangles = closed_surface(points, np.concatenate([wound, faces]))

    assert len(wound) == (2 if removed.sum() == 2 else 1) and (source == 0).all()
    assert_closed_outward(positions, triangles)
    # the cut passes through edge midpoints: a corner cut off keeps 7/8 or 1/8 of the
    # tet, the plane between two pairs halves it
    kept_fraction = {1: 7 / 8, 2: 1 / 2, 3: 1 / 8}[int(removed.sum())]
    volume = tet_volumes(points, tet)[0]
    assert enclosed_volume(positions, triangles) == pytest.approx(kept_fraction * volume)
    # every generated vertex lies on an edge from a kept to a removed corner
    kept_end, removed_end = wound[..., 0], wound[..., 1]
    assert not removed[kept_end].any() and removed[removed_end].all()


@pytest.mark.parametrize("mask", range(1, 7))
def test_each_triangle_configuration_keeps_its_kept_part_in_its_turn(mask):
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    removed = np.array([mask >> k & 1 for k in range(3)], dtype=bool)
    named, _ = clipped_triangles(np.array([[0, 1, 2]]), removed)
    positions, triangles = closed_surface(points, named)
    corners = positions[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * normals[:, 2].sum()

    assert len(named) == (2 if removed.sum() == 1 else 1)
    assert (normals[:, 2] > 0).all()  # the original triangle's turn (+z)
    assert area == pytest.approx({1: 3 / 8, 2: 1 / 8}[int(removed.sum())])


def test_the_tables_cover_every_mixed_mask_and_none_other():
    counts = (TET_CASES[:, :, 0] >= 0).sum(axis=1)
    assert counts[0] == counts[15] == 0 and (counts[1:15] > 0).all()
    counts = (TRIANGLE_CASES[:, :, 0] >= 0).sum(axis=1)
    assert counts[0] == counts[7] == 0 and (counts[1:7] > 0).all()


@pytest.mark.parametrize("seed", range(6))
def test_any_labelling_of_a_block_closes_the_kept_tissue_outwards(seed):
    arguments = block(3)
    points, tets = arguments["rest_positions"], arguments["tets"]
    boundary = arguments["surface_index"][arguments["triangles"], 0]  # direct binding
    removed = np.random.default_rng(seed).random(len(points)) < 0.3
    wound, _ = wound_triangles(tets, removed)
    kept_boundary, _ = clipped_triangles(boundary, removed)
    positions, triangles = closed_surface(points, np.concatenate([wound, kept_boundary]))

    assert_closed_outward(positions, triangles)
    # the kept tissue is between the whole-kept tets and the tets touching it
    whole = tet_volumes(points, tets[~removed[tets].any(axis=1)]).sum()
    touching = tet_volumes(points, tets[~removed[tets].all(axis=1)]).sum()
    assert whole < enclosed_volume(positions, triangles) < touching
