"""The README's scene-file reference covers every key a scene file may hold."""

from pathlib import Path

import pytest
from taichi_lap.scenes.anatomy import GENERATORS

from taichi_lap.scene import schema as scene_mod

README = (Path(__file__).resolve().parent.parent / "README.md").read_text()

TABLES = {
    "scene": scene_mod.SCENE_PARAMS,
    "camera": scene_mod.CAMERA_PARAMS,
    "planes": scene_mod.PLANE_PARAMS,
    "environment tubes": scene_mod.ENVIRONMENT_TUBE_PARAMS,
    "cavity": scene_mod.CAVITY_PARAMS,
    "tools": scene_mod.TOOL_PARAMS,
    "organs": scene_mod.ORGAN_PARAMS,
    "geometry": scene_mod.GEOMETRY_COMMON,
    "mesh": scene_mod.MESH_PARAMS,
    "attachments": scene_mod.ATTACHMENT_PARAMS,
    "task": scene_mod.TASK_PARAMS,
    "task pass": scene_mod.TASK_PASS_PARAMS,
    "task plane": scene_mod.TASK_PLANE_PARAMS,
    "task phases": scene_mod.TASK_PHASE_PARAMS,
    "task view": scene_mod.TASK_VIEW_PARAMS,
    **{f"material {m}": p for m, p in scene_mod.MATERIAL_PARAMS.items()},
    **{f"generator {g.name}": g.params for g in GENERATORS.values()},
}


@pytest.mark.parametrize("table", sorted(TABLES))
def test_readme_documents_every_key(table):
    missing = [key for key in TABLES[table] if f"| `{key}` |" not in README]
    assert not missing, f"README lacks {table} keys: {missing}"


def test_readme_names_every_model_and_generator():
    for model in scene_mod.MODELS:
        assert f"`{model}`" in README
    for name in GENERATORS:
        assert f'`generator = "{name}"`' in README
