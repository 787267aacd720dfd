"""Constraint topology of surfaces: edges, bending pairs, long-range attachments
(seed 000 §3.2) and the spring network of seed 001 §3.2."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from taichi_lap.core.geometry import SpringSheet, TriangleMesh
from taichi_lap.core.mesh import pair_lengths, unique_edges


def bending_pairs(triangles: np.ndarray) -> np.ndarray:
    """For every edge shared by two triangles, the two vertices opposite it (a distance
    constraint between them resists folding, Müller et al. 2007 §4.2), sorted i < j
    and in increasing order."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    n = np.int64(t.max(initial=0) + 1)
    a, b = t.ravel(), t[:, [1, 2, 0]].ravel()  # edge k of a triangle: corners k, k + 1
    opposite = t[:, [2, 0, 1]].ravel()
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key, opposite = key[order], opposite[order]
    same = key[1:] == key[:-1]
    pairs = np.sort(np.stack([opposite[:-1][same], opposite[1:][same]], axis=1), axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return np.stack(np.divmod(np.unique(pairs[:, 0] * n + pairs[:, 1]), n), axis=1)


@dataclass
class Attachments:
    """Long-range attachments: constrained ``particle``, its ``anchor`` and rest
    distance d' [m] (geodesic along the surface, Kim et al. 2012)."""

    particle: np.ndarray
    anchor: np.ndarray
    rest: np.ndarray


def long_range_attachments(
    mesh: TriangleMesh,
    anchors: np.ndarray,
    per_vertex: int,
    edges: np.ndarray | None = None,
    reach: float = np.inf,
) -> Attachments:
    """Each free vertex keeps its ``per_vertex`` geodesically nearest anchors (seed 000
    §3.2: "it may be constrained by different attached vertices"), fewer where its
    piece of the mesh holds fewer; distances along the mesh's ``edges`` (its unique
    edges, :func:`~taichi_lap.core.mesh.unique_edges`, found when not given).

    ``reach`` [m]: a guess at the farthest such anchor. The search from each anchor
    stops there, and runs again unbounded when a vertex found fewer anchors within it
    than its piece holds: the result is the same, found faster when the guess holds
    (a sheet cut again and again, whose attachments move little)."""
    anchors = np.unique(np.asarray(anchors, dtype=np.int64))
    n = len(mesh.vertices)
    edges = unique_edges(mesh.triangles) if edges is None else edges
    length = pair_lengths(mesh.vertices, edges)
    graph = csr_matrix(
        (np.concatenate([length, length]), (edges.ravel("F"), edges[:, ::-1].ravel("F"))),
        shape=(n, n),
    )
    free = np.ones(n, dtype=bool)
    free[anchors] = False
    count = min(per_vertex, len(anchors))
    distance = dijkstra(graph, indices=anchors, limit=reach)[:, free]  # (A, F)
    if np.isfinite(reach):
        piece = connected_components(graph, directed=False)[1]
        held = np.bincount(piece[anchors], minlength=piece.max(initial=-1) + 1)
        if np.any(np.isfinite(distance).sum(axis=0) < np.minimum(count, held[piece[free]])):
            distance = dijkstra(graph, indices=anchors)[:, free]
    nearest = np.argsort(distance, axis=0, kind="stable")[:count]  # (count, F)
    rest = np.take_along_axis(distance, nearest, axis=0)
    reachable = np.isfinite(rest)
    particle = np.broadcast_to(np.flatnonzero(free), nearest.shape)[reachable]
    return Attachments(particle=particle, anchor=anchors[nearest][reachable], rest=rest[reachable])


@dataclass
class Springs:
    """Damped springs (seed 001 §3.2): pairs, rest lengths [m], stiffness [N/m]."""

    pairs: np.ndarray
    rest: np.ndarray
    stiffness: np.ndarray


def sheet_springs(
    sheet: SpringSheet, *, intestine: float, mesentery: float, bending: float
) -> Springs:
    """Springs of seed 001 Fig. 6 on rows (R, C): along every row (row 0, the
    intestine, with ``intestine`` stiffness), between rows and across each quad's
    diagonals (``mesentery``), and skipping one mass along the intestine (``bending``).
    Particle (r, c) has index r * C + c."""
    rows, cols = sheet.rows.shape[:2]
    index = np.arange(rows * cols).reshape(rows, cols)
    along = np.stack([index[:, :-1].ravel(), index[:, 1:].ravel()], axis=1)
    across = np.stack([index[:-1].ravel(), index[1:].ravel()], axis=1)
    diagonal = np.concatenate(
        [
            np.stack([index[:-1, :-1].ravel(), index[1:, 1:].ravel()], axis=1),
            np.stack([index[:-1, 1:].ravel(), index[1:, :-1].ravel()], axis=1),
        ]
    )
    skip = np.stack([index[0, :-2], index[0, 2:]], axis=1)
    pairs = np.concatenate([along, across, diagonal, skip])
    stiffness = np.concatenate(
        [
            np.where(np.arange(len(along)) < cols - 1, intestine, mesentery),
            np.full(len(across) + len(diagonal), mesentery),
            np.full(len(skip), bending),
        ]
    )
    points = sheet.rows.reshape(-1, 3)
    rest = pair_lengths(points, pairs)
    return Springs(pairs=pairs, rest=rest, stiffness=stiffness)


def spring_pieces(pairs: np.ndarray, first: int, end: int) -> int:
    """How many connected pieces springs ``pairs`` (S, 2) make of the particles
    ``first..end`` (a particle no spring holds is a piece of its own)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2) - first
    count = end - first
    graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
    return int(connected_components(graph, directed=False)[0])


def torn_cells(pairs: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(rows - 1, cols - 1) bool: the cells of a (rows, cols) grid of masses (particle
    r cols + c) that the springs ``pairs`` (S, 2), broken, lay in or bordered: a
    diagonal's cell, the one or two cells beside a spring along a row or across rows
    (:func:`sheet_springs`); a spring skipping a mass marks the cells it spans."""
    torn = np.zeros((max(rows - 1, 0), max(cols - 1, 0)), dtype=bool)
    for i, j in np.asarray(pairs, np.int64).reshape(-1, 2).tolist():
        (r0, c0), (r1, c1) = divmod(i, cols), divmod(j, cols)
        low_r, high_r, low_c, high_c = min(r0, r1), max(r0, r1), min(c0, c1), max(c0, c1)
        if high_r == low_r:  # along a row: the cells above and below it
            low_r, high_r = low_r - 1, low_r + 1
        if high_c == low_c:  # across rows: the cells on either side
            low_c, high_c = low_c - 1, low_c + 1
        torn[max(low_r, 0) : high_r, max(low_c, 0) : high_c] = True
    return torn


def sheet_triangles(rows: int, cols: int) -> np.ndarray:
    """Two triangles per quad of a (rows, cols) grid of points (the mesentery surface)."""
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return np.concatenate([np.stack([a, c, b], axis=1), np.stack([b, c, d], axis=1)])


def shell_vertex_count(rows: int, cols: int) -> int:
    """Vertices of the :func:`shell_triangles` of a (rows, cols) grid."""
    return 2 * rows * cols + 4 * (rows - 1) + 4 * (cols - 1)


def border_samples(rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """The (row, column) of each of the R = 2 (rows - 1) + 2 (cols - 1) samples around
    the border of a (rows, cols) grid, in the rim's order
    (:func:`~taichi_lap.kernels.membrane.rim_sample`): the first row forwards, the last
    column, the last row backwards, the first column; each corner once."""
    across, down = cols - 1, rows - 1
    k = np.arange(2 * across + 2 * down)
    i = np.select(
        [k < across, k < across + down, k < 2 * across + down],
        [0, k - across, down],
        down - (k - 2 * across - down),
    )
    j = np.select(
        [k < across, k < across + down, k < 2 * across + down],
        [k, across, across - (k - across - down)],
        0,
    )
    return i, j


def shell_cells(rows: int, cols: int, across: int, along: int) -> np.ndarray:
    """For each triangle of :func:`shell_triangles` of a (rows, cols) fine grid that
    samples a coarse grid ``across`` times between its rows and ``along`` times between
    its columns: the coarse cell it lies in (row-major); a rim triangle's is that of
    the border between its two samples (:func:`border_samples`)."""
    coarse_rows, coarse_cols = (rows - 1) // across, (cols - 1) // along
    i, j = np.divmod(np.arange((rows - 1) * (cols - 1)), cols - 1)  # fine quads
    cell = (i // across) * coarse_cols + j // along
    face = np.concatenate([cell, cell])  # sheet_triangles: two per quad, in two runs
    i, j = border_samples(rows, cols)
    low_i, low_j = np.minimum(i, np.roll(i, -1)), np.minimum(j, np.roll(j, -1))
    rim = np.minimum(low_i // across, coarse_rows - 1) * coarse_cols + np.minimum(
        low_j // along, coarse_cols - 1
    )
    return np.concatenate([face, face, rim, rim])  # rim: (a, b, c) then (a, c, d)


def shell_triangles(rows: int, cols: int) -> np.ndarray:
    """A sheet of a (rows, cols) grid drawn as a closed shell: its front (the grid's
    triangles, vertex i cols + j), its back (the same turned round, from rows cols)
    and the rim between them around the border (the R = 2 (rows - 1) + 2 (cols - 1)
    border samples in order, front copies from 2 rows cols, back copies R later), as
    :func:`~taichi_lap.kernels.membrane.membrane_vertices` lays them out."""
    count, border = rows * cols, 2 * (rows - 1) + 2 * (cols - 1)
    front = sheet_triangles(rows, cols)
    k = np.arange(border)
    a, b = 2 * count + k, 2 * count + (k + 1) % border  # the rim's front corners
    c, d = b + border, a + border  # and its back ones
    rim = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
    return np.concatenate([front, front[:, [0, 2, 1]] + count, rim])
