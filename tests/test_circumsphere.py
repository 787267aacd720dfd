"""Tissue collision (seed 000 §4): adaptive circumspheres (Eq. 4-6), the lazy update
(§4.2.3), the impulse response (§4.3) and both baselines, as promises."""

import math

import numpy as np
import pytest
import taichi as ti
from taichi_lap.kernels import shape_matching
from taichi_lap.kernels.collision import response, spheres

from taichi_lap.collision.surface_tables import broad_spheres
from taichi_lap.collision.tissue import TissueCollision
from taichi_lap.core.instruments import ToolShape
from taichi_lap.sim import Control, Solver
from tests.archrun import assert_backend_matches_cpu, cpu_result
from tests.helpers import BOX, simulation

DT = 1.0 / 60.0
METHODS = ("circumsphere", "bounding_sphere", "polygon")


@pytest.fixture(scope="module")
def box():
    """(data, model, state) of the test block, a geometry-only TissueCollision and an
    empty Control (created once: kernels compile per Control instance)."""
    _, data, model, state, control, _ = simulation([BOX], gravity=[0, 0, 0])
    return data, model, state, TissueCollision(model, tools=False, tissue_pairs=False), control


def skinned(data, x):
    return (data.surface_weight[..., None] * x[data.surface_index]).sum(axis=1)


def bounding_spheres(corners):
    """Centres and radii [m] of the smallest spheres around triangles (F, 3, 3): the
    longest edge's midpoint and half its length if right or obtuse, else the
    circumcentre and circumradius."""
    a, u, v = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    w = np.cross(u, v)
    w2 = (w * w).sum(axis=1)[:, None]
    circumcenter = a + (
        (u * u).sum(axis=1)[:, None] * np.cross(v, w)
        + (v * v).sum(axis=1)[:, None] * np.cross(w, u)
    ) / (2.0 * w2)
    edge = np.roll(corners, -1, axis=1) - corners
    length = np.linalg.norm(edge, axis=2)
    rows, longest = np.arange(len(corners)), length.argmax(axis=1)
    sq = np.sort(length, axis=1) ** 2
    obtuse = sq[:, 2] >= sq[:, 0] + sq[:, 1]
    center = np.where(
        obtuse[:, None], corners[rows, longest] + 0.5 * edge[rows, longest], circumcenter
    )
    return center, np.linalg.norm(corners - center[:, None], axis=2).max(axis=1)


def triangle_areas(data, x):
    c = skinned(data, x)[data.surface_triangles]
    return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)


def counted(collision, name, action):
    before = collision.counters()[name]
    action()
    return np.int32(collision.counters()[name] - before)


def test_circumsphere_centre_lies_on_the_normal_at_the_stated_depth_through_the_vertices(box):
    data, model, state, collision, no_tools = box
    state.reset(model)
    rng = np.random.default_rng(1)
    p = data.rest_position + rng.normal(0.0, 3e-4, data.rest_position.shape)
    state.p.from_numpy(p.astype(np.float32))
    collision.reset()
    collision.update_spheres(state)
    corners = skinned(data, p)[data.surface_triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    bound_center, radius_b = bounding_spheres(corners)
    goal = skinned(data, data.rest_position)[data.surface_triangles]
    recovery = np.linalg.norm(corners - goal, axis=2).mean(axis=1)  # ε of §4.2.2
    hermite = collision.curvature_factor.to_numpy()[: collision.rows_in_use]
    assert np.allclose(collision.recovery.to_numpy()[: collision.rows_in_use], recovery, atol=1e-6)
    depth = collision.scale_phi * radius_b / math.tan(collision.safe_angle) * hermite + recovery
    center, radius = (
        collision.sphere_center.to_numpy()[: collision.rows_in_use],
        collision.sphere_radius.to_numpy()[: collision.rows_in_use],
    )
    assert np.allclose(
        collision.bound_center.to_numpy()[: collision.rows_in_use], bound_center, atol=1e-6
    )
    assert np.allclose(center, bound_center - normal * depth[:, None], atol=2e-6)
    assert np.all((hermite > 0.0) & (hermite <= 1.0))
    distance = np.linalg.norm(corners - center[:, None, :], axis=2)
    edge2 = np.sort(np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2) ** 2, axis=1)
    acute = edge2[:, 2] < edge2[:, 0] + edge2[:, 1]
    assert acute.sum() > len(acute) // 2
    assert np.allclose(distance[acute], radius[acute, None], rtol=1e-4)  # through all three
    assert np.all(distance <= radius[:, None] * (1 + 1e-4))  # obtuse: the third one inside


@ti.kernel
def evaluate_hermite(table: ti.template(), curvature: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(curvature.shape[0]):
        out[i] = spheres.curvature_factor(table, curvature[i], 1.0)


def test_hermite_factor_is_one_when_flat_zero_when_sharp_with_zero_end_slopes(box):
    collision = box[3]
    k = np.array([0.0, 1e-3, 1.0, 1.001, 1e3, 1e3 + 1.0, 1e7], dtype=np.float32)
    h = np.zeros_like(k)
    evaluate_hermite(collision.hermite, k, h)
    assert h[0] == 1.0 and h[-1] < 1e-4
    assert h[2] == pytest.approx(0.5, abs=1e-3)  # H3(K_ref) = 1/2
    middle_slope = (h[3] - h[2]) / 1e-3
    assert abs((h[1] - h[0]) / 1e-3) < 0.05 * abs(middle_slope)  # flat at K = 0
    assert abs(h[5] - h[4]) < 1e-5  # flat as K grows
    assert np.all(np.diff(h) <= 0.0)


def dual_curvature_of(organ):
    """Curvature K [1/m²], triangle areas [m²] and neighbour table of an organ's surface."""
    _, data, model, state, _, _ = simulation([organ], gravity=[0, 0, 0])
    collision = TissueCollision(model, tools=False, tissue_pairs=False)
    collision.update_spheres(state)
    return (
        collision.curvature.to_numpy()[: collision.rows_in_use],
        triangle_areas(data, data.rest_position),
        collision.tri_neighbour.to_numpy()[: collision.rows_in_use],
    )


def test_dual_curvature_is_zero_on_a_flat_patch_and_one_over_r_squared_on_a_sphere():
    sheet = {
        "name": "fascia",
        "model": "fascia_lra",
        "geometry": {
            "generator": "sheet",
            "width": 0.04,
            "depth": 0.04,
            "resolution_x": 8,
            "resolution_z": 8,
            "sag": 0.0,
        },
    }
    k, area, neighbour = dual_curvature_of(sheet)
    interior = (neighbour >= 0).all(axis=1)
    assert interior.sum() > 50
    assert np.abs(k * area).max() < 1e-5  # angle deficit [rad]
    radius = 0.02
    ball = {
        "name": "ball",
        "model": "shape_matching",
        "geometry": {"generator": "icosphere", "radius": radius, "subdivisions": 3},
    }
    k, area, _ = dual_curvature_of(ball)
    assert np.median(k * radius**2) == pytest.approx(1.0, abs=0.05)
    assert (k * area).sum() == pytest.approx(4.0 * math.pi, rel=0.02)  # Gauss-Bonnet


def test_lazy_update_skips_recomputation_under_delta_and_recomputes_above(box):
    data, model, state, collision, no_tools = box
    state.reset(model)
    collision.reset()
    step = lambda: collision.update_spheres(state)
    assert counted(collision, "recomputed", step) == len(model.data.surface_triangles)
    assert counted(collision, "recomputed", step) == 0
    center, recovery = (
        collision.sphere_center.to_numpy()[: collision.rows_in_use],
        collision.recovery.to_numpy()[: collision.rows_in_use],
    )
    shift = np.float32([0.001, 0.002, 0.0])
    state.p.from_numpy((data.rest_position + shift).astype(np.float32))
    assert counted(collision, "recomputed", step) == 0  # rigid motion: same areas
    assert np.allclose(
        collision.sphere_center.to_numpy()[: collision.rows_in_use], center + shift, atol=1e-6
    )
    assert np.array_equal(
        collision.recovery.to_numpy()[: collision.rows_in_use], recovery
    )  # ε kept, not |p - g|
    rest_area = triangle_areas(data, data.rest_position)
    delta = collision.lazy_delta
    for stretch in (0.25 * delta, 3.0 * delta):
        state.reset(model)
        collision.reset()
        step()
        x = data.rest_position * np.array([1.0 + stretch, 1.0, 1.0])
        state.p.from_numpy(x.astype(np.float32))
        expected = int((np.abs(triangle_areas(data, x) / rest_area - 1.0) >= delta).sum())
        assert counted(collision, "recomputed", step) == expected
        assert (expected == 0) == (stretch < delta)


@ti.kernel
def exchange(
    v_t: ti.types.ndarray(dtype=ti.math.vec3),
    v_u: ti.types.ndarray(dtype=ti.math.vec3),
    normal: ti.types.ndarray(dtype=ti.math.vec3),
    w_t: ti.types.ndarray(),
    w_u: ti.types.ndarray(),
    out_t: ti.types.ndarray(dtype=ti.math.vec3),
    out_u: ti.types.ndarray(dtype=ti.math.vec3),
):
    for i in range(v_t.shape[0]):
        out_t[i], out_u[i] = response.exchange_impulse(v_t[i], v_u[i], normal[i], w_t[i], w_u[i])


@ti.kernel
def pair_translation(
    c: ti.types.ndarray(dtype=ti.math.vec3),
    r: ti.types.ndarray(),
    disp: ti.types.ndarray(dtype=ti.math.vec3),
    w: ti.types.ndarray(),
    out: ti.types.ndarray(dtype=ti.math.vec3),
):
    for i in range(c.shape[0] // 2):
        a, b = 2 * i, 2 * i + 1
        up = ti.Vector([0.0, 1.0, 0.0])
        _, out[a] = response.sphere_pair_translation(
            c[a], r[a], disp[a], w[a], c[b], r[b], disp[b], w[b], up
        )
        _, out[b] = response.sphere_pair_translation(
            c[b], r[b], disp[b], w[b], c[a], r[a], disp[a], w[a], up
        )


def test_impulse_exchange_conserves_momentum_and_a_tool_takes_none_of_it():
    rng = np.random.default_rng(3)
    n = 200
    v_t, v_u = (rng.normal(0, 1, (n, 3)).astype(np.float32) for _ in range(2))
    normal = rng.normal(0, 1, (n, 3))
    normal = (normal / np.linalg.norm(normal, axis=1, keepdims=True)).astype(np.float32)
    w_t = rng.uniform(0.5, 2.0, n).astype(np.float32)
    w_u = np.where(np.arange(n) % 4 == 0, 0.0, rng.uniform(0.5, 2.0, n)).astype(np.float32)
    out_t, out_u = np.zeros_like(v_t), np.zeros_like(v_u)
    exchange(v_t, v_u, normal, w_t, w_u, out_t, out_u)
    tool = w_u == 0.0
    m_t, m_u = 1.0 / w_t[~tool, None], 1.0 / w_u[~tool, None]
    assert np.allclose(
        m_t * out_t[~tool] + m_u * out_u[~tool], m_t * v_t[~tool] + m_u * v_u[~tool], atol=1e-4
    )
    assert np.array_equal(out_u[tool], v_u[tool])  # the kinematic tool keeps its velocity
    approach = np.einsum("ij,ij->i", out_t - out_u, normal)
    assert approach.min() > -1e-5  # no approaching normal velocity is left
    receding = np.einsum("ij,ij->i", v_t - v_u, normal) >= 0
    assert np.array_equal(out_t[receding], v_t[receding])
    # sphere pairs: translations carry no momentum and leave the spheres apart
    c = rng.uniform(-0.01, 0.01, (2 * n, 3)).astype(np.float32)
    r = rng.uniform(0.002, 0.006, 2 * n).astype(np.float32)
    disp = rng.normal(0, 0.002, (2 * n, 3)).astype(np.float32)
    w = rng.uniform(0.5, 2.0, 2 * n).astype(np.float32)
    out = np.zeros_like(c)
    pair_translation(c, r, disp, w, out)
    a, b = slice(0, None, 2), slice(1, None, 2)
    assert np.abs(out[a] / w[a, None] + out[b] / w[b, None]).max() < 1e-6
    gap = np.linalg.norm((c[a] + out[a]) - (c[b] + out[b]), axis=1) - (r[a] + r[b])
    assert gap.min() > -1e-6


def sheet_run(method: str, speed: float):
    """A 2 mm tissue sheet, pinned at two edges, met by a capsule (radius 2.5 mm) moving
    down at ``speed`` [m/s] until its axis is 3 mm below the sheet's rest top, then
    held; returns the final axis height and the heights of the top-face particles
    under the axis [m]."""
    sheet = {
        "name": "sheet",
        "model": "tet_clusters",
        "geometry": {"generator": "box", "half_extents": [0.02, 0.001, 0.015]},
        "material": {
            "particle_spacing": 0.001,
            "stiffness": 0.5,
            "damping": 1.0,
            "recover_rate": 0.05,
            "eta_on_contact": 0.7,
        },
        "attachments": [
            {"kind": "fixed", "box_min": [-1, -1, -1], "box_max": [-0.018, 1, 1]},
            {"kind": "fixed", "box_min": [0.018, -1, -1], "box_max": [1, 1, 1]},
        ],
    }
    _, data, model, state, no_tools, session_solver = simulation(
        [sheet], gravity=[0, 0, 0], shape_iterations=5
    )
    collision = TissueCollision(model, method=method, tissue_pairs=False, method_tools=True)
    solver = Solver(model, session_solver.settings, collision=collision)
    tools = Control()
    radius, y, y_end = 0.0025, 0.001 + 0.0025 + 0.0005, -0.002
    x0 = data.rest_position
    under = (np.abs(x0[:, 0]) < 6e-4) & (x0[:, 1] > 9e-4) & (np.abs(x0[:, 2]) < 0.012)
    held = 0
    while held < 3:
        tools.set_tool(0, [0.0, y, -0.03], [0.0, y, 0.03], radius)
        solver.substep(state, no_tools, DT, collision_control=tools)
        held += y == y_end
        y = max(y - speed * DT, y_end)
    return y, state.x.to_numpy()[under, 1]


def test_capsule_at_quarter_metre_per_second_does_not_tunnel_through_a_2mm_sheet():
    """dt = 1/60 s, 1 substep: 4.2 mm per step against triangles of R_b ≈ 0.7 mm. The
    circumsphere holds while the step stays under r + (φ cot θ / 2) R_b ≈ 4.3 mm (the
    line to the tool must pass through the triangle's cap); the bounding-sphere and
    polygon methods let the sheet through from about r ≈ 3 mm per step (0.2 m/s)."""
    axis, heights = sheet_run("circumsphere", 0.25)
    assert len(heights) > 20
    # the sheet stays below the capsule's axis (held at its fixed edges it pushes back
    # into the capsule: its top under the axis ends 1.7 mm inside the 2.5 mm radius)
    assert heights.max() < axis - 0.0005


def two_blocks():
    """Two blocks 0.5 mm apart, one above the other: (data, model, state, empty Control)."""
    lower = {
        **BOX,
        "name": "lower",
        "geometry": {"generator": "box", "half_extents": [0.012, 0.006, 0.01]},
    }
    upper = {
        **lower,
        "name": "upper",
        "geometry": {**lower["geometry"], "translate": [0.0, 0.0125, 0.0]},
    }
    _, data, model, state, control, _ = simulation([lower, upper], gravity=[0, 0, 0])
    return data, model, state, control


@pytest.fixture(scope="module")
def blocks():
    return two_blocks()


def pressed_blocks(data, model, state, no_tools, method: str, steps: int):
    """The upper block moved 2.5 mm down within one substep (2 mm into the lower one,
    0.5 mm apart at the start), then ``steps`` collision steps; returns p [m] and the
    upper block's particle mask."""
    x = data.rest_position
    upper = data.organ == 1
    state.reset(model)
    state.p.from_numpy((x - np.outer(upper, [0.0, 0.0025, 0.0])).astype(np.float32))
    collision = TissueCollision(model, method=method, tools=False)
    for _ in range(steps):
        collision.step(state, no_tools)
    return state.p.to_numpy(), upper


@pytest.mark.parametrize("method", METHODS)
def test_tissue_pairs_are_separated_after_the_response(blocks, method):
    data, model, state, no_tools = blocks
    p, upper = pressed_blocks(data, model, state, no_tools, method, 4)
    x0 = data.rest_position
    inner = (np.abs(x0[:, 0]) < 0.009) & (np.abs(x0[:, 2]) < 0.007)
    penetration = p[~upper & inner, 1].max() - p[upper & inner, 1].min()
    assert penetration < 1e-4, f"{method}: {penetration * 1e3:.2f} mm"
    assert not np.array_equal(p[~upper], x0[~upper])  # both blocks took part


UNION = [
    ToolShape("shaft"),
    ToolShape.sphere([0.0, -0.004, 0.015], 0.004),
    ToolShape.box([0.006, -0.002, 0.03], [0.003, 0.003, 0.004]),
]
"""A tool as a union: its shaft, a sphere and a box in the tool frame [m]."""


def capsule_distances(x, a, b, r):
    """NumPy signed distances [m] of points ``x`` to the capsule a-b of radius r."""
    t = np.clip((x - a) @ (b - a) / max((b - a) @ (b - a), 1e-30), 0.0, 1.0)
    return np.linalg.norm(x - (a + t[:, None] * (b - a)), axis=1) - r


def union_distances(x, tip, tail, radius, frame):
    """NumPy signed distances [m] of points ``x`` to each shape of :data:`UNION` placed
    in the tool ``frame`` (columns, Control.tool_frame), shape (3, n)."""
    capsule = lambda a, b, r: capsule_distances(x, a, b, r)

    sphere = tip + frame @ np.asarray(UNION[1].a)
    q = np.abs((x - tip - frame @ np.asarray(UNION[2].a)) @ frame) - np.asarray(UNION[2].size)
    box = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    return np.stack([capsule(tip, tail, radius), capsule(sphere, sphere, UNION[1].size[0]), box])


TILT = 0.004
"""Rise [m] of the union tool's axis over its 6 cm, so that no face of its shapes is
parallel to the block's lattice: with the tool level, triangles beside its box's
upright faces and under its sphere's centre (level with the top face) met the facing
test at a tie (gradient and normal at right angles), which rounding broke one way on
the CPU and the other on CUDA; now 1e-7 m of noise on the start moves no result by
more than 2e-7 m."""


def compute_collision_case(method: str = "circumsphere") -> dict:
    """A union-of-shapes tool pressed into the test block (particles pushed out by the
    prediction's contacts, triangles by the collision), and two blocks pressed
    together, a few steps each (also run on Vulkan)."""
    _, data, model, state, tools, _ = simulation([BOX], gravity=[0, 0, 0])
    collision = TissueCollision(model, method=method, method_tools=True)  # seed 000 §4.3
    tools.set_tool_shapes(0, UNION)
    for k in range(3):
        y = 0.012 + 0.004 - 0.001 * k
        tools.set_tool(0, [-0.03, y, 0.0], [0.03, y + TILT, 0.002], 0.005)
        shape_matching.predict(model, state, tools, (0.0, 0.0, 0.0), 1.0 / 60.0, 0)
        collision.step(state, tools)
        state.x.copy_from(state.p)  # the next substep starts where this one ended
    p2, _ = pressed_blocks(*two_blocks(), method, 2)
    return {
        "p": state.p.to_numpy(),
        "collided": state.collided.to_numpy(),
        "p_blocks": p2,
        "tool": np.float32([-0.03, y, 0.0, 0.03, y + TILT, 0.002]),
        "frame": tools.tool_frame.to_numpy()[0],
    }


def test_a_union_of_implicit_shapes_pushes_particles_and_triangles_out():
    result = cpu_result("tests.test_circumsphere:compute_collision_case")
    tip, tail = result["tool"][:3].astype(float), result["tool"][3:].astype(float)
    distance = union_distances(
        result["p"].astype(float), tip, tail, 0.005, result["frame"].astype(float)
    )
    # nothing left inside any shape beyond the sphere method's own error: a triangle's
    # circumsphere is translated out rigidly, so a corner the prediction had put on the
    # curved shaft slides along it (about move² / 2 radius, 0.1 mm for a 1 mm move)
    assert distance.min() > -2e-4
    assert np.all(distance.min(axis=1) < 2.5e-3)  # and every shape pushed some of it
    assert result["collided"].sum() > 10


def jaw_press(jaw_length: float):
    """A tool of radius 4 mm pointing down at the test block, 1 mm deeper each frame
    from where jaws of ``jaw_length`` [m] would touch the top to 3 mm into it (the
    shaft stays clear); returns the skinned surface from p, the rest surface and the
    Control."""
    _, data, model, state, _, _ = simulation([BOX], gravity=[0, 0, 0])
    collision = TissueCollision(model, tissue_pairs=False)
    tools, radius, top = Control(), 0.004, BOX["geometry"]["half_extents"][1]
    for k in range(4):
        y = top + 0.016 + 0.7 * radius - 0.001 * k
        tools.set_tool(0, [0.0, y, 0.0], [0.0, y + 0.2, 0.0], radius, jaw_length=jaw_length)
        for _ in range(3):
            collision.step(state, tools)
    return skinned(data, state.p.to_numpy()), skinned(data, data.rest_position), tools


def test_grasper_jaws_push_the_tissue_surface_and_a_probe_at_the_same_pose_does_not():
    surface, rest, tools = jaw_press(0.016)
    jaw, tip = tools.tool_jaw.to_numpy()[0], tools.tool_a.to_numpy()[0]
    jaw_radius = float(tools.tool_jaw_radius.to_numpy()[0])
    assert jaw[1] - jaw_radius < BOX["geometry"]["half_extents"][1] - 0.002  # into the block
    inside = capsule_distances(surface, jaw, tip, jaw_radius)
    assert inside.min() > -2e-4
    assert np.abs(surface - rest).max() > 2e-3
    probe_surface, _, _ = jaw_press(0.0)
    assert np.abs(probe_surface - rest).max() < 1e-6


@pytest.mark.vulkan
def test_vulkan_matches_cpu():
    result = assert_backend_matches_cpu("tests.test_circumsphere:compute_collision_case", 2e-5)
    assert result["collided"].sum() > 10


def numpy_broad_spheres(data, x, p):
    """(F, 4) broad spheres of kernels.collision.broad_phase.update_bounds: centroid of the
    skinned p, farthest corner + the centroid's motion from x [m]."""
    sphere = broad_spheres(skinned(data, p)[data.surface_triangles])
    start = skinned(data, x)[data.surface_triangles].mean(axis=1)
    sphere[:, 3] += np.linalg.norm(sphere[:, :3] - start, axis=1)
    return sphere


def rest_excluded(collision, data):
    """(F, F) bool: pairs the broad phase never lists (its module docstring), in NumPy,
    and (F, F) bool: pairs too near a tie of its f32 tests to say."""
    tri = data.surface_triangles
    shares = (tri[:, None, :, None] == tri[None, :, None, :]).any(axis=(2, 3))
    rest = collision.rest_sphere.to_numpy()[: collision.rows_in_use].astype(np.float64)
    normal = collision.rest_normal.to_numpy()[: collision.rows_in_use].astype(np.float64)
    body = collision.tri_body.to_numpy()[: collision.rows_in_use]
    d = rest[None, :, :3] - rest[:, None, :3]
    margin = np.linalg.norm(d, axis=2) - collision.rest_exclusion * (
        rest[:, None, 3] + rest[None, :, 3]
    )
    tests = np.stack(
        [normal @ normal.T, -np.einsum("tud,td->tu", d, normal), np.einsum("tud,ud->tu", d, normal)]
    )
    facing = (tests < 0.0).all(axis=0)
    tie = (np.abs(margin) < 1e-7) | (np.abs(tests) < 1e-6).any(axis=0)
    skipped = (
        shares
        | np.eye(len(tri), dtype=bool)
        | ((margin < 0.0) & ((body[:, None] == body[None, :]) | ~facing))
    )
    return skipped, tie


def listed_pairs(collision) -> np.ndarray:
    """(F, F) bool: the pair rows as a matrix."""
    f = collision.rows_in_use
    start = collision.rows.start.to_numpy()
    partner = collision.rows.partner.to_numpy()[: start[f]]
    out = np.zeros((f, f), dtype=bool)
    out[np.repeat(np.arange(f), np.diff(start[: f + 1])), partner] = True
    return out


def unlisted_and_meeting(collision, data, skipped, tie, x, p) -> tuple[int, int]:
    """(overlapping pairs left unlisted, overlapping pairs) of the broad spheres from
    x to p (``skipped`` and ``tie`` of :func:`rest_excluded`); no listed pair may be
    one the rest exclusion skips."""
    sphere = numpy_broad_spheres(data, x, p)
    gap = (
        np.linalg.norm(sphere[:, None, :3] - sphere[None, :, :3], axis=2)
        - sphere[:, None, 3]
        - sphere[None, :, 3]
    )
    meet = (gap < -1e-6) & ~skipped & ~tie
    listed = listed_pairs(collision)
    assert not (listed & skipped & ~tie).any()
    return int((meet & ~listed).sum()), int(meet.sum())


def test_triangles_stretched_far_beyond_the_hash_cells_keep_every_pair(blocks):
    """A scan reaches as far as the largest sphere the hash holds: the upper block
    stretched to 5 times its width within one substep (its triangles' broad spheres
    several cells across) and lowered onto the lower one lists every pair that
    meets."""
    data, model, state, control = blocks
    collision = TissueCollision(model, tools=False)
    state.reset(model)
    collision.step(state, control)
    x0, upper = data.rest_position, data.organ == 1
    stretched = x0.copy()
    stretched[upper] *= [5.0, 1.0, 5.0]
    stretched[upper, 1] -= 0.002
    state.p.from_numpy(stretched.astype(np.float32))
    collision.step(state, control)
    radius = numpy_broad_spheres(data, x0, stretched)[:, 3]
    assert radius.max() > 2.0 * collision.grid.cell_size
    skipped, tie = rest_excluded(collision, data)
    unlisted, meeting = unlisted_and_meeting(collision, data, skipped, tie, x0, stretched)
    assert meeting > 100 and unlisted == 0


def test_pair_lists_hold_every_pair_that_can_meet_as_triangles_drift():
    """Broad phase (kernels.collision.broad_phase): at every step of a motion in which some
    triangles drift past the rescan threshold and others do not, the pair rows hold
    every pair whose broad spheres overlap unless the rest exclusion skips it, and no
    skipped pair. A nodule joined into the lower block is one body with it."""
    lower = {
        **BOX,
        "name": "lower",
        "geometry": {"generator": "box", "half_extents": [0.012, 0.004, 0.01]},
    }
    upper = {
        **lower,
        "name": "upper",
        "geometry": {**lower["geometry"], "translate": [0.0, 0.0095, 0.0]},
    }
    nodule = {
        **BOX,
        "name": "nodule",
        "geometry": {"generator": "sphere", "radius": 0.004, "translate": [0.004, 0.004, 0.0]},
        "attachments": [{"kind": "join", "organ": "lower"}],
    }
    _, data, model, state, control, _ = simulation([lower, upper, nodule], gravity=[0, 0, 0])
    collision = TissueCollision(model, tools=False)
    body = collision.tri_body.to_numpy()[: collision.rows_in_use]
    organ_of = np.repeat(np.arange(3), [o.triangles[1] - o.triangles[0] for o in data.organs])
    assert body[organ_of == 2][0] == body[organ_of == 0][0] != body[organ_of == 1][0]
    skipped, tie = rest_excluded(collision, data)
    x0, upper_particles = data.rest_position, data.organ == 1
    rng = np.random.default_rng(5)

    def unlisted_meeting_pairs(x, p):
        return unlisted_and_meeting(collision, data, skipped, tie, x, p)

    x, rescans, found = x0, [], 0
    for step in range(16):
        wave = 0.0004 * np.sin(x0 @ rng.normal(0.0, 300.0, (3, 3)) + step)
        p = x0 + wave - np.outer(upper_particles, [0.0004 * step, 0.0003 * step, 0.0])
        state.x.from_numpy(x.astype(np.float32))
        state.p.from_numpy(p.astype(np.float32))
        rescans.append(counted(collision, "rescanned", lambda: collision.step(state, control)))
        unlisted, meeting = unlisted_meeting_pairs(x, p)
        assert unlisted == 0, f"step {step}: {unlisted} pairs unlisted"
        found += meeting
        x = p
    assert found > 100
    assert any(0 < r < collision.rows_in_use for r in rescans[1:])
    # a reset that puts the state back at rest keeps the lists: the triangles that moved
    # away from where they were listed rescan, the others keep their rows
    state.x.from_numpy(x0.astype(np.float32))
    state.p.from_numpy(x0.astype(np.float32))
    collision.reset()
    rescanned = counted(collision, "rescanned", lambda: collision.step(state, control))
    assert unlisted_meeting_pairs(x0, x0)[0] == 0
    assert 0 < rescanned < collision.rows_in_use


def folded_sheet(rest_exclusion: float):
    """A 2 mm sheet folded in half over its hinge (x = 0), the upper half's face 1 mm
    above the lower half's, pressed 1 mm into it within one substep, then 4 collision
    steps. Returns the lowest point of the upper half and the highest of the lower
    half over the columns whose layers were 20-40 mm apart at rest [m]."""
    sheet = {
        "name": "sheet",
        "model": "tet_clusters",
        "geometry": {"generator": "box", "half_extents": [0.02, 0.001, 0.008]},
        "material": {"particle_spacing": 0.001, "stiffness": 0.5, "damping": 0.0},
    }
    _, data, model, state, control, _ = simulation([sheet], gravity=[0, 0, 0])
    x0 = data.rest_position
    right = x0[:, 0] > 0.0
    folded = x0.copy()
    folded[right, 0], folded[right, 1] = -x0[right, 0], 0.003 - x0[right, 1]  # hinge y = 1.5 mm
    pressed = folded - np.outer(right, [0.0, 0.002, 0.0])
    state.x.from_numpy(folded.astype(np.float32))
    state.goal.from_numpy(folded.astype(np.float32))
    state.p.from_numpy(pressed.astype(np.float32))
    collision = TissueCollision(model, tools=False, rest_exclusion=rest_exclusion)
    for _ in range(4):
        collision.step(state, control)
    p = state.p.to_numpy()
    far = np.abs(x0[:, 0]) > 0.01
    return p[right & far, 1].min(), p[~right & far, 1].max()


def test_a_folded_sheet_collides_where_its_layers_were_far_apart_at_rest():
    """The rest exclusion skips only what was close at rest: the two halves of one
    organ folded onto each other (20-40 mm apart at rest, κ = 2 reaches about 3 mm)
    are separated; skipping every pair of the organ (κ huge) leaves them 1 mm inside
    each other."""
    upper, lower = folded_sheet(2.0)
    assert upper > lower - 1e-4
    upper, lower = folded_sheet(1000.0)
    assert upper < lower - 5e-4
