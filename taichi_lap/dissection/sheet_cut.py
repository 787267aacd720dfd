"""Cutting sheets, trusses and walls in a session (seed 000 §5.1-5.2, Alg. 3): an
instrument's cutting shapes swept between two frames cut the fascia, the surface of
a vessel or gland (a truss structure, §3.3) and a wall whose material makes it
``cuttable`` (surface particles in shape-matching clusters, §3.1, as the rectum's), and
their physics follows the cut.

:func:`~taichi_lap.dissection.surface_cut.cut_surface` decides on the host, at the
sheet's current positions, which faces go and which come; :class:`SheetCutter` makes
that the sheet's topology:

* a new vertex takes a particle row from the sheet's reserve (rows the model was
  built with, pinned and in nothing until taken,
  :func:`~taichi_lap.preprocess.organs.add_cut_reserve`); its position, rest position
  and velocity are its parents' by the cut's weights. A vertex the cut removes gives
  its particle row back. The mass the cut triangles held goes to the triangles that
  replace them, by area (:func:`masses_after_cut`): the sheet keeps its mass but for
  the kerf's and the fragments';
* the sheet's distance constraints are its edges and bending pairs again (seed 000
  §3.2: the constraints across the cut are gone, those along it are new), their rest
  lengths from the rest positions; a truss's are its edges again and the struts
  (Alg. 2) the cut left: a strut goes with either end, when the sweep passes through
  it, and when its ends are left in different pieces of the surface;
* a wall's new particles join the clusters of the particles beside them on their side
  of the cut, and the clusters the cut parts split into its connected pieces, as the
  clusters of a tet organ do (:meth:`~taichi_lap.dissection.removal.MutableTopology.cut_wall`).
  The graph they are split over is the wall's surface edges and its links through
  the wall (:func:`~taichi_lap.preprocess.truss.through_links`), which go as struts
  do: a slit in the outer skin alone leaves each cluster whole (links a sweep crosses
  without cutting the surface go, but clusters split only where a cut changes the
  surface);
* its relaxed long-range attachments (Eq. 3) are found again on the cut sheet: each
  vertex keeps its geodesically nearest anchors that its piece still holds, so a
  piece cut free hangs from nothing and falls;
* a small piece the cut leaves holding no anchor, which no grasper holds (a sliver
  of the kerf, :data:`FRAGMENT_TRIANGLES`), goes with the cut, and is reported;
* the surface rows, the drawn mesh and the tissue collision follow the triangles
  (:class:`~taichi_lap.dissection.device.DeviceTopology`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from taichi_lap.core.geometry import TriangleMesh
from taichi_lap.core.mesh import (
    element_pieces,
    in_box,
    masses_after_cut,
    pair_lengths,
    piece_count,
    rows_in,
    triangle_areas,
    unique_edges,
)
from taichi_lap.dissection.device import DeviceTopology
from taichi_lap.dissection.removal import TopologyChange
from taichi_lap.dissection.surface_cut import Sweep, cut_surface
from taichi_lap.kernels.collision.particle_contact import FREE
from taichi_lap.kernels.scatter import gather
from taichi_lap.preprocess.organs import CUT_SURFACES, CUT_WALLS, CUTTABLE_SHEETS
from taichi_lap.preprocess.sheets import bending_pairs, long_range_attachments
from taichi_lap.preprocess.truss import through_links

log = logging.getLogger("taichi_lap")

SHORTEST_REST = 1.0
"""Strain is measured over a gauge of at least this fraction of the sheet's median
edge as built: the short edges a cut makes would otherwise tear at an instrument's
slightest push (in the rectum's script the closing scissors stretch 1 mm kerf edges
threefold, 0.17 over the median edge)."""


def built_faces(data, organ: int) -> np.ndarray:
    """The triangles (F, 3) of ``organ``'s surface as built, as particles (its surface
    vertices are its particles)."""
    faces = np.asarray(data.surface_triangles).reshape(-1, 3)[slice(*data.organs[organ].triangles)]
    return np.asarray(data.surface_index).reshape(-1, 4)[faces, 0]


def built_edges(data, organ: int) -> np.ndarray:
    """The edges (E, 2) of ``organ``'s surface as built, as particle pairs."""
    return unique_edges(built_faces(data, organ))


def wall_links(data, organ: int) -> np.ndarray:
    """The links (L, 2) through ``organ``'s wall as built, as particle pairs
    (:func:`~taichi_lap.preprocess.truss.through_links` at rest)."""
    used, local = np.unique(built_faces(data, organ), return_inverse=True)
    mesh = TriangleMesh(np.asarray(data.rest_position)[used], local.reshape(-1, 3))
    return used[through_links(mesh)]


def median_edge(data, organ: int) -> float:
    """The median edge length [m] at rest of ``organ``'s surface as built."""
    edges = built_edges(data, organ)
    return float(np.median(pair_lengths(np.asarray(data.rest_position), edges)))


def built_struts(data, organ: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The struts ``organ`` was built with (seed 000 Alg. 2): its distance constraints
    that are not edges of its surface, as (pairs (S, 2), rest [m], stiffness)."""
    first, end = data.organs[organ].particles
    pairs = np.asarray(data.distance_pair).reshape(-1, 2)
    mine = np.flatnonzero((pairs[:, 0] >= first) & (pairs[:, 0] < end))
    strut = mine[~rows_in(np.sort(pairs[mine], axis=1), built_edges(data, organ))]
    return (
        np.sort(pairs[strut], axis=1),
        np.asarray(data.distance_rest)[strut],
        np.asarray(data.distance_stiffness)[strut],
    )


def struts_in_one_piece(struts, piece: np.ndarray):
    """The ``struts`` (pairs, rest, stiffness) of a truss whose two ends are alive in
    one piece of its cut surface (``piece``: each particle's, -1 where gone)."""
    ends = piece[struts[0]]
    keep = (ends[:, 0] >= 0) & (ends[:, 0] == ends[:, 1])
    return tuple(values[keep] for values in struts)


def struts_crossed(pairs: np.ndarray, sweep: Sweep, bounds, x: np.ndarray) -> np.ndarray:
    """Which struts (particle ``pairs`` at ``x`` [m]) ``sweep`` (within the box
    ``bounds``, :meth:`Sweep.bounds`) passes through: a point along the strut is inside
    it (the points no farther apart than the sweep's thinnest shape)."""
    near = in_box(x, pairs, *bounds)
    crossed = np.zeros(len(pairs), dtype=bool)
    if near.any():
        a, b = x[pairs[near, 0]], x[pairs[near, 1]]
        samples = int(np.ceil(np.linalg.norm(b - a, axis=1).max() / sweep.thickness)) + 1
        s = np.linspace(0.0, 1.0, samples)
        points = a[:, None] + s[None, :, None] * (b - a)[:, None]
        inside = sweep.distance(points.reshape(-1, 3)) < 0.0
        crossed[near] = inside.reshape(-1, samples).any(axis=1)
    return crossed


_NO_STRUTS = (np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0))

LRA_REACH_MARGIN = 1.25
"""A sheet's LRAs are looked for again after a cut within this factor of their longest
rest distance before it (:func:`~taichi_lap.preprocess.sheets.long_range_attachments`'s
``reach``; cuts lengthen the geodesics around them)."""

WALL_MIN_AREA = 0.01
"""A wall's cut makes no face smaller at rest than this fraction of its median triangle
as built: the jaws pressing into a wall cut it again and again where they rest, and the
sub-faces of sub-faces shrank to 1e-16 m^2 at rest, their particles' masses to 1e-14
kg; stretched by the jaws they were drawn as shards centimetres long, and one vertex
gathered more triangles than its row of incident triangles holds."""

FRAGMENT_TRIANGLES = 8
"""A piece of a cut sheet of at most this many triangles holding no anchor is a
fragment, removed with the cut (the slivers the kerf leaves between its edges)."""


@dataclass
class _Sheet:
    """One cuttable organ: its index, the particle rows its reserve still holds
    (taken from the end), the material of its constraints and its anchors (the
    pinned vertices; the LRA anchors of a sheet); a truss's struts left (particle
    pairs, rest lengths [m], stiffness; none for a sheet), or a wall's links through
    it (pairs, rest lengths, stiffness 0: not constraints)."""

    organ: int
    free: list[int]
    edge_stiffness: float
    bending_stiffness: float
    anchors_per_vertex: int
    anchors: np.ndarray
    tear_strain: float
    edge: float  # the median edge length at rest as built [m]
    struts: tuple[np.ndarray, np.ndarray, np.ndarray]
    is_sheet: bool  # a sheet (bending pairs, LRAs), not a truss (struts)
    is_wall: bool  # a wall (clusters, no constraints of its own)
    pieces: int  # its connected pieces of triangles now
    lra_reach: float = np.inf  # the guess at its LRAs' longest rest distance [m]
    spent: bool = False  # whether the reserve ran out (said once)
    gauges: tuple | None = None  # (model topology version, edges, gauge lengths [m])
    min_area: float = 0.0  # [m^2] at rest: faces a cut would make smaller than this go


class SheetCutter:
    """Cuts the sheets of a session's model (module docstring). ``materials`` are the
    scene organs' material tables (``edge_stiffness``, ``bending_stiffness``,
    ``lra_anchors`` of the cuttable ones). ``separations``: the organs the last
    :meth:`cut` or :meth:`tear` parted into more connected pieces than they had, with
    their pieces now (a sheet cut free of its attachment, a vessel divided: the
    topological facts a task's phases are judged on)."""

    def __init__(self, dissection: DeviceTopology, materials: list[dict]):
        self.dissection = dissection
        data = dissection.model.data
        self.mass = dissection.topology.mass  # set by DeviceTopology.set_particles
        self.separations: list[tuple[str, int]] = []
        self.sheets = []
        for k, organ in enumerate(data.organs):
            if not organ.reserve or organ.model not in CUT_SURFACES:
                continue
            first, end = organ.particles
            built = np.arange(first, end - organ.reserve)
            material = materials[k]
            is_sheet, is_wall = organ.model in CUTTABLE_SHEETS, organ.model in CUT_WALLS
            if is_sheet:  # a sheet's constraints that are not edges are its bending pairs
                struts = _NO_STRUTS
            elif is_wall:
                links = wall_links(data, k)
                rest = pair_lengths(np.asarray(data.rest_position), links)
                struts = (links, rest, np.zeros(len(links)))
            else:
                struts = built_struts(data, k)
            sheet = _Sheet(
                organ=k,
                free=list(range(end - 1, end - organ.reserve - 1, -1)),
                edge_stiffness=float(material.get("edge_stiffness", 0.0)),
                bending_stiffness=float(material.get("bending_stiffness", 0.0)),
                anchors_per_vertex=int(material.get("lra_anchors", 0)),
                anchors=built[np.asarray(data.pinned)[built]],
                tear_strain=float(material.get("tear_strain", 0.0)),
                edge=median_edge(data, k),
                struts=struts,
                is_sheet=is_sheet,
                is_wall=is_wall,
                pieces=piece_count(dissection.topology.live_faces(k)),
            )
            if is_wall:
                areas = triangle_areas(np.asarray(data.rest_position), built_faces(data, k))
                sheet.min_area = WALL_MIN_AREA * float(np.median(areas))
            self.sheets.append(sheet)
        self.walls = [sheet for sheet in self.sheets if sheet.is_wall]
        if self.walls:
            particles = np.concatenate(
                [np.unique(dissection.topology.live_faces(wall.organ)) for wall in self.walls]
            )
            dissection.topology.link_walls(self._wall_graph(), particles)

    def cut(
        self, sweep: Sweep, x: np.ndarray, v: np.ndarray, state
    ) -> list[tuple[str, TopologyChange]]:
        """Cut every sheet, truss and wall ``sweep`` reaches, with its particles at
        ``x`` moving at ``v`` (N, 3) [m, m/s]; write the changes to the model and
        ``state``; returns the organs' names and changes (none where nothing was
        cut)."""
        changes, self.separations = [], []
        bounds = low, high = sweep.bounds
        for sheet in self.sheets:
            record = self.dissection.model.data.organs[sheet.organ]
            if self.dissection.out_of_reach(sheet.organ, x, low, high):
                continue
            crossed = struts_crossed(sheet.struts[0], sweep, bounds, x)
            crossed_ends = np.unique(sheet.struts[0][crossed])
            sheet.struts = tuple(values[~crossed] for values in sheet.struts)
            change = self._cut_sheet(sheet, sweep, x, v, state, crossed_ends)
            if change is not None:
                changes.append((record.name, change))
            if (change is not None or crossed.any()) and not sheet.is_wall:
                self._write_constraints(sheet)
        return changes

    def _cut_sheet(
        self, sheet: _Sheet, sweep, x, v, state, crossed_ends: np.ndarray
    ) -> TopologyChange | None:
        topology = self.dissection.topology
        vertices, triangles = topology.vertices, topology.triangles
        rows = self.dissection.topology.live_triangles(sheet.organ)
        used, local = np.unique(triangles["vertices"][rows], return_inverse=True)
        particles = vertices["index"][used, 0]
        cut = cut_surface(x[particles], local.reshape(-1, 3), sweep)
        if cut.empty:
            return None
        count = len(used)
        kept = np.ones(len(rows), dtype=bool)
        kept[cut.removed] = False
        old_rest = topology.rest[particles]
        every_rest = np.concatenate([old_rest, cut.new_values(old_rest)])
        made_faces = cut.added[triangle_areas(every_rest, cut.added) >= sheet.min_area]
        faces = np.concatenate([local.reshape(-1, 3)[kept], made_faces])
        row_of = np.concatenate([rows[kept], np.full(len(made_faces), -1)])  # -1: made
        fragment, fragments, piece_count = self._fragments(sheet, faces, particles, state)
        dead_triangles = np.concatenate([rows[cut.removed], row_of[fragment & (row_of >= 0)]])
        added = faces[~fragment & (row_of < 0)]
        in_use = np.zeros(count + len(cut.vertex_parents), dtype=bool)
        in_use[faces[~fragment].ravel()] = True
        made = np.flatnonzero(in_use[count:])
        if not self._reserve_left(sheet, len(made)):
            return None
        new_particles = np.array([sheet.free.pop() for _ in made], dtype=np.int64)

        def blend(values):  # at the new vertices in use, by the cut's weights
            return cut.new_values(values[particles])[made]

        dead = ~kept  # the triangles cut away, and the kept ones of a fragment
        dead[kept] = fragment[: int(kept.sum())]
        old_mass, new_mass = masses_after_cut(
            every_rest,
            local.reshape(-1, 3),
            dead,
            added,
            self.mass[particles],
        )
        rest, mass = every_rest[count + made], new_mass[made]
        topology.rest[new_particles] = rest
        topology.particle_alive[new_particles] = True
        new_vertices = vertices.take(len(made))
        vertices["index"][new_vertices] = new_particles[:, None]
        vertices["weight"][new_vertices] = [1.0, 0.0, 0.0, 0.0]
        vertices["organ"][new_vertices] = sheet.organ
        vertices["alive"][new_vertices] = True
        vertices["rest"][new_vertices] = rest
        for name in ("cluster", "kept", "cut"):
            vertices[name][new_vertices] = -1
        dead_vertices = used[~in_use[:count]]
        vertices["alive"][dead_vertices] = False
        vertices.release(dead_vertices)
        dead_particles = particles[~in_use[:count]]
        topology.particle_alive[dead_particles] = False

        slot = np.full(len(in_use), -1, dtype=np.int64)
        slot[:count] = used
        slot[count + made] = new_vertices
        triangles["alive"][dead_triangles] = False
        np.subtract.at(vertices["uses"], triangles["vertices"][dead_triangles].ravel(), 1)
        triangles.release(dead_triangles)
        new_triangles = triangles.take(len(added))
        triangles["vertices"][new_triangles] = slot[added]
        triangles["organ"][new_triangles] = sheet.organ
        triangles["alive"][new_triangles] = True
        np.add.at(vertices["uses"], slot[added].ravel(), 1)

        self.dissection.set_particles(new_particles, rest, mass, blend(x), blend(v), state)
        changed = in_use[:count] & (old_mass != self.mass[particles])  # those at the cut
        self.dissection.set_masses(particles[changed], old_mass[changed])
        if len(sheet.struts[0]):
            pieces = element_pieces(faces[~fragment])
            piece_of = np.full(len(in_use), -1)
            piece_of[faces[~fragment].ravel()] = np.repeat(pieces, 3)
            piece = np.full(len(topology.rest), -1)
            piece[particles] = piece_of[:count]
            sheet.struts = struts_in_one_piece(sheet.struts, piece)
        clusters = {}
        if sheet.is_wall:  # its clusters follow the cut
            parents, weights = cut.vertex_parents[made], cut.vertex_weights[made]
            kept_weights = np.where(in_use[:count][parents], weights, -1.0)
            heaviest = parents[np.arange(len(made)), kept_weights.argmax(axis=1)]
            side = cut.vertex_side[made]
            beside = np.where(side >= 0, side, heaviest)
            beside = np.where(in_use[:count][beside], beside, heaviest)
            at = particles[np.unique(local.reshape(-1, 3)[cut.removed])]
            clusters = topology.cut_wall(
                self._wall_graph(),
                new_particles,
                particles[beside],
                dead_particles,
                np.concatenate([at, new_particles, crossed_ends]),
            )
        change = TopologyChange(
            removed_particles=dead_particles,
            dead_triangles=dead_triangles,
            new_triangles=new_triangles,
            dead_vertices=dead_vertices,
            new_vertices=new_vertices,
            fragments=fragments,
            **clusters,
        )
        self.dissection.apply(change, state)
        sheet.free.extend(int(p) for p in dead_particles[::-1])
        self._count_pieces(sheet, piece_count)
        return change

    def _count_pieces(self, sheet: _Sheet, pieces: int):
        """Take ``pieces`` as the sheet's connected pieces now; one more than before is
        a separation (:attr:`separations`)."""
        if pieces > sheet.pieces:
            self.separations.append((self.dissection.model.data.organs[sheet.organ].name, pieces))
        sheet.pieces = pieces

    def tear(self, x: np.ndarray, state) -> list[tuple[str, TopologyChange]]:
        """Tearing after Müller et al. 2007 ("Position based dynamics", the tearing of
        its cloth): in each sheet with a ``tear_strain``, the edge stretched most
        beyond it (|x_i - x_j| / L - 1, L at least :data:`SHORTEST_REST` of the
        sheet's median edge) splits one of its ends: a plane through that vertex,
        perpendicular to the edge, parts its triangles by the side their centroid lies
        on, and those on the edge's side get a copy of the vertex (a reserve row; the
        two share its mass and velocity, read from ``state``). One split per sheet and
        frame: a tear runs on where the strain concentrates next. The physics follows
        as after a cut. Returns the organ names and changes."""
        topology = self.dissection.topology
        out, self.separations = [], []
        for sheet in self.sheets:
            if sheet.tear_strain <= 0.0:
                continue
            edges, gauge = self._gauges(sheet)
            strain = pair_lengths(x, edges) / gauge - 1.0
            over = np.flatnonzero(strain > sheet.tear_strain)
            if not len(over):
                continue
            rows = topology.live_triangles(sheet.organ)
            faces = topology.live_faces(sheet.organ)
            for e in over[np.argsort(-strain[over])]:
                change = self._split(sheet, rows, faces, edges[e], x, state)
                if change is not None:
                    out.append((self.dissection.model.data.organs[sheet.organ].name, change))
                    self._write_constraints(sheet)
                    self._count_pieces(sheet, piece_count(topology.live_faces(sheet.organ)))
                    break
        return out

    def _gauges(self, sheet: _Sheet) -> tuple[np.ndarray, np.ndarray]:
        """The sheet's edges (particle pairs) and the lengths [m] :meth:`tear`
        measures their strain over, found again after each change of the model's
        topology."""
        version = self.dissection.model.topology_version
        if sheet.gauges is None or sheet.gauges[0] != version:
            edges = unique_edges(self.dissection.topology.live_faces(sheet.organ))
            rest = pair_lengths(self.dissection.topology.rest, edges)
            sheet.gauges = version, edges, np.maximum(rest, SHORTEST_REST * sheet.edge)
        return sheet.gauges[1:]

    def _split(self, sheet: _Sheet, rows, faces, edge, x, state) -> TopologyChange | None:
        """Split an end of ``edge`` (particles) by the plane through it perpendicular
        to the edge (:meth:`tear`); None where neither end can be split (pinned, or
        all its triangles on one side) or the reserve is spent."""
        topology = self.dissection.topology
        vertices, triangles = topology.vertices, topology.triangles
        for p, q in (edge, edge[::-1]):
            if p in sheet.anchors:
                continue
            around = (faces == p).any(axis=1)
            direction = x[q] - x[p]
            side = (x[faces[around]].mean(axis=1) - x[p]) @ direction > 0.0
            if side.all() or not side.any():
                continue
            if not self._reserve_left(sheet, 1):
                return None
            new = sheet.free.pop()
            mass = 0.5 * self.mass[p]
            self.mass[[p, new]] = mass
            topology.rest[new] = topology.rest[p]
            topology.particle_alive[new] = True
            slot_of_p = vertices["index"][:, 0] == p
            old_slot = int(np.flatnonzero(slot_of_p & vertices["alive"])[0])
            slot = vertices.take(1)
            for name in vertices.arrays:
                vertices[name][slot] = vertices[name][old_slot]
            vertices["index"][slot] = new
            moved = rows[around][side]
            corners = triangles["vertices"][moved]
            corners[corners == old_slot] = slot[0]
            triangles["vertices"][moved] = corners
            vertices["uses"][old_slot] -= len(moved)
            vertices["uses"][slot] = len(moved)
            both = np.array([p, new])
            velocity = np.tile(state.v[int(p)].to_numpy(), (2, 1))
            self.dissection.set_particles(
                both, topology.rest[both], self.mass[both], x[[p, p]], velocity, state
            )
            change = TopologyChange(new_triangles=moved, new_vertices=slot)
            self.dissection.apply(change, state)
            return change
        return None

    def _reserve_left(self, sheet: _Sheet, count: int) -> bool:
        """Whether ``count`` reserve rows are left; says once when they run out."""
        if count <= len(sheet.free):
            return True
        if not sheet.spent:
            sheet.spent = True
            log.warning(
                "%s: its reserve of %d particle rows for cuts is spent; cuts and tears "
                "that need more rows are not made",
                self.dissection.model.data.organs[sheet.organ].name,
                self.dissection.model.data.organs[sheet.organ].reserve,
            )
        return False

    def _fragments(self, sheet: _Sheet, faces: np.ndarray, particles: np.ndarray, state):
        """Which of the cut sheet's ``faces`` (vertices numbered as the cut numbers
        them, the first ``len(particles)`` those of ``particles``) belong to a
        fragment: a piece of at most :data:`FRAGMENT_TRIANGLES` triangles that holds
        no anchor and that no grasper holds (in ``state``: read only for such small
        pieces; a sliver left in the kerf, removed with the cut); the particle count
        of each fragment; and how many pieces are left."""
        pieces = element_pieces(faces)
        sizes = np.bincount(pieces)
        known = faces < len(particles)
        anchored = np.zeros(len(sizes), dtype=bool)
        anchor = np.zeros(faces.shape, dtype=bool)
        anchor[known] = np.isin(particles[faces[known]], sheet.anchors)
        anchored[pieces[anchor.any(axis=1)]] = True
        small = (sizes <= FRAGMENT_TRIANGLES) & ~anchored
        if small.any():
            candidates = faces[small[pieces]]
            candidates = np.unique(candidates[candidates < len(particles)])
            held = candidates[gather(state.grasp_tool, particles[candidates]) != FREE]
            anchored[pieces[np.isin(faces, held).any(axis=1)]] = True
            small &= ~anchored
        counts = [len(np.unique(faces[pieces == k])) for k in np.flatnonzero(small)]
        return small[pieces], counts, int((~small).sum())

    def _wall_graph(self) -> np.ndarray:
        """The walls' graph their clusters split over: the edges of their live
        triangles and the links through them the cuts left (particle pairs)."""
        live = self.dissection.topology.live_faces
        return np.concatenate(
            [unique_edges(live(wall.organ)) for wall in self.walls]
            + [wall.struts[0] for wall in self.walls]
        )

    def _write_constraints(self, sheet: _Sheet):
        """Make the sheet's constraints in the model those of its live triangles
        (:meth:`_constraints`)."""
        first, end = self.dissection.model.data.organs[sheet.organ].particles
        self.dissection.model.replace_constraints(first, end, *self._constraints(sheet))

    def _constraints(self, sheet: _Sheet) -> tuple[np.ndarray, ...]:
        """The sheet's edges and bending pairs (pairs, rest lengths [m], stiffness)
        and relaxed LRAs (particles, anchors, rest distances [m]) on its live
        triangles (module docstring)."""
        topology = self.dissection.topology
        live, local = np.unique(topology.live_faces(sheet.organ), return_inverse=True)
        local = local.reshape(-1, 3)
        edges = unique_edges(local)  # numbered as ``live``, whose order they keep
        bending = bending_pairs(local) if sheet.is_sheet else np.zeros((0, 2), np.int64)
        pairs = live[np.concatenate([edges, bending])]
        rest = pair_lengths(topology.rest, pairs)
        stiffness = np.repeat(
            [sheet.edge_stiffness, sheet.bending_stiffness], [len(edges), len(bending)]
        )
        strut_pairs, strut_rest, strut_stiffness = sheet.struts
        pairs = np.concatenate([pairs, strut_pairs])
        rest = np.concatenate([rest, strut_rest])
        stiffness = np.concatenate([stiffness, strut_stiffness])
        anchors = np.flatnonzero(np.isin(live, sheet.anchors))
        if not len(anchors) or not sheet.is_sheet:
            return pairs, rest, stiffness, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        mesh = TriangleMesh(topology.rest[live], local)
        lra = long_range_attachments(
            mesh, anchors, sheet.anchors_per_vertex, edges=edges, reach=sheet.lra_reach
        )
        sheet.lra_reach = LRA_REACH_MARGIN * float(lra.rest.max(initial=0.0)) or np.inf
        return pairs, rest, stiffness, live[lra.particle], live[lra.anchor], lra.rest
