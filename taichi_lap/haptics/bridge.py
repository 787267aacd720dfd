"""A haptic device as a simulation input: a scene tool follows the graphical
(non-penetrating) tool of the servo process (seed 002 §3.4), and pushes the tissue as
the device force does.

Seed 002 §3.4 couples the two ways by letting the feedback force change the
particles' velocities (Newton's second law). Applied as it stands, once per frame to
the few particles under the tool, that step is unstable: a proxy gain g of 300 N/m
against particles of a few milligrams gives g dt² / m near 1000 per frame. The bridge
solves the same force balance implicitly instead (admittance, a virtual coupling):
while the tissue pushes the scene tool, the tool goes from where it was, s, a
fraction κ of the way the unbalanced force points,

    s' = s + κ ((q_h - s) + F_t / g),

with q_h the stylus and F_t the force the tissue pushed the tool with in the last
step (:meth:`Session.tool_reaction`: the shape-matching pull on the particles' haptic
mass, which each tissue sets, as the seed sets the mass per tissue). The contact that
holds moves the surface with the tool; the servo couples the stylus to s by the
spring g (q_h - s) (:class:`~taichi_lap.haptics.proxy.HapticProxy`); the tool settles
where F_t balances that spring, s = q_h + F_t / g, so the tissue gives way under the
stylus and the device force, g (q_h - s), is the tissue's push and grows with the
indentation. The iteration contracts while κ (1 + k_t / g) < 2, with k_t [N/m] the
tissue's stiffness under the tool. A move is at most a tool radius per frame. Where
no tissue pushes the tool it is the servo's graphical tool (the stylus in free
space, the proxy on the surface at first touch, pressed :data:`TOUCH_DEPTH` into it
so that the simulation's contact engages); so it is while the tool's jaws hold
tissue, whose pull the servo renders by Hooke's law over the grasped edges instead.

The simulation publishes its surface every frame (``poses`` is called once per
frame before the step); the servo process runs the proxy at 1 kHz and writes the
graphical tool pose and the stylus buttons back. The tool's shaft is the stylus's
+z axis, as in OpenHaptics, mapped into the scene by the device's
:class:`WorkspaceMapping`. While the tool's jaws hold particles, the published
snapshot carries their edges to free neighbours (the grasped end in the stylus
frame), from which the servo adds the pull force of Hooke's law. After a dissection
the published surface follows the tissue left: removed particles leave it and the
particles a wound exposed join it (regrouped before the next publication). A
surface that outgrows the snapshot moves it to a larger shared-memory region, which
the servo follows (:meth:`~taichi_lap.haptics.snapshot.SceneSnapshot.reserve`).
"""

from __future__ import annotations

import functools
import logging

import numpy as np

from taichi_lap.core.errors import InputError
from taichi_lap.core.instruments import tool_geometry
from taichi_lap.devices import Pose
from taichi_lap.haptics.device import WorkspaceMapping
from taichi_lap.haptics.feedback import RING_INPUT
from taichi_lap.haptics.proxy import ProxySettings, SurfaceClusters, grasp_edges
from taichi_lap.haptics.servo import ServoProcess, ServoSettings
from taichi_lap.haptics.snapshot import SceneSnapshot
from taichi_lap.sim.model import SURFACE_SPARE, spare_rows

log = logging.getLogger("taichi_lap.haptics")

GRASP_EDGE_CAPACITY = 4096
"""Grasp edges one snapshot carries to the servo."""
COUPLING = 0.5
"""κ: the fraction of the unbalanced force's way the scene tool goes per frame."""
REACTION_FLOOR = 1e-6
"""[N]: a smaller tissue push leaves the tool uncoupled."""
TOUCH_DEPTH = 5e-4
"""[m]: how far past the proxy's resting pose, towards the stylus, the uncoupled
scene tool goes at a touch, so that the simulation's contact engages (a sheet drawn
through its particles is touched only when entered) and the coupling can start."""


class HapticBridge:
    """Drives ``tool`` (a scene tool table) from the device ``device_factory``
    (a picklable callable opening a :class:`HapticDevice` in the servo process)."""

    def __init__(
        self,
        tool: dict,
        device_factory,
        *,
        label: str = "haptic device",
        settings: ServoSettings = ServoSettings(),
    ):
        self.name, self.device_label = tool["name"], label
        self.source = label  # what the session record names
        self.geometry = tool_geometry(tool)
        self.grasp_stiffness = tool["grasp_stiffness"]
        self._factory, self._settings = device_factory, settings
        self.session = self.surface = self.snapshot = self.servo = self.feedback = None
        self._surface_version = None  # the model's topology_version the surface follows
        self.tool_index = -1
        self._tip = self._coupled = None  # the scene tool's tip, the coupled tip [m]
        self.proxy = ProxySettings(self.geometry, grasp_stiffness=self.grasp_stiffness)
        self._ticks_seen = 0
        self._held = np.zeros(0, dtype=np.int64)  # the grasped particles _edges belong to
        self._edges = np.zeros((0, 2), dtype=np.int64)
        self._edge_rest = np.zeros(0)

    def attach(self, session):
        """Start the servo for ``session``: publish its surface, then open the device."""
        self.session = session
        self.tool_index = [tool["name"] for tool in session.scene.tools].index(self.name)
        self._follow_surface()
        dissectable = session.model.dissectable  # a wound exposes particles from inside
        self.snapshot = SceneSnapshot.create(
            clusters=spare_rows(self.surface.cluster_count, dissectable, SURFACE_SPARE),
            particles=spare_rows(self.surface.particle_count, dissectable, SURFACE_SPARE),
            grasp_edges=GRASP_EDGE_CAPACITY,
        )
        self.surface.publish(self.snapshot, session.state.x.to_numpy())
        try:
            self.servo = ServoProcess(
                self.snapshot.name, self._factory, self.proxy, self._settings
            ).start()
        except RuntimeError as exc:
            self.snapshot.close()
            raise InputError(
                "--device", self.device_label, f"a working haptic device was expected: {exc}"
            ) from None

    def poses(self, time: float) -> dict[str, Pose]:
        """Publish the current surface, grasp and coupled tip; the tool at that tip,
        along the servo's graphical pose."""
        state = self.session.state
        if self._surface_version != self.session.model.topology_version:
            self._follow_surface()
            surface = self.surface
            if self.snapshot.reserve(
                clusters=surface.cluster_count, particles=surface.particle_count
            ):
                log.info(
                    "haptic snapshot of %s moved to a region for %d clusters, %d particles",
                    self.device_label,
                    self.snapshot.capacity["clusters"],
                    self.snapshot.capacity["particles"],
                )
        x = state.x.to_numpy()
        closed = bool(state.jaws_closed[self.tool_index])
        grasp = self._grasp(x) if closed else {}
        self.feedback = self.servo.feedback.read()
        if self.feedback is None:
            self._tip = self._coupled = None
        else:
            self._tip = self._coupled_tip(closed)
        self.surface.publish(self.snapshot, x, coupling_tip=self._coupled, **grasp)
        if self._tip is None:
            return {}
        direction = self.feedback.graphic_pose[:3, 2]  # the tool frame's z: tip to handle
        return {self.name: Pose(self._tip, direction, self.feedback.roll)}

    def _follow_surface(self):
        """Group the particles the session's surface follows now (after a dissection:
        the wound's, not the removed ones) for the servo's collision."""
        self.surface = SurfaceClusters(self.session.data, surface=self.session.surface_particles())
        self._surface_version = self.session.model.topology_version

    def _coupled_tip(self, closed: bool) -> np.ndarray:
        """The scene tool's tip [m]: s' = s + κ ((q_h - s) + F_t / g) while tissue
        pushes it, the move at most a tool radius, else (and while the jaws are
        ``closed``) the graphical tool, at a touch :data:`TOUCH_DEPTH` past it towards
        the stylus (module docstring). Sets ``_coupled`` to the tip the servo couples
        to, or None."""
        graphic = self.feedback.graphic_pose[:3, 3].astype(np.float64)
        haptic = self.feedback.haptic_pose[:3, 3].astype(np.float64)
        self._coupled = None
        if closed or self._tip is None:
            return graphic
        reaction = self.session.tool_reaction(self.tool_index)
        touching = np.all(np.isfinite(reaction)) and np.linalg.norm(reaction) > REACTION_FLOOR
        if not touching:
            press = haptic - graphic  # zero in free space
            length = float(np.linalg.norm(press))
            return graphic + press * min(1.0, TOUCH_DEPTH / length) if length > 0.0 else graphic
        move = COUPLING * ((haptic - self._tip) + reaction / self.proxy.gain)
        length, limit = float(np.linalg.norm(move)), self.geometry.radius
        if length > limit:
            move *= limit / length
        self._coupled = self._tip + move
        return self._coupled

    def buttons(self, time: float) -> dict[str, int]:
        """The stylus buttons of the servo tick :meth:`poses` read."""
        return {self.name: self.feedback.buttons if self.feedback is not None else 0}

    def drain_ticks(self) -> list[tuple[float, dict]]:
        """The servo ticks since the last call, oldest first, each as ``(clock, {tool:
        (pose, buttons, force)})`` for :meth:`RecordStream.tick`."""
        ticks, self._ticks_seen, lost = self.servo.feedback.ticks_since(self._ticks_seen)
        if lost:
            log.warning(
                "%d servo ticks of %s were overwritten before they were recorded",
                lost,
                self.device_label,
            )
        return [
            (float(clock), {self.name: (Pose(tip, direction, float(roll)), int(buttons), force)})
            for clock, tip, direction, roll, buttons, force in zip(*(ticks[k] for k in RING_INPUT))
        ]

    def _grasp(self, x: np.ndarray) -> dict:
        """The grasp edges of the particles this tool holds (at most the snapshot's
        capacity, nearest the tip first), the grasped end in the stylus frame. The
        edges and their rest lengths are found once per grasp (the held set changes
        only when the jaws close)."""
        grasped = np.flatnonzero(self.session.state.grasp_tool.to_numpy() == self.tool_index)
        if self.feedback is None or not len(grasped):
            return {}
        if not np.array_equal(grasped, self._held):
            data = self.session.data
            self._held = grasped
            self._edges = grasp_edges(data.tets, grasped, data.distance_pair)
            ends = data.rest_position[self._edges]
            self._edge_rest = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        edges, pose = self._edges, self.feedback.graphic_pose
        local = (x[edges[:, 0]] - pose[:3, 3]) @ pose[:3, :3]
        order = np.argsort(np.linalg.norm(local, axis=1), kind="stable")[:GRASP_EDGE_CAPACITY]
        return {
            "grasp_local": local[order],
            "grasp_neighbor": x[edges[order, 1]],
            "grasp_rest": self._edge_rest[order],
        }

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
    return HapticBridge(
        tool,
        functools.partial(OpenHapticsDevice, device_name, library=library, mapping=mapping),
        label=f"openhaptics:{device_name}" if device_name else "openhaptics",
    )
