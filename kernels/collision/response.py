"""Detection and response of tissue collision after the broad phase: the
bounding-sphere and sphere phases of seed 000 §4.1 and the impulse response of §4.3,
for the spheres of :mod:`~taichi_lap.kernels.collision.spheres` or the features of the
polygon baseline (:mod:`~taichi_lap.kernels.collision.polygon`).

:func:`detect_and_respond` runs, for the active triangles of the broad phase
(:mod:`~taichi_lap.kernels.collision.broad_phase`), per triangle (gathered: each
triangle computes its own side of every pair, so there are no float atomics and runs
are bit-reproducible), then per particle:

* bounding-sphere phase (§4.1): listed pairs whose bounding spheres, grown by their
  motion over the substep, overlap, and that face each other at the substep's start
  (opposite normals, each centroid in front of the other): the back faces of a thin
  body lie inside the front faces' spheres. A triangle meets a tool when its bounding
  sphere grown by the tool's motion over the substep reaches the tool's union of
  shapes and its start normal faces the tool at its previous pose.
* sphere phase: the spheres overlap at some time of the substep (linear motion:
  continuous for sphere pairs); a sphere's centre is closer than its radius to a
  tool's union of implicit shapes. The line to the other sphere's centre (to the
  tool) must leave through the triangle's own cap (``sphere_cone``): outside that
  cone a circumsphere bulges far above its triangle.
* response (§4.3): back up along the displacements to the first contact, exchange a
  perfectly inelastic normal impulse (momentum conserved; a tool is kinematic, of
  infinite mass, and static within the substep because Control carries poses, not
  velocities), move the spheres along their new velocities to the end of the
  substep, push out what overlap remains (split by inverse mass), and translate the
  triangle with its sphere. Several contacts of one triangle are averaged (Jacobi).
* per particle: the translations of the triangle corners bound to it, averaged with
  the binding weights, move p; the particle is flagged collided (the η path of
  Alg. 1, as the particle contacts of
  :mod:`~taichi_lap.kernels.collision.particle_contact` do).

Velocities enter as displacements over the substep (v h = p - x), so h cancels.
Lengths in metres.

Parallel loops over a count held in a field (``active_count``, ``touched_count``) run
over the field's capacity and skip the indices past the count: with a constant end
Vulkan launches one thread per index instead of a fixed grid of 65,536
(docs/architecture.md, loop bounds).
"""

import taichi as ti
from taichi_lap.kernels.collision.broad_phase import broad_overlap, facing
from taichi_lap.kernels.collision.closest_points import segment_triangle
from taichi_lap.kernels.collision.polygon import add_corner, polygon_pair, polygon_tool
from taichi_lap.kernels.collision.spheres import (
    C_BOUNDING,
    C_TISSUE,
    C_TOOL,
    C_TOOL_CANDIDATES,
    C_TRIANGLES,
    POLYGON,
    bounding_overlap,
    in_cone,
)
from taichi_lap.kernels.skinning import skin
from taichi_lap.kernels.collision.tool_shapes import (
    control_pose,
    pose_motion,
    round_shape,
    shape_distance,
    side_distance,
    tool_distance,
    TOOL_FRICTION,
    TOUCH,
    coulomb_friction,
)

from taichi_lap.core.instruments import MAX_TOOL_SHAPES, MAX_TOOLS, SHAPE_BOX

CORNER_PUSH_LIMIT = 3.0
"""Most a corner moves in one tool push, in units of the push's depth. A triangle of
free corners of equal mass moves each by at most 1.2 depths (λ w b with b the contact's
barycentric weights); a corner beside fixed ones (a mesentery triangle at its root)
would take depth / b, unbounded as the contact nears the fixed edge: a tool shaft swept
through the intestine's root threw such corners out faster each substep until the
simulation faulted. Capped, the tool sinks into what cannot move instead."""


@ti.func
def exchange_impulse(v_t, v_u, normal, w_t, w_u):
    """§4.3: perfectly inelastic normal impulse j = max(-(v_t - v_u)·n, 0) / (w_t + w_u)
    between bodies of inverse masses w_t, w_u (0: kinematic); ``normal`` points from u
    to t. Returns the new velocities; m_t v_t + m_u v_u is conserved."""
    v_t_new, v_u_new = v_t, v_u
    w = w_t + w_u
    if w > 0.0:
        j = ti.max(-(v_t - v_u).dot(normal), 0.0) / w
        v_t_new = v_t + j * w_t * normal
        v_u_new = v_u - j * w_u * normal
    return v_t_new, v_u_new


@ti.func
def contact_time(d0, e, reach):
    """Smallest τ ∈ [0, 1] with |d0 + τ e| = reach (0 when already within reach)."""
    tau = 0.0
    c = d0.dot(d0) - reach * reach
    a = e.dot(e)
    if c > 0.0 and a > 1e-30:
        b = d0.dot(e)
        disc = ti.max(b * b - a * c, 0.0)
        tau = ti.math.clamp((-b - ti.sqrt(disc)) / a, 0.0, 1.0)
    return tau


@ti.func
def safe_direction(d, fallback):
    n = d.norm()
    return ti.select(n > 1e-12, d / ti.max(n, 1e-12), fallback)


@ti.func
def sphere_pair_translation(c_t, r_t, disp_t, w_t, c_u, r_u, disp_u, w_u, fallback):
    """§4.3 for two spheres ending at c_t, c_u [m] after moving by disp_t, disp_u over
    the substep: (1 if they touch during it, translation of sphere t [m]). Swapping the
    arguments gives sphere u's side exactly (its translation times its mass cancels
    ours)."""
    reach = r_t + r_u
    d0 = (c_t - disp_t) - (c_u - disp_u)
    e = disp_t - disp_u
    a = e.dot(e)
    closest = 1.0
    if a > 1e-30:
        closest = ti.math.clamp(-d0.dot(e) / a, 0.0, 1.0)
    hit = 0
    translation = ti.Vector([0.0, 0.0, 0.0])
    if (d0 + closest * e).norm() < reach and w_t + w_u > 0.0:
        hit = 1
        tau = contact_time(d0, e, reach)
        normal = safe_direction(d0 + tau * e, fallback)
        v_t, v_u = exchange_impulse(disp_t, disp_u, normal, w_t, w_u)
        final_t = c_t - disp_t + tau * disp_t + (1.0 - tau) * v_t
        final_u = c_u - disp_u + tau * disp_u + (1.0 - tau) * v_u
        gap = final_t - final_u
        dist = gap.norm()
        if dist < reach:
            final_t += (reach - dist) * w_t / (w_t + w_u) * safe_direction(gap, normal)
        translation = final_t - c_t
    return hit, translation


@ti.func
def sphere_tool_translation(control: ti.template(), tool, pose, center, r, disp):
    """§4.3 against a kinematic tool (its union of shapes at its current ``pose``). When
    the sphere (centre ``center`` [m], radius r, displacement ``disp``) started the
    substep clear of the tool: back up to where it first touched (8 bisections of
    sdf(start + τ disp) - r), remove the approaching normal velocity and move on.
    When the tool moved into it (no contact time to find), start from the end
    position. Then push out what overlap remains (two projections). Returns the
    translation of the sphere [m]; one distance call site (compile time)."""
    start = center - disp
    lo, hi = 0.0, 1.0
    final = center
    clear = False
    for it in range(12):  # 0: start, 1-8: bisection, 9: contact normal, 10-11: push out
        if it == 0 or it >= 10 or clear:
            point = start + 0.5 * (lo + hi) * disp
            if it == 0:
                point = start
            elif it == 9:
                point = start + hi * disp
            elif it >= 10:
                point = final
            d, g = tool_distance(control, tool, pose, point)
            if it == 0:
                clear = d > r
            elif it <= 8:
                if d > r:
                    lo = 0.5 * (lo + hi)
                else:
                    hi = 0.5 * (lo + hi)
            elif it == 9:
                v, _ = exchange_impulse(disp, ti.Vector([0.0, 0.0, 0.0]), g, 1.0, 0.0)
                final = point + (1.0 - hi) * v
            elif d < r:
                final += (r - d) * g
    return final - center


@ti.func
def facing_pair(coll: ti.template(), t, u):
    """t and u face each other at the substep's start (:func:`facing`)."""
    return facing(
        coll.start_centroid[t], coll.start_normal[t], coll.start_centroid[u], coll.start_normal[u]
    )


@ti.func
def add_to_corners(acc, hits, translation):
    """Every row of the local corner accumulator ``acc`` += ``translation``."""
    for k in ti.static(range(3)):
        acc, hits = add_corner(acc, hits, k, translation)
    return acc, hits


@ti.func
def sphere_pair(coll: ti.template(), t, u):
    """Sphere phase and response of t against u: (1 on contact, t's translation)."""
    d = coll.sphere_center[u] - coll.sphere_center[t]
    direction = d / ti.max(d.norm(), 1e-30)
    hit, translation = 0, ti.Vector([0.0, 0.0, 0.0])
    if in_cone(coll, t, direction) and in_cone(coll, u, -direction):
        hit, translation = sphere_pair_translation(
            coll.sphere_center[t],
            coll.sphere_radius[t],
            coll.displacement[t],
            coll.tri_inv_mass[t],
            coll.sphere_center[u],
            coll.sphere_radius[u],
            coll.displacement[u],
            coll.tri_inv_mass[u],
            coll.start_normal[t],
        )
    return hit, translation


@ti.func
def tissue_contacts(coll: ti.template(), rows: ti.template(), t, acc, hits):
    """Bounding-sphere and sphere phases of triangle t against its listed partners
    whose broad spheres overlap its own in this substep (those
    :func:`~taichi_lap.kernels.collision.broad_phase.mark_active` made active, whose
    spheres are up to date; another partner's are from the last substep it was
    active, or from before a reset); adds t's side of every contact to its corner
    accumulators. Pairs with a triangle a tool holds (``tool_held``: the tool's
    contact that holds touched it in this substep) are left out: the tool places it.
    Returns (bounding, contacts, acc, hits)."""
    bounding, contacts = 0, 0
    moved = ti.Vector([0.0, 0.0, 0.0])  # sphere methods: Σ translations of t
    for m in range(rows.start[t], rows.start[t + 1]):
        u = rows.partner[m]
        held = 0
        if ti.static(not coll.method_tools):
            held = coll.tool_held[t] | coll.tool_held[u]
        if (
            not held
            and broad_overlap(coll, t, u, 0.0)
            and bounding_overlap(coll, t, u)
            and facing_pair(coll, t, u)
        ):
            bounding += 1
            if ti.static(coll.method == POLYGON):
                n, acc, hits = polygon_pair(coll, t, u, acc, hits)
                contacts += n
            else:
                hit, translation = sphere_pair(coll, t, u)
                moved += translation
                contacts += hit
    if ti.static(coll.method != POLYGON):
        for k in ti.static(range(3)):
            for c in ti.static(range(3)):
                acc[k, c] += moved[c]
            hits[k] += contacts
    return bounding, contacts, acc, hits


@ti.func
def surface_tool(
    model: ti.template(),
    state: ti.template(),
    coll: ti.template(),
    control: ti.template(),
    t,
    k,
    pose,
    last,
    acc,
    hits,
):
    """Contact that holds: triangle t of the drawn surface against tool k at ``pose``
    (at ``last`` when the substep began). The axis of every round shape pushes the
    triangle's closest point (segment-triangle closest points, Ericson 2004 §5.1.9)
    out to the shape's radius plus the surface's thickness there, on the side it
    started the substep on (:func:`~.tool_shapes.side_distance`: a tool that moved
    past the surface within the substep pushes it ahead instead of through), spread
    over the corners as a PBD projection (Müller et al. 2007 §3.4): corner j moves by
    λ w_j b_j n with b the barycentric weights, w the corners' inverse masses and
    λ = depth / Σ w_j b_j², each corner's move at most :data:`CORNER_PUSH_LIMIT`
    depths. Boxes push the corners out of their nearest surface.
    The shapes act one after the other on a local copy of the corners (Gauss-Seidel,
    two passes: a push out of one shape may end in an overlapping one), and each moved
    corner gets the sum as one contact, so where shapes meet the pushes add up instead
    of being averaged; Coulomb friction with the tool (:func:`~.tool_shapes.coulomb_friction`)
    then keeps a pressed corner moving with the tool instead of sliding round its tip
    (the surface would split over a deep press's tip), except where the tool appeared
    in the tissue: that push has no side to keep. The corners are skinned from p here:
    tissue pairs may have moved it since the phase's skinning. Returns (contacts, acc,
    hits)."""
    v = coll.tri_vertex[t]
    w = ti.Vector([coll.corner_inv_mass[3 * t + j] for j in ti.static(range(3))])
    thickness = ti.Vector([coll.corner_thickness[3 * t + j] for j in ti.static(range(3))])
    start = ti.Matrix.rows([skin(model, state, state.p, v[j]) for j in ti.static(range(3))])
    x = [coll.vertex_x[v[j]] for j in ti.static(range(3))]
    c = start
    moved = ti.Vector([0, 0, 0])
    appeared = ti.Vector([0, 0, 0])  # pushed along the fallback: no friction
    count = 0
    for _pass in range(2):
        for s in range(MAX_TOOL_SHAPES):
            slot = k * MAX_TOOL_SHAPES + s
            if control.shape_kind[slot] == SHAPE_BOX:
                for j in ti.static(range(3)):
                    if w[j] > 0.0:
                        corner = ti.Vector([c[j, 0], c[j, 1], c[j, 2]])
                        dist, grad = shape_distance(control, slot, pose, corner)
                        if dist < thickness[j]:
                            for m in ti.static(range(3)):
                                c[j, m] += (thickness[j] - dist) * grad[m]
                            moved[j] = 1
                            count += 1
            else:
                round_, a, b, r = round_shape(control, slot, pose)
                if round_:
                    _was_round, a0, b0, _was_r = round_shape(control, slot, last)
                    p = [ti.Vector([c[j, 0], c[j, 1], c[j, 2]]) for j in ti.static(range(3))]
                    u, bary, on_seg, on_tri = segment_triangle(a, b, p[0], p[1], p[2])
                    before = bary[0] * x[0] + bary[1] * x[1] + bary[2] * x[2]
                    before -= a0 + u * (b0 - a0)
                    away = (p[1] - p[0]).cross(p[2] - p[0]).normalized(1e-30)
                    if away.dot(b - on_tri) > 0.0:  # a tool that appeared across the
                        away = -away  # surface pushes it away from its handle's end
                    reach = r + bary.dot(thickness)
                    dist, n = side_distance(on_tri - on_seg, before, reach, away)
                    on_axis = (on_tri - on_seg).norm() <= TOUCH and before.norm() <= TOUCH
                    denom = (bary * bary * w).sum()
                    if dist < 0.0 and denom > 0.0:
                        lam = -dist / denom
                        for j in ti.static(range(3)):
                            if bary[j] > 1e-6 and w[j] > 0.0:
                                push = ti.min(lam * w[j] * bary[j], -CORNER_PUSH_LIMIT * dist)
                                for m in ti.static(range(3)):
                                    c[j, m] += push * n[m]
                                moved[j] = 1
                                if on_axis:
                                    appeared[j] = 1
                        count += 1
    for j in ti.static(range(3)):
        if moved[j]:
            corner = ti.Vector([c[j, m] for m in ti.static(range(3))])
            begin = ti.Vector([start[j, m] for m in ti.static(range(3))])
            push = corner - begin
            depth = push.norm()
            if depth > 0.0 and appeared[j] == 0:
                limit = TOOL_FRICTION * depth
                corner = coulomb_friction(corner, x[j], pose.tip - last.tip, push / depth, limit)
            acc, hits = add_corner(acc, hits, j, corner - begin)
    return count, acc, hits


@ti.func
def tool_contacts(
    model: ti.template(),
    state: ti.template(),
    coll: ti.template(),
    control: ti.template(),
    t,
    acc,
    hits,
):
    """Triangle t against every active tool whose bounding capsule, grown by its
    motion over the substep, reaches the triangle's bounding sphere: the contact that
    holds (:func:`surface_tool`), or with ``coll.method_tools`` the chosen method's
    own response (seed 000's cylinder experiment). Returns (bounding-phase passes,
    contacts, acc, hits)."""
    candidates, contacts = 0, 0
    for k in range(MAX_TOOLS):
        if control.tool_active[k]:
            pose, last = control_pose(control, k), control.tool_last[k]
            move = pose_motion(last, pose)
            center, r = coll.sphere_center[t], coll.sphere_radius[t]
            touching = True
            for test in range(3):  # one distance call site: bounding, facing, sphere phase
                at, point = pose, coll.bound_center[t]
                if test == 1:
                    at, point = last, coll.start_centroid[t]
                elif test == 2:
                    point = center
                dist, grad = tool_distance(control, k, at, point)
                if test == 0:
                    touching = dist < coll.bound_reach[t] + move
                    if touching:
                        candidates += 1
                elif test == 1:
                    touching = grad.dot(coll.start_normal[t]) < 0.0
                else:
                    touching = dist < r and in_cone(coll, t, -grad)
                if not touching or ti.static(not coll.method_tools or coll.method == POLYGON):
                    break
            if touching:
                if ti.static(not coll.method_tools):
                    n, acc, hits = surface_tool(
                        model, state, coll, control, t, k, pose, last, acc, hits
                    )
                    contacts += n
                elif ti.static(coll.method == POLYGON):
                    n, acc, hits = polygon_tool(coll, control, t, k, pose, acc, hits)
                    contacts += n
                elif coll.tri_inv_mass[t] > 0.0:
                    acc, hits = add_to_corners(
                        acc,
                        hits,
                        sphere_tool_translation(control, k, pose, center, r, coll.displacement[t]),
                    )
                    contacts += 1
    return candidates, contacts, acc, hits


@ti.kernel
def detect_and_respond(
    model: ti.template(),
    state: ti.template(),
    control: ti.template(),
    coll: ti.template(),
    rows: ti.template(),
    tissue: ti.i32,
    tools: ti.i32,
):
    """The module docstring: contacts of the active triangles (corner translations,
    averaged; tissue pairs if ``tissue``, tools if ``tools``: 1 the step's first pass of
    the tools, 2 a further one, which keeps ``tool_held`` of the triangles an earlier
    pass held), then per particle under
    a contact the bound corners' translations averaged with the binding weights move p
    and set collided. Reads the spheres, the pair rows and the tool poses; writes corner_delta,
    corner_count (zero again at the end), counter, p, collided."""
    coll.touched_count[None] = 0
    ti.loop_config(serialize=ti.static(model.serial))
    for m in range(coll.active_list.shape[0]):
        if m < coll.active_count[None]:
            t = coll.active_list[m]
            acc, hits = ti.Matrix.zero(ti.f32, 3, 3), ti.Vector([0, 0, 0])
            bounding, contacts, tool_candidates, tool = 0, 0, 0, 0
            if ti.static(coll.tissue_pairs):
                if tissue:
                    bounding, contacts, acc, hits = tissue_contacts(coll, rows, t, acc, hits)
            if ti.static(coll.tools):
                if tools:
                    tool_candidates, tool, acc, hits = tool_contacts(
                        model, state, coll, control, t, acc, hits
                    )
                    held = ti.cast(tool > 0, ti.i32)
                    if tools > 1:  # a further pass: a triangle an earlier one held stays held
                        held |= coll.tool_held[t]
                    coll.tool_held[t] = held
            for k in ti.static(range(3)):
                coll.corner_delta[3 * t + k] = ti.Vector(
                    [acc[k, 0], acc[k, 1], acc[k, 2]]
                ) / ti.max(ti.cast(hits[k], ti.f32), 1.0)
                coll.corner_count[3 * t + k] = hits[k]
            ti.atomic_add(coll.counter[C_BOUNDING], bounding)
            ti.atomic_add(coll.counter[C_TISSUE], contacts)
            ti.atomic_add(coll.counter[C_TOOL_CANDIDATES], tool_candidates)
            ti.atomic_add(coll.counter[C_TOOL], tool)
            ti.atomic_add(coll.counter[C_TRIANGLES], ti.cast(hits.max() > 0, ti.i32))
    ti.loop_config(serialize=ti.static(model.serial))
    for m in range(coll.active_list.shape[0]):  # list the particles bound to hit corners
        if m < coll.active_count[None]:
            t = coll.active_list[m]
            for k in ti.static(range(3)):
                if coll.corner_count[3 * t + k] > 0:
                    s = coll.tri_vertex[t][k]
                    idx, w = model.surface_index[s], model.surface_weight[s]
                    for j in ti.static(range(4)):
                        if w[j] > 0.0:  # nested: Taichi evaluates both operands of `and`
                            if ti.atomic_add(coll.particle_mark[idx[j]], 1) == 0:
                                touched = ti.atomic_add(coll.touched_count[None], 1)
                                coll.touched_list[touched] = idx[j]
    ti.loop_config(serialize=ti.static(model.serial))
    for n in range(coll.touched_list.shape[0]):
        if n < coll.touched_count[None]:
            i = coll.touched_list[n]
            total, weight = ti.Vector([0.0, 0.0, 0.0]), 0.0
            j = coll.particle_rank[i]
            if j >= 0:  # corners as built, but those a dissection rewrote
                for m in range(coll.particle_start[j], coll.particle_start[j + 1]):
                    corner = coll.particle_corner[m]
                    if coll.corner_count[corner] > 0 and coll.corner_built[corner] != 0:
                        total += coll.particle_weight[m] * coll.corner_delta[corner]
                        weight += coll.particle_weight[m]
            r = coll.written_rank[i]
            if r >= 0:  # corners a dissection wrote
                for m in range(coll.written_start[r], coll.written_start[r + 1]):
                    corner = coll.written_corner[m]
                    if coll.corner_count[corner] > 0:
                        total += coll.written_weight[m] * coll.corner_delta[corner]
                        weight += coll.written_weight[m]
            if model.inv_mass[i] > 0.0 and weight > 0.0:
                state.p[i] = state.p[i] + total / weight
            state.collided[i] = 1
            coll.particle_mark[i] = 0
    ti.loop_config(serialize=ti.static(model.serial))
    for m in range(coll.active_list.shape[0]):
        if m < coll.active_count[None]:
            t = coll.active_list[m]
            for k in ti.static(range(3)):
                coll.corner_count[3 * t + k] = 0
