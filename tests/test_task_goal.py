"""A task's goal judged on a session file's events (``taichi_lap.training.goal``):
phases completed in order by their events, a planned transection plane against the
wound (distance, the line reached), a target held in the endoscope's view (from the
frames' statistics), tissue removed outside the goal, time to completion, and the
live panel following the same goal."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from taichi_lap.core.errors import InputError
from taichi_lap.replay import read_recording
from taichi_lap.scene import validate
from taichi_lap.scene.planned_plane import PlannedPlane
from taichi_lap.training.live import LiveScore, verdict_lines
from taichi_lap.training.metrics import session_metrics
from taichi_lap.training.report import _path_plot, report_html
from tests.test_training import DT, line, write_session

ORGANS = [{"name": name} for name in ("rectum", "fascia", "polyp", "vessel", "liver")]
TOOLS = [{"name": "grasper"}, {"name": "scissors"}, {"name": "hook"}]
PHASES = [
    {"name": "grasp the wall", "event": "grasp", "organ": "rectum"},
    {"name": "mobilise the fascia", "event": "cut", "organ": "fascia", "count": 3},
    {"name": "excise the polyp", "event": "excised", "organ": "polyp"},
]
PLANE = {  # the plane z = 0, the line along x from 0 to 20 mm
    "organ": "liver",
    "point": [0.0, 0.0, 0.0],
    "normal": [0.0, 0.0, 2.0],
    "start": [0.0, 0.01, 0.004],  # projected into the plane
    "end": [0.02, 0.01, 0.004],
    "tolerance": 0.002,
    "coverage": 0.9,
}
FRAMES = 100  # 1 s


def scene_with(task: dict) -> dict:
    return {"organs": ORGANS, "tools": TOOLS, "task": task}


def judged(tmp_path, name: str, task: dict, events, *, end: bool = True):
    """The metrics (with the task's result) of a session of FRAMES frames, the
    grasper moving 5 cm, with ``events`` ``(frame, kind, fields)``."""
    path = write_session(
        tmp_path / f"{name}.tlap",
        {"grasper": line([0.0, 0.0, 0.0], [0.05, 0.0, 0.0], FRAMES)},
        events=events,
        raw_scene=scene_with(task),
        end=end,
    )
    return session_metrics(read_recording(path))


def grasp(frame: int, organs: dict) -> tuple:
    count = sum(organs.values())
    return (frame, "grasp", {"tool": "grasper", "particles": count, "organs": organs})


def cut(frame: int, organ: str) -> tuple:
    return (frame, "cut", {"tool": "scissors", "organ": organ, "triangles": 4})


def burn(frame: int, positions, volume: float, organ: str = "liver") -> tuple:
    """A cautery event removing tissue of ``organ`` at ``positions`` [m]."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    removed = {organ: {"positions": positions.tolist(), "volume": volume}}
    fields = {"tools": ["hook"], "particles": len(positions), "volume": volume, "removed": removed}
    return (frame, "cautery", fields)


def test_phases_complete_in_order_by_their_events_and_time_the_task(tmp_path):
    """A phase counts only its events after the phase before it completed: a fascia
    cut before the grasp, a grasp of nothing and a grasp of another organ do not
    count; the time to completion is the last phase's event time."""
    events = [
        cut(5, "fascia"),  # before the grasp: not counted
        grasp(10, {}),  # jaws closed on nothing
        grasp(12, {"fascia": 3}),  # another organ
        grasp(20, {"rectum": 40, "fascia": 2}),  # phase 1 at frame 21
        cut(30, "fascia"),
        cut(31, "vessel"),  # another organ
        cut(32, "fascia"),
        (35, "excised", {"organ": "polyp", "particles": 10}),  # phase 2 not done yet
        cut(40, "fascia"),  # phase 2 at frame 41
        (60, "excised", {"organ": "polyp", "particles": 10, "volume": 1e-7, "removed": {}}),
    ]
    task = {"name": "Rectum", "time_limit": 0.8, "phases": PHASES}
    result = judged(tmp_path, "phases", task, events).task
    times = [phase["completed_at"] for phase in result["goal"]["phases"]]
    assert times == pytest.approx([21 * DT, 41 * DT, 61 * DT])
    assert result["goal"]["reached"] and result["goal"]["time_to_completion"] == pytest.approx(
        61 * DT
    )
    checks = {c["metric"]: c for c in result["checks"]}
    assert checks["phases completed"]["value"] == 3 and checks["phases completed"]["passed"]
    assert checks["time to completion"]["passed"] and result["passed"]

    late = judged(tmp_path, "late", task, events[:-1] + [(90, "excised", events[-1][2])]).task
    assert not late["passed"]
    assert [c["metric"] for c in late["checks"] if not c["passed"]] == ["time to completion"]

    unfinished = judged(tmp_path, "unfinished", task, events[:-1]).task
    failed = {c["metric"]: c["value"] for c in unfinished["checks"] if not c["passed"]}
    assert failed == {"phases completed": 2, "time to completion": None}
    lines = verdict_lines(unfinished)
    assert "  phases completed: 2, at least 3" in lines
    assert "  time to completion: not measured, at most 0.8 s" in lines


def test_a_wound_along_the_planned_line_reaches_it_and_its_distance_is_measured(tmp_path):
    """Wound points 1 mm off the plane every 2 mm along the whole line: the line is
    reached (every point of it within the tolerance of a wound point), the mean and
    largest distances are 1 mm; half the line burnt reaches half of it plus the
    tolerance at its end."""
    along = np.arange(0.0, 0.0201, 0.002)
    wound = np.column_stack([along, np.full_like(along, 0.005), np.full_like(along, 0.001)])
    half = wound[along <= 0.01]
    task = {"name": "Liver", "plane": PLANE}
    events = [burn(10, half, 1e-7), burn(50, wound[len(half) :], 1e-7)]
    result = judged(tmp_path, "plane", task, events).task
    plane = result["goal"]["plane"]
    assert plane["coverage"] == pytest.approx(1.0)
    assert plane["distance_mean"] == pytest.approx(0.001) and plane[
        "distance_max"
    ] == pytest.approx(0.001)
    assert plane["reached_at"] == pytest.approx(51 * DT) and result["passed"]
    assert result["goal"]["removed_outside"] == pytest.approx(0.0)

    halfway = judged(tmp_path, "half", task, events[:1]).task
    assert halfway["goal"]["plane"]["coverage"] == pytest.approx(
        (0.01 + PLANE["tolerance"]) / 0.02, abs=0.01
    )
    assert not halfway["passed"] and not halfway["goal"]["reached"]


def test_tissue_removed_off_the_plane_or_of_another_organ_is_outside_the_goal(tmp_path):
    """Of a removal's volume, the share of its particles farther than the tolerance
    from the plane is outside the goal; another organ's removed tissue is outside
    unless the task may remove it; the wound's distances count every point."""
    on = [[0.005, 0.005, 0.0005]] * 3
    off = [[0.01, 0.005, 0.004]]  # 4 mm from the plane
    events = [
        burn(10, on + off, 4e-6),  # a quarter of 4 ml outside
        burn(20, [[0.0, 0.0, 0.0]], 2e-6, organ="vessel"),
        burn(30, [[0.0, 0.0, 0.0]], 1e-6, organ="polyp"),
    ]
    task = {"plane": PLANE, "removable": ["polyp"], "pass": {"removed_outside": 2.5}}
    metrics = judged(tmp_path, "outside", task, events)
    result = metrics.task
    goal = result["goal"]
    np.testing.assert_allclose(goal["plane"]["line"], [[0.0, 0.01, 0.0], [0.02, 0.01, 0.0]])
    with_line = _path_plot(metrics)  # the report's path plots draw the planned line
    assert with_line != _path_plot(dataclasses.replace(metrics, task=None))
    assert goal["removed"] == pytest.approx(7.0)  # ml
    assert goal["removed_outside"] == pytest.approx(1.0 + 2.0)
    assert goal["plane"]["distance_max"] == pytest.approx(0.004)
    assert goal["plane"]["distance_mean"] == pytest.approx((3 * 0.0005 + 0.004) / 4)
    failed = [c["metric"] for c in result["checks"] if not c["passed"]]
    assert failed == ["plane coverage", "removed_outside"]


def test_the_planned_plane_projects_its_line_into_the_plane():
    plane = PlannedPlane(PLANE)
    assert plane.length == pytest.approx(0.02)
    np.testing.assert_allclose(plane.start, [0.0, 0.01, 0.0])
    np.testing.assert_allclose(plane.along, [1.0, 0.0, 0.0])
    assert plane.distance(np.array([[0.3, -2.0, -0.004]]))[0] == pytest.approx(0.004)


def test_the_live_panel_follows_the_goal_and_the_report_shows_it(tmp_path):
    """Fed the same events frame by frame, the panel's goal equals the report's: the
    phases done with their times, and the goal reached ends the task."""
    events = [grasp(20, {"rectum": 5}), *(cut(30 + k, "fascia") for k in range(3))]
    events.append((50, "excised", {"organ": "polyp", "particles": 10}))
    task = {"name": "Rectum", "phases": PHASES}
    metrics = judged(tmp_path, "live", task, events)
    live = LiveScore(validate_task(task), ["grasper"], DT)
    for k in range(FRAMES):
        happened = [{"kind": kind, **fields} for frame, kind, fields in events if frame == k]
        live.update({}, {}, {}, happened)
        if k == 40:
            assert not live.goal_reached and "[x] mobilise the fascia (0.3 s)" in live.lines()
    assert live.goal_reached and live.goal == metrics.task["goal"]
    assert "GOAL REACHED in 0.5 s" in live.lines()
    page = report_html([metrics])
    assert "phase 3: excise the polyp" in page and "0.51 s" in page


def validate_task(task: dict) -> dict:
    """``task`` checked as a scene's (defaults filled in)."""
    scene = {
        "scene": {"name": "t"},
        "organs": [
            {
                "name": organ["name"],
                "model": "tet_clusters",
                "geometry": {"generator": "box", "half_extents": [0.01, 0.01, 0.01]},
            }
            for organ in ORGANS
        ],
        "tools": [
            {"name": tool["name"], "kind": "grasper", "tip": [0.0, 0.1, 0.0]} for tool in TOOLS
        ],
        "task": task,
    }
    return validate(scene, "t.toml", Path(".")).task


@pytest.mark.parametrize(
    "task, key, message",
    [
        ({"plane": {**PLANE, "organ": "colon"}}, "task.plane.organ", "an organ in this scene"),
        ({"plane": {**PLANE, "normal": [0, 0, 0]}}, "task.plane.normal", "a non-zero vector"),
        (
            {"plane": {**PLANE, "end": [0.0, 0.01, 0.009]}},
            "task.plane.end",
            "at least 0.1 mm from start along the plane",
        ),
        ({"plane": {"organ": "liver"}}, "task.plane.point", "this key is required"),
        ({"phases": [{"name": "x", "event": "burn"}]}, "task.phases[0].event", "one of"),
        (
            {"phases": [{"name": "x", "event": "cut", "tool": "knife"}]},
            "task.phases[0].tool",
            "a tool in this scene (grasper, scissors, hook)",
        ),
        (
            {"phases": [PHASES[0], {"name": "x", "event": "cut", "organ": "gland"}]},
            "task.phases[1].organ",
            "an organ in this scene",
        ),
        ({"removable": ["gland"]}, "task.removable[0]", "an organ in this scene"),
        ({"phases": {"name": "x"}}, "task.phases", "an array of tables"),
        (
            {"view": {"target": "colon"}},
            "task.view.target",
            "an organ or environment tube in this scene",
        ),
        ({"view": {"target": "liver", "visible": 1.5}}, "task.view.visible", "a value in [0, 1]"),
    ],
)
def test_a_bad_goal_names_its_key(task, key, message):
    with pytest.raises(InputError) as error:
        validate_task(task)
    assert error.value.key == key and message in error.value.message


def test_a_target_held_in_view_long_enough_completes_the_goal(tmp_path):
    """Frames are in view when both the visible fraction and the share of the image
    reach the task's: a frame too small in the image breaks the run, and the goal is
    reached at the frame that makes an unbroken run as long as ``hold``; the panel fed
    the same frames agrees with the file."""
    visible = np.zeros(FRAMES)
    visible[10:30] = 0.8  # 0.2 s in view ...
    visible[40:60] = 0.9  # ... then 0.2 s, broken by a frame too small in the image
    visible[70:] = 0.7  # 0.3 s: held from 0.71 s, reached with the frame ending at 0.95 s
    share = np.where(np.arange(FRAMES) == 50, 0.01, 0.05)
    stats = [(k, {}, {}, {}, {"liver": [visible[k], share[k]]}) for k in range(FRAMES)]
    task = {"name": "Expose", "view": {"target": "liver", "visible": 0.6, "hold": 0.25}}
    path = write_session(
        tmp_path / "view.tlap",
        {"grasper": line([0.0, 0.0, 0.0], [0.05, 0.0, 0.0], FRAMES)},
        stats=stats,
        raw_scene=scene_with(task),
    )
    metrics = session_metrics(read_recording(path))
    view = metrics.task["goal"]["view"]
    assert view["visible_best"] == pytest.approx(0.9)
    assert view["in_view_time"] == pytest.approx(0.69)  # 20 + 19 + 30 frames
    assert view["longest_in_view"] == pytest.approx(0.3)
    assert view["reached_at"] == pytest.approx(0.95)  # frame 94 ends the 25th in a row
    assert metrics.task["goal"]["time_to_completion"] == pytest.approx(0.95)
    assert metrics.task["passed"]
    live = LiveScore(validate_task(task), ["grasper"], DT)
    for k in range(FRAMES):
        live.update({}, {}, {}, [], {"liver": (visible[k], share[k])})
        if k == 90:
            assert not live.goal_reached
            assert "liver in view: 70 % of it (needed 60 %), held 0.2 of 0.2 s" in live.lines()
    assert live.goal_reached and live.goal["view"] == view
    page = report_html([metrics])
    assert "liver in view: best visible" in page and "view held at" in page

    short = {**task, "view": {**task["view"], "hold": 0.5}}
    path = write_session(
        tmp_path / "short.tlap",
        {"grasper": line([0.0, 0.0, 0.0], [0.05, 0.0, 0.0], FRAMES)},
        stats=stats,
        raw_scene=scene_with(short),
    )
    judged_short = session_metrics(read_recording(path)).task
    assert judged_short["goal"]["view"]["reached_at"] is None and not judged_short["passed"]
    assert {c["metric"] for c in judged_short["checks"] if not c["passed"]} == {
        "liver held in view"
    }
