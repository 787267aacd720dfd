"""A haptic device drives the scene's tool through the servo process: the HDAPI
binding against the fake libHD (tests/fake_hd), in the servo's own process."""

import time

import numpy as np
import pytest

from taichi_lap import scene as scene_mod
from taichi_lap.cli import main
from taichi_lap.haptics.bridge import openhaptics_bridge
from taichi_lap.replay import read_recording
from taichi_lap.session import Session
from tests import fake_hd
from tests.blocks import block_scene_file
from tests.helpers import BOX

TWO_DEVICES = ("openhaptics:Left Device", "openhaptics:Right Device")


def headless_run(out, scene: str, frames: int, *devices: str, extra: tuple = ()) -> int:
    """Exit status of ``taichi-lap run`` of ``scene`` (detail 0.03), headless into
    ``out`` at 64x48, each of ``devices`` a ``--device``."""
    arguments = ["run", scene, "--headless", "--frames", str(frames), "--size", "64x48"]
    for device in devices:
        arguments += ["--device", device]
    return main([*arguments, "--out", str(out), *extra, "--set", "scene.detail=0.03"])


def block_with_probe() -> scene_mod.Scene:
    """The test block under a probe 3.8 cm above its top."""
    return scene_mod.from_tables([BOX], tools=[{"name": "probe", "tip": [0.0, 0.05, 0.0]}])


@pytest.fixture(scope="module")
def fake_library(tmp_path_factory):
    if fake_hd.compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH to build the fake libHD")
    return str(fake_hd.build(tmp_path_factory.mktemp("fake_hd")))


def test_device_origin_puts_the_tool_at_its_scene_tip(fake_library):
    """The fake stylus rests at its origin with the identity rotation: the graphical
    tool sits at the tool's scene tip with its shaft along +z (the stylus axis)."""
    scene = block_with_probe()
    session = Session(scene, use_cache=False, progress=False)
    tool = scene.tools[0]
    bridge = openhaptics_bridge(tool, None, fake_library)
    bridge.attach(session)
    try:
        pose = bridge.poses(0.0)[tool["name"]]
        session.step({tool["name"]: pose})
        feedback = bridge.servo.feedback.read()
    finally:
        bridge.close()
        session.close()  # the next test's session of this scene takes its fields
    assert np.allclose(pose.tip, tool["tip"], atol=1e-6)
    assert np.allclose(pose.direction, [0.0, 0.0, 1.0], atol=1e-6)
    assert feedback.tick > 0
    assert np.linalg.norm(feedback.force) <= 0.88 + 1e-9  # the fake Touch's continuous force


def test_missing_libhd_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TAICHI_LAP_LIBHD", str(tmp_path / "no-such-libHD.so"))
    status = headless_run(tmp_path / "f", "rectum", 1, "openhaptics")
    assert status == 2
    err = capsys.readouterr().err
    assert "error: --device: openhaptics: a working haptic device was expected" in err
    assert "libHD" in err and "Traceback" not in err


def test_stylus_button_grasps_and_the_servo_feels_the_pull():
    """Button 1 held on a grasper: the first step takes the tissue between the jaws;
    lifting the stylus stretches the grasped edges and the servo's pull force points
    back down to the tissue."""
    from taichi_lap.haptics.bridge import HapticBridge
    from taichi_lap.haptics.servo import scripted_device
    from taichi_lap.scene import from_tables
    from tests.test_grasp import GRASPER, HELD_BLOCK

    up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # stylus +z to scene +y
    tool = dict(GRASPER, grasp_stiffness=5.0)
    scene = from_tables([HELD_BLOCK], tools=[tool], gravity=[0, 0, 0])
    session = Session(scene, use_cache=False, progress=False)
    tip = np.asarray(GRASPER["tip"])
    device = scripted_device(
        [(0.0, tip), (0.3, tip), (1.0, tip + [0.0, 0.015, 0.0])], rotation=up, buttons=1
    )
    bridge = HapticBridge(scene.tools[0], device)
    bridge.attach(session)
    events, pulls = [], []
    try:
        deadline = None  # 20 s from the end of the first step, which compiles the kernels
        while not (pulls and pulls[-1][1] < -1e-4) and time.monotonic() < (deadline or np.inf):
            now = session.state.time
            session.step(bridge.poses(now), bridge.buttons(now))
            deadline = deadline or time.monotonic() + 20.0
            events += session.events
            feedback = bridge.servo.feedback.read()
            pulls.append(feedback.pull_force if feedback is not None else np.zeros(3))
    finally:
        bridge.close()
    assert events and events[0]["kind"] == "grasp" and events[0]["particles"] > 0
    held = session.state.grasp_tool.to_numpy() == 0
    assert held.sum() == events[0]["particles"]
    assert pulls[-1][1] < -1e-4, f"no downward pull within 20 s: last {pulls[-1]}"
    assert abs(pulls[-1][1]) > np.abs(pulls[-1][[0, 2]]).max()


@pytest.mark.long  # one device drives a tool in the default run
def test_two_openhaptics_devices_drive_two_tools(fake_library, tmp_path, monkeypatch, capsys):
    """Two hands: the probe's `device` key binds it to the left device, so the right
    one takes the free tool (the grasper); the run completes and writes its frames, and
    the recording names both devices, places each tool at its scene tip (the device
    origin) and holds every servo tick."""
    tips = {"grasper": [-0.01, 0.03, 0.0], "probe": [0.01, 0.03, 0.0]}
    scene = tmp_path / "two_hands.toml"
    scene.write_text(
        block_scene_file(
            "two_hands",
            f"""
[[tools]]
name = "grasper"
kind = "grasper"
tip = {tips["grasper"]}

[[tools]]
name = "probe"
kind = "probe"
tip = {tips["probe"]}
device = "openhaptics:Left Device"
""",
        )
    )
    monkeypatch.setenv("TAICHI_LAP_LIBHD", fake_library)
    record = tmp_path / "s.tlap"
    status = headless_run(
        tmp_path / "frames", str(scene), 3, *TWO_DEVICES, extra=("--record", str(record))
    )
    assert status == 0, capsys.readouterr().err
    assert len(list((tmp_path / "frames").glob("*.png"))) == 3
    recording = read_recording(str(record))
    device = next(e for e in recording.events if e["kind"] == "device")
    assert "openhaptics:Left Device" in device["source"]
    assert "openhaptics:Right Device" in device["source"]
    right_first = [t for t in recording.ticks if "grasper" in t.poses][0].clock
    left_first = [t for t in recording.ticks if "probe" in t.poses][0].clock
    assert left_first < right_first  # the left device was opened first, for the probe
    last = recording.frames[-1].poses
    assert np.allclose(last["grasper"].tip, tips["grasper"], atol=1e-6)
    assert np.allclose(last["probe"].tip, tips["probe"], atol=1e-6)
    # every servo tick of both devices is in the record, each device's in clock order (the
    # servo's rate is checked in the realtime group, tests/test_servo.py)
    for name in ("grasper", "probe"):
        ticks = [t for t in recording.ticks if name in t.poses]
        clocks = np.array([t.clock for t in ticks])
        assert len(ticks) > 10 and np.all(np.diff(clocks) > 0)


def test_a_second_haptic_device_needs_a_second_tool(fake_library, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("TAICHI_LAP_LIBHD", fake_library)
    status = headless_run(tmp_path / "f", "liver", 1, *TWO_DEVICES)
    assert status == 2
    err = capsys.readouterr().err
    assert (
        "tools: a tool for --device openhaptics:Right Device was expected (one whose "
        "device is 'openhaptics:Right Device' or one with no device), the scene has 1 and "
        "other devices drive 1" in err
    )


def test_the_published_surface_follows_a_dissection(fake_library):
    """After tissue is removed the servo's surface holds the particles left on it and
    those the wound exposed (the kept ends of its vertices), none of the removed."""
    scene = block_with_probe()
    session = Session(scene, use_cache=False, progress=False)
    bridge = openhaptics_bridge(scene.tools[0], None, fake_library)
    bridge.attach(session)
    try:
        built = set(bridge.surface.particles.tolist())
        rest = session.data.rest_position
        top = rest[np.argmax(rest[:, 1])]
        change = session.remove_particles(
            np.flatnonzero(np.linalg.norm(rest - top, axis=1) < 0.006)
        )
        bridge.poses(0.0)
        published = set(bridge.surface.particles.tolist())
        capacity = bridge.snapshot.capacity["particles"]
    finally:
        bridge.close()
    removed = set(change.removed_particles.tolist())
    assert removed and not published & removed
    exposed = published - built
    assert exposed and published == set(session.surface_particles().tolist())
    assert built - removed <= published and len(published) <= capacity


def test_a_wound_that_outgrows_the_snapshot_moves_it_and_the_servo_follows(
    fake_library, monkeypatch
):
    """A snapshot made for the built surface alone (no spare rows) is outgrown by the
    particles a wound exposes: it moves to a larger region, and the servo process
    reads the new region's snapshots (their sequence numbers reach its feedback)."""
    from taichi_lap.haptics import bridge as bridge_mod
    from taichi_lap.haptics.servo import ServoState

    monkeypatch.setattr(bridge_mod, "spare_rows", lambda count, *_: count)
    scene = block_with_probe()
    session = Session(scene, use_cache=False, progress=False)
    bridge = openhaptics_bridge(scene.tools[0], None, fake_library)
    bridge.attach(session)
    try:
        first_name, capacity = bridge.snapshot.name, dict(bridge.snapshot.capacity)
        assert capacity["particles"] == bridge.surface.particle_count
        rest = session.data.rest_position  # a slot 4 mm wide, 2 cm deep: two new faces
        session.remove_particles(
            np.flatnonzero((np.abs(rest[:, 0]) < 0.002) & (rest[:, 1] > -0.008))
        )
        bridge.poses(0.0)
        published = bridge.surface.particle_count
        sequence = latest = -1
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            bridge.poses(0.0)  # publishes
            latest = bridge.snapshot._region._next  # the sequence of that publication
            sequence = bridge.servo.feedback.read().snapshot_sequence
            if sequence >= latest - 1:
                break
            time.sleep(0.01)
        state = bridge.servo.feedback.state
        moved_capacity = dict(bridge.snapshot.capacity)
        moved_name = bridge.snapshot.name
    finally:
        bridge.close()
    assert published > capacity["particles"]  # the wound exposed more than was built
    assert moved_name != first_name and moved_capacity["particles"] >= published
    assert state == ServoState.RUNNING
    assert latest > 1 and sequence >= latest - 1
