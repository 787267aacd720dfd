"""Training metrics and the session report, on synthetic recordings whose answers are
known: a straight path, a half circle, a path with a stop, a known force profile,
planted events, and files cut short or damaged."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from taichi_lap.cli import main
from taichi_lap.core.errors import InputError
from taichi_lap.devices import Pose
from taichi_lap.recording import (
    CRC,
    HEADER,
    RECORD_HEAD,
    RecordStream,
    encode_event,
    encode_frame,
    encode_stats,
)
from taichi_lap.replay import read_recording
from taichi_lap.scene import validate
from taichi_lap.training.live import LiveScore, verdict_lines
from taichi_lap.training.metrics import IDLE_SPEED, session_metrics, stacked_stages
from taichi_lap.training.report import report_html
from taichi_lap.training.task import recorded_task

DT = 0.01  # [s]
UP = np.array([0.0, 1.0, 0.0])
CLOCK = 500.0  # [s] the monotonic clock at the first frame


def write_session(
    path,
    tips: dict[str, np.ndarray],
    *,
    events=(),
    ticks=(),
    stats=(),
    end: bool = True,
    raw_scene=None,
):
    """A recording of ``tips`` (per tool, (frames, 3) [m]) one frame per DT, with
    ``events`` ``(frame, kind, fields)`` after their frame, haptic ``ticks``
    ``(clock, tool, force)`` and ``stats`` ``(frame, stages, forces[, contacts])``,
    of the scene ``raw_scene`` (its TOML tables)."""
    tools = list(tips)
    start = encode_event(
        "session_start",
        time=0.0,
        frame=0,
        scene="synthetic",
        source="synthetic.toml",
        digest="0" * 64,
        raw_scene=raw_scene or {},
        dt=DT,
        arch="cpu",
        threads=1,
        versions={},
        tools=tools,
        started="2026-11-27T12:00:00+00:00",
    )
    stream = RecordStream.create(path, start, tools)
    count = len(next(iter(tips.values())))
    for k in range(count):
        clock = CLOCK + k * DT
        for tick_clock, tool, force in ticks:
            if clock - DT < tick_clock <= clock:
                stream.tick(tick_clock, {tool: (Pose(tips[tool][k], UP), 0, np.asarray(force))})
        poses = {name: Pose(tips[name][k], UP) for name in tools}
        stream.append(encode_frame(k * DT, k, clock, poses))
        for frame, kind, fields in events:
            if frame == k:
                stream.append(encode_event(kind, time=(k + 1) * DT, frame=k + 1, **fields))
        for frame, stages, forces, *contacts in stats:
            if frame == k:
                stream.append(encode_stats((k + 1) * DT, k + 1, stages, forces, *contacts))
    if end:
        stream.append(
            encode_event(
                "session_end",
                time=count * DT,
                frame=count,
                status="complete",
                frames=count,
                checksum="0" * 64,
            )
        )
    stream.close()
    return path


def line(start, end, frames: int) -> np.ndarray:
    return np.linspace(start, end, frames)


def test_a_straight_path_has_economy_one_and_no_idle_time(tmp_path):
    tips = line([0.0, 0.0, 0.0], [0.1, 0.0, 0.0], 101)  # 0.1 m in 1 s
    metrics = session_metrics(read_recording(write_session(tmp_path / "s.tlap", {"probe": tips})))
    probe = metrics.instruments["probe"]
    assert probe.path_length == pytest.approx(0.1, rel=1e-12)
    assert probe.straight_length == pytest.approx(0.1, rel=1e-12)
    assert probe.economy == pytest.approx(1.0, rel=1e-12)
    assert probe.idle_time == 0.0
    assert probe.waypoints == [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]
    assert metrics.duration == pytest.approx(101 * DT)
    assert metrics.complete and metrics.status == "complete"
    assert probe.force_source == "none" and probe.peak_force == 0.0


def test_a_half_circle_has_the_economy_of_its_arc_over_its_chord(tmp_path):
    radius, segments = 0.05, 200
    angle = np.linspace(0.0, math.pi, segments + 1)
    tips = np.stack([radius * np.cos(angle), np.zeros_like(angle), radius * np.sin(angle)], 1)
    metrics = session_metrics(read_recording(write_session(tmp_path / "c.tlap", {"probe": tips})))
    probe = metrics.instruments["probe"]
    polygon = 2 * segments * radius * math.sin(math.pi / (2 * segments))  # its exact length
    assert probe.path_length == pytest.approx(polygon, rel=1e-9)
    assert probe.straight_length == pytest.approx(2 * radius, rel=1e-12)
    assert probe.economy == pytest.approx(polygon / (2 * radius), rel=1e-9)
    assert probe.economy == pytest.approx(math.pi / 2, rel=1e-4)


def test_a_tasks_waypoints_replace_the_stops_in_the_economy(tmp_path):
    """A half circle whose task asks the probe to pass its apex: the straight path
    goes from the start through the apex to the end (economy π r / (2 √2 r))."""
    radius, segments = 0.05, 200
    angle = np.linspace(0.0, math.pi, segments + 1)
    tips = np.stack([radius * np.cos(angle), np.zeros_like(angle), radius * np.sin(angle)], 1)
    apex = [0.0, 0.0, radius]
    scene = {"tools": [{"name": "probe"}], "task": {"waypoints": {"probe": [apex]}}}
    path = write_session(tmp_path / "a.tlap", {"probe": tips}, raw_scene=scene)
    probe = session_metrics(read_recording(path)).instruments["probe"]
    np.testing.assert_allclose(probe.waypoints, [tips[0], apex, tips[-1]], atol=1e-12)
    assert probe.straight_length == pytest.approx(2 * math.sqrt(2) * radius, rel=1e-12)
    polygon = 2 * segments * radius * math.sin(math.pi / (2 * segments))
    assert probe.economy == pytest.approx(polygon / (2 * math.sqrt(2) * radius), rel=1e-9)


def test_a_stop_is_a_waypoint_and_its_time_is_idle(tmp_path):
    corner = [0.05, 0.0, 0.0]
    tips = np.concatenate(
        [
            line([0.0, 0.0, 0.0], corner, 51),  # 0.5 s along x
            np.repeat([corner], 50, axis=0),  # 0.5 s at rest
            line(corner, [0.05, 0.05, 0.0], 51)[1:],  # 0.5 s along y
        ]
    )
    tips[60:70] += [0.0, 0.0, 0.3 * IDLE_SPEED * DT]  # a drift below the idle speed
    metrics = session_metrics(read_recording(write_session(tmp_path / "w.tlap", {"probe": tips})))
    probe = metrics.instruments["probe"]
    assert len(probe.waypoints) == 3
    np.testing.assert_allclose(probe.waypoints[1], corner, atol=1e-12)
    assert probe.straight_length == pytest.approx(0.1, rel=1e-12)
    assert probe.idle_time == pytest.approx(0.5, abs=1e-9)
    assert probe.economy == pytest.approx(probe.path_length / 0.1)
    assert probe.economy == pytest.approx(1.0, abs=1e-3)


def test_a_known_haptic_force_profile_gives_its_mean_peak_and_contact_time(tmp_path):
    tips = line([0.0, 0.0, 0.0], [0.0, 0.0, 0.01], 101)
    # 1 kHz ticks: 2 N up for the first 0.25 s, a 3 N peak at one tick, then nothing
    ticks = [
        (CLOCK + 0.001 * k - DT + 1e-6, "probe", [0.0, 2.0 if k < 250 else 0.0, 0.0])
        for k in range(1000)
    ]
    ticks[100] = (ticks[100][0], "probe", [0.0, 0.0, -3.0])
    path = write_session(tmp_path / "f.tlap", {"probe": tips}, ticks=ticks)
    probe = session_metrics(read_recording(path)).instruments["probe"]
    assert probe.force_source == "haptic"
    assert probe.peak_force == pytest.approx(3.0, rel=1e-6)
    assert probe.mean_force == pytest.approx((249 * 2.0 + 3.0) / 1000, rel=1e-6)
    assert probe.mean_contact_force == pytest.approx((249 * 2.0 + 3.0) / 250, rel=1e-6)
    assert probe.contact_time == pytest.approx(0.25, rel=1e-6)


def test_without_ticks_the_force_comes_from_the_simulation_statistics(tmp_path):
    tips = {"grasper": line([0.0, 0.0, 0.0], [0.0, 0.01, 0.0], 10)}
    stats = [
        (k, {"physics": 5.0 + k, "render": 2.0}, {"grasper": [0.0, 0.0, 0.1 * k]})
        for k in range(10)
    ]
    metrics = session_metrics(read_recording(write_session(tmp_path / "s.tlap", tips, stats=stats)))
    grasper = metrics.instruments["grasper"]
    assert grasper.force_source == "simulation"
    assert grasper.peak_force == pytest.approx(0.9)
    assert grasper.mean_force == pytest.approx(0.45)
    assert grasper.contact_time == pytest.approx(9 * DT)  # 0.1 .. 0.9 N, above 0.05 N
    assert metrics.stages["physics"]["median"] == pytest.approx(9.5)
    assert metrics.stages["render"] == {"mean": 2.0, "median": 2.0, "p95": 2.0}


def test_planted_events_are_counted_and_cautery_time_is_summed(tmp_path):
    tips = {"hook": line([0.0, 0.0, 0.0], [0.02, 0.0, 0.0], 100)}  # frames end at 1.0 s
    events = [
        (19, "cautery_on", {"tool": "hook"}),  # at 0.2 s
        (34, "vessel_damage", {"tool": "hook", "organ": "vessel"}),
        (49, "cautery_off", {"tool": "hook"}),  # at 0.5 s
        (79, "cautery_on", {"tool": "hook"}),  # at 0.8 s, on to the end
        (89, "cut", {"tool": "hook", "organ": "fascia", "triangles": 4}),
    ]
    path = write_session(tmp_path / "e.tlap", tips, events=events)
    metrics = session_metrics(read_recording(path))
    assert metrics.events["vessel_damage"] == 1 and metrics.events["cut"] == 1
    assert metrics.events["tear"] == 0
    assert [e["kind"] for e in metrics.timeline] == ["vessel_damage", "cut"]
    assert metrics.timeline[0]["time"] == pytest.approx(0.35)
    assert metrics.instruments["hook"].cautery_time == pytest.approx(0.3 + 0.2)
    # the vessel bleeds from 0.35 s to the end at 1.0 s: 0.5 ml/s, clotting over 15 s
    assert metrics.blood_lost == pytest.approx(0.5 * 15.0 * (1.0 - math.exp(-0.65 / 15.0)))


def test_a_session_without_its_end_or_cut_short_is_reported_incomplete(tmp_path, caplog):
    tips = {"probe": line([0.0, 0.0, 0.0], [0.05, 0.0, 0.0], 60)}
    killed = write_session(tmp_path / "killed.tlap", tips, end=False)
    metrics = session_metrics(read_recording(killed))
    assert not metrics.complete and "no session_end" in metrics.status
    assert metrics.frames == 60

    cut = tmp_path / "cut.tlap"
    cut.write_bytes(write_session(tmp_path / "whole.tlap", tips).read_bytes()[:-7])
    metrics = session_metrics(read_recording(cut))
    assert not metrics.complete and "cut record" in metrics.status
    assert metrics.frames == 60  # every frame precedes the cut session_end
    assert metrics.instruments["probe"].path_length == pytest.approx(0.05)
    page = report_html([metrics])
    assert "class='incomplete'" in page and "the report covers what the file holds" in page

    # killed before its first frame: a report of nothing, still a report
    empty = write_session(tmp_path / "empty.tlap", {"probe": np.zeros((0, 3))}, end=False)
    metrics = session_metrics(read_recording(empty))
    assert metrics.frames == 0 and metrics.duration == 0.0 and not metrics.complete
    assert metrics.instruments["probe"].path_length == 0.0
    assert metrics.instruments["probe"].economy is None
    assert "no session_end" in report_html([metrics])


def test_the_report_of_two_sessions_holds_every_section_and_the_learning_curve(tmp_path, capsys):
    stats = [(k, {"physics": 4.0, "render": 3.0}, {"probe": [0.0, 0.2, 0.0]}) for k in range(30)]
    first = write_session(
        tmp_path / "1.tlap",
        {"probe": line([0.0, 0.0, 0.0], [0.06, 0.0, 0.0], 30)},
        stats=stats,
        events=[(10, "grasp", {"tool": "probe", "particles": 3})],
    )
    second = write_session(
        tmp_path / "2.tlap", {"probe": line([0.0, 0.0, 0.0], [0.03, 0.0, 0.0], 20)}
    )
    out, numbers_path = tmp_path / "report" / "r.html", tmp_path / "r.json"
    status = main(
        ["report", str(first), str(second), "--out", str(out), "--json", str(numbers_path)]
    )
    assert status == 0
    assert "wrote" in capsys.readouterr().out
    page = out.read_text()
    for heading in (
        "Learning curve",
        "Session 1: synthetic",
        "Session 2: synthetic",
        "Instruments",
        "Events",
        "Force on each tool",
        "Instrument paths",
        "Event timeline",
        "Cost per frame by stage",
    ):
        assert f">{heading}<" in page, heading
    assert page.count("src='data:image/png;base64,") == 1 + 2 * 4  # nothing loaded from outside
    numbers = json.loads(numbers_path.read_text())
    assert [s["frames"] for s in numbers["sessions"]] == [30, 20]
    curve = numbers["learning_curve"]
    assert curve["path length [m] (all instruments)"] == pytest.approx([0.06, 0.03])
    assert curve["duration [s]"] == pytest.approx([0.3, 0.2])
    assert numbers["sessions"][0]["events"]["grasp"] == 1
    assert numbers["sessions"][0]["instruments"]["probe"]["peak_force"] == pytest.approx(0.2)


def test_a_damaged_or_foreign_file_is_one_line_with_status_2(tmp_path, capsys):
    whole = write_session(tmp_path / "w.tlap", {"probe": line([0, 0, 0], [0.01, 0, 0], 10)})
    data = bytearray(whole.read_bytes())
    offset = HEADER.size
    for _ in range(4):  # to the fifth record: its payload's first byte flipped
        offset += RECORD_HEAD.size + RECORD_HEAD.unpack_from(data, offset)[1] + CRC.size
    data[offset + RECORD_HEAD.size] ^= 0xFF
    damaged = tmp_path / "damaged.tlap"
    damaged.write_bytes(bytes(data))
    foreign = tmp_path / "notes.txt"
    foreign.write_text("not a recording")
    for path, expected in ((damaged, "damaged record"), (foreign, "was expected")):
        status = main(["report", str(path), "--out", str(tmp_path / "r.html")])
        err = capsys.readouterr().err
        assert status == 2
        assert err.startswith(f"error: {path}") and expected in err
        assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "r.html").exists()


TASK_SCENE = {
    "organs": [{"name": "colon"}, {"name": "vessel"}],
    "task": {
        "name": "Expose the colon",
        "instructions": "Lift the loop off the colon; do not touch the vessel.",
        "time_limit": 1.5,
        "forbidden": ["vessel"],
        "pass": {"path_length": 0.2, "forbidden_contacts": 0, "peak_force": 1.0},
    },
}


def touching(frames: int, pattern: dict[str, list[int]]) -> list[tuple]:
    """Statistics records where the probe touches each organ of ``pattern`` with the
    particle counts given per frame (0: not touching)."""
    return [
        (
            k,
            {"physics": 1.0},
            {"probe": [0.0, 0.3, 0.0]},
            {"probe": {organ: counts[k] for organ, counts in pattern.items() if counts[k]}},
        )
        for k in range(frames)
    ]


def test_organ_contacts_count_the_contacts_begun_and_their_time(tmp_path):
    pattern = {"colon": [0, 3, 5, 0, 0, 2, 0, 1, 1, 1], "vessel": [1, 0, 0, 0, 0, 0, 0, 0, 0, 0]}
    path = write_session(
        tmp_path / "t.tlap",
        {"probe": line([0.0, 0.0, 0.0], [0.01, 0.0, 0.0], 10)},
        stats=touching(10, pattern),
    )
    touched = session_metrics(read_recording(path)).instruments["probe"].touched
    assert touched == {
        "colon": {"time": pytest.approx(6 * DT), "contacts": 3},
        "vessel": {"time": pytest.approx(DT), "contacts": 1},  # touching from the start
    }


def test_a_task_passes_within_its_bounds_and_fails_naming_the_bound_it_broke(tmp_path):
    frames = 100  # 1 s, within the time limit

    def judged(name: str, pattern: dict, length: int = frames, **kwargs) -> dict:
        """The task's result for the probe moving 0.1 m in ``length`` frames, touching
        the organs as ``pattern`` says in the first ``frames``."""
        path = write_session(
            tmp_path / f"{name}.tlap",
            {"probe": line([0.0, 0.0, 0.0], [0.1, 0.0, 0.0], length)},
            stats=touching(frames, pattern),
            raw_scene=TASK_SCENE,
            **kwargs,
        )
        return session_metrics(read_recording(path))

    careful = {"colon": [1] * frames, "vessel": [0] * frames}
    task = judged("expert", careful).task
    assert task["passed"] and task["name"] == "Expose the colon"
    assert [c["metric"] for c in task["checks"]] == [
        "time_limit",
        "path_length",
        "peak_force",
        "forbidden_contacts",
    ]
    assert all(c["passed"] for c in task["checks"])

    careless = {"colon": [1] * frames, "vessel": [0] * 40 + [2] * 5 + [0] * 30 + [1] * 25}
    metrics = judged("careless", careless, 2 * frames)  # 2 s, past the time limit
    task = metrics.task
    failed = {c["metric"]: c["value"] for c in task["checks"] if not c["passed"]}
    assert not task["passed"]
    assert failed == {"time_limit": pytest.approx(2.0), "forbidden_contacts": 2}
    assert task["forbidden_contacts"] == 2
    page = report_html([metrics])
    assert "Task: Expose the colon (<span class='incomplete'>failed</span>)" in page
    assert "vessel (forbidden)" in page

    task = judged("unfinished", careful, end=False).task
    assert all(c["passed"] for c in task["checks"]) and not task["passed"]


@pytest.mark.parametrize(
    "task, key, message",
    [
        ({"forbidden": ["liver"]}, "task.forbidden[0]", "an organ in this scene (colon, vessel)"),
        ({"forbidden": "vessel"}, "task.forbidden", "an array of strings was expected"),
        ({"pass": {"speed": 1.0}}, "task.pass.speed", "unknown key in task.pass"),
        ({"pass": {"economy": 0.5}}, "task.pass.economy", "a value in [1, 10000]"),
        ({"time_limit": -1.0}, "task.time_limit", "a value in [0, 86400] s"),
        ({"waypoints": {"hook": [[0, 0, 0]]}}, "task.waypoints.hook", "a tool in this scene"),
        ({"waypoints": [[0, 0, 0]]}, "task.waypoints", "a table of tool names"),
    ],
)
def test_a_bad_task_table_names_its_key(task, key, message):
    organs = [
        {
            "name": name,
            "model": "tet_clusters",
            "geometry": {"generator": "box", "half_extents": [0.01, 0.01, 0.01]},
        }
        for name in ("colon", "vessel")
    ]
    with pytest.raises(InputError) as error:
        validate({"scene": {"name": "t"}, "organs": organs, "task": task}, "t.toml", Path("."))
    assert error.value.key == key and message in error.value.message


def test_the_live_score_agrees_with_the_metrics_of_the_recorded_frames(tmp_path):
    rng = np.random.default_rng(3)
    frames = 60
    tips = {
        "probe": np.cumsum(rng.normal(0.0, 0.002, (frames, 3)), axis=0),
        "grasper": np.cumsum(rng.normal(0.0, 0.001, (frames, 3)), axis=0),
    }
    forces = {name: rng.normal(0.0, 0.5, (frames, 3)) for name in tips}
    vessel = rng.random((frames, 2)) < 0.3  # per tool, touching the forbidden vessel
    contacts = [
        {
            name: {"colon": 2, **({"vessel": 1} if vessel[k, column] else {})}
            for column, name in enumerate(tips)
        }
        for k in range(frames)
    ]
    stats = [
        (k, {"physics": 1.0}, {name: forces[name][k] for name in tips}, contacts[k])
        for k in range(frames)
    ]
    path = write_session(tmp_path / "l.tlap", tips, stats=stats, raw_scene=TASK_SCENE)
    metrics = session_metrics(read_recording(path))
    task = recorded_task(read_recording(path))
    live = LiveScore(task, list(tips), DT)
    for k in range(frames):
        live.update(
            {name: tips[name][k] for name in tips},
            {name: forces[name][k] for name in tips},
            contacts[k],
        )
    assert live.elapsed == pytest.approx(metrics.duration)
    for name in tips:
        assert live.path_length[name] == pytest.approx(metrics.instruments[name].path_length)
        assert live.peak_force[name] == pytest.approx(metrics.instruments[name].peak_force)
    assert live.forbidden_contacts == metrics.task["forbidden_contacts"] > 0
    assert live.lines()[0] == "task: Expose the colon"
    assert f"contacts with vessel: {live.forbidden_contacts}" in live.lines()
    assert not live.over_time  # 0.6 s of a 1.5 s limit
    for _ in range(90):
        live.update({}, {}, {})
    assert live.over_time and "TIME UP" in live.lines()[3]
    verdict = verdict_lines(metrics.task)
    assert verdict[0] == "task Expose the colon: FAILED"
    assert f"  forbidden_contacts: {live.forbidden_contacts}, at most 0" in verdict


def test_stacked_stages_split_the_physics_into_deformation_and_collision():
    series = {
        "render": np.array([3.0, 4.0]),
        "physics": np.array([10.0, 12.0]),
        "collision": np.array([4.0, 5.0]),
        "devices": np.array([0.5, 0.5]),
        "upload": np.array([1.0, 1.0]),
    }
    parts = stacked_stages(series)
    assert list(parts) == ["deformation", "collision", "devices", "render", "upload"]
    np.testing.assert_array_equal(parts["deformation"], [6.0, 7.0])
    total = np.sum(list(parts.values()), axis=0)
    np.testing.assert_array_equal(total, [14.5, 17.5])  # physics + devices + render + upload
