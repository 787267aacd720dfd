"""Relaxed long-range attachments (seed 000 §3.2, Eq. 3)."""

import numpy as np
import pytest
from taichi_lap.kernels import distance

from tests.archrun import assert_backend_matches_cpu
from tests.helpers import simulation, state_after

DT = 1.0 / 60.0


def fascia(beta: float, anchors: int, **material) -> dict:
    return {
        "name": "fascia",
        "model": "fascia_lra",
        "geometry": {
            "generator": "sheet",
            "width": 0.1,
            "depth": 0.06,
            "resolution_x": 16,
            "resolution_z": 10,
            "sag": 0.0,
        },
        "material": {
            "lra_relaxation": beta,
            "lra_anchors": anchors,
            "edge_stiffness": 0.0,
            "bending_stiffness": 0.0,
            "damping": 0.0,
            **material,
        },
        "attachments": [{"kind": "lra_anchor", "box_min": [-1, -1, -1], "box_max": [-0.049, 1, 1]}],
    }


def lra_distances(data, x):
    return np.linalg.norm(x[data.lra_particle] - x[data.lra_anchor], axis=1)


@pytest.mark.parametrize("beta", [0.0, 0.25, 0.4])
def test_one_projection_lands_on_the_relaxed_bound(beta):
    """Eq. 3 with one anchor per vertex: a stretched vertex ends exactly at
    d_LRA = d' + β (|x^a - x| - d')."""
    _, data, model, state, control, _ = simulation(
        [fascia(beta, 1)], gravity=[0, 0, 0], iterations=1
    )
    rest = data.rest_position
    stretched = rest.copy()
    stretched[:, 0] = rest[:, 0] + 0.5 * (
        rest[:, 0] - rest[:, 0].min()
    )  # pull away from the anchors
    state.p.from_numpy(stretched.astype(np.float32))
    before = lra_distances(data, stretched)
    distance.jacobi_sweep(model, state, control, state.p, state.p_next, 1.0)
    after = lra_distances(data, state.p_next.to_numpy())
    bound = data.lra_rest + beta * np.maximum(before - data.lra_rest, 0.0)
    violated = before > data.lra_rest
    assert violated.sum() > 10
    assert np.allclose(after[violated], bound[violated], rtol=1e-5, atol=1e-7)
    assert np.allclose(after[~violated], before[~violated], atol=1e-7)


def test_hard_lra_keeps_every_vertex_within_rest_distance():
    """β = 0 with four anchors per vertex: after each frame under gravity every
    vertex is within d' of all its anchors (1 mm slack over a 10 cm sheet)."""
    _, data, _, state, control, solver = simulation([fascia(0.0, 4)], iterations=20)
    for _ in range(30):
        solver.step(state, control, DT)
        excess = lra_distances(data, state.x.to_numpy()) - data.lra_rest
        assert excess.max() < 1e-3
    assert np.abs(state.x.to_numpy() - data.rest_position).max() > 0.01  # it did fall


def test_relaxed_lra_stretches_more_than_hard():
    sag = []
    for beta in (0.0, 0.4):
        _, data, _, state, control, solver = simulation([fascia(beta, 4)], iterations=4)
        for _ in range(40):
            solver.step(state, control, DT)
        sag.append((lra_distances(data, state.x.to_numpy()) / data.lra_rest).max())
    assert sag[1] > sag[0]


def compute_fascia_case() -> dict:
    """Hard LRA fascia falling for 20 frames (run on any backend)."""
    return state_after([fascia(0.0, 4)], 20, iterations=20)


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    assert_backend_matches_cpu("tests.test_lra:compute_fascia_case", 1e-4)


def _brute_force_attachments(mesh, anchors, per_vertex):
    """(particle, anchor, rest) sorted: every anchor's geodesic distance along the
    edges to every free vertex (Dijkstra from each, unbounded), the nearest kept."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from taichi_lap.core.mesh import pair_lengths, unique_edges

    n = len(mesh.vertices)
    edges = unique_edges(mesh.triangles)
    graph = coo_matrix((pair_lengths(mesh.vertices, edges), tuple(edges.T)), shape=(n, n))
    distance = dijkstra(graph.tocsr(), directed=False, indices=anchors)
    rows = []
    for v in np.setdiff1d(np.arange(n), anchors):
        for a in np.argsort(distance[:, v], kind="stable")[:per_vertex]:
            if np.isfinite(distance[a, v]):
                rows.append((v, anchors[a], distance[a, v]))
    return sorted(rows)


@pytest.mark.parametrize("reach", [np.inf, 0.05, 0.2, 1e-4])
def test_each_vertex_keeps_its_nearest_anchors_in_its_own_piece(reach):
    """Seed 000 §3.2: each free vertex's attachments are its ``lra_anchors`` nearest
    anchors along the surface, fewer where its piece holds fewer, none on a piece
    with no anchor, whatever ``reach`` is guessed (an unbounded search, the same
    result; the sheet is cut into three pieces holding 5, 2 and 0 anchors)."""
    from taichi_lap.core.geometry import TriangleMesh
    from taichi_lap.preprocess.sheets import long_range_attachments, sheet_triangles

    rng = np.random.default_rng(3)
    rows, cols = 9, 12
    grid = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2) * 0.01
    points = np.concatenate([grid, np.zeros((len(grid), 1))], 1)
    points += rng.normal(0.0, 1e-3, points.shape)
    faces = sheet_triangles(rows, cols)
    column = np.arange(rows * cols) % cols
    corners = column[faces]
    faces = faces[~np.isin(corners, [4]).any(axis=1) & ~np.isin(corners, [8]).any(axis=1)]
    mesh = TriangleMesh(points, faces)
    anchors = np.array([0, 1, 2, cols + 1, 2 * cols, 5, 6])  # columns 0-2 and 5-6
    per_vertex = 3
    lra = long_range_attachments(mesh, anchors, per_vertex, reach=reach)
    found = sorted(zip(lra.particle.tolist(), lra.anchor.tolist(), lra.rest.tolist()))
    expected = _brute_force_attachments(mesh, anchors, per_vertex)
    assert [row[:2] for row in found] == [row[:2] for row in expected]
    assert np.allclose([row[2] for row in found], [row[2] for row in expected], rtol=1e-12)
    held = np.bincount(lra.particle, minlength=len(points))
    assert held[column > 8].sum() == 0  # the piece with no anchor hangs from nothing
    middle = (column >= 5) & (column <= 7) & ~np.isin(np.arange(len(points)), anchors)
    assert set(held[middle]) == {2}  # the piece holding two anchors: two each


def test_bending_pairs_join_the_corners_opposite_each_inner_edge():
    """Müller et al. 2007 §4.2: one pair per edge shared by two triangles, the two
    corners opposite it; none for a boundary edge (a 3 x 4 grid of points: 23 edges,
    13 inside it)."""
    from taichi_lap.preprocess.sheets import bending_pairs, sheet_triangles

    faces = sheet_triangles(3, 4)
    pairs = bending_pairs(faces)
    expected = set()
    for f, g in [(f, g) for f in range(len(faces)) for g in range(f + 1, len(faces))]:
        shared = set(faces[f]) & set(faces[g])
        if len(shared) == 2:
            (p,), (q,) = set(faces[f]) - shared, set(faces[g]) - shared
            expected.add((min(p, q), max(p, q)))
    assert len(expected) == 13
    assert [tuple(p) for p in pairs.tolist()] == sorted(expected)
