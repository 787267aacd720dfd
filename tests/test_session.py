"""Session start: a scene with ``settle_time`` starts from its organs at rest under
gravity, and every reset returns there."""

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.session import Session, release_parked, session_key

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


def fresh_session(scene, use_cache: bool = False) -> Session:
    """A session of ``scene`` built anew, not the one a closed session left for reuse."""
    release_parked(session_key(scene))
    return Session(scene, use_cache=use_cache, progress=False)


def still_ball():
    """The ball alone, one substep, no gravity: at rest it stays where it was built."""
    return scene_mod.from_tables([BALL], substeps=1, gravity=[0.0, 0.0, 0.0])


def test_settled_start_is_at_rest_on_the_floor_and_reset_returns_to_it():
    settled = ball_session(1.5)
    x_rest, x0 = settled.data.rest_position, settled.state.positions()
    start = settled.state.snapshot()
    assert settled.state.time == 0.0 and settled.state.frame == 0
    # it sagged onto the floor from the rest shape it was built in, and has stopped
    assert x0[:, 1].mean() < x_rest[:, 1].mean() - 5e-4
    assert x0[:, 1].min() > FLOOR["point"][1] - 1e-3
    assert np.linalg.norm(settled.state.v.to_numpy(), axis=1).max() < 0.01
    # a settled start barely moves in its first frames
    for _ in range(10):
        settled.step()
    assert np.abs(settled.state.positions() - x0).max() < 1e-3
    # a start from the rest shape (the same fields, reset to it) falls
    settled.state.reset(settled.model)
    settled.solver.reset()
    np.testing.assert_allclose(settled.state.positions(), x_rest, atol=1e-7)
    for _ in range(10):
        settled.step()
    assert np.abs(settled.state.positions() - x_rest).max() > 2e-3
    settled.reset()
    again = settled.state.snapshot()
    for name, value in again.items():
        assert np.array_equal(value, start[name]), name


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


@pytest.mark.parametrize("name", ["rectum", "intestine"])
def test_a_second_session_of_a_scene_compiles_nothing_and_runs_the_same(name):
    from taichi_lap.runtime import kernel_compilations
    from taichi_lap.session import scene_script

    scene = scene_mod.load(name, {"scene.detail": 0.1, "scene.settle_time": 0.1})

    def run() -> list[np.ndarray]:
        with Session(scene, use_cache=False, progress=False) as session:
            script = scene_script(scene)
            frames = []
            for _ in range(8):
                t = session.state.time
                session.step(script.poses(t), script.buttons(t))
                frames.append(session.state.positions())
        return frames

    release_parked(session_key(scene))  # another test's session of the scene
    first = run()
    compiled = kernel_compilations()
    second = run()
    assert kernel_compilations() == compiled
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


def test_a_closed_session_cannot_step_and_its_fields_are_freed_for_another_scene():
    from taichi_lap.session import keep_closed_sessions
    from tests.conftest import KEPT_SESSIONS

    session = ball_session(0.0)
    session.close()
    with pytest.raises(RuntimeError, match="closed"):
        session.step()
    tree = session.model._group.tree
    assert tree is not None  # kept for the next session of the ball scene
    other = Session(scene_mod.from_tables([BALL], substeps=3), use_cache=False, progress=False)
    keep_closed_sessions(1)  # the default: only the last closed session is kept
    try:
        other.close()  # another scene: the ball's fields are freed
    finally:
        keep_closed_sessions(KEPT_SESSIONS)
    assert session.model._group.tree is None
    assert other.model._group.tree is not None
    release_parked(session_key(other.scene))
    assert other.model._group.tree is None
    with pytest.raises(ValueError, match="at least 1"):
        keep_closed_sessions(0)


def test_settled_start_is_cached_and_a_damaged_cache_is_settled_again(
    tmp_path, monkeypatch, caplog
):
    monkeypatch.setenv("TAICHI_LAP_CACHE", str(tmp_path))
    scene = scene_mod.from_tables([BALL], planes=[FLOOR], substeps=2, settle_time=0.5)

    def start() -> tuple[float, dict]:
        """A new session (not the one kept for reuse): its settling time and start."""
        with fresh_session(scene, use_cache=True) as session:
            return session.settle_seconds, session.state.snapshot()

    seconds, settled = start()
    assert seconds > 0.0 and len(list(tmp_path.glob("*.start.npz"))) == 1
    seconds, loaded = start()
    assert seconds == 0.0  # loaded, not simulated
    for key, value in settled.items():
        np.testing.assert_array_equal(value, loaded[key], err_msg=key)
    next(tmp_path.glob("*.start.npz")).write_bytes(b"not an archive")
    seconds, _ = start()
    assert seconds > 0.0 and "ignoring unreadable settled start" in caplog.text


def test_a_session_that_takes_a_model_dissected_outside_its_session_gets_it_as_built():
    """Tissue removed through a DeviceTopology of its own (not the session's) is put
    back too when the next session of the scene takes the closed one's model."""
    from taichi_lap.dissection.device import DeviceTopology
    from taichi_lap.dissection.removal import MutableTopology

    scene = still_ball()
    first = fresh_session(scene)
    model = first.model
    built = (model.surface_triangles.to_numpy(), model.as_built)
    topology = MutableTopology(first.data)
    rest = first.data.rest_position
    DeviceTopology(model, topology).apply(
        topology.remove(np.flatnonzero(rest[:, 0] > 0.005)), first.state
    )
    assert not model.as_built
    assert not np.array_equal(model.surface_triangles.to_numpy(), built[0])  # the wound
    first.close()
    second = Session(scene, use_cache=False, progress=False)
    assert second.model is model and model.as_built and built[1]
    np.testing.assert_array_equal(model.surface_triangles.to_numpy(), built[0])
    second.close()


def test_a_session_that_takes_a_closed_ones_control_has_only_its_scenes_tools():
    """A tool placed in a closed session's Control by hand (a test pressing the model
    through it) is out of the next session of the scene, which has no tools: that
    session's ball stays at rest (a tool left in pushed the test block 26 mm)."""
    scene = still_ball()
    first = fresh_session(scene)
    top = first.data.rest_position[:, 1].max()
    first.control.set_tool(0, [-0.03, top - 0.002, 0.0], [0.03, top - 0.002, 0.0], 0.005)
    control = first.control
    first.close()
    second = Session(scene, use_cache=False, progress=False)
    assert second.control is control
    assert not second.control.tool_active.to_numpy().any()
    for _ in range(3):
        second.step()
    assert np.abs(second.state.x.to_numpy() - second.data.rest_position).max() < 1e-6
    second.close()
