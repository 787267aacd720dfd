"""Grasping: particles between a grasper's closed jaws are held in the tool frame.

Seed 002 §3.4: "particles in the forceps' jaws are held in the tool frame" — hard
position constraints. When the jaws close, :func:`capture` takes every free
particle within reach of the jaw segment (from the tip ``length`` ahead, away from
the handle) and stores its position in the tool frame; from then on every
projection of the step (prediction, constraint sweeps, shape-matching passes, the
goal update) puts it at ``tip + R local`` (:func:`~taichi_lap.kernels.collision.particle_contact.hold_grasped`)
and flags it collided, so its goal follows (Alg. 1, lines 13-14). :func:`release`
frees them.
"""

import taichi as ti
from taichi_lap.kernels.collision.closest_points import point_segment
from taichi_lap.kernels.collision.particle_contact import FREE


@ti.kernel
def capture(
    model: ti.template(),
    state: ti.template(),
    control: ti.template(),
    tool: ti.i32,
    length: ti.f32,
    reach: ti.f32,
) -> ti.i32:
    """Hold every free movable particle whose sphere comes within ``reach`` [m] of the
    jaw segment of ``tool`` (``length`` [m] ahead of the tip); returns how many.
    Reads x; writes grasp_tool, grasp_local."""
    count = 0
    tip, frame = control.tool_a[tool], control.tool_frame[tool]
    end = tip - length * ti.Vector([frame[0, 2], frame[1, 2], frame[2, 2]])
    for i in range(model.particle_count):
        if model.inv_mass[i] > 0.0 and state.grasp_tool[i] == FREE:
            x = state.x[i]
            if (x - point_segment(tip, end, x)).norm() < reach + model.radius[i]:
                state.grasp_tool[i] = tool
                state.grasp_local[i] = frame.transpose() @ (x - tip)
                count += 1
    return count


@ti.kernel
def release(model: ti.template(), state: ti.template(), tool: ti.i32) -> ti.i32:
    """Free every particle ``tool`` holds; returns how many."""
    count = 0
    for i in range(model.particle_count):
        if state.grasp_tool[i] == tool:
            state.grasp_tool[i] = FREE
            count += 1
    return count
