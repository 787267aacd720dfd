"""Instrument tips as unions of implicit shapes: signed distance and its gradient.

Seed 000 §5.1 represents the working part of an instrument by "a combination of
implicit shapes" (column, sphere, polyhedron); the collision pipeline of §4 tests
tissue against the same shapes. A tool is placed by a :data:`ToolPose` read from its
:class:`Control` entry: the shaft capsule (tip to tail), the tool frame
``Control.tool_frame`` (columns x, y and z from the tip towards the handle; the
renderer and the grasp use the same frame) and the jaws' capsule ahead of the tip
(radius 0 for instruments without jaws). Each tool owns :data:`MAX_TOOL_SHAPES` slots
of a shape table (a ``ti.template()`` holding ``shape_kind``, ``shape_a``, ``shape_b``,
``shape_size``, row ``tool * MAX_TOOL_SHAPES + slot``):

* ``SHAPE_CONTROL`` — the shaft capsule itself;
* ``SHAPE_JAWS`` — the jaws' capsule (nothing for a probe or hook);
* ``SHAPE_SPHERE`` — centre ``shape_a``, radius ``shape_size[0]``;
* ``SHAPE_CAPSULE`` — segment ``shape_a``-``shape_b``, radius ``shape_size[0]``;
* ``SHAPE_BOX`` — centre ``shape_a``, half extents ``shape_size``, axes of the frame.

Coordinates of the last three are in the tool frame, origin at the tip. All lengths
in metres; the distance of a union is the minimum over its shapes and the gradient
that of the nearest shape (pointing out of the tool).
"""

import taichi as ti

from taichi_lap.core.instruments import MAX_TOOLS
from taichi_lap.kernels.contact import closest_on_segment

MAX_TOOL_SHAPES = 4
"""Shape slots per tool."""

SHAPE_NONE, SHAPE_CONTROL, SHAPE_SPHERE, SHAPE_CAPSULE, SHAPE_BOX, SHAPE_JAWS = range(6)
SHAPE_KINDS = {
    "control": SHAPE_CONTROL,
    "jaws": SHAPE_JAWS,
    "sphere": SHAPE_SPHERE,
    "capsule": SHAPE_CAPSULE,
    "box": SHAPE_BOX,
}
FAR = 1e6
"""Distance reported for an empty slot [m]."""

ToolPose = ti.types.struct(
    tip=ti.math.vec3,
    tail=ti.math.vec3,
    radius=ti.f32,
    frame=ti.math.mat3,
    jaw=ti.math.vec3,
    jaw_radius=ti.f32,
)
"""Where a tool is (module docstring): shaft ``tip``-``tail`` of ``radius``, ``frame``,
jaws ``jaw``-``tip`` of ``jaw_radius`` [m]."""


@ti.func
def control_pose(control: ti.template(), k):
    """Tool k's :data:`ToolPose` as :class:`Control` places it."""
    return ToolPose(
        tip=control.tool_a[k],
        tail=control.tool_b[k],
        radius=control.tool_radius[k],
        frame=control.tool_frame[k],
        jaw=control.tool_jaw[k],
        jaw_radius=control.tool_jaw_radius[k],
    )


@ti.func
def tool_extent(pose):
    """Distance [m] from the tip beyond which the jaws reach nothing (0 without jaws)."""
    return ti.select(pose.jaw_radius > 0.0, (pose.jaw - pose.tip).norm() + pose.jaw_radius, 0.0)


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
def round_shape(shapes: ti.template(), slot, pose):
    """World segment and radius of a round slot (shaft, jaws, sphere, capsule) of a tool
    at ``pose``: (1 if round and present else 0, a, b, radius)."""
    kind = shapes.shape_kind[slot]
    a, b, r, round_ = pose.tip, pose.tail, pose.radius, 0
    if kind == SHAPE_CONTROL:
        round_ = 1
    elif kind == SHAPE_JAWS:
        a, b, r, round_ = pose.jaw, pose.tip, pose.jaw_radius, int(pose.jaw_radius > 0.0)
    elif kind == SHAPE_SPHERE or kind == SHAPE_CAPSULE:
        a = pose.tip + pose.frame @ shapes.shape_a[slot]
        b = a
        if kind == SHAPE_CAPSULE:
            b = pose.tip + pose.frame @ shapes.shape_b[slot]
        r, round_ = shapes.shape_size[slot][0], 1
    return round_, a, b, r


@ti.func
def shape_distance(shapes: ti.template(), slot, pose, x):
    """Signed distance [m] and gradient of shape ``slot`` of a tool at ``pose`` (FAR for
    an empty slot)."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    if shapes.shape_kind[slot] == SHAPE_BOX:
        dist, grad = box_distance(
            pose.tip + pose.frame @ shapes.shape_a[slot], shapes.shape_size[slot], pose.frame, x
        )
    else:
        round_, a, b, r = round_shape(shapes, slot, pose)
        if round_:
            dist, grad = capsule_distance(a, b, r, x)
    return dist, grad


@ti.func
def tool_distance(shapes: ti.template(), tool, pose, x):
    """Signed distance [m] and gradient of the union of ``tool``'s shapes at ``pose``."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    for s in range(MAX_TOOL_SHAPES):
        d, g = shape_distance(shapes, tool * MAX_TOOL_SHAPES + s, pose, x)
        if d < dist:
            dist, grad = d, g
    return dist, grad


@ti.kernel
def push_particles_out_of_tools(
    model: ti.template(), state: ti.template(), control: ti.template(), shapes: ti.template()
):
    """Particles of radius r [m] inside a tool's union of shapes move to its surface
    (PBD projection, Müller et al. 2007 §3.4) and are flagged collided (seed 000
    Alg. 1 line 13-14, as :mod:`kernels.contact` does for capsules). Reads and writes
    p, collided."""
    for i in range(model.particle_count):
        if model.inv_mass[i] > 0.0:
            p, r, hit = state.p[i], model.radius[i], 0
            for k in range(MAX_TOOLS):
                if control.tool_active[k]:
                    dist, grad = tool_distance(shapes, k, control_pose(control, k), p)
                    if dist < r:
                        p += (r - dist) * grad
                        hit = 1
            if hit:
                state.p[i] = p
                state.collided[i] = 1
