"""Blood from damaged vessels: the film's drainage (kernels/blood.py), the bleed model
shared with the metrics (core/bleeding.py) and the film drawn in a scene."""

import numpy as np
import pytest

from taichi_lap.core.bleeding import BLEED_RATE, CLOTTING_TIME, bleed_rate, blood_lost
from taichi_lap.kernels.blood import bleed, drain, film_shares
from taichi_lap.render.blood import FILM_RESIDUE, BloodFilm
from taichi_lap.render.scene_mesh import ArrayMesh
from taichi_lap.scene.materials import PRESETS
from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.test_render import small_session

SPACING = 0.002  # [m] between grid points


def grid_mesh(height) -> ArrayMesh:
    """A 31 x 31 grid 2 mm apart in x and z, at y = ``height(x, z)``."""
    t = (np.arange(31) - 15) * SPACING
    x, z = np.meshgrid(t, t, indexing="ij")
    positions = np.stack([x, height(x, z), z], -1).reshape(-1, 3).astype(np.float32)
    index = np.arange(31 * 31).reshape(31, 31)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[:-1, 1:], index[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
    return ArrayMesh.of_material(faces, positions, PRESETS["liver"])


def drained(mesh: ArrayMesh, steps: int, reach: float = 0.0005) -> list[np.ndarray]:
    """The film after each of ``steps`` drainage steps (gravity -y), from the one it has."""
    film = BloodFilm()
    share, scratch = film._fields(mesh)
    args = (mesh.positions, mesh.triangles, mesh.incident, mesh.smooth_count, film.down)
    history = []
    for _ in range(steps):
        film_shares(*args, reach, FILM_RESIDUE, mesh.blood, share)
        drain(*args, share, mesh.blood, scratch)
        mesh.blood.copy_from(scratch)
        history.append(mesh.blood.to_numpy())
    return history


def test_blood_runs_down_a_slope_keeping_its_volume_and_leaving_a_stain():
    """Poured at the top of a plane sloping down along +x, the film keeps its volume,
    never turns negative, never climbs (nothing reaches the points above the source),
    its centre runs down step by step and the source keeps the residue."""
    mesh = grid_mesh(lambda x, z: -0.5 * x)
    positions = mesh.positions.to_numpy()
    source = positions[5 * 31 + 15]  # x = -2 cm, z = 0
    bleed(mesh.positions, mesh.smooth_count, tuple(source), 0.004, 1e-3, mesh.blood)
    poured = mesh.blood.to_numpy()
    history = drained(mesh, 60)
    volume = poured.sum()
    centres = [(film * positions[:, 0]).sum() / film.sum() for film in [poured] + history]
    for film in history:
        assert film.sum() == pytest.approx(volume, rel=1e-5)
        assert film.min() >= 0.0
        assert film[positions[:, 0] < source[0] - 0.0041].max() == 0.0  # above the pour
    assert np.all(np.diff(centres) > 0.0) and centres[-1] > centres[0] + 0.005
    assert history[-1][5 * 31 + 15] >= FILM_RESIDUE * (1.0 - 1e-5)


def slope_film(steps: int = 60) -> dict[str, np.ndarray]:
    """The film of a pour at the top of a 1:2 slope after ``steps`` drainage steps."""
    mesh = grid_mesh(lambda x, z: -0.5 * x)
    source = mesh.positions.to_numpy()[5 * 31 + 15]
    bleed(mesh.positions, mesh.smooth_count, tuple(source), 0.004, 1e-3, mesh.blood)
    return {"film": drained(mesh, steps)[-1]}


@pytest.mark.vulkan
def test_the_film_drains_alike_on_vulkan_and_the_cpu():
    cpu = slope_film()["film"]
    other = run_on_arch(COMPARE_ARCH, "tests.test_blood:slope_film")["film"]
    assert np.allclose(other, cpu, rtol=1e-4, atol=1e-9)


def test_blood_pools_in_a_valley():
    """Poured on one flank of a valley along z (y = |x| / 2), the film runs into the
    valley's floor and stays there: nine tenths of it within one spacing of x = 0."""
    mesh = grid_mesh(lambda x, z: 0.5 * np.abs(x))
    positions = mesh.positions.to_numpy()
    bleed(mesh.positions, mesh.smooth_count, tuple(positions[4 * 31 + 15]), 0.004, 2e-2, mesh.blood)
    film = drained(mesh, 200)[-1]
    floor = np.abs(positions[:, 0]) <= SPACING * 1.01
    assert film[floor].sum() > 0.9 * film.sum()


def test_blood_lost_is_the_integral_of_the_clotting_bleeds():
    """blood_lost sums each bleed's rate from its damage to the end (trapezoid check),
    nothing before its damage; a place loses at most rate × clotting time."""
    times = np.linspace(0.0, 40.0, 400_001)
    rate = np.array([bleed_rate(t - 3.0) + bleed_rate(t - 10.0) for t in times])
    integral = float(np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(times)))
    assert blood_lost([3.0, 10.0], 40.0) == pytest.approx(integral, rel=1e-5)  # two jumps
    assert blood_lost([50.0], 40.0) == 0.0
    assert blood_lost([0.0], 1e6) == pytest.approx(BLEED_RATE * CLOTTING_TIME)


def test_a_damaged_vessel_bleeds_on_the_drawn_tissue_and_the_blood_runs_down():
    """A vessel_damage event (made by hand) in the rectum scene starts a bleed beside
    the vessel, on the tissue it lies on: the film appears on the surface around the
    outlet, beside the damage, the blood view shows it, and as frames
    pass its volume grows with the bleed and its centre sinks."""
    from taichi_lap.render.renderer import Renderer

    session = small_session("rectum")
    renderer = Renderer.for_scene(session.scene, session.model, size=(160, 120))
    renderer.render(session.state, session.control)  # the drawn surface
    vessel = next(o for o in session.data.organs if o.name == "vessel")
    source = session.state.x.to_numpy()[vessel.particles[0] + 10]
    event = {"kind": "vessel_damage", "vessel": "vessel", "position": source.tolist()}
    film = renderer.blood
    assert isinstance(film, BloodFilm) and not film.bleeds
    mesh, dt = renderer.mesh, session.dt
    renderer.update_blood([event], session.state, session.data, 0.0, dt)
    assert len(film.bleeds) == 1
    outlet = session.state.x.to_numpy()[film.bleeds[0][0]]
    assert np.linalg.norm(outlet - source) < 0.02  # particles ~1 cm apart at this detail
    assert not vessel.particles[0] <= film.bleeds[0][0] < vessel.particles[1]
    positions = mesh.positions.to_numpy()[: mesh.smooth_count]
    first = mesh.blood.to_numpy()[: mesh.smooth_count]
    near = np.linalg.norm(positions - outlet, axis=1) < 0.015  # the patch, its edges (coarse)
    assert first[near].max() > 0.0 and first[near].sum() > 0.99 * first.sum()
    volumes, heights = [], []
    for frame in range(1, 90):
        renderer.update_blood([], session.state, session.data, frame * dt, dt)
        blood = mesh.blood.to_numpy()[: mesh.smooth_count]
        volumes.append(blood.sum())
        heights.append((blood * positions[:, 1]).sum() / blood.sum())
    assert np.all(np.diff(volumes) > 0.0)
    assert heights[-1] < heights[0] - 1e-4
    renderer.camera.target = outlet  # look down at the bleeding place from 6 cm
    renderer.camera.eye = outlet + np.array([-0.02, 0.05, -0.03])
    renderer.view = 9  # the blood view: the film's cover in grey
    renderer.render(session.state, session.control)
    assert (renderer.frame.to_numpy()[..., 0] > 0.5).sum() > 20
