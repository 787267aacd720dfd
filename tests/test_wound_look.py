"""The wound's look (seed 002 §3.3, liver transection by electrocautery): surface
vertices take a char from the peak temperatures of their particles, the G-buffer
interpolates it like the normal, and shading draws charred tissue dark, dry and rough;
the "char" debug view shows it. CPU, and the char G-buffer on Vulkan."""

import functools

import numpy as np
import pytest
import taichi as ti
from taichi_lap.kernels.draw_mesh import CHAR_FULL, CHAR_START, surface_char
from taichi_lap.kernels.shading import VIEWS

from taichi_lap.core.fields import FieldGroup
from taichi_lap.dissection.removal import CUT_POINT
from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.render.renderer import BACKGROUND, Renderer
from taichi_lap.render.scene_mesh import ArrayMesh
from taichi_lap.scene import from_tables
from taichi_lap.scene.materials import CHAR_ALBEDO, CHAR_ROUGHNESS, PRESETS
from taichi_lap.session import Session
from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.helpers import BOX

BODY = 37.0  # [°C]
HOT = 120.0  # [°C] well past boiling: fully charred
SIZE = (128, 96)
MARGIN = 0.008  # [m] from the heated half's border: beyond one mesh edge


def smoothstep(a: float, b: float, x):
    t = np.clip((np.asarray(x, np.float64) - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@ti.data_oriented
class Binding:
    """Surface vertices bound to particles the way a model binds them (``surface_index``,
    ``surface_weight``; ``surface_cluster`` >= 0 for a wound vertex), the particles'
    ``peak`` temperatures and a ``char`` field with ``extra`` rows past the surface
    (where a drawn mesh keeps instruments and tubes)."""

    def __init__(self, index, weight, cluster, peak, extra: int, extra_char: float):
        self.surface_vertex_count = len(index)
        group = FieldGroup()
        self.surface_index = group.field(ti.i32, len(index), vector=4, values=index)
        self.surface_weight = group.field(ti.f32, len(index), vector=4, values=weight)
        self.surface_cluster = group.field(ti.i32, len(index), values=cluster)
        self.peak = group.field(ti.f32, len(peak), values=np.asarray(peak, np.float32))
        rows = len(index) + extra
        self.char = group.field(ti.f32, rows, values=np.full(rows, extra_char, np.float32))
        group.finalize()


def test_char_follows_the_peak_temperature_of_the_bound_particles():
    peak = [BODY, 100.0, 130.0, 75.0, HOT, 60.0, 90.0, 50.0]
    edge = (1.0 - CUT_POINT) * BODY + CUT_POINT * HOT  # a wound vertex's place on its cut edge
    rows = {  # name: (particles, weights, skinning cluster, expected char)
        "body temperature": ([0, 0, 0, 0], [1, 0, 0, 0], -1, 0.0),
        "boiled": ([1, 0, 0, 0], [1, 0, 0, 0], -1, 1.0),
        "hotter still": ([2, 0, 0, 0], [1, 0, 0, 0], -1, 1.0),
        "midway": ([3, 0, 0, 0], [1, 0, 0, 0], -1, 0.5),
        "on an edge": ([0, 4, 0, 0], [0.5, 0.5, 0, 0], -1, smoothstep(50.0, 100.0, 78.5)),
        "in a tetrahedron": ([5, 6, 7, 3], [0.25] * 4, -1, smoothstep(50.0, 100.0, 68.75)),
        "wound vertex": ([0, 4, 0, 0], [0, 0, 0, 0], 3, smoothstep(50.0, 100.0, edge)),
        "spare row": ([1, 2, 1, 2], [0, 0, 0, 0], -1, 0.0),
    }
    index = np.array([r[0] for r in rows.values()], np.int32)
    weight = np.array([r[1] for r in rows.values()], np.float32)
    cluster = np.array([r[2] for r in rows.values()], np.int32)
    binding = Binding(index, weight, cluster, peak, extra=3, extra_char=0.25)
    surface_char(binding, binding.peak, binding.char)
    char = binding.char.to_numpy()
    assert (CHAR_START, CHAR_FULL) == (50.0, 100.0)
    for (name, (_, _, _, expected)), value in zip(rows.items(), char):
        assert value == pytest.approx(expected, abs=1e-6), name
    assert (char[len(rows) :] == 0.25).all()  # rows past the surface are left alone


def luminance(image: np.ndarray) -> np.ndarray:
    return image.astype(np.float64) @ [0.2126, 0.7152, 0.0722]


@functools.cache
def wound_renders() -> dict[str, np.ndarray]:
    """The test block seen from above its top face: fresh (no peak), at body
    temperature, with its -x half heated to HOT, in the debug views, and fresh again.
    ``frame`` keys hold the renderer's float frames (GGUI layout), the rest come from
    the wound's G-buffer."""
    session = Session(from_tables([BOX], gravity=[0, 0, 0]), use_cache=False, progress=False)
    camera = EndoscopeCamera(
        eye=np.array([0.0, -0.06, 0.11]),
        target=np.array([0.0, 0.0, 0.005]),
        up=np.array([0.0, 0.0, 1.0]),
        fov=30.0,
        near=0.005,
        far=1.0,
    )
    renderer = Renderer.for_scene(session.scene, session.model, size=SIZE)
    renderer.camera = camera
    rest = session.data.rest_position
    peak = ti.field(ti.f32, len(rest))
    result = {}

    def draw(name, temperatures, view="shaded"):
        renderer.view = VIEWS.index(view)
        if temperatures is not None:
            peak.from_numpy(temperatures.astype(np.float32))
        renderer.render(session.state, session.control, None if temperatures is None else peak)
        result[f"{name} frame"] = renderer.frame.to_numpy()

    body = np.full(len(rest), BODY)
    wound = np.where(rest[:, 0] < 0.0, HOT, BODY)
    draw("fresh", None)
    result["fresh char"] = renderer.gbuffer.char.to_numpy()
    draw("body", body)
    result["body char"] = renderer.gbuffer.char.to_numpy()
    draw("fresh albedo", None, "albedo")  # the material with its surface detail
    for view in ("albedo", "roughness", "mucus", "char"):
        draw(f"wound {view}", wound, view)
    draw("wound", wound)
    result["char"] = renderer.gbuffer.char.to_numpy()
    position = renderer.gbuffer.position.to_numpy()
    to_eye = camera.eye - position
    to_eye /= np.linalg.norm(to_eye, axis=-1, keepdims=True)
    result["x"] = position[..., 0]
    result["facing"] = np.sum(renderer.gbuffer.normal.to_numpy() * to_eye, axis=-1)
    result["triangle"] = renderer.gbuffer.triangle.to_numpy()
    draw("fresh again", None)
    result["roughness"] = renderer.mesh.roughness.to_numpy()[0]
    result["mucus"] = renderer.mesh.mucus.to_numpy()[0]
    session.close()
    return result


def test_tissue_at_body_temperature_looks_as_without_temperatures():
    renders = wound_renders()
    assert (renders["body char"] == 0.0).all() and (renders["fresh char"] == 0.0).all()
    assert np.array_equal(renders["body frame"], renders["fresh frame"])
    assert np.array_equal(renders["fresh again frame"], renders["fresh frame"])


def test_heated_tissue_is_drawn_charred_and_darker():
    """Char near 1 over the heated half, 0 elsewhere; the heated half darker wherever
    it faces the scope (seen edge-on, rough char scatters the headlight back more than
    smooth wet tissue does), the rest unchanged."""
    renders = wound_renders()
    char, x, covered = renders["char"], renders["x"], renders["triangle"] >= 0
    heated, cool = covered & (x < -MARGIN), covered & (x > MARGIN)
    assert heated.sum() > 500 and cool.sum() > 500
    assert (char[heated] > 0.99).all()
    assert (char[cool] == 0.0).all() and (char[~covered] == 0.0).all()
    assert char.min() >= 0.0 and char.max() <= 1.0

    fresh, wound = luminance(renders["fresh frame"]), luminance(renders["wound frame"])
    facing = heated & (renders["facing"] > 0.2)
    assert facing.sum() > 0.8 * heated.sum()
    assert (wound[facing] < fresh[facing]).all()
    assert wound[facing].mean() < 0.6 * fresh[facing].mean()
    assert np.array_equal(renders["wound frame"][cool], renders["fresh frame"][cool])


def test_charred_material_is_dark_rough_and_dry():
    """The debug views show the blended material: the char look where char is near 1
    (within 1 % of the way back to the block's material), the block's own material
    (its albedo with its surface detail, as drawn unheated) where it is 0."""
    renders = wound_renders()
    char, covered = renders["char"], renders["triangle"] >= 0
    charred, fresh = covered & (char > 0.99), covered & (char == 0.0)
    assert charred.sum() > 500 and fresh.sum() > 500
    albedo = renders["wound albedo frame"]
    roughness = renders["wound roughness frame"][..., 0]
    mucus = renders["wound mucus frame"][..., 0]
    assert np.allclose(albedo[charred], CHAR_ALBEDO, rtol=0, atol=0.01)
    assert np.allclose(roughness[charred], CHAR_ROUGHNESS, rtol=0, atol=0.01)
    assert (mucus[charred] <= 0.01 * renders["mucus"]).all()
    assert (albedo[fresh] == renders["fresh albedo frame"][fresh]).all()
    assert (roughness[fresh] == renders["roughness"]).all()
    assert (mucus[fresh] == renders["mucus"]).all()


def test_char_view_shows_the_char_in_grey():
    renders = wound_renders()
    frame, char, covered = renders["wound char frame"], renders["char"], renders["triangle"] >= 0
    assert VIEWS[8] == "char"
    for channel in range(3):
        assert np.array_equal(frame[..., channel][covered], char[covered])
    assert np.allclose(frame[~covered], BACKGROUND)
    assert (char[covered] > 0.99).any() and (char[covered] == 0.0).any()


def char_plane() -> dict[str, np.ndarray]:
    """A quad tilted in depth whose vertex char is an affine function of position,
    drawn from the front: G-buffer char and position."""
    positions = np.array(
        [[-0.05, -0.04, -0.05], [0.05, -0.04, -0.12], [0.05, 0.04, -0.12], [-0.05, 0.04, -0.05]],
        np.float32,
    )
    mesh = ArrayMesh(
        [[0, 1, 2], [0, 2, 3]],
        np.zeros(2, np.int32),
        [PRESETS["liver"]],
        vertex_count=4,
        smooth_count=4,
        positions=positions,
    )
    mesh.char.from_numpy(affine_char(positions).astype(np.float32))
    camera = EndoscopeCamera(
        eye=np.zeros(3),
        target=np.array([0.0, 0.0, -1.0]),
        up=np.array([0.0, 1.0, 0.0]),
        fov=70.0,
        near=0.01,
        far=1.0,
    )
    renderer = Renderer(mesh, camera, size=SIZE)
    renderer.render(None, None)
    return {
        "char": renderer.gbuffer.char.to_numpy(),
        "position": renderer.gbuffer.position.to_numpy(),
        "triangle": renderer.gbuffer.triangle.to_numpy(),
    }


def affine_char(position: np.ndarray) -> np.ndarray:
    return 0.5 + 4.0 * position[..., 0] + 3.0 * position[..., 1]


def test_gbuffer_char_is_interpolated_at_the_hit_point():
    """Barycentric interpolation of an affine function of position gives its value at
    the hit point, perspective included."""
    result = char_plane()
    covered = result["triangle"] >= 0
    assert covered.sum() > 0.5 * covered.size
    expected = affine_char(result["position"].astype(np.float64))
    assert np.abs(result["char"] - expected)[covered].max() < 1e-5
    assert (result["char"][~covered] == 0.0).all()


@pytest.mark.vulkan
def test_vulkan_gives_the_char_gbuffer_of_the_cpu():
    cpu = wound_renders()
    vulkan = run_on_arch(COMPARE_ARCH, "tests.test_wound_look:wound_renders")
    assert np.array_equal(vulkan["triangle"], cpu["triangle"])
    assert np.abs(vulkan["char"] - cpu["char"]).max() < 1e-4
    assert np.abs(vulkan["wound char frame"] - cpu["wound char frame"]).max() < 1e-4
    assert np.abs(vulkan["wound frame"] - cpu["wound frame"]).max() < 1e-3
