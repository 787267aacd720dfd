"""Skill metrics of a recorded session, computed from the session file alone (so any
recording can be scored again later): time, per instrument path length, economy of
motion, idle time and tool force, cautery on-time, the simulation's events, and the
cost of each stage per frame. Definitions and units in ``docs/training.md``.

They follow the motion and outcome metrics of published laparoscopic simulators and
skill studies: task time, instrument path length and economy of motion (path length
against the straight distance the task needs), idle time (the instrument at rest),
tool force, and tissue damage and instrument collisions counted as events.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from taichi_lap.core.bleeding import blood_lost
from taichi_lap.replay import Recording
from taichi_lap.training.task import judge_task, recorded_task

IDLE_SPEED = 0.005  # [m/s]: an instrument tip slower than this is idle
STOP_TIME = 0.25  # [s]: idle this long, the instrument stopped at a waypoint
CONTACT_FORCE = 0.05  # [N]: a tool pushed harder than this is in contact
MIN_STRAIGHT = 1e-3  # [m]: below this straight distance economy is undefined
COUNTED_EVENTS = (
    "grasp",
    "release",
    "cut",
    "tear",
    "separated",
    "dissect",
    "fragment",
    "cautery",
    "vessel_damage",
    "excised",
)


@dataclass
class ForceSeries:
    """The magnitude [N] of the force on one tool at ``time`` [s] (session time), from
    the haptic servo's ticks (what the hand felt) or the simulation's statistics."""

    source: str  # "haptic" | "simulation" | "none"
    time: np.ndarray
    magnitude: np.ndarray


@dataclass
class InstrumentMetrics:
    """One instrument's motion and force over a session (``docs/training.md``)."""

    path_length: float  # [m] the tip's path
    straight_length: float  # [m] straight distances between its waypoints
    economy: float | None  # path_length / straight_length (1 is a straight path)
    idle_time: float  # [s] tip slower than IDLE_SPEED
    waypoints: list[list[float]]  # [m] start, each stop, end
    force_source: str
    mean_force: float  # [N] over the whole session
    mean_contact_force: float  # [N] over the samples in contact
    peak_force: float  # [N]
    contact_time: float  # [s] force above CONTACT_FORCE
    cautery_time: float  # [s] energised
    touched: dict[str, dict[str, float]]  # per organ: "time" [s] touching, "contacts" begun


@dataclass
class SessionMetrics:
    """The metrics of one recording; ``complete`` is False for a session that did not
    end normally or a file cut short (``status`` says which)."""

    path: str
    scene: str
    started: str
    status: str
    complete: bool
    frames: int
    duration: float  # [s] simulated time the frames span
    instruments: dict[str, InstrumentMetrics]
    events: dict[str, int]  # count per event kind
    blood_lost: float  # [ml] bled by the end from each vessel damage (core.bleeding)
    stages: dict[str, dict[str, float]]  # per stage: mean, median, p95 [ms]
    # series for the plots, not in the JSON numbers
    frame_time: np.ndarray = field(repr=False)
    tips: dict[str, np.ndarray] = field(repr=False)  # (frames, 3) [m]
    forces: dict[str, ForceSeries] = field(repr=False)
    timeline: list[dict] = field(repr=False)  # the counted events in order
    stats_time: np.ndarray = field(repr=False)  # [s] end of each frame with statistics
    stage_series: dict[str, np.ndarray] = field(repr=False)  # per stage, ms per frame
    views: dict[str, np.ndarray] = field(repr=False, default_factory=dict)  # per view target:
    # (frames, 3) time [s], visible and share of the frames whose statistics hold it
    task: dict | None = None  # the task's result (training.task.judge_task), if any

    def numbers(self) -> dict:
        """The metrics as JSON data (no series)."""
        return {
            "path": self.path,
            "scene": self.scene,
            "started": self.started,
            "status": self.status,
            "complete": self.complete,
            "frames": self.frames,
            "duration": self.duration,
            "instruments": {name: asdict(m) for name, m in self.instruments.items()},
            "events": self.events,
            "blood_lost": self.blood_lost,
            "stages": self.stages,
            "task": self.task,
        }


def stacked_stages(stage_series: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The stages of a frame as parts that add up to its time (seed 000 Fig. 17's
    split): ``physics`` without its ``collision`` as ``deformation``, then
    ``collision``, ``topology``, ``heat``, ``devices``, ``render`` and any other."""
    parts = dict(stage_series)
    if "physics" in parts:
        physics = parts.pop("physics")
        parts = {"deformation": physics - parts.get("collision", 0.0), **parts}
    order = ("deformation", "collision", "topology", "heat", "devices", "render")
    rank = {name: (order.index(name) if name in order else len(order), name) for name in parts}
    return {name: parts[name] for name in sorted(parts, key=rank.get)}


def path_metrics(time: np.ndarray, tips: np.ndarray, task_waypoints=None) -> dict:
    """Path length, waypoints, straight length, economy and idle time of a tip moving
    through ``tips`` (n, 3) [m] at ``time`` (n,) [s]. A segment slower than
    IDLE_SPEED is idle; an idle run of STOP_TIME or longer is a stop, a waypoint at
    the position where the tip came to rest; the start and the end are waypoints.
    With ``task_waypoints`` (points [m] the task gives this tool), those are the
    waypoints between the start and the end instead of the stops."""
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    spans = np.diff(time)
    idle = steps < IDLE_SPEED * spans
    waypoints = [tips[0]] if len(tips) else []
    if task_waypoints and len(tips):
        waypoints += list(np.asarray(task_waypoints, dtype=np.float64))
    else:
        waypoints += _stops(tips, spans, idle)
    if len(tips) > 1:
        waypoints.append(tips[-1])
    points = np.array(waypoints).reshape(-1, 3)
    straight = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    path = float(steps.sum())
    return {
        "path_length": path,
        "straight_length": straight,
        "economy": path / straight if straight >= MIN_STRAIGHT else None,
        "idle_time": float(spans[idle].sum()),
        "waypoints": points.tolist(),
    }


def _stops(tips: np.ndarray, spans: np.ndarray, idle: np.ndarray) -> list[np.ndarray]:
    """Where the tip came to rest in each idle run of STOP_TIME or longer (``spans``
    the steps' durations [s], ``idle`` whether each step was idle)."""
    stops, run, rest = [], 0.0, 0
    for k, still in enumerate(idle):
        if not still:
            run = 0.0
            continue
        if run == 0.0:
            rest = k
        if run < STOP_TIME <= run + spans[k]:
            stops.append(tips[rest])
        run += spans[k]
    return stops


def force_metrics(series: ForceSeries) -> dict:
    """Mean, mean in contact, peak and contact time of a force series; each sample
    stands for the time to the next one (the last for the median interval)."""
    magnitude = series.magnitude
    if len(magnitude) == 0:
        return {
            "mean_force": 0.0,
            "mean_contact_force": 0.0,
            "peak_force": 0.0,
            "contact_time": 0.0,
        }
    spans = np.diff(series.time)
    spans = np.append(spans, np.median(spans) if len(spans) else 0.0)
    contact = magnitude > CONTACT_FORCE
    return {
        "mean_force": float(magnitude.mean()),
        "mean_contact_force": float(magnitude[contact].mean()) if contact.any() else 0.0,
        "peak_force": float(magnitude.max()),
        "contact_time": float(spans[contact].sum()),
    }


def tool_forces(recording: Recording, tool: str, session_time) -> ForceSeries:
    """The force on ``tool``: from the haptic ticks that carry it (their clock mapped
    to session time by ``session_time``), else from the statistics records."""
    ticks = [t for t in recording.ticks if tool in t.forces]
    if ticks:
        return ForceSeries(
            "haptic",
            session_time(np.array([t.clock for t in ticks])),
            np.array([np.linalg.norm(t.forces[tool]) for t in ticks]),
        )
    stats = [s for s in recording.stats if tool in s["forces"]]
    if stats:
        return ForceSeries(
            "simulation",
            np.array([s["time"] for s in stats]),
            np.array([np.linalg.norm(s["forces"][tool]) for s in stats]),
        )
    return ForceSeries("none", np.zeros(0), np.zeros(0))


def organ_contacts(recording: Recording, tool: str) -> dict[str, dict[str, float]]:
    """Per organ that touched ``tool`` (statistics records): the time [s] it touched
    it (each record stands for its frame's dt) and how many contacts began (frames
    touching after one that did not; a session that starts touching counts one)."""
    dt = float(recording.start.get("dt", 0.0))
    touching = [s["contacts"].get(tool, {}) for s in recording.stats]
    organs = sorted({organ for frame in touching for organ in frame})
    found = {}
    for organ in organs:
        touched = np.array([frame.get(organ, 0) > 0 for frame in touching])
        began = int(touched[0]) + int((touched[1:] & ~touched[:-1]).sum())
        found[organ] = {"time": float(touched.sum() * dt), "contacts": began}
    return found


def cautery_time(events: list[dict], tool: str, end: float) -> float:
    """Seconds ``tool`` was energised: from each ``cautery_on`` to its
    ``cautery_off``, or to ``end`` [s] when the session ended energised."""
    total, since = 0.0, None
    for event in events:
        if event.get("tool") != tool:
            continue
        if event["kind"] == "cautery_on" and since is None:
            since = event["time"]
        elif event["kind"] == "cautery_off" and since is not None:
            total, since = total + event["time"] - since, None
    return total + (end - since if since is not None else 0.0)


def session_status(recording: Recording) -> tuple[str, bool]:
    """``(status, complete)``: how the session ended, and whether the file holds all
    of a session that ended normally."""
    end = recording.end
    if recording.truncated_at is not None:
        return f"incomplete: the file ends in a cut record (byte {recording.truncated_at})", False
    if end is None:
        return "incomplete: no session_end record (the run was killed)", False
    return str(end["status"]), end["status"] == "complete"


def view_series(stats: list[dict]) -> dict[str, np.ndarray]:
    """Per view target recorded in the statistics: ``(frames, 3)`` rows of the frame's
    end time [s], the fraction of the target's unhidden image that showed and the
    fraction of the image it filled."""
    rows: dict[str, list] = {}
    for s in stats:
        for target, (visible, share) in s.get("view", {}).items():
            rows.setdefault(target, []).append((s["time"], visible, share))
    return {target: np.array(values, dtype=np.float64) for target, values in rows.items()}


def session_metrics(recording: Recording) -> SessionMetrics:
    """The metrics of ``recording`` (module docstring)."""
    start = recording.start
    frames = recording.frames
    time = np.array([f.time for f in frames])
    clock = np.array([f.clock for f in frames])
    dt = float(start.get("dt") or (np.median(np.diff(time)) if len(time) > 1 else 0.0))
    duration = float(time[-1] - time[0] + dt) if len(time) else 0.0
    end_time = float(time[-1] + dt) if len(time) else 0.0

    def session_time(clocks: np.ndarray) -> np.ndarray:
        """Session time [s] of monotonic ``clocks`` [s]: interpolated between the frames'
        clocks, one second per second before the first and after the last."""
        if len(clock) == 0:
            return clocks - clocks[0]
        inside = np.interp(clocks, clock, time)
        inside = np.where(clocks < clock[0], time[0] + clocks - clock[0], inside)
        return np.where(clocks > clock[-1], time[-1] + clocks - clock[-1], inside)

    task = recorded_task(recording)
    waypoints = task["waypoints"] if task is not None else {}
    tips, forces, instruments = {}, {}, {}
    for tool in recording.tools:
        held = [f for f in frames if tool in f.poses]
        tips[tool] = np.array([f.poses[tool].tip for f in held]).reshape(-1, 3)
        moved = np.array([f.time for f in held])
        forces[tool] = tool_forces(recording, tool, session_time)
        instruments[tool] = InstrumentMetrics(
            **path_metrics(moved, tips[tool], waypoints.get(tool)),
            force_source=forces[tool].source,
            **force_metrics(forces[tool]),
            cautery_time=cautery_time(recording.events, tool, end_time),
            touched=organ_contacts(recording, tool),
        )
    timeline = [e for e in recording.events if e["kind"] in COUNTED_EVENTS]
    events = {kind: sum(e["kind"] == kind for e in timeline) for kind in COUNTED_EVENTS}
    stage_names = sorted({name for s in recording.stats for name in s["stages"]})
    stage_series = {
        name: np.array([s["stages"].get(name, 0.0) for s in recording.stats])
        for name in stage_names
    }
    stages = {
        name: {
            "mean": float(series.mean()),
            "median": float(np.median(series)),
            "p95": float(np.percentile(series, 95)),
        }
        for name, series in stage_series.items()
    }
    status, complete = session_status(recording)
    metrics = SessionMetrics(
        path=recording.path,
        scene=str(start.get("scene", start["source"])),
        started=str(start.get("started", "")),
        status=status,
        complete=complete,
        frames=len(frames),
        duration=duration,
        instruments=instruments,
        events=events,
        blood_lost=1e6
        * blood_lost([e["time"] for e in timeline if e["kind"] == "vessel_damage"], end_time),
        stages=stages,
        frame_time=time,
        tips=tips,
        forces=forces,
        timeline=timeline,
        stats_time=np.array([s["time"] for s in recording.stats]),
        stage_series=stage_series,
        views=view_series(recording.stats),
    )
    if task is not None:
        metrics.task = judge_task(task, metrics, recording.events)
    return metrics
