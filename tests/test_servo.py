"""The 1 kHz servo process: rate, safety clamp, watchdog fade, faults, clean stop.

The servo runs in a spawned child process against a plane of particles that the
test process publishes at 100 Hz from a thread, with a scripted device.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from multiprocessing import shared_memory

import numpy as np
import pytest

from taichi_lap.haptics import (
    OpenHapticsDevice,
    ProxySettings,
    SceneSnapshot,
    ServoProcess,
    ServoSettings,
    ServoState,
    WorkspaceMapping,
)
from taichi_lap.haptics import servo as servo_module
from taichi_lap.haptics.servo import scripted_device
from tests import fake_hd, helpers
from tests.test_proxy import TOOL, plane, scene_of

UPRIGHT = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))  # tool +z along scene +y
ABOVE, PRESSED = (0.0, 0.02, 0.0), (0.0, -0.004, 0.0)  # [m]; the surface is at 4 mm
MAX_FORCE = 0.5  # [N]


class Publisher:
    """Publishes the plane at 100 Hz from a thread until :meth:`pause`."""

    def __init__(self, snapshot: SceneSnapshot):
        scene = scene_of(plane())
        self.fields = (
            scene.cluster_center,
            scene.cluster_radius,
            scene.cluster_start,
            scene.particle_position,
            scene.particle_radius,
        )
        self.snapshot, self.running = snapshot, threading.Event()
        self.running.set()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._done.wait(0.01):
            if self.running.is_set():
                self.snapshot.publish(*self.fields)

    def pause(self):
        self.running.clear()
        time.sleep(0.02)  # a publish under way completes

    def close(self):
        self._done.set()
        self._thread.join()


@pytest.fixture
def snapshot():
    scene = scene_of(plane())
    snapshot = SceneSnapshot.create(
        clusters=len(scene.cluster_radius), particles=len(scene.particle_position)
    )
    publisher = Publisher(snapshot)
    yield publisher
    publisher.close()
    snapshot.close()


def servo_for(publisher: Publisher, keyframes, **device) -> ServoProcess:
    device = scripted_device(keyframes, rotation=UPRIGHT, max_force=MAX_FORCE, **device)
    return ServoProcess(
        publisher.snapshot.name,
        device,
        ProxySettings(TOOL, gain=300.0),
        ServoSettings(max_rate=1000.0),
    )


wait_for = functools.partial(helpers.wait_for, timeout=5.0)


@pytest.mark.realtime
def test_servo_ticks_at_about_1khz_in_a_child_process(snapshot):
    with servo_for(snapshot, [(0.0, ABOVE), (0.3, PRESSED)]) as servo:
        start = servo.feedback.tick_history()["count"]
        time.sleep(1.0)
        history = servo.feedback.tick_history()
        tool = servo.feedback.read()
        granted = "granted" if servo.feedback.fifo_granted else "refused"
    periods = history["period"][start - history["count"] :]
    assert len(periods) > 500
    median = float(np.median(periods))
    assert median == pytest.approx(0.001, rel=0.05), (
        f"median period {median * 1e3:.3f} ms (SCHED_FIFO {granted})"
    )
    assert tool.contacts > 0 and tool.snapshot_sequence > 0
    np.testing.assert_allclose(tool.graphic_pose[:3, 3], [0.0, 0.004, 0.0], atol=1e-6)


def test_servo_forces_respect_the_safety_clamp(snapshot):
    with servo_for(snapshot, [(0.0, ABOVE), (0.2, PRESSED)]) as servo:
        samples = []
        end = time.monotonic() + 0.8
        while time.monotonic() < end:
            tool = servo.feedback.read()
            if tool is not None:
                samples.append((np.linalg.norm(tool.force), np.linalg.norm(tool.contact_force)))
            time.sleep(0.001)
        tool = servo.feedback.read()
    sent, asked = np.array(samples).T
    assert asked.max() > 2.0 * MAX_FORCE  # the proxy asks for more than the device may give
    assert sent.max() <= MAX_FORCE + 1e-9 and tool.max_force_sent <= MAX_FORCE + 1e-9
    assert tool.max_force_sent > 0.99 * MAX_FORCE  # clamped, not cut


@pytest.mark.realtime
def test_stale_snapshot_fades_the_force_to_zero(snapshot):
    with servo_for(snapshot, [(0.0, ABOVE), (0.2, PRESSED)]) as servo:
        assert wait_for(lambda: np.linalg.norm(servo.feedback.read().force) > 0.99 * MAX_FORCE)
        snapshot.pause()
        paused = time.monotonic()
        assert wait_for(lambda: np.linalg.norm(servo.feedback.read().force) == 0.0, timeout=1.0)
        faded_after = time.monotonic() - paused
        tool = servo.feedback.read()
    assert 0.09 < faded_after < 0.100 + 0.050 + 0.100  # watchdog 100 ms, fade 50 ms, margin
    assert np.linalg.norm(tool.contact_force) > MAX_FORCE  # the proxy still presses


def test_stop_is_clean_and_leaves_zero_force(snapshot):
    servo = servo_for(snapshot, [(0.0, ABOVE), (0.2, PRESSED)]).start()
    feedback_name = servo.feedback.name
    assert wait_for(lambda: np.linalg.norm(servo.feedback.read().force) > 0.0)
    servo.stop()
    assert servo.exitcode == 0 and servo.feedback.state == ServoState.STOPPED
    assert servo.feedback.message == ""
    np.testing.assert_array_equal(servo.feedback.read().force, 0.0)
    servo.close()
    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=feedback_name)


def test_device_error_stops_force_output_and_is_reported(snapshot):
    with servo_for(snapshot, [(0.0, ABOVE), (0.2, PRESSED)], fail_after=0.6) as servo:
        assert wait_for(lambda: np.linalg.norm(servo.feedback.read().force) > 0.0)
        assert wait_for(lambda: not servo.is_alive())
        assert servo.exitcode == 0 and servo.feedback.state == ServoState.FAULTED
        assert "RuntimeError: scripted device fault after 0.6 s" in servo.feedback.message
        np.testing.assert_array_equal(servo.feedback.read().force, 0.0)  # zero sent first


def test_device_that_fails_to_open_is_reported_by_start(snapshot):
    bad = scripted_device([(1.0, ABOVE), (0.0, PRESSED)])  # times run backwards
    servo = ServoProcess(snapshot.snapshot.name, bad, ProxySettings(TOOL))
    try:
        with pytest.raises(
            RuntimeError, match="did not start: ValueError: ScriptedHapticDevice: keyframes"
        ):
            servo.start()
        assert servo.feedback.state == ServoState.FAULTED
    finally:
        servo.close()


def test_servo_drives_the_openhaptics_binding_against_the_fake_libhd(snapshot, tmp_path):
    if fake_hd.compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH to build the fake libHD")
    library = str(fake_hd.build(tmp_path))
    # the fake's stylus rests at its origin, axis +z: lying 1 mm into the plane's particles
    device = functools.partial(
        OpenHapticsDevice,
        library=library,
        max_rate=1000.0,
        mapping=WorkspaceMapping(offset=(0.0, 0.003, 0.0)),
    )
    with ServoProcess(snapshot.snapshot.name, device, ProxySettings(TOOL, gain=300.0)) as servo:
        expected = [0.0, 300.0 * 0.001, 0.0]  # [N]: gain x 1 mm, once ramped in
        reads = []  # the read that showed the force: the snapshot is published once,
        # and the watchdog fades the force once it is stale (a later read, under load,
        # found it faded)

        def ramped_in() -> bool:
            reads.append(servo.feedback.read())
            return np.allclose(reads[-1].force, expected, atol=1e-6)

        assert wait_for(ramped_in)
        tool = reads[-1]
    np.testing.assert_allclose(tool.graphic_pose[:3, 3], [0.0, 0.004, 0.0], atol=1e-6)
    np.testing.assert_allclose(tool.force, expected, atol=1e-6)
    assert servo.exitcode == 0


def test_terminate_signal_stops_the_loop_cleanly(snapshot):
    servo = servo_for(snapshot, [(0.0, ABOVE), (0.2, PRESSED)]).start()
    try:
        assert wait_for(lambda: np.linalg.norm(servo.feedback.read().force) > 0.0)
        servo._process.terminate()  # what the parent's exit does to a daemonic child
        servo._process.join(5.0)
        assert servo.exitcode == 0 and servo.feedback.state == ServoState.STOPPED
        np.testing.assert_array_equal(servo.feedback.read().force, 0.0)
    finally:
        servo.close()


def test_refused_fifo_is_warned_once_and_the_servo_carries_on(monkeypatch, caplog):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(servo_module.os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="taichi_lap.haptics"):
        assert servo_module._realtime(ServoSettings()) is False
    assert len(caplog.records) == 1
    assert "SCHED_FIFO priority 80 was refused" in caplog.text
    assert servo_module._realtime(ServoSettings(fifo_priority=None)) is False


def test_the_stylus_roll_is_summed_unwrapped_from_its_readings(snapshot):
    """A stylus turning about its shaft at 3π rad/s: the servo's roll (feedback and
    tick ring) grows at that rate past ±π (unwrapped), from 0 at its first tick; its
    shaft direction stays the scene's +y."""
    rate = 3.0 * np.pi
    with servo_for(snapshot, [(0.0, ABOVE)], roll_rate=rate) as servo:
        assert wait_for(lambda: servo.feedback.read() is not None)
        time.sleep(0.8)
        ticks, count, _ = servo.feedback.ticks_since(0)
        tool = servo.feedback.read()
    slope = np.polyfit(ticks["clock"], ticks["roll"], 1)[0]
    assert slope == pytest.approx(rate, rel=0.02)
    assert ticks["roll"][0] == 0.0 and ticks["roll"].max() > 2.0 * np.pi
    assert np.all(np.diff(ticks["roll"]) >= 0.0)
    assert tool.roll >= ticks["roll"][-1]
    np.testing.assert_allclose(ticks["direction"], np.tile([0.0, 1.0, 0.0], (count, 1)), atol=1e-12)
