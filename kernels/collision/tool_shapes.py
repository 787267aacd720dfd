"""Instruments as unions of implicit shapes (seed 000 §5.1): signed distance, gradient
and the particle push, for the shape table a :class:`~taichi_lap.sim.control.Control`
holds.

The shapes are those of :mod:`taichi_lap.core.instruments` (its docstring defines
them); each tool owns :data:`MAX_TOOL_SHAPES` rows of the Control's table
(``shape_kind``, ``shape_a``, ``shape_b``, ``shape_size``, row ``tool *
MAX_TOOL_SHAPES + slot``). A tool is placed by a :data:`ToolPose` read from its
Control entry: the shaft capsule (tip to tail), the tool frame ``tool_frame`` (the
renderer and the grasp use the same frame) and the jaws' capsule ahead of the tip
(radius 0 for instruments without jaws). Particle contacts
(:func:`push_out_of_tools`), tissue collision and, in NumPy, the haptic proxy all
evaluate these shapes. Lengths in metres; a union's distance is the minimum over its
shapes and its gradient that of the nearest shape (pointing out of the tool).
"""

import taichi as ti
from taichi_lap.kernels.collision.closest_points import point_segment

from taichi_lap.core.instruments import (
    FAR,
    MAX_TOOL_SHAPES,
    MAX_TOOLS,
    SHAPE_BOX,
    SHAPE_CAPSULE,
    SHAPE_JAWS,
    SHAPE_SHAFT,
    SHAPE_SPHERE,
)

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
def bounding_radius(control: ti.template(), k, pose):
    """Radius [m] of tool k's bounding capsule about its shaft segment: every shape lies
    within it (the shaft's radius, the jaws' extent from the tip, ``tool_reach`` of the
    shapes placed in the frame)."""
    return ti.max(pose.radius, control.tool_reach[k], tool_extent(pose))


@ti.func
def capsule_distance(a, b, radius, x):
    """Signed distance [m] from ``x`` to the capsule ``a``-``b`` of ``radius`` and its
    unit gradient (the world y axis on the axis itself)."""
    d = x - point_segment(a, b, x)
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
def round_shape(control: ti.template(), slot, pose):
    """World segment and radius of a round slot (shaft, jaws, sphere, capsule) of a tool
    at ``pose``: (1 if round and present else 0, a, b, radius)."""
    kind = control.shape_kind[slot]
    a, b, r, round_ = pose.tip, pose.tail, pose.radius, 0
    if kind == SHAPE_SHAFT:
        round_ = 1
    elif kind == SHAPE_JAWS:
        a, b, r, round_ = pose.jaw, pose.tip, pose.jaw_radius, int(pose.jaw_radius > 0.0)
    elif kind == SHAPE_SPHERE or kind == SHAPE_CAPSULE:
        a = pose.tip + pose.frame @ control.shape_a[slot]
        b = a
        if kind == SHAPE_CAPSULE:
            b = pose.tip + pose.frame @ control.shape_b[slot]
        r, round_ = control.shape_size[slot][0], 1
    return round_, a, b, r


@ti.func
def shape_distance(control: ti.template(), slot, pose, x):
    """Signed distance [m] and gradient of shape ``slot`` of a tool at ``pose`` (FAR for
    an empty slot)."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    if control.shape_kind[slot] == SHAPE_BOX:
        dist, grad = box_distance(
            pose.tip + pose.frame @ control.shape_a[slot],
            control.shape_size[slot],
            pose.frame,
            x,
        )
    else:
        round_, a, b, r = round_shape(control, slot, pose)
        if round_:
            dist, grad = capsule_distance(a, b, r, x)
    return dist, grad


@ti.func
def tool_distance(control: ti.template(), tool, pose, x):
    """Signed distance [m] and gradient of the union of ``tool``'s shapes at ``pose``."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    for s in range(MAX_TOOL_SHAPES):
        d, g = shape_distance(control, tool * MAX_TOOL_SHAPES + s, pose, x)
        if d < dist:
            dist, grad = d, g
    return dist, grad


@ti.func
def push_out_of_tools(control: ti.template(), p, r):
    """A particle at ``p`` [m] of radius ``r`` [m] moved out of every active tool: onto
    the surface of each shape it is inside, one shape after the other in table order
    (PBD projection, Müller et al. 2007 §3.4), again while a pass moved it (a push out
    of one shape may end in an overlapping one), at most :data:`MAX_TOOL_SHAPES`
    passes; particles outside the tool's bounding capsule are not tested further.
    Returns the new position and 1 when a tool touched it (seed 000 Alg. 1 lines 13-14
    then hold its goal)."""
    hit = 0
    for k in range(MAX_TOOLS):
        pose = control_pose(control, k)
        reach = bounding_radius(control, k, pose) + r
        if (
            control.tool_active[k]
            and (p - point_segment(pose.tip, pose.tail, p)).norm_sqr() < reach * reach
        ):
            for _ in range(MAX_TOOL_SHAPES):
                moved = 0
                for s in range(MAX_TOOL_SHAPES):
                    dist, grad = shape_distance(control, k * MAX_TOOL_SHAPES + s, pose, p)
                    if dist < r:
                        p += (r - dist) * grad
                        moved = 1
                hit |= moved
                if not moved:
                    break
    return p, hit
