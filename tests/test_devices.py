"""The mouse device in a window (drag in the image plane, push along the view, roll,
grasp) and a script's roll."""

import numpy as np
import pytest
import taichi as ti

from taichi_lap.core.errors import InputError
from taichi_lap.devices import CAUTERY_BUTTON, GRASP_BUTTON, MouseDevice, ScriptedDevice

TOOL = {"name": "forceps", "tip": [0.0, 0.05, 0.0], "direction": [0.0, 1.0, 0.0]}
EYE, TARGET, FOV = [0.0, 0.05, 0.2], [0.0, 0.05, 0.0], 60.0


class FakeWindow:
    """What MouseDevice reads of a GGUI window: cursor (0-1, y up), keys held, size."""

    def __init__(self):
        self.cursor, self.keys = (0.5, 0.5), set()

    def get_cursor_pos(self):
        return self.cursor

    def is_pressed(self, key):
        return key in self.keys

    def get_window_shape(self):
        return (800, 600)


def test_left_drag_moves_the_tip_in_the_image_plane_by_the_cursor_distance():
    mouse, window = MouseDevice(TOOL), FakeWindow()
    mouse.update(window, EYE, TARGET, FOV, 0.016)
    window.keys.add(ti.ui.LMB)
    window.cursor = (0.6, 0.45)
    mouse.update(window, EYE, TARGET, FOV, 0.016)
    moved = mouse.poses(0.0)["forceps"].tip - np.asarray(TOOL["tip"])
    span = 2 * 0.2 * np.tan(np.radians(FOV) / 2)  # the image height at the tip's depth
    np.testing.assert_allclose(moved, [0.1 * span * 800 / 600, -0.05 * span, 0.0], atol=1e-12)


def test_drag_without_the_button_and_keys_q_e_move_as_documented():
    mouse, window = MouseDevice(TOOL, speed=0.1), FakeWindow()
    mouse.update(window, EYE, TARGET, FOV, 0.016)
    window.cursor = (0.9, 0.9)  # no button: no move
    mouse.update(window, EYE, TARGET, FOV, 0.016)
    np.testing.assert_array_equal(mouse.poses(0.0)["forceps"].tip, TOOL["tip"])
    window.keys.add("q")  # push along the view direction (-z here) at 0.1 m/s
    mouse.update(window, EYE, TARGET, FOV, 0.5)
    np.testing.assert_allclose(mouse.poses(0.0)["forceps"].tip, [0.0, 0.05, -0.05], atol=1e-12)


def test_key_g_closes_and_opens_the_jaws_once_per_press():
    mouse, window = MouseDevice(TOOL), FakeWindow()
    states = []
    for keys in (set(), {"g"}, {"g"}, set(), {"g"}, set()):
        window.keys = keys
        mouse.update(window, EYE, TARGET, FOV, 0.016)
        states.append(mouse.buttons(0.0)["forceps"])
    assert states == [0, GRASP_BUTTON, GRASP_BUTTON, GRASP_BUTTON, 0, 0]


def test_key_c_energises_a_hook_while_held():
    mouse, window = MouseDevice(TOOL), FakeWindow()
    states = []
    for keys in (set(), {"c"}, {"c", "g"}, set()):
        window.keys = keys
        mouse.update(window, EYE, TARGET, FOV, 0.016)
        states.append(mouse.buttons(0.0)["forceps"])
    assert states == [0, CAUTERY_BUTTON, CAUTERY_BUTTON | GRASP_BUTTON, GRASP_BUTTON]


def test_keys_z_x_roll_the_tool_about_its_shaft_while_held():
    mouse, window = MouseDevice(TOOL, roll_speed=1.5), FakeWindow()
    rolls = []
    for keys, dt in ((set(), 0.1), ({"x"}, 0.5), ({"x"}, 0.25), ({"z"}, 1.0), ({"z", "x"}, 1.0)):
        window.keys = keys
        mouse.update(window, EYE, TARGET, FOV, dt)
        rolls.append(mouse.poses(0.0)["forceps"].roll)
    np.testing.assert_allclose(rolls, [0.0, 0.75, 1.125, -0.375, -0.375], atol=1e-12)


def test_a_script_rolls_a_tool_linearly_between_keyframes_and_keeps_its_roll():
    frames = [
        {"time": 0.0, "tool": "forceps", "tip": [0.0, 0.0, 0.0]},
        {"time": 1.0, "tool": "forceps", "tip": [0.0, 0.0, 0.0], "roll": 90.0},
        {"time": 2.0, "tool": "forceps", "tip": [0.01, 0.0, 0.0]},  # keeps 90°
        {"time": 3.0, "tool": "forceps", "tip": [0.01, 0.0, 0.0], "roll": -450.0},
    ]
    device = ScriptedDevice.from_tables("script", frames, [TOOL])
    rolls = [device.poses(t)["forceps"].roll for t in (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 9.0)]
    expected = np.radians([0.0, 45.0, 90.0, 90.0, 90.0, -180.0, -450.0, -450.0])
    np.testing.assert_allclose(rolls, expected, atol=1e-12)
    with pytest.raises(InputError, match=r"keyframe\[0\]\.roll"):
        ScriptedDevice.from_tables("script", [dict(frames[0], roll="left")], [TOOL])
