"""Tool keyframes, as a scene's inline ``script`` or a script file holds them.

Each keyframe gives a tool's tip [m] at a time [s], optionally its direction from the
tip towards the handle (kept from the previous keyframe, first from the tool), its roll
about that axis [degrees] (kept; 0 at first), whether a grasper's jaws are closed from then on and whether a hook is energised from
then on (both kept; off at first). The two are the stylus buttons a keyframe holds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.instruments import CAUTERY_BUTTON, GRASP_BUTTON
from taichi_lap.core.params import REQUIRED, Param, check_table

KEYFRAME_PARAMS = {
    "time": Param("float", REQUIRED, "time of the keyframe", lo=0.0, hi=1e6, unit="s"),
    "tool": Param("str", REQUIRED, "name of a tool of the scene"),
    "tip": Param("vec3", REQUIRED, "tip position", lo=-100, hi=100, unit="m"),
    "direction": Param("vec3", None, "from the tip towards the handle", lo=-1e3, hi=1e3),
    "roll": Param(
        "float",
        None,
        "turn of the tool about its shaft (right-handed)",
        lo=-1e5,
        hi=1e5,
        unit="degrees",
    ),
    "grasp": Param("bool", None, "a grasper's jaws closed from this keyframe on"),
    "cautery": Param("bool", None, "a hook energised from this keyframe on"),
}
BUTTON_KEYS = {"grasp": GRASP_BUTTON, "cautery": CAUTERY_BUTTON}
"""The keyframe keys that hold a button, and its bitmask."""


class Keyframe(NamedTuple):
    """A tool's pose at a ``time`` [s]: ``tip`` [m], unit ``direction`` (tip towards
    handle), ``buttons`` held (a bitmask) and ``roll`` about the shaft [rad]."""

    time: float
    tip: np.ndarray
    direction: np.ndarray
    buttons: int
    roll: float


def unit(v) -> np.ndarray:
    """``v`` scaled to length 1 (the y axis for a zero vector)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else np.array([0.0, 1.0, 0.0])


def read_keyframes(source: str, frames: list, tools: list[dict]) -> dict[str, list[Keyframe]]:
    """Keyframe tables ``frames`` of the scene's ``tools``, checked (every error names
    ``source`` and the key), per tool name in time order."""
    names = {t["name"]: t for t in tools}
    keyframes: dict[str, list[Keyframe]] = {}
    for k, table in enumerate(frames):
        key = f"keyframe[{k}]"
        frame = check_table(source, key, table, KEYFRAME_PARAMS)
        if frame["tool"] not in names:
            raise InputError(
                source,
                f"{key}.tool",
                f"one of the scene's tools "
                f"({', '.join(names) or 'none'}) was "
                f"expected, found {frame['tool']!r}",
            )
        track = keyframes.setdefault(frame["tool"], [])
        if track and frame["time"] < track[-1].time:
            raise InputError(
                source,
                f"{key}.time",
                f"times in increasing order were expected, "
                f"found {frame['time']} after {track[-1].time}",
            )
        direction = frame["direction"] or (
            track[-1].direction if track else names[frame["tool"]]["direction"]
        )
        buttons = track[-1].buttons if track else 0
        for name, bit in BUTTON_KEYS.items():
            if frame[name] is not None:
                buttons = buttons | bit if frame[name] else buttons & ~bit
        roll = (
            np.radians(frame["roll"])
            if frame["roll"] is not None
            else (track[-1].roll if track else 0.0)
        )
        track.append(
            Keyframe(
                frame["time"],
                np.asarray(frame["tip"], float),
                unit(direction),
                buttons,
                float(roll),
            )
        )
    return keyframes
