"""Edges of triangle and tetrahedral meshes (NumPy), listed in one place for every
layer: model building, mesh checks, tissue and intestine collision, the grasp pull."""

from __future__ import annotations

import numpy as np

from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from taichi_lap.core.csr import incidence

TRIANGLE_EDGES = np.array([[0, 1], [1, 2], [2, 0]])
"""Edge k of a triangle joins corners k and k + 1."""
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
"""Faces of a tet, each opposite one corner, outward for a positive tet."""
DEGENERATE_AREA = 1e-12
"""A triangle is degenerate below this area, as a fraction of its mesh's squared
bounding-box diagonal."""


def element_edges(elements: np.ndarray) -> np.ndarray:
    """Every edge of every element, element by element (E·k, 2) int64, each sorted
    i < j: triangles (F, 3) in the order of :data:`TRIANGLE_EDGES`, tets (T, 4) in that
    of :data:`TET_EDGES`."""
    elements = np.asarray(elements, dtype=np.int64)
    pattern = {3: TRIANGLE_EDGES, 4: TET_EDGES}[elements.shape[1]]
    return np.sort(elements[:, pattern].reshape(-1, 2), axis=1)


def unique_edges(
    elements: np.ndarray, *, return_inverse: bool = False, return_counts: bool = False
):
    """The distinct edges (E, 2) of ``elements`` (see :func:`element_edges`), sorted
    i < j and in increasing order; with ``return_inverse`` also the edge of each row
    of :func:`element_edges`, with ``return_counts`` how many elements use each."""
    edges = element_edges(elements)
    n = np.int64(edges.max(initial=0) + 1)
    keys, inverse, counts = np.unique(
        edges[:, 0] * n + edges[:, 1], return_inverse=True, return_counts=True
    )
    out = [np.stack(np.divmod(keys, n), axis=1)]
    if return_inverse:
        out.append(inverse.reshape(-1))
    if return_counts:
        out.append(counts)
    return out[0] if len(out) == 1 else tuple(out)


def in_box(points: np.ndarray, elements: np.ndarray, low, high) -> np.ndarray:
    """(E,) whether each of ``elements`` (E, k) (triangles, tets) of ``points`` (V, 3)
    has a bounding box that meets the box ``low``..``high``: each point says on which
    sides of the box it lies (six bits), and an element is out when all its corners
    are on one side (cheaper than the elements' boxes when the box is small)."""
    points = np.asarray(points)
    below, above = points < np.asarray(low), points > np.asarray(high)
    sides = (below.astype(np.uint8) @ np.array([1, 2, 4], np.uint8)) | (
        above.astype(np.uint8) @ np.array([8, 16, 32], np.uint8)
    )
    elements = np.asarray(elements)
    common = sides[elements[:, 0]]
    for k in range(1, elements.shape[1]):
        common = common & sides[elements[:, k]]
    return common == 0


def pair_lengths(points: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(E,) the distance between the two points of each pair (E, 2) (edge lengths)."""
    return np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)


def edge_neighbours(triangles: np.ndarray) -> np.ndarray:
    """(F, 3): the triangle across edge k = (v_k, v_k+1) of each triangle; -1 on a
    boundary or a non-manifold edge (one shared by more than two triangles)."""
    f = len(triangles)
    _, edge, uses = unique_edges(triangles, return_inverse=True, return_counts=True)
    order = np.argsort(edge, kind="stable")
    same = edge[order[:-1]] == edge[order[1:]]
    i, j = order[:-1][same], order[1:][same]
    manifold = uses[edge[i]] == 2
    i, j = i[manifold], j[manifold]
    out = np.full(3 * f, -1, dtype=np.int64)
    out[i], out[j] = j // 3, i // 3
    return out.reshape(f, 3)


INCIDENT_WIDTH = 24
"""Triangles a surface vertex can be in (a BCC boundary vertex has up to 12, a wound
vertex on a cut edge at most two per tet around the edge plus its clipped faces)."""


def incident_table(triangles: np.ndarray, vertices: int) -> np.ndarray:
    """(V, W) the triangles each of ``vertices`` vertices is in, -1 padded (W at least
    :data:`INCIDENT_WIDTH`): normals gather over a row, and dissection rewrites only
    the rows of the vertices it touched."""
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    start, rows = incidence(triangles.reshape(-1), vertices)
    valence = np.diff(start)
    table = np.full((vertices, max(INCIDENT_WIDTH, int(valence.max(initial=0)))), -1, np.int64)
    owner = np.repeat(np.arange(vertices), valence)
    table[owner, np.arange(len(rows)) - start[owner]] = rows // 3
    return table


def face_keys(faces: np.ndarray, count: int) -> np.ndarray:
    """One int64 per triangle ``faces`` (F, 3) of vertices below ``count``, the same for
    the same three vertices in any order."""
    n = np.int64(count)
    if n >= 1 << 21:
        raise ValueError(f"{n} vertices exceed the 2^21 of int64 face keys")
    ordered = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (ordered[:, 0] * n + ordered[:, 1]) * n + ordered[:, 2]


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces ``(F, 3)`` used by one tet, counter-clockwise seen from outside."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    _, first, count = np.unique(
        face_keys(faces, tets.max() + 1), return_index=True, return_counts=True
    )
    return faces[np.sort(first[count == 1])]


def element_pieces(elements: np.ndarray) -> np.ndarray:
    """(E,) the connected piece of each element (triangles (E, 3) or tets (E, 4)),
    numbered from 0 in the order of their first elements: elements that share a
    vertex are in one piece."""
    elements = np.asarray(elements, dtype=np.int64)
    count, corners = elements.shape if elements.size else (0, 1)
    owner = np.repeat(np.arange(count), corners)
    graph = coo_matrix(
        (np.ones(owner.size), (owner, count + elements.ravel())),
        shape=(count + int(elements.max(initial=-1)) + 1,) * 2,
    )
    label = connected_components(graph, directed=False)[1][:count]
    return np.unique(label, return_inverse=True)[1].reshape(-1)


def piece_count(elements: np.ndarray) -> int:
    """How many connected pieces the ``elements`` form (:func:`element_pieces`)."""
    return int(element_pieces(elements).max(initial=-1)) + 1


def tet_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``(T,)`` [m^3] of ``tets`` at ``points``, positive for positively
    oriented tets (corner 3 on the side of the face 0-1-2 its normal points away from,
    the face turning counter-clockwise seen from outside)."""
    x = np.asarray(points, dtype=np.float64)[np.asarray(tets, dtype=np.int64)]
    d = x[:, 1:] - x[:, :1]
    return np.einsum("ij,ij->i", np.cross(d[:, 0], d[:, 1]), d[:, 2]) / 6.0


def triangle_areas(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Areas ``(F,)`` [m^2] of ``triangles`` at ``points``."""
    x = np.asarray(points, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    return 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)


def enclosed_volume(points: np.ndarray, triangles: np.ndarray) -> float:
    """Volume [m^3] a closed triangle mesh encloses (divergence theorem), negative
    when its faces point inwards."""
    x = np.asarray(points, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    return float(np.einsum("ij,ij->", x[:, 0], np.cross(x[:, 1], x[:, 2])) / 6.0)


def edge_defects(triangles: np.ndarray) -> tuple[int, int]:
    """Counts of open edges (in one triangle) and non-manifold edges (in three or
    more) of a triangle mesh that should be closed."""
    _, uses = unique_edges(triangles, return_counts=True)
    return int(np.count_nonzero(uses == 1)), int(np.count_nonzero(uses > 2))


def inconsistent_edges(triangles: np.ndarray) -> int:
    """Edges of a closed manifold mesh whose two triangles run them the same way
    (their orientations disagree)."""
    triangles = np.asarray(triangles, dtype=np.int64)
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    return int(len(directed) - len(np.unique(directed, axis=0)))


def faces_out(points: np.ndarray, triangles: np.ndarray) -> bool:
    """Whether ``triangles`` at ``points`` are closed surfaces facing out, so that
    their back faces are never seen from outside them: after welding vertices at the
    same point (a drawn mesh splits them where its normals do), every edge lies in
    two triangles that run it in opposite directions, and each connected piece
    encloses a positive volume. False for no triangles."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if not len(triangles):
        return False
    welded = np.unique(points, axis=0, return_inverse=True)[1].reshape(-1)[triangles]
    if edge_defects(welded) != (0, 0) or inconsistent_edges(welded):
        return False
    pieces = element_pieces(welded)
    x = points[triangles]
    volume = np.einsum("ij,ij->i", x[:, 0], np.cross(x[:, 1], x[:, 2]))
    return bool(np.all(np.bincount(pieces, weights=volume) > 0.0))


def degenerate_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F,) bool: triangles with a repeated vertex or an area below
    :data:`DEGENERATE_AREA` of the squared diagonal of ``points``' bounding box."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    area = triangle_areas(points, triangles)
    diagonal_sq = float(np.sum((points.max(axis=0) - points.min(axis=0)) ** 2))
    repeated = (
        (triangles[:, 0] == triangles[:, 1])
        | (triangles[:, 1] == triangles[:, 2])
        | (triangles[:, 2] == triangles[:, 0])
    )
    return repeated | (area < DEGENERATE_AREA * diagonal_sq)


def rows_in(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(len(rows),) bool: each (i, j) row of ``rows`` is a row of ``table``."""
    if not len(table) or not len(rows):
        return np.zeros(len(rows), dtype=bool)
    n = int(max(rows.max(), table.max())) + 1
    return np.isin(rows[:, 0] * n + rows[:, 1], table[:, 0] * n + table[:, 1])


def element_measures(points: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """The areas [m^2] of triangles (E, 3) or the unsigned volumes [m^3] of tets (E, 4)
    at ``points``."""
    elements = np.asarray(elements, dtype=np.int64)
    if elements.shape[1] == 3:
        return triangle_areas(points, elements)
    return np.abs(tet_volumes(points, elements))


def masses_after_cut(
    rest: np.ndarray,
    elements: np.ndarray,
    dead: np.ndarray,
    new_elements: np.ndarray,
    mass: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The masses [kg] of a mesh's vertices after a cut replaced some of its
    elements (triangles of a surface, tets of a volume), the mesh's mass kept but
    for what the cut took away: each old vertex (the first ``len(mass)`` of ``rest``
    [m], the rest positions of the old and new vertices) gives the ``elements`` that
    die (``dead``) its mass's share by their measure at it (an equal share of each
    incident element's area or volume: ``elements`` hold every element at the old
    vertices in question), and the ``new_elements`` take that mass at its mean
    density over the dead elements, shared by the same rule among their corners;
    the area or volume the cut removed (a kerf, fragments) takes its mass with it.
    Returns (the masses of the old vertices, those of the new ones)."""
    old, corners = len(mass), elements.shape[1]
    corner_measure = np.repeat(element_measures(rest, elements) / corners, corners)
    at = elements.ravel()
    measure = np.bincount(at, weights=corner_measure, minlength=old)[:old]
    lost = np.bincount(at, weights=corner_measure * np.repeat(dead, corners), minlength=old)[:old]
    given = mass * np.divide(lost, measure, out=np.zeros(old), where=measure > 0.0)
    density = given.sum() / max(lost.sum(), 1e-30)
    new_measure = np.repeat(element_measures(rest, new_elements) / corners, corners)
    taken = density * np.bincount(new_elements.ravel(), weights=new_measure, minlength=len(rest))
    return mass - given + taken[:old], taken[old:]
