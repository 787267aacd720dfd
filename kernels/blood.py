"""Blood on the tissue's surface (issue: endoscopic realism): a film, its thickness
[m] per surface vertex, that a damaged vessel feeds and gravity drains downhill along
the surface's edges until it pools where no edge leads lower. A thin-film shallow-
water model reduced to its drainage, as screen-space and surface-film bleeding is
drawn in surgical simulators, cheap enough for every frame: one gather per vertex
over its incident triangles, no float atomics, so every backend gives the same film.

Transport of one step, after the film on an incline running at ``speed`` × slope:
vertex u lets the fraction α(u) = min(1, reach s(u) / ℓ(u)) of its movable film
max(film_u - residue, 0) run off (``reach`` how far blood runs down a vertical
surface in the step, s(u) the steepest slope down any of its edges, ℓ(u) their mean
length), shared among its enumerated edges u -> v (each incident triangle's two other
corners) by their slope w(u -> v) = max(0, down · ê):

    flow(u -> v) = max(film_u - residue, 0) α(u) w(u -> v) / Σ_n w(u -> n)

``down`` is the unit direction of gravity; what stays behind is at least the
``residue`` (a stain along the trail), and a vertex no edge leads down from keeps all
(a pool). Every edge is enumerated as often from each of its ends (once per triangle
holding it), so what u sends is what its neighbours take: the sum of the film over
the vertices is kept.

Where the surface faces down, the film does not stay: :func:`drop_landings` finds
where a drop falling from such a vertex meets the surface below (another organ, or
the same one lower down), and the drawing moves the film there
(:class:`~taichi_lap.render.blood.BloodFilm`), so blood drips from organ to organ.
"""

import taichi as ti
from taichi_lap.kernels.raster import ray_barycentrics


@ti.kernel
def bleed(
    positions: ti.template(),
    count: ti.i32,
    source: ti.types.vector(3, ti.f32),
    radius: ti.f32,
    thickness: ti.f32,
    film: ti.template(),
):
    """film[v] += ``thickness`` (1 - d²/``radius``²)² for the first ``count`` vertices
    within ``radius`` [m] of ``source`` [m] (d their distance to it)."""
    for v in range(count):
        d2 = (positions[v] - source).norm_sqr()
        if d2 < radius * radius:
            falloff = 1.0 - d2 / (radius * radius)
            film[v] += thickness * falloff * falloff


@ti.func
def _edge_end(triangles: ti.template(), incident: ti.template(), v, k, c):
    """The far end of an edge vertex v enumerates: corner c of its k-th incident
    triangle, or -1 where that is v itself or the row has no k-th triangle."""
    end = -1
    t = incident[v, k]
    if t >= 0:
        end = triangles[3 * t + c]
        if end == v:
            end = -1
    return end


@ti.func
def _slope(positions: ti.template(), u, v, down):
    """The slope w(u -> v) = max(0, down · ê) of edge u -> v (0 if degenerate)."""
    edge = positions[v] - positions[u]
    length = edge.norm()
    return ti.max(0.0, down.dot(edge) / length) if length > 1e-9 else 0.0


@ti.kernel
def film_shares(
    positions: ti.template(),
    triangles: ti.template(),
    incident: ti.template(),
    count: ti.i32,
    down: ti.types.vector(3, ti.f32),
    reach: ti.f32,
    residue: ti.f32,
    film: ti.template(),
    share: ti.template(),
):
    """share[v] = max(film[v] - ``residue``, 0) α(v) / Σ_n w(v -> n) (module
    docstring), 0 where no edge leads down: what each unit of slope carries off v."""
    for v in range(count):
        edges, length, steepest, total = 0, 0.0, 0.0, 0.0
        for k in range(incident.shape[1]):
            if incident[v, k] < 0:  # a row's triangles come first
                break
            for c in ti.static(range(3)):
                n = _edge_end(triangles, incident, v, k, c)
                if n >= 0:
                    slope = _slope(positions, v, n, down)
                    edges += 1
                    length += (positions[n] - positions[v]).norm()
                    steepest = ti.max(steepest, slope)
                    total += slope
        result = 0.0
        if total > 0.0:
            runs_off = ti.min(1.0, reach * steepest * edges / length)
            result = ti.max(film[v] - residue, 0.0) * runs_off / total
        share[v] = result


@ti.kernel
def drain(
    positions: ti.template(),
    triangles: ti.template(),
    incident: ti.template(),
    count: ti.i32,
    down: ti.types.vector(3, ti.f32),
    share: ti.template(),
    film: ti.template(),
    drained: ti.template(),
):
    """drained[v] = film[v] - what v sends + what its neighbours send it, one step of
    the transport in the module docstring (``share`` from :func:`film_shares`)."""
    for v in range(count):
        sent, taken = 0.0, 0.0
        for k in range(incident.shape[1]):
            if incident[v, k] < 0:
                break
            for c in ti.static(range(3)):
                n = _edge_end(triangles, incident, v, k, c)
                if n >= 0:
                    sent += share[v] * _slope(positions, v, n, down)
                    taken += share[n] * _slope(positions, n, v, down)
        drained[v] = film[v] - sent + taken


@ti.kernel
def drop_landings(
    positions: ti.template(),
    triangles: ti.template(),
    triangle_count: ti.i32,
    sources: ti.types.ndarray(),
    down: ti.types.vector(3, ti.f32),
    gap: ti.f32,
    hit_triangle: ti.types.ndarray(),
    hit: ti.types.ndarray(),
):
    """Where a drop falling from each vertex ``sources[d]`` along unit ``down`` lands:
    the nearest triangle its ray crosses farther than ``gap`` [m] (Möller & Trumbore
    1997, :func:`~taichi_lap.kernels.raster.ray_barycentrics`), none of whose corners
    is the source, into ``hit_triangle[d]`` (-1 for none) and ``hit[d]`` = (distance
    [m], the weights of its second and third corners). One thread per drop walks every
    triangle: no atomics, the same landing on every backend."""
    for d in range(sources.shape[0]):
        source = sources[d]
        origin = positions[source]
        best, best_triangle, best_u, best_v = 1e30, -1, 0.0, 0.0
        for t in range(triangle_count):
            i0, i1, i2 = triangles[3 * t], triangles[3 * t + 1], triangles[3 * t + 2]
            if i0 != source and i1 != source and i2 != source:
                u, v, distance = ray_barycentrics(positions, triangles, origin, down, t)
                if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and gap < distance < best:
                    best, best_triangle, best_u, best_v = distance, t, u, v
        hit_triangle[d] = best_triangle
        hit[d, 0], hit[d, 1], hit[d, 2] = best, best_u, best_v
