"""A topology change written to the device model (seed 002 §3.3: "the topology
update ... followed by mesh skinning"): the host's :class:`MutableTopology` decides,
:class:`DeviceTopology` writes the rows it changed between two steps.

* removed particles get inverse mass 0 (they no longer move; no contact touches
  them) and are let go by a grasp;
* a changed cluster keeps its member rows: a member that left gets weight 0 in it,
  and the rest data (mass centre x0_cm, offsets q = x0 - x0_cm, mass) is computed
  again from the members that stay (Alg. 1 with the remaining particles);
* a split-off cluster is appended: member rows, chunks, and its frame warm-started
  from the cluster it came from; the particles that moved gather their goals from it
  (the particle-major membership rows are rewritten);
* the surface rows the change touched: triangles (a dead one degenerate, (0, 0, 0)),
  their organ, the incident-triangle rows of their vertices (normals), and the
  vertices made, removed or skinned by another cluster.

The model's :attr:`~taichi_lap.sim.model.Model.topology_version` then tells the
drawn mesh to copy the surface again.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.core.csr import rows_of
from taichi_lap.dissection.removal import MutableTopology, TopologyChange
from taichi_lap.kernels.collision.particle_contact import FREE
from taichi_lap.kernels.scatter import scatter
from taichi_lap.sim.model import Model, member_chunks


class CapacityError(RuntimeError):
    """The model's spare rows ran out (the model must be built with more)."""


class DeviceTopology:
    """Writes each :class:`TopologyChange` of ``topology`` to ``model`` and ``state``."""

    def __init__(self, model: Model, topology: MutableTopology):
        self.model, self.topology = model, topology
        data = model.data
        start = np.asarray(data.cluster_start, dtype=np.int64)
        self.cluster_rows = [(int(a), int(b)) for a, b in zip(start[:-1], start[1:])]
        self.row_particle = np.zeros(model.member_capacity, dtype=np.int64)
        self.row_particle[: len(data.cluster_member)] = data.cluster_member
        self.rows_used = len(data.cluster_member)
        self.triangles = model.surface_triangles.to_numpy().astype(np.int64)
        self.triangle_live = np.zeros(len(self.triangles), dtype=bool)
        self.triangle_live[: len(data.surface_triangles)] = True
        self.incident = model.surface_incident.to_numpy().astype(np.int64)

    def apply(self, change: TopologyChange, state):
        """Write ``change`` (just made by the topology) to the model, and release the
        removed particles from grasps in ``state``."""
        model, removed = self.model, change.removed_particles
        scatter(model.inv_mass, removed, np.zeros(len(removed)))
        held = removed[state.grasp_tool.to_numpy()[removed] != FREE]
        scatter(state.grasp_tool, held, np.full(len(held), FREE))
        for c in change.clusters.tolist():
            if c >= len(self.cluster_rows):
                self._append_cluster(c, state)
        self._write_rest_data(change.clusters)
        model.finalize_counts()
        self._write_surface(change)
        model.topology_version += 1

    def _write_surface(self, change: TopologyChange):
        """The triangles and vertices ``change`` touched, and the incident rows of
        their vertices."""
        model, v, f = self.model, self.topology.vertices, self.topology.triangles
        new, vertices = change.new_triangles, change.new_vertices
        if (len(new) and new.max() >= len(self.triangles)) or (
            len(vertices) and vertices.max() >= len(self.incident)
        ):
            raise CapacityError(
                f"the model's spare surface rows ran out ({len(self.triangles)} triangles, "
                f"{len(self.incident)} vertices)"
            )
        rows = np.union1d(change.dead_triangles, new)
        old = rows[self.triangle_live[rows]]
        old_vertices = self.triangles[old]
        self._unlist(np.repeat(old, 3), old_vertices.ravel())
        self.triangles[rows] = 0
        self.triangle_live[rows] = False
        self.triangles[new] = f["vertices"][new]
        self.triangle_live[new] = True
        self._list(np.repeat(new, 3), self.triangles[new].ravel())
        scatter(model.surface_triangles, rows, self.triangles[rows])
        scatter(model.surface_triangle_organ, new, f["organ"][new])
        touched = np.union1d(old_vertices.ravel(), self.triangles[new].ravel())
        scatter(model.surface_incident, touched, self.incident[touched])
        changed = np.union1d(np.union1d(vertices, change.dead_vertices), change.rebound_vertices)
        scatter(model.surface_index, changed, v["index"][changed])
        scatter(model.surface_weight, changed, v["weight"][changed])
        scatter(model.surface_cluster, changed, v["cluster"][changed])
        scatter(model.surface_rest, changed, v["rest"][changed])

    def _unlist(self, triangles: np.ndarray, vertices: np.ndarray):
        """Take each triangle out of its vertex's incident row."""
        hit_row, hit_column = np.nonzero(self.incident[vertices] == triangles[:, None])
        self.incident[vertices[hit_row], hit_column] = -1

    def _list(self, triangles: np.ndarray, vertices: np.ndarray):
        """Put each triangle into a free column of its vertex's incident row."""
        order = np.lexsort((triangles, vertices))
        triangles, vertices = triangles[order], vertices[order]
        distinct, first, counts = np.unique(vertices, return_index=True, return_counts=True)
        which = np.repeat(np.arange(len(distinct)), counts)
        rank = np.arange(len(vertices)) - first[which]
        rows = self.incident[distinct]
        free = np.argsort(rows != -1, axis=1, kind="stable")  # free columns first
        if (rank >= (rows == -1).sum(axis=1)[which]).any():
            raise CapacityError(f"a surface vertex is in more than {rows.shape[1]} triangles")
        self.incident[vertices, free[which, rank]] = triangles

    def _append_cluster(self, c: int, state):
        """Rows, chunks and a warm-started frame for split-off cluster ``c``."""
        model, members = self.model, self.topology.cluster_members[c]
        first, count = self.rows_used, len(members)
        chunks = member_chunks(np.array([first, first + count]), model.chunk_total)
        chunk_rows = np.arange(model.chunk_total, model.chunk_total + len(chunks["cluster"]))
        if (
            first + count > model.member_capacity
            or chunk_rows[-1] >= model.chunk_capacity
            or c >= model.cluster_capacity
        ):
            raise CapacityError(
                f"cluster {c}: the model's spare cluster rows ran out ({model.cluster_capacity} "
                f"clusters, {model.member_capacity} members, {model.chunk_capacity} chunks)"
            )
        rows = np.arange(first, first + count)
        self.row_particle[rows] = members
        self.rows_used += count
        self.cluster_rows.append((first, first + count))
        scatter(model.cluster_member, rows, members)
        scatter(model.chunk_cluster, chunk_rows, np.full(len(chunk_rows), c))
        scatter(model.chunk_begin, chunk_rows, chunks["begin"])
        scatter(model.chunk_end, chunk_rows, chunks["end"])
        scatter(model.cluster_chunk_begin, [c], chunks["first"][:1])
        scatter(model.cluster_chunk_end, [c], chunks["first"][1:])
        parent = self.topology.cluster_parent[c]
        scatter(state.cluster_quaternion, [c], state.cluster_quaternion.to_numpy()[[parent]])
        model.cluster_total = c + 1
        model.chunk_total += len(chunk_rows)

    def _write_rest_data(self, clusters: np.ndarray):
        """Member weights, rest offsets, centres and masses of ``clusters``, and the
        membership rows of their members."""
        model, topology = self.model, self.topology
        rest, mass = topology.rest, model.data.mass
        centers = {}
        for c in clusters.tolist():
            begin, end = self.cluster_rows[c]
            rows = np.arange(begin, end)
            particles = self.row_particle[rows]
            weight = np.where(np.isin(particles, topology.cluster_members[c]), mass[particles], 0.0)
            total = weight.sum()
            center = (weight[:, None] * rest[particles]).sum(axis=0) / max(total, 1e-30)
            centers[c] = center
            scatter(model.cluster_member_mass, rows, weight)
            scatter(model.cluster_rest_offset, rows, rest[particles] - center)
            scatter(model.cluster_rest_center, [c], center[None])
            scatter(model.cluster_mass, [c], [total])
        members = [topology.cluster_members[c] for c in centers]
        particles = np.unique(np.concatenate(members or [np.zeros(0, np.int64)]))
        rows = rows_of(topology.membership_start, particles)
        cluster = topology.membership_cluster[rows]
        keep = np.isin(cluster, list(centers))
        rows, cluster = rows[keep], cluster[keep]
        owner = np.repeat(particles, np.diff(topology.membership_start)[particles])[keep]
        center = np.array([centers[c] for c in cluster.tolist()]).reshape(-1, 3)
        scatter(model.membership_cluster, rows, cluster)
        scatter(model.membership_offset, rows, rest[owner] - center)
