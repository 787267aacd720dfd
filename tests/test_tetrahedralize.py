"""BCC lattice tetrahedralizer (seed 002 §3.2): volumes, quality, skin, binding."""

import numpy as np
import pytest
import trimesh

from taichi_lap.core.geometry import Solid, TriangleMesh
from taichi_lap.core.mesh import TET_EDGES, edge_defects, enclosed_volume, tet_volumes, unique_edges
from taichi_lap.core.mesh import TET_FACES
from taichi_lap.preprocess.tetrahedralize import TetMesh, points_inside, tetrahedralize

RADIUS = 0.05  # m
SPACING = RADIUS / 10  # m, cube edge of the lattice
SNAPPED_MIN_DIHEDRAL = 10.0  # degrees, bound stated for a sphere of 10 cells radius


def min_dihedral_angle(particles: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Smallest dihedral angle of each tet ``(T,)`` [degrees]; 60 for BCC tets."""
    x = particles[tets]
    faces = x[:, TET_FACES]  # (T, 4, 3, 3)
    normal = np.cross(faces[:, :, 1] - faces[:, :, 0], faces[:, :, 2] - faces[:, :, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=2, keepdims=True), 1e-300)
    cosine = -np.einsum("tei,tei->te", normal[:, TET_EDGES[:, 0]], normal[:, TET_EDGES[:, 1]])
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))).min(axis=1)


def sphere_solid(radius: float = RADIUS) -> Solid:
    return Solid(
        (np.full(3, -radius), np.full(3, radius)), sdf=lambda p: np.linalg.norm(p, axis=1) - radius
    )


@pytest.fixture(scope="module")
def sphere() -> TetMesh:
    return tetrahedralize(sphere_solid(), SPACING)


@pytest.fixture(scope="module")
def icosphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)


def test_helpers_on_a_regular_tet():
    particles = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3]])
    assert tet_volumes(particles, tets)[0] == pytest.approx(8 / 3)
    assert tet_volumes(particles, tets[:, [1, 0, 2, 3]])[0] == pytest.approx(-8 / 3)
    assert min_dihedral_angle(particles, tets)[0] == pytest.approx(np.degrees(np.arccos(1 / 3)))
    np.testing.assert_array_equal(
        unique_edges(np.array([[3, 1, 2, 0], [0, 1, 2, 4]])),
        [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [1, 3], [1, 4], [2, 3], [2, 4]],
    )


def test_sphere_volume_and_orientation(sphere):
    volumes = tet_volumes(sphere.particles, sphere.tets)
    assert np.all(volumes > 0)
    assert volumes.sum() == pytest.approx(4 / 3 * np.pi * RADIUS**3, rel=0.03)
    assert sphere.particles.dtype == np.float64 and sphere.tets.dtype == np.int64
    assert np.array_equal(np.unique(sphere.tets), np.arange(len(sphere.particles)))
    assert 4.5 < len(sphere.tets) / len(sphere.particles) < 6.5


def test_interior_tets_are_bcc_and_snapped_tets_stay_good(sphere):
    quality = min_dihedral_angle(sphere.particles, sphere.tets)
    on_skin = np.zeros(len(sphere.particles), dtype=bool)
    on_skin[sphere.binding_index[:, 0]] = True
    interior = ~on_skin[sphere.tets].any(axis=1)
    assert interior.sum() > len(sphere.tets) / 2
    assert quality[interior].min() >= 59.9
    np.testing.assert_allclose(
        tet_volumes(sphere.particles, sphere.tets[interior]), SPACING**3 / 12
    )
    assert quality.min() >= SNAPPED_MIN_DIHEDRAL


def test_sphere_skin_is_watertight_outward_and_on_the_sphere(sphere):
    skin = sphere.surface
    assert edge_defects(skin.triangles) == (0, 0)
    assert enclosed_volume(skin.vertices, skin.triangles) == pytest.approx(
        tet_volumes(sphere.particles, sphere.tets).sum(), rel=1e-9
    )
    radial_error = np.abs(np.linalg.norm(skin.vertices, axis=1) - RADIUS)
    assert radial_error.max() <= 1e-3 * SPACING


def test_direct_binding_reproduces_the_skin(sphere):
    index, weight = sphere.binding_index, sphere.binding_weight
    assert np.all(index == index[:, :1])
    np.testing.assert_array_equal(weight, np.tile([1.0, 0, 0, 0], (len(index), 1)))
    bound = np.einsum("sk,skd->sd", weight, sphere.particles[index])
    np.testing.assert_array_equal(bound, sphere.surface.vertices)


def test_particles_are_ordered_spatially(sphere):
    edges = unique_edges(sphere.tets)
    assert np.abs(edges[:, 0] - edges[:, 1]).mean() < 0.1 * len(sphere.particles)


def test_progress_is_reported_up_to_one():
    seen = []
    tetrahedralize(sphere_solid(), SPACING * 2, progress=seen.append)
    assert len(seen) >= 3 and seen == sorted(seen) and seen[-1] == 1.0


def test_parity_inside_test_matches_the_polyhedron(icosphere):
    surface = TriangleMesh(icosphere.vertices, icosphere.faces)
    points = np.random.default_rng(7).uniform(-1.2 * RADIUS, 1.2 * RADIUS, (5000, 3))
    normal = icosphere.face_normals
    offset = np.einsum("fi,fi->f", icosphere.vertices[icosphere.faces[:, 0]], normal)
    plane_distance = (points @ normal.T - offset).max(axis=1)  # convex: behind every face
    clear = np.abs(plane_distance) > 1e-6
    inside = points_inside(surface, points)
    np.testing.assert_array_equal(inside[clear], plane_distance[clear] < 0)
    assert 0.25 < inside.mean() < 0.35


def test_parity_inside_test_with_rays_along_box_edges():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    grid = np.stack(np.meshgrid(*[np.arange(-1, 1.01, 0.125)] * 3, indexing="ij"), axis=-1).reshape(
        -1, 3
    )
    on_surface = np.any(np.isclose(np.abs(grid), 0.5), axis=1) & np.all(np.abs(grid) <= 0.5, axis=1)
    inside = points_inside(TriangleMesh(box.vertices, box.faces), grid)
    np.testing.assert_array_equal(
        inside[~on_surface], np.all(np.abs(grid) < 0.5, axis=1)[~on_surface]
    )


def test_given_surface_is_bound_barycentrically(icosphere):
    surface = TriangleMesh(icosphere.vertices, icosphere.faces)
    solid = Solid((np.full(3, -RADIUS), np.full(3, RADIUS)), surface=surface)
    mesh = tetrahedralize(solid, SPACING)
    assert mesh.surface is surface
    assert np.all(tet_volumes(mesh.particles, mesh.tets) > 0)
    assert np.allclose(mesh.binding_weight.sum(axis=1), 1.0)
    bound = np.einsum("sk,skd->sd", mesh.binding_weight, mesh.particles[mesh.binding_index])
    assert np.abs(bound - surface.vertices).max() <= 1e-9


def test_no_tet_inside_is_an_error():
    with pytest.raises(ValueError, match="no tetrahedron"):
        tetrahedralize(sphere_solid(radius=0.001), 0.01)
