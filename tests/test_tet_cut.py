"""Volumetric cutting by a line blade (seed 000 §5.3, taichi_lap.dissection.tet_cut):
every separating bit code splits a tet into sub-tets of positive volume that fill it
and bound two closed pieces; a cut that ends inside a tet leaves it whole until the
blade passes through; a block and the rectum scene's polyp cut through fall into two
closed pieces of the original volume."""

import numpy as np
import pytest

from taichi_lap.core.mesh import (
    TET_EDGES,
    boundary_faces,
    edge_defects,
    element_pieces,
    enclosed_volume,
    inconsistent_edges,
    tet_volumes,
    unique_edges,
)
from taichi_lap.dissection.tet_cut import SEPARATING, SNAP_FRACTION, BladePath, cut_tets
from tests.blocks import block

CORNERS = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 1.0, 0.1], [0.3, 0.2, 1.0]]) * 0.01
"""A positively oriented tet of about 1 cm."""


def slice_path(point, normal, size: float = 0.05, frames: int = 1) -> BladePath:
    """A blade lying in the plane through ``point`` with ``normal``, drawn across a
    square of ``size`` [m] in it over ``frames`` frames."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(normal, [0.3, 0.5, 0.7])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    steps = np.linspace(-size, size, frames + 1)
    return BladePath.of([[point - size * u + s * w, point + size * u + s * w] for s in steps])


def edge_lengths(points, tets) -> np.ndarray:
    """The length of every edge of ``tets`` [m]."""
    edges = unique_edges(tets)
    return np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)


def pieces(points, tets) -> list[np.ndarray]:
    """The tets of each connected piece (sharing a vertex)."""
    label = element_pieces(tets)
    return [tets[label == k] for k in np.unique(label)]


def assert_closed_pieces(points, tets, count: int, volume: float):
    """``count`` pieces, each bounded by a closed, outward surface enclosing the
    volume of its tets, all positive, summing to ``volume``."""
    assert np.all(tet_volumes(points, tets) > 0.0)
    assert tet_volumes(points, tets).sum() == pytest.approx(volume, rel=1e-9)
    found = pieces(points, tets)
    assert len(found) == count
    for piece in found:
        surface = boundary_faces(piece)
        assert edge_defects(surface) == (0, 0)
        assert inconsistent_edges(surface) == 0
        assert enclosed_volume(points, surface) == pytest.approx(
            tet_volumes(points, piece).sum(), rel=1e-9
        )


@pytest.mark.parametrize("code, side", sorted(SEPARATING.items()))
def test_every_separating_code_splits_a_tet_into_positive_sub_tets_that_fill_it(code, side):
    tet = np.array([[0, 1, 2, 3]])
    one = [k for k in range(4) if side >> k & 1]
    other = [k for k in range(4) if not side >> k & 1]
    a, b = CORNERS[one].mean(axis=0), CORNERS[other].mean(axis=0)
    # a plane between the two sides, nearer one of them (the parameters differ)
    path = slice_path(0.6 * a + 0.4 * b, a - b)
    cut = cut_tets(CORNERS, tet, path)
    assert cut.edge_code[0] == code and cut.face_code[0] == 0
    assert list(cut.removed) == [0]
    assert len(cut.vertex_parents) == 2 * bin(code).count("1")  # one per side
    points, tets = cut.apply(CORNERS, tet)
    # a tet and a prism (1 + 3) or two prisms (3 + 3)
    assert len(tets) == (4 if len(one) in (1, 3) else 6)
    assert_closed_pieces(points, tets, 2, tet_volumes(CORNERS, tet)[0])
    # each new vertex lies on its edge, on the plane, and goes with its side
    crossed = [TET_EDGES[k] for k in range(6) if code >> k & 1]
    assert {tuple(sorted(p)) for p in cut.vertex_parents} == {tuple(e) for e in crossed}
    normal = (a - b) / np.linalg.norm(a - b)
    np.testing.assert_allclose((points[4:] - (0.6 * a + 0.4 * b)) @ normal, 0.0, atol=1e-12)
    for vertex, side_corner in zip(range(4, len(points)), cut.vertex_side):
        piece = next(p for p in pieces(points, tets) if vertex in p)
        assert side_corner in piece


def test_a_cut_ending_inside_a_tet_leaves_it_whole_until_the_blade_passes_through():
    tet = np.array([[0, 1, 2, 3]])
    a, b = CORNERS[[0]].mean(axis=0), CORNERS[1:].mean(axis=0)
    normal = a - b
    full = slice_path(0.5 * (a + b), normal, size=0.05, frames=10)
    half = BladePath.of(full.segments[:6])  # the blade stops at the plane's middle
    cut = cut_tets(CORNERS, tet, half)
    assert cut.empty and list(cut.deferred) == [0]
    assert cut.edge_code[0] not in SEPARATING and cut.edge_code[0] != 0
    assert cut.face_code[0] != 0  # the blade's edge lies across the tet
    path = half
    for segment in full.segments[6:]:
        path = path.then(segment)
    done = cut_tets(CORNERS, tet, path)
    assert list(done.removed) == [0] and done.face_code[0] == 0
    assert_closed_pieces(*done.apply(CORNERS, tet), 2, tet_volumes(CORNERS, tet)[0])


def test_a_block_cut_over_frames_falls_into_two_closed_pieces():
    b = block(3)
    points, tets = b["rest_positions"], b["tets"]
    volume = tet_volumes(points, tets).sum()
    normal = np.array([1.0, 0.2, 0.1])
    path = slice_path(np.array([0.013, 0.015, 0.014]), normal, size=0.04, frames=12)
    # partway the cut leaves the tets it ends in whole and the mesh in one piece
    partial = cut_tets(points, tets, BladePath.of(path.segments[:6]))
    assert len(partial.deferred) > 0
    part_points, part_tets = partial.apply(points, tets)
    assert_closed_pieces(part_points, part_tets, 1, volume)
    cut = cut_tets(points, tets, path)
    assert len(cut.deferred) == 0
    original = len(points)
    points, tets = cut.apply(points, tets)
    assert_closed_pieces(points, tets, 2, volume)
    # the pieces are the two sides of the plane, each with the block's vertices that
    # were snapped onto it (SNAP_FRACTION of an edge from it at most) and their twins
    reach = SNAP_FRACTION * edge_lengths(b["rest_positions"], b["tets"]).max()
    normal /= np.linalg.norm(normal)
    signs = []
    for piece in pieces(points, tets):
        own = np.unique(piece)
        above = (points[own[own < original]] - [0.013, 0.015, 0.014]) @ normal
        signs.append(np.sign(above[np.abs(above) > reach]))
        assert len(np.unique(signs[-1])) == 1
    assert signs[0][0] != signs[1][0]
    assert len(cut.added) < 6 * len(cut.split)  # fewer than Mor and Kanade's without snaps


def test_a_cut_across_the_polyps_stalk_frees_its_head():
    from scenes.anatomy import GENERATORS, defaults
    from taichi_lap.preprocess.tetrahedralize import tetrahedralize

    params = defaults("polyp") | {"radius": 0.008, "stalk_radius": 0.003, "stalk_length": 0.006}
    mesh = tetrahedralize(GENERATORS["polyp"].build(params), 0.0018)
    points, tets = mesh.particles, mesh.tets
    volume = tet_volumes(points, tets).sum()
    low, high = points[:, 1].min(), points[:, 1].max()
    # a horizontal blade drawn through the stalk a quarter of its length above its foot
    height = low + 0.25 * params["stalk_length"]
    path = slice_path(np.array([0.0, height, 0.0]), [0.0, 1.0, 0.0], size=0.02, frames=8)
    cut = cut_tets(points, tets, path)
    points, tets = cut.apply(points, tets)
    assert_closed_pieces(points, tets, 2, volume)
    head = max(pieces(points, tets), key=len)
    assert points[np.unique(head), 1].min() >= height - 1e-9
    assert points[np.unique(head), 1].max() == pytest.approx(high)


def plane_path(a, b, c, size: float = 0.05) -> BladePath:
    """A blade drawn across the plane through points a, b and c."""
    return slice_path(np.asarray(a), np.cross(np.subtract(b, a), np.subtract(c, a)), size=size)


def lerp(i: int, j: int, t: float) -> np.ndarray:
    """The point a fraction t along the edge from corner i to corner j of CORNERS."""
    return (1.0 - t) * CORNERS[i] + t * CORNERS[j]


@pytest.mark.parametrize(
    "plane, on_cut, sub_tets",
    [
        # corner 0 within 3 % of the plane: corner 1 parted from 2 and 3 by a tet and
        # a pyramid (two tets)
        ((lerp(0, 2, 0.03), lerp(1, 2, 0.5), lerp(1, 3, 0.5)), [0], 3),
        # corners 0 and 1 within 4 %: corner 2 parted from 3 by two tets
        ((lerp(0, 3, 0.04), lerp(1, 3, 0.04), lerp(2, 3, 0.5)), [0, 1], 2),
        # the plane clips corner 0's tip only: the tet stays whole
        ((lerp(0, 1, 0.03), lerp(0, 2, 0.03), lerp(0, 3, 0.03)), [0], 0),
    ],
)
def test_a_cut_through_a_corner_snaps_it_and_gives_it_a_twin(plane, on_cut, sub_tets):
    """Node snapping (SNAP_FRACTION): a crossing near a corner goes through it; the
    corner stays on one side and a twin at its place takes the other; the sub-tets
    are positive, fill the tet and bound two closed pieces; the other crossings lie
    SNAP_FRACTION of their edge or more from its ends."""
    tet = np.array([[0, 1, 2, 3]])
    cut = cut_tets(CORNERS, tet, plane_path(*plane))
    assert len(cut.added) == sub_tets
    if not sub_tets:
        assert cut.empty and len(cut.vertex_parents) == 0
        return
    twins = cut.vertex_parents[:, 0] == cut.vertex_parents[:, 1]
    assert sorted(cut.vertex_parents[twins, 0]) == on_cut
    assert np.all(cut.vertex_weights[~twins] >= SNAP_FRACTION - 1e-12)
    points, tets = cut.apply(CORNERS, tet)
    assert_closed_pieces(points, tets, 2, tet_volumes(CORNERS, tet)[0])
    for twin in np.flatnonzero(twins):
        original = cut.vertex_parents[twin, 0]
        np.testing.assert_array_equal(points[4 + twin], CORNERS[original])
        piece_of = {int(v): k for k, p in enumerate(pieces(points, tets)) for v in np.unique(p)}
        assert piece_of[original] != piece_of[4 + twin]


def test_cut_after_cut_keeps_closed_pieces_and_snapping_keeps_sub_tets_from_shrinking(
    monkeypatch,
):
    """Eight random planes cut the polyp one after the other: every cut leaves closed,
    outward pieces of the volume as built and no triangle of zero area. Without
    snapping (SNAP_FRACTION 0) the same cuts leave sub-tets a thousand times smaller
    (crossings near a corner make slivers of slivers)."""
    from scenes.anatomy import GENERATORS, defaults
    from taichi_lap.core.mesh import degenerate_triangles
    from taichi_lap.dissection import tet_cut
    from taichi_lap.preprocess.tetrahedralize import tetrahedralize

    mesh = tetrahedralize(GENERATORS["polyp"].build(defaults("polyp")), 0.0018)

    def cut_eight() -> float:
        points, tets = mesh.particles, mesh.tets
        volume = tet_volumes(points, tets).sum()
        low, high = points.min(axis=0), points.max(axis=0)
        rng = np.random.default_rng(1)
        for _ in range(8):
            path = slice_path(rng.uniform(low, high), rng.normal(size=3), size=0.05)
            points, tets = cut_tets(points, tets, path).apply(points, tets)
            label = element_pieces(tets)
            for k in np.unique(label):
                surface = boundary_faces(tets[label == k])
                assert edge_defects(surface) == (0, 0) and inconsistent_edges(surface) == 0
                assert enclosed_volume(points, surface) > 0.0
                assert not degenerate_triangles(points, surface).any()
            assert tet_volumes(points, tets).sum() == pytest.approx(volume, rel=1e-9)
        return float(tet_volumes(points, tets).min())

    snapped = cut_eight()
    monkeypatch.setattr(tet_cut, "SNAP_FRACTION", 0.0)
    monkeypatch.setattr(tet_cut, "EDGE_MARGIN", 0.05)  # as before snapping
    assert snapped > 1000.0 * cut_eight()


def test_a_cut_of_the_tets_near_the_blade_snaps_no_vertex_whose_tets_are_not_all_given():
    """As a session cuts, only some tets given (here those the plane crosses;
    ``open_vertices`` the vertices with other tets): the cut, applied to the whole
    block, leaves two closed pieces of its volume; without ``open_vertices`` a vertex
    snapped at the edge of the tets given takes its twin into only some of its tets,
    and the surface is open there."""
    b = block(3)
    points, tets = b["rest_positions"], b["tets"]
    volume = tet_volumes(points, tets).sum()
    normal = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    centre = np.array([0.0131, 0.015, 0.014])
    above = (points[tets] - centre) @ normal
    near = np.flatnonzero((above.max(axis=1) > 0.0) & (above.min(axis=1) < 0.0))  # crossed
    given = np.bincount(tets[near].ravel(), minlength=len(points))
    open_vertices = given < np.bincount(tets.ravel(), minlength=len(points))
    path = slice_path(centre, normal, size=0.04, frames=4)

    def whole_block(cut) -> tuple[np.ndarray, np.ndarray]:
        keep = np.ones(len(tets), dtype=bool)
        keep[near[cut.removed]] = False
        return cut.apply(points, np.concatenate([tets[keep], tets[near]]))[0], np.concatenate(
            [tets[keep], cut.added]
        )

    cut = cut_tets(points, tets[near], path, open_vertices=open_vertices)
    assert_closed_pieces(*whole_block(cut), 2, volume)
    careless = cut_tets(points, tets[near], path)
    twins = careless.vertex_parents[careless.vertex_parents[:, 0] == careless.vertex_parents[:, 1]]
    assert open_vertices[twins[:, 0]].any()
    assert edge_defects(boundary_faces(whole_block(careless)[1])) != (0, 0)
