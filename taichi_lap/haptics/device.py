"""The interface every haptic device offers, and the device-to-scene workspace mapping.

A haptic device (seed 002 §3.4: a Geomagic Touch per hand, position in, 3-D force
out, no torque) gives the pose of its stylus and its buttons, and takes a force.
The servo loop that talks to the hardware runs at 1 kHz in the haptics process
(Taichi kernels hold the GIL, so it cannot share the simulation's process).
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WorkspaceMapping:
    """Maps the device workspace [mm] onto the scene [m].

    Only the translation of a pose is mapped: ``t_scene = scale * t_device + offset``,
    with ``scale`` in scene metres per device millimetre (0.001 keeps real size) and
    ``offset`` [m] the scene point the device origin lands on. The rotation is kept,
    so device axes (OpenHaptics: +x right, +y up, +z toward the user) are scene axes
    and forces [N] need no mapping.
    """

    scale: float = 0.001
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if not (
            isinstance(self.scale, (int, float)) and math.isfinite(self.scale) and self.scale > 0
        ):
            raise ValueError(
                f"WorkspaceMapping.scale: a positive finite number [m/mm] was "
                f"expected, found {self.scale!r}"
            )
        offset = np.asarray(self.offset, dtype=np.float64)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise ValueError(
                f"WorkspaceMapping.offset: three finite numbers [m] were "
                f"expected, found {self.offset!r}"
            )
        object.__setattr__(self, "scale", float(self.scale))
        object.__setattr__(self, "offset", tuple(float(v) for v in offset))

    def to_scene(self, transform_mm: np.ndarray) -> np.ndarray:
        """A 4×4 device transform (translation [mm]) as a scene transform ([m])."""
        out = np.array(transform_mm, dtype=np.float64)
        out[:3, 3] = self.scale * out[:3, 3] + np.asarray(self.offset)
        return out


class HapticDevice(abc.ABC):
    """A force-feedback device: stylus pose and buttons in, force out.

    Use it as a context manager (``with Device(...) as dev:``) or call :meth:`close`;
    closing stops force output first.
    """

    @property
    @abc.abstractmethod
    def max_force(self) -> float:
        """Nominal maximum continuous force [N]; every force sent is clamped to it."""

    @abc.abstractmethod
    def pose(self) -> np.ndarray:
        """Latest stylus pose: a 4×4 row-major transform, translation in scene units [m]."""

    @abc.abstractmethod
    def buttons(self) -> int:
        """Latest button bitmask (bit k set while button k+1 is pressed)."""

    @abc.abstractmethod
    def set_force(self, force_newtons: np.ndarray, *, snapshot_time: float | None = None):
        """Command a force [N] (3-vector, scene axes) until the next call.

        ``snapshot_time`` is the ``time.monotonic()`` [s] of the simulation snapshot the
        force was computed from (default: now); a force older than the device's
        watchdog timeout fades to zero.
        """

    @abc.abstractmethod
    def close(self):
        """Stop force output and release the device; calling it again does nothing."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
