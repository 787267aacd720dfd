"""Assembling the drawn mesh every frame: organ surfaces and tube centre lines
gathered from the skinned surface, and the instruments, whose meshes are built
once in the tool's own frame (tip at the origin, shaft along +z) and placed at the
tool capsules the devices set in :class:`taichi_lap.sim.control.Control`."""

import taichi as ti


@ti.kernel
def copy_surface(surface: ti.template(), count: ti.i32, positions: ti.template()):
    """positions[:count] = surface[:count]: the skinned organ surfaces [m]."""
    for s in range(count):
        positions[s] = surface[s]


@ti.kernel
def gather_points(surface: ti.template(), source: ti.template(), points: ti.template()):
    """points[k] = surface[source[k]]: a tube's centre line [m]."""
    for k in points:
        points[k] = surface[source[k]]


@ti.func
def tool_frame(a, b):
    """Orthonormal axes (x, y, z) with z from the tip ``a`` towards the tail ``b``;
    x is horizontal (perpendicular to world y) unless the shaft is vertical."""
    z = (b - a).normalized(1e-12)
    reference = ti.Vector([0.0, 1.0, 0.0])
    if ti.abs(z.dot(reference)) > 0.99:
        reference = ti.Vector([1.0, 0.0, 0.0])
    x = reference.cross(z).normalized(1e-12)
    return x, z.cross(x), z


@ti.kernel
def place_instruments(local_position: ti.template(), local_normal: ti.template(),
                      vertex_tool: ti.template(), count: ti.i32, control: ti.template(),
                      positions: ti.template(), normals: ti.template(), offset: ti.i32):
    """positions[offset + v] = a + R · local_position[v] for the tool
    ``vertex_tool[v]`` (capsule tip ``a`` [m], frame R from :func:`tool_frame`);
    normals likewise rotated. An inactive tool collapses onto its tip, so its
    triangles are degenerate and not drawn."""
    for v in range(count):
        t = vertex_tool[v]
        a, b = control.tool_a[t], control.tool_b[t]
        x, y, z = tool_frame(a, b)
        local = local_position[v] * ti.cast(control.tool_active[t], ti.f32)
        n = local_normal[v]
        positions[offset + v] = a + local[0] * x + local[1] * y + local[2] * z
        normals[offset + v] = n[0] * x + n[1] * y + n[2] * z
