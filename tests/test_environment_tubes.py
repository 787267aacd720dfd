"""The environment's fixed tubes (``[[environment.tubes]]``: the colon beneath the
intestine's loops): checked on load, the tissue rests on them without passing
through, they are drawn where they collide, and the renderer measures how much of
one the endoscope sees (its object-id image against the tube drawn alone)."""

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.core.errors import InputError
from taichi_lap.render.renderer import Renderer
from taichi_lap.scenes.anatomy.tubes import environment_centreline
from taichi_lap.session import Session, scene_script


def intestine_scene(**overrides):
    return scene_mod.load("intestine", overrides)


def with_tube(**tube) -> dict:
    raw = scene_mod.load("intestine").raw
    raw["environment"]["tubes"] = [{"name": "colon", "radius": 0.02, **tube}]
    return raw


def test_a_tube_needs_two_points_and_a_name_of_its_own():
    with pytest.raises(InputError, match=r"environment\.tubes\[0\]\.points: at least 2 points"):
        scene_mod.validate(with_tube(points=[[0.0, 0.0, 0.0]]), "s.toml", ".")
    raw = with_tube(points=[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], name="intestine")
    with pytest.raises(InputError, match=r"environment\.tubes\[0\]\.name: a name no organ"):
        scene_mod.validate(raw, "s.toml", ".")
    raw = with_tube(points=[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    del raw["environment"]["tubes"][0]["radius"]
    with pytest.raises(InputError, match=r"environment\.tubes\[0\]\.radius: this key is required"):
        scene_mod.validate(raw, "s.toml", ".")


def tube_gaps(session: Session) -> np.ndarray:
    """Each particle's distance [m] from the colon's surface less its radius (< 0:
    inside), from the same centre line the collision uses."""
    tube = session.scene.tubes[0]
    line = environment_centreline(tube["points"])
    x = session.state.positions().astype(np.float64)
    gaps = np.full(len(x), np.inf)
    for a, b in zip(line[:-1], line[1:]):
        ab = b - a
        t = np.clip((x - a) @ ab / (ab @ ab), 0.0, 1.0)
        gaps = np.minimum(gaps, np.linalg.norm(x - (a + t[:, None] * ab), axis=1))
    return gaps - tube["radius"] - session.data.radius


def test_the_loops_rest_on_the_colon_and_do_not_pass_through_it():
    """The intestine, at rest just touching the colon, sags onto it under gravity
    while the probe sweeps the lowest loops: masses lie on it (within 2 mm) and none
    sinks more than 1 mm into it."""
    scene = intestine_scene()
    with Session(scene, progress=False) as session:
        device = scene_script(scene)
        deepest, resting = np.inf, 0
        for _ in range(45):
            now = session.state.time
            session.step(device.poses(now), device.buttons(now))
            gaps = tube_gaps(session)
            deepest, resting = min(deepest, gaps.min()), max(resting, (gaps < 2e-3).sum())
    assert deepest > -1e-3 and resting >= 3, (deepest, resting)


def test_the_colon_is_drawn_and_its_view_is_measured_from_the_object_ids():
    """From the scene's endoscope the loops hide part of the colon; from beneath the
    floor (the floor and the cavity's wall not drawn), looking up at it, nothing does
    (all of its image shows); looking away, it is out of view."""
    raw = scene_mod.load("intestine").raw
    raw["environment"]["planes"][0]["extent"] = 0.0
    del raw["environment"]["cavity"]
    scene = scene_mod.validate(raw, "intestine", ".")
    with Session(scene, progress=False) as session:
        renderer = Renderer.for_scene(scene, session.model, size=(160, 120))
        renderer.render(session.state, session.control)
        visible, share = renderer.view_of("colon")
        triangles = renderer.gbuffer.triangle.to_numpy()
        objects = renderer.mesh.triangle_object.to_numpy()
        colon = renderer.mesh.object_names.index("colon")
        shown = (triangles >= 0) & (objects[triangles] == colon)
        assert share == pytest.approx(shown.mean())
        assert 0.05 < visible < 0.95 and share > 0.01
        camera = renderer.camera
        camera.eye, camera.target = np.array([0.0, -0.35, 0.02]), np.array([0.0, -0.19, 0.0])
        camera.up = np.array([0.0, 0.0, 1.0])
        renderer.render(session.state, session.control)
        visible, share = renderer.view_of("colon")
        assert visible > 0.99 and share > 0.05
        camera.target = np.array([0.0, -0.6, 0.02])
        renderer.render(session.state, session.control)
        assert renderer.view_of("colon") == (0.0, 0.0)
