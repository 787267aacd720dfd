"""Running a scene: the interactive GGUI window, headless video, and stills.

Headless output is the deferred renderer's own frame; no window (and no Vulkan)
is needed for it. With ``record`` a run appends its device input and events to a
session file (:mod:`taichi_lap.recording`)."""

from __future__ import annotations

import time
from contextlib import contextmanager

from tqdm import tqdm

from taichi_lap.recording import SessionRecorder, maybe_recording
from taichi_lap.render.renderer import Renderer
from taichi_lap.replay import read_recording
from taichi_lap.scene import Scene
from taichi_lap.session import Session, scene_script
from taichi_lap.training.live import LiveScore, verdict_lines
from taichi_lap.training.metrics import session_metrics
from taichi_lap.video import FrameWriter, write_png


def _after_step(session: Session, renderer: Renderer):
    """After a frame was stepped: the cautery smoke of its energised hooks and the
    blood of its damaged vessels."""
    renderer.update_smoke(bool(session.energised), session.dt)
    renderer.update_blood(
        session.events, session.state, session.data, session.state.time, session.dt
    )


def _render(session: Session, renderer: Renderer):
    start = time.perf_counter()
    renderer.render(session.state, session.control, session.peak_temperature)
    session.timings["render"] = (time.perf_counter() - start) * 1e3


def _measure(
    session: Session, recorder: SessionRecorder | None, live: LiveScore, renderer: Renderer
):
    """After a frame was stepped and drawn: the force the tissue pushed each tool with
    and the organs touching each go, with the stage times and how the image showed the
    task's view target (:meth:`Renderer.view_of`), to the recording and the live
    score."""
    tools = [tool["name"] for tool in session.scene.tools]
    contact = [session.tool_contact(k) for k in range(len(tools))]
    forces = {name: force for name, (force, _) in zip(tools, contact)}
    touching = {name: organs for name, (_, organs) in zip(tools, contact)}
    task = session.scene.task
    view = None
    if task is not None and task["view"] is not None:
        target = task["view"]["target"]
        view = {target: renderer.view_of(target)}
    if recorder is not None:  # the stages of the frame, not the window's frame interval
        stages = {stage: ms for stage, ms in session.timings.items() if stage != "frame"}
        recorder.record_stats(stages, forces, touching, view)
    live.update(dict(zip(tools, session.control.tips)), forces, touching, session.events, view)


def _verdict(session: Session, recorder: SessionRecorder | None) -> list[str]:
    """Close the recording and judge the scene's task on it (the report's verdict),
    as summary lines; none without a recording or a task."""
    if recorder is None:
        return []
    recorder.close()
    if session.scene.task is None:
        return []
    return verdict_lines(session_metrics(read_recording(recorder.path)).task)


def _advance(
    session: Session, device, recorder: SessionRecorder | None, check_topology: bool = False
):
    """One frame: read the device (poses first: a replay advances on them), record
    what it gave, step, record the step's events; with ``check_topology`` run the
    topology validator when the step removed tissue."""
    start = time.perf_counter()
    now = session.state.time
    poses = device.poses(now) if device else None
    buttons = device.buttons(now) if hasattr(device, "buttons") else None
    if recorder is not None:
        if hasattr(device, "drain_ticks"):
            recorder.record_ticks(device.drain_ticks())
        recorder.record_frame(poses, buttons)
    session.timings["devices"] = (time.perf_counter() - start) * 1e3
    session.step(poses, buttons)
    if recorder is not None:
        for event in session.events:
            recorder.record_event(**event)
    if check_topology:
        session.check_topology()


@contextmanager
def _connected(device, session: Session):
    """A device that needs the running session (a haptic bridge publishes its surface
    to the servo process) is attached to it, and closed when the run ends."""
    if not hasattr(device, "attach"):
        yield
        return
    device.attach(session)
    try:
        yield
    finally:
        device.close()


def run_headless(
    scene: Scene,
    device,
    *,
    frames: int,
    out: str,
    size,
    use_cache: bool = True,
    record: str | None = None,
    check_topology: bool = False,
) -> Session:
    """Simulate ``frames`` frames and write each rendered frame to ``out``; with
    ``record``, append the session to that recording file; with ``check_topology``
    validate the topology (:meth:`Session.check_topology`)."""
    session = Session(scene, use_cache=use_cache)
    if check_topology:
        session.check_topology()
    renderer = Renderer.for_scene(scene, session.model, size=size)
    with (
        _connected(device, session),
        maybe_recording(record, session, device) as recorder,
        FrameWriter(out, fps=1.0 / session.dt) as writer,
    ):
        live = LiveScore(scene.task, [tool["name"] for tool in scene.tools], session.dt)
        session.solver.time_stages = recorder is not None
        for _ in tqdm(range(frames), desc=f"{scene.settings['name']} -> {out}", unit="frame"):
            _advance(session, device, recorder, check_topology)
            _after_step(session, renderer)
            _render(session, renderer)
            if recorder is not None or scene.task is not None:
                _measure(session, recorder, live, renderer)
            writer.write(renderer.image())
        for line in _verdict(session, recorder):
            print(line)
    return session


def run_window(
    scene: Scene,
    device,
    *,
    frames: int | None,
    size,
    use_cache: bool = True,
    record: str | None = None,
    check_topology: bool = False,
) -> Session:
    """The interactive window: mouse-driven tool, endoscope on keys and right button;
    with ``record``, append the session to that recording file; with
    ``check_topology`` validate the topology (:meth:`Session.check_topology`)."""
    from taichi_lap.viewer import Viewer

    session = Session(scene, use_cache=use_cache)
    if check_topology:
        session.check_topology()
    viewer = Viewer(session, Renderer.for_scene(scene, session.model, size=size), show_window=True)
    window, camera = viewer.window, viewer.renderer.camera
    session.camera = camera  # a piece lifted out of this view is excised
    live = LiveScore(scene.task, [tool["name"] for tool in scene.tools], session.dt)
    verdict = None  # the summary once the task is over
    with _connected(device, session), maybe_recording(record, session, device) as recorder:
        session.solver.time_stages = recorder is not None
        last = time.perf_counter()
        while window.running and (frames is None or session.state.frame < frames):
            now = time.perf_counter()
            viewer.handle_input(now - last)
            if hasattr(device, "update"):
                device.update(window, camera.eye, camera.target, camera.fov, now - last)
            stepping = not viewer.paused and verdict is None
            if stepping:
                _advance(session, device, recorder, check_topology)
                _after_step(session, viewer.renderer)
            session.timings["frame"] = (now - last) * 1e3
            last = now
            start = time.perf_counter()
            viewer.draw(live.lines() + (verdict or []))
            session.timings["render"] = (time.perf_counter() - start) * 1e3
            if stepping:
                _measure(session, recorder, live, viewer.renderer)
            if verdict is None and (live.over_time or live.goal_reached or viewer.finish_requested):
                verdict = _verdict(session, recorder) or ["finished"]
            window.show()
    return session


def render_still(scene: Scene, *, frames: int, out: str, size, use_cache: bool = True):
    """Simulate ``frames`` frames (scene scripts drive the tools), write one PNG."""
    session = Session(scene, use_cache=use_cache)
    device = scene_script(scene)
    for _ in range(frames):
        _advance(session, device, None)
    renderer = Renderer.for_scene(scene, session.model, size=size)
    renderer.render(session.state, session.control, session.peak_temperature)
    write_png(out, renderer.image())
    session.close()
