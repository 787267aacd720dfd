"""Vertex normals of the deformed surface, gathered per vertex (no float atomics):
each vertex sums the area-weighted normals of its incident triangles, listed in a
fixed-width table (-1 padded after them) that dissection can rewrite row by row, so
the result is deterministic on every backend."""

import taichi as ti


@ti.kernel
def vertex_normals(
    positions: ti.template(),
    triangles: ti.template(),
    incident: ti.template(),
    vertex_count: ti.i32,
    normals: ti.template(),
):
    """normals[v] = normalize(Σ_t (b - a) × (c - a)) over the triangles t in row v of
    ``incident`` (a 2-D table, its triangles first, then -1: a row ends at its first
    -1, so a vertex in 6 triangles of a 24-wide row reads 7 columns). ``triangles`` is
    a flat index field (3 per triangle); reads positions, writes normals."""
    for v in range(vertex_count):
        n = ti.Vector([0.0, 0.0, 0.0])
        for k in range(incident.shape[1]):
            t = incident[v, k]
            if t < 0:
                break
            a = positions[triangles[3 * t]]
            b = positions[triangles[3 * t + 1]]
            c = positions[triangles[3 * t + 2]]
            n += (b - a).cross(c - a)
        length = n.norm()
        normal = ti.Vector([0.0, 1.0, 0.0])
        if length > 1e-20:
            normal = n / length
        normals[v] = normal
