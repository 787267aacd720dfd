"""GGUI view of a running session: organ surfaces coloured per organ, the intestine
as spheres along its centre row, instruments as strings of spheres along their
shafts, and a panel with frame rate, stage timings and controls.

This is GGUI's own mesh drawing (rasterised by Vulkan; on a machine without a GPU
by Mesa's software driver). ``show_window=False`` renders offscreen for headless
output.
"""

import numpy as np
import taichi as ti

from taichi_lap.kernels.instruments import capsule_beads
from taichi_lap.kernels.normals import vertex_normals
from taichi_lap.session import Session
from taichi_lap.sim.control import MAX_TOOLS
from taichi_lap.sim.csr import incidence

TOOL_BEADS = 32
TOOL_COLOR = (0.72, 0.74, 0.78)


class Viewer:
    """Draws a :class:`Session` into a GGUI window (or offscreen)."""

    def __init__(self, session: Session, *, size=(1280, 720), show_window: bool = True,
                 title: str = "taichi-lap"):
        self.session = session
        self.window = ti.ui.Window(f"{title}: {session.scene.settings['name']}", size,
                                   show_window=show_window, vsync=show_window)
        self.canvas = self.window.get_canvas()
        self.scene3d = self.window.get_scene()
        self.camera = ti.ui.Camera()
        cam = session.scene.camera
        self.camera.position(*cam["position"])
        self.camera.lookat(*cam["target"])
        self.camera.up(*cam["up"])
        self.camera.fov(cam["fov"])
        self.camera.z_near(cam["near"])
        self.camera.z_far(cam["far"])
        self._init_surface()
        self.beads = ti.Vector.field(3, ti.f32, MAX_TOOLS * TOOL_BEADS)
        self.bead_radius = ti.field(ti.f32, MAX_TOOLS * TOOL_BEADS)
        self.paused = False
        self.show_panel = show_window

    def _init_surface(self):
        data, model = self.session.data, self.session.model
        v = max(model.surface_vertex_count, 1)
        colors = np.zeros((v, 3), dtype=np.float32)
        for organ in data.organs:
            colors[organ.surface_vertices[0]:organ.surface_vertices[1]] = organ.color
        self.colors = ti.Vector.field(3, ti.f32, v)
        self.colors.from_numpy(colors)
        tris = data.surface_triangles
        start, rows = incidence(tris.reshape(-1), v)
        self.incident_start = ti.field(ti.i32, v + 1)
        self.incident = ti.field(ti.i32, max(len(rows), 1))
        self.incident_start.from_numpy(start.astype(np.int32))
        if len(rows):
            self.incident.from_numpy((rows // 3).astype(np.int32))
        self.normals = ti.Vector.field(3, ti.f32, v)
        self.tubes = [(o.surface_vertices[0], o.row_length, o.color) for o in data.organs
                      if o.row_length]
        self.tube_radius = float(np.max(data.radius)) if self.tubes else 0.0

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.camera.curr_position), np.asarray(self.camera.curr_lookat)

    def render(self):
        """Draw the current state into the canvas."""
        session, model, state = self.session, self.session.model, self.session.state
        scene = self.scene3d
        scene.set_camera(self.camera)
        scene.ambient_light((0.25, 0.22, 0.22))
        eye, _ = self.camera_pose()
        scene.point_light(tuple(eye), (1.0, 0.95, 0.9))  # endoscope headlight
        if model.surface_triangle_count:
            vertex_normals(state.surface_position, model.surface_triangles, self.incident_start,
                           self.incident, model.surface_vertex_count, self.normals)
            scene.mesh(state.surface_position, indices=model.surface_triangles,
                       normals=self.normals, per_vertex_color=self.colors, two_sided=True)
        for start, count, color in self.tubes:
            scene.particles(state.surface_position, radius=self.tube_radius, color=tuple(color),
                            index_offset=start, index_count=count)
        if session.scene.tools:
            capsule_beads(session.control, self.beads, self.bead_radius, TOOL_BEADS)
            scene.particles(self.beads, radius=float(max(t["radius"] for t in session.scene.tools)),
                            color=TOOL_COLOR, index_count=len(session.scene.tools) * TOOL_BEADS)
        self.canvas.set_background_color((0.09, 0.05, 0.05))
        self.canvas.scene(scene)
        if self.show_panel:
            self._panel()

    def _panel(self):
        gui = self.window.get_gui()
        timings = self.session.timings
        with gui.sub_window("taichi-lap", 0.01, 0.01, 0.24, 0.3):
            gui.text(f"frame {self.session.state.frame}  t = {self.session.state.time:.2f} s")
            for stage, ms in timings.items():
                gui.text(f"{stage}: {ms:.1f} ms")
            gui.text(f"particles {self.session.model.particle_count}  "
                     f"clusters {self.session.model.cluster_total}")
            self.paused = gui.checkbox("pause", self.paused)
            if gui.button("reset"):
                self.session.state.reset(self.session.model)
            gui.text("LMB drag: move tool, q/e: depth")
            gui.text("RMB drag + WASD: camera")

    def image(self) -> np.ndarray:
        """The rendered frame as ``(H, W, 3)`` uint8 RGB."""
        rgba = self.window.get_image_buffer_as_numpy()  # (W, H, 4) float, origin bottom-left
        rgb = np.flipud(np.transpose(rgba[:, :, :3], (1, 0, 2)))
        return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
