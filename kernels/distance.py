"""Distance constraints (truss struts, sheet edges) and long-range attachments.

Distance constraint C = |p_i - p_j| - L with stiffness k (Müller et al. 2007,
§3.3); the truss gives every strut its own k (seed 000 Alg. 2). Two solvers:

* :func:`jacobi_sweep` — each particle gathers the corrections of its constraints
  and applies their average scaled by the over-relaxation ω (Macklin et al. 2014,
  "Unified particle physics", §4.2: Δx_i = ω/n_i Σ Δx_ij), which seed 000 §7 uses;
  reads one buffer, writes the other, so it is deterministic and race-free.
* :func:`gauss_seidel_color` — graph-coloured Gauss-Seidel: constraints of one
  colour share no particle and are projected in parallel, in place.

Both then apply the relaxed LRA (seed 000 Eq. 3) and the contacts.
"""

import taichi as ti
from taichi_lap.kernels.collision.particle_contact import resolve_contacts
from taichi_lap.kernels.lra import lra_correction


@ti.func
def distance_delta(pi, pj, wi, wj, rest, stiffness):
    """Correction of particle i for one distance constraint (inverse masses wi, wj)."""
    delta = ti.Vector([0.0, 0.0, 0.0])
    d = pi - pj
    length = d.norm()
    w = wi + wj
    if length > 1e-9 and w > 0.0:
        delta = -stiffness * wi / w * (length - rest) * d / length
    return delta


@ti.func
def distance_correction(model: ti.template(), positions: ti.template(), i, p):
    """The sum of the corrections of particle ``i``'s distance constraints at ``p``
    [m] (their other ends read from ``positions``), and how many there are."""
    begin, end = model.distance_begin[i], model.distance_end[i]
    delta = ti.Vector([0.0, 0.0, 0.0])
    for e in range(begin, end):
        j = model.distance_other[e]
        delta += distance_delta(
            p,
            positions[j],
            model.inv_mass[i],
            model.inv_mass[j],
            model.distance_rest[e],
            model.distance_stiffness[e],
        )
    return delta, end - begin


@ti.func
def constrained(model: ti.template(), i):
    """Whether particle ``i`` has a distance constraint or an LRA. A sweep leaves the
    others where they are (shape-matched particles: their contacts were resolved
    where they last moved, by the prediction and the goal projections)."""
    return model.distance_end[i] > model.distance_begin[i] or model.lra_end[i] > model.lra_begin[i]


@ti.func
def finish_particle(
    model: ti.template(), state: ti.template(), control: ti.template(), source: ti.template(), i, p
):
    """LRA then contacts for particle ``i``; flags the collision."""
    p += lra_correction(model, source, i, p)
    p, hit = resolve_contacts(model, state, control, i, p, state.x[i])
    if hit:
        state.collided[i] = 1
    return p


@ti.kernel
def jacobi_sweep(
    model: ti.template(),
    state: ti.template(),
    control: ti.template(),
    source: ti.template(),
    target: ti.template(),
    over_relaxation: ti.f32,
):
    """One averaged Jacobi iteration over all distance constraints and LRAs, reading
    ``source`` and writing ``target`` (both particle position fields); the particles
    not :func:`constrained` are copied."""
    ti.loop_config(serialize=ti.static(model.serial_sweeps))
    for i in range(model.particle_count):
        p = source[i]
        if model.inv_mass[i] > 0.0 and constrained(model, i):
            delta, count = distance_correction(model, source, i, p)
            if count > 0:
                p += over_relaxation * delta / count
            p = finish_particle(model, state, control, source, i, p)
        target[i] = p


@ti.kernel
def gauss_seidel_color(model: ti.template(), state: ti.template(), begin: ti.i32, end: ti.i32):
    """Project the constraints ``begin..end`` of one colour in place on ``state.p``."""
    ti.loop_config(serialize=ti.static(model.serial))
    for e in range(begin, end):
        i, j = model.colored_pair[e][0], model.colored_pair[e][1]
        pi, pj = state.p[i], state.p[j]
        wi, wj = model.inv_mass[i], model.inv_mass[j]
        rest, k = model.colored_rest[e], model.colored_stiffness[e]
        state.p[i] = pi + distance_delta(pi, pj, wi, wj, rest, k)
        state.p[j] = pj + distance_delta(pj, pi, wj, wi, rest, k)


@ti.kernel
def gauss_seidel_finish(model: ti.template(), state: ti.template(), control: ti.template()):
    """LRA and contacts after a Gauss-Seidel sweep, per :func:`constrained` particle,
    in place."""
    ti.loop_config(serialize=ti.static(model.serial))
    for i in range(model.particle_count):
        if model.inv_mass[i] > 0.0 and constrained(model, i):
            state.p[i] = finish_particle(model, state, control, state.p, i, state.p[i])


@ti.kernel
def copy_positions(source: ti.template(), target: ti.template()):
    for i in source:
        target[i] = source[i]
