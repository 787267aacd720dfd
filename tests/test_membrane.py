"""The drawn membrane of a spring sheet (the mesentery): the Catmull-Rom surface
through its masses (kernels/membrane.py) and its place in the drawn scene."""

import numpy as np
import taichi as ti

from taichi_lap.kernels.membrane import membrane_vertices
from taichi_lap.render.scene_mesh import MEMBRANE_ACROSS, MEMBRANE_ALONG, SceneMesh
from tests.test_render import small_session

ACROSS, ALONG = 4, 3


def membrane(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The membrane's samples and normals through ``grid`` (rows, cols, 3), shaped
    (fine rows, fine cols, 3)."""
    rows, cols = grid.shape[:2]
    fine = ((rows - 1) * ACROSS + 1, (cols - 1) * ALONG + 1)
    points = ti.Vector.field(3, ti.f32, rows * cols + 5)
    values = np.zeros((rows * cols + 5, 3), np.float32)
    values[5:] = grid.reshape(-1, 3)  # the grid need not start at the first point
    points.from_numpy(values)
    positions = ti.Vector.field(3, ti.f32, fine[0] * fine[1] + 7)
    normals = ti.Vector.field(3, ti.f32, fine[0] * fine[1] + 7)
    membrane_vertices(points, 5, rows, cols, ACROSS, ALONG, positions, normals, 7)
    shape = (*fine, 3)
    return positions.to_numpy()[7:].reshape(shape), normals.to_numpy()[7:].reshape(shape)


def test_the_membrane_of_an_affine_grid_is_that_plane_sampled_evenly():
    """Catmull-Rom reproduces linear functions, and the edges are extrapolated
    linearly: an affine grid gives its plane, sampled at i / across and j / along,
    with the plane's normal everywhere."""
    origin, row_step, col_step = (
        np.array([0.1, -0.2, 0.05]),
        np.array([0.0, 0.02, 0.01]),
        np.array([0.03, 0.0, -0.005]),
    )
    grid = origin + np.arange(4)[:, None, None] * row_step + np.arange(6)[None, :, None] * col_step
    samples, normals = membrane(grid)
    u = np.arange(samples.shape[0])[:, None, None] / ACROSS
    v = np.arange(samples.shape[1])[None, :, None] / ALONG
    assert np.allclose(samples, origin + u * row_step + v * col_step, atol=1e-6)
    normal = np.cross(row_step, col_step)
    assert np.allclose(normals, normal / np.linalg.norm(normal), atol=1e-5)


def test_the_membrane_passes_through_every_mass_and_follows_a_curved_sheet_smoothly():
    """On a grid sampled from a bent sheet (a quarter cylinder of 5 cm radius, 4 rows
    by 6 columns, 18° apart): the membrane passes through every mass; its samples lie
    within 0.03 mm of the cylinder and its normals within 1° of the cylinder's, where
    the flat triangles between the masses stray 0.6 mm and 9° from it."""
    radius = 0.05
    angle = np.linspace(0.0, 0.5 * np.pi, 6)
    height = np.linspace(0.0, 0.06, 4)
    grid = np.stack(
        np.broadcast_arrays(
            radius * np.cos(angle)[None, :], height[:, None], radius * np.sin(angle)[None, :]
        ),
        -1,
    )
    samples, normals = membrane(grid)
    assert np.allclose(samples[::ACROSS, ::ALONG], grid, atol=1e-6)
    off_axis = np.linalg.norm(samples[..., [0, 2]], axis=-1) - radius
    assert np.abs(off_axis).max() < 3e-5
    outward = samples * [1.0, 0.0, 1.0]
    outward /= np.linalg.norm(outward, axis=-1, keepdims=True)
    cosine = np.abs((normals * outward).sum(-1))
    assert np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))).max() < 1.0
    mid_chord = 0.5 * (grid[:, 1:] + grid[:, :-1])  # the flat triangles' worst points
    assert radius - np.linalg.norm(mid_chord[..., [0, 2]], axis=-1).max() > 6e-4
    facet_turn = np.degrees(angle[1] - angle[0]) / 2.0  # a facet's normal at its edges
    assert facet_turn > 8.9


def test_the_mesentery_is_drawn_as_its_membrane_and_its_grid_is_not():
    """In the intestine scene the sheet's own triangles are degenerate (not drawn) and
    the membrane's samples are drawn as the intestine, through its masses."""
    session = small_session("intestine")
    mesh = SceneMesh(session.scene, session.model)
    mesh.update(session.state, session.control)
    organ = session.data.organs[0]
    first, rows, cols, offset = mesh.membranes[0]
    assert (rows, cols) == (4, organ.row_length)
    triangles = mesh.triangles.to_numpy().reshape(-1, 3)
    drawn_as = mesh.triangle_object.to_numpy()
    grid = np.arange(session.model.surface_triangle_count)
    sheet = grid[drawn_as[grid] == 0]
    assert len(sheet) == 2 * (rows - 1) * (cols - 1)
    assert (triangles[sheet] == triangles[sheet][:, :1]).all()
    fine = ((rows - 1) * MEMBRANE_ACROSS + 1, (cols - 1) * MEMBRANE_ALONG + 1)
    membrane_rows = (triangles >= offset) & (triangles < offset + fine[0] * fine[1])
    drawn = np.flatnonzero(membrane_rows.all(1))
    assert len(drawn) == 2 * (fine[0] - 1) * (fine[1] - 1)
    assert (drawn_as[drawn] == 0).all()
    positions = mesh.positions.to_numpy()
    samples = positions[offset : offset + fine[0] * fine[1]].reshape(*fine, 3)
    masses = session.state.surface_position.to_numpy()[first : first + rows * cols]
    assert np.allclose(
        samples[::MEMBRANE_ACROSS, ::MEMBRANE_ALONG], masses.reshape(rows, cols, 3), atol=1e-6
    )
