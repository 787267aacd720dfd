"""Edges of triangle and tet meshes (core.mesh), shared by every layer."""

import numpy as np
import pytest

from taichi_lap.core.mesh import edge_neighbours, element_edges, element_pieces, unique_edges


def test_tet_edges_are_listed_once_each_sorted():
    edges, uses = unique_edges(np.array([[3, 1, 2, 0], [0, 1, 2, 4]]), return_counts=True)
    assert edges.tolist() == [
        [0, 1],
        [0, 2],
        [0, 3],
        [0, 4],
        [1, 2],
        [1, 3],
        [1, 4],
        [2, 3],
        [2, 4],
    ]
    assert uses.tolist() == [2, 2, 1, 1, 2, 1, 1, 1, 1]
    assert element_edges(np.array([[5, 1, 3]])).tolist() == [[1, 5], [1, 3], [3, 5]]


def test_edge_neighbours_across_manifold_edges_only():
    # a fan of three triangles on edge (0, 1) (non-manifold), and one more across (1, 2)
    triangles = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5]])
    neighbours = edge_neighbours(triangles)
    assert neighbours[0].tolist() == [-1, 3, -1]  # edge 01 in three triangles: none
    assert neighbours[3].tolist() == [0, -1, -1]
    assert neighbours[1].tolist() == [-1, -1, -1]


def test_edge_neighbours_of_a_closed_surface_are_symmetric():
    tetra = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    neighbours = edge_neighbours(tetra)
    assert (neighbours >= 0).all()
    for t, row in enumerate(neighbours):
        for u in row:
            assert t in neighbours[u]


def test_elements_sharing_a_vertex_are_one_piece():
    # two triangles joined at vertex 2 only, a third apart; tets joined at a vertex
    triangles = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]])
    assert element_pieces(triangles).tolist() == [0, 0, 1]
    tets = np.array([[9, 8, 7, 6], [0, 1, 2, 3], [3, 4, 5, 10]])
    assert element_pieces(tets).tolist() == [0, 1, 1]
    assert element_pieces(np.zeros((0, 3), dtype=int)).tolist() == []


def test_in_box_keeps_the_elements_whose_bounding_boxes_meet_the_box():
    """``in_box`` against the elements' own bounding boxes, over random triangles and
    tets and boxes (some elements straddle the box with no corner inside it)."""
    from taichi_lap.core.mesh import in_box

    rng = np.random.default_rng(7)
    points = rng.random((300, 3))
    for corners in (3, 4):
        elements = rng.integers(0, len(points), (500, corners))
        for _ in range(20):
            low = rng.random(3) * 0.8
            high = low + rng.random(3) * 0.3
            box = points[elements]
            expected = np.all((box.max(axis=1) >= low) & (box.min(axis=1) <= high), axis=1)
            got = in_box(points, elements, low, high)
            np.testing.assert_array_equal(got, expected)
            assert 0 < got.sum() < len(elements)


def test_masses_after_a_tet_split_keep_the_mass_and_follow_the_volumes():
    """Two tets sharing the face 1-2-3 (volumes 1/6 and 1/3 m^3), 1 kg at each vertex;
    the first is split in two at a new vertex 5 in the middle of its edge 0-1.
    Vertex 0 gives its whole kilogram, vertices 1-3 the third of theirs the first tet
    held at them: 2 kg over 1/6 m^3, taken back by the halves (1/12 m^3 each) at a
    quarter per corner: 0.5 kg for vertex 5 (in both), 0.25 for vertex 0 and 1,
    0.5 for 2 and 3 (in both); vertex 4, outside the cut, keeps its kilogram."""
    from taichi_lap.core.mesh import masses_after_cut

    rest = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [0.5, 0, 0]], dtype=float
    )
    tets = np.array([[0, 1, 2, 3], [1, 4, 2, 3]])
    halves = np.array([[0, 5, 2, 3], [5, 1, 2, 3]])
    old, new = masses_after_cut(rest, tets, np.array([True, False]), halves, np.ones(5))
    assert old == pytest.approx([0.25, 2 / 3 + 0.25, 2 / 3 + 0.5, 2 / 3 + 0.5, 1.0])
    assert new == pytest.approx([0.5])
    assert old.sum() + new.sum() == pytest.approx(5.0)
