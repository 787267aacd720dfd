"""Generalized-cylinder tubes for drawing (seed 001 §5): fixed-capacity meshes and the
§5.3 frame-time controller. The kernels and the maths are in
``taichi_lap.kernels.generalized_cylinder``.

Per frame::

    mesh = TubeMesh(point_capacity=100, tube_capacity=1, sides=12, max_level=2)
    control = TessellationController(target_ms=4.0, max_level=2)
    ...
    mesh.update(points, radius, tube_range, 1, vertices, normals, indices, texcoords,
                vertex_offset=organ_vertices, index_offset=3 * organ_triangles,
                epsilon=control.epsilon, level=control.level)
    control.update(measured_frame_ms)

Output layout: vertex ``vertex_offset + ring * sides + side``; triangle ``k`` at
``indices[index_offset + 3 k : index_offset + 3 k + 3]`` (absolute vertex indices,
counter-clockwise seen from outside). Rings of all tubes are packed in tube order, so
the live triangles are the first ``live_triangle_count`` of the region and the live
vertices the first ``live_vertex_count``. The rest of the rings' region
(``cap_vertex_start`` vertices, ``cap_triangle_start`` triangles) is padding: zero
vertices and normals, degenerate triangles (three equal indices) that a rasterizer
skips; it is rewritten only where the previous call had live data. After it, each tube
slot has two rounded end caps, so a tube is a closed surface; the caps
of absent tubes are padding too (all written by ``skin_tubes``).
"""

from __future__ import annotations

import math

import taichi as ti

from taichi_lap.core.fields import FieldGroup
from taichi_lap.kernels import generalized_cylinder as gc


class TubeMesh:
    """Sampling, frames and skinned cylinders of up to ``tube_capacity`` tubes over a
    field of at most ``point_capacity`` points (seed 001 §5).

    ``sides`` vertices per ring; ``max_level`` the finest cylinder primitive (level n
    has 2^(n+1) rings per interval, Eq. 13); ``tension`` of the cardinal spline (0:
    Catmull-Rom). A segment holds at most 3 samples (its knot and two Eq. 11 samples),
    so with P = ``point_capacity`` and B = 2^(max_level+1) - 1:

    - ``ring_capacity = 3 B (P - 1) + 1``
    - ``cap_vertex_start = sides * ring_capacity``
    - ``cap_triangle_start = 2 * sides * (ring_capacity - 1)``
    - ``vertex_capacity`` and ``triangle_capacity``: those and two end caps per tube
      (:func:`~taichi_lap.kernels.generalized_cylinder.cap_size`; index field: 3 per
      triangle)
    """

    def __init__(
        self,
        point_capacity: int,
        tube_capacity: int = 1,
        *,
        sides: int = 12,
        max_level: int = 2,
        tension: float = 0.0,
    ):
        if point_capacity < 2 or tube_capacity < 1 or sides < 3 or not 0 <= max_level <= 6:
            raise ValueError(
                "need point_capacity >= 2, tube_capacity >= 1, sides >= 3, 0 <= max_level <= 6"
            )
        self.point_capacity, self.tube_capacity = int(point_capacity), int(tube_capacity)
        self.sides, self.max_level, self.tension = int(sides), int(max_level), float(tension)
        bands = 2 ** (max_level + 1) - 1
        self.ring_capacity = 3 * bands * (self.point_capacity - 1) + 1
        self.cap_vertex_start = self.sides * self.ring_capacity
        self.cap_triangle_start = 2 * self.sides * (self.ring_capacity - 1)
        caps = 2 * self.tube_capacity
        cap_vertices, cap_triangles = gc.cap_size(self.sides)
        self.vertex_capacity = self.cap_vertex_start + caps * cap_vertices
        self.triangle_capacity = self.cap_triangle_start + caps * cap_triangles
        samples = 3 * self.point_capacity
        g = FieldGroup()
        f32, i32 = ti.f32, ti.i32
        self.segment_indicator = g.field(f32, self.point_capacity)  # c_i, Eq. 10
        self.segment_peak = g.field(f32, self.point_capacity)  # m_i, Eq. 11 (-1: not refined)
        self.segment_sample_count = g.field(i32, self.point_capacity)
        self.segment_sample_start = g.field(i32, self.point_capacity)
        self.sample_segment = g.field(i32, samples)
        self.sample_parameter = g.field(f32, samples)
        self.sample_position = g.field(f32, samples, vector=3)  # [m]
        self.sample_tangent = g.field(f32, samples, vector=3)
        self.sample_normal = g.field(f32, samples, vector=3)
        self.sample_radius = g.field(f32, samples)  # [m]
        self.tube_start_normal = g.field(f32, self.tube_capacity, vector=3)  # last call's
        self.tube_sample_start = g.field(i32, self.tube_capacity)
        self.tube_sample_count = g.field(i32, self.tube_capacity)
        self.tube_ring_base = g.field(i32, self.tube_capacity + 1)
        self.tube_band_base = g.field(i32, self.tube_capacity + 1)
        self.ring_center = g.field(f32, self.ring_capacity, vector=3)  # [m]
        self.ring_center_rate = g.field(f32, self.ring_capacity, vector=3)  # d/dz [m]
        self.ring_a = g.field(f32, self.ring_capacity, vector=3)  # r k, blended [m]
        self.ring_b = g.field(f32, self.ring_capacity, vector=3)  # r b, blended [m]
        self.ring_taper = g.field(f32, self.ring_capacity)  # (dr/dz) / r
        self.ring_plane = g.field(f32, self.ring_capacity, vector=3)
        self.ring_flags = g.field(i32, self.ring_capacity)
        self.ring_param = g.field(f32, self.ring_capacity)  # point index + parameter
        self.ring_radius = g.field(f32, self.ring_capacity)  # [m]
        self.live_vertex_count = g.field(i32, None)
        self.live_triangle_count = g.field(i32, None)
        self.vertex_write_end = g.field(i32, None)
        self.band_write_end = g.field(i32, None)
        self.padded_vertex_end = g.field(i32, None)
        self.padded_band_end = g.field(i32, None)
        g.finalize()
        self._group = g
        self._output = None

    def update(
        self,
        points,
        radius,
        tube_range,
        tube_count: int,
        vertices,
        normals,
        indices,
        texcoords,
        *,
        vertex_offset: int = 0,
        index_offset: int = 0,
        epsilon: float = 0.1,
        level: int | None = None,
        spacing: float = 0.01,
        reference=None,
    ) -> None:
        """Tessellate the tubes into the output region (seed 001 §5). No host sync.

        ``points`` vec3 [m] and ``radius`` f32 [m] fields, ``tube_range`` an ivec2 field of
        [start, end) per tube (ascending, disjoint; consecutive points distinct; tubes of
        fewer than 2 points draw nothing). ``epsilon``: Eq. 10 indicator threshold in [0, 1] for
        Eq. 11 refinement; ``level``: cylinder primitive level (default ``max_level``).
        Writes ``vertices``/``normals``/``texcoords`` (vec3 f32; a texcoord is (``spacing``
        [m] × the point parameter along the tube, the radius × (cos φ, sin φ)): the
        tube's material, moving with it) from ``vertex_offset`` and ``indices`` (i32)
        from ``index_offset`` (see the module docstring for the layout). Each tube's
        first frame continues the last call's (:meth:`forget_frames`), and the frames
        along it are rotation-minimizing (Eq. 12); with ``reference``, a vec3 field
        of a direction per point fixed in the tube's material (an intestine's: towards
        its mesentery), each frame's normal is that direction, interpolated and made
        normal to the tube, so the texcoords round the tube stay on the material
        however the tube bends (the rotation-minimizing frames turn about the tube as
        it bends: their holonomy)."""
        level = self.max_level if level is None else int(level)
        if not 0 <= level <= self.max_level:
            raise ValueError(f"level must be in [0, {self.max_level}], got {level}")
        if not 0 <= tube_count <= min(self.tube_capacity, tube_range.shape[0]):
            raise ValueError(f"tube_count {tube_count} exceeds the tube capacity")
        if points.shape[0] > self.point_capacity:
            raise ValueError(f"points field larger than point_capacity {self.point_capacity}")
        if (
            vertex_offset < 0
            or index_offset < 0
            or vertex_offset + self.vertex_capacity
            > min(vertices.shape[0], normals.shape[0], texcoords.shape[0])
            or index_offset + 3 * self.triangle_capacity > indices.shape[0]
        ):
            raise ValueError("output fields too small for the tube capacity at these offsets")
        output = (id(vertices), id(normals), id(indices), vertex_offset, index_offset)
        if output != self._output:  # a new region: pad all of it once
            self.padded_vertex_end[None] = self.cap_vertex_start
            self.padded_band_end[None] = self.ring_capacity - 1
            self._output = output
        referenced = reference is not None
        gc.sample_tubes(
            self,
            points,
            radius,
            tube_range,
            tube_count,
            float(epsilon),
            level,
            reference if referenced else points,
            referenced,
        )
        gc.skin_tubes(
            self,
            tube_count,
            level,
            vertices,
            normals,
            indices,
            texcoords,
            vertex_offset,
            index_offset,
            vertex_offset + self.cap_vertex_start,
            index_offset + 3 * self.cap_triangle_start,
            float(spacing),
        )

    def forget_frames(self):
        """Start the next :meth:`update`'s tubes from their Frenet frames, as tubes
        never drawn before (their first frames otherwise continue the last call's)."""
        self.tube_start_normal.fill(0.0)


class TessellationController:
    """Frame-time feedback on (ε, n), seed 001 §5.3 Eq. 15.

    Eq. 15 reads ε_{k+1} = ε_k + α (f_0 - f_k), ν_{k+1} = ν_k + β (ε_{k+1} - ε_k),
    n = ⌊ν⌋, f the frame rate. As printed, a slow frame raises ε (fewer samples) and
    also ν (finer cylinders); the sign of the ν line is taken as negative so both act
    the same way. Here the state is ν alone, in [min_level, max_level + 1):

        e_k = clip((t_k - t_0) / t_0, -1, 1)      relative frame-time error
        ν_{k+1} = clip(ν_k - gain * e_k)          unless |e_k| <= deadband
        n = ⌊ν⌋,  ε = ε_max - (ν - n) (ε_max - ε_min)

    Inside a level this is Eq. 15 with β = 1 / (ε_max - ε_min) and α = gain / β per unit
    relative error; when n changes, ε wraps to the other end of its range, so the cost
    rises continuously with ν up to a level step instead of leaving ε's bounds. ``gain``
    < 1 damps the integral action; the deadband stops level flicker near the target.
    Deterministic: plain float arithmetic on the measurement sequence.
    """

    def __init__(
        self,
        target_ms: float,
        *,
        min_level: int = 0,
        max_level: int = 2,
        epsilon_range: tuple[float, float] = (0.0, 0.5),
        gain: float = 0.5,
        deadband: float = 0.05,
        quality: float | None = None,
    ):
        if not target_ms > 0 or not 0 <= min_level <= max_level:
            raise ValueError("need target_ms > 0 and 0 <= min_level <= max_level")
        if not 0.0 <= epsilon_range[0] < epsilon_range[1] <= 1.0 or not gain > 0 or deadband < 0:
            raise ValueError("need 0 <= epsilon_min < epsilon_max <= 1, gain > 0, deadband >= 0")
        self.target_ms, self.gain, self.deadband = float(target_ms), float(gain), float(deadband)
        self.epsilon_min, self.epsilon_max = map(float, epsilon_range)
        self.min_level, self.max_level = int(min_level), int(max_level)
        top = math.nextafter(float(max_level + 1), -math.inf)
        self._bounds = (float(min_level), top)
        self.quality = self._clip(0.5 * (min_level + max_level + 1) if quality is None else quality)

    def _clip(self, nu: float) -> float:
        return min(max(float(nu), self._bounds[0]), self._bounds[1])

    @property
    def level(self) -> int:
        """n = ⌊ν⌋, the cylinder primitive level."""
        return int(math.floor(self.quality))

    @property
    def epsilon(self) -> float:
        """ε, the Eq. 10 indicator threshold for Eq. 11 samples."""
        fraction = self.quality - self.level
        return self.epsilon_max - fraction * (self.epsilon_max - self.epsilon_min)

    def update(self, frame_ms: float) -> tuple[float, int]:
        """One step from a measured frame time [ms]; returns (epsilon, level)."""
        if not math.isfinite(frame_ms) or frame_ms < 0:
            raise ValueError(f"frame time must be finite and >= 0, got {frame_ms}")
        error = min(max((frame_ms - self.target_ms) / self.target_ms, -1.0), 1.0)
        if abs(error) > self.deadband:
            self.quality = self._clip(self.quality - self.gain * error)
        return self.epsilon, self.level
