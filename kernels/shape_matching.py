"""Goal-limiting cluster shape matching: seed 000 Algorithm 1, and the integration
every particle shares.

Per substep of length h:

* :func:`predict` — Alg. 1 lines 3-6: v += α (g - x)/h + h f_ext/m, p = x + h v,
  then contacts (which set the collided flag). α is the stiffness factor; particles
  outside any cluster have α = 0 and integrate as plain PBD. External forces are
  gravity and, for mass-spring particles, seed 001's damped springs.
* :func:`match_clusters` — lines 7-11: per cluster the mass centre p_cm of the
  predicted positions, A = Σ m_i (p_i - p_cm)(x_i^0 - x_cm^0)^T (Eq. 1) and the
  rotation R of its polar decomposition (Müller et al. 2005), extracted by the
  warm-started iteration of :mod:`taichi_lap.kernels.rotation`, which gives
  det R = +1 also for inverted clusters.
* :func:`project_to_goals` — iterations: with ``shape_iterations`` n > 1, lines 7-23
  are repeated n times per substep and the first n - 1 passes move p towards the
  limited goal, p += α (g - p), then re-apply contacts. This is the position-level
  shape matching of PBD (Müller et al. 2007; Macklin et al. 2014 §5); it carries
  support through overlapping clusters, which the velocity pull alone (n = 1, the
  literal Alg. 1) transmits only weakly. n = 1 is Alg. 1 exactly.
* :func:`update_goals` — lines 12-25 (fused with the next substep's prediction of
  particles without springs, to read each particle once): η_i = η_contact if the particle collided
  this substep else max(η_i - R_r, 0) (once per particle per substep); cluster goals
  g^c = R (x^0 - x_cm^0) + p_cm (Eq. 2) averaged over the n_c clusters sharing the
  particle (gathered, not scattered); g = g^c + η (p - g^c); then v = (p - x)/h,
  x = p, with the health check.

Seed 000 §7 tunes η = 0.7 for the value set on contact; Alg. 1 writes 1 (hold the
vertex exactly). Both are the ``eta_on_contact`` material parameter.

Parallel loops over a count held in a field (``chunk_count``, ``cluster_count``) run
over the field's capacity and skip the indices past the count: with a constant end
Vulkan launches one thread per index instead of a fixed grid of 65,536
(docs/architecture.md, loop bounds).
"""

import taichi as ti
from taichi_lap.kernels.collision.particle_contact import hold_grasped, resolve_contacts
from taichi_lap.kernels.health import report_fault
from taichi_lap.kernels.mass_spring import spring_velocity
from taichi_lap.kernels.rotation import extract_rotation, quaternion_to_matrix


@ti.func
def predict_particle(
    model: ti.template(), state: ti.template(), control: ti.template(), i, gravity, h
):
    """Alg. 1 lines 4-5 for particle ``i``, then contacts: writes p and collided."""
    x = state.x[i]
    p = x
    hit = 0
    if model.inv_mass[i] > 0.0:
        v = state.v[i] + model.stiffness[i] * (state.goal[i] - x) / h + h * gravity
        if ti.static(model.spring_count > 0):
            v = spring_velocity(model, state, i, v, h)
        v *= ti.max(1.0 - model.damping[i] * h, 0.0)
        p, hit = resolve_contacts(model, state, control, i, x + h * v, x)
    state.p[i] = p
    state.collided[i] = hit


@ti.func
def has_springs(model: ti.template(), i):
    result = False
    if ti.static(model.spring_count > 0):
        result = model.spring_start[i + 1] > model.spring_start[i]
    return result


@ti.kernel
def predict(
    model: ti.template(),
    state: ti.template(),
    control: ti.template(),
    gravity: ti.math.vec3,
    h: ti.f32,
    springs_only: ti.i32,
):
    """Alg. 1 lines 3-6 and contacts for every particle, or only for those with
    springs when the others were predicted by :func:`update_goals`. Reads x, v, goal;
    writes p, collided. ``gravity`` [m/s²], ``h`` [s]."""
    ti.loop_config(serialize=ti.static(model.serial))
    for i in range(model.particle_count):
        if not springs_only or has_springs(model, i):
            predict_particle(model, state, control, i, gravity, h)


@ti.kernel
def cluster_partial_sums(model: ti.template(), state: ti.template()):
    """Alg. 1 lines 8-10 over each chunk of a cluster's members: Σ m (p - x_cm^0) and
    Σ m (p - x_cm^0) q^T (any origin works in Eq. 1 because Σ m q = 0); m is the
    member's mass in the cluster (0 once dissection took it out), q its stored
    offset plus the cluster's ``cluster_rest_shift`` (0 until members leave). Reads
    p; writes chunk_first, chunk_moment."""
    ti.loop_config(serialize=ti.static(model.serial))
    for chunk in range(model.chunk_cluster.shape[0]):
        if chunk < model.chunk_count[None]:
            c = model.chunk_cluster[chunk]
            rest_center, shift = model.cluster_rest_center[c], model.cluster_rest_shift[c]
            first = ti.Vector([0.0, 0.0, 0.0])
            moment = ti.Matrix.zero(ti.f32, 3, 3)
            for k in range(model.chunk_begin[chunk], model.chunk_end[chunk]):
                i = model.cluster_member[k]
                m = model.cluster_member_mass[k]
                d = state.p[i] - rest_center
                first += m * d
                moment += m * d.outer_product(model.cluster_rest_offset[k] + shift)
            state.chunk_first[chunk] = first
            state.chunk_moment[chunk] = moment


@ti.kernel
def cluster_frames(model: ti.template(), state: ti.template()):
    """Alg. 1 lines 8-11 per cluster: p_cm and R from the chunk sums (in order).
    Reads and writes cluster_quaternion (the warm start); writes cluster_center (p_cm)
    and cluster_rotation (R)."""
    ti.loop_config(serialize=ti.static(model.serial))
    for c in range(model.cluster_rest_center.shape[0]):
        if c < model.cluster_count[None]:
            first = ti.Vector([0.0, 0.0, 0.0])
            moment = ti.Matrix.zero(ti.f32, 3, 3)
            for chunk in range(model.cluster_chunk_begin[c], model.cluster_chunk_end[c]):
                first += state.chunk_first[chunk]
                moment += state.chunk_moment[chunk]
            state.cluster_center[c] = model.cluster_rest_center[c] + first / ti.max(
                model.cluster_mass[c], 1e-30
            )
            # R is scale-invariant: normalise A so f32 stays accurate for tiny clusters
            q = extract_rotation(
                moment / ti.max(ti.sqrt((moment * moment).sum()), 1e-30),
                state.cluster_quaternion[c],
            )
            state.cluster_quaternion[c] = q
            state.cluster_rotation[c] = quaternion_to_matrix(q)


def match_clusters(model, state):
    """Alg. 1 lines 7-11 for every cluster (two launches: chunk sums, then frames)."""
    cluster_partial_sums(model, state)
    cluster_frames(model, state)


@ti.func
def averaged_cluster_goal(model: ti.template(), state: ti.template(), i, p):
    """Mean over the clusters containing particle ``i`` of g^c (Alg. 1 lines 18, 21-23);
    ``p`` when the particle is in no cluster."""
    begin, end = model.membership_start[i], model.membership_start[i + 1]
    goal = p
    if end > begin:
        total = ti.Vector([0.0, 0.0, 0.0])
        for j in range(begin, end):
            c = model.membership_cluster[j]
            offset = model.membership_offset[j] + model.cluster_rest_shift[c]
            total += state.cluster_rotation[c] @ offset + state.cluster_center[c]
        goal = total / (end - begin)
    return goal


@ti.func
def limited_goal(model: ti.template(), state: ti.template(), i, p):
    """Alg. 1 lines 13-19 for particle ``i`` at ``p``: the recovery factor η after this
    substep (η_contact if collided, else max(η - R_r, 0)) and the goal
    g = g^c + η (p - g^c). Averaging before blending equals blending per cluster
    then averaging (the blend is linear)."""
    eta = ti.max(state.eta[i] - model.recover_rate[i], 0.0)
    if state.collided[i]:
        eta = model.eta_on_contact[i]
    goal = averaged_cluster_goal(model, state, i, p)
    return goal + eta * (p - goal), eta


@ti.kernel
def project_to_goals(model: ti.template(), state: ti.template(), control: ti.template()):
    """An extra shape-matching iteration: p += α (g - p) towards the limited goal, then
    contacts. Reads and writes p (each particle only its own), collided."""
    ti.loop_config(serialize=ti.static(model.serial))
    for i in range(model.particle_count):
        if model.inv_mass[i] > 0.0 and model.membership_start[i + 1] > model.membership_start[i]:
            p = state.p[i]
            goal, _ = limited_goal(model, state, i, p)
            p, hit = resolve_contacts(
                model, state, control, i, p + model.stiffness[i] * (goal - p), state.x[i]
            )
            state.p[i] = p
            if hit:
                state.collided[i] = 1


@ti.kernel
def update_goals(
    model: ti.template(),
    state: ti.template(),
    control: ti.template(),
    h: ti.f32,
    speed_limit: ti.f32,
    gravity: ti.math.vec3,
    predict_next: ti.i32,
):
    """Alg. 1 lines 12-25: recovery factor, limited goals, velocity and position
    update, health check; with ``predict_next`` also the next substep's prediction of
    every particle without springs (those need all neighbours updated first). Reads
    p, collided, eta, cluster frames; writes eta, goal, v, x, fault (and p, collided)."""
    ti.loop_config(serialize=ti.static(model.serial))
    for i in range(model.particle_count):
        p, _ = hold_grasped(state, control, i, state.p[i])  # collisions may have moved it
        goal, eta = limited_goal(model, state, i, p)
        state.eta[i] = eta
        state.goal[i] = goal
        v = (p - state.x[i]) / h
        report_fault(state, i, p, v, speed_limit)
        state.v[i] = v
        state.x[i] = p
        if predict_next and not has_springs(model, i):
            predict_particle(model, state, control, i, gravity, h)
