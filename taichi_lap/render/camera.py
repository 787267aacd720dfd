"""The endoscope camera: a view from the scope's tip, moved by keys and mouse in
the GGUI window (the scope pivots about its tip and slides along its axis, as
through a trocar)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / max(float(np.linalg.norm(v)), 1e-12)


@dataclass
class EndoscopeCamera:
    """Tip position ``eye`` and ``target`` [m], ``up`` direction, vertical ``fov``
    [deg], ``near`` and ``far`` clipping distances [m]."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov: float
    near: float
    far: float
    speed: float = 0.05  # [m/s] along the axis and sideways (keys)
    turn_rate: float = 2.0  # [rad] per window width of mouse drag

    @classmethod
    def from_scene(cls, camera: dict) -> "EndoscopeCamera":
        return cls(
            eye=np.asarray(camera["position"], float),
            target=np.asarray(camera["target"], float),
            up=_unit(camera["up"]),
            fov=float(camera["fov"]),
            near=float(camera["near"]),
            far=float(camera["far"]),
        )

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit ``forward``, ``right`` and ``up`` of the view."""
        forward = _unit(self.target - self.eye)
        right = _unit(np.cross(forward, self.up))
        return forward, right, np.cross(right, forward)

    def sees(self, points: np.ndarray, aspect: float = 16.0 / 9.0) -> np.ndarray:
        """(n,) bool: which ``points`` (n, 3) [m] lie in the view (between the clipping
        distances, within the vertical ``fov`` and ``aspect`` times as wide)."""
        forward, right, up = self.axes()
        d = np.asarray(points, float).reshape(-1, 3) - self.eye
        depth = d @ forward
        half = np.tan(np.radians(self.fov) / 2.0) * np.maximum(depth, 1e-12)
        return (
            (depth >= self.near)
            & (depth <= self.far)
            & (np.abs(d @ up) <= half)
            & (np.abs(d @ right) <= aspect * half)
        )

    def move(self, *, advance: float = 0.0, strafe: float = 0.0, lift: float = 0.0):
        """Slide eye and target together [m] along the view axes."""
        forward, right, up = self.axes()
        shift = advance * forward + strafe * right + lift * up
        self.eye, self.target = self.eye + shift, self.target + shift

    def turn(self, yaw: float, pitch: float):
        """Pivot the view about the tip [rad]; the distance to the target is kept
        and the view never flips over the up direction."""
        forward, right, up = self.axes()
        distance = float(np.linalg.norm(self.target - self.eye))
        heading = _unit(forward * np.cos(yaw) + right * np.sin(yaw))
        tilted = _unit(heading * np.cos(pitch) + up * np.sin(pitch))
        if abs(float(np.dot(tilted, self.up))) < 0.98:
            heading = tilted
        self.target = self.eye + distance * heading

    def track_window(self, window, dt: float, *, drag_button, last_cursor):
        """Keys w/s advance and retreat, a/d strafe, r/f lift; dragging with
        ``drag_button`` turns the scope. Returns the cursor for the next call."""
        step = self.speed * dt
        keys = {
            "w": dict(advance=step),
            "s": dict(advance=-step),
            "a": dict(strafe=-step),
            "d": dict(strafe=step),
            "r": dict(lift=step),
            "f": dict(lift=-step),
        }
        for key, motion in keys.items():
            if window.is_pressed(key):
                self.move(**motion)
        cursor = np.asarray(window.get_cursor_pos(), float)
        if window.is_pressed(drag_button) and last_cursor is not None:
            delta = cursor - last_cursor
            self.turn(delta[0] * self.turn_rate, delta[1] * self.turn_rate)
        return cursor
