"""Broad phase of tissue collision (seed 000 §4.1, spatial hash), kept between steps
as margin pair lists (Verlet 1967), and the tool culling of the surface.

A step starts with :func:`update_bounds`, the one pass over the whole surface; when
some triangle drifted, the pipeline (:class:`taichi_lap.collision.TissueCollision`)
rebuilds the hash if needed (:func:`hold_spheres`), rescans (:func:`list_pairs`) and
rebuilds the rows (:func:`count_rows`, :func:`fill_rows`); :func:`mark_active` then
lists the triangles the sphere phases and the response look at
(:mod:`~taichi_lap.kernels.collision.response`).

Triangles are bounded by broad spheres (centroid, farthest corner, grown by the
centroid's motion over the substep) and each lists the others whose broad spheres lie
within ``pair_margin`` of its own. Only a triangle whose sphere drifted (centre shift +
reach change) more than ``rescan_drift`` = margin / 3 since it was last listed scans
the hash again; the others keep their partners. A pair missing from the lists was
more than the margin apart when the later of its two triangles scanned; since then the
scanning one drifted at most margin / 3 and the other at most twice that (from its own
listing to then, and on to now), so the gap cannot have closed. The hash holds the
spheres of its last build and is rebuilt once a sphere drifted more than
``hash_slack`` from there (scans widen by that slack). A scan visits the cells within
its sphere's reach + margin + slack + the largest radius the hash holds (a partner's
centre lies there, however stretched either triangle is), each cell only for the
spheres hashed in it; the hash's cells are a few triangle sizes, so that a scan reads
little more than that ball. Scans collect hits in a tight
loop (up to :data:`NEAR`; when more, the scan goes on from the hit that did not fit)
and test them after it. Pairs never
listed: triangles sharing a vertex, and pairs close at rest that are of one body or do
not face each other then (rest exclusion, below). Listed pairs whose broad spheres
overlap, and triangles whose broad sphere reaches a tool's bounding capsule, are
active: only they get collision spheres and tests.

Rest exclusion. Seed 000 §4 resolves contacts between surfaces that come together:
tool and tissue, separate organs, folds of one organ (§4.1 picks the spatial hash for
self-collision). Two triangles whose rest broad spheres are within a couple of
triangle sizes (κ = ``rest_exclusion`` times the sum of their radii) are skipped when
* they belong to one body: one organ, or organs joined by shared shape-matching
  clusters (seed 002's vessels, joined into the liver; the portal triad runs 0.5 mm
  apart, closer than the spheres of such thin tubes reach). They can only touch by
  crushing the body over about a triangle, below what the spheres resolve (their
  curvature factor shrinks them towards the bounding spheres, §4.2.1, and
  neighbouring spheres overlap anyway) and what the shape matching of the body's
  clusters (Alg. 1), which holds the rest arrangement, lets happen;
* or they do not face each other at rest (:func:`facing` on the rest normals and
  centroids): back to back, side by side, or one inside the other. Such a pair
  becomes a contact only by one surface turning over against the other within a
  couple of triangle sizes.
Separate bodies that face each other at rest, however close, keep colliding: they
must not be pressed into each other. Far pairs are never skipped: the layers of a
folded sheet collide.

Counts are i32 totals added once per triangle (no atomics inside the candidate loops,
see :mod:`~taichi_lap.kernels.collision.spatial_hash`). Lengths in metres.

Parallel loops over a count held in a field (``row_count``, ``found.count``) run over
the field's capacity and skip the indices past the count: with a constant end Vulkan
launches one thread per index instead of a fixed grid of 65,536 (docs/architecture.md,
loop bounds).
"""

import taichi as ti
from taichi_lap.kernels.collision.spatial_hash import exclusive_scan, store_pair
from taichi_lap.kernels.collision.spheres import (
    C_CANDIDATES,
    C_LISTED,
    C_RESCANNED,
    skin_vertices,
)
from taichi_lap.kernels.collision.tool_shapes import bounding_radius, control_pose, pose_motion
from taichi_lap.kernels.scatter import serial_on_cpu

from taichi_lap.core.instruments import FAR, MAX_TOOLS

NEAR = 32
"""Hash hits a scanning triangle keeps before testing them (then it scans on from there):
the exact tests run outside the tight candidate loop."""
ROW_BLOCK = 256
"""Triangles per block of the pair rows' prefix sum."""
BROAD = ("moved", "stale", "found", "rows", "seen", "rescanned", "listed", "held")
"""Slots of the broad-phase status ``broad`` (one read per step): triangles to rescan,
hash out of date, pairs found, entries of the new rows, this rescan's counts, and the
largest radius the hash holds (f32 bits: :func:`held_reach`)."""
B_MOVED, B_STALE, B_FOUND, B_ROWS, B_SEEN, B_RESCANNED, B_LISTED, B_HELD = range(len(BROAD))


@ti.func
def xyz(sphere):
    """Centre of a (centre, radius) 4-vector."""
    return ti.Vector([sphere[0], sphere[1], sphere[2]])


@ti.func
def facing(c_t, n_t, c_u, n_u):
    """Triangles at centroids c_t, c_u with normals n_t, n_u face each other: opposite
    normals and each centroid in front of the other."""
    d = c_u - c_t
    return n_t.dot(n_u) < 0.0 and d.dot(n_t) > 0.0 and d.dot(n_u) < 0.0


@ti.func
def shares_vertex(coll: ti.template(), t, u):
    """Triangles t and u have a surface vertex in common (adjacent: never a contact)."""
    a, b = coll.tri_vertex[t], coll.tri_vertex[u]
    shared = False
    for i in ti.static(range(3)):
        for j in ti.static(range(3)):
            if a[i] == b[j]:
                shared = True
    return shared


@ti.func
def any_tool_near(coll: ti.template(), sphere):
    """Some tool's bounding capsule (:func:`update_bounds`) reaches ``sphere`` (centre,
    reach)."""
    near = False
    if ti.static(coll.tools):
        x = xyz(sphere)
        for k in ti.static(range(MAX_TOOLS)):
            cull = coll.tool_cull[k]
            if cull[3] >= 0.0:
                a, axis = coll.tool_cull_a[k], coll.tool_cull_axis[k]
                closest = a + ti.math.clamp((x - a).dot(axis) * cull[0], 0.0, 1.0) * axis
                reach = sphere[3] + cull[3]
                near = near or (x - closest).norm_sqr() < reach * reach
    return near


@ti.kernel
def update_bounds(
    model: ti.template(), state: ti.template(), control: ti.template(), coll: ti.template()
):
    """The pass over the whole surface: skin the vertices from p and x (vertex_p,
    vertex_x), bound every triangle by its broad sphere (``broad_sphere``: centroid,
    largest corner distance + centroid displacement over the substep), list as active
    the triangles that a tool's bounding capsule reaches (the Control capsule grown
    to hold all the tool's shapes, ``tool_reach``, and by its motion over the
    substep; ``tool_cull*``), and with tissue pairs flag the triangles whose
    broad sphere drifted (centre shift + reach change) more than ``rescan_drift``
    since they were listed (``moved``, counted in ``broad[B_MOVED]``) and whether some
    drifted more than ``hash_slack`` from the hash (``broad[B_STALE]``)."""
    coll.broad[B_MOVED], coll.broad[B_STALE] = 0, 0
    coll.active_count[None] = 0
    for k in ti.static(range(MAX_TOOLS)):  # bounding capsules: tip, axis, 1 / |axis|², reach
        axis = control.tool_b[k] - control.tool_a[k]
        pose = control_pose(control, k)
        reach = bounding_radius(control, k, pose) + pose_motion(control.tool_last[k], pose)
        coll.tool_cull_a[k], coll.tool_cull_axis[k] = control.tool_a[k], axis
        coll.tool_cull[k] = ti.Vector(
            [
                1.0 / ti.max(axis.dot(axis), 1e-30),
                0.0,
                0.0,
                ti.select(control.tool_active[k] != 0, reach, -1.0),
            ]
        )
    skin_vertices(model, state, coll)
    ti.loop_config(serialize=ti.static(model.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            v = coll.tri_vertex[t]
            a, b, c = coll.vertex_p[v[0]], coll.vertex_p[v[1]], coll.vertex_p[v[2]]
            center = (a + b + c) / 3.0
            motion = (
                center - (coll.vertex_x[v[0]] + coll.vertex_x[v[1]] + coll.vertex_x[v[2]]) / 3.0
            )
            far = ti.max(
                (a - center).norm_sqr(), ti.max((b - center).norm_sqr(), (c - center).norm_sqr())
            )
            sphere = ti.Vector([center[0], center[1], center[2], ti.sqrt(far) + motion.norm()])
            coll.broad_sphere[t] = sphere
            if ti.static(coll.tissue_pairs):  # a retired triangle may hold anything
                ref, held = coll.ref_sphere[t], coll.hash_sphere[t]
                moved = (center - xyz(ref)).norm() + ti.abs(sphere[3] - ref[3]) > coll.rescan_drift
                coll.moved[t] = ti.cast(moved, ti.i32)
                if moved:
                    ti.atomic_add(coll.broad[B_MOVED], 1)
                if (center - xyz(held)).norm() + ti.abs(sphere[3] - held[3]) > coll.hash_slack:
                    coll.broad[B_STALE] = 1
            if coll.tri_live[t] != 0 and any_tool_near(coll, sphere):
                coll.active_list[ti.atomic_add(coll.active_count[None], 1)] = t
            else:
                coll.tool_held[t] = 0


@ti.kernel
def hold_spheres(coll: ti.template(), grid: ti.template()):
    """After ``grid.build(broad_sphere)``: the hash holds each triangle's broad sphere
    (hash_sphere) and, in hash order, that sphere, the rest sphere and the body
    (sorted_sphere, sorted_rest, sorted_body: what the scan loop reads); the largest
    radius of a live one goes to ``broad[B_HELD]``."""
    coll.broad[B_HELD] = 0
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            sphere = coll.broad_sphere[t]
            coll.hash_sphere[t] = sphere
            if coll.tri_live[t] != 0:  # radii >= 0 (or NaN): their bits order as they do
                ti.atomic_max(coll.broad[B_HELD], ti.bit_cast(sphere[3], ti.i32))
    ti.loop_config(serialize=ti.static(coll.serial))
    for s in range(coll.tri_vertex.shape[0]):
        if s < coll.row_count[None]:
            u = grid.sorted_index[s]
            coll.sorted_sphere[s] = coll.hash_sphere[u]
            coll.sorted_rest[s] = coll.rest_sphere[u]
            coll.sorted_body[s] = coll.tri_body[u]


@ti.func
def held_reach(coll: ti.template()):
    """The largest broad radius [m] of a live triangle when the hash was built."""
    return ti.bit_cast(coll.broad[B_HELD], ti.f32)


@ti.func
def excluded(coll: ti.template(), t, u):
    """Never a contact: t itself, adjacent triangles, pairs close at rest that are of
    one body or do not face each other at rest (rest exclusion, module docstring),
    and pairs of one organ without ``self_collision``."""
    out = u == t or shares_vertex(coll, t, u)
    if ti.static(not coll.self_collision):
        out = out or coll.tri_organ[u] == coll.tri_organ[t]
    a, b = coll.rest_sphere[t], coll.rest_sphere[u]
    d = xyz(b) - xyz(a)
    near = coll.rest_exclusion * (a[3] + b[3])
    if d.dot(d) < near * near:
        out = (
            out
            or coll.tri_body[u] == coll.tri_body[t]
            or not facing(xyz(a), coll.rest_normal[t], xyz(b), coll.rest_normal[u])
        )
    return out


@ti.func
def broad_overlap(coll: ti.template(), t, u, margin):
    """Broad spheres at most ``margin`` [m] apart, of two live triangles (a triangle a
    dissection removed is no one's partner)."""
    a, b = coll.broad_sphere[t], coll.broad_sphere[u]
    reach = a[3] + b[3] + margin
    d = xyz(b) - xyz(a)
    return coll.tri_live[t] != 0 and coll.tri_live[u] != 0 and d.dot(d) <= reach * reach


@ti.func
def scan_pairs(
    coll: ti.template(), grid: ti.template(), found: ti.template(), t, write: ti.template(), base
):
    """Moved triangle t's partners from the hash (module docstring): pairs (t, u) with u
    not moved or t < u (a moved u lists the others). ``write``: 0 count, 1 write from
    slot ``base`` on, 2 write to slots taken by one atomic per pair. Returns (pairs,
    hash entries scanned)."""
    sphere, rest, body = coll.broad_sphere[t], coll.rest_sphere[t], coll.tri_body[t]
    center = xyz(sphere)
    widen = sphere[3] + coll.pair_margin + coll.hash_slack
    lo, extent, visits = grid.ball_span(center, widen + held_reach(coll))
    near = ti.Vector([0] * NEAR, ti.i32)
    count, seen, scanning = 0, 0, True
    resume_visit, resume_entry = 0, -1  # where a full buffer stopped the scan
    while scanning:  # scan on, keep up to NEAR hits, test them; go on if it was full
        n_near, scanning = 0, False
        for k in range(resume_visit, visits):
            cell, start, end = grid.span_visit(lo, extent, k)
            if k == resume_visit and resume_entry >= 0:
                start = resume_entry
            for s in range(start, end):  # held spheres in hash order: contiguous reads
                held = coll.sorted_sphere[s]
                reach = widen + held[3]
                d = xyz(held) - center
                hit = d.dot(d) <= reach * reach
                if hit:  # of this cell (Taichi's `and` evaluates both sides)
                    hit = grid.in_visit(cell, extent, xyz(held))
                if hit:  # and not of one body and close at rest (rest exclusion)
                    r = coll.sorted_rest[s]
                    e = xyz(r) - xyz(rest)
                    close = coll.rest_exclusion * (r[3] + rest[3])
                    hit = coll.sorted_body[s] != body or e.dot(e) >= close * close
                if hit and n_near == NEAR:  # full: test these, then go on from s
                    resume_visit, resume_entry, scanning = k, s, True
                    break
                if hit:
                    near[n_near] = s
                    n_near += 1
                seen += 1
            if scanning:
                break
        for m in range(n_near):
            u = grid.sorted_index[near[m]]
            if (
                (not coll.moved[u] or t < u)
                and broad_overlap(coll, t, u, coll.pair_margin)
                and not excluded(coll, t, u)
            ):
                if ti.static(write):
                    store_pair(found.pair, found.count, found.capacity, write, base, count, t, u)
                count += 1
    return count, seen


@ti.kernel
def list_pairs(coll: ti.template(), grid: ti.template(), found: ti.template()):
    """Every moved triangle scans the hash and appends its pairs to ``found`` (count
    = how many there were: more than the capacity means rerun with more room); its
    broad sphere becomes the reference of its drift (ref_sphere)."""
    found.count[None] = 0
    for k in ti.static(range(B_SEEN, B_LISTED + 1)):
        coll.broad[k] = 0
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            if coll.moved[t]:
                count, seen = 0, 0
                if ti.static(grid.reserve_per_point):  # Vulkan: count, reserve, write
                    count, seen = scan_pairs(coll, grid, found, t, 0, 0)
                    scan_pairs(coll, grid, found, t, 1, ti.atomic_add(found.count[None], count))
                else:
                    count, seen = scan_pairs(coll, grid, found, t, 2, 0)
                coll.ref_sphere[t] = coll.broad_sphere[t]
                ti.atomic_add(coll.broad[B_SEEN], seen)
                ti.atomic_add(coll.broad[B_RESCANNED], 1)
                ti.atomic_add(coll.broad[B_LISTED], count)


@ti.kernel
def count_rows(coll: ti.template(), old: ti.template(), new: ti.template(), found: ti.template()):
    """Sizes of the new pair rows: a triangle that did not move keeps its partners that
    did not move; every found pair adds to both rows. Writes new.cursor (kept), new.size,
    new.start (prefix sum) and, to compare with the capacities, broad[B_FOUND] and
    broad[B_ROWS] (the total)."""
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            kept = 0
            if not coll.moved[t]:
                for m in range(old.start[t], old.start[t + 1]):
                    if not coll.moved[old.partner[m]]:
                        kept += 1
            new.cursor[t] = kept
            new.size[t] = kept
    ti.loop_config(serialize=ti.static(coll.serial))
    for q in range(found.capacity):
        if q < found.count[None]:
            pair = found.pair[q]
            ti.atomic_add(new.size[pair[0]], 1)
            ti.atomic_add(new.size[pair[1]], 1)
    exclusive_scan(new.size, new.start, coll.row_count[None], new.block_start, ROW_BLOCK)
    coll.broad[B_FOUND] = found.count[None]
    coll.broad[B_ROWS] = new.start[coll.row_count[None]]


@ti.kernel
def fill_rows(coll: ti.template(), old: ti.template(), new: ti.template(), found: ti.template()):
    """The new rows of :func:`count_rows`, each sorted by partner (the order the
    contacts are summed in: runs stay bit-reproducible); the rescan's counts go to the
    counters."""
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            if not coll.moved[t]:
                slot = new.start[t]
                for m in range(old.start[t], old.start[t + 1]):
                    u = old.partner[m]
                    if not coll.moved[u]:
                        new.partner[slot] = u
                        slot += 1
    ti.loop_config(serialize=ti.static(coll.serial))
    for q in range(found.capacity):
        if q < found.count[None]:
            pair = found.pair[q]
            for side in ti.static(range(2)):
                row = pair[side]
                new.partner[new.start[row] + ti.atomic_add(new.cursor[row], 1)] = pair[1 - side]
    ti.atomic_add(coll.counter[C_CANDIDATES], coll.broad[B_SEEN])
    ti.atomic_add(coll.counter[C_RESCANNED], coll.broad[B_RESCANNED])
    ti.atomic_add(coll.counter[C_LISTED], coll.broad[B_LISTED])
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):  # insertion sort of the short rows
        if t < coll.row_count[None]:
            lo, hi = new.start[t], new.start[t + 1]
            for a in range(lo + 1, hi):
                v, c = new.partner[a], a
                while c > lo:
                    if new.partner[c - 1] <= v:
                        break
                    new.partner[c] = new.partner[c - 1]
                    c -= 1
                new.partner[c] = v


@ti.kernel
def mark_active(coll: ti.template(), rows: ti.template()):
    """Add to the active list (``active_list[:active_count]``, in no fixed order) the
    triangles with a listed partner whose broad sphere overlaps theirs: with those
    near a tool (:func:`update_bounds`), the triangles whose spheres
    :func:`kernels.collision.spheres.update_spheres` computes and that
    :func:`detect_and_respond` tests (both triangles of a pair are listed)."""
    ti.loop_config(serialize=ti.static(coll.serial))
    for t in range(coll.tri_vertex.shape[0]):
        if t < coll.row_count[None]:
            start, end = rows.start[t], rows.start[t + 1]
            if start < end and not any_tool_near(coll, coll.broad_sphere[t]):
                active = False
                for m in range(start, end):
                    if not active:
                        active = broad_overlap(coll, t, rows.partner[m], 0.0)
                if active:
                    coll.active_list[ti.atomic_add(coll.active_count[None], 1)] = t


@ti.kernel
def write_triangle_rows(
    coll: ti.template(),
    rows: ti.types.ndarray(),
    vertex: ti.types.ndarray(),
    flags: ti.types.ndarray(),
    rest: ti.types.ndarray(),
    corner: ti.types.ndarray(),
):
    """The triangle ``rows`` a dissection removed or wrote, as they now are (one
    launch for :meth:`taichi_lap.collision.TissueCollision.rewrite`): ``vertex``
    (R, 3), ``flags`` (R, 3) live, organ, body; ``rest`` (R, 7) rest broad sphere and
    unit rest normal; ``corner`` (R, 6) the corners' inverse masses and thickness.
    They rescan their pairs (ref_sphere far away), the hash is rebuilt (hash_sphere
    far away), no tool holds them, their corners leave the gather lists as built
    (corner_built 0) and own no vertex until the owners are written."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(rows.shape[0]):
        t = rows[k]
        coll.tri_vertex[t] = ti.Vector([vertex[k, 0], vertex[k, 1], vertex[k, 2]])
        coll.tri_live[t] = flags[k, 0]
        coll.tri_organ[t] = flags[k, 1]
        coll.tri_body[t] = flags[k, 2]
        coll.rest_sphere[t] = ti.Vector([rest[k, 0], rest[k, 1], rest[k, 2], rest[k, 3]])
        coll.rest_normal[t] = ti.Vector([rest[k, 4], rest[k, 5], rest[k, 6]])
        mass = 0.0
        for j in ti.static(range(3)):
            coll.corner_inv_mass[3 * t + j] = corner[k, j]
            coll.corner_thickness[3 * t + j] = corner[k, 3 + j]
            coll.corner_built[3 * t + j] = 0
            coll.corner_owner[3 * t + j] = 0
            mass += corner[k, j]
        coll.tri_inv_mass[t] = mass / 3.0
        coll.ref_sphere[t] = ti.Vector([FAR, FAR, FAR, FAR])
        coll.hash_sphere[t] = ti.Vector([FAR, FAR, FAR, FAR])
        coll.tool_held[t] = 0


@ti.kernel
def write_neighbours(coll: ti.template(), rows: ti.types.ndarray(), neighbour: ti.types.ndarray()):
    """Edge neighbours (R, 3) of the triangle ``rows``; their curvature is computed
    again at the next step (area_last 0, the lazy update of seed 000 §4.2.3)."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(rows.shape[0]):
        t = rows[k]
        coll.tri_neighbour[t] = ti.Vector([neighbour[k, 0], neighbour[k, 1], neighbour[k, 2]])
        coll.area_last[t] = 0.0


@ti.kernel
def write_gather(
    coll: ti.template(),
    gone: ti.types.ndarray(),
    particle: ti.types.ndarray(),
    start: ti.types.ndarray(),
    corner: ti.types.ndarray(),
    weight: ti.types.ndarray(),
):
    """The gather lists of the rewritten corners: the particles ``gone`` from them
    lose their rank; ``particle`` (P,) get ranks 0..P-1 with the entries
    ``start[r]:start[r + 1]`` of ``corner`` and ``weight``."""
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for k in range(gone.shape[0]):
        coll.written_rank[gone[k]] = -1
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for r in range(particle.shape[0]):
        coll.written_rank[particle[r]] = r
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for r in range(start.shape[0]):
        coll.written_start[r] = start[r]
    ti.loop_config(serialize=ti.static(serial_on_cpu()))
    for m in range(corner.shape[0]):
        coll.written_corner[m] = corner[m]
        coll.written_weight[m] = weight[m]
