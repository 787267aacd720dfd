"""Scored tasks: a scene's ``[task]`` table (``docs/training.md``), read back from the
session file's recorded scene, judged on the session's metrics: each threshold of
``[task.pass]`` is an upper bound of one metric, the time limit one of the duration,
and the task passes when the session ended normally and every bound holds."""

from __future__ import annotations

from taichi_lap.replay import Recording
from taichi_lap.scene import check_task
from taichi_lap.scene.schema import TASK_PASS_PARAMS


def _forbidden_contacts(metrics, forbidden: list[str]) -> int:
    return sum(
        instrument.touched[organ]["contacts"]
        for instrument in metrics.instruments.values()
        for organ in forbidden
        if organ in instrument.touched
    )


TASK_VALUES = {  # a [task.pass] key -> its value for (SessionMetrics, forbidden organs)
    "path_length": lambda m, _: sum(i.path_length for i in m.instruments.values()),
    "economy": lambda m, _: max(
        (i.economy for i in m.instruments.values() if i.economy is not None), default=None
    ),
    "idle_time": lambda m, _: sum(i.idle_time for i in m.instruments.values()),
    "peak_force": lambda m, _: max((i.peak_force for i in m.instruments.values()), default=0.0),
    "mean_contact_force": lambda m, _: max(
        (i.mean_contact_force for i in m.instruments.values()), default=0.0
    ),
    "forbidden_contacts": _forbidden_contacts,
    "vessel_damage": lambda m, _: m.events["vessel_damage"],
    "tears": lambda m, _: m.events["tear"],
}


def recorded_task(recording: Recording) -> dict | None:
    """The ``[task]`` of the recorded scene, checked as a scene file's would be, or
    None when the scene has none."""
    raw = recording.start["raw_scene"]
    if "task" not in raw:
        return None
    organs = [organ.get("name", "") for organ in raw.get("organs", [])]
    return check_task(recording.path, "session_start.raw_scene.task", raw["task"], organs)


def judge_task(task: dict, metrics) -> dict:
    """The task's result on ``metrics`` (a SessionMetrics): its name, instructions and
    forbidden organs, the contacts with them, one check per bound (metric, value,
    bound, unit, passed) and whether it passed."""
    checks = []
    if task["time_limit"] > 0.0:
        checks.append(_check("time_limit", metrics.duration, task["time_limit"], "s"))
    for key, bound in task["pass"].items():
        if bound is not None:
            value = TASK_VALUES[key](metrics, task["forbidden"])
            checks.append(_check(key, value, bound, TASK_PASS_PARAMS[key].unit))
    return {
        "name": task["name"],
        "instructions": task["instructions"],
        "forbidden": task["forbidden"],
        "forbidden_contacts": _forbidden_contacts(metrics, task["forbidden"]),
        "checks": checks,
        "passed": metrics.complete and all(check["passed"] for check in checks),
    }


def _check(metric: str, value, bound: float, unit: str) -> dict:
    """One bound: ``value`` at most ``bound`` (a value that was not measured fails)."""
    passed = value is not None and value <= bound
    return {"metric": metric, "value": value, "bound": bound, "unit": unit, "passed": passed}
