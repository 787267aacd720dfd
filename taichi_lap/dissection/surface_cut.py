"""Surface cutting by a swept implicit instrument (seed 000 §5.1-5.2, Algorithm 3,
Fig. 12-13), on the host.

The instrument's cutting part is a union of implicit shapes
(:class:`~taichi_lap.core.instruments.ToolGeometry`). :class:`Sweep` connects its
poses of two frames into the sweep volume V_sweep (seed 000 §5.1, "connecting the
implicit shapes at different times"): a round shape (capsule, sphere) sweeps the
points within its radius of the surface its axis traces, exact for a translation and
sliced finely for a turn; a box sweeps the union of its interpolated poses.

:func:`cut_surface` then runs Algorithm 3 on a triangle mesh:

* vertices inside V_sweep are removed, and so every face inside it (lines 3-5);
* each edge with one end inside gets its intersection with the boundary of V_sweep;
  an edge the sweep passes through, both ends outside, gets its several boundary
  intersections combined into their median point (Fig. 13 b), which the cut splits
  into one copy per side when it runs on through the faces on both sides of the edge
  (else the cut ends at that point and it stays one vertex);
* a face where the cut ends inside it gets the deepest point of the instrument's
  current shape in it (the intersection on the sweep surface, Fig. 13 a, purple): the
  next frame's sweep starts around that vertex and goes on from it, so a cut grows
  continuously over frames at any mesh resolution;
* each intersected face is subdivided at these points (Fig. 13 c; lines 6-8), and a
  sub-face is deleted when its centroid is inside V_sweep or its area is below
  ``v_threshold`` of its parent's (lines 9-15; seed 000 §7: v_threshold = 0.15). The
  fan around a tip is kept whatever its size: its thin triangles are where the cut
  goes on next frame, and deleting them frame after frame opened holes wider than the
  blade (our choice; the paper does not say how a cut that ends in a face is held).

The result (:class:`SurfaceCut`) names the faces it replaces, the new faces, and each
new vertex as a weighted sum of its parent face's corners, so positions, rest
positions and velocities all follow by the same weights. Cuts may cross earlier cuts:
an earlier cut's vertices are vertices like any other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from taichi_lap.core.instruments import ToolGeometry, tool_distance
from taichi_lap.core.mesh import (
    degenerate_triangles,
    in_box,
    inconsistent_edges,
    rows_in,
    unique_edges,
)

V_THRESHOLD = 0.15
"""A sub-face smaller than this fraction of its parent's area is deleted (seed 000 §5.2
Alg. 3 line 14; the value of §7)."""
MAX_POSES = 256
"""At most this many poses make a sweep; a faster motion is connected more coarsely."""
BOUNDARY_TOLERANCE = 0.01
"""A point is inside V_sweep only deeper than this fraction of the thinnest shape, so
the vertices a cut leaves on the sweep's boundary are not cut again while the
instrument rests."""

_CHUNK = 2048
"""Points whose distances to every swept shape are taken in one array."""

_NONE, _INSIDE, _CROSSED, _MEDIAN = range(4)
"""How an edge meets the sweep: not at all, both ends inside, once (one end inside),
passed through (both ends outside, several intersections: their median)."""


@dataclass(frozen=True)
class Sweep:
    """V_sweep of seed 000 §5.1: ``geometry``'s shapes moved from the pose (``tips[0]``,
    ``rotations[0]``) to (``tips[1]``, ``rotations[1]``) [m; tool frames as columns]."""

    geometry: ToolGeometry
    tips: np.ndarray
    rotations: np.ndarray

    @classmethod
    def between(cls, geometry: ToolGeometry, tip0, rotation0, tip1, rotation1) -> Sweep:
        tips = np.array([tip0, tip1], dtype=np.float64).reshape(2, 3)
        rotations = np.array([rotation0, rotation1], dtype=np.float64).reshape(2, 3, 3)
        if not (np.isfinite(tips).all() and np.isfinite(rotations).all()):
            raise ValueError("Sweep: the tool poses must be finite")
        return cls(geometry, tips, rotations)

    @property
    def thickness(self) -> float:
        """The radius of the thinnest shape [m] (a box's smallest half extent)."""
        sizes = [r for _, _, r in self.geometry.round_shapes()]
        sizes += [float(np.min(h)) for _, h in self.geometry.boxes()]
        return max(min(sizes), 1e-6)

    @property
    def tolerance(self) -> float:
        """Depth [m] below which a point counts as inside (:data:`BOUNDARY_TOLERANCE`)."""
        return BOUNDARY_TOLERANCE * self.thickness

    @cached_property
    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The interpolated poses (tips (P, 3), rotations (P, 3, 3)): tips linearly,
        rotations by slerp, so that no point within the tool's reach turns more than
        half :attr:`thickness` between two (at most :data:`MAX_POSES`); with a box,
        whose sweep is the union of its poses, nor moves."""
        turning = not np.array_equal(self.rotations[0], self.rotations[1])
        if turning:  # (a translation, the usual frame's motion, needs no slerp)
            turn = Rotation.from_matrix(self.rotations)
            angle = (turn[0].inv() * turn[1]).magnitude()
        travel = angle * (self.geometry.reach() + self.geometry.length) if turning else 0.0
        if self.geometry.boxes():
            travel += float(np.linalg.norm(self.tips[1] - self.tips[0]))
        count = int(np.clip(np.ceil(travel / (0.5 * self.thickness)) + 1, 2, MAX_POSES))
        s = np.linspace(0.0, 1.0, count)
        tips = self.tips[0] + np.multiply.outer(s, self.tips[1] - self.tips[0])
        if not turning:
            return tips, np.repeat(self.rotations[:1], count, axis=0)
        return tips, Slerp([0.0, 1.0], turn)(s).as_matrix()

    @cached_property
    def _sheets(self) -> tuple[_Triangles, np.ndarray]:
        """The surfaces each round shape's axis sweeps between consecutive poses, as
        triangles (two per quadrilateral A_k B_k B_k+1 A_k+1: exact for a translation,
        where it is a parallelogram), and the shape's radius (one per triangle)."""
        tips, rotations = self.poses
        shapes = self.geometry.round_shapes()
        a = np.array([s[0] for s in shapes]).reshape(-1, 3)
        b = np.array([s[1] for s in shapes]).reshape(-1, 3)
        starts = tips[:, None] + np.einsum("pij,sj->psi", rotations, a)
        ends = tips[:, None] + np.einsum("pij,sj->psi", rotations, b)
        a0, b0, a1, b1 = starts[:-1], ends[:-1], starts[1:], ends[1:]
        triangles = np.concatenate([np.stack([a0, b0, b1], 2), np.stack([a0, b1, a1], 2)])
        radii = np.array([s[2] for s in shapes], dtype=np.float64)
        return _Triangles(triangles.reshape(-1, 3, 3)), np.tile(radii, 2 * (len(tips) - 1))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance-like value of ``points`` (n, 3) to V_sweep: the least
        distance to the swept shapes (negative inside)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(points), np.inf)
        triangles, radii = self._sheets
        for first in range(0, len(points), _CHUNK):
            d = triangles.distance(points[first : first + _CHUNK]) - radii
            out[first : first + _CHUNK] = d.min(axis=1, initial=np.inf)
        if self.geometry.boxes():
            boxes = ToolGeometry(tuple(s for s in self.geometry.shapes if s.kind == "box"), 0, 0)
            for tip, rotation in zip(*self.poses):
                d, _, _ = tool_distance(boxes, points, tip, rotation, gradients=False)
                np.minimum(out, d, out=out)
        return out

    def end_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of ``points`` to the shapes at the end pose (the current one)."""
        d, _, _ = tool_distance(
            self.geometry, points, self.tips[1], self.rotations[1], gradients=False
        )
        return d

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """An axis-aligned box [m] holding V_sweep (low, high corners)."""
        corners = []
        for tip, rotation in zip(*self.poses):
            for a, b, r in self.geometry.round_shapes():
                for end in (a, b):
                    centre = tip + rotation @ end
                    corners += [centre - r, centre + r]
            for centre, half in self.geometry.boxes():
                reach = np.abs(rotation) @ half
                corners += [tip + rotation @ centre - reach, tip + rotation @ centre + reach]
        corners = np.array(corners)
        return corners.min(axis=0), corners.max(axis=0)


@dataclass(frozen=True)
class MeshCut:
    """What a cut changes in a mesh of ``vertex_count`` vertices: the rows of its
    elements (triangles or tets) ``removed`` (R,), deleted or replaced, and the
    elements ``added`` (K, 3 or 4), numbering the input vertices as before and new
    vertex j as ``vertex_count + j``; new vertex j lies at ``vertex_weights[j] @
    x[vertex_parents[j]]`` for any per-vertex quantity x (positions, rest positions,
    velocities); ``vertex_side[j]`` is the input vertex whose side of the cut a split
    copy belongs to (-1 for vertices the cut does not split)."""

    vertex_count: int
    removed: np.ndarray
    added: np.ndarray
    vertex_parents: np.ndarray
    vertex_weights: np.ndarray
    vertex_side: np.ndarray

    @property
    def empty(self) -> bool:
        return not len(self.removed)

    def new_values(self, values: np.ndarray) -> np.ndarray:
        """A per-vertex quantity (V, ...) at the new vertices (N, ...)."""
        values = np.asarray(values)
        return np.einsum("nk,nk...->n...", self.vertex_weights, values[self.vertex_parents])

    def apply(self, points: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cut mesh: the input points followed by the new vertices, and the kept
        elements followed by the added ones."""
        keep = np.ones(len(elements), dtype=bool)
        keep[self.removed] = False
        points = np.concatenate([np.asarray(points, np.float64), self.new_values(points)])
        return points, np.concatenate([np.asarray(elements)[keep], self.added])


@dataclass(frozen=True)
class SurfaceCut(MeshCut):
    """A surface cut (:func:`cut_surface`; :class:`MeshCut`, its triangles keep their
    orientation), with ``removed_vertices`` the input vertices inside V_sweep (no face
    uses them after) and ``removed_edges`` (E, 2) the input edges, sorted i < j, that
    no face uses after the cut (the springs, distance constraints and struts across
    it)."""

    removed_vertices: np.ndarray
    removed_edges: np.ndarray


def cut_surface(
    points: np.ndarray,
    triangles: np.ndarray,
    sweep: Sweep,
    v_threshold: float = V_THRESHOLD,
) -> SurfaceCut:
    """Seed 000 Algorithm 3: cut the triangle mesh (``points`` (V, 3) [m], ``triangles``
    (F, 3)) with ``sweep`` (module docstring)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if not 0.0 <= v_threshold < 1.0:
        raise ValueError(f"cut_surface: v_threshold in [0, 1) was expected, found {v_threshold}")
    lo, hi = sweep.bounds
    near = np.flatnonzero(in_box(points, triangles, lo, hi))
    if not len(near):
        return _no_cut(len(points))
    tri = triangles[near]
    tolerance = sweep.tolerance

    used = np.unique(tri)
    distance = np.full(len(points), np.inf)
    distance[used] = sweep.distance(points[used])
    inside = distance + tolerance < 0.0  # as _classify_edges judges the edges' ends
    edges, edge_of = unique_edges(tri, return_inverse=True)
    face_edges = edge_of.reshape(-1, 3)
    kind, t_edge = _classify_edges(points, edges, distance, sweep)

    face_inside = inside[tri]
    corners_in = face_inside.sum(axis=1)
    hole = (corners_in > 0).astype(int)  # the corners inside make one notch in the face
    contacts = hole + np.sum(kind[face_edges] == _MEDIAN, axis=1)
    tip_bary = _tips(points, tri, sweep, (contacts <= 1) & (corners_in <= 1))
    has_tip = np.isfinite(tip_bary[:, 0])
    split = _split_medians(kind, face_edges, hole, has_tip)

    touched = face_inside.any(axis=1) | (kind[face_edges] != _NONE).any(axis=1) | has_tip
    builder = _Builder(points, edges, t_edge, sweep, v_threshold)
    for f in np.flatnonzero(touched & ~face_inside.all(axis=1)):
        builder.subdivide(f, tri[f], face_edges[f], kind, split, inside, tip_bary[f])
    added, parents, weights, side = builder.finish()

    removed = near[touched]
    ring = np.flatnonzero(np.isin(triangles, tri[touched]).any(axis=1))
    beside = triangles[np.setdiff1d(ring, removed)]
    after = np.concatenate([_edges_of(beside, len(points)), _edges_of(added, len(points))])
    cut_edges = unique_edges(tri[touched]) if len(removed) else np.empty((0, 2), np.int64)
    cut_edges = cut_edges[~rows_in(cut_edges, after)]
    return SurfaceCut(
        len(points),
        removed,
        added,
        parents,
        weights,
        side,
        np.flatnonzero(inside),
        cut_edges,
    )


class _Triangles:
    """Triangles (Q, 3, 3) [m], which may be degenerate (a sphere's sweep is a
    segment), with what :meth:`distance` needs of them computed once: a sweep's
    distances are taken many times a cut, on a few points each."""

    def __init__(self, triangles: np.ndarray):
        self.corners = triangles
        normal = _cross_rows(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        norm = np.linalg.norm(normal, axis=1)
        self.edges = np.roll(triangles, -1, axis=1) - triangles  # edge k: corner k to k + 1
        self.inverse_square = 1.0 / np.maximum(
            np.einsum("qkj,qkj->qk", self.edges, self.edges), 1e-30
        )
        # (ab x ax) . n = ax . (n x ab): the inward normal of each edge
        self.inward = _cross_rows(normal[:, None, :], self.edges)
        self.flat = norm > 1e-12 * np.max(np.abs(triangles), initial=1.0) ** 2
        self.unit = normal / np.maximum(norm, 1e-30)[:, None]

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n, Q) distances [m] of ``points`` (n, 3) from the triangles: the least of
        the distances to the three edges and, where the point projects inside, to the
        plane."""
        ax = points[:, None, None, :] - self.corners  # (n, Q, 3 edges, 3)
        t = np.clip(np.einsum("nqkj,qkj->nqk", ax, self.edges) * self.inverse_square, 0.0, 1.0)
        gap = ax - t[..., None] * self.edges
        out = np.sqrt(np.einsum("nqkj,nqkj->nqk", gap, gap).min(axis=2))
        within = (np.einsum("nqkj,qkj->nqk", ax, self.inward) >= 0.0).all(axis=2) & self.flat
        plane = np.abs(np.einsum("nqj,qj->nq", ax[:, :, 0], self.unit))
        return np.where(within, np.minimum(out, plane), out)


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (3) by plain arithmetic (np.cross costs about ten
    times as much on the few rows of a cut)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def sheet_problems(points: np.ndarray, triangles: np.ndarray) -> list[str]:
    """What makes a cut surface invalid (empty when it is valid): an edge in more
    than two triangles, neighbouring triangles that run their edge alike (turn
    unlike), degenerate triangles, positions that are not finite. Boundaries are
    allowed: a cut sheet has them."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if not len(triangles):
        return []
    problems = []
    _, uses = unique_edges(triangles, return_counts=True)
    if np.any(uses > 2):
        problems.append(f"{int(np.sum(uses > 2))} edges in more than two triangles")
    flipped = inconsistent_edges(triangles)
    if flipped:
        problems.append(f"{flipped} edges whose triangles turn unlike")
    degenerate = int(degenerate_triangles(points, triangles).sum())
    if degenerate:
        problems.append(f"{degenerate} degenerate triangles")
    if not np.isfinite(points[triangles]).all():
        problems.append("positions that are not finite")
    return problems


def _no_cut(vertex_count: int) -> SurfaceCut:
    empty = np.empty(0, np.int64)
    return SurfaceCut(
        vertex_count,
        empty,
        np.empty((0, 3), np.int64),
        np.empty((0, 3), np.int64),
        np.empty((0, 3)),
        empty,
        empty,
        np.empty((0, 2), np.int64),
    )


def _classify_edges(points, edges, distance, sweep) -> tuple[np.ndarray, np.ndarray]:
    """Each edge's :data:`_NONE` .. :data:`_MEDIAN` and the parameter t along (i, j) of
    its point: the boundary intersection nearest the outside end, or the median of
    the boundary intersections of an edge the sweep passes through (Fig. 13 b).
    ``distance`` holds the vertices' distances to the sweep; the edges are sampled
    between their ends at half the thinnest shape."""
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    per_edge = np.clip(np.ceil(length / (0.5 * sweep.thickness)).astype(int) + 1, 2, 512)
    owner = np.repeat(np.arange(len(edges)), per_edge)
    first = np.concatenate([[0], np.cumsum(per_edge)[:-1]])
    last = first + per_edge - 1
    s = (np.arange(len(owner)) - first[owner]) / (per_edge[owner] - 1)
    level = np.empty(len(owner))  # distance - (-tolerance): negative inside
    level[first], level[last] = distance[edges[:, 0]], distance[edges[:, 1]]
    between = np.ones(len(owner), dtype=bool)
    between[first] = between[last] = False
    level[between] = sweep.distance(a[owner[between]] + s[between, None] * (b - a)[owner[between]])
    level += sweep.tolerance
    inside_sample = level < 0.0
    change = np.flatnonzero((inside_sample[:-1] != inside_sample[1:]) & (owner[:-1] == owner[1:]))
    t = _crossing_parameters(
        a[owner[change]],
        b[owner[change]],
        s[change],
        s[change + 1],
        level[change],
        level[change + 1],
        sweep,
    )
    crossings = np.split(t, np.searchsorted(owner[change], np.arange(1, len(edges))))

    ends_in = inside_sample[np.stack([first, last], axis=1)]
    kind = np.full(len(edges), _NONE)
    t_edge = np.zeros(len(edges))
    kind[ends_in.all(axis=1)] = _INSIDE
    for e in np.flatnonzero(ends_in[:, 0] != ends_in[:, 1]):
        kind[e] = _CROSSED
        ts = crossings[e]
        t_edge[e] = ts.max() if ends_in[e, 0] else ts.min()
    for e in np.flatnonzero(~ends_in.any(axis=1)):
        if len(crossings[e]) >= 2:
            kind[e] = _MEDIAN
            t_edge[e] = float(np.median(crossings[e]))
    return kind, t_edge


def _crossing_parameters(
    a, b, s_lo, s_hi, f_lo, f_hi, sweep, rounds: int = 2, parts: int = 8
) -> np.ndarray:
    """The parameters in [s_lo, s_hi] where the segments a-b cross the sweep's
    boundary, given f, the distance less the inside level (-tolerance), at both ends
    (of unlike signs): ``rounds`` times the interval is cut into ``parts`` and the
    first part whose ends' signs differ is kept (all segments' samples in one
    distance query: as fine as six bisections with two queries), then the root of f
    is interpolated linearly over the last interval (exact where the sweep's boundary
    is flat)."""
    lo, hi = s_lo.copy(), s_hi.copy()
    steps = np.arange(1, parts) / parts
    rows = np.arange(len(lo))
    for _ in range(rounds):
        s = lo[:, None] + steps * (hi - lo)[:, None]  # (C, parts - 1)
        points = a[:, None] + s[..., None] * (b - a)[:, None]
        f = sweep.distance(points.reshape(-1, 3)).reshape(s.shape) + sweep.tolerance
        f = np.concatenate([f, f_hi[:, None]], axis=1)  # the ends of parts 0 .. parts - 1
        first = np.argmax((f < 0.0) != (f_lo < 0.0)[:, None], axis=1)
        ends = np.concatenate([s, hi[:, None]], axis=1)
        starts = np.concatenate([lo[:, None], s], axis=1)
        f_starts = np.concatenate([f_lo[:, None], f[:, :-1]], axis=1)
        lo, hi = starts[rows, first], ends[rows, first]
        f_lo, f_hi = f_starts[rows, first], f[rows, first]
    span = f_lo - f_hi
    safe = np.abs(span) > 1e-30
    share = np.clip(np.where(safe, f_lo / np.where(safe, span, 1.0), 0.5), 0.0, 1.0)
    return lo + share * (hi - lo)


def _tips(points, tri, sweep, candidate) -> np.ndarray:
    """(F, 3) barycentric coordinates of the deepest point of the instrument's current
    shape inside each ``candidate`` face (NaN where none is, or it lies within a grid
    step of the face's edges): where the cut ends inside a face (Fig. 13 a)."""
    out = np.full((len(tri), 3), np.nan)
    faces = np.flatnonzero(candidate)
    if not len(faces):
        return out
    x = points[tri[faces]]
    longest = np.max(np.linalg.norm(x - np.roll(x, 1, axis=1), axis=2), axis=1)
    steps = np.clip(np.ceil(longest / sweep.thickness).astype(int), 3, 32)
    for n in np.unique(steps):
        grid = np.array(
            [(i, j, n - i - j) for i in range(1, n) for j in range(1, n - i)], dtype=np.float64
        )
        grid /= n
        group = faces[steps == n]
        samples = np.einsum("gk,fkd->fgd", grid, points[tri[group]])
        d = sweep.end_distance(samples.reshape(-1, 3)).reshape(len(group), len(grid))
        deepest = np.argmin(d, axis=1)
        hit = d[np.arange(len(group)), deepest] < -sweep.tolerance
        out[group[hit]] = grid[deepest[hit]]
    return out


def _split_medians(kind, face_edges, hole, has_tip) -> np.ndarray:
    """Which median points the cut splits: those where it runs on through every face
    beside the edge, to another place where the sweep meets the face's boundary (a
    notch of corners inside, another split point) or to the face's tip; elsewhere the
    cut ends at the point. Repeated until no face holds a split point it does not run
    on from."""
    split = kind == _MEDIAN
    while True:
        through = (hole + np.sum(split[face_edges], axis=1) >= 2) | has_tip
        stale = split[face_edges] & ~through[:, None]
        if not stale.any():
            return split
        split[face_edges[stale]] = False


class _Builder:
    """Subdivides intersected faces (Fig. 13 c) and keeps the sub-faces Alg. 3 lines
    9-15 keep; new vertices are keyed so that faces sharing an edge share its points."""

    def __init__(self, points, edges, t_edge, sweep, v_threshold):
        self.points, self.edges, self.t_edge = points, edges, t_edge
        self.sweep, self.v_threshold = sweep, v_threshold
        self.keys: dict[tuple, int] = {}
        self.parents: list[tuple[int, int, int]] = []
        self.weights: list[tuple[float, float, float]] = []
        self.side: list[int] = []
        self.candidates: list[tuple[tuple, tuple, tuple, float | None]] = []  # 3 items, parent area

    def _item(self, key: tuple, parents: tuple, weights: tuple) -> tuple:
        """A point of a face's boundary cycle: its key, parents, weights and position."""
        return key, parents, weights, np.asarray(weights) @ self.points[list(parents)]

    def _edge_point(self, e: int, side: int) -> tuple:
        i, j = self.edges[e]
        t = self.t_edge[e]
        return self._item(("e", int(e), int(side)), (int(i), int(j), int(i)), (1.0 - t, t, 0.0))

    def subdivide(self, f, corners, face_edges, kind, split, inside, tip_bary):
        """Queue the sub-faces of face ``f`` (its corners, its edges' indices)."""
        cycle = []  # items (_item), None where the cut separates neighbours, "in"
        for k in range(3):
            v, w = int(corners[k]), int(corners[(k + 1) % 3])
            cycle.append(
                self._item(("v", v), (v, v, v), (1.0, 0.0, 0.0)) if not inside[v] else "in"
            )
            e = int(face_edges[k])
            if kind[e] == _CROSSED:
                cycle.append(self._edge_point(e, w if inside[v] else v))
            elif kind[e] == _MEDIAN and split[e]:
                cycle += [self._edge_point(e, v), None, self._edge_point(e, w)]
            elif kind[e] == _MEDIAN:
                cycle.append(self._edge_point(e, -1))
        area = _area(self.points[corners])
        if np.isfinite(tip_bary[0]):
            tip = self._item(("t", int(f)), tuple(int(c) for c in corners), tuple(tip_bary))
            for p, q in zip(cycle, cycle[1:] + cycle[:1]):
                if p not in (None, "in") and q not in (None, "in"):
                    self.candidates.append((p, q, tip, None))
            return
        for run in _runs(cycle):
            for i, j, k in _triangulate([p[3] for p in run]):
                self.candidates.append((run[i], run[j], run[k], area))

    def finish(self):
        """The kept sub-faces numbered after the input vertices, and the new vertices."""
        if not self.candidates:
            return (
                np.empty((0, 3), np.int64),
                np.empty((0, 3), np.int64),
                np.empty((0, 3)),
                np.empty(0, np.int64),
            )
        x = np.array([[p[3] for p in c[:3]] for c in self.candidates])
        area = 0.5 * np.linalg.norm(_cross_rows(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
        large = [
            c[3] is None or a >= self.v_threshold * c[3] for c, a in zip(self.candidates, area)
        ]
        outside = self.sweep.distance(x.mean(axis=1)) >= -self.sweep.tolerance
        faces = []
        for candidate, keep in zip(self.candidates, outside & np.array(large)):
            if keep:
                faces.append([self._vertex(item) for item in candidate[:3]])
        return (
            np.array(faces, dtype=np.int64).reshape(-1, 3),
            np.array(self.parents, dtype=np.int64).reshape(-1, 3),
            np.array(self.weights, dtype=np.float64).reshape(-1, 3),
            np.array(self.side, dtype=np.int64),
        )

    def _vertex(self, item) -> int:
        key, parents, weights, _ = item
        if key[0] == "v":
            return key[1]
        if key not in self.keys:
            self.keys[key] = len(self.points) + len(self.parents)
            self.parents.append(parents)
            self.weights.append(weights)
            self.side.append(key[2] if key[0] == "e" else -1)
        return self.keys[key]


def _runs(cycle: list) -> list[list]:
    """The pieces of a face's boundary cycle the cut leaves: split where the cut
    separates two points (None) and where a corner is inside the sweep ("in")."""
    cuts = [i for i, item in enumerate(cycle) if item is None or item == "in"]
    if not cuts:
        return [cycle]
    start = cuts[0]
    rotated = cycle[start + 1 :] + cycle[: start + 1]
    runs, run = [], []
    for item in rotated:
        if item is None or item == "in":
            runs.append(run)
            run = []
        else:
            run.append(item)
    return [r for r in runs if len(r) >= 3]


def _triangulate(polygon) -> list[tuple[int, int, int]]:
    """Ear clipping of a convex polygon (n points) whose points may be collinear (points
    on one edge of the parent face): each ear has an area and leaves a polygon that
    still has one; the ear with the largest smallest angle first. (A few points: plain
    Python arithmetic, faster than NumPy's at this size.)"""
    x = [tuple(map(float, p)) for p in polygon]
    order = list(range(len(x)))
    eps = 1e-9 * max(_polygon_area([x[i] for i in order]), 1e-30)
    out = []
    while len(order) > 3:
        best = None
        for pos in range(len(order)):
            i, j, k = order[pos - 1], order[pos], order[(pos + 1) % len(order)]
            if _area((x[i], x[j], x[k])) <= eps:
                continue
            rest = order[:pos] + order[pos + 1 :]
            if _polygon_area([x[r] for r in rest]) <= eps:
                continue
            quality = _smallest_angle((x[i], x[j], x[k]))
            if best is None or quality > best[0]:
                best = (quality, pos, (i, j, k))
        if best is None:
            return out
        out.append(best[2])
        order.pop(best[1])
    if _area(tuple(x[i] for i in order)) > eps:
        out.append(tuple(order))
    return out


def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _norm(u) -> float:
    return math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])


def _area(x) -> float:
    """Area of the triangle of three points."""
    return 0.5 * _norm(_cross(_sub(x[1], x[0]), _sub(x[2], x[0])))


def _polygon_area(x) -> float:
    """Area of a planar polygon of points."""
    total = (0.0, 0.0, 0.0)
    for k in range(1, len(x) - 1):
        c = _cross(_sub(x[k], x[0]), _sub(x[k + 1], x[0]))
        total = (total[0] + c[0], total[1] + c[1], total[2] + c[2])
    return 0.5 * _norm(total)


def _smallest_angle(x) -> float:
    """The smallest angle of the triangle of three points."""
    angles = []
    for k in range(3):
        u, v = _sub(x[(k + 1) % 3], x[k]), _sub(x[(k + 2) % 3], x[k])
        cos = (u[0] * v[0] + u[1] * v[1] + u[2] * v[2]) / max(_norm(u) * _norm(v), 1e-30)
        angles.append(math.acos(min(1.0, max(-1.0, cos))))
    return min(angles)


def _edges_of(triangles: np.ndarray, vertex_count: int) -> np.ndarray:
    """The edges of ``triangles`` between input vertices (< ``vertex_count``)."""
    if not len(triangles):
        return np.empty((0, 2), np.int64)
    edges = unique_edges(triangles)
    return edges[(edges < vertex_count).all(axis=1)]
