"""The built-in scenes' tasks, here the liver's (seed 002), run headless by their scripts at the scenes' own
settings (the cautery's heat and the vessels' depth depend on the particle spacing,
so a smaller scene would be another task): the expert reference, the scene's own
script, passes; the careless reference (a built-in script) fails for the reason it
is careless."""

import pytest

from taichi_lap.cli import main
from taichi_lap.replay import read_recording
from taichi_lap.training.live import verdict_lines
from taichi_lap.training.metrics import session_metrics


def judged(tmp_path, name: str, scene: str, frames: int, *device: str, size: str = "64x48") -> dict:
    """The task's result of ``frames`` frames of ``scene`` driven by ``device``
    (default: the scene's script) and drawn at ``size``, recorded and scored from the
    file."""
    path = tmp_path / f"{name}.tlap"
    run = ["run", scene, "--headless", "--size", size, "--frames", str(frames)]
    assert main([*run, "--out", str(tmp_path / name), "--record", str(path), *device]) == 0
    return session_metrics(read_recording(path)).task


def failed(task: dict) -> set[str]:
    return {check["metric"] for check in task["checks"] if not check["passed"]}


@pytest.mark.scene_task
def test_the_liver_expert_scores_the_line_and_the_careless_hook_burns_the_vein(tmp_path):
    """Seed 002's transection task: the scene's script scores 80 % of the planned
    line within 3 mm of its plane without damaging a vessel; the careless hook burns
    5 mm deep and drifts off the plane onto the hepatic vein."""
    expert = judged(tmp_path, "expert", "liver", 330)  # the goal is reached by 5.5 s
    assert expert["passed"], verdict_lines(expert)
    plane = expert["goal"]["plane"]
    assert plane["coverage"] >= 0.8 and plane["distance_max"] <= 0.003
    assert 0.0 < expert["goal"]["time_to_completion"] < 7.5

    careless = judged(tmp_path, "careless", "liver", 300, "--device", "script:liver-careless")
    assert not careless["passed"]
    assert {"plane coverage", "time to completion", "vessel_damage"} <= failed(careless)
    assert careless["goal"]["plane"]["distance_max"] > 0.003
