"""Every kind of bad input gives one line ``error: FILE: KEY: ...`` and exit status 2."""

import textwrap

import numpy as np
import pytest

from taichi_lap.cli import main

GOOD_ORGAN = """
[[organs]]
name = "ball"
model = "tet_clusters"
geometry = { generator = "sphere", radius = 0.02 }
material = { particle_spacing = 0.006 }
"""


def scene_file(tmp_path, text: str, name="scene.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def run_check(path, capsys, *extra):
    status = main(["check", str(path), "--no-cache", *extra])
    err = capsys.readouterr().err.strip()
    return status, err


def assert_input_error(status, err, *fragments):
    assert status == 2
    assert err.startswith("error: ")
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in err, (fragment, err)


BAD_SCENES = {
    "malformed_toml": ("[scene\nname = 'x'", ["valid TOML was expected", "line 1"]),
    "unknown_top_key": (
        "[scene]\nname='x'\n[camerra]\n" + GOOD_ORGAN,
        ["camerra", "unknown top-level key"],
    ),
    "unknown_material_key": (
        "[scene]\nname='x'\n"
        + GOOD_ORGAN.replace(
            "particle_spacing = 0.006", "particle_spacing = 0.006, stifness = 0.5"
        ),
        ["organs[0].material.stifness", "unknown key", "stiffness"],
    ),
    "wrong_type": (
        "[scene]\nname='x'\ndt = 'fast'\n" + GOOD_ORGAN,
        ["scene.dt", "a number was expected", "'fast'"],
    ),
    "out_of_range": (
        "[scene]\nname='x'\n"
        + GOOD_ORGAN.replace(
            "particle_spacing = 0.006", "particle_spacing = 0.006, stiffness = 2.0"
        ),
        ["organs[0].material.stiffness", "[0, 1]", "2.0"],
    ),
    "missing_scene_table": (GOOD_ORGAN, ["scene", "[scene] table"]),
    "no_organs": ("[scene]\nname='x'\n", ["organs", "at least one"]),
    "unknown_model": (
        "[scene]\nname='x'\n" + GOOD_ORGAN.replace("tet_clusters", "fem"),
        ["organs[0].model", "one of", "'fem'"],
    ),
    "generator_for_wrong_model": (
        "[scene]\nname='x'\n" + GOOD_ORGAN.replace("tet_clusters", "truss"),
        ["organs[0].geometry.generator", "truss", "'sphere'"],
    ),
    "unknown_generator": (
        "[scene]\nname='x'\n" + GOOD_ORGAN.replace("sphere", "kidney"),
        ["organs[0].geometry.generator", "'kidney'"],
    ),
    "bad_generator_param": (
        "[scene]\nname='x'\n" + GOOD_ORGAN.replace("radius = 0.02", "radius = -1.0"),
        ["organs[0].geometry.radius", "-1.0"],
    ),
    "duplicate_names": (
        "[scene]\nname='x'\n" + GOOD_ORGAN + GOOD_ORGAN,
        ["organs[1].name", "unique", "'ball'"],
    ),
    "join_unknown_organ": (
        "[scene]\nname='x'\n"
        + GOOD_ORGAN
        + "attachments = [ { kind = 'join', organ = 'kidney' } ]\n",
        ["organs[0].attachments[0].organ", "'kidney'"],
    ),
    "empty_region": (
        "[scene]\nname='x'\n"
        + GOOD_ORGAN
        + "attachments = [ { kind = 'fixed', center = [1, 1, 1], radius = 0.01 } ]\n",
        ["organs[0].attachments[0]", "holds none"],
    ),
    "half_a_box": (
        "[scene]\nname='x'\n"
        + GOOD_ORGAN
        + "attachments = [ { kind = 'fixed', box_min = [0, 0, 0] } ]\n",
        ["organs[0].attachments[0]", "box_max"],
    ),
    "vec3_too_short": (
        "[scene]\nname='x'\ngravity = [0, -9.8]\n" + GOOD_ORGAN,
        ["scene.gravity", "3 numbers"],
    ),
    "missing_mesh": (
        "[scene]\nname='x'\n[[organs]]\nname='m'\nmodel='tet_clusters'\n"
        "geometry = { mesh = 'nowhere.stl' }\n",
        ["organs[0].geometry.mesh", "nowhere.stl", "does not exist"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_SCENES))
def test_bad_scene_gives_one_line_error(tmp_path, capsys, case):
    text, fragments = BAD_SCENES[case]
    path = scene_file(tmp_path, text)
    status, err = run_check(path, capsys)
    assert_input_error(status, err, str(path), *fragments)


def test_unknown_scene_name(capsys):
    status = main(["check", "no_such_scene"])
    assert_input_error(status, capsys.readouterr().err.strip(), "no_such_scene", "built-in scene")


def test_garbage_mesh_file(tmp_path, capsys):
    (tmp_path / "organ.stl").write_bytes(b"\x00\x01 not a mesh at all" * 10)
    path = scene_file(
        tmp_path,
        "[scene]\nname='x'\n[[organs]]\nname='m'\nmodel='tet_clusters'\n"
        "geometry = { mesh = 'organ.stl' }\n",
    )
    status, err = run_check(path, capsys)
    assert_input_error(status, err, "organ.stl", "organs[0].geometry.mesh")


def test_open_mesh_reports_open_edges(tmp_path, capsys):
    import trimesh

    box = trimesh.creation.box(extents=[0.04, 0.04, 0.04])
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    open_box.export(tmp_path / "open.stl")
    path = scene_file(
        tmp_path,
        "[scene]\nname='x'\n[[organs]]\nname='m'\nmodel='tet_clusters'\n"
        "geometry = { mesh = 'open.stl' }\n",
    )
    status, err = run_check(path, capsys)
    assert_input_error(status, err, "open.stl", "watertight", "3 open edges")


def test_non_finite_mesh(tmp_path, capsys):
    (tmp_path / "nan.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n"
    )
    path = scene_file(
        tmp_path,
        "[scene]\nname='x'\n[[organs]]\nname='m'\nmodel='tet_clusters'\n"
        "geometry = { mesh = 'nan.obj' }\n",
    )
    status, err = run_check(path, capsys)
    assert_input_error(status, err, "nan.obj", "finite")


def test_bad_override(capsys):
    status = main(["check", "rectum", "--set", "scene.substeps=0"])
    assert_input_error(status, capsys.readouterr().err.strip(), "scene.substeps", "[1, 200]")


def test_bad_script_file(tmp_path, capsys):
    script = tmp_path / "moves.toml"
    script.write_text("version = 1\n[[keyframe]]\ntime = 0.0\ntool = 'scalpel'\ntip = [0, 0, 0]\n")
    status = main(
        [
            "run",
            "rectum",
            "--headless",
            "--frames",
            "1",
            "--set",
            "scene.detail=0.05",
            "--device",
            f"script:{script}",
            "--out",
            str(tmp_path / "frames"),
        ]
    )
    assert_input_error(
        status, capsys.readouterr().err.strip(), str(script), "keyframe[0].tool", "'scalpel'"
    )


def test_good_scene_passes(tmp_path, capsys):
    path = scene_file(tmp_path, "[scene]\nname='x'\n" + GOOD_ORGAN)
    status = main(["check", str(path), "--json", "--no-cache"])
    assert status == 0
    import json

    stats = json.loads(capsys.readouterr().out)
    ball = stats["organs"][0]
    assert ball["particles"] > 50 and ball["tets"] > 100
    assert np.isclose(stats["totals"]["particles"], ball["particles"])
