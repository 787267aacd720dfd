"""Running values of a session for the window's task panel: elapsed time against the
task's limit, each instrument's path length and peak force, the contacts begun with
the task's forbidden organs and the goal's progress, updated frame by frame from what the simulation
gives (the report's metrics, :mod:`taichi_lap.training.metrics`, are computed from
the session file at the end; these agree with them for the same frames, the force
being the simulation's, not the haptic ticks')."""

from __future__ import annotations

import textwrap

import numpy as np

from taichi_lap.training.goal import REMOVAL_EVENTS, goal_result


class LiveScore:
    """Accumulates a session's running values; ``task`` is the scene's checked
    ``[task]`` or None, ``tools`` the tool names, ``dt`` [s] the frame time step."""

    def __init__(self, task: dict | None, tools: list[str], dt: float):
        self.task = task
        self.dt = dt
        self.frames = 0
        self.path_length = dict.fromkeys(tools, 0.0)  # [m]
        self.peak_force = dict.fromkeys(tools, 0.0)  # [N]
        self.forbidden_contacts = 0
        self._tips: dict[str, np.ndarray] = {}
        self._touching: set[tuple[str, str]] = set()  # (tool, forbidden organ) in contact
        self.events: list[dict] = []  # with a task, the session's events stamped [s]
        self.views: list[tuple[float, float, float]] = []  # the view target's, per frame
        self.goal = goal_result(task, [], 0.0, dt=dt) if task else None

    @property
    def elapsed(self) -> float:
        """Simulated time [s] of the frames so far (the metrics' duration)."""
        return self.frames * self.dt

    @property
    def time_limit(self) -> float:
        return self.task["time_limit"] if self.task else 0.0

    @property
    def over_time(self) -> bool:
        """Whether the task's time limit has passed."""
        return self.time_limit > 0.0 and self.elapsed >= self.time_limit

    def update(
        self,
        tips: dict[str, np.ndarray],
        forces: dict[str, np.ndarray],
        contacts: dict[str, dict[str, int]],
        events: list[dict] = (),
        view: dict[str, tuple[float, float]] | None = None,
    ):
        """One frame: the tips [m] applied before its step, and after it the force
        [N] on each tool, the particles of each organ touching it, the step's
        ``events`` (:attr:`Session.events`) and how the image showed the task's view
        target (``view``, as recorded); the goal follows them."""
        self.frames += 1
        if self.task:
            stamped = [{**event, "time": self.elapsed} for event in events]
            self.events += stamped
            goal_events = {phase["event"] for phase in self.task["phases"]}
            target = self.task["view"]["target"] if self.task.get("view") else None
            if target is not None and view and target in view:
                self.views.append((self.elapsed, *view[target]))
            if (target is not None and view) or any(
                e["kind"] in goal_events or e["kind"] in REMOVAL_EVENTS for e in stamped
            ):
                series = {target: np.array(self.views)} if self.views else {}
                self.goal = goal_result(self.task, self.events, 0.0, series, self.dt)
        for tool, tip in tips.items():
            if tool in self._tips:
                self.path_length[tool] += float(np.linalg.norm(tip - self._tips[tool]))
            self._tips[tool] = np.array(tip, dtype=np.float64)
        for tool, force in forces.items():
            self.peak_force[tool] = max(self.peak_force[tool], float(np.linalg.norm(force)))
        forbidden = self.task["forbidden"] if self.task else []
        touching = {
            (tool, organ)
            for tool, organs in contacts.items()
            for organ in forbidden
            if organs.get(organ, 0) > 0
        }
        self.forbidden_contacts += len(touching - self._touching)
        self._touching = touching

    def lines(self) -> list[str]:
        """The panel's text: the task, the timer and the running values."""
        lines = []
        if self.task:
            lines.append(f"task: {self.task['name'] or 'unnamed'}")
            lines += textwrap.wrap(self.task["instructions"], 48)
        limit = f" / {self.time_limit:.0f} s" if self.time_limit > 0.0 else ""
        lines.append(f"time {self.elapsed:.1f} s{limit}" + ("  TIME UP" if self.over_time else ""))
        for tool in self.path_length:
            lines.append(
                f"{tool}: path {100 * self.path_length[tool]:.1f} cm, "
                f"peak {self.peak_force[tool]:.2f} N"
            )
        if self.task and self.task["forbidden"]:
            forbidden = ", ".join(self.task["forbidden"])
            lines += textwrap.wrap(f"contacts with {forbidden}: {self.forbidden_contacts}", 48)
        if self.goal is not None:
            lines += self._goal_lines()
        return lines

    @property
    def goal_reached(self) -> bool:
        """Whether the task has a goal and it was reached (the task is over)."""
        return self.goal is not None and self.goal["reached"]

    def _goal_lines(self) -> list[str]:
        """Each phase, done (with its time) or to do; the planned line reached and the
        wound's distance from the plane; tissue removed outside the goal."""
        lines = [
            f"[{'x' if p['completed_at'] is not None else ' '}] {p['name']}"
            + (f" ({p['completed_at']:.1f} s)" if p["completed_at"] is not None else "")
            for p in self.goal["phases"]
        ]
        plane = self.goal["plane"]
        if plane is not None:
            lines.append(
                f"planned line reached {100 * plane['coverage']:.0f} % "
                f"(of {100 * plane['coverage_needed']:.0f} %)"
            )
            if plane["distance_max"] is not None:
                lines.append(
                    f"wound from the plane: mean {1e3 * plane['distance_mean']:.1f} mm, "
                    f"max {1e3 * plane['distance_max']:.1f} mm"
                )
        view = self.goal["view"]
        if view is not None:
            now = self.views[-1][1] if self.views else 0.0
            lines.append(
                f"{view['target']} in view: {100 * now:.0f} % of it "
                f"(needed {100 * view['visible_needed']:.0f} %), "
                f"held {view['longest_in_view']:.1f} of {view['hold']:.1f} s"
            )
        if self.goal["removed"] > 0.0:
            lines.append(f"removed outside the goal: {self.goal['removed_outside']:.2f} ml")
        if self.goal["reached"]:
            lines.append(f"GOAL REACHED in {self.goal['time_to_completion']:.1f} s")
        return lines


def verdict_lines(task: dict | None) -> list[str]:
    """A judged task (:func:`taichi_lap.training.task.judge_task`) as the panel's and
    the command line's summary: passed or failed, and each bound broken."""
    if task is None:
        return []
    lines = [f"task {task['name'] or 'unnamed'}: {'PASSED' if task['passed'] else 'FAILED'}"]
    broken = [check for check in task["checks"] if not check["passed"]]
    for check in broken:
        value = "not measured" if check["value"] is None else f"{check['value']:.4g}"
        bound = f"{check['bound']:.4g} {check['unit']}".rstrip()
        relation = "at least" if check["at_least"] else "at most"
        lines.append(f"  {check['metric']}: {value}, {relation} {bound}")
    if not task["passed"] and not broken:
        lines.append("  the session did not end normally")
    return lines
