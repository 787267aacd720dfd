"""Haptic devices and the safety of the forces sent to them (seed 002 §3.4).

:class:`HapticDevice` is the interface, :class:`WorkspaceMapping` places a device's
workspace [mm] in the scene [m], :class:`ForceSafety` filters every force and
:class:`OpenHapticsDevice` drives OpenHaptics (HDAPI) devices such as the Geomagic
Touch. Importing this package loads no device library.
"""

from taichi_lap.haptics.device import HapticDevice, WorkspaceMapping
from taichi_lap.haptics.openhaptics import HDError, OpenHapticsDevice, OpenHapticsError
from taichi_lap.haptics.safety import ForceSafety

__all__ = [
    "ForceSafety",
    "HDError",
    "HapticDevice",
    "OpenHapticsDevice",
    "OpenHapticsError",
    "WorkspaceMapping",
]
from taichi_lap.haptics.feedback import ServoFeedback, ServoState, ToolFeedback
from taichi_lap.haptics.proxy import (
    HapticProxy,
    ProxySettings,
    ProxyStatus,
    SurfaceClusters,
    grasp_edges,
    pull_force,
)
from taichi_lap.haptics.servo import ScriptedHapticDevice, ServoProcess, ServoSettings
from taichi_lap.haptics.snapshot import HapticScene, SceneSnapshot, SnapshotCapacityError

__all__ += [
    "HapticProxy",
    "HapticScene",
    "ProxySettings",
    "ProxyStatus",
    "SceneSnapshot",
    "ScriptedHapticDevice",
    "ServoFeedback",
    "ServoProcess",
    "ServoSettings",
    "ServoState",
    "SnapshotCapacityError",
    "SurfaceClusters",
    "ToolFeedback",
    "grasp_edges",
    "pull_force",
]
