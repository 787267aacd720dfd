"""Running a scene: the interactive GGUI window, headless video, and stills.

Headless output is the deferred renderer's own frame; no window (and no Vulkan)
is needed for it."""

from __future__ import annotations

import time

from tqdm import tqdm

from taichi_lap.render.renderer import Renderer
from taichi_lap.scene import Scene
from taichi_lap.session import Session, scene_script
from taichi_lap.video import FrameWriter, write_png


def _render(session: Session, renderer: Renderer):
    start = time.perf_counter()
    renderer.render(session.state, session.control)
    session.timings["render"] = (time.perf_counter() - start) * 1e3


def run_headless(scene: Scene, device, *, frames: int, out: str, size, use_cache: bool = True):
    """Simulate ``frames`` frames and write each rendered frame to ``out``."""
    session = Session(scene, use_cache=use_cache)
    renderer = Renderer.for_scene(scene, session.data, size=size)
    with FrameWriter(out, fps=1.0 / session.dt) as writer:
        for _ in tqdm(range(frames), desc=f"{scene.settings['name']} -> {out}", unit="frame"):
            session.step(device.poses(session.state.time) if device else None)
            _render(session, renderer)
            writer.write(renderer.image())


def run_window(scene: Scene, device, *, frames: int | None, size, use_cache: bool = True):
    """The interactive window: mouse-driven tool, endoscope on keys and right button."""
    from taichi_lap.viewer import Viewer

    session = Session(scene, use_cache=use_cache)
    viewer = Viewer(session, Renderer.for_scene(scene, session.data, size=size), show_window=True)
    window, camera = viewer.window, viewer.renderer.camera
    last = time.perf_counter()
    while window.running and (frames is None or session.state.frame < frames):
        now = time.perf_counter()
        viewer.handle_input(now - last)
        if hasattr(device, "update"):
            device.update(window, camera.eye, camera.target, camera.fov, now - last)
        if not viewer.paused:
            session.step(device.poses(session.state.time) if device else None)
        session.timings["frame"] = (now - last) * 1e3
        last = now
        start = time.perf_counter()
        viewer.draw()
        session.timings["render"] = (time.perf_counter() - start) * 1e3
        window.show()


def render_still(scene: Scene, *, frames: int, out: str, size, use_cache: bool = True):
    """Simulate ``frames`` frames (scene scripts drive the tools), write one PNG."""
    session = Session(scene, use_cache=use_cache)
    device = scene_script(scene)
    for _ in range(frames):
        session.step(device.poses(session.state.time) if device else None)
    renderer = Renderer.for_scene(scene, session.data, size=size)
    renderer.render(session.state, session.control)
    write_png(out, renderer.image())
