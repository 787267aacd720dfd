"""Procedural anatomy generators: geometric properties (pure NumPy, no Taichi)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from taichi_lap.scenes.anatomy import GENERATORS, defaults, sdf, tubes
from taichi_lap.scenes.anatomy import liver as liver_mod

from taichi_lap.core.geometry import Solid, SpringSheet, TriangleMesh, arc_length
from taichi_lap.core.params import KINDS

RNG = np.random.default_rng(1234)


def build(name, **overrides):
    params = defaults(name)
    params.update(overrides)
    return GENERATORS[name].build(params)


def tmesh(mesh: TriangleMesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)


def assert_closed(mesh: TriangleMesh):
    t = tmesh(mesh)
    assert t.is_watertight and t.is_winding_consistent
    assert t.volume > 0.0
    return t


# ------------------------------------------------------------------ registry


def _kind_ok(kind, v, p):
    def num_ok(x):
        return (p.lo is None or x >= p.lo) and (p.hi is None or x <= p.hi)

    if kind == "float":
        return isinstance(v, float) and num_ok(v)
    if kind == "int":
        return isinstance(v, int) and not isinstance(v, bool) and num_ok(v)
    if kind == "bool":
        return isinstance(v, bool)
    if kind == "str":
        return isinstance(v, str) and (p.choices is None or v in p.choices)
    if kind == "vec3":
        return len(v) == 3 and all(isinstance(x, (int, float)) and num_ok(x) for x in v)
    if kind == "vec3list":
        return len(v) >= 1 and all(_kind_ok("vec3", x, p) for x in v)
    return False


def test_registry_defaults_have_declared_kinds_and_ranges():
    expected = {
        "liver",
        "liver_vessel",
        "tube",
        "polyp",
        "sheet",
        "ellipsoid",
        "vessel",
        "intestine",
        "sphere",
        "box",
        "icosphere",
    }
    assert expected <= set(GENERATORS)
    for name, gen in GENERATORS.items():
        assert gen.name == name and gen.doc and gen.produces in ("solid", "surface", "spring_sheet")
        for key, p in gen.params.items():
            assert p.kind in KINDS and p.doc, (name, key)
            if p.kind in ("float", "int", "vec3", "vec3list"):
                assert p.lo is not None and p.hi is not None and p.lo < p.hi, (name, key)
            assert _kind_ok(p.kind, p.default, p), (name, key, p.default)


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_build_type_and_determinism(name):
    kinds = {"solid": Solid, "surface": TriangleMesh, "spring_sheet": SpringSheet}
    a, b = build(name), build(name)
    assert isinstance(a, kinds[GENERATORS[name].produces])
    if isinstance(a, TriangleMesh):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)
    elif isinstance(a, SpringSheet):
        assert np.array_equal(a.rows, b.rows) and np.array_equal(a.row_radius, b.row_radius)
    else:
        assert all(np.array_equal(x, y) for x, y in zip(a.bounds, b.bounds))
        pts = RNG.uniform(a.bounds[0], a.bounds[1], (500, 3))
        if a.sdf is not None:
            assert np.array_equal(a.sdf(pts), b.sdf(pts))
        if a.surface is not None:
            assert np.array_equal(a.surface.vertices, b.surface.vertices)


# ------------------------------------------------------------------ intestine


def test_intestine_rest_geometry():
    p = defaults("intestine")
    sheet = build("intestine")
    rows = sheet.rows
    assert rows.shape == (4, 100, 3)
    gut = rows[0]
    seg = np.linalg.norm(np.diff(gut, axis=0), axis=1)
    assert abs(seg.sum() - 4.0) < 0.01 * 4.0
    assert (
        seg.max() < 1.2 * seg.mean() and seg.min() > 0.3 * seg.mean()
    )  # chords shorten at fold tips
    assert np.abs(np.hypot(gut[:, 0], gut[:, 1]) - 0.15).max() < 1e-3
    # folds do not intersect: points >= 0.25 m apart along the gut stay >= 2 r apart
    s = arc_length(gut)
    far = np.abs(s[:, None] - s[None, :]) >= 0.25
    dist = np.linalg.norm(gut[:, None] - gut[None, :], axis=2)
    assert dist[far].min() >= 2 * p["intestine_radius"]
    # root on the axis within the vessel segment; middle rows on the linking segments
    root = rows[-1]
    assert np.abs(root[:, :2]).max() < 1e-12
    assert np.abs(root[:, 2]).max() <= 0.5 * p["vessel_length"] + 1e-12
    for k in range(1, 3):
        w = k / 3
        assert np.allclose(rows[k], (1 - w) * gut + w * root)
    assert np.allclose(sheet.row_radius, [0.02, 0.005, 0.005, 0.005])


def test_intestine_other_parameters():
    sheet = build("intestine", folds=8, rows=3, points_per_row=60, length=3.0)
    assert sheet.rows.shape == (3, 60, 3)
    assert abs(arc_length(sheet.rows[0])[-1] - 3.0) < 0.03


# ------------------------------------------------------------------ closed meshes


def test_tube_wall_is_closed_with_annulus_volume():
    for bend in (0.0, 0.4, 1.2):
        mesh = build("tube", bend=bend)
        t = assert_closed(mesh)
        exact = np.pi * (0.022**2 - 0.017**2) * 0.15
        assert abs(t.volume - exact) < 0.05 * exact
        assert np.abs(mesh.vertices.min(0) + mesh.vertices.max(0)).max() < 1e-9  # centred
    # inner wall faces the lumen: at the straight tube, normals of faces near r_in point at the axis
    mesh = build("tube", bend=0.0)
    t = tmesh(mesh)
    c = t.triangles_center
    r = np.hypot(c[:, 1], c[:, 2])
    radial = np.stack([0 * r, c[:, 1], c[:, 2]], 1) / np.maximum(r, 1e-12)[:, None]
    inner = (r < 0.0175) & (np.abs(c[:, 0]) < 0.07)
    outer = (r > 0.0215) & (np.abs(c[:, 0]) < 0.07)
    assert inner.sum() > 0 and outer.sum() > 0
    assert ((t.face_normals[inner] * radial[inner]).sum(1) < -0.9).all()
    assert ((t.face_normals[outer] * radial[outer]).sum(1) > 0.9).all()


def test_icosphere_and_ellipsoid_volumes():
    t = assert_closed(build("icosphere"))
    assert abs(t.volume / (4 / 3 * np.pi * 0.03**3) - 1) < 0.03
    assert np.allclose(np.linalg.norm(t.vertices, axis=1), 0.03, rtol=0.02)
    assert len(t.faces) == 20 * 4**2
    radii = np.array([0.015, 0.010, 0.012])
    t = assert_closed(build("ellipsoid"))
    assert abs(t.volume / (4 / 3 * np.pi * radii.prod()) - 1) < 0.03
    assert np.allclose(np.linalg.norm(t.vertices / radii, axis=1), 1.0, rtol=0.02)
    assert_closed(build("icosphere", subdivisions=0))


def test_vessel_tube_follows_spline():
    mesh = build("vessel")
    t = assert_closed(mesh)
    pts = np.asarray(defaults("vessel")["points"])
    centre = tubes.catmull_rom(pts, 64)
    length = arc_length(centre)[-1]
    assert 0.11 < length < 0.13
    exact = np.pi * 0.003**2 * length + 4 / 3 * np.pi * 0.003**3
    assert abs(t.volume - exact) < 0.06 * exact
    d = tubes.TubeTree([(centre, 0.003)])(mesh.vertices)
    assert np.abs(d).max() < 0.05 * 0.003


def test_sheet_is_open_unbiased_grid_facing_up():
    mesh = build("sheet")
    t = tmesh(mesh)
    assert not t.is_watertight and t.is_winding_consistent
    assert len(mesh.vertices) == 33 * 25 and len(mesh.triangles) == 2 * 32 * 24
    assert (t.face_normals[:, 1] > 0.9).all()
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    assert np.allclose([lo[0], hi[0], lo[2], hi[2]], [-0.06, 0.06, -0.04, 0.04])
    assert 0 < hi[1] <= 0.004 + 1e-12 and -0.004 - 1e-12 <= lo[1] < 0
    # the diagonal of each quad: half run one way, half the other
    e = mesh.vertices[t.edges_unique]
    diag = e[np.all(np.abs(e[:, 0, [0, 2]] - e[:, 1, [0, 2]]) > 1e-9, axis=1)]
    slope = np.sign((diag[:, 1, 0] - diag[:, 0, 0]) * (diag[:, 1, 2] - diag[:, 0, 2]))
    assert len(diag) == 32 * 24 and abs(slope.sum()) <= 1


# ------------------------------------------------------------------ signed distances


def test_sphere_box_exact_values():
    sph = build("sphere").sdf
    p = np.array([[0, 0, 0], [0.05, 0, 0], [0, -0.01, 0], [0.03, 0.04, 0.0]])
    assert np.allclose(sph(p), [-0.03, 0.02, -0.02, 0.02])
    box = build("box").sdf
    p = np.array([[0, 0, 0], [0.05, 0, 0], [0.0, 0.015, 0.0], [0.06, 0.06, 0.0], [0.03, 0.0, 0.0]])
    assert np.allclose(box(p), [-0.02, 0.02, -0.005, np.hypot(0.03, 0.04), 0.0])


def test_sdf_helpers():
    a, b = np.array([[0, 0, 0.0]]), np.array([[0.1, 0.02, 0.0]])
    pts = RNG.uniform(-0.1, 0.2, (2000, 3))
    t = np.linspace(0, 1, 3001)[:, None]
    centres, radii = a + (b - a) * t, 0.02 + (0.01 - 0.02) * t[:, 0]
    brute = (np.linalg.norm(pts[:, None] - centres[None], axis=2) - radii).min(1)
    d = sdf.round_cones(pts, a, b, [0.02], [0.01])[:, 0]
    assert np.array_equal(d < 0, brute < 0)
    assert np.abs(d - brute)[brute > 0].max() < 1e-6  # exact outside
    d1, d2 = sdf.sphere(pts, (0, 0, 0), 0.05), sdf.box(pts, (0.05, 0, 0), (0.02, 0.02, 0.02))
    assert (sdf.smooth_union(d1, d2, 0.01) <= np.minimum(d1, d2) + 1e-15).all()
    g = sdf.gradient(lambda q: sdf.sphere(q, (0, 0, 0), 0.05), pts)
    assert np.allclose(g, pts / np.linalg.norm(pts, axis=1, keepdims=True), atol=1e-6)


def test_polyp_shape():
    solid = build("polyp")
    f = solid.sdf
    top = 0.006 + 2 * 0.008
    p = np.array(
        [
            [0, 0.001, 0],
            [0, 0.014, 0],
            [0, -0.001, 0],
            [0.005, 0.001, 0],
            [0, top, 0],
            [0.008, 0.014, 0],
        ]
    )
    d = f(p)
    assert d[0] < 0 and d[1] < 0 and d[2] > 0 and d[3] > 0
    assert abs(d[4]) < 1e-9 and abs(d[5]) < 1e-9  # top of head, head equator
    grid = RNG.uniform(solid.bounds[0] - 0.005, solid.bounds[1] + 0.005, (20000, 3))
    inside = grid[f(grid) < 0]
    assert (inside >= solid.bounds[0]).all() and (inside <= solid.bounds[1]).all()


# ------------------------------------------------------------------ liver


def _bcc(lo, hi, h):
    axes = [np.arange(a, b + h, h) for a, b in zip(lo, hi)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return np.vstack([g, g + 0.5 * h])


@pytest.fixture(scope="module")
def liver_lattice():
    solid = build("liver")
    pts = _bcc(solid.bounds[0] - 0.003, solid.bounds[1] + 0.003, 0.0029)
    return solid, pts, solid.sdf(pts)


def test_liver_volume_size_and_bounds(liver_lattice):
    solid, pts, d = liver_lattice
    inside = pts[d < 0]
    # a BCC lattice of 2.9 mm holds 2 points per cube: N = 2 V / h^3 (seed 002 Table 1: 146090)
    volume = len(inside) * 0.0029**3 / 2
    assert 1.6e-3 < volume < 1.95e-3
    assert 0.96 * 146090 < len(inside) < 1.04 * 146090
    lo, hi = inside.min(0), inside.max(0)
    size = hi - lo
    assert 0.22 < size[0] < 0.27 and 0.08 < size[1] < 0.13 and 0.13 < size[2] < 0.17
    assert (lo >= solid.bounds[0]).all() and (hi <= solid.bounds[1]).all()
    assert (lo - solid.bounds[0]).max() < 0.004 and (solid.bounds[1] - hi).max() < 0.004
    assert np.linalg.norm(0.5 * (lo + hi)) < 0.02  # centred near the origin

    # large right lobe (-x), thin tapering left lobe (+x)
    def thickness(x):
        col = inside[np.abs(inside[:, 0] - x) < 0.003]
        return np.ptp(col[:, 1])

    assert thickness(-0.05) > 1.8 * thickness(0.08)


def test_liver_gradient_near_surface_and_scale(liver_lattice):
    solid, pts, d = liver_lattice
    near = pts[np.abs(d) < 0.003]
    near = near[RNG.choice(len(near), 4000, replace=False)]
    g = np.linalg.norm(sdf.gradient(solid.sdf, near, 1e-5), axis=1)
    assert np.abs(g - 1).max() < 0.2
    big = build("liver", scale=2.0)
    sample = near[:200]
    assert np.allclose(big.sdf(2 * sample), 2 * solid.sdf(sample))
    assert np.allclose(big.bounds[1], 2 * solid.bounds[1])


@pytest.mark.parametrize("vessel", liver_mod.VESSELS)
def test_liver_vessels_inside_liver_and_sdf_matches_mesh(vessel):
    for scale in (1.0, 0.6):
        f = liver_mod.liver_sdf(scale)
        branches = liver_mod.vessel_branches(vessel, scale)
        pts = np.vstack([p for p, _, _ in branches])
        rad = np.concatenate([r for _, r, _ in branches])
        assert (-f(pts) >= rad + 0.002 * scale - 1e-9).all()
    solid = build("liver_vessel", vessel=vessel)
    branches = liver_mod.vessel_branches(vessel)
    pts = np.vstack([p for p, _, _ in branches])
    assert (solid.sdf(pts) < 0).all()
    comps = tmesh(solid.surface).split(only_watertight=False)
    assert len(comps) == len(branches) >= 7
    for c in comps:
        assert c.is_watertight and c.is_winding_consistent and c.volume > 0
    # surface vertices on the zero set: own branch within 5 % of r, the union never outside
    v = solid.surface.vertices
    d = solid.sdf(v)
    near = []
    for p, r, _ in liver_mod.vessel_branches(vessel):
        q, rq = tubes.resample(p, r, 1.0)
        verts = tubes.tube_mesh(q, rq, 12).vertices
        assert np.abs(tubes.TubeTree([(q, rq)])(verts)).max() < 0.05 * rq.min()
        dv = solid.sdf(verts)
        assert dv.max() < 0.05 * rq.min()
        near.append(np.abs(dv) < 0.05 * rq.min())
        assert (-liver_mod.liver_sdf(1.0)(q) >= rq + 0.002 - 1e-9).all()  # the ring centres too
    assert np.concatenate(near).mean() > 0.5
    assert np.abs(d).min() < 1e-6 and len(v) == sum(len(n) for n in near)
    # the k-d tree pruning keeps the sign everywhere, exact values near the surface, a lower bound far away
    lo, hi = solid.bounds
    assert (v >= lo).all() and (v <= hi).all()
    pts = RNG.uniform(lo - 0.005, hi + 0.005, (20000, 3))
    fast, full = solid.sdf(pts), solid.sdf._all(pts)
    assert np.array_equal(fast < 0, full < 0) and (fast <= full + 1e-15).all()
    close = np.abs(full) < solid.sdf.extent
    assert np.allclose(fast[close], full[close], rtol=0, atol=1e-12)


def test_vessel_radii_and_portal_triad():
    def radii(name):
        return np.concatenate([r for _, r, _ in liver_mod.vessel_branches(name)])

    for name, (rmax, rmin) in {
        "portal_vein": (0.006, 0.002),
        "hepatic_vein": (0.005, 0.002),
        "hepatic_artery": (0.0025, 0.001),
        "bile_duct": (0.003, 0.0015),
    }.items():
        r = radii(name)
        assert abs(r.max() - rmax) < 1e-9 and abs(r.min() - rmin) < 2e-4, name
    # the artery and the bile duct run beside the portal branches without crossing them
    portal = liver_mod.vessel_branches("portal_vein")
    pp, pr = np.vstack([p for p, _, _ in portal]), np.concatenate([r for _, r, _ in portal])
    for name in ("hepatic_artery", "bile_duct"):
        for q, r, _ in liver_mod.vessel_branches(name):
            gap = np.linalg.norm(q[:, None] - pp[None], axis=2) - r[:, None] - pr[None]
            assert gap.min() > -1e-4
            assert np.median(gap.min(1)) < 0.002  # and stay close to them
    # three hepatic veins start at one confluence
    roots = [p[0] for p, _, k in liver_mod.vessel_branches("hepatic_vein") if k < 0]
    assert len(roots) == 3 and np.ptp(np.array(roots), axis=0).max() < 1e-12
