"""Lattice tetrahedralization of organ solids, no external mesher (seed 002 §3.2).

Seed 002 fills the liver with nearly regular tetrahedra whose vertices are the
physical particles; each capsule vertex is tied to one particle and each vessel
vertex is bound to a tetrahedron by barycentric coordinates. Here the tetrahedra
come from a body-centred cubic (BCC) lattice: cube corners and cube centres, 12
congruent tetrahedra per cube (dihedral angles 60 and 90 degrees), about 6 per
particle. Lengths are metres, volumes cubic metres.

Lattice points are addressed by *doubled* integer coordinates ``D`` (position
``origin + D * spacing / 2``): cube corners are even in every axis, centres odd.
A candidate tetrahedron is one of 12 templates placed at a cube cell.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from taichi_lap.core.geometry import SignedDistance, Solid, TriangleMesh
from taichi_lap.core.mesh import boundary_faces, tet_volumes, unique_edges

# Deterministic ray shift (times the mesh diagonal) so rays miss vertices and edges.
_RAY_SHIFT = np.array([0.7548776662466927e-9, 0.5698402909980532e-9])
_SDF_CHUNK = 1 << 20  # points per sdf call
_PAIR_CHUNK = 1 << 20  # (triangle, ray) pairs tested at once
_REPAIR_ROUNDS = 8  # non-manifold edge repairs before giving up
_NEWTON_STEPS = 4  # boundary snapping iterations
_HALVINGS = 8  # step halvings before a moving particle is held
_MIN_VOLUME_FRACTION = 0.1  # of the rest lattice volume, while moving the skin
_BIND_CANDIDATES = 16  # nearest tets tried per bound surface vertex


@dataclass
class TetMesh:
    """Tetrahedral model of one organ (seed 002 §3.2).

    ``particles`` ``(N, 3)`` [m] are the tet vertices (physical particles), in a
    spatial (Morton) order; ``tets`` ``(T, 4)`` int64, positively oriented;
    ``surface`` the render/collision skin with outward normals; surface vertex
    ``s`` is ``sum_k binding_weight[s, k] * particles[binding_index[s, k]]`` at
    rest (direct binding: ``[i, i, i, i]`` with ``[1, 0, 0, 0]``).
    """

    particles: np.ndarray
    tets: np.ndarray
    surface: TriangleMesh
    binding_index: np.ndarray
    binding_weight: np.ndarray


def _bcc_templates() -> np.ndarray:
    """The 12 BCC tets of a cell, ``(12, 4, 3)`` doubled offsets from ``2 * cell``.

    Template ``t`` joins the cell centre to the next centre along axis ``t // 4``
    and the two ends of one edge of their shared square face.
    """
    eye = np.eye(3, dtype=np.int64)
    centre = np.ones(3, dtype=np.int64)
    templates = []
    for a in range(3):
        b, c = eye[(a + 1) % 3], eye[(a + 2) % 3]
        face = centre + eye[a]
        for s in (-1, 1):
            for edge in (
                (face - b + s * c, face + b + s * c),
                (face + s * b - c, face + s * b + c),
            ):
                templates.append([centre, centre + 2 * eye[a], *edge])
    templates = np.array(templates)
    negative = np.linalg.det((templates[:, 1:] - templates[:, :1]).astype(float)) < 0
    templates[negative] = templates[negative][:, [0, 1, 3, 2]]
    return templates


_TEMPLATES = _bcc_templates()


@dataclass
class _Lattice:
    """BCC lattice of ``cells`` cubes of edge ``spacing`` [m] from ``origin``.

    Lattice vertex ids: the ``(cells + 1)`` corner grid first, then the centres.
    """

    origin: np.ndarray
    spacing: float
    cells: np.ndarray

    @classmethod
    def covering(cls, bounds, spacing: float) -> _Lattice:
        lo, hi = bounds
        cells = np.maximum(np.ceil((hi - lo) / spacing).astype(np.int64) + 2, 2)
        return cls(lo - spacing, float(spacing), cells)

    @property
    def candidates(self) -> int:
        return 12 * int(np.prod(self.cells))

    def split(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate ids -> template index ``(m,)`` and cell ``(m, 3)``."""
        template, cell = np.divmod(ids, np.prod(self.cells))
        return template, np.stack(np.unravel_index(cell, self.cells), axis=1)

    def valid_ids(self) -> np.ndarray:
        """Candidates whose second cube centre lies inside the lattice."""
        template, cell = self.split(np.arange(self.candidates))
        axis = template // 4
        return np.flatnonzero(cell[np.arange(len(cell)), axis] < self.cells[axis] - 1)

    def centroids(self, ids: np.ndarray) -> np.ndarray:
        template, cell = self.split(ids)
        return self.position(2 * cell + _TEMPLATES.mean(axis=1)[template])

    @cached_property
    def doubled(self) -> np.ndarray:
        """Doubled coordinates ``(V, 3)`` of all lattice vertices, by vertex id."""
        corners = np.stack(
            np.unravel_index(np.arange(np.prod(self.cells + 1)), self.cells + 1), axis=1
        )
        centres = np.stack(np.unravel_index(np.arange(np.prod(self.cells)), self.cells), axis=1)
        return np.concatenate([2 * corners, 2 * centres + 1])

    def tet_vertices(self, ids: np.ndarray) -> np.ndarray:
        """Lattice vertex ids ``(m, 4)`` of candidate tets."""
        template, cell = self.split(ids)
        corner_stride = np.array([(self.cells[1] + 1) * (self.cells[2] + 1), self.cells[2] + 1, 1])
        centre_stride = np.array([self.cells[1] * self.cells[2], self.cells[2], 1])
        centre = _TEMPLATES[:, :, 0] % 2 == 1  # (12, 4)
        delta = np.where(
            centre, (_TEMPLATES // 2) @ centre_stride, (_TEMPLATES // 2) @ corner_stride
        )
        base = np.where(
            centre[template],
            (np.prod(self.cells + 1) + cell @ centre_stride)[:, None],
            (cell @ corner_stride)[:, None],
        )
        return base + delta[template]

    def position(self, doubled: np.ndarray) -> np.ndarray:
        return self.origin + doubled * (self.spacing / 2)

    def star(self, doubled: np.ndarray) -> np.ndarray:
        """Candidate ids ``(m, 48)`` of the tets around lattice points, -1 padded."""
        offsets = _TEMPLATES.reshape(48, 3)
        template = np.repeat(np.arange(12), 4)
        delta = doubled[:, None, :] - offsets[None]
        cell = delta // 2
        limit = self.cells - np.eye(3, dtype=np.int64).repeat(4, axis=0)  # (12, 3)
        ok = np.all((delta % 2 == 0) & (cell >= 0) & (cell < limit[template]), axis=2)
        flat = np.ravel_multi_index(
            tuple(np.clip(cell, 0, self.cells - 1).transpose(2, 0, 1)), self.cells
        )
        return np.where(ok, template * np.prod(self.cells) + flat, -1)


def _morton(doubled: np.ndarray) -> np.ndarray:
    """Z-order keys of non-negative integer coordinates ``(m, 3)`` (21 bits each)."""
    key = np.zeros(len(doubled), dtype=np.uint64)
    for axis in range(3):
        v = doubled[:, axis].astype(np.uint64) & np.uint64(0x1FFFFF)
        for shift, mask in (
            (32, 0x1F00000000FFFF),
            (16, 0x1F0000FF0000FF),
            (8, 0x100F00F00F00F00F),
            (4, 0x10C30C30C30C30C3),
            (2, 0x1249249249249249),
        ):
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        key |= v << np.uint64(axis)
    return key


def _compact(lattice: _Lattice, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kept candidates -> lattice vertex ids of the particles ``(N,)`` in Morton
    order of their doubled coordinates, and tets ``(T, 4)`` sorted by first particle."""
    corners = lattice.tet_vertices(np.flatnonzero(kept))
    used = np.unique(corners)
    used = used[np.argsort(_morton(lattice.doubled[used]))]
    rank = np.empty(int(used.max()) + 1, dtype=np.int64)
    rank[used] = np.arange(len(used))
    tets = rank[corners]
    return used, tets[np.argsort(tets.min(axis=1), kind="stable")]


def _repair_ids(lattice: _Lattice, doubled: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Candidate tets around the boundary edges used by more than two faces."""
    edges, count = unique_edges(faces, return_counts=True)
    edges = edges[count > 2]
    around = np.concatenate(
        [lattice.star(doubled[edges[:, 0]]), lattice.star(doubled[edges[:, 1]])], axis=1
    )
    tagged = np.where(around >= 0, np.arange(len(edges))[:, None] * lattice.candidates + around, -1)
    tagged, count = np.unique(tagged[tagged >= 0], return_counts=True)
    return tagged[count == 2] % lattice.candidates


def _compact_manifold(lattice: _Lattice, kept: np.ndarray, repair: bool):
    """Compact the kept tets; with ``repair``, first add the tets around boundary
    edges in more than two faces until each boundary edge is in two faces."""
    for round_ in range(_REPAIR_ROUNDS + 1):
        used, tets = _compact(lattice, kept)
        if not repair:
            return used, tets
        extra = _repair_ids(lattice, lattice.doubled[used], boundary_faces(tets))
        extra = extra[~kept[extra]]
        if extra.size == 0 or round_ == _REPAIR_ROUNDS:
            return used, tets
        kept[extra] = True


def _classify_by_warp(lattice: _Lattice, distance: np.ndarray, ids: np.ndarray):
    """Keep tets of a sdf solid the way isosurface stuffing warps (Labelle and
    Shewchuk 2007, warp limit 1/2, no cutting).

    ``distance`` ``(V,)`` is the sdf at the lattice vertices [m]. On each lattice
    edge whose ends differ in sign the surface cut is interpolated; an end within
    half the edge of a cut is warped to its nearest cut and counts as on the
    surface. Every sign change is then absorbed, so the tets with no outside and
    at least one inside vertex have only warped vertices on their boundary.
    Returns the kept candidate ids and each lattice vertex's warp ``(V, 3)`` [m].
    """
    corners = lattice.tet_vertices(ids)
    inside, outside = distance < 0, distance > 0
    straddling = inside[corners].any(axis=1) & outside[corners].any(axis=1)
    edges = unique_edges(corners[straddling])
    edges = edges[inside[edges].any(axis=1) & outside[edges].any(axis=1)]
    f = distance[edges]
    along = f[:, 0] / (f[:, 0] - f[:, 1])  # cut, from end 0
    vertex = edges.T.reshape(-1)
    fraction = np.concatenate([along, 1 - along])
    near = fraction <= 0.5
    vertex, fraction = vertex[near], fraction[near]
    cut = np.concatenate([edges[:, 1], edges[:, 0]])[near]
    order = np.lexsort((fraction, vertex))
    first = order[np.unique(vertex[order], return_index=True)[1]]  # nearest cut
    doubled = lattice.doubled
    warp = np.zeros((len(distance), 3))
    warp[vertex[first]] = (
        (doubled[cut[first]] - doubled[vertex[first]])
        * (lattice.spacing / 2)
        * fraction[first, None]
    )
    side = np.sign(distance)
    side[vertex[first]] = 0
    corner_side = side[corners]
    return ids[np.all(corner_side <= 0, axis=1) & np.any(corner_side < 0, axis=1)], warp


def _sdf(sdf: SignedDistance, points: np.ndarray) -> np.ndarray:
    return np.concatenate(
        [
            np.asarray(sdf(points[i : i + _SDF_CHUNK]), dtype=np.float64).reshape(-1)
            for i in range(0, len(points), _SDF_CHUNK)
        ]
        or [np.zeros(0)]
    )


def _edge_function(u: np.ndarray, v: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2-D cross (v - u) x (p - u) and its side bit, computed with the endpoints in
    lexicographic order so the two triangles sharing an edge agree bit for bit."""
    swap = (u[:, 0] > v[:, 0]) | ((u[:, 0] == v[:, 0]) & (u[:, 1] > v[:, 1]))
    s = np.where(swap[:, None], v, u)
    e = np.where(swap[:, None], u, v)
    value = (e[:, 0] - s[:, 0]) * (p[:, 1] - s[:, 1]) - (e[:, 1] - s[:, 1]) * (p[:, 0] - s[:, 0])
    return np.where(swap, -value, value), (value >= 0) ^ swap


def _ray_crossings(vertices: np.ndarray, triangles: np.ndarray, lines: np.ndarray):
    """Crossings of +x rays at ``lines`` ``(L, 2)`` (y, z) with the triangles.

    Returns line index and x [m] of each crossing. Rays are bucketed into strips
    of y and sorted by z inside a strip; each triangle's (y, z) box selects rays.
    """
    corner = vertices[triangles]  # (M, 3, 3)
    tlo, thi = corner[:, :, 1:].min(axis=1), corner[:, :, 1:].max(axis=1)
    lo, hi = lines.min(axis=0), lines.max(axis=0)
    width = max(float(np.median(thi[:, 0] - tlo[:, 0])), (hi[0] - lo[0]) / 4096, 1e-300)
    strips = int((hi[0] - lo[0]) // width) + 1
    stride = (hi[1] - lo[1]) + 2 * width
    margin = 1e-9 * stride
    strip_of = ((lines[:, 0] - lo[0]) // width).astype(np.int64)
    order = np.lexsort((lines[:, 1], strip_of))
    keys = strip_of[order] * stride + (lines[order, 1] - lo[1])
    first = np.clip(((tlo[:, 0] - lo[0]) // width).astype(np.int64), 0, strips)
    last = np.clip(((thi[:, 0] - lo[0]) // width).astype(np.int64), -1, strips - 1)
    count = np.maximum(last - first + 1, 0)
    tri = np.repeat(np.arange(len(triangles)), count)
    strip = first[tri] + np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)
    z_range = hi[1] - lo[1]
    start = np.searchsorted(
        keys, strip * stride + np.clip(tlo[tri, 1] - lo[1], 0, z_range) - margin
    )
    stop = np.searchsorted(
        keys, strip * stride + np.clip(thi[tri, 1] - lo[1], 0, z_range) + margin, side="right"
    )
    rays = stop - start
    chunk = (np.cumsum(rays) - rays) // _PAIR_CHUNK
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(chunk)) + 1, [len(rays)]])
    found_line, found_x = [], []
    for a, b in zip(cuts[:-1], cuts[1:]):
        n = rays[a:b]
        pair_tri = np.repeat(tri[a:b], n)
        pair_line = order[
            np.repeat(start[a:b], n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        ]
        p, c = lines[pair_line], corner[pair_tri]
        e_ab, bit_ab = _edge_function(c[:, 0, 1:], c[:, 1, 1:], p)
        e_bc, bit_bc = _edge_function(c[:, 1, 1:], c[:, 2, 1:], p)
        e_ca, bit_ca = _edge_function(c[:, 2, 1:], c[:, 0, 1:], p)
        total = e_ab + e_bc + e_ca
        hit = (bit_ab == bit_bc) & (bit_bc == bit_ca) & (total != 0)
        x = (e_bc * c[:, 0, 0] + e_ca * c[:, 1, 0] + e_ab * c[:, 2, 0])[hit] / total[hit]
        found_line.append(pair_line[hit])
        found_x.append(x)
    return np.concatenate(found_line), np.concatenate(found_x)


def points_inside(surface: TriangleMesh, points: np.ndarray) -> np.ndarray:
    """Inside test of points ``(K, 3)`` [m] against a closed surface, ``(K,)`` bool.

    Ray parity: a point is inside when an odd number of triangles cross the +x
    ray from it. Rays are shifted by ~1e-9 of the mesh diagonal so they graze no
    vertex or edge; shared edges are evaluated identically by both triangles.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vertices, triangles = surface.vertices, surface.triangles
    inside = np.zeros(len(points), dtype=bool)
    if len(triangles) == 0:
        return inside
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    boxed = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
    if boxed.size == 0:
        return inside
    yz = points[boxed, 1:] + np.linalg.norm(hi - lo) * _RAY_SHIFT
    lines, line_of = np.unique(yz, axis=0, return_inverse=True)
    line_of = line_of.reshape(-1)
    crossing_line, crossing_x = _ray_crossings(vertices, triangles, lines)
    # Merge points and crossings by (line, x): a point counts the crossings after it.
    line = np.concatenate([line_of, crossing_line])
    x = np.concatenate([points[boxed, 0], crossing_x])
    is_crossing = np.arange(len(line)) >= len(boxed)
    order = np.lexsort((is_crossing, x, line))
    seen = np.cumsum(is_crossing[order])
    point_at = order[~is_crossing[order]]
    up_to_line = np.searchsorted(np.sort(crossing_line), line_of[point_at], side="right")
    inside[boxed[point_at]] = (up_to_line - seen[~is_crossing[order]]) % 2 == 1
    return inside


def _newton_step(sdf: SignedDistance, x: np.ndarray, h: float) -> np.ndarray:
    """Step ``-f grad f / |grad f|^2`` onto the zero set, central differences ``h``."""
    offsets = np.concatenate([np.eye(3), -np.eye(3)]) * h
    values = _sdf(sdf, np.concatenate([x, (x[:, None, :] + offsets).reshape(-1, 3)]))
    f, probes = values[: len(x)], values[len(x) :].reshape(-1, 6)
    grad = (probes[:, :3] - probes[:, 3:]) / (2 * h)
    return -(f / np.maximum(np.einsum("ij,ij->i", grad, grad), 1e-300))[:, None] * grad


def _displace(
    particles: np.ndarray,
    near: np.ndarray,
    moving: np.ndarray,
    step: np.ndarray,
    slot: np.ndarray,
    floor: float,
) -> None:
    """Move ``moving`` particles by ``step`` ``(m, 3)`` [m] in place, halving (then
    cancelling) the step of each particle of a tet in ``near`` that would end at
    ``floor`` [m^3] or less and smaller than it was."""
    start = particles[moving]
    before = tet_volumes(particles, near)
    alpha = np.ones(len(moving))
    halvings = 0
    while True:
        particles[moving] = start + alpha[:, None] * step
        volume = tet_volumes(particles, near)
        bad = (volume <= floor) & (volume < before)
        if not bad.any():
            return
        held = slot[near[bad]]
        held = held[held >= 0]
        alpha[held] = 0.5 * alpha[held] if halvings < _HALVINGS else 0.0
        halvings += 1


def _snap(
    particles: np.ndarray,
    tets: np.ndarray,
    moving: np.ndarray,
    warp: np.ndarray,
    sdf: SignedDistance,
    spacing: float,
) -> None:
    """Warp the ``moving`` particles, then put them on the sdf zero set by Newton
    steps, in place; no tet falls to 10% of the rest volume ``spacing^3 / 12``."""
    near = tets[np.isin(tets, moving).any(axis=1)]
    slot = np.full(len(particles), -1)
    slot[moving] = np.arange(len(moving))
    floor = _MIN_VOLUME_FRACTION * spacing**3 / 12
    _displace(particles, near, moving, warp, slot, floor)
    for _ in range(_NEWTON_STEPS):
        step = _newton_step(sdf, particles[moving], 1e-4 * spacing)
        _displace(particles, near, moving, step, slot, floor)


def _bind_barycentric(particles: np.ndarray, tets: np.ndarray, points: np.ndarray):
    """Bind points to the tet containing them, else the nearby tet whose barycentric
    coordinates are least negative (extrapolated); returns index, weight ``(S, 4)``."""
    k = min(_BIND_CANDIDATES, len(tets))
    _, candidate = cKDTree(particles[tets].mean(axis=1)).query(points, k=k)
    candidate = candidate.reshape(len(points), k)
    x = particles[tets[candidate]]  # (S, k, 4, 3)
    frame = np.swapaxes(x[:, :, 1:] - x[:, :, :1], -1, -2)
    inner = np.linalg.solve(frame, (points[:, None, :] - x[:, :, 0])[..., None])[..., 0]
    weight = np.concatenate([1.0 - inner.sum(axis=2, keepdims=True), inner], axis=2)
    best = weight.min(axis=2).argmax(axis=1)
    rows = np.arange(len(points))
    return tets[candidate[rows, best]], weight[rows, best]


def tetrahedralize(
    solid: Solid, spacing: float, *, progress: Callable[[float], None] | None = None
) -> TetMesh:
    """Fill ``solid`` with BCC tets of cube edge ``spacing`` [m] (seed 002 §3.2).

    With a given ``solid.surface``, tets whose centroid is inside (``sdf < 0``,
    else ray parity against the surface) are kept and each surface vertex is bound
    barycentrically to a tet. Without one, tets are kept by warping
    (:func:`_classify_by_warp`), the boundary is made manifold, its vertices are
    snapped onto the sdf zero set and become the directly bound skin.
    ``progress(fraction)`` is called as the build advances.
    """
    report = progress or (lambda fraction: None)
    report(0.0)
    lattice = _Lattice.covering(solid.bounds, spacing)
    ids = lattice.valid_ids()
    if solid.surface is None:
        distance = _sdf(solid.sdf, lattice.position(lattice.doubled))
        ids, warp = _classify_by_warp(lattice, distance, ids)
    elif solid.sdf is not None:
        ids = ids[_sdf(solid.sdf, lattice.centroids(ids)) < 0]
    else:
        ids = ids[points_inside(solid.surface, lattice.centroids(ids))]
    if ids.size == 0:
        raise ValueError(f"no tetrahedron lies inside the solid at spacing {spacing} m")
    kept = np.zeros(lattice.candidates, dtype=bool)
    kept[ids] = True
    report(0.3)
    used, tets = _compact_manifold(lattice, kept, repair=solid.surface is None)
    particles = lattice.position(lattice.doubled[used])
    report(0.6)
    if solid.surface is None:
        faces = boundary_faces(tets)
        skin = np.unique(faces)
        _snap(particles, tets, skin, warp[used[skin]], solid.sdf, lattice.spacing)
        surface = TriangleMesh(particles[skin], np.searchsorted(skin, faces))
        index, weight = np.repeat(skin[:, None], 4, axis=1), np.zeros((len(skin), 4))
        weight[:, 0] = 1.0
    else:
        surface = solid.surface
        index, weight = _bind_barycentric(particles, tets, surface.vertices)
    report(1.0)
    return TetMesh(particles, tets, surface, index.astype(np.int64), weight)
