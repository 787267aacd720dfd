"""Input devices that place the instruments: scripted keyframes and the mouse
(a recorded session is fed back by :class:`taichi_lap.replay.ReplayDevice`).

A device gives, for each tool it drives, a pose: the tip position [m] and the
direction from the tip towards the handle; a device with buttons also gives
``buttons(time)``, a bitmask per tool (bit k set while button k+1 is pressed).
:func:`apply_poses` turns poses into the capsules of
:class:`~taichi_lap.sim.control.Control`.

Script files (``--device script:PATH``) are TOML::

    version = 1
    [[keyframe]]
    time = 0.0            # s
    tool = "probe"        # a tool of the scene
    tip = [0.0, 0.1, 0.0] # m
    direction = [0, 1, 0] # optional, kept from the previous keyframe

Between keyframes the tip moves linearly; after the last it stays.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taichi_lap.errors import InputError
from taichi_lap.schema import REQUIRED, check_table
from taichi_lap.scenes.anatomy.params import Param
from taichi_lap.sim.control import MAX_TOOLS, Control

KEYFRAME_PARAMS = {
    "time": Param("float", REQUIRED, "time of the keyframe", lo=0.0, hi=1e6, unit="s"),
    "tool": Param("str", REQUIRED, "name of a tool of the scene"),
    "tip": Param("vec3", REQUIRED, "tip position", lo=-100, hi=100, unit="m"),
    "direction": Param("vec3", None, "from the tip towards the handle", lo=-1e3, hi=1e3),
}


@dataclass
class Pose:
    """Tool tip [m] and unit direction towards the handle."""

    tip: np.ndarray
    direction: np.ndarray


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else np.array([0.0, 1.0, 0.0])


class ScriptedDevice:
    """Poses interpolated from keyframes per tool; ``source`` names the script."""

    def __init__(self, keyframes: dict[str, list[tuple[float, np.ndarray, np.ndarray]]],
                 source: str = ""):
        self.keyframes = keyframes
        self.source = source

    @classmethod
    def from_file(cls, path: str | Path, tools: list[dict]) -> "ScriptedDevice":
        """Read a script file; every error names the file and the key."""
        path = Path(path)
        try:
            raw = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise InputError(str(path), "", f"a readable script file was expected: {exc.strerror}") \
                from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise InputError(str(path), "", f"valid TOML was expected: {exc}") from None
        check_table(str(path), "", raw, {"version": Param("int", REQUIRED, "format version",
                                                          lo=1, hi=1)}, ignore=("keyframe",))
        frames = raw.get("keyframe", [])
        if not isinstance(frames, list) or not frames:
            raise InputError(str(path), "keyframe", "one or more [[keyframe]] tables were expected")
        return cls.from_tables(str(path), frames, tools)

    @classmethod
    def from_tables(cls, source: str, frames: list, tools: list[dict]) -> "ScriptedDevice":
        names = {t["name"]: t for t in tools}
        keyframes: dict[str, list] = {}
        for k, table in enumerate(frames):
            key = f"keyframe[{k}]"
            frame = check_table(source, key, table, KEYFRAME_PARAMS)
            if frame["tool"] not in names:
                raise InputError(source, f"{key}.tool", f"one of the scene's tools "
                                                        f"({', '.join(names) or 'none'}) was "
                                                        f"expected, found {frame['tool']!r}")
            track = keyframes.setdefault(frame["tool"], [])
            if track and frame["time"] < track[-1][0]:
                raise InputError(source, f"{key}.time", f"times in increasing order were expected, "
                                                        f"found {frame['time']} after {track[-1][0]}")
            direction = frame["direction"] or (track[-1][2] if track else
                                               names[frame["tool"]]["direction"])
            track.append((frame["time"], np.asarray(frame["tip"], float), _unit(direction)))
        return cls(keyframes, source)

    def poses(self, time: float) -> dict[str, Pose]:
        out = {}
        for name, track in self.keyframes.items():
            times = [t for t, _, _ in track]
            k = int(np.searchsorted(times, time, side="right"))
            if k == 0:
                _, tip, direction = track[0]
            elif k == len(track):
                _, tip, direction = track[-1]
            else:
                (t0, a0, d0), (t1, a1, d1) = track[k - 1], track[k]
                s = (time - t0) / (t1 - t0) if t1 > t0 else 1.0
                tip, direction = a0 + s * (a1 - a0), _unit(d0 + s * (d1 - d0))
            out[name] = Pose(tip=tip, direction=direction)
        return out


class MouseDevice:
    """Moves one tool in the camera's image plane with the cursor while the left
    button is held; ``q`` / ``e`` push and pull it along the view direction."""

    def __init__(self, tool: dict, speed: float = 0.1):
        self.name = tool["name"]
        self.pose = Pose(tip=np.asarray(tool["tip"], float), direction=_unit(tool["direction"]))
        self.speed = speed  # [m/s] along the view axis
        self._last_cursor = None

    def update(self, window, camera_position, camera_target, fov_deg: float, dt: float):
        """Read the window's cursor and keys; move the tip (GGUI window)."""
        import taichi as ti

        eye, target = np.asarray(camera_position, float), np.asarray(camera_target, float)
        forward = _unit(target - eye)
        right = _unit(np.cross(forward, [0.0, 1.0, 0.0]))
        up = np.cross(right, forward)
        depth = float(np.dot(self.pose.tip - eye, forward))
        cursor = np.asarray(window.get_cursor_pos(), float)
        if window.is_pressed(ti.ui.LMB) and self._last_cursor is not None:
            width, height = window.get_window_shape()
            span = 2.0 * depth * np.tan(np.radians(fov_deg) / 2.0)
            delta = (cursor - self._last_cursor) * np.array([span * width / height, span])
            self.pose.tip = self.pose.tip + right * delta[0] + up * delta[1]
        self._last_cursor = cursor
        if window.is_pressed("q"):
            self.pose.tip = self.pose.tip + forward * self.speed * dt
        if window.is_pressed("e"):
            self.pose.tip = self.pose.tip - forward * self.speed * dt

    def poses(self, time: float) -> dict[str, Pose]:
        return {self.name: self.pose}


def applied_poses(tools: list[dict], poses: dict[str, Pose]) -> dict[str, Pose]:
    """Every placed tool's pose, in scene order: the device's, or the scene pose for a
    tool no device drives."""
    return {tool["name"]: poses.get(tool["name"]) or Pose(np.asarray(tool["tip"], float),
                                                          _unit(tool["direction"]))
            for tool in tools[:MAX_TOOLS]}


def apply_poses(control: Control, tools: list[dict], poses: dict[str, Pose]):
    """Write each tool's capsule (tip to tip + length·direction) into ``control``;
    a tool no device drives keeps its scene pose."""
    placed = applied_poses(tools, poses)
    for index, tool in enumerate(tools[:MAX_TOOLS]):
        pose = placed[tool["name"]]
        control.set_tool(index, pose.tip, pose.tip + tool["length"] * pose.direction, tool["radius"])
