"""The blood film drawn on the tissue (kernels in ``taichi_lap.kernels.blood``): each
vessel damage starts a bleed where the tissue around the damaged vessel is open
(:meth:`BloodFilm._outlet`), which follows the tissue as it moves; every stepped
frame each bleed pours its flow (:func:`~taichi_lap.core.bleeding.bleed_rate`) onto
the surface around it and the film drains one step downhill. The film is the drawn mesh's ``blood`` (thickness [m] per
surface vertex), which the G-buffer interpolates and the shading draws as wet, dark
red blood."""

from __future__ import annotations

import math

import numpy as np
import taichi as ti

from taichi_lap.core.bleeding import bleed_rate
from taichi_lap.core.fields import FieldGroup
from taichi_lap.kernels.blood import bleed, drain, film_shares

BLEED_RADIUS = 0.004
"""[m] the patch of surface a bleed pours onto, around its source."""
BLOOD_SPEED = 0.02
"""[m/s] how fast blood runs down a vertical surface (slope × this on an incline;
chosen by eye: a trickle, not a jet)."""
FILM_RESIDUE = 5e-5
"""[m] the film blood leaves behind as it runs on (a stain along its trail)."""


class BloodFilm:
    """The bleeds of a session and the film they make on a drawn mesh's surface;
    blood runs along ``gravity`` (a 3-vector, any length; straight down -y when zero)."""

    def __init__(self, gravity=(0.0, -9.81, 0.0)):
        g = np.asarray(gravity, np.float64)
        down = g / np.linalg.norm(g) if np.linalg.norm(g) > 0.0 else np.array([0.0, -1.0, 0.0])
        self.down = tuple(float(c) for c in down)
        self.bleeds: list[tuple[int, float]] = []  # (particle followed, time it began [s])
        self._scratch = None  # (mesh, share, drained, group) for the mesh last drained

    def update(self, events: list[dict], state, data, time: float, dt: float, mesh):
        """After a stepped frame ending at ``time`` [s]: a bleed for each new
        ``vessel_damage`` event (at its outlet, :meth:`_outlet`; ``data`` the model's
        :class:`~taichi_lap.core.topology.ModelData`), then each bleed's flow over
        ``dt`` [s] poured onto ``mesh``'s surface and one drainage step."""
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
