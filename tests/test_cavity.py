"""The body cavity around each scene (``[environment.cavity]`` and the planes drawn
as tissue): a closed wall around its centre, discs in their planes, checked names,
a drawn look that does not change the physics' key, and, from every built-in
scene's default endoscope, no pixel of empty background."""

import numpy as np
import pytest
import trimesh

from taichi_lap import scene as scene_mod
from taichi_lap.core.errors import InputError
from taichi_lap.render.camera import EndoscopeCamera
from taichi_lap.render.renderer import Renderer
from taichi_lap.render.scene_mesh import ArrayMesh, environment_arrays
from taichi_lap.scenes.anatomy.cavity import cavity_wall, plane_patch
from taichi_lap.session import session_key


def winding_number(vertices, triangles, point) -> float:
    """How many times the closed surface winds round ``point`` (1 inside, 0 outside):
    the triangles' solid angles (Van Oosterom and Strackee 1983) over 4π."""
    a, b, c = (vertices[triangles[:, k]] - point for k in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    numerator = np.einsum("ij,ij->i", a, np.cross(b, c))
    denominator = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", b, c) * la
        + np.einsum("ij,ij->i", c, a) * lb
    )
    return abs(float(np.sum(2.0 * np.arctan2(numerator, denominator)))) / (4.0 * np.pi)


def test_the_wall_is_closed_around_its_centre_within_its_relief():
    center, radii, relief = np.array([0.01, -0.02, 0.03]), np.array([0.2, 0.1, 0.15]), 0.1
    wall = cavity_wall(center, radii, relief)
    mesh = trimesh.Trimesh(wall.vertices, wall.triangles, process=False)
    assert mesh.is_watertight
    assert winding_number(wall.vertices, wall.triangles, center) == pytest.approx(1.0)
    # every vertex on the ellipsoid scaled by 1 ± relief along its direction
    scale = np.linalg.norm((wall.vertices - center) / radii, axis=1)
    assert scale.min() >= 1.0 - relief - 1e-9 and scale.max() <= 1.0 + relief + 1e-9
    assert scale.max() - scale.min() > relief  # it bulges both ways
    flat = cavity_wall(center, radii, 0.0)
    assert np.allclose(np.linalg.norm((flat.vertices - center) / radii, axis=1), 1.0)


def test_a_plane_patch_is_a_disc_in_its_plane_around_its_point():
    point, normal = np.array([0.0, -0.04, 0.01]), np.array([0.0, 2.0, 1.0])
    patch = plane_patch(point, normal, 0.3)
    unit = normal / np.linalg.norm(normal)
    assert np.abs((patch.vertices - point) @ unit).max() < 1e-12
    assert np.allclose(np.linalg.norm(patch.vertices[1:] - point, axis=1), 0.3)
    area = trimesh.Trimesh(patch.vertices, patch.triangles, process=False).area
    assert area == pytest.approx(np.pi * 0.3**2, rel=0.01)


def test_the_cavity_is_an_object_no_organ_may_be_named_after():
    raw = scene_mod.load("rectum").raw
    raw["tools"][0]["name"] = "cavity"
    with pytest.raises(InputError, match=r"environment: no organ, tool or tube named 'cavity'"):
        scene_mod.validate(raw, "s.toml", ".")
    raw["environment"].pop("cavity")
    for plane in raw["environment"]["planes"]:
        plane["extent"] = 0.0
    raw.pop("task")  # it names the grasper
    assert scene_mod.validate(raw, "s.toml", ".").tools[0]["name"] == "cavity"  # nothing drawn
    raw["environment"]["cavity"] = {"center": [0.0, 0.0, 0.0], "radii": [0.1, 0.0, 0.1]}
    with pytest.raises(InputError, match=r"environment\.cavity\.radii"):
        scene_mod.validate(raw, "s.toml", ".")


def test_how_the_planes_look_leaves_the_sessions_key_alone():
    scene = scene_mod.load("rectum")
    raw = scene_mod.load("rectum").raw
    raw["environment"]["planes"][0].update(appearance="liver", extent=0.1, color=[1.0, 0, 0])
    assert session_key(scene_mod.validate(raw, "s.toml", ".")) == session_key(scene)
    raw["environment"]["planes"][0]["point"] = [0.0, -0.05, 0.0]
    assert session_key(scene_mod.validate(raw, "s.toml", ".")) != session_key(scene)


@pytest.mark.parametrize("name", scene_mod.builtin_names())
def test_every_pixel_of_a_built_in_scenes_view_ends_on_tissue(name):
    """The cavity wall and planes alone (the organs only hide more of them) cover the
    whole image from the scene's endoscope."""
    scene = scene_mod.load(name)
    environment = environment_arrays(scene)
    assert environment["names"][-1] == scene_mod.CAVITY
    positions = environment["position"]
    mesh = ArrayMesh(
        environment["triangles"],
        environment["piece"],
        environment["materials"],
        vertex_count=len(positions),
        smooth_count=len(positions),
        positions=positions,
    )
    renderer = Renderer(mesh, EndoscopeCamera.from_scene(scene.camera), size=(96, 54))
    renderer.render(None, None)
    assert (renderer.gbuffer.triangle.to_numpy() >= 0).all()
    assert renderer.image().max() > 0
