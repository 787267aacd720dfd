"""Session recording and replay: a recorded run replays bit for bit, a cut or
killed recording reads up to its last complete record, and bad files are named."""

import logging
import os
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.cli import main
from taichi_lap.core.errors import InputError
from taichi_lap.devices import Pose
from taichi_lap.recording import (
    CRC,
    FRAME_HEAD,
    FRAME_TOOL,
    FRAME_TOOL_V1,
    HEADER,
    MAGIC,
    RECORD_HEAD,
    TAG_FRAME,
    TAG_TICK,
    TICK_HEAD,
    TICK_TOOL,
    TICK_TOOL_V1,
    SessionRecorder,
    encode_event,
    encode_record,
    state_checksum,
)
from taichi_lap.replay import ReplayDevice, read_recording
from taichi_lap.session import Session, scene_script
from taichi_lap.training.metrics import session_metrics

SMALL = ["--set", "scene.detail=0.03"]
RUN = ["run", "intestine", "--headless", "--size", "64x48", *SMALL]
FRAMES = 64  # the probe's script reaches the intestine at frame 56


@pytest.fixture(scope="module")
def scene():
    return scene_mod.load("intestine", {"scene.detail": 0.03})


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recording of the intestine scene's own tool script, made through the CLI."""
    folder = tmp_path_factory.mktemp("recorded")
    path = folder / "session.tlap"
    status = main(
        [*RUN, "--frames", str(FRAMES), "--out", str(folder / "frames"), "--record", str(path)]
    )
    assert status == 0
    return path


def record_bounds(data: bytes) -> list[tuple[int, int]]:
    """(start, end) byte offsets of each record, parsed from the documented framing."""
    bounds, offset = [], HEADER.size
    while offset < len(data):
        _, length = RECORD_HEAD.unpack_from(data, offset)
        end = offset + RECORD_HEAD.size + length + CRC.size
        bounds.append((offset, end))
        offset = end
    return bounds


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_replay_reproduces_the_recorded_final_state(recorded, tmp_path, capsys):
    status, out, err = run_cli(
        capsys, *RUN, "--out", str(tmp_path / "r"), "--device", f"replay:{recorded}"
    )
    assert status == 0, err
    assert f"replay matches {recorded}" in out and f"after {FRAMES} frames" in out


def test_each_recorded_frame_has_its_stage_times_and_tool_force(recorded):
    stats = read_recording(recorded).stats
    assert [s["frame"] for s in stats] == list(range(1, FRAMES + 1))
    assert all({"devices", "physics", "collision", "render"} <= set(s["stages"]) for s in stats)
    # the collision pipelines are a part of the physics (the intestine's self-collision)
    assert all(0.0 < s["stages"]["collision"] < s["stages"]["physics"] for s in stats)
    force = np.linalg.norm([s["forces"]["probe"] for s in stats], axis=1)
    assert np.isfinite(force).all()
    assert force[:15].max() == 0.0  # the probe comes down through the air
    assert force[56:].max() > 0.1  # and pushes the intestine from frame 56
    # the particles pushing it are the ones counted as touching it (the one organ)
    touching = np.array([s["contacts"]["probe"].get("intestine", 0) for s in stats])
    assert all(set(s["contacts"]["probe"]) <= {"intestine"} for s in stats)
    np.testing.assert_array_equal(touching > 0, force > 0.0)


def test_a_recorded_run_of_a_task_prints_the_verdict_of_its_report(tmp_path, capsys):
    """The intestine's probe script as a task that also forbids touching the intestine:
    the run prints the failed bounds, as the report judges them from the file (in these
    few frames the colon is not yet exposed, so its view goal fails too)."""
    path = tmp_path / "task.tlap"
    task = [
        *("--set", 'task.name="Hands off"'),
        *("--set", 'task.forbidden=["intestine"]'),
        *("--set", "task.pass.forbidden_contacts=0"),
        *("--set", "task.time_limit=5.0"),
    ]
    status, out, err = run_cli(
        capsys,
        *RUN,
        *task,
        "--frames",
        str(FRAMES),
        "--out",
        str(tmp_path / "f"),
        "--record",
        str(path),
    )
    assert status == 0, err
    judged = session_metrics(read_recording(path)).task
    assert not judged["passed"] and judged["forbidden_contacts"] >= 1
    failed = [c["metric"] for c in judged["checks"] if not c["passed"]]
    assert failed == ["colon held in view", "time to completion", "forbidden_contacts"]
    assert "task Hands off: FAILED" in out
    assert f"  forbidden_contacts: {judged['forbidden_contacts']}, at most 0" in out


def test_replayed_state_arrays_equal_a_scripted_run(recorded, scene):
    recording = read_recording(recorded)
    assert len(recording.frames) == FRAMES and recording.end["status"] == "complete"
    snapshots, touched = [], False
    for device in (scene_script(scene), ReplayDevice(recording)):
        # one after the other: the replay's session takes the scripted one's closed fields
        with Session(scene, progress=False) as session:
            for _ in range(FRAMES):
                session.step(device.poses(session.state.time))
                touched |= bool(session.state.collided.to_numpy().any())
            snapshots.append(session.state.snapshot())
            checksum = state_checksum(session.state)
    assert touched
    expected, found = snapshots
    for name in expected:
        np.testing.assert_array_equal(found[name], expected[name], err_msg=name)
    assert checksum == recording.end["checksum"]


def test_a_diverging_replay_is_reported_with_status_1(recorded, tmp_path, capsys):
    data = recorded.read_bytes()
    frames = 5
    # session_start, device, then five frames, each with its statistics
    cut = record_bounds(data)[2 + 2 * frames - 1][1]
    forged = tmp_path / "forged.tlap"
    forged.write_bytes(
        data[:cut]
        + encode_event(
            "session_end",
            time=0.0,
            frame=frames,
            status="complete",
            frames=frames,
            checksum="0" * 64,
        )
    )
    status, _, err = run_cli(
        capsys, *RUN, "--out", str(tmp_path / "r"), "--device", f"replay:{forged}"
    )
    assert status == 1
    assert f"error: {forged}: session_end.checksum: the recorded final state 0000" in err
    assert "same backend, threads and versions" in err


def test_a_cut_file_reads_up_to_its_last_complete_record_and_warns(recorded, tmp_path, caplog):
    data = recorded.read_bytes()
    bounds = record_bounds(data)
    cut_file = tmp_path / "cut.tlap"
    for cut in (bounds[1][0] + 3, bounds[10][0] + 30, bounds[-2][0] + 50, len(data) - 1):
        cut_file.write_bytes(data[:cut])
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="taichi_lap"):
            recording = read_recording(cut_file)
        complete = [b for b in bounds if b[1] <= cut]
        read = len(recording.events) + len(recording.frames) + len(recording.stats)
        assert read == len(complete)
        assert recording.truncated_at == complete[-1][1]
        assert f"truncated at byte {recording.truncated_at}" in caplog.text
    cut_file.write_bytes(data[: bounds[20][1]] + bytes(500))  # power cut: a zero-filled tail
    assert read_recording(cut_file).truncated_at == bounds[20][1]
    cut_file.write_bytes(data[: bounds[20][1]])  # a cut between records is a shorter recording
    assert read_recording(cut_file).truncated_at is None
    for cut, key in ((5, "header"), (bounds[0][1] - 1, "record 0")):
        cut_file.write_bytes(data[:cut])
        with pytest.raises(InputError, match=key):
            read_recording(cut_file)


def test_a_killed_recording_leaves_a_readable_file(tmp_path, capsys):
    path = tmp_path / "killed.tlap"
    child = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "taichi_lap",
            *RUN,
            "--frames",
            "100000",
            "--out",
            str(tmp_path / "f"),
            "--record",
            str(path),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        while not (path.exists() and len(read_recording(path).frames) >= 10):
            assert child.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    recording = read_recording(path)
    assert recording.end is None and len(recording.frames) >= 10
    assert [f.frame for f in recording.frames] == list(range(len(recording.frames)))
    status, out, err = run_cli(
        capsys, *RUN, "--frames", "10", "--out", str(tmp_path / "r"), "--device", f"replay:{path}"
    )
    assert status == 0, err
    assert "no session_end record: final state not compared" in out


def _foreign(data: bytes) -> bytes:
    return b"PK\x03\x04" + data[4:]


def _version_7(data: bytes) -> bytes:
    return data[:8] + struct.pack("<I", 7) + data[12:]


def _damaged_middle(data: bytes) -> bytes:
    start, end = record_bounds(data)[10]
    return data[: start + 20] + bytes([data[start + 20] ^ 0xFF]) + data[start + 21 :]


@pytest.mark.parametrize(
    "damage, message",
    [
        (
            _foreign,
            "header: a taichi-lap recording (magic 89 54 4c 41 50 0d 0a 1a) was expected, "
            "found 50 4b 03 04",
        ),
        (_version_7, "header.version: version 1 or 2 was expected, found 7"),
        (_damaged_middle, "record 10 (byte "),
    ],
)
def test_bad_recordings_are_named_with_status_2(recorded, tmp_path, capsys, damage, message):
    bad = tmp_path / "bad.tlap"
    bad.write_bytes(damage(recorded.read_bytes()))
    status, _, err = run_cli(
        capsys, *RUN, "--out", str(tmp_path / "r"), "--device", f"replay:{bad}"
    )
    assert status == 2
    assert err.strip().splitlines() == [err.strip()]  # one line, no traceback
    assert err.startswith(f"error: {bad}: {message}")
    assert "expected" in err and "found" in err


def test_replay_of_another_scene_names_what_differs(recorded, tmp_path, capsys):
    status, _, err = run_cli(
        capsys,
        "run",
        "intestine",
        "--headless",
        "--set",
        "scene.detail=0.04",
        "--out",
        str(tmp_path / "r"),
        "--device",
        f"replay:{recorded}",
    )
    assert status == 2
    assert (
        f"error: {recorded}: session_start.digest: the recorded scene 'intestine' was expected"
        in err
        and "scene.detail = 0.04 (recorded: 0.03)" in err
    )
    status, _, err = run_cli(
        capsys,
        *RUN,
        "--frames",
        str(FRAMES + 1),
        "--out",
        str(tmp_path / "r"),
        "--device",
        f"replay:{recorded}",
    )
    assert status == 2 and f"at most {FRAMES}" in err


def test_a_recording_is_never_overwritten(recorded, tmp_path, capsys):
    before = recorded.read_bytes()
    status, _, err = run_cli(
        capsys, *RUN, "--frames", "1", "--out", str(tmp_path / "r"), "--record", str(recorded)
    )
    assert status == 2 and "--record" in err and "never overwritten" in err
    assert recorded.read_bytes() == before


def test_events_and_haptic_ticks_round_trip_and_unknown_records_are_skipped(scene, tmp_path):
    path = tmp_path / "events.tlap"
    session = Session(scene, progress=False)
    grasp = {"tool": "probe", "particles": np.array([3, 5, 8]), "force": np.float32(0.25)}
    force = np.array([0.5, -1.0, 2.0])
    with SessionRecorder(path, session, scene_script(scene)) as recorder:
        recorder.record_event("grasp", **grasp)
        recorder.record_ticks(
            [
                (
                    100.0 + k * 1e-3,
                    {
                        "probe": (
                            Pose(np.array([0.0, 0.01 * k, 0.0]), np.array([0, 1.0, 0]), 0.25 * k),
                            1,
                            force,
                        )
                    },
                )
                for k in range(3)
            ]
        )
        recorder.stream.append(encode_record(ord("Z"), b"a record type of a later writer"))
        recorder.record_event("release", tool="probe")
        recorder.record_event("dissect", tool="probe", particles=12)
        recorder.record_event("fragment", particles=7)
        with pytest.raises(ValueError, match="event kind"):
            recorder.record_event("grasp_typo")
    recording = read_recording(path)
    kinds = [e["kind"] for e in recording.events]
    assert kinds == [
        "session_start",
        "device",
        "grasp",
        "release",
        "dissect",
        "fragment",
        "session_end",
    ]
    assert recording.events[2] == {
        "kind": "grasp",
        "time": 0.0,
        "frame": 0,
        "tool": "probe",
        "particles": [3, 5, 8],
        "force": 0.25,
    }
    assert recording.events[1]["device"] == "ScriptedDevice"
    assert recording.start["digest"] and recording.start["raw_scene"]["scene"]["detail"] == 0.03
    assert [t.clock for t in recording.ticks] == [100.0 + k * 1e-3 for k in range(3)]
    last = recording.ticks[-1]
    assert last.buttons == {"probe": 1}
    np.testing.assert_array_equal(last.forces["probe"], force.astype(np.float32))
    np.testing.assert_array_equal(last.poses["probe"].tip, np.float32([0.0, 0.02, 0.0]))
    assert last.poses["probe"].roll == 0.5


def _as_version_1(data: bytes) -> bytes:
    """``data`` (a version-2 recording) as version 1 wrote it: the frame and tick
    records without the roll, their CRCs made again."""
    out = bytearray(HEADER.pack(MAGIC, 1))
    layouts = {
        TAG_FRAME: (FRAME_HEAD, FRAME_TOOL, FRAME_TOOL_V1),
        TAG_TICK: (TICK_HEAD, TICK_TOOL, TICK_TOOL_V1),
    }
    for start, end in record_bounds(data):
        tag, length = RECORD_HEAD.unpack_from(data, start)
        payload = data[start + RECORD_HEAD.size : start + RECORD_HEAD.size + length]
        if tag in layouts:
            head, new, old = layouts[tag]
            count = head.unpack_from(payload)[-1]
            tools = [new.unpack_from(payload, head.size + k * new.size) for k in range(count)]
            payload = payload[: head.size] + b"".join(
                old.pack(*values[:7], *values[8:]) for values in tools
            )
        out += encode_record(tag, payload)
    return bytes(out)


def test_a_version_1_recording_reads_with_roll_0_and_replays(recorded, tmp_path, capsys):
    """Recordings written before the tools had a roll (format version 1) still read,
    their poses with roll 0, and replay to their recorded final state."""
    old = tmp_path / "v1.tlap"
    old.write_bytes(_as_version_1(recorded.read_bytes()))
    now, then = read_recording(recorded), read_recording(old)
    assert (now.version, then.version) == (2, 1) and len(then.frames) == len(now.frames) == FRAMES
    for a, b in zip(now.frames, then.frames):
        for name, pose in a.poses.items():
            np.testing.assert_array_equal(b.poses[name].tip, pose.tip)
            np.testing.assert_array_equal(b.poses[name].direction, pose.direction)
            assert b.poses[name].roll == pose.roll == 0.0
    status, out, err = run_cli(
        capsys, *RUN, "--out", str(tmp_path / "r"), "--device", f"replay:{old}"
    )
    assert status == 0, err
    assert f"after {FRAMES} frames" in out


def test_a_grasping_session_replays_to_the_same_state(tmp_path, capsys):
    """The rectum scene's script closes the grasper on the wall at 0.9 s: the grasp is
    an event of the record, and the replay (poses and buttons) ends in the same state."""
    path, frames = tmp_path / "grasp.tlap", 58
    run = ["run", "rectum", "--headless", "--size", "64x48", *SMALL, "--set", "scene.collision=off"]
    status, _, err = run_cli(
        capsys, *run, "--frames", str(frames), "--out", str(tmp_path / "a"), "--record", str(path)
    )
    assert status == 0, err
    grasps = [e for e in read_recording(path).events if e["kind"] == "grasp"]
    assert len(grasps) == 1 and grasps[0]["tool"] == "grasper" and grasps[0]["particles"] > 0
    status, out, err = run_cli(
        capsys, *run, "--out", str(tmp_path / "b"), "--device", f"replay:{path}"
    )
    assert status == 0, err
    assert f"after {frames} frames" in out


def test_a_cutting_session_replays_to_the_same_checksum(tmp_path):
    """Scissors, rolling about their shaft at 1 rad/s, cut a sheet through (the
    sheet-cut tests' quick cut): the cuts are events of the record, and replaying
    its poses (with their roll) and buttons in a new session makes the same cuts and
    ends in the state of the recorded checksum."""
    from tests.test_sheet_cut import quick_cut_scene

    cutting, device = quick_cut_scene()
    path = tmp_path / "cut.tlap"
    session = Session(cutting, use_cache=False, progress=False)
    with SessionRecorder(path, session, device) as recorder:
        for _ in range(12):
            time = session.state.time
            poses = {k: Pose(p.tip, p.direction, time) for k, p in device.poses(time).items()}
            buttons = device.buttons(time)
            recorder.record_frame(poses, buttons)
            session.step(poses, buttons)
            for event in session.events:
                recorder.record_event(**event)
    session.close()
    recording = read_recording(path)
    cuts = [e for e in recording.events if e["kind"] == "cut"]
    assert cuts and all(e["tool"] == "scissors" and e["triangles"] > 0 for e in cuts)
    assert recording.frames[-1].poses["scissors"].roll == pytest.approx(11 * recording.start["dt"])

    replay = ReplayDevice(recording)
    again = Session(cutting, use_cache=False, progress=False)
    events = []
    for _ in range(len(recording.frames)):
        time = again.state.time
        again.step(replay.poses(time), replay.buttons(time))
        events += again.events
    assert [e for e in events if e["kind"] == "cut"] == [
        {k: v for k, v in e.items() if k not in ("time", "frame")} for e in cuts
    ]
    assert state_checksum(again.state) == recording.end["checksum"]
    again.close()
