"""Marching tetrahedra on kept/removed particle labels: the wound surface of seed 002
§3.3 (Fig. 4).

When particles are removed, every tet with both kept and removed corners is cut by
the surface that separates them: a new vertex on each edge joining a kept and a
removed corner, connected by one of 14 configurations (2^4 - 2; Fig. 4b-d are three,
the other 11 are their rotations). A surface triangle with one or two removed corners
keeps its kept part, split into triangles by one of 6 configurations (2^3 - 2; Fig.
4f-g). Together they close the kept part of the tet mesh again.

Both tables are built once from the three and two base cases on reference elements;
each triangle is oriented so its normal points from the kept corners towards the
removed ones (outwards of the kept tissue), which an affine map of positive
determinant preserves, so the tables hold for every positively oriented tet
(:func:`taichi_lap.core.mesh.tet_volumes` > 0) and keep a triangle's own orientation.

A generated vertex is named by the particles of the edge it lies on, ``(kept,
removed)``; a kept corner of a clipped surface triangle by ``(corner, corner)``.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.core.mesh import TET_EDGES, TRIANGLE_EDGES


def _tet_edge(a: int, b: int) -> int:
    """Row of :data:`TET_EDGES` joining corners ``a`` and ``b``."""
    return int(np.flatnonzero((np.sort([a, b]) == TET_EDGES).all(axis=1))[0])


def _tet_cases() -> np.ndarray:
    """(16, 2, 3) local edges (rows of TET_EDGES) of each mask's wound triangles (bit
    k of the mask: corner k removed), -1 where a mask has fewer than two."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    midpoint = corners[TET_EDGES].mean(axis=1)
    table = np.full((16, 2, 3), -1, dtype=np.int64)
    for mask in range(1, 15):
        removed = [k for k in range(4) if mask >> k & 1]
        kept = [k for k in range(4) if not mask >> k & 1]
        if len(removed) == 2:  # the quad between the two pairs, as two triangles
            (k1, k2), (r1, r2) = kept, removed
            quad = [_tet_edge(k1, r1), _tet_edge(k1, r2), _tet_edge(k2, r2), _tet_edge(k2, r1)]
            triangles = [quad[:3], [quad[0], quad[2], quad[3]]]
        else:  # one corner cut off
            apex = (removed if len(removed) == 1 else kept)[0]
            triangles = [[_tet_edge(apex, k) for k in range(4) if k != apex]]
        outward = corners[removed].mean(axis=0) - corners[kept].mean(axis=0)
        for row, triangle in enumerate(triangles):
            a, b, c = midpoint[triangle]
            if np.cross(b - a, c - a) @ outward < 0.0:
                triangle = triangle[::-1]
            table[mask, row] = triangle
    return table


def _triangle_cases() -> np.ndarray:
    """(8, 2, 3) slots of each mask's kept triangles (bit k: corner k removed); slot
    k < 3 is corner k, slot 3 + e the point on edge e of TRIANGLE_EDGES; -1 where a
    mask has fewer than two."""
    table = np.full((8, 2, 3), -1, dtype=np.int64)
    for mask in range(1, 7):
        removed = [k for k in range(3) if mask >> k & 1]
        if len(removed) == 1:  # the quad a, b, (b, r), (r, a) in the triangle's turn
            r = removed[0]
            a, b = (r + 1) % 3, (r + 2) % 3
            table[mask, 0] = [a, b, 3 + b]
            table[mask, 1] = [a, 3 + b, 3 + r]
        else:  # the kept corner k and the points on its two edges
            k = ({0, 1, 2} - set(removed)).pop()
            table[mask, 0] = [k, 3 + k, 3 + (k + 2) % 3]
    return table


TET_CASES = _tet_cases()
"""Marching-tetrahedra configurations: mask -> up to two triangles of local edges."""
TRIANGLE_CASES = _triangle_cases()
"""Surface-triangle configurations: mask -> up to two triangles of slots."""


def _masks(elements: np.ndarray, removed: np.ndarray) -> np.ndarray:
    """Bit k set where corner k of each element is removed."""
    bits = removed[elements].astype(np.int64)
    return (bits << np.arange(elements.shape[1])).sum(axis=1)


def _oriented_pairs(ends: np.ndarray, removed: np.ndarray) -> np.ndarray:
    """(..., 2) particle pairs reordered to (kept, removed)."""
    swap = removed[ends[..., 0]]
    return np.where(swap[..., None], ends[..., ::-1], ends)


def wound_triangles(tets: np.ndarray, removed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marching-tetrahedra triangles of ``tets`` (T, 4) for the labels ``removed`` (N,)
    bool: (K, 3, 2) vertex names ``(kept, removed)`` per corner, and (K,) the row of
    ``tets`` each came from. Tets with no or only removed corners give none."""
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    cases = TET_CASES[_masks(tets, removed)]  # (T, 2, 3)
    source, row = np.nonzero(cases[:, :, 0] >= 0)
    local = cases[source, row]  # (K, 3) local edges
    ends = tets[source[:, None, None], TET_EDGES[local]]  # (K, 3, 2)
    return _oriented_pairs(ends, removed), source


def clipped_triangles(triangles: np.ndarray, removed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The kept parts of ``triangles`` (F, 3) of particles for the labels ``removed``:
    (K, 3, 2) vertex names per corner (``(p, p)`` for a kept corner ``p``), and (K,)
    the row each came from. Unchanged triangles come back as themselves; triangles
    with only removed corners give none."""
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    cases = TRIANGLE_CASES[_masks(triangles, removed)]
    whole = _masks(triangles, removed) == 0
    cases[whole, 0] = [0, 1, 2]
    source, row = np.nonzero(cases[:, :, 0] >= 0)
    slots = cases[source, row]  # (K, 3)
    corner_pairs = np.stack([triangles, triangles], axis=2)  # (F, 3, 2)
    edge_pairs = triangles[:, TRIANGLE_EDGES]  # (F, 3, 2)
    named = np.concatenate([corner_pairs, edge_pairs], axis=1)  # (F, 6, 2)
    ends = named[source[:, None], slots]
    return _oriented_pairs(ends, removed), source
