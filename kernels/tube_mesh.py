"""Tube skins for drawing: a ring of vertices around every point of a polyline
(the intestine's centre row, instrument shafts), so tubes join the organ surfaces
in one triangle mesh.

Ring frames use the tangent from the neighbouring points and a fixed reference
axis; this is a drawing aid, not the rotation-minimising generalized cylinder of
seed 001 §5.
"""

import math

import taichi as ti

from taichi_lap.kernels.contact import MAX_TOOLS


@ti.kernel
def gather_polylines(surface: ti.template(), surface_count: ti.i32, tube_source: ti.template(),
                     tube_count: ti.i32, control: ti.template(), vertices: ti.template(),
                     points: ti.template(), radius: ti.template()):
    """Copy the skinned surface into ``vertices[:surface_count]``; fill ``points`` with
    the ``tube_count`` tube points (``surface`` at ``tube_source``; their radius is
    preset) followed by tip and tail of every tool (radius 0 when inactive)."""
    for s in range(surface_count):
        vertices[s] = surface[s]
    for k in range(tube_count):
        points[k] = surface[tube_source[k]]
    for t in range(MAX_TOOLS):
        points[tube_count + 2 * t] = control.tool_a[t]
        points[tube_count + 2 * t + 1] = control.tool_b[t]
        r = control.tool_radius[t] * control.tool_active[t]
        radius[tube_count + 2 * t] = r
        radius[tube_count + 2 * t + 1] = r


@ti.kernel
def ring_vertices(points: ti.template(), radius: ti.template(), previous: ti.template(),
                  following: ti.template(), point_count: ti.i32, sides: ti.i32,
                  vertices: ti.template(), offset: ti.i32):
    """vertices[offset + k·sides + j] = points[k] + r_k (cos θ_j n + sin θ_j b), with
    the tangent from ``points[previous[k]]`` to ``points[following[k]]``."""
    for k, j in ti.ndrange(point_count, sides):
        tangent = (points[following[k]] - points[previous[k]]).normalized(1e-12)
        reference = ti.Vector([0.0, 1.0, 0.0])
        if ti.abs(tangent.dot(reference)) > 0.9:
            reference = ti.Vector([1.0, 0.0, 0.0])
        n = tangent.cross(reference).normalized(1e-12)
        b = tangent.cross(n)
        angle = 2.0 * math.pi * j / sides
        vertices[offset + k * sides + j] = points[k] + radius[k] * (ti.cos(angle) * n +
                                                                    ti.sin(angle) * b)
