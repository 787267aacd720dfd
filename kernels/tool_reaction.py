"""The force the tissue pushes a tool with, for the haptic coupling (seed 002 §3.4;
:mod:`taichi_lap.haptics.bridge`), and which organs touch it.

PBD has no forces: each constraint moves its particles by a correction Δ per
substep h. Read as the force that would move the particle's haptic mass r m by Δ in
h, r m Δ / h², the correction of each constraint a particle takes part in becomes
the pull of a spring; the tool feels the sum of these pulls over the particles it
holds out of their place. r is the material's ``haptic_mass_ratio`` (seed 002 sets
the particles' mass per tissue for the feel; the block's plain pull, r = 1, was
about 3 N/m, below anything a hand feels).
"""

import taichi as ti
from taichi_lap.kernels.collision.tool_shapes import control_pose, tool_distance
from taichi_lap.kernels.distance import distance_correction
from taichi_lap.kernels.lra import lra_correction
from taichi_lap.kernels.mass_spring import spring_force


@ti.func
def constraint_pull(model: ti.template(), state: ti.template(), i, h):
    """The pull [N] on particle ``i`` of the constraints the next substep ``h`` [s]
    would project at x, as a force on its haptic mass (module docstring): shape
    matching α (g - x) (seed 000 Alg. 1 line 4), each distance constraint's
    correction (truss struts, sheet edges; every one, not their Jacobi average), and
    the relaxed long-range attachments (seed 000 Eq. 3); plus the mass-spring
    springs' force (already in newtons)."""
    x = state.x[i]
    correction = model.stiffness[i] * (state.goal[i] - x)
    if ti.static(model.distance_count > 0):
        correction += distance_correction(model, state.x, i, x)[0]
    if ti.static(model.lra_count > 0):
        correction += lra_correction(model, state.x, i, x)
    force = model.haptic_mass_ratio[i] * correction / (model.inv_mass[i] * h * h)
    if ti.static(model.spring_count > 0):
        force += spring_force(model, state, i)
    return force


@ti.kernel
def measure_tool_contact(
    model: ti.template(), state: ti.template(), control: ti.template(), k: ti.i32, h: ti.f32
):
    """``control.tool_reaction[k]``: the force [N] the tissue touching tool k pushes it
    with, the sum over the collided particles near the tool of their
    :func:`constraint_pull`, weighted 1 up to a particle radius from the tool's
    contact surface and down to 0 a radius further (a particle crossing that edge
    changes the force smoothly; a hard edge left a 10 % ripple in a held stylus's
    force); ``control.tool_contacts[k, organ]``: how many of those particles (weight
    above 0) each organ has (the training metrics' instrument contacts). Reads x,
    goal, collided (after a step)."""
    control.tool_reaction[k] = ti.Vector([0.0, 0.0, 0.0])
    ti.loop_config(serialize=ti.static(model.serial))
    for organ in range(control.tool_contacts.shape[1]):
        control.tool_contacts[k, organ] = 0
    pose = control_pose(control, k)
    ti.loop_config(serialize=ti.static(model.serial))
    for i in range(model.particle_count):
        if state.collided[i] and model.inv_mass[i] > 0.0:
            dist, _ = tool_distance(control, k, pose, state.x[i])
            reach = model.contact_radius[i] + 2.0 * model.radius[i]
            weight = ti.min(1.0, (reach - dist) / model.radius[i])
            if weight > 0.0:
                control.tool_reaction[k] += weight * constraint_pull(model, state, i, h)
                ti.atomic_add(control.tool_contacts[k, model.particle_organ[i]], 1)
