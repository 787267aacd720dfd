"""Adaptive circumspheres of surface triangles: seed 000 §4.2 (Qian et al., VRST 2015,
Eq. 4-6, lazy update of §4.2.3), and the bounding spheres of the baseline (Mendoza and
O'Sullivan 2006), for :class:`taichi_lap.collision.TissueCollision`:
:mod:`kernels.collision.broad_phase` finds the triangles that need them and
:mod:`kernels.collision.response` detects and responds with them.

:func:`update_spheres` computes, for the triangles the broad phase of
:mod:`kernels.collision.broad_phase` found near something (``active``), from the skinned
predicted positions p and the substep's start positions x: the smallest bounding
sphere (centre m_b, radius R_b; Ericson 2004 §4.3), the displacement of the centroid
over the substep, unit normal N_c, area S and the collision sphere:

* circumsphere (Eq. 4-6): centre C = x_c - N_c (φ R_b cot θ H3(K) + ε), radius
  sqrt(R_b² + depth²): the sphere passes through the vertices, so a deeper centre
  gives a larger, flatter sphere. x_c is the circumcentre; for right and obtuse
  triangles, where it leaves the triangle (far away for the slivers that deformation
  makes), m_b is used instead (the same point for acute triangles): the sphere then
  passes through the longest edge's ends and holds the third vertex below its cap.
  Eq. 6 of the extracted text reads "x_c - N_c φ R_b cot θ H3(K) - ε"; ε is a length,
  so it is read as a further shift along -N_c. θ is the safe angle (π/6, §7) and φ
  the global scale (ψ = 3 in §7, "coarse uniform factor"). Seen from C the bounding
  circle subtends the half-angle atan(R_b / depth), θ itself when φ = 1, H3 = 1 and
  ε = 0 (Fig. 6): inside that cone the sphere's cap stands for the triangle, outside
  it the sphere bulges far above it. The cone's cosine, depth / radius, is stored as
  ``sphere_cone`` for the contact test.
* curvature (§4.2.1): K is the Gauss curvature at the dual-mesh vertex (the
  triangle's centroid) by the Gauss-Bonnet angle deficit (Surazhsky et al. 2003): 2π
  minus the angles between the dual edges to the three edge-neighbours' centroids,
  over the triangle's area (the dual vertices' regions tile the surface, so Σ K S is
  the total deficit, 4π on a closed genus-0 surface); 0 on a boundary. H3 is the cubic
  Hermite with H3(0) = 1, H3(∞) = 0 and zero end slopes. The extracted text puts the
  second node at K = ∞, which no cubic reaches, so K is mapped onto s = |K| / (|K| +
  K_ref) ∈ [0, 1) and H3 = h_00(s) = 1 - 3s² + 2s³, tabulated once
  (:func:`hermite_table`). K_ref = 4 / (φ R_b cot θ)², the curvature of a sphere of
  radius half the flat-case depth, gives H3 = 1/2 there (our choice: the paper gives
  no scale). |K| is used because a saddle is not flat either.
* recovery (§4.2.2): ε is the mean distance of the triangle's vertices from their goal
  positions (Alg. 1).
* lazy update (§4.2.3): K and ε (hence H3) are recomputed only when |S / S_last - 1|
  >= δ, S_last the area at the last recomputation; otherwise the centre keeps its
  depth below the moving x_c (moves rigidly with the triangle).
* bounding sphere: C = m_b, radius R_b, any direction (``sphere_cone`` = -1).

Lengths in metres, curvature in 1/m².

Parallel loops over a count held in a field (``vertex_rows``; not the sphere update, see
there) run over the field's capacity and skip the indices past the count: with a
constant end Vulkan launches one thread per index instead of a fixed grid of 65,536
(docs/architecture.md, loop bounds).
"""

import math

import numpy as np
import taichi as ti

from taichi_lap.kernels.skinning import skin

CIRCUMSPHERE, BOUNDING_SPHERE, POLYGON = 0, 1, 2
HERMITE_SAMPLES = 256
"""Intervals of the tabulated H3 over s ∈ [0, 1]."""

COUNTERS = (
    "candidates",
    "bounding_pairs",
    "tissue_contacts",
    "tool_candidates",
    "tool_contacts",
    "recomputed",
    "contact_triangles",
    "rescanned",
    "listed_pairs",
)
"""Cumulative i32 event counters (wrap around; take differences)."""
(
    C_CANDIDATES,
    C_BOUNDING,
    C_TISSUE,
    C_TOOL_CANDIDATES,
    C_TOOL,
    C_RECOMPUTED,
    C_TRIANGLES,
    C_RESCANNED,
    C_LISTED,
) = range(len(COUNTERS))


def hermite_table(samples: int = HERMITE_SAMPLES) -> np.ndarray:
    """H3 at s = 0, 1/samples, ..., 1: the cubic Hermite basis h_00(s) = 1 - 3s² + 2s³
    (values 1 -> 0, zero end slopes), seed 000 §4.2.1."""
    s = np.linspace(0.0, 1.0, samples + 1)
    return 1.0 - 3.0 * s**2 + 2.0 * s**3


@ti.func
def curvature_factor(table: ti.template(), curvature, curvature_ref):
    """H3(K) from the table: s = |K| / (|K| + K_ref) [both 1/m²], linear between samples."""
    k = ti.abs(curvature)
    s = k / ti.max(k + curvature_ref, 1e-30)
    f = s * HERMITE_SAMPLES
    i = ti.min(ti.cast(f, ti.i32), HERMITE_SAMPLES - 1)
    frac = f - ti.cast(i, ti.f32)
    return table[i] + frac * (table[i + 1] - table[i])


@ti.func
def circumcircle(a, b, c):
    """Circumcentre x_c, circumradius, unit normal N_c ((b-a)×(c-a), counter-clockwise)
    and area of a triangle; a degenerate triangle gives its centroid, the largest
    vertex distance and the y axis."""
    u, v = b - a, c - a
    w = u.cross(v)
    w2 = w.dot(w)
    center = (a + b + c) / 3.0
    radius = ti.max((a - center).norm(), ti.max((b - center).norm(), (c - center).norm()))
    normal = ti.Vector([0.0, 1.0, 0.0])
    if w2 > 1e-30:
        center = a + (u.dot(u) * v.cross(w) + v.dot(v) * w.cross(u)) / (2.0 * w2)
        radius = (a - center).norm()
        normal = w / ti.sqrt(w2)
    return center, radius, normal, 0.5 * ti.sqrt(w2)


@ti.func
def bounding_sphere(a, b, c, circumcenter, circumradius):
    """Smallest sphere around a triangle (Ericson 2004 §4.3): the longest edge's
    diametral sphere for right or obtuse triangles, else the circumsphere."""
    center, radius = circumcenter, circumradius
    if (a - c).dot(b - c) <= 0.0:  # obtuse or right at c: a-b is the longest edge
        center, radius = 0.5 * (a + b), 0.5 * (a - b).norm()
    elif (b - a).dot(c - a) <= 0.0:
        center, radius = 0.5 * (b + c), 0.5 * (b - c).norm()
    elif (c - b).dot(a - b) <= 0.0:
        center, radius = 0.5 * (c + a), 0.5 * (c - a).norm()
    return center, radius


@ti.func
def angle_between(u, v):
    """Angle [rad] between two vectors, atan2(|u × v|, u · v) (accurate near 0 and π)."""
    return ti.atan2(u.cross(v).norm(), u.dot(v))


@ti.func
def dual_curvature(centroid, n0, n1, n2, area):
    """Gauss-Bonnet at the dual vertex ``centroid`` with edge-neighbour centroids
    n0..n2: (angle deficit 2π - Σ angles [rad], K = deficit / area [1/m²])."""
    e0, e1, e2 = n0 - centroid, n1 - centroid, n2 - centroid
    deficit = 2.0 * math.pi - angle_between(e0, e1) - angle_between(e1, e2) - angle_between(e2, e0)
    return deficit, deficit / ti.max(area, 1e-30)


@ti.func
def cot(angle):
    """cot θ."""
    return ti.cos(angle) / ti.sin(angle)


@ti.func
def circumsphere_center(center, normal, bound_radius, scale_phi, safe_angle, hermite, recovery):
    """Eq. 4-6: C = x_c - N_c (φ R_b cot θ H3(K) + ε) with x_c = ``center``; returns C
    and its depth [m]."""
    depth = scale_phi * bound_radius * cot(safe_angle) * hermite + recovery
    return center - normal * depth, depth


@ti.func
def triangle_goal_distance(model: ti.template(), state: ti.template(), v):
    """ε of §4.2.2: mean over the corners ``v`` of |skinned p - skinned goal| [m]."""
    total = 0.0
    for k in ti.static(range(3)):
        idx, w = model.surface_index[v[k]], model.surface_weight[v[k]]
        d = ti.Vector([0.0, 0.0, 0.0])
        for j in ti.static(range(4)):
            d += w[j] * (state.p[idx[j]] - state.goal[idx[j]])
        total += d.norm()
    return total / 3.0


@ti.func
def centroid(coll: ti.template(), t):
    """Centroid [m] of triangle t from the skinned vertices."""
    v = coll.tri_vertex[t]
    return (coll.vertex_p[v[0]] + coll.vertex_p[v[1]] + coll.vertex_p[v[2]]) / 3.0


@ti.func
def skin_vertices(model: ti.template(), state: ti.template(), coll: ti.template()):
    """Surface vertices in use from p and x by the surface binding (vertex_p,
    vertex_x; :func:`~taichi_lap.kernels.skinning.skin`); call at a kernel's top
    level (a parallel loop)."""
    for s in range(coll.vertex_p.shape[0]):
        if s < coll.vertex_rows[None]:
            coll.vertex_p[s] = skin(model, state, state.p, s)
            coll.vertex_x[s] = skin(model, state, state.x, s)


@ti.kernel
def update_spheres(
    model: ti.template(), state: ti.template(), coll: ti.template(), every: ti.template()
):
    """The module docstring's spheres of the active triangles, after the skinning of
    :func:`kernels.collision.broad_phase.update_bounds`, or of all triangles with ``every``
    (skinning first). Reads vertex_p, vertex_x and goal; writes bound_center,
    bound_radius, displacement, bound_reach = R_b + |displacement|, start_centroid,
    start_normal, normal, the spheres (sphere_center, sphere_radius, sphere_cone) and,
    for circumspheres, the lazy-update state (area_last, curvature, curvature_factor,
    recovery) and ``recomputed``."""
    if ti.static(every):
        skin_vertices(model, state, coll)
    # the end read at run time, unlike the module's other loops over a count: over the
    # capacity, lavapipe rounded the dual curvature otherwise and flipped a contact
    ti.loop_config(serialize=ti.static(model.serial))
    for m in range(coll.row_count[None] if ti.static(every) else coll.active_count[None]):
        t = m if ti.static(every) else coll.active_list[m]
        v = coll.tri_vertex[t]
        a, b, c = coll.vertex_p[v[0]], coll.vertex_p[v[1]], coll.vertex_p[v[2]]
        a0, b0, c0 = coll.vertex_x[v[0]], coll.vertex_x[v[1]], coll.vertex_x[v[2]]
        circumcenter, circumradius, normal, area = circumcircle(a, b, c)
        center_b, radius_b = bounding_sphere(a, b, c, circumcenter, circumradius)
        start_normal = circumcircle(a0, b0, c0)[2]
        displacement = (a + b + c - a0 - b0 - c0) / 3.0
        coll.bound_center[t] = center_b
        coll.bound_radius[t] = radius_b
        coll.bound_reach[t] = radius_b + displacement.norm()
        coll.displacement[t] = displacement
        coll.start_centroid[t] = (a0 + b0 + c0) / 3.0
        coll.start_normal[t] = start_normal
        coll.normal[t] = normal
        if ti.static(coll.method == CIRCUMSPHERE):
            last = coll.area_last[t]
            if last <= 0.0 or ti.abs(area / last - 1.0) >= coll.lazy_delta:
                nb = coll.tri_neighbour[t]
                curvature = 0.0
                if nb[0] >= 0 and nb[1] >= 0 and nb[2] >= 0:
                    _, curvature = dual_curvature(
                        (a + b + c) / 3.0,
                        centroid(coll, nb[0]),
                        centroid(coll, nb[1]),
                        centroid(coll, nb[2]),
                        area,
                    )
                flat_depth = coll.scale_phi * radius_b * cot(coll.safe_angle)
                coll.curvature[t] = curvature
                coll.curvature_factor[t] = curvature_factor(
                    coll.hermite, curvature, 4.0 / ti.max(flat_depth * flat_depth, 1e-30)
                )
                coll.recovery[t] = triangle_goal_distance(model, state, v)
                coll.area_last[t] = area
                ti.atomic_add(coll.counter[C_RECOMPUTED], 1)
            center, depth = circumsphere_center(
                center_b,
                normal,
                radius_b,
                coll.scale_phi,
                coll.safe_angle,
                coll.curvature_factor[t],
                coll.recovery[t],
            )
            radius = ti.sqrt(radius_b * radius_b + depth * depth)
            coll.sphere_center[t] = center
            coll.sphere_radius[t] = radius
            coll.sphere_cone[t] = depth / ti.max(radius, 1e-30)
        else:
            coll.sphere_center[t] = center_b
            coll.sphere_radius[t] = radius_b
            coll.sphere_cone[t] = -1.0


@ti.func
def in_cone(coll: ti.template(), t, direction):
    """The unit ``direction`` from t's sphere centre lies in its cap's cone."""
    return direction.dot(coll.normal[t]) >= coll.sphere_cone[t]


@ti.func
def bounding_overlap(coll: ti.template(), t, u):
    """Bounding-sphere phase (§4.1): the spheres grown by their motion overlap."""
    reach = coll.bound_reach[t] + coll.bound_reach[u]
    d = coll.bound_center[u] - coll.bound_center[t]
    return d.dot(d) <= reach * reach
