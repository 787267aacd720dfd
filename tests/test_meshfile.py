"""Loading user surface meshes (OBJ/STL/PLY) with one-line InputErrors."""

import numpy as np
import pytest
import trimesh

from taichi_lap.core.errors import InputError
from taichi_lap.core.mesh import edge_defects, enclosed_volume
from taichi_lap.preprocess.meshfile import load_surface_mesh

SCENE = "scene.toml"
KEY = "organs.liver.mesh"


def load(path, watertight=True, **kwargs):
    return load_surface_mesh(path, scene_file=SCENE, key=KEY, watertight=watertight, **kwargs)


def write_obj(path, vertices, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def box():
    return trimesh.creation.box(extents=(30.0, 20.0, 10.0))  # millimetres


def test_closed_stl_merges_to_a_watertight_outward_mesh(tmp_path, box):
    path = tmp_path / "liver.stl"
    box.export(path)
    mesh = load(path)
    assert len(mesh.vertices) == 8 and len(mesh.triangles) == 12
    assert edge_defects(mesh.triangles) == (0, 0)
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(6000.0, rel=1e-6)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".OBJ"])
def test_other_formats_load(tmp_path, box, suffix):
    path = tmp_path / f"organ{suffix}"
    box.export(path, file_type=suffix[1:].lower())
    mesh = load(path)
    assert len(mesh.triangles) == 12
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(6000.0, rel=1e-6)


def test_scale_converts_millimetres(tmp_path, box):
    path = tmp_path / "liver.stl"
    box.export(path)
    mesh = load(path, scale=0.001)
    np.testing.assert_allclose(
        mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0), [0.03, 0.02, 0.01]
    )
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(6e-6, rel=1e-6)


def test_inward_mesh_comes_back_outward(tmp_path, box):
    path = write_obj(tmp_path / "inward.obj", box.vertices, box.faces[:, ::-1])
    mesh = load(path)
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(6000.0, rel=1e-6)


def expect_error(path, fragment, file=None, **kwargs):
    with pytest.raises(InputError) as caught:
        load(path, **kwargs)
    error = caught.value
    assert fragment in error.message, error.message
    assert error.key == KEY
    assert error.file == (file if file is not None else str(path))
    assert "\n" not in error.one_line() and "expected" in error.message
    return error


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.stl"
    expect_error(path, f"mesh file {path} was expected, it does not exist", file=SCENE)


def test_unknown_extension(tmp_path):
    path = tmp_path / "liver.vtk"
    path.write_text("# vtk DataFile Version 3.0\n")
    error = expect_error(path, ".vtk", file=SCENE)
    assert ".obj, .stl, .ply" in error.message


def test_empty_file(tmp_path):
    path = tmp_path / "empty.stl"
    path.write_bytes(b"")
    expect_error(path, "found none")


def test_garbage_file(tmp_path):
    path = tmp_path / "garbage.ply"
    path.write_bytes(np.random.default_rng(3).bytes(2000))
    expect_error(path, "parsing failed")


def test_nan_coordinates(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v nan 0 0\nv 1 0 inf\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    expect_error(path, "found 2 non-finite values")


def test_face_index_out_of_range(tmp_path):
    path = tmp_path / "range.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"
    )
    expect_error(path, "found 1 out of range")


def test_degenerate_faces(tmp_path, box):
    faces = np.concatenate([box.faces, [[0, 0, 1], [0, 1, 1]]])
    expect_error(
        write_obj(tmp_path / "repeated.obj", box.vertices, faces), "found 2 degenerate faces"
    )
    vertices = np.concatenate([box.vertices, [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]])
    faces = np.concatenate([box.faces, [[8, 9, 10]]])  # collinear: zero area
    expect_error(
        write_obj(tmp_path / "flat.obj", vertices, faces),
        "found 1 degenerate faces",
        watertight=False,
    )


def test_open_mesh(tmp_path, box):
    path = tmp_path / "open.stl"
    trimesh.Trimesh(box.vertices, box.faces[1:], process=False).export(path)
    expect_error(path, "found 3 open edges and 0 non-manifold edges")
    assert len(load(path, watertight=False).triangles) == 11


def test_non_manifold_mesh(tmp_path, box):
    fin = np.array([[0, 1, 6]])  # a third face on box edge 0-1, two new open edges
    expect_error(
        write_obj(tmp_path / "fin.obj", box.vertices, np.concatenate([box.faces, fin])),
        "found 2 open edges and 1 non-manifold edges",
    )


def test_inconsistent_orientation(tmp_path, box):
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    expect_error(write_obj(tmp_path / "flipped.obj", box.vertices, faces), "found 3 edges")


def test_bad_scale(tmp_path, box):
    path = tmp_path / "liver.stl"
    box.export(path)
    expect_error(path, "found 0.0", file=SCENE, scale=0.0)
