"""Tissue collision (seed 000 §4): surface triangles of all organs against each other
and against the tools, by adaptive circumspheres (Eq. 4-6, lazy update §4.2.3,
impulse response §4.3) or either baseline of §4.4 (bounding spheres, polygons).

:class:`TissueCollision` owns the per-triangle tables and the spatial hash; the
kernels live in :mod:`kernels.circumsphere` (spheres, lazy update),
:mod:`kernels.tissue_collision` (phases and response), :mod:`kernels.polygon_collision`
and :mod:`kernels.tool_shapes`. A frame calls
:meth:`TissueCollision.begin_frame` once after the tools are placed, then
:meth:`TissueCollision.step` after every shape-matching pass: it reads the predicted
positions p, the substep's start positions x and the goals, and moves p and sets
``collided`` of the particles under contacting triangles.
"""

import math
import time

import numpy as np
import taichi as ti

from taichi_lap.kernels import circumsphere, tissue_collision
from taichi_lap.kernels.contact import MAX_TOOLS
from taichi_lap.kernels.spatial_hash import SpatialHash
from taichi_lap.kernels.tool_shapes import (MAX_TOOL_SHAPES, SHAPE_CONTROL, SHAPE_KINDS,
                                            push_particles_out_of_tools)
from taichi_lap.sim.csr import incidence
from taichi_lap.sim.fields import FieldGroup

METHODS = {"circumsphere": circumsphere.CIRCUMSPHERE,
           "bounding_sphere": circumsphere.BOUNDING_SPHERE,
           "polygon": circumsphere.POLYGON}


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


def bounding_radii(corners: np.ndarray) -> np.ndarray:
    """Radii [m] of the smallest spheres around triangles ``corners`` (F, 3, 3) [m]:
    half the longest edge for right or obtuse triangles, else the circumradius."""
    edge = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2)
    longest = edge.max(axis=1)
    sq = np.sort(edge, axis=1) ** 2
    obtuse = sq[:, 2] >= sq[:, 0] + sq[:, 1]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                         corners[:, 2] - corners[:, 0]), axis=1)
    circum = edge.prod(axis=1) / np.maximum(4.0 * area, 1e-30)
    return np.where(obtuse, 0.5 * longest, circum)


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
    return {"bound_particle": bound, "particle_start": start,
            "particle_corner": corner[keep][rows],
            "particle_weight": weight.reshape(-1)[keep][rows],
            "corner_inv_mass": corner_inv_mass, "corner_owner": owner.astype(np.int32)}


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
    features by the polygon method; ``cell_size`` [m] of the spatial hash (default
    2.5 × the largest rest bounding radius; a triangle's bounding radius plus its
    motion in a substep must stay under half of it); ``timing``: synchronise around
    :meth:`step` and record ``last_ms`` / ``total_ms`` / ``calls``. These settings are
    compiled into the kernels: fixed per instance.
    """

    def __init__(self, model, *, method: str = "circumsphere", scale_phi: float = 3.0,
                 safe_angle: float = math.pi / 6, lazy_delta: float = 0.05,
                 tissue_pairs: bool = True, self_collision: bool = True, tools: bool = True,
                 tool_particles: bool = False, polygon_thickness: float = 1e-4,
                 cell_size: float | None = None, timing: bool = False):
        if method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        if not 0.0 < safe_angle < math.pi / 2 or scale_phi < 0.0 or lazy_delta < 0.0:
            raise ValueError("safe_angle must lie in (0, π/2), scale_phi and lazy_delta >= 0")
        self.model = model
        self.method = METHODS[method]
        self.scale_phi, self.safe_angle = float(scale_phi), float(safe_angle)
        self.lazy_delta = float(lazy_delta)
        self.tissue_pairs, self.self_collision = bool(tissue_pairs), bool(self_collision)
        self.tools, self.tool_particles = bool(tools), bool(tool_particles)
        self.polygon_thickness = float(polygon_thickness)
        self.timing, self.last_ms, self.total_ms, self.calls = timing, 0.0, 0.0, 0
        self._begun = False
        data = model.data
        triangles = np.asarray(data.surface_triangles, dtype=np.int64).reshape(-1, 3)
        self.triangle_count, self.vertex_count = len(triangles), len(data.surface_index)
        tables = triangle_corner_tables(data)
        self.bound_count = len(tables["bound_particle"])
        self._init_fields(data, triangles, tables)
        self.grid = None  # tissue pairs only: the hash allocates its own fields
        if tissue_pairs:
            if cell_size is None:
                rest = (data.surface_weight[..., None]
                        * data.rest_position[data.surface_index]).sum(axis=1)
                largest = float(bounding_radii(rest[triangles]).max(initial=0.0))
                cell_size = 2.5 * max(largest, 1e-5)
            self.grid = SpatialHash(max(self.triangle_count, 1),
                                    1 << max(4, int(2 * self.triangle_count).bit_length()),
                                    cell_size, pair_capacity=1)

    def _init_fields(self, data, triangles: np.ndarray, tables: dict):
        f, v, group = self.triangle_count, self.vertex_count, FieldGroup()
        self._group = group
        organ = np.zeros(f, dtype=np.int32)
        for k, record in enumerate(data.organs):
            organ[record.triangles[0]:record.triangles[1]] = k
        corner_inv_mass = tables["corner_inv_mass"]
        self.tri_vertex = group.field(ti.i32, f, vector=3, values=triangles)
        self.tri_neighbour = group.field(ti.i32, f, vector=3, values=edge_neighbours(triangles))
        self.tri_organ = group.field(ti.i32, f, values=organ)
        self.tri_inv_mass = group.field(ti.f32, f,
                                        values=corner_inv_mass.reshape(-1, 3).mean(axis=1))
        self.corner_inv_mass = group.field(ti.f32, 3 * f, values=corner_inv_mass)
        self.corner_owner = group.field(ti.i32, 3 * f, values=tables["corner_owner"])
        for name in ("bound_particle", "particle_start", "particle_corner"):
            setattr(self, name, group.field(ti.i32, len(tables[name]), values=tables[name]))
        self.particle_weight = group.field(ti.f32, len(tables["particle_weight"]),
                                           values=tables["particle_weight"])
        self.hermite = group.field(ti.f32, circumsphere.HERMITE_SAMPLES + 1,
                                   values=circumsphere.hermite_table())
        shapes = MAX_TOOLS * MAX_TOOL_SHAPES
        self.shape_kind = group.field(ti.i32, shapes, values=np.tile(
            [SHAPE_CONTROL] + [0] * (MAX_TOOL_SHAPES - 1), MAX_TOOLS))
        self.shape_a = group.field(ti.f32, shapes, vector=3)
        self.shape_b = group.field(ti.f32, shapes, vector=3)
        self.shape_size = group.field(ti.f32, shapes, vector=3)
        for name in ("tool_prev_a", "tool_prev_b", "tool_last_a", "tool_last_b"):
            setattr(self, name, group.field(ti.f32, MAX_TOOLS, vector=3))
        self.tool_prev_radius = group.field(ti.f32, MAX_TOOLS)
        self.tool_last_radius = group.field(ti.f32, MAX_TOOLS)
        self.tool_last_active = group.field(ti.i32, MAX_TOOLS)
        self.vertex_p = group.field(ti.f32, v, vector=3)
        self.vertex_x = group.field(ti.f32, v, vector=3)
        for name in ("bound_center", "displacement", "start_centroid", "start_normal", "normal",
                     "sphere_center"):
            setattr(self, name, group.field(ti.f32, f, vector=3))
        for name in ("bound_radius", "bound_reach", "sphere_radius", "sphere_cone", "area_last",
                     "curvature", "curvature_factor", "recovery"):
            setattr(self, name, group.field(ti.f32, f))
        self.sorted_sphere = group.field(ti.f32, f, vector=4)
        self.corner_delta = group.field(ti.f32, 3 * f, vector=3)
        self.corner_count = group.field(ti.i32, 3 * f)
        self.counter = group.field(ti.i32, len(circumsphere.COUNTERS))
        group.finalize()

    def set_tool_shapes(self, tool: int, shapes: list[tuple]):
        """Replace tool ``tool``'s shapes (at most MAX_TOOL_SHAPES), in its frame [m]:
        ``("control",)`` the Control capsule, ``("sphere", center, radius)``,
        ``("capsule", a, b, radius)``, ``("box", center, half_extents)``."""
        if not 0 <= tool < MAX_TOOLS or len(shapes) > MAX_TOOL_SHAPES:
            raise ValueError(f"tool in 0..{MAX_TOOLS - 1} with at most {MAX_TOOL_SHAPES} shapes")
        kind, a, b, size = (self.shape_kind.to_numpy(), self.shape_a.to_numpy(),
                            self.shape_b.to_numpy(), self.shape_size.to_numpy())
        rows = slice(tool * MAX_TOOL_SHAPES, (tool + 1) * MAX_TOOL_SHAPES)
        kind[rows], a[rows], b[rows], size[rows] = 0, 0.0, 0.0, 0.0
        for slot, shape in enumerate(shapes):
            row = tool * MAX_TOOL_SHAPES + slot
            name, args = shape[0], [np.asarray(x, dtype=np.float32) for x in shape[1:]]
            if name not in SHAPE_KINDS:
                raise ValueError(f"unknown tool shape {name!r}: expected "
                                 f"{', '.join(SHAPE_KINDS)}")
            kind[row] = SHAPE_KINDS[name]
            if name in ("sphere", "box"):
                a[row], size[row] = args[0], np.broadcast_to(args[1], 3)
            elif name == "capsule":
                a[row], b[row], size[row] = args[0], args[1], args[2]
        for f, values in ((self.shape_kind, kind), (self.shape_a, a), (self.shape_b, b),
                          (self.shape_size, size)):
            f.from_numpy(values)

    def begin_frame(self, control):
        """Remember the tools' poses of the last frame (for the tool motion in the
        bounding-sphere phase and the facing test); call once per frame after the
        devices placed the tools."""
        tissue_collision.remember_tool_poses(control, self)
        self._begun = True

    def reset(self):
        """Forget the lazy-update state (every circumsphere is recomputed at the next
        step) and the tools' last poses, e.g. after :meth:`State.reset`."""
        self.area_last.fill(0.0)
        self.tool_last_active.fill(0)
        self._begun = False

    def step(self, state, control):
        """Detect and respond once (module docstring): moves ``state.p`` and flags
        ``state.collided``; velocities follow from p - x in the solver's update."""
        if not self._begun:
            self.begin_frame(control)
        if self.timing:
            ti.sync()
            start = time.perf_counter()
        if self.tool_particles:
            push_particles_out_of_tools(self.model, state, control, self)
        circumsphere.update_spheres(self.model, state, self)
        if self.tissue_pairs:
            self.grid.build(self.bound_center, self.triangle_count)
        tissue_collision.detect_and_respond(self.model, state, control, self, self.grid)
        if self.timing:
            ti.sync()
            self.last_ms = (time.perf_counter() - start) * 1e3
            self.total_ms += self.last_ms
            self.calls += 1

    def counters(self) -> dict[str, int]:
        """Cumulative event counts (i32, wrapping: compare differences)."""
        return dict(zip(circumsphere.COUNTERS, self.counter.to_numpy().tolist()))
