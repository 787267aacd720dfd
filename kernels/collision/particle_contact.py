"""Particle contact with kinematic tools and environment planes.

Position-level projection in the PBD manner (Müller et al. 2007, §3.4): a particle
of radius r inside one of a tool's shapes (:mod:`.tool_shapes`) is moved to its
surface and flagged as collided, which holds its shape-matching goal (seed 000
Alg. 1, lines 13-14). Planes (the
abdominal wall, the table) push particles out with Coulomb friction on the
displacement of the substep (Macklin et al. 2014, §6.1); they do not flag
collisions, so tissue resting on them keeps recovering its shape. A particle a
grasper holds (:mod:`taichi_lap.kernels.grasp`) is put at its place in the tool
frame last, whatever pushed it.
"""

import taichi as ti
from taichi_lap.kernels.collision.tool_shapes import push_out_of_tools

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
            move = p - x
            tangential = move - move.dot(n) * n
            length = tangential.norm()
            limit = model.plane_friction[k] * depth
            if length <= limit:
                p -= tangential
            else:
                p -= tangential * (limit / length)
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
    tools, planes, then the grasp. Returns the projected position and the collided
    flag."""
    r = model.radius[i]
    p, hit = push_out_of_tools(control, p, r)
    p = push_out_of_planes(model, p, x, r)
    p, held = hold_grasped(state, control, i, p)
    return p, hit | held
