"""Tissue collision (seed 000 §4): the pipeline that orders its stages. Surface
triangles of all organs meet each other and the tools, by adaptive circumspheres
(Eq. 4-6, lazy update §4.2.3, impulse response §4.3) or either baseline of §4.4
(bounding spheres, polygons).

:class:`TissueCollision` owns the per-triangle tables (:mod:`.surface_tables`), the
spatial hash and the margin pair lists (:mod:`.pair_lists`); the kernels of each stage
live in :mod:`taichi_lap.kernels.collision`: the broad phase, the spheres and their
phases, the polygon baseline, the response and the tool shapes. The solver calls
:meth:`TissueCollision.step` after every shape-matching pass (tissue pairs may be left
to the last pass of a substep: ``tissue=False``): it reads the predicted positions p,
the substep's start positions x, the goals and the tools' poses at the substep's
start and end, and moves p and sets ``collided`` of the particles under contacting
triangles.

Tools meet the drawn surface by the contact that holds
(:func:`~taichi_lap.kernels.collision.response.surface_tool`) whatever the method of
the tissue pairs, or, with ``method_tools``, by the method's own response (seed 000
compares the methods on a tool).
"""

from __future__ import annotations

import math
import time

import numpy as np
import taichi as ti

from taichi_lap.collision.pair_lists import FoundPairs, PairRows
from taichi_lap.collision.surface_tables import (
    SurfaceRows,
    corner_binding,
    first_corners,
    live_neighbours,
    organ_bodies,
    rest_tables,
    triangle_corner_tables,
)
from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, padded_rows
from taichi_lap.core.instruments import FAR, MAX_TOOLS
from taichi_lap.core.mesh import edge_neighbours
from taichi_lap.kernels.collision import broad_phase, response, spheres
from taichi_lap.kernels.collision.spatial_hash import SpatialHash
from taichi_lap.kernels.scatter import scatter


METHODS = {
    "circumsphere": spheres.CIRCUMSPHERE,
    "bounding_sphere": spheres.BOUNDING_SPHERE,
    "polygon": spheres.POLYGON,
}
PHASES = ("bounds", "hash", "pairs", "spheres", "detect")
"""Phases of :meth:`TissueCollision.step` timed with ``timing``."""

CELL_REACHES = 1.0
"""Default edge of the hash's cells, in reaches of a scan from the smallest triangle
(the largest rest broad radius + margin + slack). Measured on the liver at detail 0.1
(32k triangles), a full rescan on the CPU: 0.5 reaches 300 ms (many cells to visit),
1 reach 150 ms, 2 reaches 270 ms (many spheres to read).
"""
TOOL_PASSES = 2
"""Jacobi passes of the contact that holds in every collision step (PBD iterates its
projections, Müller et al. 2007 §3.2). One pass averages the pushes of the triangles
that share a corner, which under-resolves where several stretched triangles wrap a
thin shape: with 4 substeps and η on contact 0.7, a hook's 0.9 mm wire pressed 8 mm
into the test block and a grasper's 2.1 mm jaws pressed 20 mm ended inside it after
one pass (indent_ratio 0.22 and 0.41) and held after two (perf/bench_contact.py)."""
ROW_CAPACITY = 32
"""Partners per triangle the pair lists are first allocated for (the rectum's lists
hold up to ~29 while its wall settles). Lists that outgrow them are reallocated, and
every new list recompiles the collision kernels, which takes seconds."""


@ti.data_oriented
class TissueCollision:
    """Collision of a model's surface triangles (seed 000 §4).

    ``method``: ``"circumsphere"`` (Eq. 4-6), ``"bounding_sphere"`` (Mendoza and
    O'Sullivan 2006) or ``"polygon"`` (Ericson 2004 vertex-triangle and edge-edge).
    ``scale_phi`` φ (seed 000 §7: 3), ``safe_angle`` θ [rad] (π/6), ``lazy_delta`` δ of
    §4.2.3 (relative area change that triggers recomputing curvature and recovery);
    ``tissue_pairs`` tissue-tissue contacts (``self_collision``: also inside one organ);
    ``tools`` tool-triangle contacts (the tools' shapes are the Control's, the same the
    particle contacts of the solver's prediction use), ``method_tools`` by the
    method's response instead of the contact that holds; ``polygon_thickness`` [m] kept
    between tissue features by the polygon method. Broad phase
    (:mod:`taichi_lap.kernels.collision.broad_phase`):
    ``pair_margin`` [m] of the pair lists (default the median rest broad radius;
    triangles rescan after drifting a third of it), ``hash_slack`` [m] a sphere may
    drift from where the hash holds it (default the margin), ``rest_exclusion`` κ:
    pairs closer at rest than κ times the sum of their broad radii never collide when
    of one body (:func:`organ_bodies`) or not facing each other at rest (0: only
    adjacent triangles are skipped), ``cell_size`` [m] of the spatial hash (default
    :data:`CELL_REACHES` × (the largest rest broad radius + margin + slack), the
    reach of a scan from the smallest triangle; a scan from a larger one, or after
    triangles stretched, visits more cells).
    ``timing``: synchronise around :meth:`step` and record ``last_ms``, ``total_ms``,
    ``calls`` and ``phase_ms`` (cumulative per phase). These settings are compiled
    into the kernels: fixed per instance.
    """

    def __init__(
        self,
        model,
        *,
        method: str = "circumsphere",
        scale_phi: float = 3.0,
        safe_angle: float = math.pi / 6,
        lazy_delta: float = 0.05,
        tissue_pairs: bool = True,
        self_collision: bool = True,
        tools: bool = True,
        method_tools: bool = False,
        polygon_thickness: float = 1e-4,
        pair_margin: float | None = None,
        hash_slack: float | None = None,
        rest_exclusion: float = 2.0,
        cell_size: float | None = None,
        timing: bool = False,
    ):
        if method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        if not 0.0 < safe_angle < math.pi / 2 or scale_phi < 0.0 or lazy_delta < 0.0:
            raise ValueError("safe_angle must lie in (0, π/2), scale_phi and lazy_delta >= 0")
        if rest_exclusion < 0.0 or (pair_margin or 0.0) < 0.0 or (hash_slack or 0.0) < 0.0:
            raise ValueError("pair_margin, hash_slack and rest_exclusion must be >= 0")
        self.model = model
        self._options = dict(
            method=method,
            scale_phi=scale_phi,
            safe_angle=safe_angle,
            lazy_delta=lazy_delta,
            tissue_pairs=tissue_pairs,
            self_collision=self_collision,
            tools=tools,
            method_tools=method_tools,
            polygon_thickness=polygon_thickness,
            pair_margin=pair_margin,
            hash_slack=hash_slack,
            rest_exclusion=rest_exclusion,
            cell_size=cell_size,
            timing=timing,
        )
        self.method = METHODS[method]
        self.scale_phi, self.safe_angle = float(scale_phi), float(safe_angle)
        self.lazy_delta = float(lazy_delta)
        self.tissue_pairs, self.self_collision = bool(tissue_pairs), bool(self_collision)
        self.tools, self.method_tools = bool(tools), bool(method_tools)
        self.polygon_thickness = float(polygon_thickness)
        self.rest_exclusion = float(rest_exclusion)
        self.timing, self.last_ms, self.total_ms, self.calls = timing, 0.0, 0.0, 0
        self.phase_ms = dict.fromkeys(PHASES, 0.0)
        self._hashed, self._mark = False, 0.0
        data = model.data
        triangles = np.asarray(data.surface_triangles, dtype=np.int64).reshape(-1, 3)
        # the model's rows, spare ones included (a dissection writes them); the loops
        # run over the rows in use (row_count, vertex_rows)
        self.triangle_count = model.surface_triangle_count
        self.vertex_count = model.surface_vertex_count
        self.rows_in_use = len(triangles)
        rest = data.rest_surface()
        rest_sphere, rest_normal = rest_tables(rest, triangles)
        self.pair_margin = float(
            np.median(rest_sphere[:, 3])
            if pair_margin is None and len(triangles)
            else pair_margin or 0.0
        )
        self.hash_slack = self.pair_margin if hash_slack is None else float(hash_slack)
        self.rescan_drift = self.pair_margin / 3.0
        self._body = organ_bodies(data)
        tables = triangle_corner_tables(data)
        group = FieldGroup()  # one SNode tree: the tables, the hash and the pair lists
        self._init_fields(group, data, triangles, tables, rest_sphere, rest_normal)
        self._retired = []  # pair lists outgrown, freed with the rest by close()
        self.grid = self.rows = self.spare = self.found = None  # tissue pairs only
        if tissue_pairs:
            if cell_size is None:
                largest = max(float(rest_sphere[:, 3].max(initial=0.0)), 1e-5)
                cell_size = CELL_REACHES * (largest + self.pair_margin + self.hash_slack)
            f = max(self.triangle_count, 1)
            self.grid = SpatialHash(f, 1 << max(4, int(2 * f).bit_length()), cell_size, group)
            self.rows = PairRows(f, ROW_CAPACITY * f, group)
            self.spare = PairRows(f, ROW_CAPACITY * f, group)
            self.found = FoundPairs(ROW_CAPACITY // 2 * f, group)
        group.finalize()
        self._set_rows_in_use(len(triangles), len(data.surface_index))
        self._swapped = False  # rows and spare trade places at every listing
        self.reset(pairs=True)

    def _init_fields(
        self,
        group: FieldGroup,
        data,
        triangles: np.ndarray,
        tables: dict,
        rest_sphere: np.ndarray,
        rest_normal: np.ndarray,
    ):
        f, v = self.triangle_count, self.vertex_count
        self._group = group
        n = len(data.pinned)
        organ = np.zeros(len(triangles), dtype=np.int32)
        for k, record in enumerate(data.organs):
            organ[record.triangles[0] : record.triangles[1]] = k
        corner_inv_mass = tables["corner_inv_mass"]
        built = {  # what a dissection rewrites, as built; spare rows dead
            "tri_vertex": (triangles, 0),
            "tri_neighbour": (edge_neighbours(triangles), -1),
            "tri_organ": (organ, 0),
            "tri_body": (self._body[organ], 0),
            "tri_live": (np.ones(len(triangles), dtype=np.int32), 0),
            "rest_sphere": (rest_sphere, 0.0),
            "rest_normal": (rest_normal, 0.0),
            "tri_inv_mass": (corner_inv_mass.reshape(-1, 3).mean(axis=1), 0.0),
        }
        corners = {
            "corner_inv_mass": (corner_inv_mass, 0.0),
            "corner_owner": (tables["corner_owner"], 0),
            "corner_thickness": (tables["corner_thickness"], 0.0),
            "corner_built": (np.ones(3 * len(triangles), dtype=np.int32), 0),
        }
        self._built = {
            **{name: padded_rows(values, f, fill) for name, (values, fill) in built.items()},
            **{name: padded_rows(values, 3 * f, fill) for name, (values, fill) in corners.items()},
        }
        for name, values in self._built.items():
            kind = ti.i32 if values.dtype.kind in "iub" else ti.f32
            vector = values.shape[1] if values.ndim > 1 else 0
            setattr(self, name, group.field(kind, len(values), vector=vector, values=values))
        self._tri_vertex = self._built["tri_vertex"].astype(np.int64)  # host copy
        self._written = np.zeros(f, dtype=bool)  # rows a dissection wrote
        self.row_count = group.field(ti.i32, None)
        self.vertex_rows = group.field(ti.i32, None)
        self.broad_sphere = group.field(ti.f32, f, vector=4)
        self.ref_sphere = group.field(ti.f32, f, vector=4)
        self.hash_sphere = group.field(ti.f32, f, vector=4)
        self.moved = group.field(ti.i32, f)
        self.tool_held = group.field(ti.i32, f)
        self.active_list = group.field(ti.i32, f)
        self.active_count = group.field(ti.i32, None)
        self.touched_list = group.field(ti.i32, n)
        self.touched_count = group.field(ti.i32, None)
        self.particle_mark = group.field(ti.i32, n)
        rank = np.full(n, -1)
        rank[tables["bound_particle"]] = np.arange(len(tables["bound_particle"]))
        self.particle_rank = group.field(ti.i32, n, values=rank)
        self.broad = group.field(ti.i32, len(broad_phase.BROAD))
        for name in ("bound_particle", "particle_start", "particle_corner"):
            setattr(self, name, group.field(ti.i32, len(tables[name]), values=tables[name]))
        self.particle_weight = group.field(
            ti.f32, len(tables["particle_weight"]), values=tables["particle_weight"]
        )
        # the gather lists of the corners of rows a dissection wrote (rank -1: none);
        # a corner binds at most four particles
        self._written_particles = np.zeros(0, dtype=np.int64)
        self.written_rank = group.field(ti.i32, n, values=np.full(n, -1))
        self.written_start = group.field(ti.i32, n + 1)
        self.written_corner = group.field(ti.i32, 12 * f)
        self.written_weight = group.field(ti.f32, 12 * f)
        self.hermite = group.field(
            ti.f32, spheres.HERMITE_SAMPLES + 1, values=spheres.hermite_table()
        )
        self.tool_cull = group.field(ti.f32, MAX_TOOLS, vector=4)
        self.tool_cull_a = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_cull_axis = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.vertex_p = group.field(ti.f32, v, vector=3)
        self.vertex_x = group.field(ti.f32, v, vector=3)
        for name in (
            "bound_center",
            "displacement",
            "start_centroid",
            "start_normal",
            "normal",
            "sphere_center",
        ):
            setattr(self, name, group.field(ti.f32, f, vector=3))
        for name in (
            "bound_radius",
            "bound_reach",
            "sphere_radius",
            "sphere_cone",
            "area_last",
            "curvature",
            "curvature_factor",
            "recovery",
        ):
            setattr(self, name, group.field(ti.f32, f))
        self.sorted_sphere = group.field(ti.f32, f, vector=4)
        self.sorted_rest = group.field(ti.f32, f, vector=4)
        self.sorted_body = group.field(ti.i32, f)
        self.corner_delta = group.field(ti.f32, 3 * f, vector=3)
        self.corner_count = group.field(ti.i32, 3 * f)
        self.counter = group.field(ti.i32, len(spheres.COUNTERS))

    @property
    def serial(self) -> bool:
        """Whether its kernels loop serially (their loop_config): as its model's
        (:attr:`~taichi_lap.sim.model.Model.serial`)."""
        return self.model.serial

    def close(self):
        """Free the fields of the tables, the hash and the pair lists (Taichi then
        compiles every kernel again at its next launch: not on a frame's path)."""
        self._group.close()
        for owner in (self.grid, self.rows, self.spare, self.found, *self._retired):
            if owner is not None:
                owner.close()

    def _set_rows_in_use(self, triangles: int, vertices: int):
        """The rows the loops run over: ``triangles`` triangles, ``vertices`` vertices."""
        self.rows_in_use = int(triangles)
        self.row_count[None] = self.rows_in_use
        self.vertex_rows[None] = int(vertices)

    def rewrite(self, rows: np.ndarray, surface: SurfaceRows):
        """Follow a dissection (seed 002 §3.3: every consumer of the surface follows a
        topology change): the triangle ``rows`` it removed or wrote anew, as
        ``surface`` now holds them, collide as they are. Their tables (vertices,
        organ, rest sphere and normal, corner masses and thickness), the edge
        neighbours of them and of the triangles next to them, the owner corners of
        their vertices and the gather lists of every rewritten corner are written;
        they rescan their pairs and the hash is rebuilt at the next step, and the
        curvature of them and their neighbours is computed again. Only rows near the
        change and the rewritten corners' gather lists are touched."""
        rows = np.unique(np.asarray(rows, dtype=np.int64))
        if not len(rows):
            return
        if rows[-1] >= self.triangle_count:
            raise ValueError(
                f"surface row {rows[-1]} beyond the collision's {self.triangle_count} rows "
                "(a grown model needs a collision of its size: regrown)"
            )
        live = surface.live[: self.triangle_count]
        old_vertices = self._tri_vertex[rows]
        new_vertices = surface.triangles[rows].astype(np.int64)
        self._tri_vertex[rows] = new_vertices
        self._written[rows] = True
        organ = surface.organ[rows].astype(np.int64)
        rest_sphere, rest_normal = rest_tables(surface.rest, new_vertices)
        inv_mass, thickness = corner_binding(
            new_vertices,
            surface.index,
            surface.weight,
            surface.inverse_mass,
            surface.contact_radius,
        )
        broad_phase.write_triangle_rows(
            self,
            rows.astype(np.int32),
            new_vertices.astype(np.int32),
            np.stack([live[rows], organ, self._body[organ]], axis=1).astype(np.int32),
            np.concatenate([rest_sphere, rest_normal], axis=1).astype(np.float32),
            np.concatenate([inv_mass.reshape(-1, 3), thickness.reshape(-1, 3)], axis=1).astype(
                np.float32
            ),
        )
        nearby = live_neighbours(self._tri_vertex, live, surface.incident, rows[live[rows]])
        near = np.union1d(rows, nearby[nearby >= 0])
        neighbours = live_neighbours(self._tri_vertex, live, surface.incident, near)
        broad_phase.write_neighbours(self, near.astype(np.int32), neighbours.astype(np.int32))
        self._rewrite_owners(np.union1d(old_vertices.ravel(), new_vertices.ravel()), surface)
        self._set_rows_in_use(max(self.rows_in_use, int(rows[-1]) + 1), surface.vertex_rows)
        self._rewrite_gather(surface)

    def _rewrite_owners(self, vertices: np.ndarray, surface: SurfaceRows):
        """Owner corners (:func:`corner_owners`) of ``vertices``: every live corner at
        one of them (their incident rows list them all) is written."""
        triangles = surface.triangles_of(vertices)
        corner_vertex = self._tri_vertex[triangles].ravel()
        corner = (3 * triangles[:, None] + np.arange(3)).ravel()
        mine = np.isin(corner_vertex, vertices)  # all of their live corners are here
        owner = first_corners(corner_vertex[mine], corner[mine])
        scatter(self.corner_owner, corner[mine], owner.astype(np.int32))

    def _rewrite_gather(self, surface: SurfaceRows):
        """The gather lists of every live rewritten corner (particle -> corners bound
        to it with their weights), sorted by particle then corner: the response
        reads them beside the lists as built, whose rewritten corners it skips."""
        rows = np.flatnonzero(self._written & surface.live[: self.triangle_count])
        vertex = self._tri_vertex[rows].ravel()
        corner = np.repeat((3 * rows[:, None] + np.arange(3)).ravel(), 4)
        particle = surface.index[vertex].ravel()
        weight = surface.weight[vertex].ravel()
        keep = weight > 0.0
        particle, corner, weight = particle[keep], corner[keep], weight[keep]
        order = np.lexsort((corner, particle))
        particle, corner, weight = particle[order], corner[order], weight[order]
        distinct, first = np.unique(particle, return_index=True)
        gone = np.setdiff1d(self._written_particles, distinct)
        broad_phase.write_gather(
            self,
            gone.astype(np.int32),
            distinct.astype(np.int32),
            np.append(first, len(particle)).astype(np.int32),
            corner.astype(np.int32),
            weight.astype(np.float32),
        )
        self._written_particles = distinct

    def revive(self):
        """Collide the surface as built again (the model was put back as built)."""
        fields.write((getattr(self, name), values) for name, values in self._built.items())
        self._tri_vertex = self._built["tri_vertex"].astype(np.int64)
        self._written[:] = False
        scatter(
            self.written_rank, self._written_particles, np.full(len(self._written_particles), -1)
        )
        self._written_particles = np.zeros(0, dtype=np.int64)
        data = self.model.data
        self._set_rows_in_use(len(data.surface_triangles), len(data.surface_index))
        self.reset(pairs=True)

    def regrown(self, surface: SurfaceRows) -> TissueCollision:
        """A collision of the same settings sized for the model's rows after
        :meth:`~taichi_lap.sim.model.Model.grow`, holding the rows this one
        rewrote; this one is closed."""
        grown = TissueCollision(self.model, **self._options)
        grown.rewrite(np.flatnonzero(self._written), surface)
        self.close()
        return grown

    def reset(self, *, pairs: bool = False):
        """Forget the lazy-update state (every circumsphere is recomputed at the next
        step), e.g. after :meth:`State.reset`. The pair lists
        stay: each row holds the partners within the margin of where its triangle was
        when listed, wherever the state jumped since, and a triangle that is now
        elsewhere rescans at the next step, as after any drift. With ``pairs`` the
        lists and the hash are forgotten too (every triangle rescans, as in a new
        collision). Which triangles a tool's
        contact held is forgotten (the response reads it in the next step)."""
        cleared = [(self.area_last, 0.0), (self.tool_held, 0)]
        fields.fill(cleared + [(self.ref_sphere, FAR)] if pairs else cleared)
        if pairs:
            self._hashed = False
            if self._swapped:  # a reused collision lists in the order it first did
                self.rows, self.spare, self._swapped = self.spare, self.rows, False

    def prime(self, state, control):
        """List the pairs of every triangle at the current positions (p and x) now, e.g.
        at a session's start, rather than in the first step (seconds for the full
        liver's 58k triangles)."""
        if self.tissue_pairs:
            broad_phase.update_bounds(self.model, state, control, self)
            self._refresh_pairs()

    def update_spheres(self, state):
        """Every triangle's bounding and collision sphere (seed 000 §4.2) from p and x,
        detecting nothing (to look at them)."""
        spheres.update_spheres(self.model, state, self, True)

    def step(self, state, control, tissue: bool = True):
        """Detect and respond (module docstring): moves ``state.p`` and flags
        ``state.collided``; velocities follow from p - x in the solver's update. The
        tissue pairs are tested once, the contact that holds :data:`TOOL_PASSES` times.
        ``tissue=False`` leaves out the tissue pairs (tools only), e.g. for all but the
        last shape-matching pass of a substep."""
        start = None
        if self.timing:
            ti.sync()
            start = self._mark = time.perf_counter()
        broad_phase.update_bounds(self.model, state, control, self)
        self._lap("bounds")
        tissue = tissue and self.tissue_pairs
        if tissue:
            self._refresh_pairs()
            broad_phase.mark_active(self, self.rows)
        if self.active_count[None] == 0:  # nothing near any triangle: no sphere, no contact
            self._finish(start)
            return
        spheres.update_spheres(self.model, state, self, False)
        self._lap("spheres")
        if tissue and self.tools and not self.method_tools:  # tissue first: the tools win
            response.detect_and_respond(self.model, state, control, self, self.rows, 1, 0)
            response.detect_and_respond(self.model, state, control, self, self.rows, 0, 1)
        else:
            response.detect_and_respond(self.model, state, control, self, self.rows, int(tissue), 1)
        if self.tools and not self.method_tools:
            for _ in range(TOOL_PASSES - 1):
                response.detect_and_respond(self.model, state, control, self, self.rows, 0, 2)
        self._lap("detect")
        self._finish(start)

    def _finish(self, start: float | None):
        """The step's time into :attr:`last_ms` and the totals (``start``: when it began,
        None when not timing)."""
        if start is not None:
            self.last_ms = (time.perf_counter() - start) * 1e3
            self.total_ms += self.last_ms
            self.calls += 1

    def _refresh_pairs(self):
        """After :func:`kernels.collision.broad_phase.update_bounds`: rescan the triangles
        that drifted."""
        moved, stale = self.broad.to_numpy()[[broad_phase.B_MOVED, broad_phase.B_STALE]]
        if moved:
            self._list_pairs(bool(stale))

    def _list_pairs(self, stale: bool):
        """Broad phase of the moved triangles (:mod:`kernels.collision.broad_phase`): the hash
        is rebuilt when out of date, the moved rescan it, the rows are rebuilt; found
        pairs and rows that outgrow their arrays get larger ones (compiled once more)
        and the rescan runs again. The spare grows with the rows, so that both keep one
        capacity and a reused collision lists into the arrays its kernels were compiled
        for."""
        if stale or not self._hashed:
            self.grid.build(self.broad_sphere, self.rows_in_use)
            broad_phase.hold_spheres(self, self.grid)
            self._hashed = True
            self._lap("hash")
        while True:
            broad_phase.list_pairs(self, self.grid, self.found)
            broad_phase.count_rows(self, self.rows, self.spare, self.found)
            status = self.broad.to_numpy()
            found = int(status[broad_phase.B_FOUND])
            rows = int(status[broad_phase.B_ROWS])
            if found > self.found.capacity:
                self._retired.append(self.found)
                self.found = FoundPairs(2 * found)
            elif rows > self.spare.capacity:
                self._retired.append(self.spare)
                self.spare = PairRows(self.triangle_count, 2 * rows)
            else:
                break
        broad_phase.fill_rows(self, self.rows, self.spare, self.found)
        self.rows, self.spare = self.spare, self.rows
        self._swapped = not self._swapped
        if self.spare.capacity < self.rows.capacity:
            self._retired.append(self.spare)
            self.spare = PairRows(self.triangle_count, self.rows.capacity)
        self._lap("pairs")

    def _lap(self, phase: str):
        """With ``timing``: add the time since the last lap to ``phase_ms[phase]``."""
        if self.timing:
            ti.sync()
            now = time.perf_counter()
            self.phase_ms[phase] += (now - self._mark) * 1e3
            self._mark = now

    def counters(self) -> dict[str, int]:
        """Cumulative event counts (i32, wrapping: compare differences)."""
        return dict(zip(spheres.COUNTERS, self.counter.to_numpy().tolist()))
