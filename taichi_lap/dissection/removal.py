"""Removing particles from tet organs, on the host (seed 002 §3.3): the update of
tets, wound surface, clusters and fragments that one removal makes.

:class:`MutableTopology` keeps the model's topology as NumPy arrays with alive flags
and slots that are reused, and :meth:`MutableTopology.remove` changes only what lies
next to the removed particles:

1. the particles die, and every tet using one; a particle left in no live tet (an
   orphan) dies with them;
2. fragments: a small piece of live tissue (:data:`FRAGMENT_PARTICLES`) near the
   removal that is no longer connected to the rest of its organ (nor pinned) is
   removed whole and reported with its particle count;
3. clusters: the live members of every cluster that lost one are split into the
   connected components of the live tet graph ("remaining tets", breadth-first in
   seed 002). A part that was connected when the model was built and is no longer
   becomes a cluster of its own; the largest piece of each stays in the cluster, or
   in a cluster joining organs the piece nearest the other organ (so such clusters
   keep joining the organs where they touch, and a piece cut off the joined end
   leaves);
4. the wound surface: marching tetrahedra (:mod:`taichi_lap.dissection.marching`)
   on the tets and surface triangles touching a removed particle replace what they
   made before. New vertices lie halfway along the cut edges at rest and follow
   their nearest cluster's rotation (linear blend skinning, seed 002 §3.3) from the
   edge's kept particle: bound to it with weight 1 and a rest offset, so a push on
   the wound moves that particle and the wound stays joined to the tissue it bounds.

5. embedded surfaces (a vessel's tube, bound barycentrically in the vessel's own tets,
   seed 002 §3.2): a vertex bound to a removed particle dies with its triangles, and
   each hole this leaves is closed by a cap: fans around new vertices across its
   boundary loop (:func:`fan_arcs`), bound like wound vertices to their nearest live
   particle: the cut vessel ends in sealed stumps.

Organs of tets can lose particles: those whose surface vertices are their boundary
particles (direct binding, the BCC liver of seed 002) get a marching-tetrahedra
wound, those whose surface is embedded in their tets (the vessels) get caps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from taichi_lap.core.csr import both_ends, incidence, owners_of, rows_of
from taichi_lap.core.mesh import TET_FACES, face_keys, tet_volumes, unique_edges
from taichi_lap.core.topology import Topology
from taichi_lap.dissection.marching import clipped_triangles, wound_triangles
from taichi_lap.preprocess.model_data import fit_weights

FRAGMENT_DEPTH = 8
"""Tet edges from a removal within which a piece cut off from its organ is looked for."""
LOCAL_CHECK_MEMBERS = 2000
"""Clusters larger than this (an organ-wide cluster) are first checked near the
removal (:meth:`MutableTopology._stays_connected`) before all their members are."""
FRAGMENT_PARTICLES = 40
"""A piece cut off from its organ with at most this many particles (about a 1 cm cube
of the liver's 3 mm lattice) is a fragment and is removed; a larger one stays as
tissue of its own (a transected lobe)."""
CUT_POINT = 0.5
"""Where along a cut edge, from its kept end, a wound vertex sits (seed 002: "the
weight sum of the two endpoints")."""


def dissectable_organs(data) -> np.ndarray:
    """(organs,) bool: the tet organs whose surface vertices are their particles
    (directly bound: the liver), whose wound marching tetrahedra make."""
    weight = np.asarray(data.surface_weight, dtype=np.float64).reshape(-1, 4)
    return np.array(
        [
            organ.tets[1] > organ.tets[0]
            and bool(np.all(weight[slice(*organ.surface_vertices), 0] == 1.0))
            for organ in data.organs
        ],
        dtype=bool,
    )


def cuttable_organs(data) -> np.ndarray:
    """(organs,) bool: the organs removal can take particles from: the tet organs."""
    return np.array([organ.tets[1] > organ.tets[0] for organ in data.organs], dtype=bool)


def embedded_organs(data) -> np.ndarray:
    """(organs,) bool: the tet organs whose surface is bound barycentrically in their
    tets (the vessels of seed 002 §3.2): cut, their holes are capped."""
    return cuttable_organs(data) & ~dissectable_organs(data)


FAN_EDGES = 16
"""Loop edges one cap vertex fans over at most: a longer loop takes several (a cap
vertex stays within the incident rows of :data:`taichi_lap.core.mesh.INCIDENT_WIDTH`)."""


def fan_arcs(loop: list[int], new_vertex) -> list[tuple[int, int, int]]:
    """Triangles closing the hole bounded by ``loop`` (vertices in the order the cap's
    edges run, the reverse of the surface's edges along the hole), oriented like it:
    fans around new vertices, each made by ``new_vertex(arc)`` for the arc of loop
    vertices it fans over. A loop of at most FAN_EDGES edges is one fan; a longer
    one gives its first FAN_EDGES edges a fan, and the rest of the hole, closed
    through that fan's vertex, is capped the same way."""
    out = []
    while True:
        if len(loop) <= FAN_EDGES:
            centre = new_vertex(loop)
            ring = loop + loop[:1]
            out += [(a, b, centre) for a, b in zip(ring[:-1], ring[1:])]
            return out
        arc = loop[: FAN_EDGES + 1]
        centre = new_vertex(arc)
        out += [(a, b, centre) for a, b in zip(arc[:-1], arc[1:])]
        loop = loop[FAN_EDGES:] + [loop[0], centre]


def boundary_loops(edges: list[tuple[int, int]]) -> list[list[int]]:
    """Simple closed loops chained from directed ``edges`` (a, b): a walk that comes
    back to a vertex it passed (a hole pinched at a vertex) gives the loop since then
    on its own, so no vertex is twice in a loop; a chain that does not close is left
    out."""
    following: dict[int, list[int]] = {}
    for a, b in edges:
        following.setdefault(a, []).append(b)
    loops = []
    while following:
        at = next(iter(following))
        path, where = [at], {at: 0}
        while True:
            nexts = following.get(at)
            if not nexts:
                break
            b = nexts.pop()
            if not nexts:
                del following[at]
            if b in where:
                i = where[b]
                loops.append(path[i:])
                for vertex in path[i + 1 :]:
                    del where[vertex]
                del path[i + 1 :]
            else:
                where[b] = len(path)
                path.append(b)
            at = b
    return loops


def _none() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dataclass
class TopologyChange:
    """What one :meth:`MutableTopology.remove` or :meth:`~MutableTopology.split_tets`
    changed (indices of its arrays)."""

    removed_particles: np.ndarray = field(default_factory=_none)
    dead_tets: np.ndarray = field(default_factory=_none)
    removed_volume: float = 0.0  # [m^3] rest volume of the dead tets
    dead_triangles: np.ndarray = field(default_factory=_none)
    new_triangles: np.ndarray = field(default_factory=_none)  # slots written (maybe reused)
    dead_vertices: np.ndarray = field(default_factory=_none)
    new_vertices: np.ndarray = field(default_factory=_none)
    clusters: np.ndarray = field(default_factory=_none)  # members changed, new ones included
    rebound_vertices: np.ndarray = field(default_factory=_none)  # wound, skinned anew
    joined: np.ndarray = field(
        default_factory=lambda: np.zeros((0, 2), np.int64)
    )  # (cluster, new member)
    memberships_rebuilt: bool = False  # particle -> clusters rows made again
    fragments: list[int] = field(default_factory=list)  # particles of each fragment
    split_tets: int = 0  # tets a volume cut split (of dead_tets; the rest took twins)
    reweighed: np.ndarray = field(default_factory=_none)  # old particles given new masses

    @property
    def empty(self) -> bool:
        return not (len(self.removed_particles) or len(self.dead_tets))


class _Slots:
    """Rows of growable arrays with a free list: dead rows are reused first."""

    def __init__(self, arrays: dict[str, np.ndarray], used: int):
        self.arrays = arrays
        self.used = used
        self.free: list[int] = []

    def take(self, count: int) -> np.ndarray:
        reused = [self.free.pop() for _ in range(min(count, len(self.free)))]
        fresh = np.arange(self.used, self.used + count - len(reused))
        self.used += len(fresh)
        capacity = len(next(iter(self.arrays.values())))
        if self.used > capacity:
            grown = max(self.used, 2 * capacity)
            for name, values in self.arrays.items():
                extra = np.zeros((grown - capacity,) + values.shape[1:], values.dtype)
                self.arrays[name] = np.concatenate([values, extra])
        return np.concatenate([np.array(reused, dtype=np.int64), fresh])

    def release(self, rows: np.ndarray):
        self.free.extend(int(r) for r in rows)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]


class MutableTopology:
    """The topology of a built model (a ``ModelData``) that particles can be removed
    from; see the module docstring."""

    def __init__(self, data):
        self.data = data
        n = data.particle_count
        self.rest = np.array(data.rest_position, dtype=np.float64)  # a cut sets rows
        self.mass = np.array(data.mass, dtype=np.float64)  # and their mass
        self.organ_of = np.asarray(data.organ, dtype=np.int64)
        self.pinned = np.array(data.pinned, dtype=bool)  # a reserve row a cut takes is free
        self.particle_alive = np.ones(n, dtype=bool)
        for organ in data.organs:  # a sheet's reserve rows live once a cut takes them
            self.particle_alive[organ.particles[1] - organ.reserve : organ.particles[1]] = False
        self.removed_volume = 0.0

        self.tets = np.asarray(data.tets, dtype=np.int64).reshape(-1, 4)
        self.tet_alive = np.ones(len(self.tets), dtype=bool)
        self.tet_removed = np.zeros(len(self.tets), dtype=bool)  # by a removal, not a cut
        self.wall_pairs = np.zeros((0, 2), dtype=np.int64)  # the cut walls' graph
        self._mask = np.zeros(n, dtype=bool)  # scratch, left all False
        self._reached = np.zeros(n, dtype=bool)  # scratch, left all False
        self._corner = np.zeros(n, dtype=bool)  # scratch, left all False
        self._slot = np.full(n, -1, dtype=np.int64)  # scratch, left all -1
        self._index_tets()

        self._init_surface(data)
        self._init_clusters(data)

    # -- set-up ---------------------------------------------------------------------

    def _index_tets(self):
        """The tets' incidence (particle -> tets, edges) and live counts, and the
        graph over them (:meth:`_index_graph`): as built, and again after a cut adds
        tets."""
        n = len(self.rest)
        self.tet_start, rows = incidence(self.tets.ravel(), n)
        self.particle_tet = rows // 4
        live = self.tets[self.tet_alive]
        self.live_tets_of = np.bincount(live.ravel(), minlength=n)
        edges, inverse = unique_edges(self.tets, return_inverse=True)
        self.tet_edges = edges.reshape(-1, 2)
        self.tet_edge = inverse.reshape(-1, 6)
        self._index_graph()

    def _index_graph(self):
        """The graph clusters split over (adjacency and live counts): the tets'
        edges, then the :attr:`wall_pairs`, live while listed; again after a wall's
        cut changes only these (:meth:`_link_walls`)."""
        self.edge_live = np.concatenate(
            [
                np.bincount(self.tet_edge[self.tet_alive].ravel(), minlength=len(self.tet_edges)),
                np.ones(len(self.wall_pairs), dtype=np.int64),
            ]
        )
        self.adjacency_start, self.adjacency_edge, self.adjacency_other = both_ends(
            np.concatenate([self.tet_edges, self.wall_pairs]), len(self.rest)
        )

    def _index_memberships(self):
        """Particle -> its clusters (compressed rows, by particle then cluster, as the
        model's memberships are): as built, and again after a cut adds members."""
        sizes = [len(m) for m in self.cluster_members]
        owner = np.repeat(np.arange(len(sizes)), sizes)
        member = np.concatenate(self.cluster_members or [np.zeros(0, np.int64)])
        self.membership_start, rows = incidence(member, len(self.rest))
        self.membership_cluster = owner[rows]

    def _index_originals(self, original: np.ndarray, particles: np.ndarray | None = None):
        """The surface triangles a removal can clip (``original``: slots; as built the
        directly bound organs' triangles, then also those a cut made) by particle:
        their corners' particles ``particles`` (len(original), 3), by default those
        their slots hold now."""
        self.original = original
        if particles is None:
            f, v = self.triangles, self.vertices
            particles = v["index"][f["vertices"][original], 0]
        self.original_particles = particles
        self.original_start, rows = incidence(self.original_particles.ravel(), len(self.rest))
        self.particle_original = rows // 3

    def _init_surface(self, data):
        # copies: reused slots are written in place, and the model data stays as built
        index = np.array(data.surface_index, dtype=np.int64).reshape(-1, 4)
        weight = np.array(data.surface_weight, dtype=np.float64).reshape(-1, 4)
        triangles = np.array(data.surface_triangles, dtype=np.int64).reshape(-1, 3)
        v, f = len(index), len(triangles)
        vertex_organ = np.full(v, -1, dtype=np.int64)
        triangle_organ = np.full(f, -1, dtype=np.int64)
        self.dissectable = dissectable_organs(data)
        for k, organ in enumerate(data.organs):
            vertex_organ[slice(*organ.surface_vertices)] = k
            triangle_organ[slice(*organ.triangles)] = k
        self.vertices = _Slots(
            {
                "index": index,
                "weight": weight,
                "organ": vertex_organ,
                "alive": np.ones(v, dtype=bool),
                "rest": (weight[..., None] * self.rest[index]).sum(axis=1),
                "cluster": np.full(v, -1, dtype=np.int64),  # skinning cluster, wound only
                "kept": np.full(v, -1, dtype=np.int64),  # kept end, wound only
                "cut": np.full(v, -1, dtype=np.int64),  # removed end, wound only
                "uses": np.bincount(triangles.ravel(), minlength=v),
            },
            v,
        )
        self.triangles = _Slots(
            {
                "vertices": triangles,
                "organ": triangle_organ,
                "alive": np.ones(f, dtype=bool),
            },
            f,
        )
        self._index_originals(np.flatnonzero(self.dissectable[triangle_organ]))
        self.original_pieces = {int(t): [int(t)] for t in self.original}
        self.tet_wound: dict[int, list[int]] = {}
        self.wound_vertex: dict[tuple[int, int], int] = {}
        self.particle_vertex = np.full(len(self.rest), -1, dtype=np.int64)
        bound = self.dissectable[vertex_organ]
        self.particle_vertex[index[bound, 0]] = np.flatnonzero(bound)
        self.embedded = embedded_organs(data)
        self.cuttable = self.dissectable | self.embedded
        embedded = np.flatnonzero(self.embedded[vertex_organ])  # vertex -> its particles
        follows = weight[embedded] != 0.0  # barycentric weights may be negative
        self.embedded_start, rows = incidence(index[embedded][follows], len(self.rest))
        self.embedded_vertex = np.repeat(embedded, follows.sum(axis=1))[rows]
        built = np.flatnonzero(self.embedded[triangle_organ])  # vertex -> its triangles
        self.embedded_triangle_start, rows = incidence(triangles[built].ravel(), v)
        self.embedded_triangle = built[rows // 3]
        self.cap_triangles_at: dict[int, list[int]] = {}  # vertex -> caps made at it
        self.cap_vertices_of: dict[int, list[int]] = {}  # particle -> cap vertices on it

    def _init_clusters(self, data):
        start = np.asarray(data.cluster_start, dtype=np.int64)
        member = np.asarray(data.cluster_member, dtype=np.int64)
        self._built = (start, member)
        self.cluster_members = [member[a:b] for a, b in zip(start[:-1], start[1:])]
        self.cluster_alive = np.ones(len(self.cluster_members), dtype=bool)
        self._index_memberships()
        self._built_parts: dict[int, np.ndarray] = {}  # parts of a cluster as built
        self.cluster_parent: dict[int, int] = {}  # a split-off cluster's cluster of origin

    # -- queries --------------------------------------------------------------------

    def clusters_of(self, particles: np.ndarray) -> np.ndarray:
        """The distinct clusters the ``particles`` are members of."""
        return np.unique(self.membership_cluster[rows_of(self.membership_start, particles)])

    def built_members(self, c: int) -> np.ndarray:
        """The members cluster ``c`` (one of the model's) was built with."""
        start, member = self._built
        return member[start[c] : start[c + 1]]

    def live_triangles(self, organ: int | None = None) -> np.ndarray:
        """The rows of the live surface triangles (``organ``'s only, when given)."""
        f = self.triangles
        live = f["alive"][: f.used]
        if organ is not None:
            live = live & (f["organ"][: f.used] == organ)
        return np.flatnonzero(live)

    def live_faces(self, organ: int | None = None) -> np.ndarray:
        """The live surface triangles (``organ``'s only, when given) as the particles of
        their corners (F, 3)."""
        f = self.triangles
        return self.vertices["index"][f["vertices"][self.live_triangles(organ)], 0]

    def live_tets(self, organ: int) -> np.ndarray:
        """The rows of ``organ``'s live tets (a cut appends tets after every organ's)."""
        return np.flatnonzero(self.tet_alive & (self.organ_of[self.tets[:, 0]] == organ))

    def beside_wound(self, tets: np.ndarray) -> np.ndarray:
        """(T,) bool: whether each of ``tets`` has a corner in a tet a removal took
        (its faces there are under a marching-tetrahedra wound, which a cut leaves
        alone)."""
        wounded = np.zeros(len(self.rest), dtype=bool)
        wounded[self.tets[self.tet_removed].ravel()] = True
        return wounded[self.tets[tets]].any(axis=1)

    def surface_particles(self) -> np.ndarray:
        """Sorted particles the live surface follows: those its vertices are bound to
        (weights > 0; a wound vertex's kept particle)."""
        v = self.vertices
        live = np.flatnonzero(v["alive"][: v.used])
        return np.unique(v["index"][live][v["weight"][live] > 0.0])

    def topology(self, positions: np.ndarray | None = None) -> Topology:
        """The validator's view at the particle ``positions`` (N, 3) [m] (default: the
        rest shape). Wound vertices sit at a rotated offset from their kept
        particle: the view puts them at their rest place, so to check a deformed
        wound set its ``surface_position`` to the skinned surface."""
        v, f = self.vertices, self.triangles
        sizes = [len(m) for m in self.cluster_members]
        index, weight = v["index"][: v.used], v["weight"][: v.used]
        wound = v["cluster"][: v.used] >= 0
        at_rest = (weight[..., None] * self.rest[index]).sum(axis=1)
        at_rest[wound] = v["rest"][: v.used][wound]
        if positions is None:
            positions, surface = self.rest, at_rest
        else:
            surface = (weight[..., None] * positions[index]).sum(axis=1)
            surface[wound] = at_rest[wound]
        return Topology(
            rest_positions=self.rest,
            positions=positions,
            tets=self.tets,
            surface_index=index,
            surface_weight=weight,
            triangles=f["vertices"][: f.used],
            cluster_start=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            cluster_member=np.concatenate(self.cluster_members or [np.zeros(0, np.int64)]),
            organs=self.data.organs,
            particle_alive=self.particle_alive,
            tet_alive=self.tet_alive,
            triangle_alive=f["alive"][: f.used],
            cluster_alive=self.cluster_alive,
            vertex_alive=v["alive"][: v.used],
            triangle_organ=f["organ"][: f.used],
            vertex_organ=v["organ"][: v.used],
            surface_position=surface,
            rest_surface_position=at_rest,
            removed_volume=self.removed_volume,
            built_tets=len(self.data.tets),
        )

    # -- the update -----------------------------------------------------------------

    def remove(self, particles) -> TopologyChange:
        """Remove ``particles`` (indices; already removed ones are ignored) and all
        that goes with them (module docstring). Raises ``ValueError`` for particles
        of an organ that cannot be dissected."""
        particles = np.unique(np.asarray(particles, dtype=np.int64))
        if len(particles) and (particles.min() < 0 or particles.max() >= len(self.rest)):
            raise ValueError(f"particle indices must lie in [0, {len(self.rest)})")
        refused = np.unique(self.organ_of[particles][~self.cuttable[self.organ_of[particles]]])
        if len(refused):
            names = ", ".join(self.data.organs[k].name for k in refused)
            raise ValueError(f"organ(s) {names}: only organs of tets can lose particles")
        removed, dead_tets = self._kill(particles[self.particle_alive[particles]])
        if not len(removed):
            return TopologyChange()
        fragments = self._fragments(np.unique(self.tets[dead_tets]))
        if fragments:
            more, more_tets = self._kill(np.concatenate(fragments))
            removed, dead_tets = (
                np.concatenate([removed, more]),
                np.concatenate([dead_tets, more_tets]),
            )
        volume = float(tet_volumes(self.rest, self.tets[dead_tets]).sum())
        self.removed_volume += volume
        clusters = self._split_clusters(removed, self._corners(dead_tets))
        surface = self._rebuild_surface(removed)
        capped = self._cap_embedded(removed)
        for kind in ("triangles", "vertices") if capped else ():  # a reused slot is new
            new = np.union1d(surface[f"new_{kind}"], capped[f"new_{kind}"])
            dead = np.union1d(surface[f"dead_{kind}"], capped[f"dead_{kind}"])
            surface[f"new_{kind}"], surface[f"dead_{kind}"] = new, np.setdiff1d(dead, new)
        rebound = self._rebind(set(clusters.tolist()))
        return TopologyChange(
            removed_particles=removed,
            dead_tets=dead_tets,
            removed_volume=volume,
            clusters=clusters,
            rebound_vertices=rebound,
            fragments=[len(piece) for piece in fragments],
            **surface,
        )

    def split_tets(self, cut, tets: np.ndarray, rows: np.ndarray) -> TopologyChange:
        """Make a volumetric cut (:class:`~taichi_lap.dissection.tet_cut.TetCut` of the
        live ``tets`` of a directly bound organ, its new vertex j numbered
        ``len(self.rest) + j``) the topology, its new vertices taking the particle
        ``rows`` (reserve rows of the
        organ, :func:`~taichi_lap.preprocess.organs.add_cut_reserve`; their rest
        positions set here by the cut's weights):

        1. the split tets die and their sub-tets live (the rest volume stays);
        2. each new particle joins the clusters of the input particle whose side of
           the cut it is on, then clusters whose members the cut parted split as
           after a removal (:meth:`_split_clusters`);
        3. the surface triangles on the split tets' faces give way to the faces of
           the sub-tets that no other live tet shares (the cut's two sides and the
           pieces of the faces it crossed), their vertices bound directly.

        The change lists the clusters that gained members (``joined``)."""
        n = len(self.rest)
        rows = np.asarray(rows, dtype=np.int64)
        number = np.concatenate([np.arange(n), rows])  # cut numbering -> particle
        self.rest[rows] = cut.new_values(self.rest)
        self.particle_alive[rows] = True
        dead_tets = np.asarray(tets, dtype=np.int64)[cut.removed]
        added = number[cut.added]
        first_new = len(self.tets)
        self.tets = np.concatenate([self.tets, added])
        self.tet_alive[dead_tets] = False
        self.tet_alive = np.concatenate([self.tet_alive, np.ones(len(added), dtype=bool)])
        self.tet_removed = np.concatenate([self.tet_removed, np.zeros(len(added), dtype=bool)])
        self._index_tets()

        joined = self._join_sides(rows, np.asarray(cut.vertex_side, dtype=np.int64))
        clusters = self._split_clusters(np.zeros(0, dtype=np.int64), self._corners(dead_tets))
        surface = self._surface_of_cut(dead_tets, np.arange(first_new, len(self.tets)))
        rebound = self._rebind(set(clusters.tolist()))
        return TopologyChange(
            dead_tets=dead_tets,
            clusters=clusters,
            rebound_vertices=rebound,
            joined=joined,
            memberships_rebuilt=True,
            split_tets=len(cut.split),
            **surface,
        )

    def link_walls(self, pairs: np.ndarray, particles: np.ndarray):
        """Make ``pairs`` (P, 2) the graph of the organs whose clusters are surface
        particles (a wall, seed 000 §3.1: its surface edges and links through it),
        as built, before any cut of it; their ``particles``' clusters learn their
        parts as built over it (:meth:`_know_built_parts`)."""
        self._link_walls(pairs)
        self._know_built_parts(self.clusters_of(particles).tolist())

    def cut_wall(self, pairs, rows, side, removed, at) -> dict[str, np.ndarray]:
        """The clusters after a surface cut of a wall (its triangles, particles and
        rest positions already cut, :class:`~taichi_lap.dissection.sheet_cut.SheetCutter`):
        each new particle ``rows`` joins the clusters of the particle ``side`` whose
        side of the cut it is on, the ``removed`` particles leave theirs, the walls'
        graph becomes ``pairs`` (their live edges and links), and the clusters of the
        particles ``at`` the cut whose members it parted split into its connected
        pieces, as after a removal (:meth:`_split_clusters`). Returns the change's
        ``joined``, ``clusters`` and ``memberships_rebuilt``."""
        joined = self._join_sides(np.asarray(rows, np.int64), np.asarray(side, np.int64))
        self._link_walls(pairs)
        at = np.asarray(at, dtype=np.int64)
        clusters = self._split_clusters(np.asarray(removed, np.int64), at[self.particle_alive[at]])
        return {"joined": joined, "clusters": clusters, "memberships_rebuilt": True}

    def _link_walls(self, pairs):
        """Make ``pairs`` the walls' graph (:attr:`wall_pairs`) and index it."""
        self.wall_pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self._index_graph()

    def _join_sides(self, rows: np.ndarray, side: np.ndarray) -> np.ndarray:
        """New particles ``rows`` (a cut's) join every live cluster of the particle
        ``side`` whose side of the cut each is on, in its built part; returns the
        (cluster, particle) pairs joined."""
        which = rows_of(self.membership_start, side)
        owner = owners_of(self.membership_start, side)  # the new particle of each row
        joined_cluster = self.membership_cluster[which]
        live = self.cluster_alive[joined_cluster]
        owner, joined_cluster = owner[live], joined_cluster[live]
        order = np.argsort(joined_cluster, kind="stable")
        owner, joined_cluster = owner[order], joined_cluster[order]
        clusters, first = np.unique(joined_cluster, return_index=True)
        self._know_built_parts(clusters.tolist())
        for c, group in zip(clusters.tolist(), np.split(owner, first[1:])):
            members = self.cluster_members[c]
            by_particle = np.argsort(members)
            at = by_particle[np.searchsorted(members, side[group], sorter=by_particle)]
            self.cluster_members[c] = np.concatenate([members, rows[group]])
            self._built_parts[c] = np.concatenate([self._built_parts[c], self._built_parts[c][at]])
        self._index_memberships()
        return np.stack([joined_cluster, rows[owner]], 1).astype(np.int64)

    def _corners(self, tets: np.ndarray) -> np.ndarray:
        """The live particles at the corners of ``tets``."""
        corners = np.unique(self.tets[tets])
        return corners[self.particle_alive[corners]]

    def _surface_of_cut(self, dead_tets: np.ndarray, new_tets: np.ndarray) -> dict:
        """Step 3 of :meth:`split_tets`: the triangles on the faces of ``dead_tets``
        go, the faces of ``new_tets`` no other live tet shares come, and so do those of
        live tets that a dead tet shared and none does now (where the cut runs along a
        face, through snapped vertices), each corner the vertex its particle is bound
        to (made where it has none)."""
        f, v = self.triangles, self.vertices

        def keys(faces):
            return face_keys(faces, len(self.rest))

        live = self.live_triangles()
        own = (v["kept"][f["vertices"][live]] < 0).all(axis=1)  # not a wound's
        live = live[own & self.dissectable[f["organ"][live]]]
        parent_keys = keys(self.tets[dead_tets][:, TET_FACES].reshape(-1, 3))
        on_parent = np.isin(keys(v["index"][f["vertices"][live], 0]), parent_keys)
        dead = live[on_parent]
        corners = np.unique(self.tets[np.concatenate([new_tets, dead_tets])])
        near = np.unique(self.particle_tet[rows_of(self.tet_start, corners)])
        near = near[self.tet_alive[near]]
        faces = self.tets[near][:, TET_FACES].reshape(-1, 3)
        near_keys = keys(faces)
        distinct, count = np.unique(near_keys, return_counts=True)
        single = count[np.searchsorted(distinct, near_keys)] == 1
        # a face of a tet the cut kept that a dead tet shared: the cut runs along it
        from_new = np.repeat(np.isin(near, new_tets), 4) | np.isin(near_keys, parent_keys)
        faces = faces[single & from_new]

        f["alive"][dead] = False
        old_vertices = f["vertices"][dead].ravel()
        np.subtract.at(v["uses"], old_vertices, 1)
        f.release(dead)
        particles = np.unique(faces)
        lacking = particles[self.particle_vertex[particles] < 0]
        made = v.take(len(lacking))
        v["index"][made] = 0
        v["index"][made, 0] = lacking
        v["weight"][made] = (1.0, 0.0, 0.0, 0.0)
        v["organ"][made] = self.organ_of[lacking]
        v["alive"][made] = True
        v["rest"][made] = self.rest[lacking]
        v["cluster"][made], v["kept"][made], v["cut"][made] = -1, -1, -1
        v["uses"][made] = 0
        self.particle_vertex[lacking] = made
        slots = f.take(len(faces))
        f["vertices"][slots] = self.particle_vertex[faces]
        f["organ"][slots] = self.organ_of[faces[:, 0]]
        f["alive"][slots] = True
        np.add.at(v["uses"], f["vertices"][slots].ravel(), 1)

        gone = np.unique(old_vertices)
        gone = gone[v["alive"][gone] & (v["uses"][gone] == 0)]
        v["alive"][gone] = False
        self.particle_vertex[v["index"][gone, 0]] = -1
        v.release(gone)
        for t in dead.tolist():
            self.original_pieces.pop(t, None)
        self.original_pieces.update({int(t): [int(t)] for t in slots})
        # the originals that keep pieces keep their corners (a clipped one's slot may
        # hold another triangle by now); one a removal took whole leaves the index
        listed = np.fromiter(self.original_pieces, dtype=np.int64, count=len(self.original_pieces))
        kept = np.isin(self.original, listed) & ~np.isin(self.original, slots)
        self._index_originals(
            np.concatenate([self.original[kept], slots]),
            np.concatenate([self.original_particles[kept], v["index"][f["vertices"][slots], 0]]),
        )
        return dict(
            dead_triangles=np.setdiff1d(dead, slots),
            new_triangles=slots,
            dead_vertices=np.setdiff1d(gone, made),
            new_vertices=made,
        )

    def _kill(self, particles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Particles die with their tets, then the orphans those leave."""
        removed, dead = [], []
        while len(particles):
            self.particle_alive[particles] = False
            removed.append(particles)
            tets = np.unique(self.particle_tet[rows_of(self.tet_start, particles)])
            tets = tets[self.tet_alive[tets]]
            self.tet_alive[tets] = False
            self.tet_removed[tets] = True
            dead.append(tets)
            np.subtract.at(self.live_tets_of, self.tets[tets].ravel(), 1)
            np.subtract.at(self.edge_live, self.tet_edge[tets].ravel(), 1)
            corners = np.unique(self.tets[tets])
            particles = corners[self.particle_alive[corners] & (self.live_tets_of[corners] == 0)]
        empty = np.zeros(0, dtype=np.int64)
        return np.concatenate(removed or [empty]), np.concatenate(dead or [empty])

    def _neighbours(self, nodes: np.ndarray, live: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(owner, other) of every tet edge at ``nodes``: the live ones, or with
        ``live=False`` every edge the model was built with."""
        rows = rows_of(self.adjacency_start, nodes)
        owner = nodes[owners_of(self.adjacency_start, nodes)]
        if not live:
            return owner, self.adjacency_other[rows]
        keep = self.edge_live[self.adjacency_edge[rows]] > 0
        return owner[keep], self.adjacency_other[rows][keep]

    def _components(self, groups: list[np.ndarray], live: bool = True) -> list[np.ndarray]:
        """Connected components of the tet graph (live edges, or as built) within each
        group of particles: a label per particle of each group (labels are distinct
        across groups). One graph holds all groups, so many small clusters cost one
        search."""
        if not groups:
            return []
        sizes = [len(g) for g in groups]
        nodes = np.concatenate(groups)
        group = np.repeat(np.arange(len(groups)), sizes)
        distinct, slot = np.unique(nodes, return_inverse=True)
        node_at = np.full((len(groups), len(distinct)), -1, dtype=np.int64)
        node_at[group, slot] = np.arange(len(nodes))  # (group, particle) -> its node
        slot_of = self._slot
        slot_of[distinct] = np.arange(len(distinct))
        rows = rows_of(self.adjacency_start, nodes)
        owner = owners_of(self.adjacency_start, nodes)
        if live:
            keep = self.edge_live[self.adjacency_edge[rows]] > 0
            rows, owner = rows[keep], owner[keep]
        other = slot_of[self.adjacency_other[rows]]
        slot_of[distinct] = -1
        owner, other = owner[other >= 0], other[other >= 0]
        b = node_at[group[owner], other]
        a, b = owner[b >= 0], b[b >= 0]
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(nodes), len(nodes)))
        labels = connected_components(graph, directed=False)[1]
        return np.split(labels, np.cumsum(sizes)[:-1])

    def _stays_connected(self, members: np.ndarray, seeds: np.ndarray) -> bool:
        """Whether the live ``members`` of a cluster are as connected as before a
        removal, given the ``seeds``, its members at the tets that died: they still
        reach each other within FRAGMENT_DEPTH live edges inside the cluster (a path
        broken by the removal entered and left the dead tets through them)."""
        inside = self._mask
        inside[members] = True
        connected = self._seeds_joined(seeds, inside)
        inside[members] = False
        return connected

    def _seeds_joined(self, seeds: np.ndarray, inside=None, more_than: int = 0) -> bool:
        """Whether ``seeds`` all reach each other within FRAGMENT_DEPTH live edges
        (through particles the mask ``inside`` holds, when given), in a piece of more
        than ``more_than`` particles: breadth-first from the first seed, stopping as
        soon as both hold."""
        if len(seeds) <= 1 and not more_than:
            return True
        reached = self._reached
        reached[seeds[0]] = True
        frontier, visited, count = seeds[:1], [seeds[:1]], 1
        joined = False
        for _ in range(FRAGMENT_DEPTH):
            _, other = self._neighbours(frontier)
            other = other[~reached[other]]
            frontier = np.unique(other if inside is None else other[inside[other]])
            reached[frontier] = True
            visited.append(frontier)
            count += len(frontier)
            joined = bool(reached[seeds].all()) and count > more_than
            if joined or not len(frontier):
                break
        reached[np.concatenate(visited)] = False
        return joined

    def _fragments(self, corners: np.ndarray) -> list[np.ndarray]:
        """Pieces of live tissue cut off near the dead tets' ``corners``: breadth-first
        over live tet edges for FRAGMENT_DEPTH steps; the components of what was
        reached that reach no further, hold at most FRAGMENT_PARTICLES particles and
        no pinned one."""
        seeds = corners[self.particle_alive[corners]]
        if len(seeds) and self._seeds_joined(seeds, more_than=FRAGMENT_PARTICLES):
            return []  # every piece the search could find holds all seeds: too large
        reached = np.zeros(len(self.rest), dtype=bool)
        reached[seeds] = True
        frontier, order = seeds, [seeds]
        for _ in range(FRAGMENT_DEPTH):
            _, other = self._neighbours(frontier)
            frontier = np.unique(other[~reached[other]])
            if not len(frontier):
                break
            reached[frontier] = True
            order.append(frontier)
        region = np.sort(np.concatenate(order))
        if not len(region):
            return []
        (labels,) = self._components([region])
        reaching_on = set(labels[np.searchsorted(region, frontier)].tolist())
        pieces = (
            region[labels == label] for label in range(labels.max() + 1) if label not in reaching_on
        )
        return [
            piece
            for piece in pieces
            if len(piece) <= FRAGMENT_PARTICLES and not self.pinned[piece].any()
        ]

    def _split_clusters(self, removed: np.ndarray, corners: np.ndarray) -> np.ndarray:
        """Drop the ``removed`` members of their clusters and split the clusters whose
        built parts came apart at the live particles ``corners`` (those of the tets
        that died, or where a wall was cut: a cluster can lose an edge without
        losing a member); returns the changed clusters, new ones included."""
        is_corner = self._corner
        is_corner[corners] = True
        candidates = self.clusters_of(np.concatenate([removed, corners]))
        changed, pending = [], []
        for c in candidates[self.cluster_alive[candidates]].tolist():
            members = self.cluster_members[c]
            alive = self.particle_alive[members]
            if not alive.all():
                changed.append(c)
                self.cluster_members[c] = members[alive]
                if c in self._built_parts:
                    self._built_parts[c] = self._built_parts[c][alive]
                self.cluster_alive[c] = alive.any()
            members = self.cluster_members[c]
            if len(members) and not (
                len(members) > LOCAL_CHECK_MEMBERS
                and self._stays_connected(members, members[is_corner[members]])
            ):
                pending.append(c)
        is_corner[corners] = False
        self._know_built_parts(pending)
        now = self._components([self.cluster_members[c] for c in pending])
        new = []
        for c, labels in zip(pending, now):
            members, built = self.cluster_members[c], self._built_parts[c]
            keep = np.zeros(len(members), dtype=bool)
            for part in np.unique(built):
                keep[
                    (built == part) & (labels == self._kept_piece(members, built, labels, part))
                ] = True
            if keep.all():
                continue
            self.cluster_members[c] = members[keep]
            self._built_parts[c] = built[keep]
            for piece in np.unique(labels[~keep]):
                new.append(self._add_cluster(c, members[~keep & (labels == piece)]))
            changed.append(c)
        return np.unique(np.array(changed + new, dtype=np.int64))

    def _know_built_parts(self, clusters: list[int]):
        """Label the live members of each of ``clusters`` by the part of the cluster as
        built they are in (connected over the tet edges as built), where not yet
        known: one component search for all of them."""
        unknown = [c for c in clusters if c not in self._built_parts]
        built = self._components([self.built_members(c) for c in unknown], live=False)
        for c, labels in zip(unknown, built):
            self._built_parts[c] = labels[self.particle_alive[self.built_members(c)]]

    def _kept_piece(self, members, built, labels, part) -> int:
        """The label of the piece of built ``part`` that stays in its cluster when the
        part came apart: in a cluster joining organs (several built parts, seed 002
        §3.2) the piece nearest at rest to the other parts (where the organs touch),
        else the largest."""
        mine = built == part
        pieces, counts = np.unique(labels[mine], return_counts=True)
        if len(pieces) == 1 or mine.all():
            return int(pieces[counts.argmax()])
        gap, _ = cKDTree(self.rest[members[~mine]]).query(self.rest[members[mine]])
        return int(labels[mine][np.argmin(gap)])

    def _add_cluster(self, parent: int, members: np.ndarray) -> int:
        """A new cluster of ``members`` (all leaving ``parent``); its index."""
        c = len(self.cluster_members)
        self.cluster_parent[c] = parent
        self.cluster_members.append(members)
        self.cluster_alive = np.append(self.cluster_alive, True)
        self._built_parts[c] = np.zeros(len(members), dtype=np.int64)
        rows = rows_of(self.membership_start, members)
        rows = rows[self.membership_cluster[rows] == parent]
        self.membership_cluster[rows] = c
        return c

    def _rebuild_surface(self, removed: np.ndarray) -> dict[str, np.ndarray]:
        """Marching tetrahedra on the tets and surface triangles at ``removed``:
        their old triangles go, the new ones take free slots."""
        dead_label = ~self.particle_alive
        tets = np.unique(self.particle_tet[rows_of(self.tet_start, removed)])
        tets = tets[self.tet_removed[tets] & self.dissectable[self.organ_of[self.tets[tets, 0]]]]
        originals = np.unique(self.particle_original[rows_of(self.original_start, removed)])
        old = [s for t in tets.tolist() for s in self.tet_wound.pop(t, [])]
        old += [
            s for t in originals.tolist() for s in self.original_pieces.pop(int(self.original[t]))
        ]
        old = np.array(old, dtype=np.int64)
        wound, wound_tet = wound_triangles(self.tets[tets], dead_label)
        clipped, clipped_from = clipped_triangles(self.original_particles[originals], dead_label)
        named = np.concatenate([wound, clipped])
        organ = self.organ_of[named[:, 0, 0]]

        f, v = self.triangles, self.vertices
        f["alive"][old] = False
        old_vertices = f["vertices"][old].ravel()
        np.subtract.at(v["uses"], old_vertices, 1)
        f.release(old)
        vertices, new_vertices = self._name_vertices(named)
        slots = f.take(len(named))
        f["vertices"][slots] = vertices
        f["organ"][slots] = organ
        f["alive"][slots] = True
        np.add.at(v["uses"], vertices.ravel(), 1)
        for slot, t in zip(slots[: len(wound)].tolist(), tets[wound_tet].tolist()):
            self.tet_wound.setdefault(t, []).append(slot)
        pieces_of = self.original[originals[clipped_from]]
        for slot, t in zip(slots[len(wound) :].tolist(), pieces_of.tolist()):
            self.original_pieces.setdefault(t, []).append(slot)

        touched = np.unique(np.concatenate([old_vertices, vertices.ravel()]))
        dead = touched[v["alive"][touched] & (v["uses"][touched] == 0)]
        v["alive"][dead] = False
        wound = dead[v["cluster"][dead] >= 0]
        for key in zip(v["kept"][wound].tolist(), v["cut"][wound].tolist()):
            del self.wound_vertex[key]
        v["cluster"][dead] = -1
        own = dead[(v["weight"][dead, 0] == 1.0) & (v["kept"][dead] < 0)]  # a particle's own
        self.particle_vertex[v["index"][own, 0]] = -1
        v.release(dead)
        return dict(
            dead_triangles=np.setdiff1d(old, slots),
            new_triangles=slots,
            dead_vertices=np.setdiff1d(dead, new_vertices),
            new_vertices=new_vertices,
        )

    def _triangles_at(self, vertex: int) -> list[int]:
        """Live triangles of an embedded surface at ``vertex`` (as built, and caps;
        a slot reused since is left out: it no longer holds the vertex)."""
        at = self.cap_triangles_at.get(vertex, [])
        if vertex + 1 < len(self.embedded_triangle_start):  # a vertex as built
            a, b = self.embedded_triangle_start[vertex], self.embedded_triangle_start[vertex + 1]
            at = self.embedded_triangle[a:b].tolist() + at
        f = self.triangles
        return sorted({t for t in at if f["alive"][t] and vertex in f["vertices"][t]})

    def _cap_embedded(self, removed: np.ndarray) -> dict[str, np.ndarray]:
        """Embedded surfaces at ``removed`` (module docstring, step 5): the vertices
        bound to a removed particle die with their triangles; every edge a dying
        triangle shares with a live one is on a hole, the holes' loops are capped
        (:func:`fan_arcs`) and a vertex left in no triangle dies. Returns the
        triangles and vertices it changed (empty when no embedded surface lost any)."""
        v, f = self.vertices, self.triangles
        caps = [s for i in removed.tolist() for s in self.cap_vertices_of.pop(i, [])]
        dying = np.unique(
            np.concatenate([self.embedded_vertex[rows_of(self.embedded_start, removed)], caps])
        ).astype(np.int64)
        dying = dying[v["alive"][dying] & self.embedded[v["organ"][dying]]]  # not reused
        if not len(dying):
            return {}
        dead = sorted({t for s in dying.tolist() for t in self._triangles_at(s)})
        dead_set, dying_set = set(dead), set(dying.tolist())
        rim = []  # the caps' edges: a dying triangle's edges whose twin lives
        for t in dead:
            corners = f["vertices"][t].tolist()
            for k in range(3):
                a, b = corners[k], corners[(k + 1) % 3]
                if a in dying_set or b in dying_set:
                    continue
                twins = set(self._triangles_at(a)) & set(self._triangles_at(b))
                if twins - dead_set:
                    rim.append((a, b))
        dead = np.array(dead, dtype=np.int64)
        f["alive"][dead] = False
        old_vertices = f["vertices"][dead].ravel()
        np.subtract.at(v["uses"], old_vertices, 1)
        f.release(dead)
        made: list[int] = []

        def new_vertex(arc: list[int]) -> int:
            made.append(self._cap_vertex(v["rest"][arc].mean(axis=0), int(v["organ"][arc[0]])))
            return made[-1]

        caps = [t for loop in boundary_loops(rim) for t in fan_arcs(loop, new_vertex)]
        slots = f.take(len(caps))
        if len(caps):
            corners = np.array(caps, dtype=np.int64)
            f["vertices"][slots] = corners
            f["organ"][slots] = v["organ"][corners[:, 0]]
            f["alive"][slots] = True
            np.add.at(v["uses"], corners.ravel(), 1)
            for slot, corner in zip(slots.tolist(), corners.tolist()):
                for s in corner:
                    self.cap_triangles_at.setdefault(s, []).append(slot)
        touched = np.unique(old_vertices)
        gone = touched[v["alive"][touched] & (v["uses"][touched] == 0)]
        v["alive"][gone] = False
        v["cluster"][gone] = -1
        v.release(gone)
        made = np.array(made, dtype=np.int64)
        return dict(
            dead_triangles=np.setdiff1d(dead, slots),
            new_triangles=slots,
            dead_vertices=np.setdiff1d(gone, made),
            new_vertices=made,
        )

    def _cap_vertex(self, rest: np.ndarray, organ: int) -> int:
        """A cap's new vertex at ``rest`` [m]: bound, as a wound vertex is, to the
        nearest live particle of ``organ`` with its rest offset (its cluster is chosen
        by :meth:`_rebind`); it dies with that particle."""
        particles = np.arange(*self.data.organs[organ].particles)
        particles = particles[self.particle_alive[particles]]
        kept = int(particles[np.argmin(((self.rest[particles] - rest) ** 2).sum(axis=1))])
        v = self.vertices
        vertex = int(v.take(1)[0])
        v["index"][vertex] = kept
        v["weight"][vertex] = (1.0, 0.0, 0.0, 0.0)
        v["organ"][vertex] = organ
        v["alive"][vertex] = True
        v["rest"][vertex] = rest
        v["kept"][vertex], v["cut"][vertex], v["cluster"][vertex] = kept, -1, -1
        v["uses"][vertex] = 0
        self.cap_vertices_of.setdefault(kept, []).append(vertex)
        return vertex

    def _name_vertices(self, named: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertex slots of the corners ``named`` (K, 3, 2): a kept corner's own
        vertex, a cut edge's wound vertex (made where it is new); and the new ones."""
        pairs = named.reshape(-1, 2)
        out = self.particle_vertex[pairs[:, 0]].copy()
        cut = pairs[:, 0] != pairs[:, 1]
        keys, inverse = np.unique(pairs[cut], axis=0, return_inverse=True)
        slots = np.array(
            [self.wound_vertex.get((k, r), -1) for k, r in keys.tolist()], dtype=np.int64
        )
        fresh = np.flatnonzero(slots < 0)
        v = self.vertices
        made = v.take(len(fresh))
        slots[fresh] = made
        kept, removed = keys[fresh, 0], keys[fresh, 1]
        v["index"][made] = 0
        v["index"][made, 0], v["index"][made, 1] = kept, removed
        v["weight"][made] = 0.0
        v["weight"][made, 0] = 1.0  # follows the kept particle (and its cluster's rotation)
        v["organ"][made] = self.organ_of[kept]
        v["alive"][made] = True
        v["rest"][made] = self.rest[kept] + CUT_POINT * (self.rest[removed] - self.rest[kept])
        v["kept"][made] = kept
        v["cut"][made] = removed
        v["cluster"][made] = -1  # bound by _rebind
        v["uses"][made] = 0
        for vertex, key in zip(made.tolist(), keys[fresh].tolist()):
            self.wound_vertex[tuple(key)] = vertex
        out[cut] = slots[inverse.reshape(-1)]
        return out.reshape(-1, 3), made

    def _rebind(self, clusters: set[int]) -> np.ndarray:
        """Skin every wound vertex that is new or followed one of ``clusters`` to
        the nearest (by rest centre) live cluster of its kept particle, an organ-wide
        one (over LOCAL_CHECK_MEMBERS) only where there is no other; returns them."""
        v = self.vertices
        used = np.arange(v.used)
        wound = used[v["alive"][: v.used] & (v["kept"][: v.used] >= 0)]
        bound = v["cluster"][wound]
        stale = wound[(bound < 0) | np.isin(bound, list(clusters))]
        if not len(stale):
            return stale
        kept = v["kept"][stale]
        rows = rows_of(self.membership_start, kept)
        owner = owners_of(self.membership_start, kept)
        candidate = self.membership_cluster[rows]
        live = self.cluster_alive[candidate]
        size = np.array([len(self.cluster_members[c]) for c in candidate.tolist()], dtype=np.int64)
        local = live & (size <= LOCAL_CHECK_MEMBERS)
        has_local = np.bincount(owner[local], minlength=len(stale)) > 0
        keep = local | (live & ~has_local[owner])
        owner, candidate = owner[keep], candidate[keep]
        distinct, which = np.unique(candidate, return_inverse=True)
        centers = self.rest_centers(distinct)[which]
        distance = ((centers - v["rest"][stale][owner]) ** 2).sum(axis=1)
        order = np.lexsort((distance, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        v["cluster"][stale[owner[first]]] = candidate[first]
        return stale

    def fit_mass(self, particles: np.ndarray) -> np.ndarray:
        """``particles``' weights in their clusters' fits now [kg]
        (:func:`~taichi_lap.preprocess.model_data.fit_weights`)."""
        return fit_weights(self.mass[particles], self.pinned[particles])

    def rest_centers(self, clusters: np.ndarray) -> np.ndarray:
        """(C, 3) [m] rest mass centres of the live members of ``clusters``."""
        members = [self.cluster_members[c] for c in clusters.tolist()]
        which = np.repeat(np.arange(len(members)), [len(m) for m in members])
        members = np.concatenate(members)
        mass = self.fit_mass(members)
        total = np.bincount(which, weights=mass, minlength=len(clusters))
        moment = [
            np.bincount(which, weights=mass * self.rest[members, a], minlength=len(clusters))
            for a in range(3)
        ]
        return np.stack(moment, axis=1) / np.maximum(total, 1e-30)[:, None]
