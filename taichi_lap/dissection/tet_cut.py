"""Volumetric cutting by a line blade (seed 000 §5.3), on the host.

The instrument's implicit shape is a line, the blade's edge, so its sweep volume is a
sweep surface: :class:`BladePath` joins the blade's segments of successive frames into
quadrilaterals (two triangles each, exact for a translation). A cut accumulates its
path while the blade cuts, so a tet it crosses over several frames is cut when the
path has passed through it.

Each tet's intersection state is the tuple of seed 000's binary codes
(:func:`intersection_codes`): an edge code (bit k: the path crosses edge k of
:data:`~taichi_lap.core.mesh.TET_EDGES`) and a face code (bit k: the path's boundary,
the blade's edge itself or its ends' tracks, crosses the face opposite corner k,
where a cut ends inside the tet). :func:`cut_tets` splits the tets the path
separates, whose edge code is one of the seven of :data:`SEPARATING` (one corner
from three, or two from two), into sub-tets after the minimal subdivision of Mor and
Kanade (2000) for a completed cut: each cut edge gets a new vertex per side; the side
of one corner is a tet, each side of three or two corners a prism split into three
tets along diagonals through the least vertex index of each quadrilateral face
(Dompierre et al. 1999), so tets that share a face split it alike. Tets whose code is
partial (the cut ends inside them: Mor and Kanade's progressive cases) are left whole
until the path passes through them, and so are their neighbours on the edges they
share, so the mesh stays conforming. Sub-tets have positive volume (intersections are
kept :data:`EDGE_MARGIN` from the corners) and fill their parent exactly; the faces on
the cut become surface on both sides
(:func:`~taichi_lap.core.mesh.boundary_faces`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.mesh import TET_EDGES, TET_FACES, tet_volumes, unique_edges
from taichi_lap.dissection.surface_cut import MeshCut

EDGE_MARGIN = 0.05
"""An intersection is kept this fraction of its edge away from the edge's ends, so no
sub-tet is flat."""


def _separating_codes() -> dict[int, int]:
    """Edge code -> the corners (bit mask) on one side, for the seven codes that
    split a tet in two: one corner from three (4) and two from two (3)."""
    out = {}
    for side in range(1, 15):
        if side & 1:  # each split once, named by the side without corner 0
            continue
        code = 0
        for k, (i, j) in enumerate(TET_EDGES):
            if bool(side >> i & 1) != bool(side >> j & 1):
                code |= 1 << k
        out[code] = side
    return out


SEPARATING = _separating_codes()
"""The edge codes of a tet the cut separates, with the corners of one side."""


@dataclass(frozen=True)
class BladePath:
    """The blade's edge at successive poses: ``segments`` (P, 2, 3) [m], the blade
    from its heel to its point at each."""

    segments: np.ndarray

    @classmethod
    def of(cls, segments) -> BladePath:
        segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
        if len(segments) < 2 or not np.isfinite(segments).all():
            raise ValueError("BladePath: at least two finite blade segments were expected")
        return cls(segments)

    def then(self, segment) -> BladePath:
        """The path with the blade's next pose appended."""
        return BladePath.of(np.concatenate([self.segments, np.reshape(segment, (1, 2, 3))]))

    @property
    def triangles(self) -> np.ndarray:
        """The sweep surface as triangles (2 (P - 1), 3, 3)."""
        a0, b0 = self.segments[:-1, 0], self.segments[:-1, 1]
        a1, b1 = self.segments[1:, 0], self.segments[1:, 1]
        return np.concatenate([np.stack([a0, b0, b1], 1), np.stack([a0, b1, a1], 1)])

    @property
    def boundary(self) -> np.ndarray:
        """The sweep surface's boundary as segments (2 P, 2, 3): the first and the last
        blade and the tracks of its heel and point."""
        s = self.segments
        tracks = [np.stack([s[:-1, end], s[1:, end]], 1) for end in (0, 1)]
        return np.concatenate([s[:1], s[-1:], *tracks])


def segment_crossings(
    starts: np.ndarray, ends: np.ndarray, triangles: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where segments (n, 3) -> (n, 3) cross triangles (Q, 3, 3) (Möller and Trumbore
    1997): a mask (n, Q) and the parameters t (n, Q) along the segments."""
    d = ends - starts
    e1 = triangles[:, 1] - triangles[:, 0]
    e2 = triangles[:, 2] - triangles[:, 0]
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("nqj,qj->nq", p, e1)
    scale = np.maximum(np.linalg.norm(d, axis=1)[:, None], 1e-30) * np.linalg.norm(
        np.cross(e1, e2), axis=1
    )
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-30)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = starts[:, None, :] - triangles[None, :, 0]
    u = np.einsum("nqj,nqj->nq", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("nj,nqj->nq", d, q) * inv
    t = np.einsum("qj,nqj->nq", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < 1)
    return hit, t


def _edge_codes(crossed: np.ndarray, tet_edges: np.ndarray) -> np.ndarray:
    """Each tet's edge code: bit k set where its edge k (``tet_edges`` (T, 6), rows of
    the distinct edges) is ``crossed``."""
    return (crossed[tet_edges] * (1 << np.arange(6))).sum(axis=1)


def intersection_codes(
    points: np.ndarray, tets: np.ndarray, path: BladePath
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seed 000 §5.3's intersection state of each tet: edge codes (T,), face codes
    (T,), the tets' distinct edges (E, 2) with each one's crossing parameter along
    (i, j) (NaN where the path does not cross it: no crossing, or an even number of
    them), and each tet's edges as rows of those (T, 6)."""
    points = np.asarray(points, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    edges, edge_of = unique_edges(tets, return_inverse=True)
    tet_edges = edge_of.reshape(-1, 6)
    hit, t = segment_crossings(points[edges[:, 0]], points[edges[:, 1]], path.triangles)
    count = hit.sum(axis=1)
    t_edge = np.full(len(edges), np.nan)
    for e in np.flatnonzero(count % 2 == 1):
        t_edge[e] = float(np.median(t[e][hit[e]]))
    edge_code = _edge_codes(np.isfinite(t_edge), tet_edges)

    boundary = path.boundary
    faces = points[tets[:, TET_FACES]].reshape(-1, 3, 3)
    face_hit, _ = segment_crossings(boundary[:, 0], boundary[:, 1], faces)
    through = face_hit.any(axis=0).reshape(-1, 4)
    face_code = (through * (1 << np.arange(4))).sum(axis=1)
    return edge_code, face_code, edges, t_edge, tet_edges


@dataclass(frozen=True)
class TetCut(MeshCut):
    """A volumetric cut (:func:`cut_tets`; :class:`MeshCut`, its added tets
    positively oriented), with the ``edge_code`` and ``face_code`` of every input tet
    and the tets the cut reached but left whole (``deferred``: it ends inside them or
    beside them)."""

    edge_code: np.ndarray
    face_code: np.ndarray
    deferred: np.ndarray


def cut_tets(
    points: np.ndarray,
    tets: np.ndarray,
    path: BladePath,
    rest: np.ndarray | None = None,
    keep_whole: np.ndarray | None = None,
) -> TetCut:
    """Seed 000 §5.3: split the tets (T, 4) at ``points`` (V, 3) [m] that ``path``
    separates (module docstring); sub-tets are oriented positively at ``rest`` (the
    rest positions; default ``points``). Tets marked in ``keep_whole`` (T,) bool are
    not split (a cut's own sub-tets, a wound's tets), nor, so that the mesh stays
    conforming, their neighbours on the edges they share where that leaves a cut
    partial."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    rest = points if rest is None else np.asarray(rest, dtype=np.float64).reshape(-1, 3)
    edge_code, face_code, edges, t_edge, tet_edges = intersection_codes(points, tets, path)
    crossed = np.isfinite(t_edge)
    if keep_whole is not None:
        crossed[tet_edges[np.asarray(keep_whole, dtype=bool)]] = False
    reached = edge_code != 0
    while True:  # a tet the cut does not separate keeps its edges whole, for all
        code = _edge_codes(crossed, tet_edges)
        partial = (code != 0) & ~np.isin(code, list(SEPARATING))
        if not partial.any():
            break
        crossed[tet_edges[partial]] = False
    split = np.flatnonzero(code != 0)
    t_edge = np.clip(t_edge, EDGE_MARGIN, 1.0 - EDGE_MARGIN)

    keys: dict[tuple[int, int], int] = {}
    parents, weights, side_of = [], [], []

    def copy(e: int, corner: int) -> int:
        """The new vertex on edge e on the side of input vertex ``corner``."""
        if (e, corner) not in keys:
            keys[(e, corner)] = len(points) + len(parents)
            i, j = edges[e]
            parents.append((i, j))
            weights.append((1.0 - t_edge[e], t_edge[e]))
            side_of.append(corner)
        return keys[(e, corner)]

    edge_index = {(int(i), int(j)): k for k, (i, j) in enumerate(TET_EDGES)}

    def point(tet: int, i: int, j: int, near: int) -> int:
        """The new vertex on the edge between corners i and j of ``tet``, on the side
        of its corner ``near``."""
        k = edge_index[(min(i, j), max(i, j))]
        return copy(int(tet_edges[tet, k]), int(tets[tet, near]))

    added = []
    for tet in split:
        c = tets[tet]
        side = SEPARATING[int(code[tet])]
        one = [k for k in range(4) if side >> k & 1]
        other = [k for k in range(4) if not side >> k & 1]
        if len(one) == 2:
            (a, b), (g, d) = one, other
            added += _prism(
                [c[a], point(tet, a, g, a), point(tet, a, d, a)],
                [c[b], point(tet, b, g, b), point(tet, b, d, b)],
            )
            added += _prism(
                [c[g], point(tet, a, g, g), point(tet, b, g, g)],
                [c[d], point(tet, a, d, d), point(tet, b, d, d)],
            )
        else:
            (v,), others = (one, other) if len(one) == 1 else (other, one)
            added.append([c[v], *(point(tet, v, k, v) for k in others)])
            added += _prism([c[k] for k in others], [point(tet, v, k, k) for k in others])

    parents = np.array(parents, dtype=np.int64).reshape(-1, 2)
    weights = np.array(weights, dtype=np.float64).reshape(-1, 2)
    added = np.array(added, dtype=np.int64).reshape(-1, 4)
    if len(added):
        at_rest = np.concatenate([rest, np.einsum("nk,nkd->nd", weights, rest[parents])])
        flipped = tet_volumes(at_rest, added) < 0.0
        added[flipped] = added[flipped][:, [0, 2, 1, 3]]
    return TetCut(
        len(points),
        split,
        added,
        parents,
        weights,
        np.array(side_of, dtype=np.int64),
        edge_code,
        face_code,
        np.flatnonzero(reached & (code == 0)),
    )


def _prism(bottom: list[int], top: list[int]) -> list[list[int]]:
    """Three tets filling the prism with triangles ``bottom`` and ``top`` (top[k]
    above bottom[k]), each quadrilateral face split along the diagonal through its
    least vertex index (Dompierre et al. 1999), so a face two prisms share is split
    alike in both."""
    v = [*bottom, *top]
    least = int(np.argmin(v))
    turn = least % 3  # rotate so the least vertex is corner 0 (bottom or top)
    order = [(turn + k) % 3 for k in range(3)]
    lower = [bottom[k] for k in order]
    upper = [top[k] for k in order]
    if least >= 3:
        lower, upper = upper, lower
    v0, v1, v2 = lower
    v3, v4, v5 = upper
    if min(v1, v5) < min(v2, v4):
        return [[v0, v1, v2, v5], [v0, v1, v5, v4], [v0, v4, v5, v3]]
    return [[v0, v1, v2, v4], [v0, v4, v2, v5], [v0, v4, v5, v3]]
