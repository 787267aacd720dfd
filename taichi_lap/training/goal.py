"""A task's goal, judged on a session's events alone (``docs/training.md``): the
phases of an operation, each completed by its events in order (seed 000 §7: press
and grasp, mobilise, separate, excise), and a planned transection plane (seed 002:
the wound, the tissue the cautery and the dissector removed from the organ, against
the plane: its distance from it and how much of the planned line it reaches), with
the tissue removed outside the goal; and a view (seed 001's teaching goals: place
the endoscope and move the loops so that the target shows), judged on the view
series the session file's statistics hold."""

from __future__ import annotations

import numpy as np

from taichi_lap.scene.planned_plane import PlannedPlane

WOUND_EVENTS = ("cautery", "dissect")  # removals that make the wound of a transection
REMOVAL_EVENTS = ("cautery", "dissect", "fragment", "excised")
ML_PER_M3 = 1e6  # [ml per m^3]


def event_matches(phase: dict, event: dict) -> bool:
    """Whether ``event`` counts for ``phase``: its kind, took something (a grasp of
    nothing does not count), and the phase's organ and tool where it names them (the
    organ as the event's ``organ``, ``vessel``, an organ it grasped or removed)."""
    if event["kind"] != phase["event"] or event.get("particles", 1) == 0:
        return False
    organ = phase["organ"]
    if organ is not None and organ not in (
        event.get("organ"),
        event.get("vessel"),
        *event.get("organs", {}),
        *event.get("removed", {}),
    ):
        return False
    tool = phase["tool"]
    return tool is None or tool == event.get("tool") or tool in event.get("tools", ())


def phase_times(phases: list[dict], events: list[dict]) -> list[float | None]:
    """The session time [s] each phase completed, None for those that did not: phase
    k completes at its ``count``-th matching event after phase k-1 completed."""
    times: list[float | None] = [None] * len(phases)
    current, seen = 0, 0
    for event in events:
        if current == len(phases):
            break
        if event_matches(phases[current], event):
            seen += 1
            if seen == phases[current]["count"]:
                times[current], current, seen = float(event["time"]), current + 1, 0
    return times


def plane_result(plane: dict, events: list[dict]) -> dict:
    """The wound against a planned ``plane`` (``[task.plane]``): the removed tissue
    of its organ in the cautery and dissection events. Its mean and largest distance
    [m] from the plane (None without a wound), the fraction of the line it reached
    (:meth:`PlannedPlane.reached`), the fraction required, the session time [s]
    it got there (None if it did not) and the planned ``line``'s ends in the plane
    [m] (for the report's path plots)."""
    planned = PlannedPlane(plane)
    reached = np.zeros(len(planned.samples), dtype=bool)
    distances = []
    at = None
    for event in events:
        if event["kind"] not in WOUND_EVENTS or plane["organ"] not in event.get("removed", {}):
            continue
        points = np.asarray(event["removed"][plane["organ"]]["positions"], dtype=np.float64)
        points = points.reshape(-1, 3)
        distances.append(planned.distance(points))
        reached |= planned.reached(points)
        if at is None and reached.mean() >= plane["coverage"]:
            at = float(event["time"])
    distance = np.concatenate(distances) if distances else np.zeros(0)
    return {
        "organ": plane["organ"],
        "wound_particles": len(distance),
        "distance_mean": float(distance.mean()) if len(distance) else None,
        "distance_max": float(distance.max()) if len(distance) else None,
        "coverage": float(reached.mean()),
        "coverage_needed": plane["coverage"],
        "reached_at": at,
        "line": [planned.start.tolist(), (planned.start + planned.length * planned.along).tolist()],
    }


def removed_outside(task: dict, events: list[dict]) -> tuple[float, float]:
    """``(removed, outside)`` [ml]: the rest volume of all tissue removed in the
    session, and of that removed outside the goal: not of an organ the task may
    remove (``removable``) and, of the planned plane's organ, farther than its
    tolerance from the plane (a removal's volume split by its particles)."""
    plane = task["plane"]
    planned = PlannedPlane(plane) if plane else None
    total = outside = 0.0
    for event in events:
        if event["kind"] not in REMOVAL_EVENTS:
            continue
        for organ, tissue in event.get("removed", {}).items():
            total += tissue["volume"]
            if organ in task["removable"]:
                continue
            share = 1.0
            if planned is not None and organ == plane["organ"] and tissue["positions"]:
                points = np.asarray(tissue["positions"], dtype=np.float64).reshape(-1, 3)
                share = float((planned.distance(points) > planned.tolerance).mean())
            outside += share * tissue["volume"]
    return total * ML_PER_M3, outside * ML_PER_M3


def view_result(view: dict, series: np.ndarray | None, dt: float) -> dict:
    """The target's view (``[task.view]``) over ``series`` (rows of frame end time
    [s], visible, share; None when nothing was recorded), frames of ``dt`` [s]: a frame
    is in view when the visible fraction and the share of the image both reach the
    task's; the best visible fraction, the time in view [s], the longest time in view
    without a break [s], the time needed (``hold``) and the session time [s] the view
    was first held that long (None if never)."""
    series = np.zeros((0, 3)) if series is None else np.asarray(series, dtype=np.float64)
    good = (series[:, 1] >= view["visible"]) & (series[:, 2] >= view["share"])
    run = longest = 0
    at = None
    for k, in_view in enumerate(good):
        run = run + 1 if in_view else 0
        longest = max(longest, run)
        if at is None and in_view and round(run * dt, 6) >= view["hold"]:
            at = float(series[k, 0])
    return {
        "target": view["target"],
        "visible_needed": view["visible"],
        "share_needed": view["share"],
        "visible_best": float(series[:, 1].max()) if len(series) else 0.0,
        "in_view_time": round(float(good.sum() * dt), 6),
        "longest_in_view": round(float(longest * dt), 6),  # [s], as "hold" is compared
        "hold": view["hold"],
        "reached_at": at,
    }


def goal_result(
    task: dict,
    events: list[dict],
    start_time: float,
    views: dict[str, np.ndarray] | None = None,
    dt: float = 0.0,
) -> dict:
    """The task's goal on a session's ``events`` and view series ``views`` (per
    target, :func:`view_result`; frames of ``dt`` [s]), session ``start_time`` [s]
    (its first frame): the phases with the time each completed, the plane's and the
    view's results, tissue removed [ml] in all and outside the goal, whether the goal
    was reached (every phase, the plane's coverage, the view held) and the time to
    reach it [s] from the start (None if not reached or the task has no goal)."""
    times = phase_times(task["phases"], events)
    plane = plane_result(task["plane"], events) if task["plane"] else None
    view = None
    if task.get("view"):
        view = view_result(task["view"], (views or {}).get(task["view"]["target"]), dt)
    removed, outside = removed_outside(task, events)
    ends = list(times) + ([plane["reached_at"]] if plane else [])
    ends += [view["reached_at"]] if view else []
    has_goal = bool(ends)
    reached = has_goal and all(t is not None for t in ends)
    return {
        "phases": [
            {"name": phase["name"], "completed_at": t} for phase, t in zip(task["phases"], times)
        ],
        "plane": plane,
        "view": view,
        "removed": removed,
        "removed_outside": outside,
        "has_goal": has_goal,
        "reached": reached,
        "time_to_completion": max(ends) - start_time if reached else None,
    }
