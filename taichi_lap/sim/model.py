"""The static model on the device: rest shape, masses, materials, clusters,
constraints, surfaces and environment colliders (the Warp/Newton ``Model``).

Built once from :class:`taichi_lap.preprocess.model_data.ModelData`; kernels receive it
as a ``ti.template()`` argument and only read it.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core.csr import both_ends, incidence
from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.preprocess.model_data import ModelData

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
class Model(FieldOwner):
    """Device copy of a :class:`ModelData` plus the environment planes.

    ``planes`` is a list of ``(point, normal, friction)``; ``iterations`` is the
    number of constraint iterations per substep (sets the per-iteration stiffness).
    Per-particle material channels are fields named as in ``PARTICLE_MATERIAL``.
    """

    def __init__(
        self, data: ModelData, *, planes=(), iterations: int = 10, constraint_solver: str = "jacobi"
    ):
        self.data = data
        self._group = FieldGroup()
        n = data.particle_count
        self.particle_count = n
        self.cluster_total = data.cluster_count
        self.constraint_solver = constraint_solver

        self.rest_position = self._floats(data.rest_position, vector=3)
        self.mass = self._floats(data.mass)
        self.inv_mass = self._floats(data.inverse_mass())
        self.radius = self._floats(data.radius)
        self.contact_radius = self._floats(data.contact_radius())
        for name, values in data.material.items():
            setattr(self, name, self._floats(values))

        self._init_clusters(data, n)
        self._init_distance(data, n, iterations)
        self._init_lra(data, n)
        self._init_springs(data, n)
        self._init_surface(data)
        self._init_tubes(data)
        self._init_planes(planes)
        self._group.finalize()

    def _ints(self, values, vector: int = 0):
        """An i32 field holding ``values`` (one entry per row)."""
        values = np.asarray(values, dtype=np.int32)
        return self._group.field(ti.i32, len(values), vector=vector, values=values)

    def _floats(self, values, vector: int = 0):
        """An f32 field holding ``values`` (one entry per row)."""
        values = np.asarray(values, dtype=np.float32)
        return self._group.field(ti.f32, len(values), vector=vector, values=values)

    def _init_clusters(self, data: ModelData, n: int):
        """Cluster tables of seed 000 Alg. 1: members, rest offsets q = x0 - x0_cm,
        masses, and for every particle its clusters and rest offsets in them (the
        memberships it gathers goals from)."""
        c = data.cluster_count
        start, member = data.cluster_start, data.cluster_member
        owner = np.repeat(np.arange(c), np.diff(start))
        m = data.mass[member]
        cmass = np.bincount(owner, weights=m, minlength=c)
        rest = data.rest_position
        center = (
            np.stack(
                [np.bincount(owner, weights=m * rest[member, a], minlength=c) for a in range(3)],
                axis=1,
            )
            / np.maximum(cmass, 1e-12)[:, None]
        )
        offset = rest[member] - center[owner]
        mstart, mrows = incidence(member, n)

        self.cluster_start = self._ints(start)
        self.cluster_member = self._ints(member)
        self.cluster_rest_offset = self._floats(offset, vector=3)
        self.cluster_rest_center = self._floats(center, vector=3)
        self.cluster_mass = self._floats(cmass)
        self.membership_start = self._ints(mstart)
        # particle-major copies: a particle's goal gather reads contiguous memory
        self.membership_cluster = self._ints(owner[mrows])
        self.membership_offset = self._floats(offset[mrows], vector=3)
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
        self.chunk_total = int(chunk_start[-1])
        self.cluster_chunk_start = self._ints(chunk_start)
        self.chunk_cluster = self._ints(owner)
        self.chunk_begin = self._ints(begin)
        self.chunk_end = self._ints(np.minimum(begin + CHUNK, start[owner + 1]))

    def _init_distance(self, data: ModelData, n: int, iterations: int):
        """Distance constraints (struts, sheet edges): per-particle lists for the
        Jacobi gather, and the same constraints sorted by colour for Gauss-Seidel."""
        pairs = data.distance_pair.reshape(-1, 2)
        stiff = iteration_stiffness(data.distance_stiffness, iterations)
        start, edge, other = both_ends(pairs, n)
        self.distance_count = len(pairs)
        self.distance_start = self._ints(start)
        self.distance_other = self._ints(other)
        self.distance_rest = self._floats(data.distance_rest[edge])
        self.distance_stiffness = self._floats(stiff[edge])

        colors = (
            greedy_colors(pairs, n)
            if self.constraint_solver == "gauss_seidel"
            else np.zeros(len(pairs), dtype=np.int64)
        )
        order = np.argsort(colors, kind="stable")
        bounds = np.searchsorted(colors[order], np.arange(colors.max() + 2)) if len(pairs) else [0]
        self.color_ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        self.colored_pair = self._ints(pairs[order], vector=2)
        self.colored_rest = self._floats(data.distance_rest[order])
        self.colored_stiffness = self._floats(stiff[order])

    def _init_lra(self, data: ModelData, n: int):
        """Long-range attachments per constrained particle (seed 000 §3.2)."""
        start, rows = incidence(data.lra_particle, n)
        self.lra_count = len(rows)
        self.lra_start = self._ints(start)
        self.lra_anchor = self._ints(data.lra_anchor[rows])
        self.lra_rest = self._floats(data.lra_rest[rows])

    def _init_springs(self, data: ModelData, n: int):
        """Damped springs gathered per particle (seed 001 §3.2)."""
        start, edge, other = both_ends(data.spring_pair, n)
        self.spring_count = len(data.spring_pair)
        self.spring_start = self._ints(start)
        self.spring_other = self._ints(other)
        self.spring_rest = self._floats(data.spring_rest[edge])
        self.spring_stiffness = self._floats(data.spring_stiffness[edge])
        self.spring_damping = self._floats(data.spring_damping[edge])

    def _init_surface(self, data: ModelData):
        """Render/collision surface bound to particles (direct or barycentric)."""
        self.surface_vertex_count = len(data.surface_index)
        self.surface_triangle_count = len(data.surface_triangles)
        self.surface_index = self._ints(data.surface_index, vector=4)
        self.surface_weight = self._floats(data.surface_weight, vector=4)
        self.surface_triangles = self._ints(data.surface_triangles.reshape(-1))

    def _init_tubes(self, data: ModelData):
        """Tubes drawn around a row of masses (row 0 of a spring sheet, seed 001): the
        particles in order with their neighbours along the tube (-1 at its ends)."""
        rows = [np.arange(o.particles[0], o.particles[0] + o.row_length) for o in data.organs]
        particle = np.concatenate([r for r in rows if len(r)] or [np.zeros(0, np.int64)])
        prev = np.concatenate([np.r_[-1, r[:-1]] for r in rows if len(r)] or [particle])
        after = np.concatenate([np.r_[r[1:], -1] for r in rows if len(r)] or [particle])
        self.tube_particle_count = len(particle)
        self.tube_particle = self._ints(particle)
        self.tube_prev = self._ints(prev)
        self.tube_next = self._ints(after)

    def _init_planes(self, planes):
        """Environment half-spaces (abdominal wall, table) the tissue rests on."""
        planes = list(planes)
        normal = np.array([p[1] for p in planes], dtype=np.float64).reshape(-1, 3)
        self.plane_count = len(planes)
        self.plane_point = self._floats(np.reshape([p[0] for p in planes], (-1, 3)), vector=3)
        self.plane_normal = self._floats(
            normal / np.linalg.norm(normal, axis=1, keepdims=True), vector=3
        )
        self.plane_friction = self._floats([p[2] for p in planes])
