"""The deferred renderer as a whole: golden images of every material preset under
the headlight (CPU and Vulkan), scene materials, instruments, tubes, and the GGUI
window offscreen on Vulkan.

Refresh the golden image after a deliberate change of the look:
``python -m tests.test_render`` (writes tests/golden/materials.png).
"""

from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
import taichi as ti
import trimesh
from taichi_lap.kernels.shading import filled, srgb_encode

from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.render.renderer import Renderer
from taichi_lap.render.scene_mesh import ArrayMesh, SceneMesh
from taichi_lap.scene.materials import PRESETS
from taichi_lap.session import Session
from tests.archrun import COMPARE_ARCH, run_on_arch

GOLDEN = Path(__file__).parent / "golden" / "materials.png"
SIZE = (192, 144)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio of two uint8 images [dB]."""
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def head_on(eye, fov: float, near: float = 0.01) -> EndoscopeCamera:
    """A camera at ``eye`` [m] looking along -z, y up, of vertical ``fov`` [deg]."""
    return EndoscopeCamera(
        eye=eye,
        target=eye - np.array([0.0, 0.0, 0.1]),
        up=np.array([0.0, 1.0, 0.0]),
        fov=fov,
        near=near,
        far=1.0,
    )


def material_spheres() -> dict[str, np.ndarray]:
    """One sphere per material preset, 4 per row, seen head-on under the headlight
    and the image-based light: the rendered ``image`` (H, W, 3) uint8."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.018)
    positions, triangles, material = [], [], []
    for index in range(len(PRESETS)):
        row, column = divmod(index, 4)
        offset = np.array([0.045 * (column - 1.5), 0.045 * (1.0 - row), 0.0])
        triangles.append(sphere.faces + len(sphere.vertices) * index)
        positions.append(sphere.vertices + offset)
        material.append(np.full(len(sphere.faces), index))
    positions = np.concatenate(positions).astype(np.float32)
    mesh = ArrayMesh(
        np.concatenate(triangles),
        np.concatenate(material),
        list(PRESETS.values()),
        vertex_count=len(positions),
        smooth_count=len(positions),
        positions=positions,
    )
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.0, 0.2]), 45.0), size=SIZE)
    renderer.render(None, None)
    return {"image": renderer.image()}


def test_material_spheres_match_the_golden_image():
    image = material_spheres()["image"]
    golden = imageio.imread(GOLDEN)
    assert image.shape == golden.shape
    assert psnr(image, golden) >= 35.0


@pytest.mark.vulkan
def test_vulkan_renders_the_golden_image_like_the_cpu():
    cpu = material_spheres()["image"]
    vulkan = run_on_arch(COMPARE_ARCH, "tests.test_render:material_spheres")["image"]
    assert psnr(cpu, vulkan) >= 35.0


def test_every_preset_is_drawn_in_its_own_colour():
    """A pixel on each sphere, away from the highlight at its centre, is lit (not
    background), and presets of different albedo give different pixels."""
    image = material_spheres()["image"].astype(int)
    height, width = image.shape[:2]
    centres = []
    for index in range(len(PRESETS)):
        row, column = divmod(index, 4)
        # the sphere centres project 0.045 m apart at 0.2 m with a 45° field of view
        scale = height / (2 * 0.2 * np.tan(np.radians(22.5)))
        x = int(width / 2 + scale * (0.045 * (column - 1.5) - 0.008))
        y = int(height / 2 - scale * (0.045 * (1.0 - row) - 0.008))
        centres.append(image[y, x])
    centres = np.array(centres)
    assert (centres.sum(axis=1) > 60).all(), centres
    albedo = np.array([m.albedo for m in PRESETS.values()])
    for a in range(len(PRESETS)):
        for b in range(a):
            if np.abs(albedo[a] - albedo[b]).max() > 0.05:
                assert np.abs(centres[a] - centres[b]).max() >= 4, (a, b)


@ti.kernel
def encode_srgb(values: ti.types.ndarray(), out: ti.types.ndarray()):
    for k in range(values.shape[0]):
        out[k] = srgb_encode(values[k])


def test_srgb_encoding_is_within_a_quarter_level_of_the_standard_curve():
    x = np.linspace(0.0, 1.0, 100_001).astype(np.float32)
    out = np.zeros_like(x)
    encode_srgb(x, out)
    exact = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x.astype(np.float64) ** (1 / 2.4) - 0.055)
    assert np.abs(out - exact).max() * 255.0 <= 0.26


def small_session(name: str, overrides: dict | None = None) -> Session:
    """A session of built-in scene ``name`` at detail 0.05, with more ``overrides``."""
    from taichi_lap import scene as scene_mod

    settings = {"scene.detail": 0.05, **(overrides or {})}
    return Session(scene_mod.load(name, settings), progress=False)


def test_organs_get_their_appearance_and_colour():
    session = small_session("rectum")
    mesh = SceneMesh(session.scene, session.model)
    albedo = mesh.albedo.to_numpy()
    for index, organ in enumerate(session.scene.organs):
        expected = organ.color if organ.color is not None else PRESETS[organ.appearance].albedo
        assert np.allclose(albedo[index], expected)
    assert np.allclose(albedo[len(session.scene.organs)], PRESETS["metal"].albedo)


def objects_seen(renderer: Renderer) -> set[int]:
    triangles = renderer.gbuffer.triangle.to_numpy()
    objects = renderer.mesh.triangle_object.to_numpy()
    return set(objects[triangles[triangles >= 0]].tolist())


def test_instrument_is_drawn_where_its_shapes_are_and_hidden_when_inactive():
    session = small_session("rectum")
    renderer = Renderer.for_scene(session.scene, session.model, size=(160, 120))
    tool_object = len(session.data.organs)
    tip = session.control.tool_a[0].to_numpy()
    renderer.camera.target = tip  # look straight at the tool tip
    renderer.render(session.state, session.control)
    assert tool_object in objects_seen(renderer)
    triangle = renderer.gbuffer.triangle[80, 60]
    assert renderer.mesh.triangle_object[triangle] == tool_object
    depth = renderer.gbuffer.depth[80, 60]
    assert abs(depth - np.linalg.norm(tip - renderer.camera.eye)) < 0.02
    tail, radius = session.control.tool_b[0].to_numpy(), session.control.tool_radius[0]
    session.control.set_tool(0, tip, tail, radius, active=False)
    renderer.render(session.state, session.control)
    assert tool_object not in objects_seen(renderer)


def test_intestine_is_drawn_as_a_generalized_cylinder():
    session = small_session("intestine")
    renderer = Renderer.for_scene(session.scene, session.model, size=(160, 120))
    renderer.render(session.state, session.control)
    mesh = renderer.mesh
    first_tube_triangle = mesh.tube_offsets[0][1] // 3
    triangles = renderer.gbuffer.triangle.to_numpy()
    objects = mesh.triangle_object.to_numpy()
    intestine = mesh.object_names.index("intestine")
    tube_pixels = (triangles >= first_tube_triangle) & (objects[triangles] == intestine)
    assert tube_pixels.sum() > 500
    normals = renderer.gbuffer.normal.to_numpy()[triangles >= 0]
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-3)


def test_the_planned_plane_of_the_task_is_marked_dashed_on_its_organ_only():
    """The liver task's planned line: the pixels the mark changed show the liver within
    the mark's half width of the plane, beside the line, on the dashes only; thick
    cautery smoke hides it as it hides the tissue."""
    from taichi_lap.kernels.shading import MARK_DASH, MARK_HALF_WIDTH

    session = small_session("liver")
    renderer = Renderer.for_scene(session.scene, session.model, size=(320, 240))
    renderer.distortion = renderer.vignetting = 0.0  # pixels as the G-buffer's
    renderer.render(session.state, session.control)
    marked = renderer.image()
    organ, plane = renderer.planned
    renderer.planned = None
    renderer.render(session.state, session.control)
    changed = np.any(marked != renderer.image(), axis=2)
    at = np.flipud(changed).T  # image rows, top first -> G-buffer [x, y]
    assert at.sum() > 30
    triangles = renderer.gbuffer.triangle.to_numpy()[at]
    assert (renderer.mesh.triangle_object.to_numpy()[triangles] == organ).all()
    points = renderer.gbuffer.position.to_numpy()[at].astype(np.float64)
    assert plane.distance(points).max() < MARK_HALF_WIDTH + 1e-6
    along = (points - plane.start) @ plane.along
    assert along.min() >= -1e-6 and along.max() <= plane.length + 1e-6
    assert (np.mod(along, MARK_DASH) < 0.6 * MARK_DASH + 1e-6).all()
    renderer.smoke = 1e4  # nothing but smoke
    renderer.render(session.state, session.control)
    veiled = renderer.image()
    renderer.planned = (organ, plane)
    renderer.render(session.state, session.control)
    assert np.array_equal(renderer.image(), veiled)


def window_screenshot() -> dict[str, np.ndarray]:
    """A scene drawn into an offscreen GGUI window: its screenshot and the
    renderer's own image."""
    from taichi_lap.viewer import Viewer

    # unsettled: the window shows what the renderer drew, whatever the organs' shape
    session = small_session("rectum", {"scene.settle_time": 0.0})
    viewer = Viewer(
        session,
        Renderer.for_scene(session.scene, session.model, size=(160, 120)),
        show_window=False,
    )
    viewer.draw()
    rgba = viewer.window.get_image_buffer_as_numpy()  # (W, H, 4) float, origin bottom-left
    rgb = np.flipud(np.transpose(rgba[:, :, :3], (1, 0, 2)))
    screenshot = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return {"screenshot": screenshot, "image": viewer.renderer.image()}


@pytest.mark.vulkan
def test_offscreen_window_shows_the_rendered_scene():
    result = run_on_arch("vulkan", "tests.test_render:window_screenshot")
    screenshot = result["screenshot"]
    assert screenshot.std() > 10.0, "blank screenshot"
    assert psnr(screenshot, result["image"]) >= 30.0


def test_automatic_exposure_follows_the_square_of_the_views_depth_and_adapts():
    """The same view twice as large and as far (every depth doubled) gets a quarter of
    the headlight's light: automatic exposure exposes it four times as much (the depth
    bins are octave fractions, so exactly), and after a jump of the view it
    approaches the new exposure frame by frame."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)

    def mesh(scale):
        return ArrayMesh.of_material(
            sphere.faces, np.asarray(sphere.vertices * scale, np.float32), PRESETS["liver"]
        )

    def camera(distance):
        return head_on(np.array([0.0, 0.0, distance]), 30.0, 0.01 * distance)

    near = Renderer(mesh(1.0), camera(0.1), size=(64, 48), exposure=2.0, auto_exposure=True)
    far = Renderer(mesh(2.0), camera(0.2), size=(64, 48), exposure=2.0, auto_exposure=True)
    near.render(None, None)
    far.render(None, None)
    first_near, first_far = near.params.exposure[None], far.params.exposure[None]
    assert first_far / first_near == pytest.approx(4.0, rel=1e-5)
    near.camera = camera(0.3)  # the view jumps back
    fresh = Renderer(mesh(1.0), camera(0.3), size=(64, 48), exposure=2.0, auto_exposure=True)
    fresh.render(None, None)
    target = fresh.params.exposure[None]
    steps = []
    for _ in range(20):  # 0.75^20: within 1 % of a 27-fold jump
        near.render(None, None)
        steps.append(near.params.exposure[None])
    assert target > 2.0 * first_near
    assert np.all(np.diff(steps) > 0) and steps[0] < first_near + 0.5 * (target - first_near)
    assert steps[-1] == pytest.approx(target, rel=0.05)


def test_surface_detail_moves_with_the_tissue_not_with_space():
    """The albedo view of a liver-textured sphere moved 3 cm (and the camera with it)
    is the unmoved one's when its texcoords stay its rest positions, and another
    pattern when they follow it through space (as world-space texturing would)."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    rest = np.asarray(sphere.vertices, np.float32)
    offset = np.array([0.03, -0.01, 0.02], np.float32)

    def albedo(positions, texcoords, eye):
        mesh = ArrayMesh.of_material(sphere.faces, positions, PRESETS["liver"], texcoords)
        renderer = Renderer(mesh, head_on(eye, 40.0), size=(96, 96))
        renderer.view = 1  # albedo
        renderer.render(None, None)
        return renderer.frame.to_numpy(), renderer.gbuffer.triangle.to_numpy() >= 0

    eye = np.array([0.0, 0.0, 0.1])
    still, covered = albedo(rest, rest, eye)
    moved, moved_covered = albedo(rest + offset, rest, eye + offset)
    swum, _ = albedo(rest + offset, rest + offset, eye + offset)
    both = covered & moved_covered
    assert both.sum() > 0.9 * covered.sum() > 2000
    assert np.quantile(np.abs(moved - still)[both], 0.99) < 1.0 / 255.0
    assert np.abs(swum - still)[both].mean() > 10.0 * np.abs(moved - still)[both].mean() + 0.005


def test_the_lens_bends_each_pixels_ray_radially_and_darkens_the_corners():
    """Through the lens (G-buffer resolve), the pixel at radius r (of the half-diagonal)
    shows the point of a wall facing the scope that the rectilinear ray at r (1 + k r²)
    meets, scaled to keep the middles of the side edges; at the corners, past the
    rectilinear image, nothing; vignetting alone scales the shaded image by 1 - v r²."""
    width, height, fov, k = 64, 48, 60.0, 0.1
    wall = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    mesh = ArrayMesh.of_material(
        np.array([[0, 1, 2], [0, 2, 3]]), wall.astype(np.float32), PRESETS["liver"]
    )
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.0, 0.1]), fov), size=(width, height))
    renderer.distortion = k
    renderer.render(None, None)
    x, y = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    half = np.array([width, height]) / 2.0
    ndc = (np.stack([x, y], -1) + 0.5) / half - 1.0
    r2 = ((ndc * half) ** 2).sum(-1) / (half**2).sum()
    scale = 1.0 / (1.0 + k * (half[0] ** 2 / (half**2).sum()))
    bent = ndc * (scale * (1.0 + k * r2))[..., None]
    inside = (np.abs(bent) < 1.0).all(-1)
    assert inside.mean() > 0.9 and not inside.all()
    reach = 0.1 * np.tan(np.radians(fov / 2.0)) * np.array([width / height, 1.0])
    shown = renderer.gbuffer.position.to_numpy()[..., :2]
    assert np.allclose(shown[inside], (bent * reach)[inside], atol=1e-6)
    assert (renderer.gbuffer.triangle.to_numpy()[~inside] == -1).all()
    renderer.distortion = 0.0
    renderer.render(None, None)
    plain = renderer.frame.to_numpy()
    renderer.vignetting = 0.35
    renderer.render(None, None)
    assert np.allclose(renderer.frame.to_numpy(), plain * (1.0 - 0.35 * r2)[..., None], atol=1e-6)


def test_a_changed_lens_is_looked_up_anew():
    """The G-buffer's lens lookup follows the lens: a renderer that drew through one
    distortion and then another draws what a new renderer draws through the second."""
    wall = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    mesh = ArrayMesh.of_material(
        np.array([[0, 1, 2], [0, 2, 3]]), wall.astype(np.float32), PRESETS["liver"]
    )
    camera = head_on(np.array([0.0, 0.0, 0.1]), 60.0)
    drawn = []
    for distortions in ((0.05, 0.3), (0.3,)):
        renderer = Renderer(mesh, camera, size=(64, 48))
        for k in distortions:
            renderer.distortion = k
            renderer.render(None, None)
        drawn.append((renderer.gbuffer.position.to_numpy(), renderer.gbuffer.triangle.to_numpy()))
    assert np.array_equal(drawn[0][1], drawn[1][1]) and (drawn[0][1] == -1).sum() > 50
    assert np.array_equal(drawn[0][0], drawn[1][0])


def test_cautery_smoke_thickens_to_its_balance_thins_by_half_and_veils_the_view():
    """Under steady cautery the smoke settles where it thickens as fast as it thins
    (rate × half-life / ln 2); a half-life later, the hook off, half is left. Drawn,
    it pulls every pixel towards the smoke's grey (none away), the more the thicker
    it is."""
    from taichi_lap.render.renderer import SMOKE_HALF_LIFE, SMOKE_RATE

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    mesh = ArrayMesh.of_material(
        sphere.faces, np.asarray(sphere.vertices, np.float32), PRESETS["liver"]
    )
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.0, 0.1]), 40.0), size=(64, 48), smoke=1.0)
    dt = 1.0 / 600.0
    for _ in range(18000):  # 30 s of cautery in small steps
        renderer.update_smoke(True, dt)
    balance = SMOKE_RATE * SMOKE_HALF_LIFE / np.log(2.0)
    assert renderer.smoke == pytest.approx(balance, rel=2e-3)  # less dt's rounding
    for _ in range(round(SMOKE_HALF_LIFE / dt)):
        renderer.update_smoke(False, dt)
    assert renderer.smoke == pytest.approx(balance / 2.0, rel=1e-3)
    images = []
    for density in (0.0, 5.0, 20.0):
        renderer.smoke = density
        renderer.render(None, None)
        images.append(renderer.frame.to_numpy())
    renderer.smoke = 1e4  # nothing but smoke
    renderer.render(None, None)
    grey = renderer.frame.to_numpy()
    covered = renderer.gbuffer.triangle.to_numpy() >= 0
    away = [np.abs(image - grey).sum(-1)[covered] for image in images]
    for thin, thick in zip(away, away[1:]):  # (a saturated highlight may stay white)
        assert (thick <= thin).all() and thick.mean() < 0.8 * thin.mean()


@ti.kernel
def filled_pixels(gbuffer: ti.template(), materials: ti.template(), out: ti.types.ndarray()):
    for x, y in gbuffer.triangle:
        out[x, y] = 1 if filled(gbuffer, materials, x, y) else 0


def test_checkerboard_shading_fills_only_smooth_pixels_from_their_shaded_neighbours():
    """Checkerboard shading (the scenes' default) on the intestine's loops: the pixels
    it fills have odd x + y, lie inside the border and show the object their four
    neighbours show; each is the mean of its neighbours, every other pixel is shaded
    exactly as at full rate, and the image stays within 40 dB of full rate."""
    session = small_session("intestine")
    renderer = Renderer.for_scene(session.scene, session.model, size=(192, 144))
    renderer.auto_exposure, renderer.distortion, renderer.vignetting = False, 0.0, 0.0
    renderer.target = None  # the task target's outline is drawn over the filled image
    images = {}
    for checkerboard in (False, True):
        renderer.checkerboard = checkerboard
        renderer.render(session.state, session.control)
        images[checkerboard] = renderer.frame.to_numpy()
    marks = np.zeros((192, 144), np.int32)
    filled_pixels(renderer.gbuffer, renderer.mesh, marks)
    chosen = marks == 1
    triangles = renderer.gbuffer.triangle.to_numpy()
    objects = np.where(triangles >= 0, renderer.mesh.triangle_object.to_numpy()[triangles], -1)
    x, y = np.nonzero(chosen)
    assert 0.3 < chosen.mean() <= 0.5
    assert np.all((x + y) % 2 == 1) and x.min() > 0 and y.min() > 0
    assert x.max() < 191 and y.max() < 143
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        assert np.array_equal(objects[x + dx, y + dy], objects[x, y])
        assert not chosen[x + dx, y + dy].any()
    full, half = images[False], images[True]
    assert np.array_equal(half[~chosen], full[~chosen])
    mean = sum(full[x + dx, y + dy] for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))) / 4.0
    assert np.allclose(half[x, y], mean, atol=1e-6)
    to_bytes = lambda image: np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
    assert psnr(to_bytes(half), to_bytes(full)) >= 40.0


if __name__ == "__main__":
    from taichi_lap import runtime

    runtime.init("cpu", threads=2)
    GOLDEN.parent.mkdir(exist_ok=True)
    imageio.imwrite(GOLDEN, material_spheres()["image"])
    print(f"wrote {GOLDEN}")


def test_a_view_target_is_outlined_where_it_shows():
    """Two squares side by side, objects 0 and 1; with object 1 the view target, the
    pixels of it within TARGET_OUTLINE pixels (along the axes) of a pixel that does
    not show it turn towards the marker's green, and no other pixel changes. The
    intestine scene's renderer outlines its task's target, the colon."""
    from taichi_lap.kernels.shading import TARGET_OUTLINE
    from taichi_lap.scene.planned_plane import MARK_COLOUR

    squares = [
        np.array([[x, -0.01, 0.0], [x + 0.018, -0.01, 0.0], [x + 0.018, 0.01, 0.0], [x, 0.01, 0.0]])
        for x in (-0.02, 0.001)
    ]
    positions = np.concatenate(squares).astype(np.float32)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    mesh = ArrayMesh(
        triangles,
        np.zeros(4, np.int32),
        [PRESETS["liver"]],
        vertex_count=8,
        smooth_count=8,
        positions=positions,
        triangle_object=np.array([0, 0, 1, 1]),
    )
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.0, 0.08]), 20.0), size=(160, 80))
    renderer.render(None, None)
    plain = renderer.image().astype(float)
    renderer.target = 1
    renderer.render(None, None)
    outlined = renderer.image().astype(float)
    triangle = np.flipud(renderer.gbuffer.triangle.to_numpy().T)
    target = np.isin(triangle, [2, 3])
    edge = np.zeros_like(target)
    padded = np.pad(target, TARGET_OUTLINE, constant_values=False)
    height, width = target.shape
    for step in range(1, TARGET_OUTLINE + 1):
        for dy, dx in ((0, step), (0, -step), (step, 0), (-step, 0)):
            shifted = padded[
                TARGET_OUTLINE + dy : TARGET_OUTLINE + dy + height,
                TARGET_OUTLINE + dx : TARGET_OUTLINE + dx + width,
            ]
            edge |= target & ~shifted
    changed = np.abs(outlined - plain).max(axis=2) > 0
    assert edge.sum() > 100 and (target & ~edge).sum() > 100
    assert not (changed & ~edge).any()  # nothing but the target's outline changes
    green = np.array(MARK_COLOUR) * 255.0
    closer = np.linalg.norm(outlined - green, axis=2) < np.linalg.norm(plain - green, axis=2)
    assert closer[edge].all()

    session = small_session("intestine")
    scene_renderer = Renderer.for_scene(session.scene, session.model, size=(64, 48))
    assert scene_renderer.mesh.object_names[scene_renderer.target] == "colon"
