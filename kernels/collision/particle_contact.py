"""Particle contact with kinematic tools, environment planes and fixed tubes.

Position-level projection in the PBD manner (Müller et al. 2007, §3.4): a particle
closer to one of a tool's shapes (:mod:`.tool_shapes`) than its contact radius (the
drawn surface's distance from it: 0 on a surface through the particles, a tube's
radius) is moved out, on the side it came from, and flagged as collided, which holds
its shape-matching goal (seed 000 Alg. 1, lines 13-14). Planes (the abdominal wall,
the table) push particles out with Coulomb friction on the displacement of the
substep (Macklin et al. 2014, §6.1); they do not flag collisions, so tissue resting
on them keeps recovering its shape. A particle a
grasper holds (:mod:`taichi_lap.kernels.grasp`) is put at its place in the tool
frame last, whatever pushed it. The environment's fixed tubes (a colon beneath the
intestine's loops) are capsule chains that push particles out as the planes do.

The intestine of seed 001 is drawn as a tube around its row of masses, which lie
several tube radii apart: :func:`push_tubes_out_of_tools` keeps every segment of the
row, a capsule of the masses' radius, outside the tools, so a tool cannot pass
between two masses.
"""

import taichi as ti
from taichi_lap.kernels.collision.closest_points import point_segment, segment_segment
from taichi_lap.kernels.collision.tool_shapes import (
    control_pose,
    coulomb_friction,
    push_out_of_tools,
    round_shape,
    side_distance,
)

from taichi_lap.core.instruments import MAX_TOOL_SHAPES, MAX_TOOLS

FREE = -1
"""``State.grasp_tool`` of a particle no tool holds."""


@ti.func
def push_out_of_planes(model: ti.template(), p, x, r):
    """Keep a particle of radius ``r`` [m] above every environment plane; friction
    removes (static) or shortens (kinetic) the tangential part of ``p - x``."""
    for k in range(model.plane_count):
        n = model.plane_normal[k]
        depth = r - (p - model.plane_point[k]).dot(n)
        if depth > 0:
            p += depth * n
            still = ti.Vector([0.0, 0.0, 0.0])
            p = coulomb_friction(p, x, still, n, model.plane_friction[k] * depth)
    return p


@ti.func
def push_out_of_environment_tubes(model: ti.template(), p, x, r):
    """Keep a particle of radius ``r`` [m] outside every segment capsule of the
    environment's fixed tubes (pushed along the line from the segment's closest point,
    Ericson 2004 §5.1.2), with Coulomb friction as on the planes."""
    for k in range(model.environment_count):
        d = p - point_segment(model.environment_a[k], model.environment_b[k], p)
        gap = d.norm()
        depth = model.environment_radius[k] + r - gap
        if depth > 0 and gap > 1e-9:
            n = d / gap
            p += depth * n
            still = ti.Vector([0.0, 0.0, 0.0])
            p = coulomb_friction(p, x, still, n, model.environment_friction[k] * depth)
    return p


@ti.func
def hold_grasped(state: ti.template(), control: ti.template(), i, p):
    """Particle ``i`` at ``p``: where its tool holds it (tip + R local, seed 002 §3.4)
    and 1, or ``p`` and 0 when no tool holds it."""
    held = 0
    tool = state.grasp_tool[i]
    if tool != FREE:
        p = control.tool_a[tool] + control.tool_frame[tool] @ state.grasp_local[i]
        held = 1
    return p, held


@ti.func
def resolve_contacts(model: ti.template(), state: ti.template(), control: ti.template(), i, p, x):
    """All contacts of particle ``i`` at predicted ``p`` (previous position ``x``):
    tools, planes, fixed tubes, then the grasp. Returns the projected position and the collided
    flag."""
    p, hit = push_out_of_tools(control, p, x, model.contact_radius[i])
    p = push_out_of_planes(model, p, x, model.radius[i])
    p = push_out_of_environment_tubes(model, p, x, model.radius[i])
    p, held = hold_grasped(state, control, i, p)
    return p, hit | held


@ti.func
def segment_push(control: ti.template(), p_i, p_j, x_i, x_j, r_i, r_j, w_i, w_j):
    """Particle i's share of pushing the tube segment i-j (now p_i-p_j, at the
    substep's start x_i-x_j, radii r_i, r_j [m], inverse masses w_i, w_j) out of every
    round shape of every active tool: the segments' closest points (Ericson 2004
    §5.1.9) kept the shape's radius plus the tube's apart, on the side they started on
    (:func:`~.tool_shapes.side_distance`), as a PBD projection spread by the segment
    parameter s (b = 1 - s, s; Δ_i = λ w_i b_i n, λ = depth / Σ w b²). Returns (the
    summed correction, the number of contacts)."""
    delta, count = ti.Vector([0.0, 0.0, 0.0]), 0
    for k in range(MAX_TOOLS):
        if control.tool_active[k]:
            pose, last = control_pose(control, k), control.tool_last[k]
            for slot in range(k * MAX_TOOL_SHAPES, (k + 1) * MAX_TOOL_SHAPES):
                round_, a, b, r = round_shape(control, slot, pose)
                if round_:
                    _was_round, a0, b0, _was_r = round_shape(control, slot, last)
                    s, u, on_tube, on_tool = segment_segment(p_i, p_j, a, b)
                    before = x_i + s * (x_j - x_i) - (a0 + u * (b0 - a0))
                    reach = r + (1.0 - s) * r_i + s * r_j
                    up = ti.Vector([0.0, 1.0, 0.0])
                    dist, n = side_distance(on_tube - on_tool, before, reach, up)
                    denom = w_i * (1.0 - s) ** 2 + w_j * s * s
                    if dist < 0.0 and denom > 0.0:
                        delta += -dist / denom * w_i * (1.0 - s) * n
                        count += 1
    return delta, count


@ti.kernel
def push_tubes_out_of_tools(model: ti.template(), state: ti.template(), control: ti.template()):
    """Every tube segment out of the tools (module docstring): each tube particle
    gathers its share of its two segments' pushes (averaged, Jacobi) from p into
    p_next, then takes it and is flagged collided. Reads p, x; writes p_next, p,
    collided."""
    ti.loop_config(serialize=ti.static(model.serial))
    for n in range(model.tube_particle_count):
        i = model.tube_particle[n]
        delta, count = ti.Vector([0.0, 0.0, 0.0]), 0
        for side in ti.static(range(2)):
            j = model.tube_prev[n] if side == 0 else model.tube_next[n]
            if j >= 0:
                d, c = segment_push(
                    control,
                    state.p[i],
                    state.p[j],
                    state.x[i],
                    state.x[j],
                    model.contact_radius[i],
                    model.contact_radius[j],
                    model.inv_mass[i],
                    model.inv_mass[j],
                )
                delta += d
                count += c
        state.p_next[i] = state.p[i] + delta / ti.max(count, 1)
        if count > 0:
            state.collided[i] = 1
    ti.loop_config(serialize=ti.static(model.serial))
    for n in range(model.tube_particle_count):
        i = model.tube_particle[n]
        state.p[i] = state.p_next[i]
