"""Instrument tips as unions of implicit shapes: signed distance and its gradient.

Seed 000 §5.1 represents the working part of an instrument by "a combination of
implicit shapes" (column, sphere, polyhedron); the collision pipeline of §4 tests
tissue against the same shapes. A tool is placed by its :class:`Control` capsule, tip
``a`` to tail ``b`` [m]. Each tool owns :data:`MAX_TOOL_SHAPES` slots of a shape table
(a ``ti.template()`` holding ``shape_kind``, ``shape_a``, ``shape_b``, ``shape_size``,
row ``tool * MAX_TOOL_SHAPES + slot``):

* ``SHAPE_CONTROL`` — the Control capsule itself (the default of every tool);
* ``SHAPE_SPHERE`` — centre ``shape_a``, radius ``shape_size[0]``;
* ``SHAPE_CAPSULE`` — segment ``shape_a``-``shape_b``, radius ``shape_size[0]``;
* ``SHAPE_BOX`` — centre ``shape_a``, half extents ``shape_size``, axes of the frame.

Coordinates of the last three are in the tool frame: origin at the tip, z along tip ->
tail, x = normalize(helper × z) with helper the world y axis (the world x axis when z
is within ~25° of y), y = z × x. Control carries no roll about the shaft, so a box
keeps this fixed roll. All lengths in metres; the distance of a union is the minimum
over its shapes and the gradient that of the nearest shape (pointing out of the tool).
"""

import taichi as ti

from taichi_lap.kernels.contact import MAX_TOOLS, closest_on_segment

MAX_TOOL_SHAPES = 4
"""Shape slots per tool."""

SHAPE_NONE, SHAPE_CONTROL, SHAPE_SPHERE, SHAPE_CAPSULE, SHAPE_BOX = range(5)
SHAPE_KINDS = {"control": SHAPE_CONTROL, "sphere": SHAPE_SPHERE, "capsule": SHAPE_CAPSULE,
               "box": SHAPE_BOX}
FAR = 1e6
"""Distance reported for an empty slot [m]."""


@ti.func
def tool_frame(tip, tail):
    """Rotation whose columns are the tool frame's x, y, z axes (module docstring)."""
    z = tail - tip
    length = z.norm()
    z = ti.select(length > 1e-9, z / ti.max(length, 1e-9), ti.Vector([0.0, 0.0, 1.0]))
    helper = ti.Vector([0.0, 1.0, 0.0])
    if ti.abs(z[1]) > 0.9:
        helper = ti.Vector([1.0, 0.0, 0.0])
    x = helper.cross(z).normalized()
    return ti.Matrix.cols([x, z.cross(x), z])


@ti.func
def capsule_distance(a, b, radius, x):
    """Signed distance [m] from ``x`` to the capsule ``a``-``b`` of ``radius`` and its
    unit gradient (the world y axis on the axis itself)."""
    d = x - closest_on_segment(a, b, x)
    dist = d.norm()
    grad = ti.Vector([0.0, 1.0, 0.0])
    if dist > 1e-12:
        grad = d / dist
    return dist - radius, grad


@ti.func
def box_distance(center, half, frame, x):
    """Signed distance [m] from ``x`` to the box of ``half`` extents at ``center`` with
    axes ``frame`` (columns), and its unit gradient."""
    local = frame.transpose() @ (x - center)
    q = ti.abs(local) - half
    outside = ti.max(q, 0.0).norm()
    inside = ti.min(ti.max(q[0], ti.max(q[1], q[2])), 0.0)
    side = ti.select(local >= 0.0, 1.0, -1.0)
    grad_local = ti.Vector([0.0, 0.0, 0.0])
    if outside > 0.0:
        grad_local = side * ti.max(q, 0.0) / outside
    else:
        axis = 0
        if q[1] > q[axis]:
            axis = 1
        if q[2] > q[axis]:
            axis = 2
        grad_local[axis] = side[axis]
    return outside + inside, frame @ grad_local


@ti.func
def shape_distance(shapes: ti.template(), slot, tip, tail, radius, x):
    """Signed distance [m] and gradient of shape ``slot`` of a tool posed by the
    capsule ``tip``-``tail`` of ``radius`` (FAR for an empty slot)."""
    kind = shapes.shape_kind[slot]
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    if kind != SHAPE_NONE:
        a, b, r, frame = tip, tail, radius, ti.Matrix.identity(ti.f32, 3)
        size = shapes.shape_size[slot]
        if kind != SHAPE_CONTROL:
            frame = tool_frame(tip, tail)
            a = tip + frame @ shapes.shape_a[slot]
            b = ti.select(kind == SHAPE_CAPSULE, tip + frame @ shapes.shape_b[slot], a)
            r = size[0]
        if kind == SHAPE_BOX:
            dist, grad = box_distance(a, size, frame, x)
        else:
            dist, grad = capsule_distance(a, b, r, x)
    return dist, grad


@ti.func
def tool_distance(shapes: ti.template(), tool, tip, tail, radius, x):
    """Signed distance [m] and gradient of the union of ``tool``'s shapes at ``x``."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    for s in range(MAX_TOOL_SHAPES):
        d, g = shape_distance(shapes, tool * MAX_TOOL_SHAPES + s, tip, tail, radius, x)
        if d < dist:
            dist, grad = d, g
    return dist, grad


@ti.func
def round_shape(shapes: ti.template(), slot, tip, tail, radius):
    """World segment and radius of a sphere or capsule slot (the Control capsule
    included): (1 if round else 0, a, b, radius) for segment-triangle tests."""
    kind = shapes.shape_kind[slot]
    a, b, r, round_ = tip, tail, radius, 0
    if kind == SHAPE_CONTROL:
        round_ = 1
    elif kind == SHAPE_SPHERE or kind == SHAPE_CAPSULE:
        frame = tool_frame(tip, tail)
        a = tip + frame @ shapes.shape_a[slot]
        b = a
        if kind == SHAPE_CAPSULE:
            b = tip + frame @ shapes.shape_b[slot]
        r, round_ = shapes.shape_size[slot][0], 1
    return round_, a, b, r


@ti.kernel
def push_particles_out_of_tools(model: ti.template(), state: ti.template(),
                                control: ti.template(), shapes: ti.template()):
    """Particles of radius r [m] inside a tool's union of shapes move to its surface
    (PBD projection, Müller et al. 2007 §3.4) and are flagged collided (seed 000
    Alg. 1 line 13-14, as :mod:`kernels.contact` does for capsules). Reads and writes
    p, collided."""
    for i in range(model.particle_count):
        if model.inv_mass[i] > 0.0:
            p, r, hit = state.p[i], model.radius[i], 0
            for k in range(MAX_TOOLS):
                if control.tool_active[k]:
                    dist, grad = tool_distance(shapes, k, control.tool_a[k], control.tool_b[k],
                                               control.tool_radius[k], p)
                    if dist < r:
                        p += (r - dist) * grad
                        hit = 1
            if hit:
                state.p[i] = p
                state.collided[i] = 1
