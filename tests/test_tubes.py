"""Generalized-cylinder tubes (kernels/generalized_cylinder.py, taichi_lap/render/tubes.py; seed 001
§5): spline, Eq. 10-11 sampling, Eq. 12 frames, Eq. 1/13 skinning, §5.3 controller."""

import functools

import numpy as np
import pytest
import taichi as ti

from taichi_lap.core.fields import FieldGroup
from taichi_lap.render.tubes import TessellationController, TubeMesh
from tests.archrun import assert_backend_matches_cpu

CAPACITY, TUBES, SIDES, MAX_LEVEL = 128, 3, 16, 3


def live_counts(mesh) -> tuple[int, int]:
    """(vertices, triangles) the last update of a TubeMesh wrote."""
    return int(mesh.live_vertex_count[None]), int(mesh.live_triangle_count[None])


@functools.cache
def rig():
    """One TubeMesh and its input/output fields for the whole module (one compilation)."""
    mesh = TubeMesh(CAPACITY, TUBES, sides=SIDES, max_level=MAX_LEVEL)
    g = FieldGroup()
    fields = dict(
        points=g.field(ti.f32, CAPACITY, vector=3),
        radius=g.field(ti.f32, CAPACITY),
        tube_range=g.field(ti.i32, TUBES, vector=2),
        vertices=g.field(ti.f32, mesh.vertex_capacity + 7, vector=3),
        normals=g.field(ti.f32, mesh.vertex_capacity + 7, vector=3),
        indices=g.field(ti.i32, 3 * mesh.triangle_capacity + 5),
        texcoords=g.field(ti.f32, mesh.vertex_capacity + 7, vector=3),
        reference=g.field(ti.f32, CAPACITY, vector=3),
    )
    g.finalize()
    return mesh, fields


def tessellate(
    polylines,
    radii,
    epsilon=0.1,
    level=2,
    vertex_offset=7,
    index_offset=5,
    *,
    keep=False,
    references=None,
):
    """Upload the tubes, update (their first frames anew, or with ``keep`` continuing
    the last call's; with ``references``, a material direction per point of each
    tube); return the mesh, the live output and the whole regions."""
    mesh, f = rig()
    if not keep:
        mesh.forget_frames()
    points = np.zeros((CAPACITY, 3), np.float32)
    radius = np.zeros(CAPACITY, np.float32)
    reference = np.zeros((CAPACITY, 3), np.float32)
    ranges, start = np.zeros((TUBES, 2), np.int32), 0
    for t, (p, r) in enumerate(zip(polylines, radii)):
        points[start : start + len(p)], radius[start : start + len(p)] = p, r
        if references is not None:
            reference[start : start + len(p)] = references[t]
        ranges[t] = start, start + len(p)
        start += len(p)
    f["points"].from_numpy(points)
    f["radius"].from_numpy(radius)
    f["tube_range"].from_numpy(ranges)
    f["reference"].from_numpy(reference)
    mesh.update(
        f["points"],
        f["radius"],
        f["tube_range"],
        len(polylines),
        f["vertices"],
        f["normals"],
        f["indices"],
        f["texcoords"],
        vertex_offset=vertex_offset,
        index_offset=index_offset,
        epsilon=epsilon,
        level=level,
        reference=None if references is None else f["reference"],
    )
    nv, nt = live_counts(mesh)
    v = f["vertices"].to_numpy()[vertex_offset : vertex_offset + mesh.vertex_capacity]
    n = f["normals"].to_numpy()[vertex_offset : vertex_offset + mesh.vertex_capacity]
    i = f["indices"].to_numpy()[index_offset : index_offset + 3 * mesh.triangle_capacity]
    i = i.reshape(-1, 3) - vertex_offset
    t = f["texcoords"].to_numpy()[vertex_offset : vertex_offset + nv]
    return mesh, dict(vertices=v[:nv], normals=n[:nv], triangles=i[:nt], texcoords=t), (v, n, i)


def samples(mesh, tube=0):
    s, c = mesh.tube_sample_start[tube], mesh.tube_sample_count[tube]
    return {
        k: getattr(mesh, "sample_" + k).to_numpy()[s : s + c]
        for k in ("segment", "parameter", "position", "tangent", "normal", "radius")
    }


def bend(degrees, h=1.0, legs=5):
    """A polyline of 2 legs of ``legs`` segments of length h [m] turning by ``degrees`` at 0."""
    a = np.radians(degrees)
    before = [[-h * k, 0.0, 0.0] for k in range(legs, 0, -1)]
    after = [[h * k * np.cos(a), h * k * np.sin(a), 0.0] for k in range(legs + 1)]
    return np.array(before + after, np.float32)


def helix(radius=0.05, rise=0.01, turns=2.0, n=60):
    """Points on x = R cos φ, y = R sin φ, z = rise φ [m]."""
    phi = np.linspace(0.0, 2 * np.pi * turns, n)
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), rise * phi], 1).astype(np.float32)


def catmull_rom(p, i):
    """NumPy reference: coefficients (4, 3) of segment i with Bessel ghost points."""
    p = np.asarray(p, np.float64)
    q = np.vstack([3 * p[0] - 3 * p[1] + p[2], p, 3 * p[-1] - 3 * p[-2] + p[-3]])
    q0, q1, q2, q3 = q[i : i + 4]
    m1, m2 = 0.5 * (q2 - q0), 0.5 * (q3 - q1)
    return np.array([q1, m1, 3 * (q2 - q1) - 2 * m1 - m2, 2 * (q1 - q2) + m1 + m2])


def ring_planes(vertices):
    """Centroid and unit normal (least-squares plane) of every ring, (rings, sides, 3)."""
    rings = vertices.reshape(-1, SIDES, 3).astype(np.float64)
    centre = rings.mean(1)
    normal = np.array([np.linalg.svd(r - c)[2][2] for r, c in zip(rings, centre)])
    return rings, centre, normal


def test_spline_interpolates_the_mechanical_points():
    p = helix(n=30)
    mesh, _, _ = tessellate([p], [np.full(len(p), 0.01)], epsilon=0.02)
    s = samples(mesh)
    knots = s["parameter"] == 0.0
    assert np.array_equal(s["position"][knots], p[s["segment"][knots]])
    assert np.allclose(s["position"][-1], p[-1], atol=1e-6)
    inner = ~knots & (s["parameter"] < 1.0)
    assert inner.sum() > 10
    for seg, u, x in zip(s["segment"][inner], s["parameter"][inner], s["position"][inner]):
        assert np.allclose(np.array([1, u, u * u, u**3]) @ catmull_rom(p, seg), x, atol=1e-6)


def test_rmf_frames_stay_orthonormal_and_follow_the_helix_rmf():
    R, rise = 0.05, 0.01
    p = helix(R, rise, turns=3.0, n=90)
    mesh, _, _ = tessellate([p], [np.full(len(p), 0.01)], epsilon=0.0, level=1)
    s = samples(mesh)
    t, k = s["tangent"].astype(np.float64), s["normal"].astype(np.float64)
    assert np.abs(np.linalg.norm(t, axis=1) - 1).max() < 1e-4
    assert np.abs(np.linalg.norm(k, axis=1) - 1).max() < 1e-4
    assert np.abs((t * k).sum(1)).max() < 1e-4
    # double reflection (Wang et al. 2008) in float64 on the same samples
    x, ref = s["position"].astype(np.float64), [k[0]]
    for j in range(len(x) - 1):
        v1 = x[j + 1] - x[j]
        r_l = ref[-1] - 2 / (v1 @ v1) * (v1 @ ref[-1]) * v1
        t_l = t[j] - 2 / (v1 @ v1) * (v1 @ t[j]) * v1
        v2 = t[j + 1] - t_l
        ref.append(r_l - 2 / (v2 @ v2) * (v2 @ r_l) * v2)
    assert np.abs(np.array(ref) - k).max() < 1e-4
    # analytic RMF of the helix: the normal turns against the Frenet normal by -torsion * s
    phi = np.unwrap(np.arctan2(x[:, 1], x[:, 0]))
    arc = phi * np.hypot(R, rise)
    frenet_n = np.stack([-np.cos(phi), -np.sin(phi), np.zeros_like(phi)], 1)
    frenet_b = np.cross(t, frenet_n)
    angle = np.unwrap(np.arctan2((k * frenet_b).sum(1), (k * frenet_n).sum(1)))
    twist = angle - angle[0] + rise / (R * R + rise * rise) * arc
    assert abs(angle[-1] - angle[0]) > 3.6  # 3 turns: the RMF turns 3.70 rad against Frenet
    assert np.abs(twist).max() < 2e-3  # measured 3.1e-4 rad (8e-6 with knots only)


def first_normal_angles(keep: bool) -> np.ndarray:
    """The first normal's angle [rad] round the x axis while the first point of a tube
    along x (points 1 cm apart) circles the axis 1 mm off it (the tube's first bend
    turns round it), in 24 steps of a turn."""
    angles = []
    for a in np.linspace(0.0, 2.0 * np.pi, 25)[1:]:
        p = np.stack([np.arange(12) * 0.01, np.zeros(12), np.zeros(12)], 1)
        p[0, 1:] = 0.001 * np.cos(a), 0.001 * np.sin(a)
        mesh, _, _ = tessellate([p.astype(np.float32)], [np.full(12, 0.003)], keep=keep)
        k = samples(mesh)["normal"][0]
        angles.append(np.arctan2(k[2], k[1]))
    return np.unwrap(angles)


def test_the_first_frame_turns_with_the_tube_not_with_its_first_bend():
    """Carried from call to call, the first normal (where the texcoords' angle starts)
    stays within 10° while the tube's first bend turns a full circle round its axis (it
    turns by the solid angle the first tangent sweeps, 8.5° off the axis: about 4°);
    the Frenet frame of each call alone follows the bend round (the tube's detail
    would spin about the tube)."""
    mesh, _ = rig()
    mesh.forget_frames()
    carried = first_normal_angles(keep=True)
    assert np.ptp(carried) < np.radians(10.0)
    frenet = first_normal_angles(keep=False)
    assert np.ptp(frenet) > np.radians(300.0)


def ring_start_angles(out, reference_at) -> np.ndarray:
    """For each ring, the angle [rad] between the direction from its centre to its
    first vertex (where the texcoords' angle is 0) and ``reference_at`` (rings, 3)
    made normal to the ring's axis."""
    rings = out["vertices"].reshape(-1, SIDES, 3).astype(np.float64)
    centre = rings.mean(axis=1)
    axis = np.gradient(centre, axis=0)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ref = reference_at - np.sum(reference_at * axis, axis=1, keepdims=True) * axis
    first = rings[:, 0] - centre
    first -= np.sum(first * axis, axis=1, keepdims=True) * axis
    cos = np.sum(first * ref, axis=1) / np.linalg.norm(first, axis=1) / np.linalg.norm(ref, axis=1)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def twisted_helix(turn: float) -> tuple[np.ndarray, np.ndarray]:
    """A helix's points and a material direction at each, across the tube, turned
    by ``turn`` [rad] about it over its length (a twisted intestine)."""
    points = helix(n=40).astype(np.float64)
    tangent = np.gradient(points, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross(tangent, [0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    angle = np.linspace(0.0, turn, len(points))[:, None]
    return points.astype(np.float32), np.cos(angle) * normal + np.sin(angle) * binormal


def test_the_texcoords_round_a_tube_follow_its_material_as_it_twists():
    """With a material direction per point (an intestine's: towards its mesentery),
    every ring's texcoord angle 0 lies towards that direction there (within 3°), as
    the material twists by a quarter and by a whole turn along a helix; the
    rotation-minimizing frames alone do not turn with the twist (the tube's detail
    would stay while its material turned)."""
    for turn in (0.5 * np.pi, 2.0 * np.pi):
        points, reference = twisted_helix(turn)
        _, out, _ = tessellate([points], [0.004], references=[reference])
        rings = len(out["vertices"]) // SIDES
        # each ring's material direction: the samples' references by the ring's place
        along = out["texcoords"].reshape(rings, SIDES, 3)[:, 0, 0] / 0.01
        at = np.stack(
            [np.interp(along, np.arange(len(points)), reference[:, a]) for a in range(3)], 1
        )
        assert np.degrees(ring_start_angles(out, at)).max() < 3.0
        _, plain, _ = tessellate([points], [0.004])
        assert np.degrees(ring_start_angles(plain, at)).max() > 45.0


def test_a_tube_with_a_material_direction_comes_back_as_it_was():
    """The first bend of a tube circling its axis, as in the test above, with a
    material direction fixed in space: after a full circle each vertex (each texcoord)
    is where the first call put it (the frames carried from call to call come back
    turned by the solid angle the first tangent swept)."""
    mesh, _ = rig()
    mesh.forget_frames()
    reference = np.tile([0.0, 0.0, 1.0], (12, 1))
    vertices = {True: [], False: []}
    for material in (True, False):
        mesh.forget_frames()
        for a in np.linspace(0.0, 2.0 * np.pi, 25):
            p = np.stack([np.arange(12) * 0.01, np.zeros(12), np.zeros(12)], 1)
            p[0, 1:] = 0.001 * np.cos(a), 0.001 * np.sin(a)
            _, out, _ = tessellate(
                [p.astype(np.float32)],
                [np.full(12, 0.003)],
                keep=True,
                references=[reference] if material else None,
            )
            vertices[material].append(out["vertices"])
    assert np.abs(vertices[True][-1] - vertices[True][0]).max() < 1e-6
    assert np.abs(vertices[False][-1] - vertices[False][0]).max() > 1e-5


def test_more_samples_land_where_curvature_is_high():
    p = bend(120.0)  # sharp bend at point 5; straight legs
    mesh, _, _ = tessellate([p], [np.full(len(p), 0.3)], epsilon=0.1)
    counts = mesh.segment_sample_count.to_numpy()[: len(p)]
    c = mesh.segment_indicator.to_numpy()[: len(p)]
    assert c[5] == pytest.approx(0.75) and np.abs(np.delete(c, 5)).max() < 1e-6
    assert counts[4] > 1 and counts[5] > 1  # the two segments meeting at the bend
    assert np.all(np.delete(counts, [4, 5, len(p) - 1]) == 1) and counts[-1] == 0


def test_eq11_samples_straddle_the_curvature_maximum():
    x = np.array([-2.0, -1.2, -0.55, 0.3, 1.1, 2.0])  # uneven knots on a parabola
    p = np.stack([x, 0.8 * x * x, 0 * x], 1).astype(np.float32)
    mesh, _, _ = tessellate([p], [np.full(len(p), 0.1)], epsilon=0.0)  # refine every segment
    peak = mesh.segment_peak.to_numpy()[: len(p) - 1]
    s = samples(mesh)
    grid = np.linspace(0.0, 1.0, 20001)
    interior = 0
    for i in np.nonzero(peak >= 0)[0]:
        C = catmull_rom(p, i)
        d1 = np.stack([np.zeros_like(grid), np.ones_like(grid), 2 * grid, 3 * grid**2], 1) @ C
        d2 = np.stack([0 * grid, 0 * grid, 2 + 0 * grid, 6 * grid], 1) @ C
        kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / np.linalg.norm(d1, axis=1) ** 3
        m = grid[np.argmax(kappa)]
        assert abs(peak[i] - m) < 2e-3, (i, peak[i], m)
        u = s["parameter"][s["segment"] == i]
        extra = np.sort(u[(u > 0) & (u < 1)])
        expected = [u for u in (2 * m / 3, (1 + 2 * m) / 3) if 0.05 <= u <= 0.95]
        assert np.allclose(extra, expected, atol=2e-3)  # m - δ and m + δ', Eq. 11
        interior += 0.1 < m < 0.9
    assert interior >= 1  # maxima at the knots are common; this one is inside a segment


@pytest.mark.parametrize("radius,legs,h", [(1.0, 5, 1.0), (0.3, 5, 1.0), (1.0, 20, 0.2)])
def test_cross_sections_do_not_cross_at_a_sharp_bend(radius, legs, h):
    """120° bend, tube radius = segment length (and 0.3 x, and 5 x): at every level every
    vertex of ring k+1 lies ahead of the plane of ring k and every vertex of ring k behind
    the plane of ring k+1, and no triangle faces against its vertex normals."""
    p = bend(120.0, h, legs)
    for level in range(MAX_LEVEL + 1):
        _, out, _ = tessellate([p], [np.full(len(p), radius)], epsilon=0.1, level=level)
        rings, centre, normal = ring_planes(out["vertices"])
        forward = np.diff(centre, axis=0)
        normal *= np.sign((np.vstack([forward, forward[-1:]]) * normal).sum(1))[:, None]
        ahead = np.einsum("ksx,kx->ks", rings[1:] - centre[:-1, None], normal[:-1]).min()
        behind = np.einsum("ksx,kx->ks", rings[:-1] - centre[1:, None], normal[1:]).max()
        assert ahead > 0 and behind < 0, (level, ahead, behind)
        v, tri = out["vertices"].astype(np.float64), out["triangles"]
        face = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
        real = np.linalg.norm(face, axis=1) > 1e-9 * radius**2
        facing = (face * out["normals"][tri].sum(1)).sum(1)
        assert np.all(facing[real] > 0), level
        assert np.isfinite(v).all()


def test_surface_lies_at_the_radius_on_straight_parts():
    direction = np.array([0.6, -0.48, 0.64])
    straight = (np.arange(12)[:, None] * 0.04 * direction).astype(np.float32)
    p = bend(90.0, 0.04, 8)
    mesh, out, _ = tessellate([straight, p], [np.full(12, 0.02), np.full(len(p), 0.015)])
    v = out["vertices"].astype(np.float64)
    first = v[: mesh.tube_ring_base[1] * SIDES]
    along = first @ direction
    distance = np.linalg.norm(first - along[:, None] * direction, axis=1)
    assert np.abs(distance / 0.02 - 1).max() < 0.01
    second = v[len(first) :].reshape(-1, SIDES, 3)
    legs = second[second[:, :, 0].max(1) < -0.1]  # more than 2.5 segments before the bend
    assert len(legs) > 20
    assert np.abs(np.hypot(legs[..., 1], legs[..., 2]) / 0.015 - 1).max() < 0.01


def test_texcoords_run_along_the_tube_and_round_it():
    """A tube's texcoords (the surface detail's rest-space points): along it, the
    spacing (0.01 m by default) times the point parameter, from 0 at the first ring to
    the last point's index at the last, the same round each ring and growing ring by
    ring; across it, the radius round the circle of the ring's side angle."""
    points = helix()
    _, out, _ = tessellate([points], [0.004])
    rings = out["texcoords"].reshape(-1, SIDES, 3).astype(np.float64)
    along = rings[:, :, 0]
    assert np.allclose(along, along[:, :1], atol=1e-7)
    assert along[0, 0] == pytest.approx(0.0, abs=1e-7)
    assert along[-1, 0] == pytest.approx(0.01 * (len(points) - 1), rel=1e-5)
    assert np.all(np.diff(along[:, 0]) > 0.0)
    assert np.allclose(np.linalg.norm(rings[:, :, 1:], axis=2), 0.004, rtol=1e-4)
    angle = np.arctan2(rings[0, :, 2], rings[0, :, 1])
    assert np.allclose(np.diff(np.unwrap(angle)), 2 * np.pi / SIDES, atol=1e-5)


def test_unused_capacity_is_degenerate_padding():
    p = helix(n=40)
    mesh, _, _ = tessellate([p], [np.full(40, 0.01)], epsilon=0.0, level=3)
    _, out, (v, n, i) = tessellate([p[:20]], [np.full(20, 0.01)], epsilon=0.5, level=1)
    nv, nt = len(out["vertices"]), len(out["triangles"])
    assert nt == 2 * (nv // SIDES - 1) * SIDES and 0 < nt < mesh.cap_triangle_start
    rings_v, rings_t = slice(nv, mesh.cap_vertex_start), slice(nt, mesh.cap_triangle_start)
    assert np.all(i[rings_t] == 0) and not np.any(v[rings_v]) and not np.any(n[rings_v])
    assert out["triangles"].min() == 0 and out["triangles"].max() == nv - 1


def test_each_tube_is_closed_by_its_rounded_end_caps():
    """With its two caps a tube is a closed surface (every edge in exactly two
    triangles) facing out (its triangles run each edge in opposite directions and
    enclose a positive volume: the renderer skips its back faces); each cap is a half sphere of the end ring's radius about the end ring's
    centre, its pole one radius beyond the end along the tube; the caps of the tube
    slots left empty are zero vertices and degenerate triangles."""
    from taichi_lap.core.mesh import enclosed_volume, inconsistent_edges
    from taichi_lap.kernels.generalized_cylinder import CAP_RINGS

    p = helix(n=30)
    mesh, out, (v, n, i) = tessellate([p], [np.full(len(p), 0.01)])
    per_cap = (CAP_RINGS - 1) * SIDES + 1
    cap_triangles = (2 * CAP_RINGS - 1) * SIDES
    start = mesh.cap_triangle_start
    closed = np.concatenate([out["triangles"], i[start : start + 2 * cap_triangles]])
    edges = np.sort(closed[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert np.all(uses == 2)
    assert inconsistent_edges(closed) == 0
    assert enclosed_volume(v, closed) > 0.0
    assert np.all(i[start + 2 * cap_triangles :] == 0)
    assert not np.any(v[mesh.cap_vertex_start + 2 * per_cap :])
    rings = len(out["vertices"]) // SIDES
    for end, ring in ((0, 0), (1, rings - 1)):
        centre = mesh.ring_center.to_numpy()[ring]
        axis = mesh.ring_center_rate.to_numpy()[ring]
        axis *= (2 * end - 1) / np.linalg.norm(axis)
        first = mesh.cap_vertex_start + end * per_cap
        cap = v[first : first + per_cap]
        assert np.allclose(np.linalg.norm(cap - centre, axis=1), 0.01, rtol=1e-3)
        assert np.allclose(cap[-1], centre + 0.01 * axis, atol=1e-5)
        normals = n[first : first + per_cap]
        assert np.allclose(normals, (cap - centre) / 0.01, atol=1e-3)


def test_packed_tubes_match_tubes_drawn_alone():
    a, b = helix(n=25), bend(100.0, 0.03, 6) + np.float32([0.2, 0, 0])
    ra, rb = np.full(len(a), 0.01), np.linspace(0.01, 0.02, len(b))
    _, alone_a, _ = tessellate([a], [ra])
    _, alone_b, _ = tessellate([b], [rb])
    _, both, _ = tessellate([a, np.zeros((1, 3)), b], [ra, [0.01], rb])  # middle tube: 1 point
    na = len(alone_a["vertices"])
    assert np.array_equal(both["vertices"][:na], alone_a["vertices"])
    assert np.array_equal(both["vertices"][na:], alone_b["vertices"])
    assert np.array_equal(both["triangles"][len(alone_a["triangles"]) :], alone_b["triangles"] + na)


def wiggle(n=100, seed=3):
    """An intestine-like polyline: 4 m, 100 points, random bends up to ~70°."""
    rng = np.random.default_rng(seed)
    heading = np.array([1.0, 0, 0])
    p = [np.zeros(3)]
    for _ in range(n - 1):
        axis = rng.normal(size=3)
        axis -= axis @ heading * heading
        angle = rng.uniform(0.0, 1.2) ** 2
        axis /= np.linalg.norm(axis)
        heading = heading * np.cos(angle) + np.cross(axis, heading) * np.sin(angle)
        p.append(p[-1] + 0.04 * heading)
    return np.array(p, np.float32)


@pytest.mark.parametrize("target_ms", [2.0, 4.0, 8.0])
def test_frame_time_controller_converges_on_a_linear_cost_model(target_ms):
    """frame_ms = 1 + 1e-4 * triangles (3.2 ms at the start, level 2): within 10% of the
    target from the 12th update on, for 40 updates (measured: from the 4th, 6th, 10th)."""
    p = wiggle()
    radius = np.full(len(p), 0.02)
    control = TessellationController(target_ms, max_level=MAX_LEVEL)
    times = []
    for _ in range(52):
        tessellate([p], [radius], control.epsilon, control.level)
        frame_ms = 1.0 + 1e-4 * live_counts(rig()[0])[1]
        times.append(frame_ms)
        epsilon, level = control.update(frame_ms)
        assert 0.0 <= epsilon <= 0.5 and 0 <= level <= MAX_LEVEL
    within = np.abs(np.array(times) / target_ms - 1) <= 0.1
    assert within[12:].all() and not within[0], times


def test_frame_time_controller_stops_at_its_bounds():
    slow = TessellationController(4.0, max_level=MAX_LEVEL)
    for _ in range(20):
        slow.update(100.0)
    assert (slow.level, slow.epsilon) == (0, 0.5)
    for _ in range(20):
        slow.update(0.1)
    assert slow.level == MAX_LEVEL and slow.epsilon == pytest.approx(0.0, abs=1e-6)


def test_two_runs_are_identical():
    p = wiggle(60, seed=5)
    first = tessellate([p], [np.linspace(0.01, 0.03, 60)], 0.05, 2)[1]
    tessellate([helix()], [np.full(60, 0.01)], 0.0, 3)
    second = tessellate([p], [np.linspace(0.01, 0.03, 60)], 0.05, 2)[1]
    for key in first:
        assert np.array_equal(first[key], second[key]), key


def vulkan_case(level=2):
    """Live output for a wiggle and a bend, and their end caps (run on CPU and on
    Vulkan)."""
    mesh, out, (vertices, normals, _) = tessellate(
        [wiggle(50, seed=7), bend(120.0, 0.03, 6)],
        [np.full(50, 0.02), np.full(13, 0.03)],
        0.1,
        level,
    )
    caps = slice(mesh.cap_vertex_start, None)
    return dict(out, cap_vertices=vertices[caps], cap_normals=normals[caps])


@pytest.mark.vulkan
def test_vulkan_matches_cpu():
    # unit normals: CUDA's fused multiply-adds left them 2.5e-5 from the CPU's (an H100)
    cpu = assert_backend_matches_cpu(
        "tests.test_tubes:vulkan_case", 1e-5, {"normals": 1e-4, "cap_normals": 1e-4}
    )
    assert len(cpu["triangles"]) > 1000
