"""GGUI view of a running session: organ surfaces coloured per organ, the
intestine and the instruments as tubes, and a panel with frame rate, stage
timings and controls.

Everything is drawn as one triangle mesh (GGUI's own rasteriser, on Vulkan; on a
machine without a GPU Mesa's software driver). With several GGUI renderables per
frame, Taichi 1.7.4's GGUI on the CPU backend drops whole draws on random frames;
a single mesh does not. ``show_window=False`` renders offscreen for headless output.
"""

import numpy as np
import taichi as ti

from taichi_lap.kernels.contact import MAX_TOOLS
from taichi_lap.kernels.normals import vertex_normals
from taichi_lap.kernels.tube_mesh import gather_polylines, ring_vertices
from taichi_lap.session import Session
from taichi_lap.sim.csr import incidence
from taichi_lap.sim.fields import FieldGroup

TUBE_SIDES = 10
TOOL_COLOR = (0.72, 0.74, 0.78)
GGUI_MIN_NEAR = 0.02
"""GGUI drops draws on random frames with a near plane closer than about 2 cm; the
GGUI view clamps it (the scene value is kept for renderers that handle it)."""


def _tube_triangles(first_ring: int, rings: int, sides: int) -> np.ndarray:
    """Triangles joining consecutive rings of a tube."""
    k, j = np.meshgrid(np.arange(rings - 1), np.arange(sides), indexing="ij")
    a = first_ring + k * sides + j
    b = first_ring + k * sides + (j + 1) % sides
    c, d = a + sides, b + sides
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                           np.stack([b, d, c], -1).reshape(-1, 3)])


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
        self.camera.z_near(max(cam["near"], GGUI_MIN_NEAR))
        self.camera.z_far(cam["far"])
        self._build_mesh()
        self.paused = False
        self.show_panel = show_window

    def _build_mesh(self):
        """Static parts of the drawn mesh: indices, colours, tube layout, incidence."""
        data, model = self.session.data, self.session.model
        surface_count = model.surface_vertex_count
        tubes = [o for o in data.organs if o.row_length]
        tube_source = np.concatenate([np.arange(o.surface_vertices[0],
                                                o.surface_vertices[0] + o.row_length)
                                      for o in tubes] or [np.zeros(0, np.int64)])
        tube_radius = np.concatenate([data.radius[o.particles[0]:o.particles[0] + o.row_length]
                                      for o in tubes] or [np.zeros(0)])
        lines = [(o.row_length, o.color) for o in tubes] + [(2, TOOL_COLOR)] * MAX_TOOLS
        points = sum(n for n, _ in lines)
        previous, following, triangles = [], [], [data.surface_triangles]
        colors = [np.zeros((surface_count, 3))]
        for organ in data.organs:
            colors[0][organ.surface_vertices[0]:organ.surface_vertices[1]] = organ.color
        start = 0
        for count, color in lines:
            k = np.arange(start, start + count)
            previous.append(np.maximum(k - 1, start))
            following.append(np.minimum(k + 1, start + count - 1))
            triangles.append(_tube_triangles(surface_count + start * TUBE_SIDES, count, TUBE_SIDES))
            colors.append(np.tile(color, (count * TUBE_SIDES, 1)))
            start += count
        triangles = np.concatenate(triangles).astype(np.int32).reshape(-1)
        vertex_count = surface_count + points * TUBE_SIDES
        self.surface_count, self.tube_count, self.point_count = surface_count, len(tube_source), points

        group = FieldGroup()
        self.tube_source = group.field(ti.i32, len(tube_source), values=tube_source)
        self.point_radius = group.field(ti.f32, points, values=np.concatenate(
            [tube_radius, np.zeros(2 * MAX_TOOLS)]).astype(np.float32))
        self.previous = group.field(ti.i32, points, values=np.concatenate(previous))
        self.following = group.field(ti.i32, points, values=np.concatenate(following))
        self.points = group.field(ti.f32, points, vector=3)
        self.vertices = group.field(ti.f32, vertex_count, vector=3)
        self.normals = group.field(ti.f32, vertex_count, vector=3)
        self.colors = group.field(ti.f32, vertex_count, vector=3,
                                  values=np.concatenate(colors).astype(np.float32))
        self.indices = group.field(ti.i32, len(triangles), values=triangles)
        start, rows = incidence(triangles, vertex_count)
        self.incident_start = group.field(ti.i32, vertex_count + 1, values=start.astype(np.int32))
        self.incident = group.field(ti.i32, len(rows), values=(rows // 3).astype(np.int32))
        group.finalize()
        self.vertex_count = vertex_count

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.camera.curr_position), np.asarray(self.camera.curr_lookat)

    def render(self):
        """Draw the current state into the canvas."""
        session = self.session
        gather_polylines(session.state.surface_position, self.surface_count, self.tube_source,
                         self.tube_count, session.control, self.vertices, self.points,
                         self.point_radius)
        ring_vertices(self.points, self.point_radius, self.previous, self.following,
                      self.point_count, TUBE_SIDES, self.vertices, self.surface_count)
        vertex_normals(self.vertices, self.indices, self.incident_start, self.incident,
                       self.vertex_count, self.normals)
        scene = self.scene3d
        scene.set_camera(self.camera)
        scene.ambient_light((0.25, 0.22, 0.22))
        eye, _ = self.camera_pose()
        scene.point_light(tuple(eye), (1.0, 0.95, 0.9))  # endoscope headlight
        scene.mesh(self.vertices, indices=self.indices, normals=self.normals,
                   per_vertex_color=self.colors, two_sided=True)
        self.canvas.set_background_color((0.09, 0.05, 0.05))
        self.canvas.scene(scene)
        if self.show_panel:
            self._panel()

    def _panel(self):
        gui = self.window.get_gui()
        with gui.sub_window("taichi-lap", 0.01, 0.01, 0.24, 0.3):
            gui.text(f"frame {self.session.state.frame}  t = {self.session.state.time:.2f} s")
            for stage, ms in self.session.timings.items():
                gui.text(f"{stage}: {ms:.1f} ms")
            gui.text(f"particles {self.session.model.particle_count}  "
                     f"clusters {self.session.model.cluster_total}")
            self.paused = gui.checkbox("pause", self.paused)
            if gui.button("reset"):
                self.session.reset()
            gui.text("LMB drag: move tool, q/e: depth")
            gui.text("RMB drag + WASD: camera")

    def image(self) -> np.ndarray:
        """The rendered frame as ``(H, W, 3)`` uint8 RGB."""
        rgba = self.window.get_image_buffer_as_numpy()  # (W, H, 4) float, origin bottom-left
        rgb = np.flipud(np.transpose(rgba[:, :, :3], (1, 0, 2)))
        return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
