"""Session start: a scene with ``settle_time`` starts from its organs at rest under
gravity, and every reset returns there."""

import numpy as np

from taichi_lap import scene as scene_mod
from taichi_lap.session import Session

BALL = {
    "name": "ball",
    "model": "tet_clusters",
    "geometry": {"generator": "sphere", "radius": 0.02},
    "material": {"particle_spacing": 0.004, "stiffness": 0.3, "damping": 6.0},
}
FLOOR = {"point": [0.0, -0.02, 0.0], "normal": [0.0, 1.0, 0.0], "friction": 0.8}


def ball_session(settle_time: float) -> Session:
    scene = scene_mod.from_tables(
        [BALL],
        planes=[FLOOR],
        substeps=2,
        shape_iterations=2,
        settle_time=settle_time,
        collision="circumsphere",
    )
    return Session(scene, use_cache=False, progress=False)


def test_settled_start_is_at_rest_on_the_floor_and_reset_returns_to_it():
    rest = ball_session(0.0)
    settled = ball_session(1.5)
    x_rest, x0 = rest.state.positions(), settled.state.positions()
    assert settled.state.time == 0.0 and settled.state.frame == 0
    # it sagged onto the floor from the rest shape it was built in, and has stopped
    assert x0[:, 1].mean() < x_rest[:, 1].mean() - 5e-4
    assert x0[:, 1].min() > FLOOR["point"][1] - 1e-3
    assert np.linalg.norm(settled.state.v.to_numpy(), axis=1).max() < 0.01
    # a settled start barely moves in its first frames, a rest-shape start falls
    for session in (rest, settled):
        for _ in range(10):
            session.step()
    assert np.abs(settled.state.positions() - x0).max() < 1e-3
    assert np.abs(rest.state.positions() - x_rest).max() > 2e-3
    settled.reset()
    again = settled.state.snapshot()
    fresh = ball_session(1.5).state.snapshot()
    for name, value in again.items():
        assert np.array_equal(value, fresh[name]), name
    np.testing.assert_array_equal(again["x"], x0)


def test_solver_settings_take_every_default_from_the_scene_schema():
    from dataclasses import fields

    from taichi_lap.scene.schema import SCENE_PARAMS
    from taichi_lap.sim import SolverSettings

    defaults = SolverSettings()
    for field in fields(SolverSettings):
        expected = SCENE_PARAMS[field.name].default
        assert getattr(defaults, field.name) == (
            tuple(expected) if isinstance(expected, list) else expected
        ), field.name
    scene = scene_mod.from_tables([BALL], substeps=3, gravity=[0.0, 0.0, -1.0])
    settings = SolverSettings.from_scene(scene.settings)
    assert settings.substeps == 3 and settings.gravity == (0.0, 0.0, -1.0)
    assert settings.self_collision is True
