"""Objects drawn one-sided: the rasterizer skips the back faces of closed surfaces
facing out (taichi_lap.core.mesh.faces_out, taichi_lap.render.scene_mesh
one_sided_objects), which must leave every built-in scene's image as it was."""

import numpy as np
import pytest
import trimesh

from taichi_lap.core.mesh import faces_out
from taichi_lap.render.renderer import Renderer
from taichi_lap.render.scene_mesh import SceneMesh
from taichi_lap.session import scene_script
from tests.test_render import small_session


def test_faces_out_holds_for_closed_outward_surfaces_only():
    """A closed box and two apart face out; turned inside out, with a face missing,
    or with a piece turned inside out they do not; vertices split at the same point
    (as a drawn mesh splits them for its normals) are welded first."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    points, faces = np.asarray(box.vertices), np.asarray(box.faces)
    assert faces_out(points, faces)
    assert not faces_out(points, faces[:, ::-1])
    assert not faces_out(points, faces[1:])
    assert not faces_out(points, faces[:0])
    apart = np.concatenate([points, points + 5.0])
    assert faces_out(apart, np.concatenate([faces, faces + len(points)]))
    assert not faces_out(apart, np.concatenate([faces, faces[:, ::-1] + len(points)]))
    split = points[faces].reshape(-1, 3)  # three vertices of its own per triangle
    assert faces_out(split, np.arange(len(split)).reshape(-1, 3))


def test_closed_organs_tools_and_tubes_are_one_sided_and_cut_surfaces_are_not():
    """In the rectum scene the rectum, the polyp (cut through its volume, which closes
    the wound) and the closed tools are one-sided; the fascia (an open sheet), the
    gland and the vessel (whose surfaces scissors cut open) and the cavity (seen
    from within) are not. The intestine (tubes, end caps and the membrane's shell)
    is closed and faces out as drawn, as its flag takes it to."""
    session = small_session("rectum")
    mesh = SceneMesh(session.scene, session.model)
    flags = dict(zip(mesh.object_names, mesh.one_sided.to_numpy().tolist()))
    assert flags == {
        "rectum": 1,
        "polyp": 1,
        "fascia": 0,
        "gland": 0,
        "vessel": 0,
        "grasper": 1,
        "scissors": 1,
        "cavity": 0,
    }
    session = small_session("intestine")
    mesh = SceneMesh(session.scene, session.model)
    mesh.update(session.state, session.control)
    intestine = mesh.object_names.index("intestine")
    assert mesh.one_sided[intestine] == 1
    triangles = mesh.triangles.to_numpy().reshape(-1, 3)
    drawn = (mesh.triangle_object.to_numpy() == intestine) & (
        (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
    )
    assert drawn.sum() > 1000
    assert faces_out(mesh.positions.to_numpy(), triangles[drawn])


@pytest.mark.parametrize("name", ["liver", "rectum", "intestine"])
def test_skipping_back_faces_leaves_each_scene_image_as_it_was(name):
    """Each built-in scene's default view, a few frames into its script, shows the
    same triangle at every pixel with its one-sided objects' back faces skipped as
    with every face drawn (tests/test_raster.py shows the skipping acts)."""
    session = small_session(name)
    device = scene_script(session.scene)
    for _ in range(3):
        t = session.state.time
        session.step(device.poses(t), device.buttons(t))
    renderer = Renderer.for_scene(session.scene, session.model, size=(160, 120))
    flags = renderer.mesh.one_sided.to_numpy()
    assert flags.any()
    renderer.render(session.state, session.control)
    one_sided = renderer.gbuffer.triangle.to_numpy()
    renderer.mesh.one_sided.from_numpy(np.zeros_like(flags))
    renderer.render(session.state, session.control)
    both = renderer.gbuffer.triangle.to_numpy()
    assert (both >= 0).mean() > 0.9
    assert np.array_equal(one_sided, both)
