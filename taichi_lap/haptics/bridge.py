"""A haptic device as a simulation input: the scene's first tool follows the
graphical (non-penetrating) tool of the servo process (seed 002 §3.4).

The simulation publishes its surface every frame (``poses`` is called once per
frame before the step); the servo process runs the proxy at 1 kHz and writes the
graphical tool pose back. The tool's shaft is the stylus's +z axis, as in
OpenHaptics, mapped into the scene by the device's :class:`WorkspaceMapping`.
"""

from __future__ import annotations

import functools

import numpy as np

from taichi_lap.devices import Pose
from taichi_lap.errors import InputError
from taichi_lap.haptics.device import WorkspaceMapping
from taichi_lap.haptics.proxy import ProxySettings, SurfaceClusters, ToolCapsule
from taichi_lap.haptics.servo import ServoProcess, ServoSettings
from taichi_lap.haptics.snapshot import SceneSnapshot


class HapticBridge:
    """Drives ``tool`` (a scene tool table) from the device ``device_factory``
    (a picklable callable opening a :class:`HapticDevice` in the servo process)."""

    def __init__(self, tool: dict, device_factory, *, label: str = "haptic device",
                 settings: ServoSettings = ServoSettings()):
        self.name, self.device_label = tool["name"], label
        self.capsule = ToolCapsule(length=tool["length"], radius=tool["radius"])
        self._factory, self._settings = device_factory, settings
        self.session = self.surface = self.snapshot = self.servo = None

    def attach(self, session):
        """Start the servo for ``session``: publish its surface, then open the device."""
        self.session = session
        self.surface = SurfaceClusters(session.data)
        self.snapshot = SceneSnapshot.create(clusters=self.surface.cluster_count,
                                             particles=self.surface.particle_count)
        self.surface.publish(self.snapshot, session.state.x.to_numpy())
        try:
            self.servo = ServoProcess(self.snapshot.name, self._factory,
                                      ProxySettings(self.capsule), self._settings).start()
        except RuntimeError as exc:
            self.snapshot.close()
            raise InputError("--device", self.device_label, f"a working haptic device was "
                                                            f"expected: {exc}") from None

    def poses(self, time: float) -> dict[str, Pose]:
        """Publish the current surface; the tool at the servo's graphical pose."""
        self.surface.publish(self.snapshot, self.session.state.x.to_numpy())
        feedback = self.servo.feedback.read()
        if feedback is None:
            return {}
        pose = feedback.graphic_pose
        direction = pose[:3, :3] @ np.asarray(self.capsule.axis)
        return {self.name: Pose(tip=pose[:3, 3].copy(), direction=direction)}

    def close(self):
        """Stop the servo (zero force first), then free the shared memory."""
        if self.servo is not None:
            self.servo.close()
        if self.snapshot is not None:
            self.snapshot.close()


def openhaptics_bridge(tool: dict, device_name: str | None, library: str | None) -> HapticBridge:
    """The bridge for an OpenHaptics device (``device_name`` None: the default one),
    mapped so that the device's origin lies at the tool's scene tip."""
    from taichi_lap.haptics.openhaptics import OpenHapticsDevice

    mapping = WorkspaceMapping(scale=tool["workspace_scale"], offset=tuple(tool["tip"]))
    return HapticBridge(tool, functools.partial(OpenHapticsDevice, device_name, library=library,
                                                mapping=mapping),
                        label=f"openhaptics:{device_name}" if device_name else "openhaptics")
