"""The blood film drawn on the tissue (kernels in ``taichi_lap.kernels.blood``): each
vessel damage starts a bleed where the tissue around the damaged vessel is open
(:meth:`BloodFilm._outlet`), which follows the tissue as it moves; every stepped
frame each bleed pours its flow (:func:`~taichi_lap.core.bleeding.bleed_rate`) onto
the surface around it and the film drains one step downhill. Where the film gathers
on a surface facing down it drips: a drop falls along gravity onto the surface
below (:func:`~taichi_lap.kernels.blood.drop_landings`) and joins the film there when
its fall is over. The film is the drawn mesh's ``blood`` (thickness [m] per
surface vertex), which the G-buffer interpolates and the shading draws as wet, dark
red blood."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import taichi as ti

from taichi_lap.core.bleeding import bleed_rate
from taichi_lap.core.fields import FieldGroup
from taichi_lap.kernels.blood import bleed, drain, drop_landings, film_shares

BLEED_RADIUS = 0.004
"""[m] the patch of surface a bleed pours onto, around its source."""
BLOOD_SPEED = 0.02
"""[m/s] how fast blood runs down a vertical surface (slope × this on an incline;
chosen by eye: a trickle, not a jet)."""
FILM_RESIDUE = 5e-5
"""[m] the film blood leaves behind as it runs on (a stain along its trail)."""
DRIP_FILM = 4e-4
"""[m] the film a surface facing down holds before a drop falls from it (a hanging
drop about 1 mm across; chosen by eye)."""
DRIP_FACING = 0.5
"""A vertex sheds drops where its normal turns more than 60° from up to down
(normal · gravity's direction above this)."""
MAX_DRIPS = 4
"""Drops released per frame at most, the thickest films first (each one's landing
tests every drawn triangle)."""
DRIP_GAP = 2e-4
"""[m] a drop lands only on a surface farther than this below its vertex (not on the
triangles beside it)."""


DROP_RADIUS = 7e-4
"""[m] a falling drop's radius as drawn (the hanging drop of :data:`DRIP_FILM`)."""


class Drop(NamedTuple):
    """A falling drop: where [m] and when [s] it fell from, how far it falls [m] and
    when it lands [s], the triangle it lands on, its corners and their weights, and how
    much film it carries (thickness [m] at one vertex)."""

    start: tuple[float, float, float]
    released: float
    height: float
    lands: float
    triangle: int
    corners: tuple[int, int, int]
    weights: tuple[float, float, float]
    film: float


class BloodFilm:
    """The bleeds of a session and the film they make on a drawn mesh's surface;
    blood runs along ``gravity`` (a 3-vector, any length; straight down -y when zero)."""

    def __init__(self, gravity=(0.0, -9.81, 0.0)):
        g = np.asarray(gravity, np.float64)
        down = g / np.linalg.norm(g) if np.linalg.norm(g) > 0.0 else np.array([0.0, -1.0, 0.0])
        self.down = tuple(float(c) for c in down)
        self.gravity = float(np.linalg.norm(g))  # [m/s²]; 0: drops land at once
        self.bleeds: list[tuple[int, float]] = []  # (particle followed, time it began [s])
        self.falling: list[Drop] = []
        self.spilled = 0.0  # film [m] of the drops that fell off the drawn tissue
        self.time = 0.0  # [s] the end of the frame last updated
        self._scratch = None  # (mesh, share, drained, group) for the mesh last drained

    def update(self, events: list[dict], state, data, time: float, dt: float, mesh):
        """After a stepped frame ending at ``time`` [s]: a bleed for each new
        ``vessel_damage`` event (at its outlet, :meth:`_outlet`; ``data`` the model's
        :class:`~taichi_lap.core.topology.ModelData`), then each bleed's flow over
        ``dt`` [s] poured onto ``mesh``'s surface, one drainage step and the drops
        (:meth:`drip`)."""
        self.time = time
        for event in (e for e in events if e["kind"] == "vessel_damage"):
            self.bleeds.append((self._outlet(event, state, data, mesh), time))
        if not self.bleeds:
            return
        count = mesh.smooth_count
        area = math.pi * BLEED_RADIUS**2 / 3.0  # ∫ (1 - d²/r²)² over the disc
        for particle, began in self.bleeds:
            thickness = bleed_rate(time - began) * dt / area
            source = tuple(float(c) for c in state.x[particle])
            bleed(mesh.positions, count, source, BLEED_RADIUS, thickness, mesh.blood)
        share, drained = self._fields(mesh)
        args = (mesh.positions, mesh.triangles, mesh.incident, count, self.down)
        film_shares(*args, BLOOD_SPEED * dt, FILM_RESIDUE, mesh.blood, share)
        drain(*args, share, mesh.blood, drained)
        mesh.blood.copy_from(drained)
        self.drip(mesh, time)

    def drip(self, mesh, time: float):
        """At ``time`` [s]: the drops whose fall is over join the film where they
        land (spread over the triangle's corners by where they hit it); then from each
        of the :data:`MAX_DRIPS` vertices with the most film above :data:`DRIP_FILM`
        whose normal faces down (:data:`DRIP_FACING`) the film above the residue falls
        as a drop, landing where :func:`drop_landings` finds the surface below, after
        √(2 h / g). A drop that meets nothing drawn, or what holds no film (the
        cavity's wall, whose triangles are too coarse to draw a drop's stain, or an
        instrument), adds to :attr:`spilled`. The film's sum over the vertices, plus the
        falling drops and the spilled film, is kept."""
        film = mesh.blood.to_numpy()
        landed = [d for d in self.falling if d.lands <= time]
        for drop in landed:
            for corner, weight in zip(drop.corners, drop.weights):
                film[corner] += drop.film * weight
        self.falling = [d for d in self.falling if d.lands > time]
        count = mesh.smooth_count
        facing = mesh.normals.to_numpy()[:count] @ np.asarray(self.down)
        hanging = np.flatnonzero((film[:count] > DRIP_FILM) & (facing > DRIP_FACING))
        sources = hanging[np.argsort(-film[hanging], kind="stable")[:MAX_DRIPS]].astype(np.int32)
        if not landed and not len(sources):
            return
        if len(sources):
            starts = mesh.positions.to_numpy()[sources]
            hit_triangle = np.zeros(len(sources), np.int32)
            hit = np.zeros((len(sources), 3), np.float32)
            drop_landings(
                mesh.positions,
                mesh.triangles,
                mesh.triangle_count,
                sources,
                self.down,
                DRIP_GAP,
                hit_triangle,
                hit,
            )
            for source, start, triangle, (height, u, v) in zip(sources, starts, hit_triangle, hit):
                amount = float(film[source] - FILM_RESIDUE)
                film[source] = FILM_RESIDUE
                corners = (
                    tuple(int(mesh.triangles[3 * triangle + k]) for k in range(3))
                    if triangle >= 0
                    else None
                )
                if corners is None or max(corners) >= count:  # onto nothing that holds film
                    self.spilled += amount
                    continue
                fall = math.sqrt(2.0 * height / self.gravity) if self.gravity > 0.0 else 0.0
                weights = (float(1.0 - u - v), float(u), float(v))
                self.falling.append(
                    Drop(
                        tuple(float(c) for c in start),
                        time,
                        float(height),
                        time + fall,
                        int(triangle),
                        corners,
                        weights,
                        amount,
                    )
                )
        mesh.blood.from_numpy(film)

    def in_flight(self) -> tuple[np.ndarray, np.ndarray]:
        """The drops still falling at the end of the frame last updated: their centres
        (D, 3) [m], fallen from rest under gravity, and the triangles they land on
        (D,)."""
        falling = [d for d in self.falling if d.lands > self.time]
        centres = [
            np.asarray(d.start)
            + np.asarray(self.down)
            * min(0.5 * self.gravity * (self.time - d.released) ** 2, d.height)
            for d in falling
        ]
        return (
            np.array(centres, np.float32).reshape(-1, 3),
            np.array([d.triangle for d in falling], np.int32),
        )

    @staticmethod
    def _outlet(event: dict, state, data, mesh) -> int:
        """The particle a new bleed follows: the blood leaves the damaged vessel where
        the tissue around it is open, so it pours onto the drawn surface nearest the
        damage that is not the vessel's own (a wound's floor, the tissue under the
        vessel), and follows the particle of the other organs nearest that point."""
        vessel = next(o for o in data.organs if o.name == event["vessel"])
        surface = mesh.positions.to_numpy()[: mesh.smooth_count]
        gap = np.linalg.norm(surface - np.asarray(event["position"]), axis=1)
        gap[vessel.surface_vertices[0] : vessel.surface_vertices[1]] = np.inf
        pour = surface[int(np.argmin(gap))]
        reach = np.linalg.norm(state.x.to_numpy() - pour, axis=1)
        reach[vessel.particles[0] : vessel.particles[1]] = np.inf
        return int(np.argmin(reach))

    def _fields(self, mesh):
        """The per-vertex scratch of ``mesh`` (made again for a new mesh)."""
        if self._scratch is None or self._scratch[0] is not mesh:
            if self._scratch is not None:
                self._scratch[3].close()
            group = FieldGroup()
            share = group.field(ti.f32, mesh.vertex_count)
            drained = group.field(ti.f32, mesh.vertex_count)
            group.finalize()
            self._scratch = (mesh, share, drained, group)
        return self._scratch[1], self._scratch[2]
