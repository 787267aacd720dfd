"""Blood from damaged vessels: the film's drainage (kernels/blood.py), the bleed model
shared with the metrics (core/bleeding.py) and the film drawn in a scene."""

import numpy as np
import pytest

from taichi_lap.core.bleeding import BLEED_RATE, CLOTTING_TIME, bleed_rate, blood_lost
from taichi_lap.kernels.blood import bleed, drain, film_shares
from taichi_lap.render.blood import DRIP_FILM, DROP_RADIUS, FILM_RESIDUE, MAX_DRIPS, BloodFilm
from taichi_lap.render.renderer import Renderer
from taichi_lap.render.scene_mesh import ArrayMesh
from taichi_lap.scene.materials import PRESETS
from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.test_render import head_on, small_session

SPACING = 0.002  # [m] between grid points


def grid(size: int, height, facing_down: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A ``size`` x ``size`` grid 2 mm apart in x and z, centred, at y = ``height(x,
    z)``, its triangles wound to face down (on flat ground) or up: (positions, faces)."""
    t = (np.arange(size) - size // 2) * SPACING
    x, z = np.meshgrid(t, t, indexing="ij")
    positions = np.stack([x, height(x, z), z], -1).reshape(-1, 3).astype(np.float32)
    index = np.arange(size * size).reshape(size, size)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[:-1, 1:], index[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
    return positions, faces if facing_down else faces[:, ::-1]


def grid_mesh(height) -> ArrayMesh:
    """A 31 x 31 grid 2 mm apart in x and z, at y = ``height(x, z)``."""
    positions, faces = grid(31, height)
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


def roof_and_floor(roof_faces_down: bool, floor: bool = True) -> ArrayMesh:
    """An 11 x 11 roof 2 cm above a 31 x 31 floor facing up (or no floor), one mesh, a
    2 mm-thick film poured on the roof's middle."""
    roof = grid(11, lambda x, z: np.full_like(x, 0.02), roof_faces_down)
    parts = [roof] + ([grid(31, lambda x, z: np.zeros_like(x), facing_down=False)] if floor else [])
    offsets = np.cumsum([0] + [len(p) for p, _ in parts])
    positions = np.concatenate([p for p, _ in parts])
    faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)])
    mesh = ArrayMesh.of_material(faces, positions, PRESETS["liver"])
    mesh.update()  # the normals the drops are shed by
    bleed(mesh.positions, 121, (0.0, 0.02, 0.0), 0.004, 2e-3, mesh.blood)
    return mesh


def dripped(mesh: ArrayMesh, seconds: float, dt: float = 0.02) -> BloodFilm:
    """The drops of ``seconds`` of frames ``dt`` apart."""
    film = BloodFilm()
    for step in range(int(round(seconds / dt))):
        film.drip(mesh, step * dt)
    return film


def test_blood_drips_from_a_roof_onto_the_floor_below_keeping_its_volume():
    """From a roof facing down, the film above the residue falls as drops, the thickest
    first (MAX_DRIPS a frame), onto the floor straight below them after √(2 h / g) (h = 2
    cm: 64 ms): what the roof loses the floor gains, with nothing spilled."""
    mesh = roof_and_floor(roof_faces_down=True)
    poured = mesh.blood.to_numpy()
    sources = np.flatnonzero(poured > DRIP_FILM)
    assert len(sources) > MAX_DRIPS and sources.max() < 121  # more than a frame's drops
    film = dripped(mesh, 0.04)  # two frames: drops released, none landed yet
    after = mesh.blood.to_numpy()
    assert len(film.falling) == 2 * MAX_DRIPS and after[121:].max() == 0.0
    thickest = np.sort(poured)[::-1][: 2 * MAX_DRIPS]
    assert sorted(d.film for d in film.falling) == pytest.approx(sorted(thickest - FILM_RESIDUE))
    in_flight = sum(d.film for d in film.falling)
    assert after.sum() + in_flight == pytest.approx(poured.sum(), rel=1e-5)
    mesh = roof_and_floor(roof_faces_down=True)
    film = dripped(mesh, 1.0)
    assert not film.falling and film.spilled == 0.0
    after, positions = mesh.blood.to_numpy(), mesh.positions.to_numpy()
    assert after.sum() == pytest.approx(poured.sum(), rel=1e-5)
    np.testing.assert_allclose(after[sources], FILM_RESIDUE, rtol=1e-6)
    landed = after[121:]
    assert landed.sum() == pytest.approx((poured[sources] - FILM_RESIDUE).sum(), rel=1e-5)
    wet = positions[121:][landed > 0.0]
    assert np.abs(wet[:, [0, 2]]).max() <= 0.004 + SPACING  # straight under the pour


def test_blood_stays_on_a_surface_facing_up_and_spills_where_nothing_is_below():
    """The same film on the roof turned up stays on it (no drop); from a roof facing
    down over no floor, every drop spills off the drawn tissue and is counted."""
    mesh = roof_and_floor(roof_faces_down=False)
    poured = mesh.blood.to_numpy()
    film = dripped(mesh, 0.2)
    assert not film.falling and film.spilled == 0.0
    np.testing.assert_array_equal(mesh.blood.to_numpy(), poured)
    mesh = roof_and_floor(roof_faces_down=True, floor=False)
    film = dripped(mesh, 0.2)
    assert not film.falling
    assert mesh.blood.to_numpy().sum() + film.spilled == pytest.approx(poured.sum(), rel=1e-5)
    assert film.spilled == pytest.approx((poured[poured > DRIP_FILM] - FILM_RESIDUE).sum())


def roof_drips() -> dict[str, np.ndarray]:
    """The film of the roof and floor after a second of drips."""
    mesh = roof_and_floor(roof_faces_down=True)
    dripped(mesh, 1.0)
    return {"film": mesh.blood.to_numpy()}


@pytest.mark.vulkan
def test_drops_land_alike_on_vulkan_and_the_cpu():
    cpu = roof_drips()["film"]
    other = run_on_arch(COMPARE_ARCH, "tests.test_blood:roof_drips")["film"]
    assert np.allclose(other, cpu, rtol=1e-4, atol=1e-9)


def drop_frames(times: list[float]) -> tuple[list[np.ndarray], BloodFilm]:
    """The roof's first drops seen from the side, between the roof and the floor, at
    ``times`` [s] after they fell, with the image of no drop first."""
    mesh = roof_and_floor(True)
    film = dripped(mesh, 0.02)  # released at 0, falling for about 64 ms
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.01, 0.06]), 40.0), size=(160, 120))
    frames = []
    for time in [None, *times]:
        renderer.blood = film if time is not None else BloodFilm()
        film.time = time or 0.0
        renderer.render(None, None)
        frames.append(renderer.image().astype(int))
    return frames, film


def test_falling_drops_are_drawn_as_blood_where_gravity_has_taken_them():
    """Drops in flight are drawn (spheres of blood, DROP_RADIUS, through the lens)
    where they have fallen from rest: red, lower in the image later, none once
    landed."""
    frames, film = drop_frames([0.02, 0.045, 0.2])
    assert 0 < len(film.falling) <= MAX_DRIPS
    assert not len(film.in_flight()[0])  # at the last time: landed
    film.time = 0.02
    centres, triangles = film.in_flight()  # from the roof, 1.962 mm down
    assert centres[:, 1] == pytest.approx(0.02 - 0.5 * 9.81 * 0.02**2, abs=1e-6)
    assert (triangles >= 200).all()  # the floor's (after the roof's 200)
    rows = []
    for frame in frames[1:3]:
        drawn = np.abs(frame - frames[0]).sum(axis=2) > 30
        assert drawn.sum() >= 4
        red, green = frame[drawn][:, 0], frame[drawn][:, 1]
        assert (red > 1.5 * green).mean() > 0.9  # blood red (lit by the headlight)
        rows.append(np.flatnonzero(drawn.any(axis=1)).mean())
    # 2 mm fallen at 20 ms, 9.9 mm at 45 ms: about 25 pixels lower (120 rows over 40°)
    assert rows[1] - rows[0] > 15
    assert np.abs(frames[3] - frames[0]).sum(axis=2).max() <= 30  # landed: no drop
    # a drop's image is about as wide as a sphere of its radius at its distance
    wide = (np.abs(frames[1] - frames[0]).sum(axis=2) > 30).any(axis=0).sum()
    assert wide <= len(film.falling) * (2 * DROP_RADIUS / 0.06 / np.tan(np.radians(20)) * 60 + 3)


def falling_drops() -> dict[str, np.ndarray]:
    """The images of the roof's drops 20 and 45 ms into their fall."""
    frames, _ = drop_frames([0.02, 0.045])
    return {"frames": np.stack(frames[1:])}


@pytest.mark.vulkan
def test_falling_drops_are_drawn_alike_on_vulkan_and_the_cpu():
    cpu = falling_drops()["frames"]
    other = run_on_arch(COMPARE_ARCH, "tests.test_blood:falling_drops")["frames"]
    # alike but for a few pixels on a drop's outline, where a ray grazes its sphere
    assert (np.abs(other - cpu).sum(axis=-1) > 6).sum() <= 8


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
    outlet, beside the damage, the blood view shows it, and as frames pass its volume
    (with the drops falling and spilled) grows with the bleed and its centre sinks."""
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
        volumes.append(blood.sum() + sum(d.film for d in film.falling) + film.spilled)
        heights.append((blood * positions[:, 1]).sum() / blood.sum())
    assert np.all(np.diff(volumes) > 0.0)  # with the drops falling and spilled
    assert heights[-1] < heights[0] - 1e-4
    renderer.camera.target = outlet  # look down at the bleeding place from 6 cm
    renderer.camera.eye = outlet + np.array([-0.02, 0.05, -0.03])
    renderer.view = 9  # the blood view: the film's cover in grey
    renderer.render(session.state, session.control)
    assert (renderer.frame.to_numpy()[..., 0] > 0.5).sum() > 20
