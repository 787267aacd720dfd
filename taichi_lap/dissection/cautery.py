"""Electrocautery in a running scene (seed 002 §3.3): the energised hooks heat the tet
organs (:class:`~taichi_lap.dissection.heat.HeatField`), particles that reach their
ablation temperature are removed, and a vessel heated past its damage temperature is
reported once per place.

Each organ's material gives its thermal conductivity, specific heat, perfusion (the
cooling towards body temperature), ablation temperature and, for a vessel, damage
temperature (:data:`taichi_lap.scene.schema.MATERIAL_PARAMS`); each hook's ``power``
[W] is shared by the particles touching its L-shaped electrode: those whose cell (half
the lattice spacing around them) reaches within HOOK_HEAT_GAP shaft radii of the
wire's surface. Every tet organ is ablated at its own ablation temperature: a vessel
(a damage temperature set) is damaged first and parts only at its higher ablation
temperature where the scene sets one (the liver scene's vessels: 120 °C), its cut
ends capped (:mod:`taichi_lap.dissection.removal`).

The heat equation runs every frame while a hook is energised and afterwards as long as
any particle is warmer than WARM_MARGIN above body temperature (it cools by perfusion),
so peaks and damage keep following the heat that spreads.
"""

from __future__ import annotations

import math

import numpy as np

from taichi_lap.core.instruments import HOOK_HEAT_GAP, HOOK_WIRE, MAX_TOOLS, hook_electrode
from taichi_lap.dissection.heat import HeatField, HeatSource
from taichi_lap.dissection.removal import cuttable_organs

BODY_TEMPERATURE = 37.0
"""Core body temperature [°C]: the tissue's start and what perfusion cools it to."""
WARM_MARGIN = 0.5
"""The heat equation stops once no particle is warmer than this above body
temperature [K] and no hook is energised (nothing it reports can change then)."""
DAMAGE_PLACE = 0.005
"""Size of the cells [m] (of the rest shape) that make a vessel's places: a vessel
damaged in one cell is reported once (event ``vessel_damage``)."""


class Cautery:
    """The heat of a session's hooks (module docstring) over the model ``data`` of
    ``scene``: :meth:`step` heats and lists what to remove and report."""

    def __init__(self, scene, data):
        specs = {organ.name: organ for organ in scene.organs}
        n = data.particle_count
        cuttable = cuttable_organs(data)
        per_particle = {  # organs without tets take no heat: their values stay unused
            "specific_heat": np.ones(n),
            "perfusion_rate": np.zeros(n),
            "ablation": np.full(n, math.inf),
            "damage": np.full(n, math.inf),
        }
        tet_conductivity = np.zeros(len(data.tets))
        for k, organ in enumerate(data.organs):
            if organ.tets[1] == organ.tets[0]:
                continue
            material = specs[organ.name].material
            rows = slice(*organ.particles)
            per_particle["specific_heat"][rows] = material["specific_heat"]
            per_particle["perfusion_rate"][rows] = material["perfusion_rate"]
            if cuttable[k]:
                per_particle["ablation"][rows] = material["ablation_temperature"]
            if material["damage_temperature"] is not None:
                per_particle["damage"][rows] = material["damage_temperature"]
            tet_conductivity[slice(*organ.tets)] = material["thermal_conductivity"]
        self.heat = HeatField(
            data.rest_position,
            data.tets,
            data.mass,
            conductivity=tet_conductivity,
            specific_heat=per_particle["specific_heat"],
            body_temperature=BODY_TEMPERATURE,
            cooling_rate=per_particle["perfusion_rate"],
            ablation_temperature=per_particle["ablation"],
            damage_temperature=per_particle["damage"],
            particle_radius=data.radius,
        )
        self.hooks = [
            (index, tool)
            for index, tool in enumerate(scene.tools[:MAX_TOOLS])
            if tool["kind"] == "hook"
        ]
        self.organ_names = [organ.name for organ in data.organs]
        self.organ_of = np.asarray(data.organ)
        self.rest = np.asarray(data.rest_position)
        self.warm = False
        self._reported: set[tuple[int, ...]] = set()

    def reset(self):
        """Back to body temperature everywhere, every particle of a tet alive, no
        damage reported."""
        self.heat.reset()
        self.warm = False
        self._reported.clear()

    def sources(self, control, energised: set[str]) -> list[HeatSource]:
        """The heat sources of the ``energised`` hooks (names) placed by ``control``:
        each electrode segment (stem, foot) with its share of the hook's power by
        length."""
        sources = []
        for index, tool in self.hooks:
            if tool["name"] not in energised:
                continue
            tip, frame = control.tips[index], control.frames[index]
            reach = (HOOK_WIRE + HOOK_HEAT_GAP) * tool["radius"]
            segments = [
                (tip + frame @ a, tip + frame @ b) for a, b in hook_electrode(tool["radius"])
            ]
            lengths = np.array([np.linalg.norm(b - a) for a, b in segments])
            for (a, b), share in zip(segments, lengths / lengths.sum()):
                sources.append(HeatSource(tuple(a), tuple(b), reach, tool["power"] * share))
        return sources

    def step(self, dt: float, state, control, energised: set[str]) -> tuple[np.ndarray, list]:
        """Advance the heat ``dt`` [s] with the ``energised`` hooks (names) as sources,
        the tissue where ``state`` has it; returns the particles that reached their
        ablation temperature (to remove) and the new ``vessel_damage`` events
        (``vessel``, ``position`` [m] now, ``peak_temperature`` [°C])."""
        sources = self.sources(control, energised)
        if not sources and not self.warm:
            return np.zeros(0, dtype=np.int64), []
        self.heat.step(dt, sources, positions=state.x)
        self.warm = bool(sources) or self.heat.hottest[None] > BODY_TEMPERATURE + WARM_MARGIN
        damaged = self.heat.newly_damaged()
        events = self._damage_events(damaged, state) if len(damaged) else []
        return self.heat.ablated(), events

    def remove(self, particles: np.ndarray):
        """Particles removed from the tissue stop taking and passing heat."""
        self.heat.remove(particles)

    def _damage_events(self, particles: np.ndarray, state) -> list[dict]:
        """One ``vessel_damage`` event per vessel and DAMAGE_PLACE cell of the newly
        damaged ``particles`` not reported before: where its particles are now, and
        their highest peak temperature."""
        cells = np.floor(self.rest[particles] / DAMAGE_PLACE).astype(np.int64)
        keys = np.column_stack([self.organ_of[particles], cells])
        places, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        fresh = [
            k for k, key in enumerate(map(tuple, places.tolist())) if key not in self._reported
        ]
        if not fresh:
            return []
        x = state.x.to_numpy()
        peaks = self.heat.peaks()
        events = []
        for k in fresh:
            self._reported.add(tuple(places[k].tolist()))
            members = particles[inverse == k]
            events.append(
                {
                    "kind": "vessel_damage",
                    "vessel": self.organ_names[int(places[k, 0])],
                    "position": x[members].mean(axis=0).tolist(),
                    "peak_temperature": float(peaks[members].max()),
                }
            )
        return events
