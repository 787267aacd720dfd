"""A topology change written to the device model (seed 002 §3.3: "the topology
update ... followed by mesh skinning"): the host's :class:`MutableTopology` decides,
:class:`DeviceTopology` writes the rows it changed between two steps.

* removed particles get inverse mass 0 (they no longer move; no contact touches
  them) and are let go by a grasp;
* a changed cluster keeps its member rows: a member that left gets weight 0 in it,
  and the cluster's mass and rest mass centre x0_cm follow (Alg. 1 with the
  remaining particles); the offsets q stay relative to the centre the cluster had
  when its rows were written, and ``cluster_rest_shift`` (that centre - x0_cm)
  makes them x0 - x0_cm again, so a change costs what it removed, not the size of
  the clusters it touched;
* a split-off cluster is appended: member rows, chunks, and its frame warm-started
  from the cluster it came from; the particles that moved gather their goals from it
  (the particle-major membership rows are rewritten);
* the surface rows the change touched: triangles (a dead one degenerate, (0, 0, 0)),
  their organ, the incident-triangle rows of their vertices (normals), and the
  vertices made, removed or skinned by another cluster (a wound vertex: its kept
  particle with weight 1, its cluster and its rest offset from that particle).

A change that needs more rows than the model has spare first grows the model and
the state (:meth:`~taichi_lap.sim.model.Model.grow`, by :data:`GROWTH`, one log
line): geometry is never dropped.

The model's :attr:`~taichi_lap.sim.model.Model.topology_version` then tells the
drawn mesh to copy the surface again.
"""

from __future__ import annotations

import logging

import numpy as np

from taichi_lap.collision.surface_tables import SurfaceRows
from taichi_lap.core.csr import owners_of, rows_of, rows_of_extents
from taichi_lap.core.fields import padded_rows
from taichi_lap.dissection.removal import MutableTopology, TopologyChange
from taichi_lap.kernels.collision.particle_contact import FREE
from taichi_lap.kernels.scatter import RowWrites, gather
from taichi_lap.sim.model import CHUNK, Model, member_chunks

log = logging.getLogger("taichi_lap")

GROWTH = 1.5
"""Factor by which rows that ran out grow (at least to what the change needs)."""


class CapacityError(RuntimeError):
    """A surface vertex is in more triangles than its incident row holds."""


class DeviceTopology:
    """Writes each :class:`TopologyChange` of ``topology`` to ``model`` and ``state``."""

    def __init__(self, model: Model, topology: MutableTopology):
        self.model, self.topology = model, topology
        self._pending = RowWrites()  # set_particles' and set_masses', for apply's launch
        self._reweighed = np.zeros(0, np.int64)  # the particles given masses, for apply
        data = model.data
        start = np.asarray(data.cluster_start, dtype=np.int64)
        member = np.asarray(data.cluster_member, dtype=np.int64)
        n, c = data.particle_count, data.cluster_count
        keys = np.repeat(np.arange(c), np.diff(start)) * n + member
        order = np.argsort(keys, kind="stable")
        self.row_key, self.row_of_key = keys[order], order  # (cluster, particle) -> row
        self.rows_used = len(member)
        self.row_mass = np.zeros(model.member_capacity)
        self.row_mass[: len(member)] = data.fit_mass()[member]
        self.mass = np.zeros(model.cluster_capacity)
        self.center = np.zeros((model.cluster_capacity, 3))
        self.mass[:c] = model.cluster_mass.to_numpy()[:c]
        self.center[:c] = model.cluster_rest_center.to_numpy()[:c]
        self.origin = self.center.copy()  # the centre each cluster's offsets are from
        chunks = member_chunks(start)
        self.cluster_chunks = np.zeros((model.cluster_capacity, 2), dtype=np.int64)
        self.cluster_chunks[:c] = np.stack([chunks["first"][:-1], chunks["first"][1:]], 1)
        self.chunk_rows = np.stack([chunks["begin"], chunks["end"]], 1)  # member rows
        self.triangles = model.surface_triangles.to_numpy().astype(np.int64)
        self.triangle_live = np.zeros(len(self.triangles), dtype=bool)
        self.triangle_live[: len(data.surface_triangles)] = True
        self.incident = model.surface_incident.to_numpy().astype(np.int64)
        self.inverse_mass = data.inverse_mass().astype(np.float64)  # removed ones 0

    def apply(self, change: TopologyChange, state):
        """Write ``change`` (just made by the topology) to the model, and release the
        removed particles from grasps in ``state``; the particles given masses since the
        last change (:meth:`set_particles`, :meth:`set_masses`) are its ``reweighed``."""
        model, topology, removed = self.model, self.topology, change.removed_particles
        new = [c for c in change.clusters.tolist() if c >= model.cluster_total]
        self._fit(change, new, state)
        writes, self._pending = self._pending, RowWrites()  # the update's rows, one launch
        if len(change.joined):
            self._add_members(writes, change.joined[:, 0], change.joined[:, 1])
            writes.flush()  # the members dropped below rewrite rows of the same clusters
        writes.add(removed, {model.inv_mass: np.zeros(len(removed))})
        self.inverse_mass[removed] = 0.0
        held = removed[gather(state.grasp_tool, removed) != FREE]
        writes.add(held, {state.grasp_tool: np.full(len(held), FREE)})
        rows = rows_of(topology.membership_start, removed)
        left = [
            (
                topology.membership_cluster[rows],
                removed[owners_of(topology.membership_start, removed)],
            )
        ]
        for c in new:
            members = topology.cluster_members[c]
            left.append((np.full(len(members), topology.cluster_parent[c]), members))
        self._drop_members(
            writes, np.concatenate([a for a, _ in left]), np.concatenate([b for _, b in left])
        )
        for c in new:
            self._append_cluster(writes, c, state, not change.memberships_rebuilt)
        if new or len(change.joined):
            model.finalize_counts()
        if change.memberships_rebuilt:
            self._write_memberships(writes)
        self._write_surface(writes, change)
        writes.flush()
        change.reweighed, self._reweighed = self._reweighed, np.zeros(0, np.int64)
        members = change.reweighed[np.diff(topology.membership_start)[change.reweighed] > 0]
        if len(members):  # the clusters' tables as the change left them, weighed anew
            self._weigh_members(writes, members)
            writes.flush()
        model.topology_version += 1
        model.as_built = False

    def set_particles(self, particles, rest, mass, x, v, state):
        """Give the particle rows ``particles`` (reserve rows a cut or tear takes, a
        torn vertex's: :mod:`taichi_lap.dissection.sheet_cut`) their rest
        position, mass, inverse mass, position and velocity ((P, 3) or (P,) each) in
        the model and ``state``: in the host tables now, on the device with the
        change's :meth:`apply` (one launch for all of them)."""
        self.topology.pinned[particles] = False
        self._add_masses(particles, mass, 1.0 / np.asarray(mass, dtype=np.float64))
        self._pending.add(
            particles, {self.model.rest_position: rest, state.x: x, state.p: x, state.v: v}
        )

    def set_masses(self, particles, mass):
        """Give the particle rows ``particles`` the mass ``mass`` [kg] (host tables
        now, the model with the next :meth:`apply`); a particle held in place
        (inverse mass 0) keeps it 0. The clusters they are members of weigh them
        anew with that :meth:`apply`, after its change (their masses and rest
        centres follow, as when a member leaves)."""
        particles = np.asarray(particles, dtype=np.int64)
        inverse = np.where(self.inverse_mass[particles] > 0.0, 1.0 / np.asarray(mass), 0.0)
        self._add_masses(particles, mass, inverse)

    def _add_masses(self, particles, mass, inverse):
        """Set ``particles``' mass and ``inverse`` mass in the host tables, and for the
        model (no longer as built) with the next :meth:`apply`."""
        self.model.as_built = False
        self.inverse_mass[particles] = inverse
        self.topology.mass[particles] = mass
        self._reweighed = np.union1d(self._reweighed, particles)
        self._pending.add(particles, {self.model.mass: mass, self.model.inv_mass: inverse})

    def out_of_reach(self, organ: int, x: np.ndarray, low, high) -> bool:
        """Whether ``organ``'s particles at ``x`` (N, 3) [m] lie outside the box
        ``low``..``high`` (a cut's reach), by their bounding box."""
        span = x[slice(*self.model.data.organs[organ].particles)]
        return bool(np.any(span.min(axis=0) > high) or np.any(span.max(axis=0) < low))

    def surface_rows(self) -> SurfaceRows:
        """The model's surface rows as the changes so far left them (what the tissue
        collision follows, :meth:`~taichi_lap.collision.tissue.TissueCollision.rewrite`)."""
        v, f = self.topology.vertices, self.topology.triangles
        rows = len(self.triangles)
        return SurfaceRows(
            triangles=self.triangles,
            live=self.triangle_live,
            organ=padded_rows(f["organ"][:rows], rows, 0),
            incident=self.incident,
            index=v["index"],
            weight=v["weight"],
            rest=v["rest"],
            vertex_rows=v.used,
            inverse_mass=self.inverse_mass,
            contact_radius=self.model.data.contact_radius(),
        )

    def _fit(self, change: TopologyChange, new: list[int], state):
        """Grow the model, the state and these tables when ``change`` with its
        ``new`` clusters needs more rows than are spare (module docstring)."""
        model = self.model
        sizes = np.array([len(self.topology.cluster_members[c]) for c in new], dtype=np.int64)
        joined, gained = np.unique(change.joined[:, 0], return_counts=True)
        kept_chunks = np.diff(self.cluster_chunks[joined], axis=1).sum()
        need = {
            "clusters": max(new, default=-1) + 1,
            "members": self.rows_used + int(sizes.sum()) + len(change.joined),
            "memberships": len(self.topology.membership_cluster),
            "chunks": model.chunk_total
            + int(np.maximum(-(-sizes // CHUNK), 1).sum())
            + int(kept_chunks + (-(-gained // CHUNK)).sum()),
            "triangles": int(change.new_triangles.max(initial=-1)) + 1,
            "vertices": int(change.new_vertices.max(initial=-1)) + 1,
        }
        if need["chunks"] > model.capacity["chunks"]:
            need["chunks"] -= self._pack_chunks()
        short = {k: n for k, n in need.items() if n > model.capacity[k]}
        if not short:
            return
        self._pending.flush()  # into the fields before they are reallocated
        rows = {k: max(n, int(GROWTH * model.capacity[k])) for k, n in short.items()}
        log.warning(
            "dissection: the model's spare rows ran out; growing %s (kernels compile again)",
            ", ".join(f"{k} {model.capacity[k]} -> {n}" for k, n in rows.items()),
        )
        model.grow(**rows)
        state.grow(model)
        self.row_mass = padded_rows(self.row_mass, model.member_capacity, 0.0)
        self.mass = padded_rows(self.mass, model.cluster_capacity, 0.0)
        self.center = padded_rows(self.center, model.cluster_capacity, 0.0)
        self.origin = padded_rows(self.origin, model.cluster_capacity, 0.0)
        self.cluster_chunks = padded_rows(self.cluster_chunks, model.cluster_capacity, 0)
        self.triangles = padded_rows(self.triangles, model.surface_triangle_count, 0)
        self.triangle_live = padded_rows(self.triangle_live, model.surface_triangle_count, False)
        self.incident = padded_rows(self.incident, model.surface_vertex_count, -1)

    def _pack_chunks(self) -> int:
        """List every cluster's chunks again from row 0, without the listings that
        :meth:`_add_members` emptied (a wall cut gives clusters members every frame it
        cuts, each time listing their chunks again): the spare chunk rows are found
        there before the model grows. Returns the rows freed."""
        model = self.model
        self._pending.flush()  # its rows are those of the listing before
        total = model.cluster_total
        counts = np.diff(self.cluster_chunks[:total], axis=1).ravel()
        listed = self.chunk_rows[rows_of_extents(self.cluster_chunks[:total, 0], counts)]
        first = np.concatenate([[0], np.cumsum(counts)])
        writes = RowWrites()
        writes.add(
            np.arange(len(listed)),
            {
                model.chunk_cluster: np.repeat(np.arange(total), counts),
                model.chunk_begin: listed[:, 0],
                model.chunk_end: listed[:, 1],
            },
        )
        writes.add(
            np.arange(total),
            {model.cluster_chunk_begin: first[:-1], model.cluster_chunk_end: first[1:]},
        )
        writes.flush()
        freed = model.chunk_total - len(listed)
        self.cluster_chunks[:total] = np.stack([first[:-1], first[1:]], 1)
        self.chunk_rows = listed
        model.chunk_total = len(listed)
        model.finalize_counts()
        return freed

    def _drop_members(self, writes: RowWrites, clusters: np.ndarray, particles: np.ndarray):
        """Members ``particles`` leave ``clusters`` (pairs): their rows weigh 0
        (:meth:`_set_member_weights`)."""
        self._set_member_weights(writes, clusters, particles, np.zeros(len(particles)))

    def _weigh_members(self, writes: RowWrites, particles: np.ndarray):
        """Every cluster row of ``particles`` weighs the particle's weight in the fits
        now (its mass; a fixed particle's more: :meth:`MutableTopology.fit_mass`)."""
        topology = self.topology
        rows = rows_of(topology.membership_start, particles)
        owners = particles[owners_of(topology.membership_start, particles)]
        self._set_member_weights(
            writes, topology.membership_cluster[rows], owners, topology.fit_mass(owners)
        )

    def _set_member_weights(
        self, writes: RowWrites, clusters: np.ndarray, particles: np.ndarray, weights
    ):
        """Members ``particles`` of ``clusters`` (pairs) weigh ``weights`` [kg] (0: they
        left), and each cluster's mass and rest centre follow; its offsets stay and
        the kernels add ``cluster_rest_shift`` = origin - centre (q = x0 - x0_cm
        again)."""
        model = self.model
        n = len(self.topology.rest)
        keys = clusters * n + particles
        at = np.minimum(np.searchsorted(self.row_key, keys), len(self.row_key) - 1)
        if (self.row_key[at] != keys).any():
            raise RuntimeError("a cluster member has no row in its cluster")
        rows = self.row_of_key[at]
        gained = weights - self.row_mass[rows]
        self.row_mass[rows] = weights
        changed, which = np.unique(clusters, return_inverse=True)
        rest = self.topology.rest[particles]
        moment = np.stack(
            [
                np.bincount(which, weights=gained * rest[:, a], minlength=len(changed))
                for a in range(3)
            ],
            axis=1,
        )
        total = self.mass[changed] + np.bincount(which, weights=gained, minlength=len(changed))
        kept = total > 1e-12 * np.maximum(self.mass[changed], 1e-30)
        center = self.center[changed].copy()
        center[kept] = (self.mass[changed][kept, None] * center[kept] + moment[kept]) / total[
            kept, None
        ]
        self.mass[changed] = np.where(kept, total, 0.0)
        self.center[changed] = center
        writes.add(rows, {model.cluster_member_mass: weights})
        writes.add(
            changed,
            {
                model.cluster_mass: self.mass[changed],
                model.cluster_rest_center: center,
                model.cluster_rest_shift: self.origin[changed] - center,
            },
        )

    def _add_members(self, writes: RowWrites, clusters: np.ndarray, particles: np.ndarray):
        """Members ``particles`` join ``clusters`` (pairs; a cut's new particles): each
        cluster's new members take rows at the end, its chunks are listed again at
        the end with chunks of those rows (the old listing is emptied), and its mass
        and rest centre follow (offsets from its ``origin``, as for every member). A
        particle row a cut took again (a wall's reserve row, given back when a later
        sweep removed its vertex) takes the row it left in the cluster, weighing 0,
        listed still."""
        model = self.model
        n = len(self.topology.rest)
        order = np.argsort(clusters, kind="stable")
        clusters, particles = clusters[order], particles[order]
        keys = clusters * n + particles
        at = np.minimum(np.searchsorted(self.row_key, keys), len(self.row_key) - 1)
        fresh = self.row_key[at] != keys
        rows = self.row_of_key[at]
        rows[fresh] = np.arange(self.rows_used, self.rows_used + int(fresh.sum()))
        self.rows_used += int(fresh.sum())
        self._key_rows(keys[fresh], rows[fresh])
        mass = self.topology.fit_mass(particles)
        rest = self.topology.rest[particles]
        gained = mass - np.where(fresh, 0.0, self.row_mass[rows])
        self.row_mass[rows] = mass
        changed, first = np.unique(clusters, return_index=True)
        total = self.mass[changed] + np.add.reduceat(gained, first)
        moment = self.mass[changed, None] * self.center[changed] + np.add.reduceat(
            gained[:, None] * rest, first
        )
        self.center[changed] = moment / np.maximum(total, 1e-30)[:, None]
        self.mass[changed] = total
        writes.add(
            rows,
            {
                model.cluster_member: particles,
                model.cluster_member_mass: mass,
                model.cluster_rest_offset: rest - self.origin[clusters],
            },
        )
        chunk_cluster, chunk_rows = [np.zeros(0, np.int64)], [np.zeros((0, 2), np.int64)]
        at = model.chunk_total
        ranges = self.cluster_chunks[changed].copy()
        ends = np.append(first[1:], len(clusters))
        for i, (c, a, b) in enumerate(zip(changed.tolist(), first.tolist(), ends.tolist())):
            taken = rows[a:b][fresh[a:b]]  # in order, one after another
            if not len(taken):
                continue  # rows it had: listed already
            old = self.chunk_rows[slice(*self.cluster_chunks[c])]
            added = member_chunks(np.array([taken[0], taken[-1] + 1]))
            listed = np.concatenate([old, np.stack([added["begin"], added["end"]], 1)])
            writes.add(
                np.arange(*self.cluster_chunks[c]),
                {model.chunk_end: old[:, 0]},  # the old listing, emptied
            )
            ranges[i] = (at, at + len(listed))
            chunk_cluster.append(np.full(len(listed), c))
            chunk_rows.append(listed)
            at += len(listed)
        self.cluster_chunks[changed] = ranges
        chunk_rows = np.concatenate(chunk_rows)
        new_chunks = np.arange(model.chunk_total, at)
        self.chunk_rows = np.concatenate([self.chunk_rows, chunk_rows])
        model.chunk_total = at
        writes.add(
            new_chunks,
            {
                model.chunk_cluster: np.concatenate(chunk_cluster),
                model.chunk_begin: chunk_rows[:, 0],
                model.chunk_end: chunk_rows[:, 1],
            },
        )
        writes.add(
            changed,
            {
                model.cluster_mass: self.mass[changed],
                model.cluster_rest_center: self.center[changed],
                model.cluster_rest_shift: self.origin[changed] - self.center[changed],
                model.cluster_chunk_begin: ranges[:, 0],
                model.cluster_chunk_end: ranges[:, 1],
            },
        )

    def _key_rows(self, keys: np.ndarray, rows: np.ndarray):
        """List member ``rows`` under their (cluster, particle) ``keys``, the listing
        kept sorted by key (a split-off cluster's members need not be in order)."""
        keys = np.concatenate([self.row_key, keys])
        by_key = np.argsort(keys, kind="stable")
        self.row_key = keys[by_key]
        self.row_of_key = np.concatenate([self.row_of_key, rows])[by_key]

    def _write_memberships(self, writes: RowWrites):
        """Every particle's memberships again, as the topology lists them (a cut gave
        new particles clusters): the clusters, and each offset from its cluster's
        ``origin`` (:meth:`_add_members`)."""
        model, topology = self.model, self.topology
        start = topology.membership_start
        owner = np.repeat(np.arange(len(start) - 1), np.diff(start))
        cluster = topology.membership_cluster
        writes.add(np.arange(len(start)), {model.membership_start: start})
        writes.add(
            np.arange(len(cluster)),
            {
                model.membership_cluster: cluster,
                model.membership_offset: topology.rest[owner] - self.origin[cluster],
            },
        )

    def _append_cluster(self, writes: RowWrites, c: int, state, memberships: bool):
        """Rows, chunks, rest data and a warm-started frame for split-off cluster
        ``c``; with ``memberships`` its members' membership rows name it (else
        :meth:`_write_memberships` writes them all)."""
        model, topology = self.model, self.topology
        members = topology.cluster_members[c]
        first, count = self.rows_used, len(members)
        chunks = member_chunks(np.array([first, first + count]), model.chunk_total)
        chunk_rows = np.arange(model.chunk_total, model.chunk_total + len(chunks["cluster"]))
        rows = np.arange(first, first + count)
        n = len(topology.rest)
        self._key_rows(c * n + members, rows)
        self.rows_used += count
        mass = topology.fit_mass(members)
        rest = topology.rest[members]
        self.row_mass[rows] = mass
        self.mass[c] = mass.sum()
        self.center[c] = self.origin[c] = topology.rest_centers(np.array([c]))[0]
        writes.add(
            rows,
            {
                model.cluster_member: members,
                model.cluster_member_mass: mass,
                model.cluster_rest_offset: rest - self.center[c],
            },
        )
        parent = topology.cluster_parent[c]
        writes.add(
            [c],
            {
                model.cluster_mass: [self.mass[c]],
                model.cluster_rest_center: self.center[c][None],
                model.cluster_rest_shift: np.zeros((1, 3)),
                model.cluster_chunk_begin: chunks["first"][:1],
                model.cluster_chunk_end: chunks["first"][1:],
                state.cluster_quaternion: state.cluster_quaternion.to_numpy()[[parent]],
            },
        )
        writes.add(
            chunk_rows,
            {
                model.chunk_cluster: np.full(len(chunk_rows), c),
                model.chunk_begin: chunks["begin"],
                model.chunk_end: chunks["end"],
            },
        )
        model.cluster_total = c + 1
        model.chunk_total += len(chunk_rows)
        self.cluster_chunks[c] = (chunk_rows[0], chunk_rows[-1] + 1)
        self.chunk_rows = np.concatenate(
            [self.chunk_rows, np.stack([chunks["begin"], chunks["end"]], 1)]
        )
        if not memberships:
            return
        membership = rows_of(topology.membership_start, members)
        owner = members[owners_of(topology.membership_start, members)]
        mine = topology.membership_cluster[membership] == c
        membership, owner = membership[mine], owner[mine]
        writes.add(
            membership,
            {
                model.membership_cluster: np.full(len(membership), c),
                model.membership_offset: topology.rest[owner] - self.center[c],
            },
        )

    def _write_surface(self, writes: RowWrites, change: TopologyChange):
        """The triangles and vertices ``change`` touched, and the incident rows of
        their vertices."""
        model, v, f = self.model, self.topology.vertices, self.topology.triangles
        new, vertices = change.new_triangles, change.new_vertices
        rows = np.union1d(change.dead_triangles, new)
        old = rows[self.triangle_live[rows]]
        old_vertices = self.triangles[old]
        self._unlist(np.repeat(old, 3), old_vertices.ravel())
        self.triangles[rows] = 0
        self.triangle_live[rows] = False
        self.triangles[new] = f["vertices"][new]
        self.triangle_live[new] = True
        self._list(np.repeat(new, 3), self.triangles[new].ravel())
        writes.add(  # a dead row's organ is its last one: any value will do
            rows,
            {
                model.surface_triangles: self.triangles[rows],
                model.surface_triangle_organ: f["organ"][rows],
            },
        )
        touched = np.union1d(old_vertices.ravel(), self.triangles[new].ravel())
        writes.add(touched, {model.surface_incident: self.incident[touched]})
        changed = np.union1d(np.union1d(vertices, change.dead_vertices), change.rebound_vertices)
        offset = v["rest"][changed] - self.topology.rest[v["index"][changed, 0]]
        offset[v["cluster"][changed] < 0] = 0.0
        writes.add(
            changed,
            {
                model.surface_index: v["index"][changed],
                model.surface_weight: v["weight"][changed],
                model.surface_cluster: v["cluster"][changed],
                model.surface_offset: offset,
            },
        )

    def _unlist(self, triangles: np.ndarray, vertices: np.ndarray):
        """Take each triangle out of its vertex's incident row; the triangles left keep
        their order, first in the row (the normals stop at a row's first -1)."""
        hit_row, hit_column = np.nonzero(self.incident[vertices] == triangles[:, None])
        self.incident[vertices[hit_row], hit_column] = -1
        rows = np.unique(vertices)
        left = self.incident[rows]
        self.incident[rows] = np.take_along_axis(
            left, np.argsort(left < 0, axis=1, kind="stable"), axis=1
        )

    def _list(self, triangles: np.ndarray, vertices: np.ndarray):
        """Put each triangle into a free column of its vertex's incident row, the first
        free ones (after the triangles it holds)."""
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
