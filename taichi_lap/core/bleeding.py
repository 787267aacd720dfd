"""How a damaged vessel bleeds, shared by the drawn blood film
(:class:`~taichi_lap.render.blood.BloodFilm`) and the training metrics (blood lost):
each ``vessel_damage`` event starts a bleed of :data:`BLEED_RATE` that slows as the
blood clots, rate(t) = BLEED_RATE exp(-t / CLOTTING_TIME), so one damaged place
loses at most BLEED_RATE × CLOTTING_TIME. The rates are chosen for a small vessel
opened by the hook (a few millilitres a place), not measured."""

from __future__ import annotations

import math

BLEED_RATE = 0.5e-6
"""[m³/s] a fresh bleed's flow (0.5 ml/s)."""
CLOTTING_TIME = 15.0
"""[s] the bleed slows by a factor e every CLOTTING_TIME."""


def bleed_rate(age: float) -> float:
    """[m³/s] the flow of a bleed ``age`` [s] after its vessel was damaged (0 before)."""
    return BLEED_RATE * math.exp(-age / CLOTTING_TIME) if age >= 0.0 else 0.0


def blood_lost(damage_times, end: float) -> float:
    """[m³] the blood lost by ``end`` [s] from bleeds started at ``damage_times`` [s]:
    Σ BLEED_RATE CLOTTING_TIME (1 - exp(-(end - t) / CLOTTING_TIME))."""
    return sum(
        BLEED_RATE * CLOTTING_TIME * (1.0 - math.exp(-(end - t) / CLOTTING_TIME))
        for t in damage_times
        if end > t
    )
