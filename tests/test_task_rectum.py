"""The rectum scene's task (seed 000 §7), run headless by its scripts at the scene's
own settings (see ``tests/test_task_liver.py``)."""

from tests.test_task_liver import failed, judged
from taichi_lap.training.live import verdict_lines


def test_the_rectum_expert_does_every_phase_and_the_careless_scissors_close_on_the_gland(
    tmp_path,
):
    """Seed 000 §7's operation: the scene's script grasps the wall, cuts the fascia
    along its attachment, excises the polyp and divides the vessel, in order, without
    touching the gland; the careless scissors press on the gland and close on it, and
    leave the fascia, the polyp and the vessel."""
    expert = judged(tmp_path, "expert", "rectum", 630)  # the last phase ends by 10.5 s
    assert expert["passed"], verdict_lines(expert)
    times = [phase["completed_at"] for phase in expert["goal"]["phases"]]
    assert all(t is not None for t in times) and times == sorted(times)

    careless = judged(tmp_path, "careless", "rectum", 180, "--device", "script:rectum-careless")
    assert not careless["passed"] and careless["forbidden_contacts"] > 0
    assert {"phases completed", "time to completion", "forbidden_contacts"} <= failed(careless)
    done = [phase["completed_at"] is not None for phase in careless["goal"]["phases"]]
    assert done == [True, False, False, False]
