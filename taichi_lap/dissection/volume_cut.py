"""Volumetric cutting in a session (seed 000 §5.3): the scissors' blade, swept while
their jaws close, splits the tets of the organs whose surface is their particles,
and a piece cut free can be taken out of the body.

:func:`~taichi_lap.dissection.tet_cut.cut_tets` decides on the host, at the tissue's
current positions, which tets the blade's path (:class:`BladePath`, the jaws' edge at
every step of the stroke) has passed through; :class:`VolumeCutter` makes that the
organ's topology (:meth:`~taichi_lap.dissection.removal.MutableTopology.split_tets`):

* a new vertex takes a particle row from the organ's reserve
  (:func:`~taichi_lap.preprocess.organs.add_cut_reserve`) with its parents' position,
  rest position and velocity by the cut's weights, and joins the clusters of
  the particle on its side of the cut; clusters the cut parts split into their
  connected pieces, so the two sides move apart;
* the mass the split tets held goes to their sub-tets by volume
  (:func:`~taichi_lap.core.mesh.masses_after_cut`): the organ keeps its mass, and the
  clusters weigh their members anew;
* the sub-tets a stroke made are not cut again by the same stroke (their faces on
  the cut lie on its path), nor are tets beside a removal's wound;
* a piece of an organ that the cut left holding no pinned particle and sharing no
  cluster with other tissue is loose (:meth:`VolumeCutter.loose_pieces`): lifted
  out of the endoscope's view it is excised (:meth:`~taichi_lap.session.Session`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from taichi_lap.core.instruments import CUT_REACH, JAW_LENGTH, JAW_RADIUS
from taichi_lap.core.csr import rows_of
from taichi_lap.core.mesh import element_pieces, in_box, masses_after_cut
from taichi_lap.dissection.device import DeviceTopology
from taichi_lap.dissection.removal import TopologyChange
from taichi_lap.dissection.tet_cut import BladePath, cut_tets

log = logging.getLogger("taichi_lap")

PATH_REACH = 0.01
"""The blade path a stroke keeps [m]: the blades of the steps within this distance of
the current one (the path stays where it was drawn in space while the tissue moves;
a piece falling through where the blade passed long ago is not cut), several tets
long so a blade that moves slowly still passes through the tets it entered."""


def scissor_blade(tool: dict, tip: np.ndarray, frame: np.ndarray, motion=None) -> np.ndarray:
    """The cutting edge of a scissors' closed jaws (2, 3) [m]: from the tool's ``tip``
    (the jaws' hinge at the end of the shaft) along the jaws' axis,
    :data:`~taichi_lap.core.instruments.JAW_LENGTH` shaft radii ahead of it (tool
    frame ``frame``, 3×3, columns; the shaft runs along +z). Moving by ``motion``
    (3,) [m] since the last step, the edge is the jaws' leading side: the axis moved
    ahead by the jaws' radius and the cutting reach (the contact keeps the tissue on
    the jaws' surface, where the axis alone would never reach it, as
    :func:`~taichi_lap.core.instruments.cutting_geometry` says for sheets)."""
    tip = np.asarray(tip, float)
    axis = np.asarray(frame, float) @ np.array([0.0, 0.0, -JAW_LENGTH * float(tool["radius"])])
    blade = np.stack([tip, tip + axis])
    if motion is None:
        return blade
    across = np.asarray(motion, float) - (np.dot(motion, axis) / np.dot(axis, axis)) * axis
    length = float(np.linalg.norm(across))
    if length < 1e-9:
        return blade
    return blade + (JAW_RADIUS + CUT_REACH) * float(tool["radius"]) * across / length


@dataclass
class _Organ:
    """One organ the blade cuts: its index and the reserve rows left (taken from the
    end)."""

    organ: int
    free: list[int]
    spent: bool = False  # whether the reserve ran out (said once)


@dataclass
class _Stroke:
    """A tool's blade since its jaws closed: the blade at each step, the tets it made."""

    blades: list[np.ndarray] = field(default_factory=list)
    made: set[int] = field(default_factory=set)


class VolumeCutter:
    """Cuts the tet organs of a session's model with scissors (module docstring)."""

    def __init__(self, dissection: DeviceTopology):
        self.dissection = dissection
        data = dissection.model.data
        self.organs = []
        for k, organ in enumerate(data.organs):
            if organ.volume_cuttable:
                end = organ.particles[1]
                self.organs.append(_Organ(k, list(range(end - 1, end - organ.reserve - 1, -1))))
        self.strokes: dict[int, _Stroke] = {}

    def stroke(
        self, tool: int, blade: np.ndarray, x: np.ndarray, v: np.ndarray, state
    ) -> list[tuple[str, TopologyChange]]:
        """The blade (2, 3) [m] of scissors ``tool`` at this step, its jaws closed:
        cut every organ the stroke's path has now passed through, with the particles
        at ``x`` moving at ``v`` (N, 3); returns (organ name, change) of each cut."""
        stroke = self.strokes.setdefault(tool, _Stroke())
        stroke.blades.append(np.asarray(blade, dtype=np.float64))
        now = stroke.blades[-1].mean(axis=0)
        while len(stroke.blades) > 2 and (
            np.linalg.norm(stroke.blades[1].mean(axis=0) - now) > PATH_REACH
        ):
            stroke.blades.pop(0)
        if len(stroke.blades) < 2:
            return []
        path = BladePath.of(stroke.blades)
        out = []
        for organ in self.organs:
            change = self._cut(organ, stroke, path, x, v, state)
            if change is not None:
                out.append((self.dissection.model.data.organs[organ.organ].name, change))
        return out

    def release(self, tool: int):
        """Scissors ``tool`` opened its jaws: the next closing starts a new stroke."""
        self.strokes.pop(tool, None)

    def _cut(
        self, organ: _Organ, stroke: _Stroke, path: BladePath, x, v, state
    ) -> TopologyChange | None:
        """Cut ``organ``'s live tets near ``path`` (module docstring); None where no
        tet was split or the reserve is spent."""
        topology = self.dissection.topology
        low, high = (
            path.segments.reshape(-1, 3).min(axis=0),
            path.segments.reshape(-1, 3).max(axis=0),
        )
        if self.dissection.out_of_reach(organ.organ, x, low, high):
            return None
        tets = topology.live_tets(organ.organ)
        tets = tets[in_box(x, topology.tets[tets], low, high)]
        if not len(tets):
            return None
        keep_whole = np.isin(tets, list(stroke.made)) | topology.beside_wound(tets)
        given = np.bincount(topology.tets[tets].ravel(), minlength=len(topology.rest))
        cut = cut_tets(
            x,
            topology.tets[tets],
            path,
            rest=topology.rest,
            keep_whole=keep_whole,
            open_vertices=given < topology.live_tets_of,
        )
        if cut.empty:
            return None
        count = len(cut.vertex_parents)
        if count > len(organ.free):
            if not organ.spent:
                organ.spent = True
                record = self.dissection.model.data.organs[organ.organ]
                log.warning(
                    "%s: its reserve of %d particle rows for cuts is spent; cuts that need "
                    "more rows are not made",
                    record.name,
                    record.reserve,
                )
            return None
        rows = np.array([organ.free.pop() for _ in range(count)], dtype=np.int64)
        first_new = len(topology.tets)
        corners = np.unique(topology.tets[tets[cut.removed]])
        around = np.unique(topology.particle_tet[rows_of(topology.tet_start, corners)])
        around = around[topology.tet_alive[around]]  # every tet at the split tets' corners
        change = topology.split_tets(cut, tets, rows)
        mass = topology.mass.copy()
        mass[rows] = 0.0  # reserve rows: what they take comes from the cut's tets
        mass, _ = masses_after_cut(
            topology.rest,
            topology.tets[around],
            np.isin(around, change.dead_tets),
            topology.tets[first_new:],
            mass,
        )
        self.dissection.set_particles(
            rows, topology.rest[rows], mass[rows], cut.new_values(x), cut.new_values(v), state
        )
        self.dissection.set_masses(corners, mass[corners])
        self.dissection.apply(change, state)
        stroke.made.update(range(first_new, len(topology.tets)))
        return change

    def loose_pieces(self) -> list[tuple[int, np.ndarray]]:
        """(organ, particles) of every piece of a cut organ that hangs from nothing:
        a connected piece of its live tets with no pinned particle whose clusters
        hold only its own particles."""
        topology = self.dissection.topology
        out = []
        for organ in self.organs:
            tets = topology.tets[topology.live_tets(organ.organ)]
            label = element_pieces(tets)
            if label.max(initial=0) < 1:
                continue
            for k in range(label.max() + 1):
                piece = np.unique(tets[label == k])
                if topology.pinned[piece].any():
                    continue
                clusters = topology.clusters_of(piece)
                members = np.concatenate([topology.cluster_members[c] for c in clusters])
                if np.isin(members, piece).all():
                    out.append((organ.organ, piece))
        return out
