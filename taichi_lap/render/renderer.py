"""The deferred renderer (seed 000 §6.3): scene mesh → visibility buffer and
G-buffer (:mod:`taichi_lap.kernels.raster`) → shading with the headlight and
image-based lighting (:mod:`taichi_lap.kernels.shading`) → an RGB frame, shown by
GGUI's ``canvas.set_image`` or written to PNG/MP4. The same kernels run on the
CPU, Vulkan and CUDA backends."""

from __future__ import annotations

import math
import time

import numpy as np
import taichi as ti

from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, padded_rows
from taichi_lap.kernels.ibl import ImageLighting
from taichi_lap.kernels.raster import (
    GBuffer,
    camera_matrices,
    count_object_pixels,
    gather_object_triangles,
)
from taichi_lap.kernels.shading import (
    DEPTH_BINS,
    DEPTH_BINS_PER_OCTAVE,
    depth_histogram,
    fill_checkerboard,
    mark_plane,
    outline_target,
    shade,
)
from taichi_lap.render.blood import DRIP_FILM, DROP_RADIUS, BloodFilm
from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.render.scene_mesh import SceneMesh
from taichi_lap.scene.planned_plane import PlannedPlane

BACKGROUND = (0.02, 0.008, 0.006)
EXPOSURE_DISTANCE = 0.3
"""[m] The depth at which the headlight's light is exposed as set (``exposure``): with
automatic exposure a view whose depth (:data:`EXPOSURE_QUANTILE`) is d is exposed
(d / this)² as much, as the headlight's inverse-square light asks (a laparoscope's
camera adapts so)."""
EXPOSURE_QUANTILE = 0.25
"""The depth automatic exposure exposes for: the nearest quarter of the image (the
tissue worked on, nearer than the cavity's wall behind it)."""
EXPOSURE_ADAPTATION = 0.25
"""Fraction of the way (in log exposure) towards the view's exposure taken per frame:
after a jump of the view the image settles in about ten frames."""
SMOKE_RATE = 2.0
"""[1/m per s] How fast an energised hook's smoke thickens in front of the scope (at
``[camera] smoke`` = 1): under steady cautery it settles at 4.3/m (rate × half-life
/ ln 2), veiling tissue 10 cm away by a third."""
SMOKE_HALF_LIFE = 1.5
"""[s] The smoke thins by half in this time (insufflation carries it off)."""
SMOKE_MAX = 8.0
"""[1/m] The thickest smoke."""
MAX_DRAWN_DROPS = 32
"""Falling drops of blood drawn at most (the nearest to the eye; each costs a sphere
test per pixel while drops fall)."""


@ti.data_oriented
class ShadingParams:
    """0-D fields the shading kernel reads: the camera (``eye``, ``forward`` [m]),
    the headlight (``intensity`` [W/sr], cone cosines), IBL scale ``ambient``,
    ``exposure``, ``far`` [m], the ``smoke`` density [1/m], the lens's ``vignetting``
    and the ``background`` colour; declared in the renderer's ``group``."""

    def __init__(self, group: FieldGroup):
        self.eye = group.field(ti.f32, None, vector=3)
        self.forward = group.field(ti.f32, None, vector=3)
        self.background = group.field(ti.f32, None, vector=3)
        for name in (
            "intensity",
            "cos_inner",
            "cos_outer",
            "ambient",
            "exposure",
            "far",
            "smoke",
            "vignetting",
        ):
            setattr(self, name, group.field(ti.f32, None))


_lighting: tuple | None = None
"""The Taichi program and the image-based lighting its renderers share."""


def shared_lighting() -> ImageLighting:
    """The cavity's image-based lighting (:class:`ImageLighting`), computed once per
    Taichi program and shared by every renderer in it: one SNode tree and one
    precomputation per program instead of one of each per renderer."""
    global _lighting
    program = ti.lang.impl.get_runtime().prog
    if _lighting is None or _lighting[0] is not program:
        _lighting = (program, ImageLighting())
    return _lighting[1]


class Renderer:
    """Renders a mesh (a :class:`SceneMesh` or anything with its fields and an
    ``update(state, control, peak)``) from an :class:`EndoscopeCamera` into ``frame``
    (``(width, height)`` vec3 field, GGUI layout). ``timings`` holds the last
    frame's milliseconds per pass."""

    def __init__(
        self,
        mesh,
        camera: EndoscopeCamera,
        *,
        size=(640, 480),
        headlight: float = 0.15,
        ambient: float = 0.06,
        exposure: float = 1.0,
        spot_angle: float = 50.0,
        auto_exposure: bool = False,
        distortion: float = 0.0,
        vignetting: float = 0.0,
        smoke: float = 0.0,
        checkerboard: bool = False,
        gravity=(0.0, -9.81, 0.0),
    ):
        self.width, self.height = size
        self.mesh = mesh
        self.camera = camera
        self.gbuffer = GBuffer(self.width, self.height)
        self.lighting = shared_lighting()
        group = FieldGroup()  # one SNode tree: parameters, image, histogram, drops
        self.params = ShadingParams(group)
        self.frame = group.field(ti.f32, self.width, vector=3, columns=self.height)
        self._depths = group.field(ti.i32, DEPTH_BINS) if auto_exposure else None
        self._drop_centre = group.field(ti.f32, MAX_DRAWN_DROPS, vector=3)
        self._drop_triangle = group.field(ti.i32, MAX_DRAWN_DROPS)
        group.finalize()
        self.params.intensity[None] = headlight
        self.params.cos_inner[None] = math.cos(math.radians(0.6 * spot_angle))
        self.params.cos_outer[None] = math.cos(math.radians(spot_angle))
        self.params.ambient[None] = ambient
        self.params.exposure[None] = exposure
        self.exposure, self.auto_exposure = exposure, auto_exposure
        self._adapted = None  # the exposure automatic exposure reached (None: none yet)
        self.distortion, self.vignetting = distortion, vignetting  # the lens (0 0: none)
        self.params.background[None] = BACKGROUND
        self.checkerboard = checkerboard  # shade half the smooth pixels, fill the rest
        self.blood = BloodFilm(gravity)  # bleeds of damaged vessels, drawn on the surface
        self.smoke_rate, self.smoke = smoke * SMOKE_RATE, 0.0  # [1/m per s], [1/m]
        self.view = 0
        self.planned: tuple[int, PlannedPlane] | None = None  # (organ, plane) to mark
        self.target: int | None = None  # the object index of a view target to outline
        self.timings: dict[str, float] = {}
        self._alone = None  # view_of's G-buffer and triangle list, made at its first call
        self._matrix = None  # the last frame's view-projection

    @classmethod
    def for_scene(cls, scene, model, *, size=(640, 480)) -> "Renderer":
        """The renderer of a scene: the organs of its ``model``, tubes and instruments
        seen from its camera, with its task's planned transection marked and its view
        target outlined."""
        renderer = cls(
            SceneMesh(scene, model),
            EndoscopeCamera.from_scene(scene.camera),
            size=size,
            exposure=scene.camera["exposure"],
            auto_exposure=scene.camera["auto_exposure"],
            distortion=scene.camera["distortion"],
            vignetting=scene.camera["vignetting"],
            smoke=scene.camera["smoke"],
            checkerboard=scene.camera["checkerboard"],
            gravity=scene.settings["gravity"],
        )
        plane = scene.task["plane"] if scene.task else None
        if plane is not None:
            organ = [organ.name for organ in scene.organs].index(plane["organ"])
            renderer.planned = (organ, PlannedPlane(plane))
        view = scene.task["view"] if scene.task else None
        if view is not None:
            renderer.target = renderer.mesh.object_names.index(view["target"])
        return renderer

    def render(self, state, control, peak=None):
        """Draw ``state`` (deformed surfaces) and ``control`` (instruments); with
        ``peak``, the particles' peak temperatures [°C], heated tissue is drawn
        charred (the wound's look), without it all tissue is fresh."""
        marks = [time.perf_counter()]
        if self.mesh.outgrown:
            self.mesh = self.mesh.rebuilt()
        self.mesh.update(state, control, peak)
        ti.sync()
        marks.append(time.perf_counter())
        cam = self.camera
        view, projection = camera_matrices(
            cam.eye, cam.target, cam.up, cam.fov, self.width / self.height, cam.near, cam.far
        )
        self._matrix = projection @ view
        self.gbuffer.render(
            self.mesh.positions,
            self.mesh.normals,
            self.mesh.char,
            self.mesh.blood,
            self.mesh.triangles,
            self.mesh.triangle_object,
            self.mesh.one_sided,
            self.mesh.triangle_count,
            cam.eye,
            self._matrix,
            cam.near,
            self.distortion,
        )
        self._draw_drops()
        ti.sync()
        marks.append(time.perf_counter())
        self.params.eye[None] = cam.eye
        self.params.forward[None] = cam.axes()[0]
        self.params.far[None] = cam.far
        self.params.smoke[None] = self.smoke
        self.params.vignetting[None] = self.vignetting
        if self.auto_exposure:
            self.params.exposure[None] = self._adapt_exposure(cam.near)
        checkerboard = self.checkerboard and self.view == 0
        shade(
            self.gbuffer, self.mesh, self.lighting, self.params, self.frame, self.view, checkerboard
        )
        if checkerboard:
            fill_checkerboard(self.frame)
        if self.planned is not None and self.view == 0:
            organ, plane = self.planned
            mark_plane(
                self.gbuffer,
                self.mesh,
                self.frame,
                organ,
                plane.point,
                plane.normal,
                plane.start,
                plane.along,
                plane.length,
                self.smoke,
            )
        if self.target is not None and self.view == 0:
            outline_target(self.gbuffer, self.mesh, self.frame, self.target, self.smoke)
        ti.sync()
        marks.append(time.perf_counter())
        for name, a, b in zip(("vertex", "visibility", "shading"), marks, marks[1:]):
            self.timings[name] = (b - a) * 1e3

    def _draw_drops(self):
        """The blood's falling drops (:meth:`BloodFilm.in_flight`), the nearest
        :data:`MAX_DRAWN_DROPS` to the eye, into the G-buffer as spheres of blood
        (:data:`~taichi_lap.render.blood.DROP_RADIUS`) that the shading draws wet."""
        centres, triangles = self.blood.in_flight()
        if not len(centres):
            return
        nearest = np.argsort(np.linalg.norm(centres - self.camera.eye, axis=1))
        nearest = nearest[:MAX_DRAWN_DROPS]
        fields.write(
            [
                (self._drop_centre, padded_rows(centres[nearest], MAX_DRAWN_DROPS)),
                (self._drop_triangle, padded_rows(triangles[nearest], MAX_DRAWN_DROPS)),
            ]
        )
        self.gbuffer.add_spheres(
            self._drop_centre,
            self._drop_triangle,
            len(nearest),
            DROP_RADIUS,
            DRIP_FILM,
            self.camera.eye,
            self._matrix,
            self.distortion,
        )

    def update_smoke(self, cauterising: bool, dt: float):
        """Cautery smoke over ``dt`` [s]: it thickens by the smoke rate while some hook
        is energised (``cauterising``), up to :data:`SMOKE_MAX`, and thins by half every
        :data:`SMOKE_HALF_LIFE`."""
        grown = self.smoke + (self.smoke_rate * dt if cauterising else 0.0)
        self.smoke = min(grown, SMOKE_MAX) * 0.5 ** (dt / SMOKE_HALF_LIFE)

    def update_blood(self, events: list[dict], state, data, time: float, dt: float):
        """After a stepped frame ending at ``time`` [s]: bleeds from its
        ``vessel_damage`` events and the blood film over ``dt`` [s]
        (:meth:`BloodFilm.update`)."""
        if self.mesh.outgrown:
            self.mesh = self.mesh.rebuilt()
        self.blood.update(events, state, data, time, dt, self.mesh)

    def _adapt_exposure(self, near: float) -> float:
        """The exposure of this frame with automatic exposure: ``exposure`` × (the
        depth of the nearest :data:`EXPOSURE_QUANTILE` of the image /
        :data:`EXPOSURE_DISTANCE`)², approached by :data:`EXPOSURE_ADAPTATION` per frame
        from the last one (reached at once in the first frame)."""
        depth_histogram(self.gbuffer, self._depths, near)
        counts = np.cumsum(self._depths.to_numpy())
        if counts[-1] == 0:  # nothing drawn: keep what was reached
            return self._adapted or self.exposure
        nearest = int(np.searchsorted(counts, counts[-1] * EXPOSURE_QUANTILE))
        depth = near * 2.0 ** ((nearest + 0.5) / DEPTH_BINS_PER_OCTAVE)
        target = self.exposure * (depth / EXPOSURE_DISTANCE) ** 2
        if self._adapted is None:
            self._adapted = target
        self._adapted *= (target / self._adapted) ** EXPOSURE_ADAPTATION
        return self._adapted

    def view_of(self, name: str) -> tuple[float, float]:
        """How the last frame shows object ``name`` (an organ, tool or environment
        tube), from the object-id image: ``(visible, share)``, the fraction of the pixels
        it would cover if nothing hid it that show it (its triangles drawn alone, same
        camera), and the fraction of the image it fills; ``(0, 0)`` out of view."""
        target = self.mesh.object_names.index(name)
        capacity = 3 * self.mesh.triangle_count
        if self._alone is None or self._alone[1].shape[0] < capacity:
            group = FieldGroup()
            triangles, count = group.field(ti.i32, capacity), group.field(ti.i32, None)
            objects = group.field(ti.i32, self.mesh.triangle_count)
            group.finalize()
            self._alone = (GBuffer(self.width, self.height), triangles, objects, count, group)
        alone, triangles, objects, count, _ = self._alone
        mesh = self.mesh
        gather_object_triangles(
            mesh.triangles,
            mesh.triangle_object,
            mesh.triangle_count,
            target,
            triangles,
            objects,
            count,
        )
        cam = self.camera
        alone.render(
            mesh.positions,
            mesh.normals,
            mesh.char,
            mesh.blood,
            triangles,
            objects,
            mesh.one_sided,
            int(count[None]),
            cam.eye,
            self._matrix,
            cam.near,
            self.distortion,
        )
        shown = int(count_object_pixels(self.gbuffer.triangle, mesh.triangle_object, target)[0])
        unhidden = int(count_object_pixels(alone.triangle, mesh.triangle_object, -1)[1])
        if unhidden == 0:
            return 0.0, 0.0
        return min(shown / unhidden, 1.0), shown / (self.width * self.height)

    def image(self) -> np.ndarray:
        """The last frame as ``(height, width, 3)`` uint8 RGB, top row first."""
        rgb = np.flipud(np.transpose(self.frame.to_numpy(), (1, 0, 2)))
        return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
