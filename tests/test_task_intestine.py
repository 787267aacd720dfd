"""The intestine scene's task (seed 001's teaching goals: place the endoscope, move
the loops with dexterity), run headless by its scripts (see
``tests/test_task_liver.py``): the view of the colon beneath the loops is measured
from each frame's object-id image, so the runs are drawn at 160 x 120, where the
colon covers a few hundred pixels."""

import pytest

from taichi_lap.training.live import verdict_lines
from tests.test_task_liver import failed, judged


@pytest.mark.scene_task
def test_the_intestine_expert_exposes_the_colon_and_the_careless_probe_hides_it(tmp_path):
    """The scene's script sweeps the lowest loops off the colon: 80 % of it shows,
    filling 4 % of the image, for more than the second the task asks. The careless
    probe drags the loops towards the scope, over the colon."""
    expert = judged(tmp_path, "expert", "intestine", 250, size="160x120")
    assert expert["passed"], verdict_lines(expert)
    view = expert["goal"]["view"]
    assert view["visible_best"] >= 0.8 and view["longest_in_view"] >= 1.0
    assert expert["goal"]["time_to_completion"] <= 4.2

    careless = judged(
        tmp_path,
        "careless",
        "intestine",
        250,
        "--device",
        "script:intestine-careless",
        size="160x120",
    )
    assert not careless["passed"]
    assert failed(careless) == {"colon held in view", "time to completion"}
    assert careless["goal"]["view"]["visible_best"] < 0.75
