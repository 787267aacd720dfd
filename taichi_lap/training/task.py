"""Scored tasks: a scene's ``[task]`` table (``docs/training.md``), read back from the
session file's recorded scene, judged on the session's metrics and events: its goal
(:mod:`taichi_lap.training.goal`) must be reached, within the time limit (a task
without a goal: the session's duration within it), each threshold of ``[task.pass]``
is an upper bound of one metric, and the task passes when the session ended normally
and every check holds."""

from __future__ import annotations

from taichi_lap.replay import Recording
from taichi_lap.scene import check_task
from taichi_lap.scene.schema import TASK_PASS_PARAMS
from taichi_lap.training.goal import goal_result


def _forbidden_contacts(metrics, forbidden: list[str]) -> int:
    return sum(
        instrument.touched[organ]["contacts"]
        for instrument in metrics.instruments.values()
        for organ in forbidden
        if organ in instrument.touched
    )


TASK_VALUES = {  # a [task.pass] key -> its value for (SessionMetrics, task, goal result)
    "path_length": lambda m, *_: sum(i.path_length for i in m.instruments.values()),
    "economy": lambda m, *_: max(
        (i.economy for i in m.instruments.values() if i.economy is not None), default=None
    ),
    "idle_time": lambda m, *_: sum(i.idle_time for i in m.instruments.values()),
    "peak_force": lambda m, *_: max((i.peak_force for i in m.instruments.values()), default=0.0),
    "mean_contact_force": lambda m, *_: max(
        (i.mean_contact_force for i in m.instruments.values()), default=0.0
    ),
    "forbidden_contacts": lambda m, task, _: _forbidden_contacts(m, task["forbidden"]),
    "vessel_damage": lambda m, *_: m.events["vessel_damage"],
    "tears": lambda m, *_: m.events["tear"],
    "removed_outside": lambda m, task, goal: goal["removed_outside"],
    "wound_distance_mean": lambda m, task, goal: (goal["plane"] or {}).get("distance_mean"),
    "wound_distance_max": lambda m, task, goal: (goal["plane"] or {}).get("distance_max"),
}


def recorded_task(recording: Recording) -> dict | None:
    """The ``[task]`` of the recorded scene, checked as a scene file's would be, or
    None when the scene has none."""
    raw = recording.start["raw_scene"]
    if "task" not in raw:
        return None
    organs = [organ.get("name", "") for organ in raw.get("organs", [])]
    tools = [tool.get("name", "") for tool in raw.get("tools", [])]
    tubes = [tube.get("name", "") for tube in raw.get("environment", {}).get("tubes", [])]
    return check_task(
        recording.path, "session_start.raw_scene.task", raw["task"], organs, tools, tubes
    )


def judge_task(task: dict, metrics, events: list[dict]) -> dict:
    """The task's result on ``metrics`` (a SessionMetrics) and the session's
    ``events``: its name, instructions and forbidden organs, the contacts with
    them, its goal (:func:`~taichi_lap.training.goal.goal_result`), one check per
    requirement (metric, value, bound, unit, at_least, passed) and whether it
    passed."""
    time = metrics.frame_time
    start = float(time[0]) if len(time) else 0.0
    dt = metrics.duration / len(time) if len(time) else 0.0
    goal = goal_result(task, events, start, metrics.views, dt)
    checks = []
    if goal["plane"] is not None:
        plane = goal["plane"]
        checks.append(
            _check("plane coverage", plane["coverage"], plane["coverage_needed"], "", True)
        )
    if goal["view"] is not None:
        view = goal["view"]
        checks.append(
            _check(
                f"{view['target']} held in view", view["longest_in_view"], view["hold"], "s", True
            )
        )
    if task["phases"]:
        done = sum(phase["completed_at"] is not None for phase in goal["phases"])
        checks.append(_check("phases completed", done, len(task["phases"]), "", True))
    if task["time_limit"] > 0.0:
        elapsed = goal["time_to_completion"] if goal["has_goal"] else metrics.duration
        metric = "time to completion" if goal["has_goal"] else "time_limit"
        checks.append(_check(metric, elapsed, task["time_limit"], "s"))
    for key, bound in task["pass"].items():
        if bound is not None:
            value = TASK_VALUES[key](metrics, task, goal)
            checks.append(_check(key, value, bound, TASK_PASS_PARAMS[key].unit))
    return {
        "name": task["name"],
        "instructions": task["instructions"],
        "forbidden": task["forbidden"],
        "forbidden_contacts": _forbidden_contacts(metrics, task["forbidden"]),
        "goal": goal,
        "checks": checks,
        "passed": metrics.complete and all(check["passed"] for check in checks),
    }


def _check(metric: str, value, bound: float, unit: str, at_least: bool = False) -> dict:
    """One requirement: ``value`` at most ``bound`` (at least, with ``at_least``); a
    value that was not measured fails."""
    passed = value is not None and (value >= bound if at_least else value <= bound)
    return {
        "metric": metric,
        "value": value,
        "bound": bound,
        "unit": unit,
        "at_least": at_least,
        "passed": passed,
    }
