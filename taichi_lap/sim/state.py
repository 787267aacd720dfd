"""Dynamic simulation state (the Warp/Newton ``State``): positions, velocities,
goals, recovery factors, collision flags, cluster frames, the skinned surface and
the health flag. :meth:`State.reset` puts it at rest; the solver updates it in place.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.core import fields
from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.core.instruments import MAX_TOOLS
from taichi_lap.kernels.collision.particle_contact import FREE
from taichi_lap.kernels.health import NO_FAULT
from taichi_lap.sim.model import Model

SNAPSHOT_FIELDS = (
    "x",
    "v",
    "goal",
    "eta",
    "collided",
    "grasp_tool",
    "grasp_local",
    "cluster_rotation",
    "cluster_quaternion",
    "cluster_center",
)
"""State fields carried from one frame to the next (the rest is scratch of a step)."""
ROW_FIELDS = {
    "cluster_rotation": ("clusters", {"matrix": (3, 3)}),
    "cluster_quaternion": ("clusters", {"vector": 4}),
    "cluster_center": ("clusters", {"vector": 3}),
    "chunk_first": ("chunks", {"vector": 3}),
    "chunk_moment": ("chunks", {"matrix": (3, 3)}),
    "surface_position": ("vertices", {"vector": 3}),
}
"""f32 fields sized by a kind of the model's rows (:attr:`Model.capacity`): name ->
(kind, shape of an entry); :meth:`State.grow` follows the model's."""


@ti.data_oriented
class State(FieldOwner):
    """Per-particle ``x`` [m], ``v`` [m/s], predicted ``p`` [m] (and a second buffer
        for Jacobi sweeps), shape-matching ``goal`` [m], recovery factor ``eta`` and
        ``collided`` flag (seed 000 Alg. 1); per-cluster rotation and mass centre; the
        skinned surface vertices; ``fault`` (non-zero after a non-finite or exploding
        particle, the first such particle in ``fault_particle``); the grasp: per particle
    the holding tool (``grasp_tool``, -1 for none) and its place in that tool's frame
    (``grasp_local`` [m]); per tool on the Python side whether its jaws are closed
    (``jaws_closed``)."""

    def __init__(self, model: Model):
        n = model.particle_count
        group = FieldGroup()
        self.x = group.field(ti.f32, n, vector=3)
        self.v = group.field(ti.f32, n, vector=3)
        self.p = group.field(ti.f32, n, vector=3)
        self.p_next = group.field(ti.f32, n, vector=3)
        self.goal = group.field(ti.f32, n, vector=3)
        self.eta = group.field(ti.f32, n)
        self.collided = group.field(ti.i32, n)
        for name, (kind, shape) in ROW_FIELDS.items():
            setattr(self, name, group.field(ti.f32, model.capacity[kind], **shape))
        self._rows = group  # a tree of their own once grown (Model.grow)
        self.grasp_tool = group.field(ti.i32, n)
        self.grasp_local = group.field(ti.f32, n, vector=3)
        self.fault = group.field(ti.i32, None)
        self.fault_particle = group.field(ti.i32, None)
        group.finalize()
        self._group = group
        self.time = 0.0
        self.frame = 0
        self.jaws_closed = [False] * MAX_TOOLS

    def grow(self, model: Model):
        """Reallocate the fields sized by ``model``'s rows after :meth:`Model.grow`
        (values kept), in a tree of their own as the model's."""
        rows = {name: model.capacity[kind] for name, (kind, _) in ROW_FIELDS.items()}
        self._rows = self._rows.regrown(self, rows)

    def close(self):
        """Free the state's fields (:meth:`FieldGroup.close`)."""
        self._rows.close()
        super().close()

    def reset(self, model: Model):
        """Return to the rest configuration."""
        rest, centers = fields.read([model.rest_position, model.cluster_rest_center])
        n = len(rest)
        clusters = self.cluster_rotation.shape[0]
        fields.write(
            [(getattr(self, name), rest) for name in ("x", "p", "p_next", "goal")]
            + [
                (self.v, np.zeros((n, 3))),
                (self.eta, np.zeros(n)),
                (self.collided, np.zeros(n)),
                (self.cluster_rotation, np.broadcast_to(np.eye(3), (clusters, 3, 3))),
                (self.cluster_quaternion, np.tile([1.0, 0.0, 0.0, 0.0], (clusters, 1))),
                (self.cluster_center, centers),
                (self.grasp_tool, np.full(n, FREE)),
                (self.grasp_local, np.zeros((n, 3))),
            ]
        )
        self.fault[None] = 0
        self.fault_particle[None] = NO_FAULT
        self.time = 0.0
        self.frame = 0
        self.jaws_closed = [False] * MAX_TOOLS

    def positions(self) -> np.ndarray:
        """Particle positions (N, 3) [m] as a NumPy copy."""
        return self.x.to_numpy()

    def snapshot(self) -> dict[str, np.ndarray]:
        """Everything that evolves between frames, as NumPy copies (for determinism
        checks and :meth:`restore`)."""
        values = fields.read(getattr(self, name) for name in SNAPSHOT_FIELDS)
        return dict(zip(SNAPSHOT_FIELDS, values))

    def restore(self, snapshot: dict[str, np.ndarray]):
        """Put back a :meth:`snapshot` taken while no tool held tissue, as frame 0:
        predictions at x, no fault, jaws open, time 0. A snapshot taken before the
        model grew (:meth:`grow`) lacks the new cluster rows, which keep their values.
        A snapshot of another model (an array of another shape or type) raises
        ValueError and changes nothing."""
        arrays = {}
        for name, current in self.snapshot().items():
            array = snapshot[name]
            if name.startswith("cluster_") and len(array) < len(current):
                array = np.concatenate([array, current[len(array) :]])
            arrays[name] = array
            if array.shape != current.shape or array.dtype != current.dtype:
                raise ValueError(
                    f"{name}: {array.dtype} {array.shape} was found, {current.dtype} "
                    f"{current.shape} was expected"
                )
        if (snapshot["grasp_tool"] != FREE).any():
            raise ValueError("cannot restore a snapshot taken while a tool held tissue")
        fields.write(
            [(getattr(self, name), arrays[name]) for name in SNAPSHOT_FIELDS]
            + [(self.p, arrays["x"]), (self.p_next, arrays["x"])]
        )
        self.fault[None] = 0
        self.fault_particle[None] = NO_FAULT
        self.time = 0.0
        self.frame = 0
        self.jaws_closed = [False] * MAX_TOOLS
