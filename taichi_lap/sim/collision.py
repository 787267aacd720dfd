"""Tissue collision (seed 000 §4): surface triangles of all organs against each other
and against the tools, by adaptive circumspheres (Eq. 4-6, lazy update §4.2.3,
impulse response §4.3) or either baseline of §4.4 (bounding spheres, polygons).

:class:`TissueCollision` owns the per-triangle tables, the spatial hash and the margin
pair lists (:class:`PairRows`); the kernels live in :mod:`kernels.circumsphere`
(spheres, lazy update), :mod:`kernels.tissue_collision` (broad phase, phases and
response), :mod:`kernels.polygon_collision` and :mod:`kernels.tool_shapes`. A frame calls
:meth:`TissueCollision.begin_frame` once after the tools are placed, then
:meth:`TissueCollision.step` after every shape-matching pass (tissue pairs may be left
to the last pass of a substep: ``tissue=False``): it reads the predicted positions p,
the substep's start positions x and the goals, and moves p and sets ``collided`` of the
particles under contacting triangles.
"""

import logging
import math
import time

import numpy as np
import taichi as ti

from taichi_lap.kernels import circumsphere, tissue_collision
from taichi_lap.core.instruments import MAX_TOOLS
from taichi_lap.kernels.spatial_hash import SpatialHash
from taichi_lap.kernels.tool_shapes import (
    MAX_TOOL_SHAPES,
    SHAPE_CONTROL,
    SHAPE_JAWS,
    SHAPE_KINDS,
    ToolPose,
    push_particles_out_of_tools,
)
from taichi_lap.core.csr import incidence
from taichi_lap.core.fields import FieldGroup

log = logging.getLogger("taichi_lap")

METHODS = {
    "circumsphere": circumsphere.CIRCUMSPHERE,
    "bounding_sphere": circumsphere.BOUNDING_SPHERE,
    "polygon": circumsphere.POLYGON,
}
PHASES = ("bounds", "hash", "pairs", "spheres", "detect")
"""Phases of :meth:`TissueCollision.step` timed with ``timing``."""
REACH_FACTOR = 1.5
"""How much larger than the largest rest broad radius a triangle's broad sphere (its
radius plus its motion in a substep) may grow before its pairs may be missed; the
settled rectum stretches its largest triangles by up to 38 %."""
ROW_CAPACITY = 32
"""Partners per triangle the pair lists are first allocated for (the rectum's lists
hold up to ~29 while its wall settles). Lists that outgrow them are reallocated, and
every new list recompiles the collision kernels, which takes seconds."""
FAR = 1e9
"""Reference sphere of a triangle never listed [m]: any drift from it is a move."""


def shape_reach(kind: int, a: np.ndarray, b: np.ndarray, size: np.ndarray) -> float:
    """Distance [m] from the tool tip that holds a shape of the tool-frame table (0 for
    the shaft, the jaws and empty slots: the collision reads their reach from the
    Control)."""
    if kind == SHAPE_KINDS["sphere"]:
        return float(np.linalg.norm(a) + size[0])
    if kind == SHAPE_KINDS["capsule"]:
        return float(max(np.linalg.norm(a), np.linalg.norm(b)) + size[0])
    if kind == SHAPE_KINDS["box"]:
        return float(np.linalg.norm(a) + np.linalg.norm(size))
    return 0.0


def edge_neighbours(triangles: np.ndarray) -> np.ndarray:
    """(F, 3): the triangle across edge k = (v_k, v_k+1) of each triangle; -1 on a
    boundary or a non-manifold edge."""
    f = len(triangles)
    a = triangles.reshape(-1).astype(np.int64)
    b = np.roll(triangles, -1, axis=1).reshape(-1).astype(np.int64)
    key = np.minimum(a, b) * (int(triangles.max(initial=0)) + 1) + np.maximum(a, b)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    order = np.argsort(key, kind="stable")
    same = key[order[:-1]] == key[order[1:]]
    i, j = order[:-1][same], order[1:][same]
    manifold = counts[inverse[i]] == 2
    i, j = i[manifold], j[manifold]
    out = np.full(3 * f, -1, dtype=np.int64)
    out[i], out[j] = j // 3, i // 3
    return out.reshape(f, 3)


def broad_spheres(corners: np.ndarray) -> np.ndarray:
    """(F, 4) broad spheres of triangles ``corners`` (F, 3, 3) [m]: the centroid and the
    largest corner distance from it (:func:`kernels.tissue_collision.update_bounds`)."""
    center = corners.mean(axis=1)
    radius = np.linalg.norm(corners - center[:, None, :], axis=2).max(axis=1)
    return np.concatenate([center, radius[:, None]], axis=1)


def organ_bodies(data) -> np.ndarray:
    """Body index of each organ: organs that share a shape-matching cluster (joined, as
    seed 002's vessels are into the liver) are one body."""
    body = np.arange(len(data.organs))
    member_cluster = np.repeat(np.arange(data.cluster_count), np.diff(data.cluster_start))
    pairs = np.unique(np.stack([member_cluster, data.organ[data.cluster_member]], axis=1), axis=0)
    for c in np.flatnonzero(np.bincount(pairs[:, 0], minlength=data.cluster_count) > 1):
        joined = body[pairs[pairs[:, 0] == c, 1]]
        body[np.isin(body, joined)] = joined.min()
    return body


def triangle_corner_tables(data) -> dict[str, np.ndarray]:
    """Host tables binding triangle corners (3 t + k) to particles: the gather lists
    per particle (weights > 0 of the surface binding), the corners' inverse masses
    (Σ w m⁻¹ of the bound particles), and one owner corner per surface vertex."""
    corner_vertex = data.surface_triangles.reshape(-1)
    index = data.surface_index[corner_vertex]
    weight = data.surface_weight[corner_vertex]
    inv_mass = np.where(data.pinned, 0.0, 1.0 / np.maximum(data.mass, 1e-12))
    corner_inv_mass = (weight * inv_mass[index]).sum(axis=1)
    particle, corner = index.reshape(-1), np.repeat(np.arange(len(corner_vertex)), 4)
    keep = weight.reshape(-1) > 0.0
    bound = np.unique(particle[keep])
    rank = np.searchsorted(bound, particle[keep])
    start, rows = incidence(rank, len(bound))
    first = np.full(len(data.surface_index), len(corner_vertex))
    np.minimum.at(first, corner_vertex, np.arange(len(corner_vertex)))
    owner = first[corner_vertex] == np.arange(len(corner_vertex))
    return {
        "bound_particle": bound,
        "particle_start": start,
        "particle_corner": corner[keep][rows],
        "particle_weight": weight.reshape(-1)[keep][rows],
        "corner_inv_mass": corner_inv_mass,
        "corner_owner": owner.astype(np.int32),
    }


@ti.data_oriented
class PairRows:
    """Partner lists of ``triangles`` triangles in one array of ``capacity`` entries:
    row t is ``partner[start[t]:start[t + 1]]``, sorted (CSR); ``size``, ``cursor`` and
    ``block_start`` are scratch of the rebuild (:func:`kernels.tissue_collision.count_rows`)."""

    def __init__(self, triangles: int, capacity: int):
        group = FieldGroup()
        self.capacity = int(capacity)
        self.start = group.field(ti.i32, triangles + 1)
        self.size = group.field(ti.i32, triangles)
        self.cursor = group.field(ti.i32, triangles)
        self.block_start = group.field(ti.i32, -(-triangles // tissue_collision.ROW_BLOCK))
        self.partner = group.field(ti.i32, self.capacity)
        group.finalize()
        self._group = group


@ti.data_oriented
class FoundPairs:
    """Pairs found by one rescan (at most ``capacity``; ``count`` may say more)."""

    def __init__(self, capacity: int):
        group = FieldGroup()
        self.capacity = int(capacity)
        self.pair = group.field(ti.i32, self.capacity, vector=2)
        self.count = group.field(ti.i32, None)
        group.finalize()
        self._group = group


@ti.data_oriented
class TissueCollision:
    """Collision of a model's surface triangles (seed 000 §4).

    ``method``: ``"circumsphere"`` (Eq. 4-6), ``"bounding_sphere"`` (Mendoza and
    O'Sullivan 2006) or ``"polygon"`` (Ericson 2004 vertex-triangle and edge-edge).
    ``scale_phi`` φ (seed 000 §7: 3), ``safe_angle`` θ [rad] (π/6), ``lazy_delta`` δ of
    §4.2.3 (relative area change that triggers recomputing curvature and recovery);
    ``tissue_pairs`` tissue-tissue contacts (``self_collision``: also inside one organ);
    ``tools`` tool-triangle contacts; ``tool_particles`` also pushes particles out of
    the tools' shapes (off by default: the solver's prediction already pushes particles
    out of the Control capsules); ``polygon_thickness`` [m] kept between tissue
    features by the polygon method. Broad phase (:mod:`kernels.tissue_collision`):
    ``pair_margin`` [m] of the pair lists (default the median rest broad radius;
    triangles rescan after drifting a third of it), ``hash_slack`` [m] a sphere may
    drift from where the hash holds it (default the margin), ``rest_exclusion`` κ:
    pairs closer at rest than κ times the sum of their broad radii never collide when
    of one body (:func:`organ_bodies`) or not facing each other at rest (0: only
    adjacent triangles are skipped), ``cell_size`` [m] of the spatial hash (default
    2 × REACH_FACTOR × the largest rest broad radius + margin + slack: a triangle's
    broad radius plus its motion in a substep must stay under REACH_FACTOR × that
    largest radius, ``reach_bound``; steps where some do not are counted in
    ``oversize_steps`` and the first is logged as a warning).
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
        tool_particles: bool = False,
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
        self.method = METHODS[method]
        self.scale_phi, self.safe_angle = float(scale_phi), float(safe_angle)
        self.lazy_delta = float(lazy_delta)
        self.tissue_pairs, self.self_collision = bool(tissue_pairs), bool(self_collision)
        self.tools, self.tool_particles = bool(tools), bool(tool_particles)
        self.polygon_thickness = float(polygon_thickness)
        self.rest_exclusion = float(rest_exclusion)
        self.timing, self.last_ms, self.total_ms, self.calls = timing, 0.0, 0.0, 0
        self.oversize_steps = 0
        self.phase_ms = dict.fromkeys(PHASES, 0.0)
        self._begun, self._hashed, self._mark = False, False, 0.0
        data = model.data
        triangles = np.asarray(data.surface_triangles, dtype=np.int64).reshape(-1, 3)
        self.triangle_count, self.vertex_count = len(triangles), len(data.surface_index)
        rest = (data.surface_weight[..., None] * data.rest_position[data.surface_index]).sum(axis=1)
        corners = rest[triangles]
        rest_sphere = broad_spheres(corners)
        rest_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        rest_normal /= np.maximum(np.linalg.norm(rest_normal, axis=1, keepdims=True), 1e-30)
        self.pair_margin = float(
            np.median(rest_sphere[:, 3])
            if pair_margin is None and len(triangles)
            else pair_margin or 0.0
        )
        self.hash_slack = self.pair_margin if hash_slack is None else float(hash_slack)
        self.rescan_drift = self.pair_margin / 3.0
        self.reach_bound = REACH_FACTOR * max(float(rest_sphere[:, 3].max(initial=0.0)), 1e-5)
        tables = triangle_corner_tables(data)
        self._init_fields(data, triangles, tables, rest_sphere, rest_normal)
        self.grid = self.rows = self.spare = self.found = None  # tissue pairs only
        if tissue_pairs:
            if cell_size is None:
                cell_size = 2.0 * self.reach_bound + self.pair_margin + self.hash_slack
            f = max(self.triangle_count, 1)
            self.grid = SpatialHash(
                f, 1 << max(4, int(2 * f).bit_length()), cell_size, pair_capacity=1
            )
            self.rows = PairRows(f, ROW_CAPACITY * f)
            self.spare = PairRows(f, ROW_CAPACITY * f)
            self.found = FoundPairs(ROW_CAPACITY // 2 * f)

    def _init_fields(
        self,
        data,
        triangles: np.ndarray,
        tables: dict,
        rest_sphere: np.ndarray,
        rest_normal: np.ndarray,
    ):
        f, v, group = self.triangle_count, self.vertex_count, FieldGroup()
        self._group = group
        organ = np.zeros(f, dtype=np.int32)
        for k, record in enumerate(data.organs):
            organ[record.triangles[0] : record.triangles[1]] = k
        self.tri_body = group.field(ti.i32, f, values=organ_bodies(data)[organ])
        corner_inv_mass = tables["corner_inv_mass"]
        self.tri_vertex = group.field(ti.i32, f, vector=3, values=triangles)
        self.tri_neighbour = group.field(ti.i32, f, vector=3, values=edge_neighbours(triangles))
        self.tri_organ = group.field(ti.i32, f, values=organ)
        self.broad_sphere = group.field(ti.f32, f, vector=4)
        self.rest_sphere = group.field(ti.f32, f, vector=4, values=rest_sphere)
        self.rest_normal = group.field(ti.f32, f, vector=3, values=rest_normal)
        self.ref_sphere = group.field(ti.f32, f, vector=4, values=np.full((f, 4), FAR))
        self.hash_sphere = group.field(ti.f32, f, vector=4)
        self.moved = group.field(ti.i32, f)
        self.active_list = group.field(ti.i32, f)
        self.active_count = group.field(ti.i32, None)
        self.touched_list = group.field(ti.i32, len(data.pinned))
        self.touched_count = group.field(ti.i32, None)
        self.particle_mark = group.field(ti.i32, len(data.pinned))
        rank = np.full(len(data.pinned), -1)
        rank[tables["bound_particle"]] = np.arange(len(tables["bound_particle"]))
        self.particle_rank = group.field(ti.i32, len(data.pinned), values=rank)
        self.broad = group.field(ti.i32, len(tissue_collision.BROAD))
        self.tri_inv_mass = group.field(
            ti.f32, f, values=corner_inv_mass.reshape(-1, 3).mean(axis=1)
        )
        self.corner_inv_mass = group.field(ti.f32, 3 * f, values=corner_inv_mass)
        self.corner_owner = group.field(ti.i32, 3 * f, values=tables["corner_owner"])
        for name in ("bound_particle", "particle_start", "particle_corner"):
            setattr(self, name, group.field(ti.i32, len(tables[name]), values=tables[name]))
        self.particle_weight = group.field(
            ti.f32, len(tables["particle_weight"]), values=tables["particle_weight"]
        )
        self.hermite = group.field(
            ti.f32, circumsphere.HERMITE_SAMPLES + 1, values=circumsphere.hermite_table()
        )
        shapes = MAX_TOOLS * MAX_TOOL_SHAPES
        self.shape_kind = group.field(
            ti.i32,
            shapes,
            values=np.tile([SHAPE_CONTROL, SHAPE_JAWS] + [0] * (MAX_TOOL_SHAPES - 2), MAX_TOOLS),
        )
        self.shape_a = group.field(ti.f32, shapes, vector=3)
        self.shape_b = group.field(ti.f32, shapes, vector=3)
        self.shape_size = group.field(ti.f32, shapes, vector=3)
        self.tool_prev = group.field(ToolPose, MAX_TOOLS)
        self.tool_last = group.field(ToolPose, MAX_TOOLS)
        self.tool_reach = group.field(ti.f32, MAX_TOOLS)
        self.tool_cull = group.field(ti.f32, MAX_TOOLS, vector=4)
        self.tool_cull_a = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_cull_axis = group.field(ti.f32, MAX_TOOLS, vector=3)
        self.tool_last_active = group.field(ti.i32, MAX_TOOLS)
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
        self.counter = group.field(ti.i32, len(circumsphere.COUNTERS))
        group.finalize()

    def set_tool_shapes(self, tool: int, shapes: list[tuple]):
        """Replace tool ``tool``'s shapes (at most MAX_TOOL_SHAPES), in its frame [m]:
        ``("control",)`` the shaft capsule, ``("jaws",)`` the jaws' capsule (both
        placed by the Control; the default is these two), ``("sphere", center, radius)``,
        ``("capsule", a, b, radius)``, ``("box", center, half_extents)``."""
        if not 0 <= tool < MAX_TOOLS or len(shapes) > MAX_TOOL_SHAPES:
            raise ValueError(f"tool in 0..{MAX_TOOLS - 1} with at most {MAX_TOOL_SHAPES} shapes")
        kind, a, b, size = (
            self.shape_kind.to_numpy(),
            self.shape_a.to_numpy(),
            self.shape_b.to_numpy(),
            self.shape_size.to_numpy(),
        )
        rows = slice(tool * MAX_TOOL_SHAPES, (tool + 1) * MAX_TOOL_SHAPES)
        kind[rows], a[rows], b[rows], size[rows] = 0, 0.0, 0.0, 0.0
        for slot, shape in enumerate(shapes):
            row = tool * MAX_TOOL_SHAPES + slot
            name, args = shape[0], [np.asarray(x, dtype=np.float32) for x in shape[1:]]
            if name not in SHAPE_KINDS:
                raise ValueError(f"unknown tool shape {name!r}: expected {', '.join(SHAPE_KINDS)}")
            kind[row] = SHAPE_KINDS[name]
            if name in ("sphere", "box"):
                a[row], size[row] = args[0], np.broadcast_to(args[1], 3)
            elif name == "capsule":
                a[row], b[row], size[row] = args[0], args[1], args[2]
        for f, values in (
            (self.shape_kind, kind),
            (self.shape_a, a),
            (self.shape_b, b),
            (self.shape_size, size),
        ):
            f.from_numpy(values)
        reach = self.tool_reach.to_numpy()
        reach[tool] = max(
            [
                shape_reach(kind[row], a[row], b[row], size[row])
                for row in range(rows.start, rows.stop)
            ]
        )
        self.tool_reach.from_numpy(reach)

    def begin_frame(self, control):
        """Remember the tools' poses of the last frame (for the tool motion in the
        bounding-sphere phase and the facing test); call once per frame after the
        devices placed the tools."""
        tissue_collision.remember_tool_poses(control, self)
        self._begun = True

    def reset(self):
        """Forget the lazy-update state (every circumsphere is recomputed at the next
        step) and the tools' last poses, e.g. after :meth:`State.reset`. The pair lists
        stay: each row holds the partners within the margin of where its triangle was
        when listed, wherever the state jumped since, and a triangle that is now
        elsewhere rescans at the next step, as after any drift."""
        self.area_last.fill(0.0)
        self.tool_last_active.fill(0)
        self._begun = False

    def prime(self, state, control):
        """List the pairs of every triangle at the current positions (p and x) now, e.g.
        at a session's start, rather than in the first step (seconds for the full
        liver's 58k triangles)."""
        if self.tissue_pairs:
            tissue_collision.update_bounds(self.model, state, control, self)
            self._refresh_pairs()

    def update_spheres(self, state):
        """Every triangle's bounding and collision sphere (seed 000 §4.2) from p and x,
        detecting nothing (to look at them)."""
        circumsphere.update_spheres(self.model, state, self, True)

    def step(self, state, control, tissue: bool = True):
        """Detect and respond once (module docstring): moves ``state.p`` and flags
        ``state.collided``; velocities follow from p - x in the solver's update.
        ``tissue=False`` leaves out the tissue pairs (tools only), e.g. for all but the
        last shape-matching pass of a substep."""
        if not self._begun:
            self.begin_frame(control)
        if self.timing:
            ti.sync()
            start = self._mark = time.perf_counter()
        if self.tool_particles:
            push_particles_out_of_tools(self.model, state, control, self)
        tissue_collision.update_bounds(self.model, state, control, self)
        self._lap("bounds")
        tissue = tissue and self.tissue_pairs
        if tissue:
            oversize = self._refresh_pairs()
            if oversize:
                self._report_oversize(oversize)
            tissue_collision.mark_active(self, self.rows)
        circumsphere.update_spheres(self.model, state, self, False)
        self._lap("spheres")
        tissue_collision.detect_and_respond(
            self.model, state, control, self, self.rows, int(tissue)
        )
        self._lap("detect")
        if self.timing:
            self.last_ms = (time.perf_counter() - start) * 1e3
            self.total_ms += self.last_ms
            self.calls += 1

    def _refresh_pairs(self) -> int:
        """After :func:`kernels.tissue_collision.update_bounds`: rescan the triangles
        that drifted; returns how many outgrew the hash's bound."""
        moved, stale, oversize = self.broad.to_numpy()[
            [tissue_collision.B_MOVED, tissue_collision.B_STALE, tissue_collision.B_OVERSIZE]
        ]
        if moved:
            self._list_pairs(bool(stale))
        return int(oversize)

    def _report_oversize(self, count: int):
        """Count steps where some triangle's broad sphere (its radius plus its motion in
        the substep) outgrew ``reach_bound``, the largest the hash cells are sized for:
        their tissue pairs may be missed. Warns at the first such step, naming the
        organs and the largest sphere."""
        if not self.oversize_steps:
            f = self.triangle_count
            radius = self.broad_sphere.to_numpy()[:f, 3]
            organ = self.tri_organ.to_numpy()[:f][radius > self.reach_bound]
            organs = sorted({self.model.data.organs[k].name for k in np.unique(organ)})
            log.warning(
                "tissue collision: %d triangles of %s are stretched or move beyond %.2f mm "
                "in a substep (the largest %.2f mm); their tissue contacts may be missed "
                "(more substeps per frame help where they move)",
                count,
                ", ".join(organs),
                self.reach_bound * 1e3,
                radius.max() * 1e3,
            )
        self.oversize_steps += 1

    def _list_pairs(self, stale: bool):
        """Broad phase of the moved triangles (:mod:`kernels.tissue_collision`): the hash
        is rebuilt when out of date, the moved rescan it, the rows are rebuilt; found
        pairs and rows that outgrow their arrays get larger ones (compiled once more)
        and the rescan runs again."""
        if stale or not self._hashed:
            self.grid.build(self.broad_sphere, self.triangle_count)
            tissue_collision.hold_spheres(self, self.grid)
            self._hashed = True
            self._lap("hash")
        while True:
            tissue_collision.list_pairs(self, self.grid, self.found)
            tissue_collision.count_rows(self, self.rows, self.spare, self.found)
            status = self.broad.to_numpy()
            found = int(status[tissue_collision.B_FOUND])
            rows = int(status[tissue_collision.B_ROWS])
            if found > self.found.capacity:
                self.found = FoundPairs(2 * found)
            elif rows > self.spare.capacity:
                self.spare = PairRows(self.triangle_count, 2 * rows)
            else:
                break
        tissue_collision.fill_rows(self, self.rows, self.spare, self.found)
        self.rows, self.spare = self.spare, self.rows
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
        return dict(zip(circumsphere.COUNTERS, self.counter.to_numpy().tolist()))
