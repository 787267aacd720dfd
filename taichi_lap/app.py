"""Running a scene: the interactive GGUI window, headless video, and stills."""

from __future__ import annotations

import time

from tqdm import tqdm

from taichi_lap.scene import Scene
from taichi_lap.session import Session
from taichi_lap.video import FrameWriter, write_png
from taichi_lap.viewer import Viewer


def _timed_render(session: Session, viewer: Viewer):
    start = time.perf_counter()
    viewer.render()
    session.timings["render"] = (time.perf_counter() - start) * 1e3


def run_headless(scene: Scene, device, *, frames: int, out: str, size, use_cache: bool = True):
    """Simulate ``frames`` frames and write each rendered frame to ``out``."""
    session = Session(scene, use_cache=use_cache)
    viewer = Viewer(session, size=size, show_window=False)
    with FrameWriter(out, fps=1.0 / session.dt) as writer:
        for _ in tqdm(range(frames), desc=f"{scene.settings['name']} -> {out}", unit="frame"):
            session.step(device.poses(session.state.time) if device else None)
            _timed_render(session, viewer)
            writer.write(viewer.image())


def run_window(scene: Scene, device, *, frames: int | None, size, use_cache: bool = True):
    """The interactive window: mouse-driven tool, camera on the right button."""
    import taichi as ti

    session = Session(scene, use_cache=use_cache)
    viewer = Viewer(session, size=size, show_window=True)
    window = viewer.window
    last = time.perf_counter()
    while window.running and (frames is None or session.state.frame < frames):
        now = time.perf_counter()
        viewer.camera.track_user_inputs(window, movement_speed=0.002, hold_key=ti.ui.RMB)
        if hasattr(device, "update"):
            eye, target = viewer.camera_pose()
            device.update(window, eye, target, scene.camera["fov"], now - last)
        if not viewer.paused:
            session.step(device.poses(session.state.time) if device else None)
        session.timings["frame"] = (now - last) * 1e3
        last = now
        _timed_render(session, viewer)
        window.show()


def render_still(scene: Scene, *, frames: int, out: str, size, use_cache: bool = True):
    """Simulate ``frames`` frames (scene scripts drive the tools), write one PNG."""
    from taichi_lap.session import scene_script

    session = Session(scene, use_cache=use_cache)
    device = scene_script(scene)
    for _ in range(frames):
        session.step(device.poses(session.state.time) if device else None)
    viewer = Viewer(session, size=size, show_window=False)
    viewer.render()
    write_png(out, viewer.image())
