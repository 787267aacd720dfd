"""Contract tests of the OpenHaptics (HDAPI) binding against the fake libHD.

The fake (``tests/fake_hd/fake_hd.c``) is compiled once per session with the system
C compiler; it runs its own 1 kHz servo thread and records what the binding did.
"""

from __future__ import annotations

import functools
import logging
import time

import numpy as np
import pytest

from taichi_lap.haptics import OpenHapticsDevice, OpenHapticsError, WorkspaceMapping, openhaptics
from tests import fake_hd, helpers

HD_FORCE_OUTPUT = 0x4000
HD_DEVICE_FAULT = 0x300
HD_WARM_MOTORS = 0x200
HD_EXCEEDED_MAX_VELOCITY = 0x203
TOUCH_MAX_CONTINUOUS_FORCE = 0.88  # [N], the fake's HD_NOMINAL_MAX_CONTINUOUS_FORCE


@pytest.fixture(scope="session")
def fake_library(tmp_path_factory):
    if fake_hd.compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH to build the fake libHD")
    return str(fake_hd.build(tmp_path_factory.mktemp("fake_hd")))


@pytest.fixture
def fake(fake_library):
    controls = fake_hd.FakeHD(fake_library)
    controls.reset()
    yield controls
    controls.reset()


wait_for = functools.partial(helpers.wait_for, timeout=1.0)


def last_force(fake, handle: int) -> np.ndarray:
    """The force [N] the fake device output in its latest frame (zero before any)."""
    forces = fake.forces(handle, 1)
    return forces[-1] if len(forces) else np.zeros(3)


def rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def column_major(rot: np.ndarray, translation_mm) -> np.ndarray:
    """The 16 doubles of HD_CURRENT_TRANSFORM: column-major, translation at 12-14."""
    values = np.zeros(16)
    for col in range(3):
        values[4 * col : 4 * col + 3] = rot[:, col]
    values[12:15] = translation_mm
    values[15] = 1.0
    return values


def test_default_device_opens_reads_model_and_max_force(fake):
    with OpenHapticsDevice(library=fake.path) as dev:
        assert dev.model == "Fake Touch"
        assert dev.max_force == pytest.approx(TOUCH_MAX_CONTINUOUS_FORCE)
        assert fake.is_enabled(dev.handle, HD_FORCE_OUTPUT)
        assert fake.scheduler_running() and fake.scheduled_count() == 1
        assert wait_for(lambda: fake.frame_count(dev.handle) > 5)
    assert fake.calls()[:5] == [
        "hdInitDevice Default Device -> 1",
        "hdEnable 0x4000 device 1",
        "hdScheduleAsynchronous 1 priority 65535",
        "hdSetSchedulerRate 1000",
        "hdStartScheduler",
    ]


def test_named_device_opens_and_unknown_name_is_reported(fake):
    with OpenHapticsDevice("Right Device", library=fake.path) as dev:
        assert dev.handle == 3 and dev.model == "Fake Touch"
    with pytest.raises(
        OpenHapticsError, match="hdInitDevice.*'Middle Device'.*HD_COMM_CONFIG_ERROR"
    ):
        OpenHapticsDevice("Middle Device", library=fake.path)
    assert fake.error_count() == 0 and not fake.scheduler_running()


@pytest.mark.realtime
def test_servo_callback_runs_at_about_1khz(fake):
    with OpenHapticsDevice(library=fake.path) as dev:
        assert wait_for(lambda: fake.frame_count(dev.handle) > 20)
        ticks0, frames0, t0 = fake.tick_count(), fake.frame_count(dev.handle), time.monotonic()
        time.sleep(0.5)
        elapsed = time.monotonic() - t0
        tick_rate = (fake.tick_count() - ticks0) / elapsed
        rate = (fake.frame_count(dev.handle) - frames0) / elapsed
    assert tick_rate == pytest.approx(1000.0, rel=0.15), f"scheduler ticked at {tick_rate:.0f} Hz"
    assert rate == pytest.approx(1000.0, rel=0.15), f"servo callback ran at {rate:.0f} Hz"


def test_column_major_transform_lands_as_row_major_pose(fake):
    rot = rotation(2, np.radians(30)) @ rotation(0, np.radians(90))
    with OpenHapticsDevice(library=fake.path) as dev:
        fake.set_pose(dev.handle, column_major(rot, [12.0, -34.0, 56.0]))
        fake.set_buttons(dev.handle, 0b101)
        assert wait_for(lambda: dev.buttons() == 0b101 and dev.pose()[0, 3] > 0.0)
        pose = dev.pose()
    np.testing.assert_allclose(pose[:3, :3], rot, atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [0.012, -0.034, 0.056], atol=1e-12)  # mm -> m
    np.testing.assert_allclose(pose[3], [0, 0, 0, 1])


def test_workspace_mapping_scales_and_offsets_translation(fake):
    mapping = WorkspaceMapping(scale=0.002, offset=(0.1, -0.2, 0.3))
    with OpenHapticsDevice(library=fake.path, mapping=mapping) as dev:
        fake.set_pose(dev.handle, column_major(np.eye(3), [10.0, 20.0, -30.0]))
        expected = [0.002 * 10.0 + 0.1, 0.002 * 20.0 - 0.2, 0.002 * -30.0 + 0.3]
        assert wait_for(lambda: np.allclose(dev.pose()[:3, 3], expected, atol=1e-12))
        pose = dev.pose()
    np.testing.assert_allclose(pose[:3, 3], [0.12, -0.16, 0.24], atol=1e-12)
    np.testing.assert_allclose(pose[:3, :3], np.eye(3))


@pytest.mark.parametrize(
    "scale, offset",
    [(0.0, (0, 0, 0)), (float("nan"), (0, 0, 0)), (0.001, (0, 0)), (0.001, (0, float("inf"), 0))],
)
def test_workspace_mapping_rejects_bad_values(scale, offset):
    with pytest.raises(ValueError, match="WorkspaceMapping"):
        WorkspaceMapping(scale=scale, offset=offset)


def test_commanded_force_reaches_library_clamped_and_rate_limited(fake):
    with OpenHapticsDevice(library=fake.path, max_rate=100.0) as dev:
        dev.set_force(np.array([5.0, 0.0, 0.0]))
        assert wait_for(lambda: last_force(fake, dev.handle)[0] >= dev.max_force - 1e-9)
        forces = fake.forces(dev.handle)
    magnitudes = np.linalg.norm(forces, axis=1)
    assert magnitudes.max() <= TOUCH_MAX_CONTINUOUS_FORCE + 1e-12
    assert np.abs(np.diff(forces, axis=0)).max() <= 100.0 * 0.002 + 1e-12


def test_injected_error_is_drained_named_and_stops_force_output(fake, caplog):
    with OpenHapticsDevice(library=fake.path, max_rate=1000.0) as dev:
        dev.set_force([0.0, 0.5, 0.0])
        assert wait_for(lambda: last_force(fake, dev.handle)[1] > 0.49)
        with caplog.at_level(logging.ERROR, logger="taichi_lap.haptics"):
            fake.push_errors(dev.handle, HD_WARM_MOTORS, HD_EXCEEDED_MAX_VELOCITY, HD_DEVICE_FAULT)
            assert wait_for(lambda: dev.fault is not None)
        assert "HD_DEVICE_FAULT (0x300" in dev.fault and "Device fault" in dev.fault
        assert "HD_WARM_MOTORS (0x200" in dev.fault
        assert "HD_EXCEEDED_MAX_VELOCITY (0x203" in dev.fault
        assert "HD_DEVICE_FAULT" in caplog.text
        assert fake.error_count() == 0
        assert not fake.is_enabled(dev.handle, HD_FORCE_OUTPUT)
        frames = fake.frame_count(dev.handle)
        assert wait_for(lambda: fake.frame_count(dev.handle) > frames + 3)
        np.testing.assert_array_equal(fake.forces(dev.handle, 3), np.zeros((3, 3)))
        with pytest.raises(OpenHapticsError, match="force output stopped after HD_"):
            dev.set_force([0.1, 0.0, 0.0])


class _BrokenMapping(WorkspaceMapping):
    """Raises for stylus positions beyond 500 mm (an error inside the servo callback)."""

    def to_scene(self, transform_mm):
        if abs(transform_mm[0, 3]) > 500.0:
            raise RuntimeError("mapping failed")
        return super().to_scene(transform_mm)


def test_exception_in_servo_callback_never_reaches_c_and_zeroes_force(fake):
    with OpenHapticsDevice(library=fake.path, mapping=_BrokenMapping(), max_rate=1000.0) as dev:
        dev.set_force([0.5, 0.0, 0.0])
        assert wait_for(lambda: last_force(fake, dev.handle)[0] > 0.49)
        fake.set_pose(dev.handle, column_major(np.eye(3), [1000.0, 0.0, 0.0]))
        assert wait_for(lambda: dev.fault is not None)
        assert "RuntimeError: mapping failed" in dev.fault
        assert not fake.is_enabled(dev.handle, HD_FORCE_OUTPUT)
        frames = fake.frame_count(dev.handle)
        assert wait_for(lambda: fake.frame_count(dev.handle) > frames + 3)  # still ticking
        np.testing.assert_array_equal(fake.forces(dev.handle, 3), np.zeros((3, 3)))


def test_stale_command_fades_to_zero(fake):
    with OpenHapticsDevice(library=fake.path, max_rate=1000.0) as dev:
        dev.set_force([0.0, 0.0, 0.6])
        assert wait_for(lambda: last_force(fake, dev.handle)[2] > 0.59)
        time.sleep(0.100 + 0.050 + 0.020)  # watchdog timeout + fade time + margin
        np.testing.assert_array_equal(fake.forces(dev.handle, 3), np.zeros((3, 3)))


def test_close_zeroes_force_then_stops_unschedules_and_disables(fake):
    dev = OpenHapticsDevice(library=fake.path, max_rate=1000.0)
    dev.set_force([0.4, 0.0, 0.0])
    assert wait_for(lambda: last_force(fake, dev.handle)[0] > 0.39)
    dev.close()
    dev.close()
    assert fake.calls()[-4:] == [
        "hdStopScheduler",
        "hdUnschedule 1",
        "hdDisable 0x4000 device 1",
        "hdDisableDevice 1",
    ]
    np.testing.assert_array_equal(fake.forces(dev.handle, 1), np.zeros((1, 3)))
    assert not fake.scheduler_running() and fake.scheduled_count() == 0
    assert not fake.is_enabled(dev.handle)
    with pytest.raises(OpenHapticsError, match="is closed"):
        dev.set_force([0.0, 0.0, 0.0])


def test_two_devices_have_independent_poses_and_forces(fake):
    with (
        OpenHapticsDevice("Left Device", library=fake.path, max_rate=1000.0) as left,
        OpenHapticsDevice("Right Device", library=fake.path, max_rate=1000.0) as right,
    ):
        assert {left.handle, right.handle} == {2, 3} and fake.scheduled_count() == 2
        fake.set_pose(left.handle, column_major(np.eye(3), [-100.0, 0.0, 0.0]))
        fake.set_pose(right.handle, column_major(rotation(1, 0.5), [100.0, 5.0, 0.0]))
        left.set_force([0.3, 0.0, 0.0])
        right.set_force([0.0, -0.4, 0.0])
        assert wait_for(
            lambda: (
                last_force(fake, left.handle)[0] > 0.29
                and last_force(fake, right.handle)[1] < -0.39
            )
        )
        assert wait_for(lambda: left.pose()[0, 3] < 0 and right.pose()[0, 3] > 0)
        np.testing.assert_allclose(left.pose()[:3, 3], [-0.1, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(right.pose()[:3, 3], [0.1, 0.005, 0.0], atol=1e-12)
        np.testing.assert_allclose(right.pose()[:3, :3], rotation(1, 0.5), atol=1e-12)
        np.testing.assert_allclose(last_force(fake, left.handle), [0.3, 0.0, 0.0])
        np.testing.assert_allclose(last_force(fake, right.handle), [0.0, -0.4, 0.0])
        left.close()
        assert fake.scheduler_running() and not fake.is_enabled(left.handle)
        frames = fake.frame_count(right.handle)
        assert wait_for(lambda: fake.frame_count(right.handle) > frames + 5)
    assert not fake.scheduler_running() and fake.scheduled_count() == 0


def test_failed_open_leaves_the_open_device_running(fake):
    with OpenHapticsDevice("Left Device", library=fake.path) as left:
        with pytest.raises(OpenHapticsError, match="HD_DEVICE_ALREADY_INITIATED"):
            OpenHapticsDevice("Left Device", library=fake.path)
        with pytest.raises(OpenHapticsError, match="HD_COMM_CONFIG_ERROR"):
            OpenHapticsDevice("Middle Device", library=fake.path)
        assert fake.scheduler_running() and fake.scheduled_count() == 1
        frames = fake.frame_count(left.handle)
        assert wait_for(lambda: fake.frame_count(left.handle) > frames + 5)
        assert fake.is_enabled(left.handle, HD_FORCE_OUTPUT) and left.fault is None


def test_calibration_update_and_manual_input(fake, caplog):
    fake.set_calibration("Left Device", 0x5001)  # HD_CALIBRATION_NEEDS_UPDATE
    with OpenHapticsDevice("Left Device", library=fake.path) as dev:
        assert dev.calibration == openhaptics.HD_CALIBRATION_OK
    assert "hdUpdateCalibration 4 device 2" in fake.calls()  # HD_CALIBRATION_INKWELL
    fake.set_calibration("Right Device", 0x5002)  # HD_CALIBRATION_NEEDS_MANUAL_INPUT
    with caplog.at_level(logging.WARNING, logger="taichi_lap.haptics"):
        with OpenHapticsDevice("Right Device", library=fake.path) as dev:
            assert dev.calibration == openhaptics.HD_CALIBRATION_NEEDS_MANUAL_INPUT
    assert "HD_CALIBRATION_NEEDS_MANUAL_INPUT" in caplog.text and "inkwell" in caplog.text


def test_missing_library_error_names_what_was_searched(tmp_path, monkeypatch):
    missing = tmp_path / "libHD.so.3.0.0"
    with pytest.raises(OpenHapticsError, match=f"libHD could not be loaded; tried {missing}"):
        OpenHapticsDevice(library=str(missing))
    monkeypatch.setattr(openhaptics.ctypes.util, "find_library", lambda name: None)
    monkeypatch.setattr(openhaptics, "LIBRARY_NAMES", ("libHD-absent.so", "libHD-absent.so.3"))
    with pytest.raises(OpenHapticsError) as info:
        OpenHapticsDevice()
    message = str(info.value)
    assert "find_library('HD')" in message and "libHD-absent.so.3" in message
    assert "library=PATH" in message
