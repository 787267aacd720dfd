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
share, so the mesh stays conforming.

Node snapping (Nienhuys and van der Stappen 2001): a crossing within
:data:`SNAP_FRACTION` of an edge's end goes through that vertex instead. The vertex
keeps the side of one group of its neighbours and a twin at its place takes the other
(neighbours told apart by the edges the cut crosses around it, and by the side of the
cut's plane where those leave groups unjoined); a tet with corners on the cut splits
into fewer sub-tets (one corner: a tet and a pyramid; two: two tets), one it only
touches keeps its corner or takes the twin whole. A vertex is not snapped where its
sides cannot be told, where its tets are not all given, or where two parts of one side
would meet along an edge on the cut (a plane through an edge where the surface folds
in). Sub-tets have positive volume and fill their parent exactly; the faces on the cut
become surface on both sides (:func:`~taichi_lap.core.mesh.boundary_faces`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_lap.core.csr import incidence, rows_of
from taichi_lap.core.mesh import TET_EDGES, TET_FACES, boundary_faces, tet_volumes, unique_edges
from taichi_lap.dissection.surface_cut import MeshCut

EDGE_MARGIN = 1e-6
"""A crossing no vertex could be snapped to is kept this fraction of its edge away
from the edge's ends, so no sub-tet is flat; so little that a tet's crossings stay
on the cut's plane (moved further apart, a prism's split could invert a tet)."""
SNAP_FRACTION = 0.15
"""A crossing nearer than this fraction of its edge to one of the edge's ends goes
through that end instead: the vertex is snapped onto the cut (node snapping,
Nienhuys and van der Stappen 2001), so cut after cut does not leave ever smaller
sub-tets (the fraction is seed 000's v_threshold for faces, Alg. 3)."""


def _side_table() -> np.ndarray:
    """(16, 64): for the corners on the cut (bit mask) and an edge code, the corners
    (bit mask) of the side without the least corner off the cut, or -1 where the code
    does not part the corners off the cut in two (or one) sides."""
    table = np.full((16, 64), -1, dtype=np.int64)
    for snapped in range(16):
        free = [k for k in range(4) if not snapped >> k & 1]
        for side in range(16):
            if side & snapped or (free and side >> free[0] & 1):
                continue
            code = 0
            for k, (i, j) in enumerate(TET_EDGES):
                if i in free and j in free and bool(side >> i & 1) != bool(side >> j & 1):
                    code |= 1 << k
            table[snapped, code] = side
    return table


SIDES = _side_table()
""":func:`_side_table`."""
SEPARATING = {code: int(side) for code, side in enumerate(SIDES[0]) if side > 0}
"""The edge codes of a tet the cut separates (no corner on the cut), with the
corners of one side: one corner from three (4) and two from two (3)."""


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
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seed 000 §5.3's intersection state of each tet: edge codes (T,), face codes
    (T,), the tets' distinct edges (E, 2) with each one's crossing parameter along
    (i, j) (NaN where the path does not cross it: no crossing, or an even number of
    them) and a triangle of the path it crosses (-1 where none), and each tet's edges
    as rows of those (T, 6)."""
    points = np.asarray(points, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    edges, edge_of = unique_edges(tets, return_inverse=True)
    tet_edges = edge_of.reshape(-1, 6)
    hit, t = segment_crossings(points[edges[:, 0]], points[edges[:, 1]], path.triangles)
    count = hit.sum(axis=1)
    crossed_at = np.where(count > 0, np.argmax(hit, axis=1), -1)
    t_edge = np.full(len(edges), np.nan)
    once = np.flatnonzero(count == 1)
    t_edge[once] = t[once, crossed_at[once]]
    for e in np.flatnonzero((count % 2 == 1) & (count > 1)):
        t_edge[e] = float(np.median(t[e][hit[e]]))
    edge_code = _edge_codes(np.isfinite(t_edge), tet_edges)

    boundary = path.boundary
    faces = points[tets[:, TET_FACES]].reshape(-1, 3, 3)
    face_hit, _ = segment_crossings(boundary[:, 0], boundary[:, 1], faces)
    through = face_hit.any(axis=0).reshape(-1, 4)
    face_code = (through * (1 << np.arange(4))).sum(axis=1)
    return edge_code, face_code, edges, t_edge, crossed_at, tet_edges


@dataclass(frozen=True)
class TetCut(MeshCut):
    """A volumetric cut (:func:`cut_tets`; :class:`MeshCut`, its added tets
    positively oriented), with the ``edge_code`` and ``face_code`` of every input tet,
    the tets it ``split`` (the others of ``removed`` are whole again, with a snapped
    vertex's twin) and the tets the cut reached but left whole (``deferred``: it ends
    inside them or beside them)."""

    edge_code: np.ndarray
    face_code: np.ndarray
    split: np.ndarray
    deferred: np.ndarray


def cut_tets(
    points: np.ndarray,
    tets: np.ndarray,
    path: BladePath,
    rest: np.ndarray | None = None,
    keep_whole: np.ndarray | None = None,
    open_vertices: np.ndarray | None = None,
) -> TetCut:
    """Seed 000 §5.3: split the tets (T, 4) at ``points`` (V, 3) [m] that ``path``
    separates (module docstring); sub-tets are oriented positively at ``rest`` (the
    rest positions; default ``points``). Tets marked in ``keep_whole`` (T,) bool are
    not split (a cut's own sub-tets, a wound's tets), nor, so that the mesh stays
    conforming, their neighbours on the edges they share where that leaves a cut
    partial. Vertices marked in ``open_vertices`` (V,) bool (some of their tets are
    not among ``tets``) are not snapped."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    rest = points if rest is None else np.asarray(rest, dtype=np.float64).reshape(-1, 3)
    edge_code, face_code, edges, t_edge, crossed_at, tet_edges = intersection_codes(
        points, tets, path
    )
    held = np.zeros(len(tets), dtype=bool)
    if keep_whole is not None:
        held |= np.asarray(keep_whole, dtype=bool)
    raw = np.isfinite(t_edge)
    raw[tet_edges[held]] = False
    snapped = np.zeros(len(points), dtype=bool)
    plane_of = np.full(len(points), -1)  # a path triangle beside each snapped vertex
    for end, near in ((0, t_edge < SNAP_FRACTION), (1, t_edge > 1.0 - SNAP_FRACTION)):
        snapped[edges[raw & near, end]] = True
        plane_of[edges[raw & near, end]] = crossed_at[raw & near]
    snapped[tets[held].ravel()] = False
    if open_vertices is not None:
        snapped &= ~np.asarray(open_vertices, dtype=bool)
    star_start, star_rows = incidence(tets.ravel(), len(points))
    star_tet = star_rows // 4  # the tets around each vertex
    triangles = path.triangles
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])

    def above(s: int, vertices: list[int]) -> np.ndarray:
        """How far ``vertices`` are above the cut's plane beside snapped vertex s
        (along a normal of no particular length)."""
        k = plane_of[s]
        return (points[vertices] - triangles[k, 0]) @ normals[k]

    t_edge = np.clip(t_edge, EDGE_MARGIN, 1.0 - EDGE_MARGIN)
    while True:  # snapped vertices where the cut does not part the mesh cleanly unsnap
        crossed, code, on_cut, side, partial = _crossings(raw, snapped, edges, tet_edges, tets)
        stars, failed = _stars(
            np.flatnonzero(snapped), star_start, star_tet, snapped, tets, crossed[tet_edges], above
        )
        if failed:
            snapped[failed] = False
            continue
        pieces = _Split(tets, edges, tet_edges, t_edge, snapped, stars, len(points))
        moved = [t for star in stars.values() for t in star.moved]
        split_tets = np.flatnonzero(code != 0)
        touched = np.union1d(split_tets, np.array(moved, dtype=np.int64))
        for tet in touched.tolist():
            pieces.tet(tet, int(on_cut[tet]), int(side[tet]))
        pinched = pieces.pinched(touched, star_start, star_tet)
        if not pinched:
            break
        snapped[pinched] = False

    parents = np.array(pieces.parents, dtype=np.int64).reshape(-1, 2)
    weights = np.array(pieces.weights, dtype=np.float64).reshape(-1, 2)
    added = np.array(pieces.added, dtype=np.int64).reshape(-1, 4)
    if len(added):
        at_rest = np.concatenate([rest, np.einsum("nk,nkd->nd", weights, rest[parents])])
        flipped = tet_volumes(at_rest, added) < 0.0
        added[flipped] = added[flipped][:, [0, 2, 1, 3]]
    deferred = (edge_code != 0) & (held | partial)
    deferred[touched] = False
    return TetCut(
        len(points),
        touched,
        added,
        parents,
        weights,
        np.array(pieces.side_of, dtype=np.int64),
        edge_code,
        face_code,
        split_tets,
        np.flatnonzero(deferred),
    )


class _Split:
    """The sub-tets of a cut (:func:`cut_tets`) and the vertices they add."""

    def __init__(self, tets, edges, tet_edges, t_edge, snapped, stars, vertex_count: int):
        self.tets, self.edges, self.tet_edges, self.t_edge = tets, edges, tet_edges, t_edge
        self.snapped, self.stars, self.vertex_count = snapped, stars, vertex_count
        self.keys: dict[tuple[int, int], int] = {}
        self.parents, self.weights, self.side_of, self.added = [], [], [], []

    def _new_vertex(self, key: tuple[int, int], ends, weight, side: int) -> int:
        if key not in self.keys:
            self.keys[key] = self.vertex_count + len(self.parents)
            self.parents.append(ends)
            self.weights.append(weight)
            self.side_of.append(side)
        return self.keys[key]

    def point(self, tet: int, i: int, j: int, near: int) -> int:
        """The new vertex on the edge between corners i and j of ``tet``, on the side
        of its corner ``near``."""
        e = int(self.tet_edges[tet, EDGE_OF_CORNERS[i, j]])
        t = self.t_edge[e]
        corner = int(self.tets[tet, near])
        return self._new_vertex((e, corner), tuple(self.edges[e]), (1.0 - t, t), corner)

    def at(self, tet: int, k: int, near: int) -> int:
        """Corner k of ``tet`` on the side of its corner ``near`` (off the cut): a
        snapped vertex's twin on the side its star colours 1."""
        c = int(self.tets[tet, k])
        star = self.stars.get(c)
        if star is None or not star.colour[int(self.tets[tet, near])]:
            return c
        return self._new_vertex((-1, c), (c, c), (1.0, 0.0), c)

    def tet(self, tet: int, on_cut: int, side: int) -> None:
        """Add the sub-tets of ``tet`` (its corners ``on_cut`` and the ``side`` of the
        others, :data:`SIDES`): Mor and Kanade's for a tet the cut separates, one or
        two fewer where corners are on the cut, the tet itself with its snapped
        corners' twins where the cut only touches it."""
        c = self.tets[tet]
        free = [k for k in range(4) if not on_cut >> k & 1]
        one = [k for k in free if side >> k & 1]
        other = [k for k in free if not side >> k & 1]
        cut = [k for k in range(4) if on_cut >> k & 1]
        point, at = self.point, self.at
        if not one:
            self.added.append([at(tet, k, other[0]) for k in range(4)])
        elif not cut and len(one) == 2:
            (a, b), (g, d) = one, other
            self.added += _prism(
                [c[a], point(tet, a, g, a), point(tet, a, d, a)],
                [c[b], point(tet, b, g, b), point(tet, b, d, b)],
            )
            self.added += _prism(
                [c[g], point(tet, a, g, g), point(tet, b, g, g)],
                [c[d], point(tet, a, d, d), point(tet, b, d, d)],
            )
        elif not cut:
            (v,), others = (one, other) if len(one) == 1 else (other, one)
            self.added.append([c[v], *(point(tet, v, k, v) for k in others)])
            self.added += _prism([c[k] for k in others], [point(tet, v, k, k) for k in others])
        elif len(free) == 3:  # one corner on the cut: a tet and a pyramid
            (u,), (w, x) = (one, other) if len(one) == 1 else (other, one)
            (s,) = cut
            self.added.append([at(tet, s, u), c[u], point(tet, u, w, u), point(tet, u, x, u)])
            self.added += _pyramid(
                at(tet, s, w), [c[w], c[x], point(tet, u, x, x), point(tet, u, w, w)]
            )
        else:  # two corners on the cut: two tets
            (u,), (x,) = one, other
            for near in (u, x):
                self.added.append(
                    [*(at(tet, k, near) for k in cut), c[near], point(tet, u, x, near)]
                )

    def pinched(self, touched: np.ndarray, start, star_tet) -> list[int]:
        """The snapped vertices at an end of an edge the cut leaves in more than two
        surface triangles: two parts of one side meeting along an edge on the cut (a
        plane through an edge where the surface folds in)."""
        twins = {index: v for (e, v), index in self.keys.items() if e < 0}
        if not twins:
            return []
        added = np.array(self.added, dtype=np.int64).reshape(-1, 4)
        on_cut = np.flatnonzero(self.snapped)
        corners = np.union1d(added[added < self.vertex_count], on_cut)
        around = np.setdiff1d(np.unique(star_tet[rows_of(start, corners)]), touched)
        faces = boundary_faces(np.concatenate([self.tets[around], added]))
        pairs = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        pairs = pairs[np.isin(pairs, np.concatenate([on_cut, list(twins)])).any(axis=1)]
        pairs, count = np.unique(pairs, axis=0, return_counts=True)
        ends = {twins.get(v, v) for v in pairs[count > 2].ravel().tolist()}
        return sorted(v for v in ends if v < self.vertex_count and self.snapped[v])


def _edge_of_corners() -> np.ndarray:
    """(4, 4): the edge of :data:`~taichi_lap.core.mesh.TET_EDGES` between two
    corners (-1 on the diagonal)."""
    table = np.full((4, 4), -1, dtype=np.int64)
    for k, (i, j) in enumerate(TET_EDGES):
        table[i, j] = table[j, i] = k
    return table


EDGE_OF_CORNERS = _edge_of_corners()


def _crossings(raw, snapped, edges, tet_edges, tets):
    """The edges a cut crosses, the tets' edge codes, their corners on the cut and the
    side of each (bit masks, :data:`SIDES`), and the tets it leaves whole because it
    ends inside them: ``raw`` crossings, less those through a snapped vertex, less
    those of every tet whose code does not part its corners off the cut, until every
    code does."""
    crossed = raw & ~snapped[edges].any(axis=1)
    on_cut = (snapped[tets] * (1 << np.arange(4))).sum(axis=1)
    partial = np.zeros(len(tets), dtype=bool)
    while True:
        code = _edge_codes(crossed, tet_edges)
        side = SIDES[on_cut, code]
        if not (side < 0).any():
            return crossed, code, on_cut, side, partial
        partial |= side < 0
        crossed[tet_edges[side < 0]] = False


@dataclass
class _Star:
    """The tets around a snapped vertex: ``colour`` of each neighbour off the cut
    (0 keeps the vertex, 1 takes its twin) and the tets the cut does not split that
    move to the twin (``moved``)."""

    colour: dict[int, int]
    moved: list[int]


def _stars(
    vertices: np.ndarray, start, star_tet, snapped, tets, crossed_edges, above
) -> tuple[dict[int, _Star], list[int]]:
    """Colour each snapped vertex's neighbours by the side of the cut they are on:
    neighbours joined by an edge the cut does not cross (in a tet around the vertex)
    are on one side, by one it crosses on two, and neighbours so joined are on the
    side of the cut's plane (``above(s, vertices)``) most of their distance says, 1
    below. Returns the stars of the vertices the cut passes through (two sides) and
    the vertices whose sides cannot be told: an edge crossed within one side, or a
    tet around it with every corner on the cut."""
    stars, failed = {}, []
    for s in vertices.tolist():
        around = star_tet[start[s] : start[s + 1]].tolist()
        links, all_on_cut = [], False
        for tet in around:
            c = tets[tet]
            free = [k for k in range(4) if not snapped[c[k]]]
            all_on_cut |= not free
            links += [(int(c[free[0]]), int(c[free[0]]), False)] if free else []
            for a in range(len(free)):
                for b in range(a + 1, len(free)):
                    crossed = crossed_edges[tet, EDGE_OF_CORNERS[free[a], free[b]]]
                    links.append((int(c[free[a]]), int(c[free[b]]), bool(crossed)))
        colour = _two_colours(links, lambda vertices, s=s: above(s, vertices))
        two_sides = colour is not None and 0 < sum(colour.values()) < len(colour)
        if colour is None or (all_on_cut and two_sides):
            failed.append(s)
        elif two_sides:
            moved = [t for t in around if all(colour.get(int(v), 1) for v in tets[t])]
            stars[s] = _Star(colour, moved)
    return stars, failed


def _two_colours(links: list[tuple[int, int, bool]], above) -> dict[int, int] | None:
    """Colour the vertices of ``links`` (i, j, differ) 0 and 1, the two ends of a
    link alike or differing as it says; of each set of vertices so linked, the side
    whose vertices are further above the plane (``above(vertices)``) 0. None where
    the links contradict each other or a set lies on the plane."""
    neighbours: dict[int, list[tuple[int, bool]]] = {}
    for i, j, differ in links:
        neighbours.setdefault(i, []).append((j, differ))
        neighbours.setdefault(j, []).append((i, differ))
    colour: dict[int, int] = {}
    for first in neighbours:
        if first in colour:
            continue
        colour[first] = 0
        linked, queue = [first], [first]
        while queue:
            v = queue.pop()
            for w, differ in neighbours[v]:
                want = colour[v] ^ differ
                if w not in colour:
                    colour[w] = want
                    linked.append(w)
                    queue.append(w)
                elif colour[w] != want:
                    return None
        sign = np.array([1.0 - 2.0 * colour[v] for v in linked])
        vote = float(above(linked) @ sign)
        if vote == 0.0:
            return None
        if vote < 0.0:
            colour.update({v: 1 - colour[v] for v in linked})
    return colour


def _pyramid(apex: int, base: list[int]) -> list[list[int]]:
    """Two tets filling the pyramid over the quadrilateral ``base`` (in order around
    it), split along the diagonal through its least vertex index, as :func:`_prism`
    splits its faces."""
    k = int(np.argmin(base))
    q = base[k:] + base[:k]
    return [[apex, q[0], q[1], q[2]], [apex, q[0], q[2], q[3]]]


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
