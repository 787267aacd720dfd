"""The GGUI training window: the deferred image (``canvas.set_image``), an
endoscope camera moved by keys and mouse, a panel with frame rate, ms per
stage, the instruments' state, lighting toggles and G-buffer debug views, and the
trainee's task panel (task, timer, running values, verdict).

``show_window=False`` renders offscreen (GGUI on Vulkan; Mesa's software driver
where there is no GPU)."""

from __future__ import annotations

import taichi as ti

from taichi_lap.kernels.shading import VIEWS
from taichi_lap.render.renderer import Renderer
from taichi_lap.render.tubes import TessellationController
from taichi_lap.session import Session

FRAME_TARGET_MS = 1000.0 / 30.0
"""Frame time the tube tessellation controller holds in the window (≥ 30 Hz)."""


class Viewer:
    """A :class:`Session` drawn by a :class:`Renderer` into a GGUI window."""

    def __init__(
        self,
        session: Session,
        renderer: Renderer,
        *,
        show_window: bool = True,
        title: str = "taichi-lap",
    ):
        self.session = session
        self.renderer = renderer
        self.window = ti.ui.Window(
            f"{title}: {session.scene.settings['name']}",
            (renderer.width, renderer.height),
            show_window=show_window,
            vsync=show_window,
        )
        self.canvas = self.window.get_canvas()
        self.paused = False
        self.finish_requested = False  # the trainee ended the task (panel button)
        self.show_panel = show_window
        self._cursor = None
        mesh = renderer.mesh
        self.tessellation = (
            TessellationController(FRAME_TARGET_MS, max_level=mesh.tubes[0].max_level)
            if mesh.tubes
            else None
        )
        self._defaults = {
            "headlight": renderer.params.intensity[None],
            "ambient": renderer.params.ambient[None],
        }

    def handle_input(self, dt: float):
        """Move the endoscope: w/s/a/d/r/f and right-button drag."""
        self._cursor = self.renderer.camera.track_window(
            self.window, dt, drag_button=ti.ui.RMB, last_cursor=self._cursor
        )

    def draw(self, task_lines: list[str] = ()):
        """Render the session's state and show it with the panel, and the task panel
        with ``task_lines`` (:class:`~taichi_lap.training.live.LiveScore`) when given.
        The tubes' tessellation follows the last frame time (seed 001 §5.3)."""
        if self.tessellation is not None and "frame" in self.session.timings:
            mesh = self.renderer.mesh
            mesh.tube_epsilon, mesh.tube_level = self.tessellation.update(
                self.session.timings["frame"]
            )
        self.renderer.render(
            self.session.state, self.session.control, self.session.peak_temperature
        )
        self.canvas.set_image(self.renderer.frame)
        if self.show_panel:
            self._panel()
            if task_lines:
                self._task_panel(task_lines)

    def _task_panel(self, lines: list[str]):
        """The trainee's panel: the task, timer, running values, and once the task is
        over its verdict; a button ends the task early."""
        gui = self.window.get_gui()
        with gui.sub_window("task", 0.64, 0.01, 0.35, 0.42):
            for line in lines:
                gui.text(line)
            if not self.finish_requested and gui.button("finish the task"):
                self.finish_requested = True

    def _panel(self):
        session, renderer = self.session, self.renderer
        gui = self.window.get_gui()
        with gui.sub_window("taichi-lap", 0.01, 0.01, 0.28, 0.5):
            frame_ms = session.timings.get("frame", 0.0)
            gui.text(
                f"frame {session.state.frame}  t = {session.state.time:.2f} s  "
                f"{1e3 / frame_ms if frame_ms > 0 else 0.0:.0f} fps"
            )
            for stage, ms in {**session.timings, **renderer.timings}.items():
                gui.text(f"  {stage}: {ms:.1f} ms")
            if self.tessellation is not None:
                gui.text(
                    f"tubes: level {renderer.mesh.tube_level}, "
                    f"epsilon {renderer.mesh.tube_epsilon:.2f}"
                )
            gui.text(
                f"particles {session.model.particle_count}  clusters {session.model.cluster_total}"
            )
            for index, tool in enumerate(session.scene.tools):
                tip = session.control.tool_a[index]
                energised = " ENERGISED" if tool["name"] in session.energised else ""
                gui.text(
                    f"{tool['name']} ({tool['kind']}): tip "
                    f"{tip[0]:+.3f} {tip[1]:+.3f} {tip[2]:+.3f} m{energised}"
                )
            self.paused = gui.checkbox("pause", self.paused)
            if gui.button("reset"):
                session.reset()
            params = renderer.params
            headlight = gui.checkbox("headlight", params.intensity[None] > 0.0)
            params.intensity[None] = self._defaults["headlight"] if headlight else 0.0
            ambient = gui.checkbox("image-based light", params.ambient[None] > 0.0)
            params.ambient[None] = self._defaults["ambient"] if ambient else 0.0
            params.exposure[None] = gui.slider_float("exposure", params.exposure[None], 0.1, 4.0)
            renderer.view = gui.slider_int(
                f"view: {VIEWS[renderer.view]}", renderer.view, 0, len(VIEWS) - 1
            )
            gui.text("LMB drag: tool, q/e: tool depth, z/x: roll, g: grasp, c (held): cautery")
            gui.text("RMB drag: turn scope, w/s a/d r/f: move scope")
