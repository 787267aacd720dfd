"""The drawn membrane of a spring sheet (the mesentery): the Catmull-Rom surface
through its masses (kernels/membrane.py) and its place in the drawn scene."""

import numpy as np
import pytest
import taichi as ti

from taichi_lap.core.mesh import inconsistent_edges, unique_edges
from taichi_lap.kernels.membrane import membrane_vertices
from taichi_lap.preprocess.sheets import shell_triangles, shell_vertex_count
from taichi_lap.render.scene_mesh import (
    MEMBRANE_ACROSS,
    MEMBRANE_ALONG,
    MEMBRANE_THICKNESS,
    SceneMesh,
)
from tests.test_render import small_session

ACROSS, ALONG = 4, 3


def membrane_shell(grid: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """All the vertices and normals (V, 3) of the membrane shell through ``grid``
    (rows, cols, 3), ``half`` [m] to either side."""
    rows, cols = grid.shape[:2]
    fine = ((rows - 1) * ACROSS + 1, (cols - 1) * ALONG + 1)
    points = ti.Vector.field(3, ti.f32, rows * cols + 5)
    values = np.zeros((rows * cols + 5, 3), np.float32)
    values[5:] = grid.reshape(-1, 3)  # the grid need not start at the first point
    points.from_numpy(values)
    count = shell_vertex_count(*fine)
    positions = ti.Vector.field(3, ti.f32, count + 7)
    normals = ti.Vector.field(3, ti.f32, count + 7)
    membrane_vertices(points, 5, rows, cols, ACROSS, ALONG, half, positions, normals, 7)
    return positions.to_numpy()[7:], normals.to_numpy()[7:]


def membrane(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The membrane's samples and normals through ``grid`` (rows, cols, 3), shaped
    (fine rows, fine cols, 3): the front of a shell of no thickness."""
    rows, cols = grid.shape[:2]
    fine = ((rows - 1) * ACROSS + 1, (cols - 1) * ALONG + 1)
    positions, normals = membrane_shell(grid, 0.0)
    shape, count = (*fine, 3), fine[0] * fine[1]
    return positions[:count].reshape(shape), normals[:count].reshape(shape)


def bent_sheet(radius: float) -> tuple[np.ndarray, np.ndarray]:
    """A grid of 4 rows by 6 columns on a quarter cylinder of ``radius`` [m], 6 cm
    high: the columns' angles and the grid (4, 6, 3)."""
    angle = np.linspace(0.0, 0.5 * np.pi, 6)
    height = np.linspace(0.0, 0.06, 4)
    grid = np.stack(
        np.broadcast_arrays(
            radius * np.cos(angle)[None, :], height[:, None], radius * np.sin(angle)[None, :]
        ),
        -1,
    )
    return angle, grid


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
    angle, grid = bent_sheet(radius)
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
    the membrane's shell is drawn as the intestine, its front half its thickness off
    the surface through its masses."""
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
    in_shell = (triangles >= offset) & (triangles < offset + shell_vertex_count(*fine))
    shell = np.flatnonzero(in_shell.all(1))
    np.testing.assert_array_equal(triangles[shell], shell_triangles(*fine) + offset)
    assert (drawn_as[shell] == 0).all()  # the whole shell is drawn as the intestine
    front = slice(offset, offset + fine[0] * fine[1])
    samples = (
        mesh.positions.to_numpy()[front] - 0.5 * MEMBRANE_THICKNESS * mesh.normals.to_numpy()[front]
    )
    masses = session.state.surface_position.to_numpy()[first : first + rows * cols]
    assert np.allclose(
        samples.reshape(*fine, 3)[::MEMBRANE_ACROSS, ::MEMBRANE_ALONG],
        masses.reshape(rows, cols, 3),
        atol=1e-6,
    )


def test_the_membrane_is_a_closed_shell_of_its_thickness_facing_outwards():
    """Through the bent sheet of the test above, 2 mm thick: the front and back lie
    1 mm to either side of the surface along its normal, facing away from each
    other; welded where the rim meets them, the shell is closed (every edge in two
    triangles, all turning alike) and encloses the sheet's area times its thickness;
    each triangle faces the way its vertices' normals do (the rim's outward across
    the border)."""
    radius, half = 0.05, 0.001
    _, grid = bent_sheet(radius)
    positions, normals = membrane_shell(grid, half)
    surface, surface_normals = membrane(grid)
    fine = surface.shape[:2]
    count = fine[0] * fine[1]
    flat, flat_normals = surface.reshape(-1, 3), surface_normals.reshape(-1, 3)
    np.testing.assert_allclose(positions[:count], flat + half * flat_normals, atol=1e-6)
    np.testing.assert_allclose(positions[count : 2 * count], flat - half * flat_normals, atol=1e-6)
    np.testing.assert_allclose(normals[count : 2 * count], -flat_normals, atol=1e-6)
    triangles = shell_triangles(*fine)
    assert triangles.max() == len(positions) - 1
    _, weld = np.unique(np.round(positions / 1e-7).astype(np.int64), axis=0, return_inverse=True)
    welded = weld.ravel()[triangles]
    _, uses = unique_edges(welded, return_counts=True)
    assert (uses == 2).all() and inconsistent_edges(welded) == 0
    corners = positions[triangles].astype(np.float64)
    volume = np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6
    area = 0.5 * np.pi * radius * 0.06  # a quarter cylinder 6 cm high
    assert volume == pytest.approx(2 * half * area, rel=0.02)
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert (np.einsum("ij,ij->i", face, normals[triangles].sum(axis=1)) > 0).all()
