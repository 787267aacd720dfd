"""Vessels seen through the tissue above them (kernels/subsurface.py): the tint grid
holds the nearest vessel's colour weighted by exp(-d / SUBSURFACE_DEPTH), and the
shading blends a material's albedo towards it by that weight and its ``subsurface``
(CPU and Vulkan alike)."""

import numpy as np
import pytest

from taichi_lap.render.renderer import Renderer
from taichi_lap.render.scene_mesh import ArrayMesh
from taichi_lap.render.subsurface import TINT_REACH, TintGrid, vessel_tint_grid
from taichi_lap.scene.materials import SUBSURFACE_DEPTH, Material
from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.test_render import head_on

VEIN = Material((0.2, 0.1, 0.3), 0.4, 0.0, 0.5)
ARTERY = Material((0.7, 0.1, 0.1), 0.4, 0.0, 0.5)


def test_each_node_takes_the_nearest_vessel_weighted_by_its_distance():
    """A random cloud of tissue particles and two vessels: every node of the grid
    holds exp(-d / SUBSURFACE_DEPTH) of the nearest vessel particle (brute force),
    premultiplying that vessel's albedo; nothing beyond the reach."""
    rng = np.random.default_rng(3)
    rest = np.concatenate([rng.uniform(0.0, 0.02, (300, 3)), rng.uniform(0.005, 0.015, (40, 3))])
    vein, artery = np.arange(300, 320), np.arange(320, 340)
    grid = vessel_tint_grid(rest, [np.arange(300)], [(vein, VEIN), (artery, ARTERY)])
    nodes = np.stack(
        np.meshgrid(
            *[grid.origin[k] + grid.cell * np.arange(grid.shape[k]) for k in range(3)],
            indexing="ij",
        ),
        axis=-1,
    ).reshape(-1, 3)
    assert np.all(nodes.min(axis=0) <= rest[:300].min(axis=0)) and len(nodes) == len(grid.tint)
    distance = np.linalg.norm(nodes[:, None] - rest[None, 300:], axis=2)
    nearest, d = distance.argmin(axis=1), distance.min(axis=1)
    reach = d < TINT_REACH * SUBSURFACE_DEPTH
    weight = np.where(reach, np.exp(-d / SUBSURFACE_DEPTH), 0.0)
    colour = np.where((nearest < 20)[:, None], VEIN.albedo, ARTERY.albedo)
    np.testing.assert_allclose(grid.tint[:, 3], weight, atol=1e-6)
    np.testing.assert_allclose(grid.tint[:, :3], colour * weight[:, None], atol=1e-6)
    assert reach.any() and (~reach).any()
    assert vessel_tint_grid(rest, [], [(vein, VEIN)]).tint.shape == (1, 4)  # nothing tinted


TISSUE = Material((0.5, 0.3, 0.2), 0.4, 0.0, 0.5, subsurface=0.6)
PLAIN = Material((0.5, 0.3, 0.2), 0.4, 0.0, 0.5)
TINT = np.array([0.1, 0.2, 0.6])


def tinted_albedo() -> dict[str, np.ndarray]:
    """Three squares side by side at z = 0 seen head-on in the albedo view: with
    ``subsurface`` over a grid whose weight grows linearly along x (trilinear
    interpolation reproduces it exactly), without ``subsurface`` over the same grid,
    and with it outside the grid. ``image`` and the G-buffer's ``position``."""
    squares = []
    for k in range(3):
        x0 = -0.03 + 0.021 * k
        squares.append(
            np.array(
                [[x0, -0.01, 0], [x0 + 0.018, -0.01, 0], [x0 + 0.018, 0.01, 0], [x0, 0.01, 0]],
                np.float32,
            )
        )
    positions = np.concatenate(squares)
    triangles = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * k for k in range(3)])
    material = np.array([0, 0, 1, 1, 0, 0])
    shape = np.array([9, 5, 3])  # y from -0.011 to 0.013, z from -0.001
    origin, cell = np.array([-0.031, -0.011, -0.001]), 0.006
    x = origin[0] + cell * np.arange(shape[0])
    weight = np.clip((x + 0.031) / 0.05, 0.0, 1.0)  # 0 at the left, 0.96 at x = 0.017
    tint = np.zeros((*shape, 4))
    tint[..., :3] = TINT * weight[:, None, None, None]
    tint[..., 3] = weight[:, None, None]
    mesh = ArrayMesh(
        triangles,
        material,
        [TISSUE, PLAIN],
        vertex_count=len(positions),
        smooth_count=len(positions),
        positions=positions,
        tint=TintGrid(tint.reshape(-1, 4).astype(np.float32), shape.astype(np.int32), origin, cell),
    )
    # the third square (x 0.012..0.03) reaches past the grid (x < 0.017)
    renderer = Renderer(mesh, head_on(np.array([0.0, 0.0, 0.1]), 20.0), size=(160, 60))
    renderer.view = 1
    renderer.render(None, None)
    position = np.flipud(np.transpose(renderer.gbuffer.position.to_numpy(), (1, 0, 2)))
    triangle = np.flipud(renderer.gbuffer.triangle.to_numpy().T)
    return {"image": renderer.image(), "position": position, "triangle": triangle}


def test_the_albedo_is_blended_towards_the_vessel_by_weight_and_strength():
    out = tinted_albedo()
    image, position, triangle = out["image"] / 255.0, out["position"], out["triangle"]
    base = np.array(TISSUE.albedo)
    weight = np.clip((position[..., 0] + 0.031) / 0.05, 0.0, 1.0)
    inside = position[..., 0] < 0.017 - 1e-4  # within the grid's last cell
    expected = base + (TINT - base) * (0.6 * weight)[..., None]
    first, second, third = (np.isin(triangle, [2 * k, 2 * k + 1]) for k in range(3))
    np.testing.assert_allclose(image[first], expected[first], atol=1.01 / 255)
    np.testing.assert_allclose(
        image[second], np.broadcast_to(base, image[second].shape), atol=0.51 / 255
    )
    outside = third & ~inside
    within = third & inside
    assert outside.sum() > 100 and within.sum() > 100
    np.testing.assert_allclose(
        image[outside], np.broadcast_to(base, image[outside].shape), atol=0.51 / 255
    )
    np.testing.assert_allclose(image[within], expected[within], atol=1.01 / 255)
    assert np.abs(image[first] - base).max() > 0.08  # the tint shows


@pytest.mark.vulkan
def test_vulkan_tints_like_the_cpu():
    cpu = tinted_albedo()["image"].astype(int)
    vulkan = run_on_arch(COMPARE_ARCH, "tests.test_subsurface:tinted_albedo")["image"]
    assert np.abs(cpu - vulkan.astype(int)).max() <= 1
