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

Tools move within a frame: :func:`place_tool` keeps where a tool was when the device
moved it (``tool_start``) beside where the device put it (``tool_goal``), and
:func:`interpolate_tools` places it in between for each substep, keeping the pose at
the substep's start in ``tool_last``. Contacts compare where a point lay relative to
the tool at the substep's start with where it lies now (:func:`swept_shape_distance`),
so a tool that moved past a point within a substep pushes it back to the side it came
from instead of through the tool.
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
def pose_between(start, goal, f):
    """The pose a fraction ``f`` of the way from ``start`` to ``goal`` (points linear,
    frame re-orthonormalised about the interpolated axis; ``goal`` itself at f >= 1)."""
    pose = goal
    if f < 1.0:
        pose.tip = start.tip + f * (goal.tip - start.tip)
        pose.tail = start.tail + f * (goal.tail - start.tail)
        pose.jaw = start.jaw + f * (goal.jaw - start.jaw)
        m = start.frame + f * (goal.frame - start.frame)
        z = ti.Vector([m[0, 2], m[1, 2], m[2, 2]]).normalized(1e-12)
        x = ti.Vector([m[0, 0], m[1, 0], m[2, 0]])
        x = (x - x.dot(z) * z).normalized(1e-12)
        y = z.cross(x)
        pose.frame = ti.Matrix.cols([x, y, z])
    return pose


@ti.kernel
def place_tool(
    control: ti.template(),
    k: ti.i32,
    tip: ti.math.vec3,
    tail: ti.math.vec3,
    radius: ti.f32,
    active: ti.i32,
    frame: ti.math.mat3,
    jaw: ti.math.vec3,
    jaw_radius: ti.f32,
    jump: ti.i32,
):
    """Tool k's new pose (its Control entry and ``tool_goal``); the pose it leaves
    becomes ``tool_start`` and ``tool_last``, or the new one when ``jump`` (a tool that
    appears or teleports sweeps nothing)."""
    goal = ToolPose(tip=tip, tail=tail, radius=radius, frame=frame, jaw=jaw, jaw_radius=jaw_radius)
    start = goal
    if not jump:
        start = control_pose(control, k)
    control.tool_start[k] = start
    control.tool_last[k] = start
    control.tool_goal[k] = goal
    control.tool_a[k], control.tool_b[k], control.tool_radius[k] = tip, tail, radius
    control.tool_frame[k], control.tool_jaw[k], control.tool_jaw_radius[k] = frame, jaw, jaw_radius
    control.tool_active[k] = active


@ti.kernel
def interpolate_tools(control: ti.template(), begin: ti.f32, end: ti.f32):
    """A substep from fraction ``begin`` to ``end`` of the way between each tool's
    ``tool_start`` and ``tool_goal``: ``tool_last`` where it starts, the Control entry
    where it ends (the goal at ``end`` = 1)."""
    ti.loop_config(serialize=True)  # four tools: less than a thread-pool launch
    for k in range(MAX_TOOLS):
        start, goal = control.tool_start[k], control.tool_goal[k]
        control.tool_last[k] = pose_between(start, goal, begin)
        now = pose_between(start, goal, end)
        control.tool_a[k], control.tool_b[k], control.tool_frame[k] = now.tip, now.tail, now.frame
        control.tool_jaw[k] = now.jaw


@ti.func
def pose_motion(last, pose):
    """How far [m] the shaft's ends and the jaws' end moved from ``last`` to ``pose``."""
    return ti.max(
        (pose.tip - last.tip).norm(), (pose.tail - last.tail).norm(), (pose.jaw - last.jaw).norm()
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
def swept_shape_distance(control: ti.template(), slot, last, pose, x, p):
    """Signed distance [m] and push direction of a point now at ``p`` from shape
    ``slot`` of a tool now at ``pose``, the point having been at ``x`` when the tool was
    at ``last`` (the substep's start). For a round shape the direction is the one
    from the shape's axis to the point, unless the axis has moved past the point
    since the start (the two offsets point apart): then the point is pushed back to
    the side it started on and the distance is measured along that side (negative
    beyond the axis), so a fast tool pushes tissue ahead of it instead of through
    itself. Boxes use the nearest surface (:func:`shape_distance`)."""
    dist, grad = FAR, ti.Vector([0.0, 1.0, 0.0])
    if control.shape_kind[slot] == SHAPE_BOX:
        dist, grad = shape_distance(control, slot, pose, p)
    else:
        round_, a, b, r = round_shape(control, slot, pose)
        if round_:
            _was_round, a0, b0, _was_r = round_shape(control, slot, last)
            now = p - point_segment(a, b, p)
            before = x - point_segment(a0, b0, x)
            dist, grad = side_distance(now, before, r, ti.Vector([0.0, 1.0, 0.0]))
    return dist, grad


TOUCH = 1e-7
"""[m] Offsets from a shape's axis shorter than this count as on the axis (f32 noise
at the scale of a scene is about 1e-9 m; a fixed threshold keeps backends agreeing)."""


@ti.func
def side_distance(now, before, r, fallback):
    """Distance [m] of a point from a round shape of radius ``r`` given its offset
    from the shape's axis ``now`` and at the substep's start ``before``, and the
    direction to push it (:func:`swept_shape_distance`). A point on the axis now and
    at the start (a tool that appeared in tissue) goes along the unit ``fallback``."""
    length = now.norm()
    grad = fallback
    dist = length - r
    if length > TOUCH:
        grad = now / length
    if before.norm() > TOUCH and (before.dot(now) < 0.0 or length <= TOUCH):
        grad = before.normalized()
        dist = now.dot(grad) - r
    return dist, grad


TOOL_FRICTION = 1.0
"""Coulomb coefficient of tissue on an instrument (static and kinetic): a point
pressed by a tip moves on with the tip instead of sliding round it."""


@ti.func
def coulomb_friction(p, x, obstacle_motion, n, limit):
    """A point pushed to ``p`` [m] along the contact normal ``n`` (at ``x`` at the
    substep's start) with Coulomb friction (PBD friction, Müller et al. 2007 §3.5 as in
    Macklin et al. 2014 §6.1): its motion relative to the obstacle's
    (``obstacle_motion``) loses its tangential part when that is within ``limit`` [m]
    (friction coefficient × how far the contact pushed: it sticks), else that much of
    it."""
    relative = p - x - obstacle_motion
    tangential = relative - relative.dot(n) * n
    length = tangential.norm()
    if length <= limit:
        p -= tangential
    else:
        p -= tangential * (limit / length)
    return p


@ti.func
def push_out_of_tools(control: ti.template(), p, x, r):
    """A particle at ``p`` [m] (at ``x`` at the substep's start) of radius ``r`` [m]
    moved out of every active tool: onto the surface of each shape it is inside, on
    the side it came from (:func:`swept_shape_distance`), one shape after the other in
    table order (PBD projection, Müller et al. 2007 §3.4), again while a pass moved it
    (a push out of one shape may end in an overlapping one), at most
    :data:`MAX_TOOL_SHAPES` passes; particles outside the tool's bounding capsule are
    not tested further. Coulomb friction with the tool (:func:`coulomb_friction`)
    then acts along the tool's whole push (per shape, a second shape's friction would
    undo the first one's push where shapes meet). Returns the new position and 1 when
    a tool touched it (seed 000 Alg. 1 lines 13-14 then hold its goal)."""
    hit = 0
    for k in range(MAX_TOOLS):
        if control.tool_active[k]:  # nested: Taichi evaluates both sides of `and`
            pose, last = control_pose(control, k), control.tool_last[k]
            reach = bounding_radius(control, k, pose) + pose_motion(last, pose) + r
            if (p - point_segment(pose.tip, pose.tail, p)).norm_sqr() < reach * reach:
                entry = p
                for _ in range(MAX_TOOL_SHAPES):
                    moved = 0
                    for s in range(MAX_TOOL_SHAPES):
                        dist, grad = swept_shape_distance(
                            control, k * MAX_TOOL_SHAPES + s, last, pose, x, p
                        )
                        if dist < r:
                            p += (r - dist) * grad
                            moved = 1
                    hit |= moved
                    if not moved:
                        break
                push = p - entry
                depth = push.norm()
                if depth > 0.0:
                    limit = TOOL_FRICTION * depth
                    p = coulomb_friction(p, x, pose.tip - last.tip, push / depth, limit)
    return p, hit
