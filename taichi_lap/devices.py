"""Input devices that place the instruments: scripted keyframes and the mouse
(a recorded session is fed back by :class:`taichi_lap.replay.ReplayDevice`).

A device gives, for each tool it drives, a pose: the tip position [m], the
direction from the tip towards the handle and the roll about that axis [rad]; a device with buttons also gives
``buttons(time)``, a bitmask per tool (bit k set while button k+1 is pressed).
:func:`apply_poses` turns poses into the capsules of
:class:`~taichi_lap.sim.control.Control`; button 1 (``GRASP_BUTTON``) closes a
grasper's jaws, button 2 (``CAUTERY_BUTTON``) energises a hook (the session heats).

Script files (``--device script:PATH``) are TOML::

    version = 1
    [[keyframe]]
    time = 0.0            # s
    tool = "probe"        # a tool of the scene
    tip = [0.0, 0.1, 0.0] # m
    direction = [0, 1, 0] # optional, kept from the previous keyframe
    roll = 90.0           # degrees about the shaft, optional, kept (0 at first)
    grasp = true          # optional: jaws closed from here on (kept; open at first)
    cautery = true        # optional: hook energised from here on (kept; off at first)

Between keyframes the tip and the roll move linearly; after the last they stay. The jaws and the
hook's current change at a keyframe's time.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.instruments import CAUTERY_BUTTON, GRASP_BUTTON, MAX_TOOLS, tool_geometry
from taichi_lap.core.params import REQUIRED, Param, check_table
from taichi_lap.scene.keyframes import Keyframe, read_keyframes, unit
from taichi_lap.sim.control import Control


@dataclass
class Pose:
    """Tool tip [m], unit direction towards the handle and roll [rad]: the tool's
    turn about that axis (right-handed), unwrapped (a device that turns the tool
    round twice gives 4π); :meth:`Control.set_tool` turns the tool's frame by how
    much it changed."""

    tip: np.ndarray
    direction: np.ndarray
    roll: float = 0.0


class ScriptedDevice:
    """Poses interpolated from keyframes per tool; ``source`` names the script."""

    def __init__(self, keyframes: dict[str, list[Keyframe]], source: str = ""):
        self.keyframes = keyframes
        self.source = source

    @classmethod
    def from_file(cls, path: str | Path, tools: list[dict]) -> "ScriptedDevice":
        """Read a script file; every error names the file and the key."""
        path = Path(path)
        try:
            raw = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise InputError(
                str(path), "", f"a readable script file was expected: {exc.strerror}"
            ) from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise InputError(str(path), "", f"valid TOML was expected: {exc}") from None
        check_table(
            str(path),
            "",
            raw,
            {"version": Param("int", REQUIRED, "format version", lo=1, hi=1)},
            ignore=("keyframe",),
        )
        frames = raw.get("keyframe", [])
        if not isinstance(frames, list) or not frames:
            raise InputError(str(path), "keyframe", "one or more [[keyframe]] tables were expected")
        return cls.from_tables(str(path), frames, tools)

    @classmethod
    def from_tables(cls, source: str, frames: list, tools: list[dict]) -> "ScriptedDevice":
        """A device from keyframe tables (:func:`~taichi_lap.scene.keyframes.read_keyframes`)."""
        return cls(read_keyframes(source, frames, tools), source)

    def duration(self) -> float:
        """Time [s] of the last keyframe of any tool."""
        return max(track[-1].time for track in self.keyframes.values())

    def _after(self, track, time: float) -> int:
        """How many keyframes of ``track`` lie at or before ``time``."""
        return int(np.searchsorted([frame.time for frame in track], time, side="right"))

    def buttons(self, time: float) -> dict[str, int]:
        """Per tool the buttons of the last keyframe at or before ``time``."""
        return {
            name: track[max(self._after(track, time) - 1, 0)].buttons
            for name, track in self.keyframes.items()
        }

    def poses(self, time: float) -> dict[str, Pose]:
        out = {}
        for name, track in self.keyframes.items():
            k = self._after(track, time)
            if k in (0, len(track)):
                key = track[min(k, len(track) - 1)]
                out[name] = Pose(key.tip, key.direction, key.roll)
                continue
            a, b = track[k - 1], track[k]
            s = (time - a.time) / (b.time - a.time) if b.time > a.time else 1.0
            out[name] = Pose(
                a.tip + s * (b.tip - a.tip),
                unit(a.direction + s * (b.direction - a.direction)),
                a.roll + s * (b.roll - a.roll),
            )
        return out


class MouseDevice:
    """Moves one tool in the camera's image plane with the cursor while the left
    button is held; ``q`` / ``e`` push and pull it along the view direction; ``z`` /
    ``x`` roll it about its shaft (to orient a hook's or the scissors' blades); ``g``
    closes or opens a grasper's jaws; a hook is energised while ``c`` is held."""

    def __init__(self, tool: dict, speed: float = 0.1, roll_speed: float = np.pi / 2):
        self.name = tool["name"]
        self.pose = Pose(tip=np.asarray(tool["tip"], float), direction=unit(tool["direction"]))
        self.speed = speed  # [m/s] along the view axis
        self.roll_speed = roll_speed  # [rad/s]
        self.grasp = False
        self.cautery = False
        self._last_cursor = None
        self._grasp_key_down = False

    def update(self, window, camera_position, camera_target, fov_deg: float, dt: float):
        """Read the window's cursor and keys; move the tip (GGUI window)."""
        import taichi as ti

        eye, target = np.asarray(camera_position, float), np.asarray(camera_target, float)
        forward = unit(target - eye)
        right = unit(np.cross(forward, [0.0, 1.0, 0.0]))
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
        turn = float(window.is_pressed("x")) - float(window.is_pressed("z"))
        self.pose.roll += turn * self.roll_speed * dt
        self.toggle_grasp(window.is_pressed("g"))
        self.cautery = window.is_pressed("c")

    def toggle_grasp(self, key_down: bool):
        """Flip the jaws when the grasp key goes down."""
        if key_down and not self._grasp_key_down:
            self.grasp = not self.grasp
        self._grasp_key_down = key_down

    def buttons(self, time: float) -> dict[str, int]:
        return {
            self.name: (GRASP_BUTTON if self.grasp else 0) | (CAUTERY_BUTTON if self.cautery else 0)
        }

    def poses(self, time: float) -> dict[str, Pose]:
        return {self.name: self.pose}


def applied_poses(tools: list[dict], poses: dict[str, Pose]) -> dict[str, Pose]:
    """Every placed tool's pose, in scene order: the device's, or the scene pose for a
    tool no device drives."""
    return {
        tool["name"]: poses.get(tool["name"])
        or Pose(np.asarray(tool["tip"], float), unit(tool["direction"]))
        for tool in tools[:MAX_TOOLS]
    }


def apply_poses(
    control: Control,
    tools: list[dict],
    poses: dict[str, Pose],
    buttons: dict[str, int] | None = None,
):
    """Write each tool's capsule (tip to tip + length·direction) into ``control``;
    a tool no device drives keeps its scene pose. Graspers and scissors have jaws; a
    grasper's are closed while its ``GRASP_BUTTON`` is pressed."""
    placed = applied_poses(tools, poses)
    buttons = buttons or {}
    for index, tool in enumerate(tools[:MAX_TOOLS]):
        pose = placed[tool["name"]]
        control.set_tool(
            index,
            pose.tip,
            pose.tip + tool["length"] * pose.direction,
            tool["radius"],
            grasp=tool["kind"] == "grasper" and bool(buttons.get(tool["name"], 0) & GRASP_BUTTON),
            jaw_length=tool_geometry(tool).jaw_length,
            roll=pose.roll,
        )


class DeviceSet:
    """Several devices driving the scene at once, as two haptic devices for two hands:
    their poses and buttons merged (a later device wins a tool two devices drive),
    each attached to the session and closed with it when it needs that."""

    def __init__(self, devices: list):
        self.devices = devices
        self.source = ", ".join(
            f"{type(d).__name__}" + (f"({d.source})" if getattr(d, "source", "") else "")
            for d in devices
        )

    def poses(self, time: float) -> dict[str, Pose]:
        return {name: pose for device in self.devices for name, pose in device.poses(time).items()}

    def buttons(self, time: float) -> dict[str, int]:
        return {
            name: value
            for device in self.devices
            if hasattr(device, "buttons")
            for name, value in device.buttons(time).items()
        }

    def drain_ticks(self) -> list[tuple[float, dict]]:
        """The haptic ticks of every device since the last call, in clock order."""
        ticks = [
            tick
            for device in self.devices
            if hasattr(device, "drain_ticks")
            for tick in device.drain_ticks()
        ]
        return sorted(ticks, key=lambda tick: tick[0])

    def update(self, *args):
        for device in self.devices:
            if hasattr(device, "update"):
                device.update(*args)

    def attach(self, session):
        """Attach every device that needs the session; on a failure close those
        already attached, then raise."""
        attached = []
        try:
            for device in self.devices:
                if hasattr(device, "attach"):
                    device.attach(session)
                    attached.append(device)
        except BaseException:
            for device in reversed(attached):
                device.close()
            raise

    def close(self):
        for device in reversed(self.devices):
            if hasattr(device, "close"):
                device.close()
