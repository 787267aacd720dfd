"""The session report: one self-contained HTML page (plots embedded as PNG) and the
numbers as JSON, for one recorded session or several (then with a learning curve).

Per session: how it ended (a session that did not end normally, or a file cut short,
is marked incomplete and reported for what it holds), the metrics of each instrument
(:mod:`taichi_lap.training.metrics`), the events counted, the force on each tool
over time, the instrument paths in two projections, the event timeline, and the cost
of each stage per frame (as seed 000 Fig. 17 plots its operation phases).
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from taichi_lap import plots
from taichi_lap.core.files import write_atomically
from taichi_lap.replay import read_recording
from taichi_lap.scene.planned_plane import MARK_COLOUR
from taichi_lap.training.metrics import (
    COUNTED_EVENTS,
    SessionMetrics,
    session_metrics,
    stacked_stages,
)

CURVE_METRICS = {  # learning-curve panels: title -> value of a session
    "duration [s]": lambda m: m.duration,
    "path length [m] (all instruments)": lambda m: sum(
        i.path_length for i in m.instruments.values()
    ),
    "economy of motion (mean)": lambda m: _mean(
        [i.economy for i in m.instruments.values() if i.economy is not None]
    ),
    "idle time [s] (all instruments)": lambda m: sum(i.idle_time for i in m.instruments.values()),
    "peak force [N]": lambda m: max((i.peak_force for i in m.instruments.values()), default=0.0),
    "vessel damage events": lambda m: m.events["vessel_damage"],
}
INSTRUMENT_COLUMNS = (  # (heading, attribute, scale, format)
    ("path [mm]", "path_length", 1e3, "{:.0f}"),
    ("straight [mm]", "straight_length", 1e3, "{:.0f}"),
    ("economy", "economy", 1.0, "{:.2f}"),
    ("idle [s]", "idle_time", 1.0, "{:.2f}"),
    ("force from", "force_source", None, "{}"),
    ("mean force [N]", "mean_force", 1.0, "{:.3f}"),
    ("mean in contact [N]", "mean_contact_force", 1.0, "{:.3f}"),
    ("peak force [N]", "peak_force", 1.0, "{:.3f}"),
    ("in contact [s]", "contact_time", 1.0, "{:.2f}"),
    ("cautery on [s]", "cautery_time", 1.0, "{:.2f}"),
)
STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 1100px; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.2em; }
td, th { border: 1px solid #bbb; padding: 3px 8px; text-align: right; }
th:first-child, td:first-child { text-align: left; }
.incomplete { color: #a00; font-weight: bold; }
img { max-width: 100%; }
"""


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def load_sessions(paths: list[str]) -> list[SessionMetrics]:
    """The metrics of each recording, in the order given. A file that is not a
    readable recording raises :class:`~taichi_lap.core.errors.InputError`."""
    return [session_metrics(read_recording(path)) for path in paths]


def report_numbers(sessions: list[SessionMetrics]) -> dict:
    """The report as JSON data: each session's metrics and, for several, the
    learning curve (each metric per session, in order)."""
    numbers = {"sessions": [m.numbers() for m in sessions]}
    if len(sessions) > 1:
        numbers["learning_curve"] = {
            title: [value(m) for m in sessions] for title, value in CURVE_METRICS.items()
        }
    return numbers


def write_report(paths: list[str], out: str | Path, json_out: str | Path | None = None) -> dict:
    """Read the recordings ``paths``, write the HTML page ``out`` and, with
    ``json_out``, the numbers (both atomically); returns the numbers."""
    sessions = load_sessions(paths)
    numbers = report_numbers(sessions)
    write_atomically(out, report_html(sessions))
    if json_out is not None:
        write_atomically(json_out, json.dumps(numbers, indent=2))
    return numbers


def report_html(sessions: list[SessionMetrics]) -> str:
    """The whole page (module docstring)."""
    title = "Session report" if len(sessions) == 1 else f"Report of {len(sessions)} sessions"
    body = [f"<h1>{title}</h1>"]
    if len(sessions) > 1:
        body += ["<h2>Learning curve</h2>", _image(_learning_curve(sessions), "learning curve")]
    for number, metrics in enumerate(sessions, 1):
        body += _session_section(number, metrics)
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{title}</title><style>{STYLE}</style></head><body>\n"
        + "\n".join(body)
        + "\n</body></html>\n"
    )


def _session_section(number: int, m: SessionMetrics) -> list[str]:
    status = html.escape(m.status)
    if not m.complete:
        status = f"<span class='incomplete'>{status} (the report covers what the file holds)</span>"
    rows = [
        ("file", html.escape(m.path)),
        ("scene", html.escape(m.scene)),
        ("started", html.escape(m.started)),
        ("status", status),
        ("frames", str(m.frames)),
        ("duration [s]", f"{m.duration:.2f}"),
        ("blood lost [ml]", f"{m.blood_lost:.1f}"),
    ]
    parts = [f"<h2>Session {number}: {html.escape(m.scene)}</h2>", _table(None, rows)]
    parts += _task_section(m.task)
    parts += ["<h3>Instruments</h3>", _instrument_table(m)]
    parts += ["<h3>Organs touched</h3>", _touched_table(m)]
    parts += ["<h3>Events</h3>", _table(("event", "count"), list(m.events.items()))]
    parts += ["<h3>Force on each tool</h3>", _image(_force_plot(m), "force over time")]
    parts += ["<h3>Instrument paths</h3>", _image(_path_plot(m), "instrument paths")]
    parts += ["<h3>Event timeline</h3>", _image(_timeline_plot(m), "event timeline")]
    parts += ["<h3>Cost per frame by stage</h3>", _image(_stage_plot(m), "stage cost")]
    return parts


def _task_section(task: dict | None) -> list[str]:
    """The task's verdict, its goal and its checks, or a line saying the scene has no
    task."""
    if task is None:
        return ["<h3>Task</h3>", "<p>The scene has no task: nothing is judged.</p>"]
    verdict = "passed" if task["passed"] else "<span class='incomplete'>failed</span>"
    rows = [
        (
            html.escape(check["metric"]),
            _number(check["value"]),
            f"{'at least' if check['at_least'] else 'at most'} {check['bound']:.4g}",
            check["unit"],
            "yes" if check["passed"] else "<span class='incomplete'>no</span>",
        )
        for check in task["checks"]
    ]
    forbidden = ", ".join(task["forbidden"]) or "none"
    return [
        f"<h3>Task: {html.escape(task['name'] or 'unnamed')} ({verdict})</h3>",
        f"<p>{html.escape(task['instructions'])}</p>",
        f"<p>Forbidden organs: {html.escape(forbidden)}; contacts with them: "
        f"{task['forbidden_contacts']}.</p>",
        *_goal_section(task["goal"]),
        _table(("requirement", "value", "bound", "unit", "passed"), rows),
    ]


def _goal_section(goal: dict) -> list[str]:
    """The goal's phases with the time each completed, the wound against the planned
    plane, the tissue removed in all and outside the goal, and the view target's
    time in view."""
    rows = [
        (f"phase {k}: {html.escape(phase['name'])}", _seconds(phase["completed_at"]))
        for k, phase in enumerate(goal["phases"], 1)
    ]
    plane = goal["plane"]
    if plane is not None:
        rows += [
            (
                f"planned plane through the {html.escape(plane['organ'])}: line reached",
                f"{100 * plane['coverage']:.0f} % (needed {100 * plane['coverage_needed']:.0f} %)",
            ),
            (
                "wound distance from the plane, mean / largest [mm]",
                f"{_number(plane['distance_mean'], 1e3)} / {_number(plane['distance_max'], 1e3)}",
            ),
            ("line reached at", _seconds(plane["reached_at"])),
        ]
    rows += [
        (
            "tissue removed, outside the goal [ml]",
            f"{goal['removed']:.3f}, {goal['removed_outside']:.3f}",
        ),
        *_view_rows(goal["view"]),
        ("time to completion", _seconds(goal["time_to_completion"])),
    ]
    if not goal["has_goal"]:
        rows = rows[-2:-1]
    return ["<h4>Goal</h4>", _table(None, rows)]


def _view_rows(view: dict | None) -> list[tuple[str, str]]:
    """The view target's rows of the goal table (none without a view goal)."""
    if view is None:
        return []
    target = html.escape(view["target"])
    return [
        (
            f"{target} in view: best visible",
            f"{100 * view['visible_best']:.0f} % (needed {100 * view['visible_needed']:.0f} %"
            f" of it, filling {100 * view['share_needed']:.0f} % of the image)",
        ),
        (
            f"{target} in view: in all, longest [s]",
            f"{view['in_view_time']:.1f}, {view['longest_in_view']:.1f} (needed {view['hold']:.1f})",
        ),
        ("view held at", _seconds(view["reached_at"])),
    ]


def _number(value, scale: float = 1.0) -> str:
    return "—" if value is None else f"{value * scale:.4g}"


def _seconds(value) -> str:
    return "not reached" if value is None else f"{value:.2f} s"


def _touched_table(m: SessionMetrics) -> str:
    forbidden = set(m.task["forbidden"]) if m.task else set()
    rows = [
        (
            html.escape(name),
            html.escape(organ) + (" (forbidden)" if organ in forbidden else ""),
            f"{touch['time']:.2f}",
            str(touch["contacts"]),
        )
        for name, metrics in m.instruments.items()
        for organ, touch in metrics.touched.items()
    ]
    return _table(("instrument", "organ", "touching [s]", "contacts"), rows)


def _instrument_table(m: SessionMetrics) -> str:
    rows = []
    for name, metrics in m.instruments.items():
        cells = [html.escape(name)]
        for _, attribute, scale, form in INSTRUMENT_COLUMNS:
            value = getattr(metrics, attribute)
            if value is None:
                cells.append("—")
            else:
                cells.append(form.format(value * scale if scale is not None else value))
        rows.append(cells)
    return _table(("instrument", *(c[0] for c in INSTRUMENT_COLUMNS)), rows)


def _table(heading, rows) -> str:
    head = "<tr>" + "".join(f"<th>{h}</th>" for h in heading) + "</tr>" if heading else ""
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table>{head}{body}</table>"


def _image(png: bytes, alt: str) -> str:
    return f"<img alt='{alt}' src='data:image/png;base64,{base64.b64encode(png).decode()}'>"


def _force_plot(m: SessionMetrics) -> bytes:
    fig, axes = plots.figure(size=(9.0, 2.8))
    ax = axes[0, 0]
    for name, series in m.forces.items():
        if len(series.time):
            ax.plot(series.time, series.magnitude, lw=1, label=f"{name} ({series.source})")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("|force| [N]")
    _legend_or_note(ax, "no force recorded")
    return plots.png_bytes(fig)


def _path_plot(m: SessionMetrics) -> bytes:
    """The tips' paths seen from above (x, z) and from the front (x, y), waypoints
    marked, and the task's planned line (dashed green, as drawn on the tissue)."""
    fig, axes = plots.figure(1, 2, size=(9.0, 4.0))
    plane = ((m.task or {}).get("goal") or {}).get("plane")
    planned = 1e3 * np.array(plane["line"]) if plane else None
    for ax, (a, b), view in zip(axes[0], ((0, 2), (0, 1)), ("from above", "from the front")):
        if planned is not None:
            ax.plot(planned[:, a], planned[:, b], "--", color=MARK_COLOUR, label="planned line")
        for name, tips in m.tips.items():
            if len(tips):
                line = ax.plot(1e3 * tips[:, a], 1e3 * tips[:, b], lw=1, label=name)[0]
                waypoints = np.array(m.instruments[name].waypoints)
                ax.plot(1e3 * waypoints[:, a], 1e3 * waypoints[:, b], "o", color=line.get_color())
        ax.set_xlabel(f"{'xyz'[a]} [mm]")
        ax.set_ylabel(f"{'xyz'[b]} [mm]")
        ax.set_title(view, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        _legend_or_note(ax, "no instrument")
    return plots.png_bytes(fig)


def _timeline_plot(m: SessionMetrics) -> bytes:
    fig, axes = plots.figure(size=(9.0, 2.8))
    ax = axes[0, 0]
    rows = {kind: k for k, kind in enumerate(COUNTED_EVENTS)}
    if m.timeline:
        ax.plot([e["time"] for e in m.timeline], [rows[e["kind"]] for e in m.timeline], "|", ms=12)
    ax.set_yticks(range(len(COUNTED_EVENTS)), COUNTED_EVENTS, fontsize=7)
    begin = m.frame_time[0] if m.frames else 0.0
    ax.set_xlim(begin, begin + max(m.duration, 1e-3))
    ax.set_xlabel("time [s]")
    return plots.png_bytes(fig)


def _stage_plot(m: SessionMetrics) -> bytes:
    fig, axes = plots.figure(size=(9.0, 2.8))
    ax = axes[0, 0]
    if m.stage_series:
        parts = stacked_stages(m.stage_series)
        ax.stackplot(m.stats_time, *parts.values(), labels=list(parts))
        total = np.sum(list(parts.values()), axis=0)
        top = 1.5 * np.percentile(total, 95)
        above = int((total > top).sum())
        ax.set_ylim(0.0, top)
        if above:  # the first frames of a process compile kernels
            ax.set_title(
                f"{above} frame{'s' if above > 1 else ''} above the scale "
                f"(up to {total.max():.0f} ms)",
                fontsize=9,
            )
    ax.set_xlabel("time [s]")
    ax.set_ylabel("ms per frame")
    _legend_or_note(ax, "no statistics recorded")
    return plots.png_bytes(fig)


def _learning_curve(sessions: list[SessionMetrics]) -> bytes:
    fig, axes = plots.figure(2, 3, size=(10.0, 5.0))
    order = np.arange(1, len(sessions) + 1)
    for ax, (title, value) in zip(axes.flat, CURVE_METRICS.items()):
        values = [value(m) for m in sessions]
        ax.plot(order, [np.nan if v is None else v for v in values], "o-")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("session")
        ax.set_xticks(order)
    return plots.png_bytes(fig)


def _legend_or_note(ax, note: str):
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, note, transform=ax.transAxes, ha="center", va="center")
