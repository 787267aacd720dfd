"""Visibility buffer and G-buffer resolve (kernels/raster.py): exact pixel-centre
coverage with the top-left rule, watertight shared edges, depth order, near-plane
clipping, agreement with a NumPy ray cast, interpolation, determinism, Vulkan."""

import functools

import numpy as np
import pytest
import taichi as ti
from taichi_lap.kernels.raster import BACKGROUND_DEPTH, GBuffer, camera_matrices, ray_basis

from tests.archrun import assert_backend_matches_cpu

WIDTH, HEIGHT = 64, 48
VERTEX_CAPACITY, TRIANGLE_CAPACITY = 1024, 2048
EYE = np.zeros(3)


class Mesh:
    """Positions [m], normals, char (zeros), flat triangle ids, each triangle's object
    and the objects' one-sided flags in one SNode tree, refilled per test."""

    OBJECTS = 4

    def __init__(self):
        self.positions = ti.Vector.field(3, ti.f32)
        self.normals = ti.Vector.field(3, ti.f32)
        self.char = ti.field(ti.f32)
        self.triangles = ti.field(ti.i32)
        self.triangle_object = ti.field(ti.i32)
        self.one_sided = ti.field(ti.i32)
        builder = ti.FieldsBuilder()
        builder.dense(ti.i, VERTEX_CAPACITY).place(self.positions, self.normals, self.char)
        builder.dense(ti.i, 3 * TRIANGLE_CAPACITY).place(self.triangles)
        builder.dense(ti.i, TRIANGLE_CAPACITY).place(self.triangle_object)
        builder.dense(ti.i, self.OBJECTS).place(self.one_sided)
        self.tree = builder.finalize()

    def load(self, vertices, faces, normals=None, objects=None, one_sided=()):
        """Fill the mesh; ``objects``: each face's object (default 0), ``one_sided``:
        the objects drawn one-sided (default none)."""
        vertices, faces = (
            np.asarray(vertices, np.float32),
            np.asarray(faces, np.int32).reshape(-1, 3),
        )
        normals = np.tile([0.0, 0.0, 1.0], (len(vertices), 1)) if normals is None else normals
        objects = np.zeros(len(faces), np.int32) if objects is None else objects
        sided = np.isin(np.arange(self.OBJECTS), one_sided).astype(np.int32)
        for field, values, rows in (
            (self.positions, vertices, VERTEX_CAPACITY),
            (self.normals, np.asarray(normals, np.float32), VERTEX_CAPACITY),
            (self.triangles, faces.reshape(-1), 3 * TRIANGLE_CAPACITY),
            (self.triangle_object, np.asarray(objects, np.int32), TRIANGLE_CAPACITY),
            (self.one_sided, sided, self.OBJECTS),
        ):
            padded = np.zeros((rows,) + values.shape[1:], values.dtype)
            padded[: len(values)] = values
            field.from_numpy(padded)
        return len(faces)


@functools.cache
def mesh() -> Mesh:
    return Mesh()


@functools.cache
def gbuffer(by_pixel: bool) -> GBuffer:
    return GBuffer(WIDTH, HEIGHT, by_pixel=by_pixel)


def camera(near: float):
    """View-projection of the default camera: at the origin looking down -z, fov 90 deg."""
    view, projection = camera_matrices(
        EYE, (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 90.0, WIDTH / HEIGHT, near, 100.0
    )
    return projection @ view


def draw(target: GBuffer, count: int, near: float):
    """Rasterize the first ``count`` triangles of the shared mesh into ``target``, seen
    by the default camera with the near plane at ``near`` [m]."""
    target.render(
        mesh().positions,
        mesh().normals,
        mesh().char,
        mesh().char,  # no blood either
        mesh().triangles,
        mesh().triangle_object,
        mesh().one_sided,
        count,
        EYE,
        camera(near),
        near,
    )


def render(
    vertices, faces, *, normals=None, near=0.01, by_pixel=False, objects=None, one_sided=()
) -> dict:
    """G-buffer arrays of a mesh seen by the default camera (``objects`` and
    ``one_sided`` as :meth:`Mesh.load` takes them)."""
    count = mesh().load(vertices, faces, normals, objects, one_sided)
    target = gbuffer(by_pixel)
    draw(target, count, near)
    return {
        "triangle": target.triangle.to_numpy(),
        "depth": target.depth.to_numpy(),
        "position": target.position.to_numpy(),
        "normal": target.normal.to_numpy(),
    }


def from_screen(points_px, depth=1.0):
    """World points [m] that the default camera (fov 90 deg) projects to ``points_px``
    (x right, y up, in pixels) at view depth ``depth``."""
    p = np.asarray(points_px, np.float64)
    x = (2.0 * p[:, 0] / WIDTH - 1.0) * depth * WIDTH / HEIGHT
    y = (2.0 * p[:, 1] / HEIGHT - 1.0) * depth
    return np.stack([x, y, np.full(len(p), -depth)], -1)


def reference_coverage(polygon_px) -> np.ndarray:
    """Pixel centres inside a convex polygon (pixels, either orientation), in exact
    integers on the 1/256 px grid, with the top-left rule for y up."""
    corners = np.round(np.asarray(polygon_px, np.float64) * 256).astype(np.int64)
    following = np.roll(corners, -1, axis=0)
    area2 = np.sum(corners[:, 0] * following[:, 1] - corners[:, 1] * following[:, 0])
    if area2 < 0:
        corners = corners[::-1]
    px, py = np.meshgrid(np.arange(WIDTH) * 256 + 128, np.arange(HEIGHT) * 256 + 128, indexing="ij")
    inside = np.full((WIDTH, HEIGHT), area2 != 0)
    for u, v in zip(corners, np.roll(corners, -1, axis=0)):
        d = v - u
        edge = d[0] * (py - u[1]) - d[1] * (px - u[0])
        inside &= edge >= (0 if d[1] < 0 or (d[1] == 0 and d[0] < 0) else 1)
    return inside


TRIANGLES_PX = {
    "general": [(3.3, 4.1), (50.7, 9.9), (20.2, 40.6)],
    "clockwise": [(3.3, 4.1), (20.2, 40.6), (50.7, 9.9)],
    "edges through centres": [(10.5, 10.5), (40.5, 10.5), (10.5, 40.5)],
    "diagonal through centres": [(5.5, 5.5), (45.5, 25.5), (25.5, 45.5)],
    "sliver": [(2.0, 3.0), (60.0, 30.0), (31.1, 16.6)],
    "partly off screen": [(-20.0, -10.0), (90.0, 20.0), (30.0, 70.0)],
    "one pixel": [(30.4, 20.4), (30.6, 20.4), (30.5, 20.6)],
}


@pytest.mark.parametrize("by_pixel", [False, True])
@pytest.mark.parametrize("name", list(TRIANGLES_PX))
def test_triangle_covers_exactly_the_pixel_centres_inside_it(name, by_pixel):
    corners = TRIANGLES_PX[name]
    covered = render(from_screen(corners), [0, 1, 2], by_pixel=by_pixel)["triangle"] == 0
    assert np.array_equal(covered, reference_coverage(corners))
    assert covered.sum() > 0 or name == "sliver"


@pytest.mark.parametrize("by_pixel", [False, True])
def test_back_faces_are_skipped_only_for_one_sided_objects(by_pixel):
    """A triangle counter-clockwise on screen (facing the eye) is drawn either way; one
    clockwise (its back seen) is drawn for a two-sided object, skipped for a
    one-sided one; the flag is the triangle's object's."""
    world = from_screen([(10.2, 8.1), (50.7, 12.3), (28.4, 40.9)])  # counter-clockwise
    for faces, one_sided, drawn in (
        ([0, 1, 2], (), True),
        ([0, 1, 2], (0,), True),
        ([0, 2, 1], (), True),
        ([0, 2, 1], (0,), False),
        ([0, 2, 1], (1,), True),
    ):
        covered = render(world, faces, by_pixel=by_pixel, one_sided=one_sided)["triangle"] == 0
        assert covered.any() == drawn, (faces, one_sided)


@pytest.mark.parametrize("by_pixel", [False, True])
def test_one_sided_closed_surface_draws_the_same_image(by_pixel):
    """Seen from outside, a closed surface facing out hides its back faces behind its
    front ones: drawn one-sided it shows the same triangle at the same depth at every
    pixel. Turned inside out, one-sided shows its far side's inside over the same
    pixels (the near side is skipped), so the skipping acts."""
    vertices, faces = icosphere()
    vertices = vertices * 0.5 + [0.05, -0.02, -0.9]
    both = render(vertices, faces, by_pixel=by_pixel)
    one = render(vertices, faces, by_pixel=by_pixel, one_sided=(0,))
    assert (both["triangle"] >= 0).sum() > 500
    assert np.array_equal(one["triangle"], both["triangle"])
    assert np.array_equal(one["depth"], both["depth"])
    inside_out = render(vertices, faces[:, ::-1], by_pixel=by_pixel, one_sided=(0,))
    covered = both["triangle"] >= 0
    assert np.array_equal(inside_out["triangle"] >= 0, covered)
    farther = inside_out["depth"][covered] - both["depth"][covered]
    assert np.all(farther >= 0.0) and np.median(farther) > 0.3  # the sphere is 1 m across


def fan_around(centre, outer):
    """Vertices and faces of a fan: the centre vertex joined to each outer edge."""
    vertices = [centre] + list(outer)
    faces = [[0, 1 + k, 1 + (k + 1) % len(outer)] for k in range(len(outer))]
    return vertices, faces


def coverage_counts(vertices_px, faces, by_pixel):
    """How many triangles cover each pixel centre, drawing them one at a time."""
    world = from_screen(vertices_px)
    return sum(
        (render(world, face, by_pixel=by_pixel)["triangle"] == 0).astype(int) for face in faces
    )


@pytest.mark.parametrize("by_pixel", [False, True])
def test_shared_edges_leave_no_gap_and_no_double_coverage(by_pixel):
    square = [(10.5, 10.5), (30.5, 10.5), (30.5, 30.5), (10.5, 30.5)]  # diagonal through centres
    counts = coverage_counts(square, [[0, 1, 2], [0, 2, 3]], by_pixel)
    expected = np.zeros((WIDTH, HEIGHT), bool)
    expected[10:30, 11:31] = True  # left and top edges included, right and bottom not
    assert counts.max() == 1 and np.array_equal(counts == 1, expected)

    octagon = [(32.5 + 14 * np.cos(a), 24.5 + 14 * np.sin(a)) for a in np.arange(8) * np.pi / 4]
    octagon = [(np.round(x * 2) / 2, np.round(y * 2) / 2) for x, y in octagon]  # centres, edges
    vertices, faces = fan_around((32.5, 24.5), octagon)  # hub on a pixel centre
    counts = coverage_counts(vertices, faces, by_pixel)
    assert counts.max() == 1 and np.array_equal(counts == 1, reference_coverage(octagon))
    assert counts[32, 24] == 1


def test_jittered_grid_covers_its_rectangle_once():
    rng = np.random.default_rng(3)
    xs, ys = np.linspace(4.5, 58.5, 7), np.linspace(4.5, 42.5, 5)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1)
    grid[1:-1, 1:-1] += rng.uniform(-3.0, 3.0, grid[1:-1, 1:-1].shape)
    grid = np.round(grid * 256) / 256
    index = np.arange(grid.shape[0] * grid.shape[1]).reshape(grid.shape[:2])
    faces = [
        [index[i, j], index[i + 1, j], index[i + 1, j + 1]] for i in range(6) for j in range(4)
    ]
    faces += [
        [index[i, j], index[i + 1, j + 1], index[i, j + 1]] for i in range(6) for j in range(4)
    ]
    counts = coverage_counts(grid.reshape(-1, 2), faces, False)
    rectangle = reference_coverage([(4.5, 4.5), (58.5, 4.5), (58.5, 42.5), (4.5, 42.5)])
    assert counts.max() == 1 and np.array_equal(counts == 1, rectangle)


def test_far_off_screen_vertex_is_pulled_in_without_gaps():
    a, b, c, far = (
        (10.5, 10.5),
        (50.5, 15.5),
        (40.5, 40.5),
        (3.0e6, 1.0e6),
    )  # far: past the guard band
    counts = coverage_counts([a, b, c, far], [[0, 3, 2], [0, 1, 3]], False)
    expected = reference_coverage([a, b, far, c])
    assert counts.max() == 1 and (counts.sum() > 500)
    assert np.count_nonzero((counts == 1) != expected) <= 2  # the pull turns edges by ~1e-5 rad


def test_nearer_of_two_overlapping_triangles_wins_in_both_orders():
    corners = [(5.0, 5.0), (55.0, 8.0), (20.0, 40.0)]
    near_tri, far_tri = from_screen(corners, 1.0), from_screen(corners, 2.0)
    overlap = reference_coverage(corners)
    for order in ([near_tri, far_tri], [far_tri, near_tri]):
        result = render(np.concatenate(order), [[0, 1, 2], [3, 4, 5]])
        nearer = 0 if order[0] is near_tri else 1
        assert np.all(result["triangle"][overlap] == nearer)
        distance = np.linalg.norm(result["position"][overlap], axis=-1)
        assert np.allclose(result["depth"][overlap], distance)
    twins = render(np.concatenate([near_tri, near_tri]), [[3, 4, 5], [0, 1, 2]])
    assert np.all(twins["triangle"][overlap] == 0)  # equal depths: the lower triangle id


def icosphere(subdivisions=2, seed=0, jitter=0.15):
    """Vertices and faces of a bumpy icosphere of radius ~1."""
    t = (1.0 + 5**0.5) / 2.0
    vertices = [
        (-1, t, 0),
        (1, t, 0),
        (-1, -t, 0),
        (1, -t, 0),
        (0, -1, t),
        (0, 1, t),
        (0, -1, -t),
        (0, 1, -t),
        (t, 0, -1),
        (t, 0, 1),
        (-t, 0, -1),
        (-t, 0, 1),
    ]
    faces = [
        (0, 11, 5),
        (0, 5, 1),
        (0, 1, 7),
        (0, 7, 10),
        (0, 10, 11),
        (1, 5, 9),
        (5, 11, 4),
        (11, 10, 2),
        (10, 7, 6),
        (7, 1, 8),
        (3, 9, 4),
        (3, 4, 2),
        (3, 2, 6),
        (3, 6, 8),
        (3, 8, 9),
        (4, 9, 5),
        (2, 4, 11),
        (6, 2, 10),
        (8, 6, 7),
        (9, 8, 1),
    ]
    vertices = [np.array(v, float) / np.linalg.norm(v) for v in vertices]
    for _ in range(subdivisions):
        midpoint, refined = {}, []
        for a, b, c in faces:
            m = []
            for u, v in ((a, b), (b, c), (c, a)):
                if (u, v) not in midpoint:
                    middle = vertices[u] + vertices[v]
                    vertices.append(middle / np.linalg.norm(middle))
                    midpoint[(u, v)] = midpoint[(v, u)] = len(vertices) - 1
                m.append(midpoint[(u, v)])
            refined += [(a, m[0], m[2]), (b, m[1], m[0]), (c, m[2], m[1]), (m[0], m[1], m[2])]
        faces = refined
    vertices = np.array(vertices)
    radius = 1.0 + jitter * np.random.default_rng(seed).uniform(-1.0, 1.0, len(vertices))
    return vertices * radius[:, None], np.array(faces)


def pixel_rays():
    """Unit directions through the pixel centres of the default camera, (W, H, 3)."""
    x, y = np.meshgrid(
        (np.arange(WIDTH) + 0.5) * 2 / WIDTH - 1,
        (np.arange(HEIGHT) + 0.5) * 2 / HEIGHT - 1,
        indexing="ij",
    )
    d = np.stack([x * WIDTH / HEIGHT, y, -np.ones_like(x)], -1)  # fov 90 deg: tan(45 deg) = 1
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def ray_cast(vertices, faces, near=0.0):
    """Brute-force nearest hit per pixel in f64 (Möller-Trumbore), keeping hits at view
    depth >= near: triangle (-1 none), distance [m], and ``clear``: 0 where the ray
    passes within 2e-3 (barycentric) of some triangle's edge, where ties are possible."""
    rays = pixel_rays().reshape(-1, 3)
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))  # the eye is at the origin
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(rays[:, None, :], e2[None])
    det = np.einsum("tk,ptk->pt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.einsum("tk,ptk->pt", -v0, p) / det
        q = np.cross(-v0, e1)
        v = np.einsum("pk,tk->pt", rays, q) / det
        t = np.einsum("tk,tk->t", e2, q)[None] / det
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    hit = (margin >= 0) & (t * -rays[:, 2:3] >= near)
    t = np.where(hit, t, np.inf)
    best = np.argmin(t, axis=1)
    rows = np.arange(len(rays))
    triangle = np.where(np.isfinite(t[rows, best]), best, -1)
    clear = np.where(np.abs(margin) < 2e-3, 0, 1).min(axis=1)
    shape = (WIDTH, HEIGHT)
    return triangle.reshape(shape), t[rows, best].reshape(shape), clear.reshape(shape)


def test_visibility_matches_a_ray_cast_of_a_bumpy_sphere():
    vertices, faces = icosphere()
    vertices = vertices * 0.5 + [0.05, -0.02, -0.9]
    result = render(vertices, faces)
    triangle, distance, clear = ray_cast(vertices, faces)
    mismatch = result["triangle"] != triangle
    assert (triangle >= 0).sum() > 500
    assert np.all(clear[mismatch] == 0)  # disagreements only where a ray grazes an edge
    assert mismatch.sum() <= 0.01 * (triangle >= 0).sum()
    agree = ~mismatch & (triangle >= 0)
    assert np.allclose(result["depth"][agree], distance[agree], rtol=1e-4)
    assert np.all(result["depth"][triangle < 0] == np.float32(BACKGROUND_DEPTH))
    assert np.all(result["triangle"][~mismatch & (triangle < 0)] == -1)


@pytest.mark.parametrize("behind", [1, 2])
def test_triangle_crossing_the_near_plane_is_clipped_not_dropped(behind):
    near = 0.05
    corners = [(-1.0, -0.02, -1.0), (1.0, -0.02, -1.0), (0.0, -0.02, 1.0)]  # floor under the eye
    if behind == 2:
        corners = [(-1.0, -0.02, 1.0), (1.0, -0.02, 1.0), (0.0, -0.02, -1.0)]
    vertices, faces = np.array(corners), np.array([[0, 1, 2]])
    result = render(vertices, faces, near=near)
    triangle, _, clear = ray_cast(vertices, faces, near=near)
    covered = result["triangle"] == 0
    rays = pixel_rays()
    view_depth_at_hit = np.where(rays[..., 1] < 0, 0.02 / -rays[..., 1], np.inf) * -rays[..., 2]
    graze = (np.abs(view_depth_at_hit - near) < 1e-4) | (clear == 0)
    assert covered.sum() > 200
    assert np.all((covered == (triangle == 0)) | graze)
    assert result["depth"][covered].min() >= near * (1 - 1e-6)


def test_resolve_interpolates_linear_functions_and_lands_on_the_pixel_ray():
    rng = np.random.default_rng(5)
    vertices = np.array([(-0.4, -0.3, -1.2), (0.5, -0.2, -0.7), (0.1, 0.45, -1.6)])
    linear, offset = rng.normal(size=(3, 3)), rng.normal(size=3)
    normals = vertices @ linear.T + offset  # unnormalised on purpose
    result = render(vertices, [[0, 1, 2]], normals=normals)
    covered = result["triangle"] == 0
    assert covered.sum() > 120
    position, normal = result["position"][covered], result["normal"][covered]
    rays = pixel_rays()[covered]
    along = np.einsum("pk,pk->p", position, rays)
    assert np.abs(position - along[:, None] * rays).max() < 1e-6  # on the ray through the centre
    plane = np.cross(vertices[1] - vertices[0], vertices[2] - vertices[0])
    assert np.abs((position - vertices[0]) @ plane).max() < 1e-6  # on the triangle
    expected = position @ linear.T + offset
    expected /= np.linalg.norm(expected, axis=-1, keepdims=True)
    assert np.abs(np.abs(np.einsum("pk,pk->p", normal, expected)) - 1).max() < 1e-5
    assert np.allclose(result["depth"][covered], np.linalg.norm(position, axis=-1), rtol=1e-6)


def test_normals_are_unit_and_face_the_viewer():
    vertices, faces = icosphere(seed=1)
    vertices = vertices * 0.3 + [0.0, 0.0, -0.8]
    for sign in (1.0, -1.0):  # outward, then inward vertex normals
        result = render(vertices, faces, normals=sign * (vertices - [0.0, 0.0, -0.8]))
        covered = result["triangle"] >= 0
        normal, position = result["normal"][covered], result["position"][covered]
        assert np.abs(np.linalg.norm(normal, axis=-1) - 1).max() < 1e-5
        assert np.all(np.einsum("pk,pk->p", normal, EYE - position) >= 0)
        assert np.all(result["normal"][~covered] == 0)


def test_results_are_identical_across_runs_and_traversals():
    vertices, faces = icosphere(seed=2)
    vertices = vertices * 0.3 + [0.05, 0.0, -0.9]
    runs = [render(vertices, faces, by_pixel=by_pixel) for by_pixel in (False, True, False, True)]
    for key in runs[0]:
        assert np.array_equal(runs[0][key], runs[2][key]) and np.array_equal(
            runs[1][key], runs[3][key]
        )
    assert np.array_equal(runs[0]["triangle"], runs[1]["triangle"])
    assert np.allclose(runs[0]["depth"], runs[1]["depth"], rtol=1e-6)


def test_camera_matrices_follow_opengl_conventions():
    view, projection = camera_matrices(
        [1.0, 2.0, 3.0], [1.0, 2.0, 0.0], [0.0, 1.0, 0.0], 60.0, 1.5, 0.1, 10.0
    )
    for depth, ndc_z in ((0.1, -1.0), (10.0, 1.0)):
        clip = projection @ view @ [1.0, 2.0, 3.0 - depth, 1.0]
        assert np.allclose(clip[:3] / clip[3], [0.0, 0.0, ndc_z], atol=1e-5)
        assert np.isclose(clip[3], depth)
    clip = (
        projection @ view @ [1.0, 2.0 + np.tan(np.radians(30.0)), 2.0, 1.0]
    )  # top edge of the view
    assert np.isclose(clip[1] / clip[3], 1.0)
    with pytest.raises(ValueError):
        camera_matrices([0, 0, 0], [0, 1, 0], [0, 1, 0], 60.0, 1.0, 0.1, 10.0)


def compute_gbuffer() -> dict:
    """A bumpy sphere and a floor crossing the near plane, default traversal of the backend."""
    sphere, sphere_faces = icosphere(seed=4)
    floor = np.array([(-1.0, -0.05, -1.5), (1.0, -0.05, -1.5), (0.0, -0.05, 1.0)])
    vertices = np.concatenate([sphere * 0.3 + [0.0, 0.1, -1.0], floor])
    faces = np.concatenate([sphere_faces, [[len(sphere), len(sphere) + 1, len(sphere) + 2]]])
    objects = np.repeat([0, 1], [len(sphere_faces), 1])  # the sphere one-sided, the floor not
    target, count = GBuffer(WIDTH, HEIGHT), mesh().load(vertices, faces, None, objects, (0,))
    draw(target, count, 0.02)
    return {
        "triangle": target.triangle.to_numpy(),
        "depth": target.depth.to_numpy(),
        "position": target.position.to_numpy(),
    }


@pytest.mark.vulkan
def test_vulkan_matches_cpu():
    cpu = assert_backend_matches_cpu("tests.test_raster:compute_gbuffer", 1e-5)
    floor = len(icosphere()[1])
    assert (cpu["triangle"] == floor).sum() > 100 and (cpu["triangle"] >= 0).sum() > 1000


def test_ray_basis_points_through_the_image_point():
    """base + ndc_x along_x + ndc_y along_y runs from the eye through the point the
    projection maps to ``ndc`` (any depth), towards the view, for random cameras and
    image points, past the image's edges too."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        eye = rng.normal(size=3)
        view, projection = camera_matrices(
            eye, eye + rng.normal(size=3), (0.0, 1.0, 0.0), rng.uniform(30, 100), 4 / 3, 0.01, 5.0
        )
        matrix = (projection @ view).astype(np.float64)
        rays = ray_basis(matrix).astype(np.float64)
        for ndc in rng.uniform(-1.5, 1.5, size=(10, 2)):
            ray = rays[0] + ndc[0] * rays[1] + ndc[1] * rays[2]
            far = np.linalg.solve(matrix, np.array([ndc[0], ndc[1], 0.5, 1.0]))
            towards = far[:3] / far[3] - eye
            cosine = ray @ towards / np.linalg.norm(ray) / np.linalg.norm(towards)
            assert cosine > 1.0 - 1e-6
