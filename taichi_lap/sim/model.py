"""The static model on the device: rest shape, masses, materials, clusters,
constraints, surfaces and environment colliders (the Warp/Newton ``Model``).

Built once from :class:`taichi_lap.build.model_data.ModelData`; kernels receive it
as a ``ti.template()`` argument and only read it.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.build.model_data import ModelData
from taichi_lap.sim.csr import both_ends, incidence
from taichi_lap.sim.fields import FieldGroup


CHUNK = 128
"""Cluster members summed by one thread in the cluster-matching reduction."""


def iteration_stiffness(stiffness: np.ndarray, iterations: int) -> np.ndarray:
    """Per-iteration stiffness k' = 1 - (1 - k)^(1/n) so that n iterations give the
    effect of stiffness k whatever n is (Müller et al. 2007, §3.3)."""
    k = np.clip(np.asarray(stiffness, dtype=np.float64), 0.0, 1.0)
    return 1.0 - (1.0 - k) ** (1.0 / max(iterations, 1))


def greedy_colors(pairs: np.ndarray, count: int) -> np.ndarray:
    """Colour the constraints ``pairs`` (D, 2) so that no two of one colour share a
    particle (greedy, in order); for graph-coloured Gauss-Seidel."""
    used = [0] * count
    colors = np.empty(len(pairs), dtype=np.int64)
    for e, (i, j) in enumerate(pairs.tolist()):
        taken = used[i] | used[j]
        c = (~taken & (taken + 1)).bit_length() - 1
        colors[e] = c
        used[i] |= 1 << c
        used[j] |= 1 << c
    return colors


@ti.data_oriented
class Model:
    """Device copy of a :class:`ModelData` plus the environment planes.

    ``planes`` is a list of ``(point, normal, friction)``; ``iterations`` is the
    number of constraint iterations per substep (sets the per-iteration stiffness).
    """

    def __init__(self, data: ModelData, *, planes=(), iterations: int = 10,
                 constraint_solver: str = "jacobi"):
        self.data = data
        self._group = FieldGroup()
        n, c = data.particle_count, data.cluster_count
        k = len(data.cluster_member)
        self.particle_count = n
        self.cluster_total = c
        self.constraint_solver = constraint_solver
        self.iterations = iterations

        self.rest_position = self._group.field(ti.f32, n, vector=3)
        self.mass = self._group.field(ti.f32, n)
        self.inv_mass = self._group.field(ti.f32, n)
        self.radius = self._group.field(ti.f32, n)
        self._group.fill(self.rest_position, data.rest_position.astype(np.float32))
        self._group.fill(self.mass, data.mass.astype(np.float32))
        inv = np.where(data.pinned, 0.0, 1.0 / np.maximum(data.mass, 1e-12))
        self._group.fill(self.inv_mass, inv.astype(np.float32))
        self._group.fill(self.radius, data.radius.astype(np.float32))
        self.material = {}
        for name, values in data.material.items():
            f = self._group.field(ti.f32, n)
            self._group.fill(f, values.astype(np.float32))
            self.material[name] = f
            setattr(self, name, f)

        self._init_clusters(data, n, c, k)
        self._init_distance(data, n, iterations)
        self._init_lra(data, n)
        self._init_springs(data, n)
        self._init_surface(data)
        self._init_planes(planes)
        self._group.finalize()

    def _init_clusters(self, data: ModelData, n: int, c: int, k: int):
        """Cluster tables of seed 000 Alg. 1: members, rest offsets q = x0 - x0_cm,
        masses, and for every particle its clusters and rest offsets in them (the
        memberships it gathers goals from)."""
        start, member = data.cluster_start, data.cluster_member
        owner = np.repeat(np.arange(c), np.diff(start))
        m = data.mass[member]
        cmass = np.bincount(owner, weights=m, minlength=c) if c else np.zeros(0)
        rest = data.rest_position
        center = np.stack([np.bincount(owner, weights=m * rest[member, a], minlength=c)
                           for a in range(3)], axis=1) / np.maximum(cmass, 1e-12)[:, None] if c \
            else np.zeros((0, 3))
        offset = rest[member] - center[owner] if c else np.zeros((0, 3))
        mstart, mrows = incidence(member, n)

        self.cluster_start = self._group.field(ti.i32, c + 1)
        self.cluster_member = self._group.field(ti.i32, k)
        self.cluster_rest_offset = self._group.field(ti.f32, k, vector=3)
        self.cluster_rest_center = self._group.field(ti.f32, c, vector=3)
        self.cluster_mass = self._group.field(ti.f32, c)
        self.membership_start = self._group.field(ti.i32, n + 1)
        self.membership_cluster = self._group.field(ti.i32, k)
        self.membership_offset = self._group.field(ti.f32, k, vector=3)
        self._group.fill(self.cluster_start, start.astype(np.int32))
        self._group.fill(self.cluster_member, member.astype(np.int32))
        self._group.fill(self.cluster_rest_offset, offset.astype(np.float32))
        self._group.fill(self.cluster_rest_center, center.astype(np.float32))
        self._group.fill(self.cluster_mass, cmass.astype(np.float32))
        self._group.fill(self.membership_start, mstart.astype(np.int32))
        # particle-major copies: a particle's goal gather reads contiguous memory
        self._group.fill(self.membership_cluster, owner[mrows].astype(np.int32))
        self._group.fill(self.membership_offset, offset[mrows].astype(np.float32))
        self._init_chunks(start)

    def _init_chunks(self, start: np.ndarray):
        """Split each cluster's members into chunks of at most :data:`CHUNK`, summed in
        parallel then per cluster in order: balanced work for clusters of any size (a
        whole-organ cluster has ~10^5 members), still deterministic."""
        sizes = np.diff(start)
        per_cluster = np.maximum(-(-sizes // CHUNK), 1)
        chunk_start = np.concatenate([[0], np.cumsum(per_cluster)])
        owner = np.repeat(np.arange(len(sizes)), per_cluster)
        rank = np.arange(chunk_start[-1]) - chunk_start[owner]
        begin = start[owner] + rank * CHUNK
        end = np.minimum(begin + CHUNK, start[owner + 1])
        self.chunk_total = int(chunk_start[-1])
        self.cluster_chunk_start = self._group.field(ti.i32, len(chunk_start))
        self.chunk_cluster = self._group.field(ti.i32, self.chunk_total)
        self.chunk_begin = self._group.field(ti.i32, self.chunk_total)
        self.chunk_end = self._group.field(ti.i32, self.chunk_total)
        self._group.fill(self.cluster_chunk_start, chunk_start.astype(np.int32))
        self._group.fill(self.chunk_cluster, owner.astype(np.int32))
        self._group.fill(self.chunk_begin, begin.astype(np.int32))
        self._group.fill(self.chunk_end, end.astype(np.int32))

    def _init_distance(self, data: ModelData, n: int, iterations: int):
        """Distance constraints (struts, sheet edges): per-particle lists for the
        Jacobi gather, and the same constraints sorted by colour for Gauss-Seidel."""
        pairs = data.distance_pair.reshape(-1, 2)
        stiff = iteration_stiffness(data.distance_stiffness, iterations)
        start, edge, other = both_ends(pairs, n)
        self.distance_count = len(pairs)
        self.distance_start = self._group.field(ti.i32, n + 1)
        self.distance_other = self._group.field(ti.i32, len(edge))
        self.distance_rest = self._group.field(ti.f32, len(edge))
        self.distance_stiffness = self._group.field(ti.f32, len(edge))
        self._group.fill(self.distance_start, start.astype(np.int32))
        self._group.fill(self.distance_other, other.astype(np.int32))
        self._group.fill(self.distance_rest, data.distance_rest[edge].astype(np.float32))
        self._group.fill(self.distance_stiffness, stiff[edge].astype(np.float32))

        self.color_ranges: list[tuple[int, int]] = []
        colors = greedy_colors(pairs, n) if self.constraint_solver == "gauss_seidel" \
            else np.zeros(len(pairs), dtype=np.int64)
        order = np.argsort(colors, kind="stable")
        bounds = np.searchsorted(colors[order], np.arange(colors.max() + 2)) if len(pairs) else [0]
        self.color_ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        self.colored_pair = self._group.field(ti.i32, len(pairs), vector=2)
        self.colored_rest = self._group.field(ti.f32, len(pairs))
        self.colored_stiffness = self._group.field(ti.f32, len(pairs))
        self._group.fill(self.colored_pair, pairs[order].astype(np.int32))
        self._group.fill(self.colored_rest, data.distance_rest[order].astype(np.float32))
        self._group.fill(self.colored_stiffness, stiff[order].astype(np.float32))

    def _init_lra(self, data: ModelData, n: int):
        """Long-range attachments per constrained particle (seed 000 §3.2)."""
        start, rows = incidence(data.lra_particle, n)
        self.lra_count = len(rows)
        self.lra_start = self._group.field(ti.i32, n + 1)
        self.lra_anchor = self._group.field(ti.i32, len(rows))
        self.lra_rest = self._group.field(ti.f32, len(rows))
        self._group.fill(self.lra_start, start.astype(np.int32))
        self._group.fill(self.lra_anchor, data.lra_anchor[rows].astype(np.int32))
        self._group.fill(self.lra_rest, data.lra_rest[rows].astype(np.float32))

    def _init_springs(self, data: ModelData, n: int):
        """Damped springs gathered per particle (seed 001 §3.2)."""
        start, edge, other = both_ends(data.spring_pair, n)
        self.spring_count = len(data.spring_pair)
        self.spring_start = self._group.field(ti.i32, n + 1)
        self.spring_other = self._group.field(ti.i32, len(edge))
        self.spring_rest = self._group.field(ti.f32, len(edge))
        self.spring_stiffness = self._group.field(ti.f32, len(edge))
        self.spring_damping = self._group.field(ti.f32, len(edge))
        self._group.fill(self.spring_start, start.astype(np.int32))
        self._group.fill(self.spring_other, other.astype(np.int32))
        self._group.fill(self.spring_rest, data.spring_rest[edge].astype(np.float32))
        self._group.fill(self.spring_stiffness, data.spring_stiffness[edge].astype(np.float32))
        self._group.fill(self.spring_damping, data.spring_damping[edge].astype(np.float32))

    def _init_surface(self, data: ModelData):
        """Render/collision surface bound to particles (direct or barycentric)."""
        v, f = len(data.surface_index), len(data.surface_triangles)
        self.surface_vertex_count = v
        self.surface_triangle_count = f
        self.surface_index = self._group.field(ti.i32, v, vector=4)
        self.surface_weight = self._group.field(ti.f32, v, vector=4)
        self.surface_triangles = self._group.field(ti.i32, 3 * f)
        self._group.fill(self.surface_index, data.surface_index.astype(np.int32))
        self._group.fill(self.surface_weight, data.surface_weight.astype(np.float32))
        self._group.fill(self.surface_triangles, data.surface_triangles.reshape(-1).astype(np.int32))

    def _init_planes(self, planes):
        """Environment half-spaces (abdominal wall, table) the tissue rests on."""
        planes = list(planes)
        self.plane_count = len(planes)
        self.plane_point = self._group.field(ti.f32, len(planes), vector=3)
        self.plane_normal = self._group.field(ti.f32, len(planes), vector=3)
        self.plane_friction = self._group.field(ti.f32, len(planes))
        if planes:
            point = np.array([p[0] for p in planes], dtype=np.float32)
            normal = np.array([p[1] for p in planes], dtype=np.float64)
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            self._group.fill(self.plane_point, point)
            self._group.fill(self.plane_normal, normal.astype(np.float32))
            self._group.fill(self.plane_friction, np.array([p[2] for p in planes], dtype=np.float32))
