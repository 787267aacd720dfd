"""Surface cutting, seed 000 Algorithm 3 (taichi_lap.dissection.surface_cut): on a flat
sheet a known sweep leaves exactly the expected faces; boundary intersections on one
edge merge into their median point; sub-faces below v_threshold of their parent go;
what lies inside the sweep goes; a cut grows over frames, at coarse and fine
resolutions, and crosses an earlier cut; any sequence of cuts leaves a valid mesh."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from perf.bench_topology import blade  # a column across the sheet (along y)
from taichi_lap.core.mesh import element_pieces, unique_edges
from taichi_lap.dissection.surface_cut import V_THRESHOLD, Sweep, cut_surface, sheet_problems

CM = 0.01
LEVEL = np.eye(3)


def sheet(cells: int, size: float = 4 * CM):
    """A square sheet in the x-z plane, ``cells`` squares a side, each split along
    one diagonal into two triangles."""
    xs = np.linspace(0.0, size, cells + 1)
    x, z = np.meshgrid(xs, xs, indexing="ij")
    points = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    at = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b = at[:-1, :-1].ravel(), at[:-1, 1:].ravel()
    c, d = at[1:, 1:].ravel(), at[1:, :-1].ravel()
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return points, triangles


def sweep(start, end, radius: float = 0.05 * CM) -> Sweep:
    return Sweep.between(blade(radius), start, LEVEL, end, LEVEL)


def areas(points, triangles) -> np.ndarray:
    x = points[triangles]
    return 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)


def pieces(points, triangles) -> list[float]:
    """The areas of the connected pieces of the mesh, largest first."""
    piece = element_pieces(triangles)
    a = areas(points, triangles)
    return sorted((float(a[piece == p].sum()) for p in np.unique(piece)), reverse=True)


def assert_valid(points, triangles):
    """An oriented, edge-manifold mesh (boundaries allowed) with no degenerate face."""
    assert sheet_problems(points, triangles) == []


def cut_along(points, triangles, start, end, frames: int, radius: float = 0.05 * CM):
    """Cut with the blade moved from ``start`` to ``end`` over ``frames`` frames."""
    path = np.linspace(start, end, frames + 1)
    for a, b in zip(path[:-1], path[1:]):
        points, triangles = cut_surface(points, triangles, sweep(a, b, radius)).apply(
            points, triangles
        )
    return points, triangles


def test_a_blade_drawn_across_a_sheet_leaves_exactly_the_expected_faces():
    points, triangles = sheet(4)
    cut = cut_surface(points, triangles, sweep((1.5 * CM, 0, -CM), (1.5 * CM, 0, 5 * CM)))
    # the column of cells between x = 1 and 2 cm: both of their triangles are replaced
    strip = np.flatnonzero(np.all(np.isin(points[triangles, 0], (CM, 2 * CM)), axis=1))
    assert sorted(cut.removed) == sorted(strip)
    # every edge across x = 1.5 cm (5 along x, 4 diagonals) is cut at its median point,
    # into one copy per side; nothing lies inside the thin sweep
    assert len(cut.removed_vertices) == 0
    crossing = unique_edges(triangles[strip])
    crossing = crossing[np.ptp(points[crossing, 0], axis=1) > 0]
    assert len(crossing) == 9
    assert sorted(map(tuple, cut.removed_edges)) == sorted(map(tuple, crossing))
    new = cut.new_values(points)
    assert len(new) == 18
    np.testing.assert_allclose(new[:, 0], 1.5 * CM, atol=1e-7)
    sides = points[cut.vertex_side, 0]
    assert np.count_nonzero(sides < 1.5 * CM) == np.count_nonzero(sides > 1.5 * CM) == 9
    # each strip triangle becomes its corner on one side and two on the other
    assert len(cut.added) == 3 * len(strip)
    after_points, after = cut.apply(points, triangles)
    assert_valid(after_points, after)
    assert pieces(after_points, after) == pytest.approx([2.5 * 4 * CM**2, 1.5 * 4 * CM**2])


def test_boundary_intersections_on_one_edge_merge_into_their_median():
    # a column 1.6 mm wide crosses the triangle's two edges x = 0 .. 1 cm (both ends of
    # each outside it): each edge meets its boundary twice, 0.8 mm either side of the
    # column's path at x = 0.3 cm, and is cut once, at the median (Fig. 13 b)
    points = np.array([[0, 0, 0], [CM, 0, 0], [0, 0, CM]], dtype=float)
    triangles = np.array([[0, 2, 1]])
    path = sweep((0.3 * CM, 0, -0.5 * CM), (0.3 * CM, 0, 1.5 * CM), radius=0.08 * CM)
    cut = cut_surface(points, triangles, path)
    new = cut.new_values(points)
    np.testing.assert_allclose(
        np.unique(new.round(9), axis=0), [[0.3 * CM, 0, 0], [0.3 * CM, 0, 0.7 * CM]], atol=1e-8
    )
    assert len(new) == 4  # one copy per side
    after_points, after = cut.apply(points, triangles)
    assert_valid(after_points, after)
    # no sliver between the two intersections: the area is kept, in two pieces
    assert pieces(after_points, after) == pytest.approx([0.255 * CM**2, 0.245 * CM**2])


@pytest.mark.parametrize("corner, kept", [(0.3, False), (0.45, True)])
def test_a_sub_face_below_v_threshold_of_its_parent_is_deleted(corner, kept):
    # a cut parallel to the hypotenuse at x + z = corner: the corner's sub-face has
    # corner² of the parent's area (0.09 < 0.15: deleted; 0.2025: kept); the rest
    # keeps pieces of (1 - corner) and corner (1 - corner), above the threshold
    points = np.array([[0, 0, 0], [CM, 0, 0], [0, 0, CM]], dtype=float)
    triangles = np.array([[0, 2, 1]])
    across = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)
    middle = np.array([0.5, 0.0, 0.5]) * corner * CM
    cut = cut_surface(points, triangles, sweep(middle - 2 * CM * across, middle + 2 * CM * across))
    after_points, after = cut.apply(points, triangles)
    assert_valid(after_points, after)
    parent = 0.5 * CM**2
    assert 0.3**2 < V_THRESHOLD < 0.45**2
    expected = [(1 - corner**2) * parent] + ([corner**2 * parent] if kept else [])
    assert pieces(after_points, after) == pytest.approx(expected, rel=1e-4)
    # with no threshold the corner stays
    across_all = sweep(middle - 2 * CM * across, middle + 2 * CM * across)
    loose = cut_surface(points, triangles, across_all, v_threshold=0.0)
    assert len(pieces(*loose.apply(points, triangles))) == 2


def test_what_lies_inside_the_sweep_is_removed():
    points, triangles = sheet(32)
    radius = 0.6 * CM
    start, end = np.array([0.5 * CM, 0, 2 * CM]), np.array([3.5 * CM, 0, 2 * CM])
    path = sweep(start, end, radius)
    cut = cut_surface(points, triangles, path)
    after_points, after = cut.apply(points, triangles)
    assert_valid(after_points, after)
    inside = path.distance(points) < -path.tolerance
    assert sorted(cut.removed_vertices) == sorted(np.flatnonzero(inside))
    assert not np.isin(after, cut.removed_vertices).any()
    assert np.all(path.distance(after_points[after].mean(axis=1)) >= -path.tolerance)
    # the hole is the stadium the column swept (2 r L + π r²), its rim of chords across
    # cells of 1.25 mm, less the sub-faces there below v_threshold
    hole = 4 * CM**2 * 4 - areas(after_points, after).sum()
    stadium = 2 * radius * 3 * CM + np.pi * radius**2
    assert 0.95 * stadium <= hole <= 1.05 * stadium


@pytest.mark.parametrize("cells, frames", [(4, 1), (4, 60), (32, 8)])
def test_a_cut_grows_over_frames_and_crosses_an_earlier_cut(cells, frames):
    points, triangles = sheet(cells)
    radius = 0.05 * CM
    points, triangles = cut_along(
        points, triangles, (1.51 * CM, 0, -CM), (1.51 * CM, 0, 5 * CM), frames, radius
    )
    assert_valid(points, triangles)
    assert len(pieces(points, triangles)) == 2
    points, triangles = cut_along(
        points, triangles, (-CM, 0, 2.53 * CM), (5 * CM, 0, 2.53 * CM), frames, radius
    )
    assert_valid(points, triangles)
    quarters = pieces(points, triangles)
    assert len(quarters) == 4
    expected = sorted((a * b * CM**2 for a in (1.51, 2.49) for b in (2.53, 1.47)), reverse=True)
    # each quarter loses at most a strip of 1.5 blade widths along its cut sides (the
    # blade's own half width and the rim's sub-faces below v_threshold)
    assert quarters == pytest.approx(expected, abs=1.5 * 2 * radius * 4 * CM)
    assert sum(quarters) < 16 * CM**2


def test_a_cut_that_stops_inside_a_face_ends_at_its_tip_and_goes_on_from_it():
    points, triangles = sheet(2)  # cells of 2 cm: the blade stops inside one
    stop = np.array([1.5 * CM, 0, 0.7 * CM])
    points, triangles = cut_along(points, triangles, (1.5 * CM, 0, -CM), stop, 4)
    assert_valid(points, triangles)
    assert len(pieces(points, triangles)) == 1
    # the slit's two sides meet at a vertex inside the blade
    tip = np.flatnonzero(np.linalg.norm(points - stop, axis=1) < 0.05 * CM)
    assert len(tip) >= 1 and np.isin(tip, triangles).any()
    points, triangles = cut_along(points, triangles, stop, (1.5 * CM, 0, 5 * CM), 6)
    assert_valid(points, triangles)
    assert len(pieces(points, triangles)) == 2


def test_sheet_problems_name_what_is_wrong():
    points, triangles = sheet(2)
    assert sheet_problems(points, triangles) == []
    flipped = triangles.copy()
    flipped[0] = flipped[0, ::-1]
    assert "turn unlike" in " ".join(sheet_problems(points, flipped))
    fin = np.concatenate([triangles, [[4, 0, 2]]])  # a third triangle on edge 0-4
    assert "more than two" in " ".join(sheet_problems(points, fin))
    flat = np.concatenate([triangles, [[0, 1, 2]]])
    assert "degenerate" in " ".join(sheet_problems(points, flat))


def test_new_vertices_lie_on_their_parents_at_rest_and_deformed():
    points, triangles = sheet(4)
    cut = cut_surface(points, triangles, sweep((1.5 * CM, 0, -CM), (1.5 * CM, 0, 5 * CM)))
    assert np.allclose(cut.vertex_weights.sum(axis=1), 1.0)
    bent = points + np.stack([np.zeros(len(points)), points[:, 0] ** 2, np.zeros(len(points))], 1)
    np.testing.assert_allclose(
        cut.new_values(bent), np.einsum("nk,nkd->nd", cut.vertex_weights, bent[cut.vertex_parents])
    )
    assert np.all(cut.vertex_side >= 0)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-0.5, 4.5),
            st.floats(-0.5, 4.5),
            st.floats(-0.5, 4.5),
            st.floats(-0.5, 4.5),
            st.floats(0.02, 0.4),
            st.floats(-0.6, 0.6),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_any_sequence_of_cuts_leaves_a_valid_mesh(cuts):
    points, triangles = sheet(6)
    area = areas(points, triangles).sum()
    for x0, z0, x1, z1, radius, tilt in cuts:
        lean = np.array(
            [[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]
        )
        path = Sweep.between(
            blade(radius * CM), (x0 * CM, 0, z0 * CM), lean, (x1 * CM, 0, z1 * CM), lean
        )
        cut = cut_surface(points, triangles, path)
        points, triangles = cut.apply(points, triangles)
        if len(triangles):
            assert_valid(points, triangles)
        assert not np.isin(triangles, cut.removed_vertices).any()
        now = areas(points, triangles).sum()
        assert now <= area * (1 + 1e-9)
        area = now
