"""Material presets for the deferred pass (seed 000 §6.1): base colour (linear
RGB albedo), roughness (α = roughness²), metalness, and the weight of the wet
mucus layer drawn as a second, smoother specular lobe.

Values are chosen to match laparoscopic footage under the endoscope's light: moist
tissue with a strong, tight highlight over a rough, saturated base. Tissue that
electrocautery heated is drawn blended towards the charred look of the wound
(:data:`CHAR_ALBEDO`, :data:`CHAR_ROUGHNESS`, no mucus) by its char in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Material:
    """A surface material: ``albedo`` linear RGB in [0, 1], ``roughness`` and
    ``metalness`` and ``mucus`` (wet-layer weight) in [0, 1]; its procedural surface
    detail (:mod:`taichi_lap.kernels.surface_detail`, in rest-space coordinates):
    ``mottling`` (relative albedo variation), ``vessels`` (how dark its capillary
    lines are), ``bump`` (slope of its relief) and ``scale`` [m] (the size of its
    features: lobules, folds); ``subsurface``: how strongly the vessels running
    under its surface tint it (:mod:`taichi_lap.kernels.subsurface`)."""

    albedo: tuple[float, float, float]
    roughness: float
    metalness: float
    mucus: float
    mottling: float = 0.0
    vessels: float = 0.0
    bump: float = 0.0
    scale: float = 0.003
    subsurface: float = 0.0


PRESETS: dict[str, Material] = {
    "liver": Material((0.36, 0.075, 0.055), 0.45, 0.0, 0.65, 0.25, 0.1, 0.06, 0.004, 0.8),
    "mucosa": Material((0.62, 0.24, 0.21), 0.5, 0.0, 0.8, 0.12, 0.3, 0.08, 0.005),
    "serosa": Material((0.78, 0.46, 0.40), 0.45, 0.0, 0.7, 0.1, 0.4, 0.05, 0.008),
    "fascia": Material((0.80, 0.68, 0.60), 0.55, 0.0, 0.45, 0.06, 0.2, 0.03, 0.01),
    "fat": Material((0.86, 0.68, 0.34), 0.4, 0.0, 0.5, 0.2, 0.25, 0.12, 0.008),
    "peritoneum": Material((0.70, 0.38, 0.33), 0.45, 0.0, 0.75, 0.12, 0.45, 0.06, 0.015),
    "artery": Material((0.62, 0.09, 0.075), 0.35, 0.0, 0.6, 0.06, 0.0, 0.03, 0.005),
    "vein": Material((0.22, 0.09, 0.20), 0.35, 0.0, 0.6, 0.06, 0.0, 0.03, 0.005),
    "bile_duct": Material((0.46, 0.50, 0.18), 0.4, 0.0, 0.55, 0.06, 0.0, 0.03, 0.005),
    "polyp": Material((0.72, 0.26, 0.27), 0.45, 0.0, 0.75, 0.15, 0.25, 0.1, 0.003),
    "gland": Material((0.74, 0.45, 0.36), 0.5, 0.0, 0.5, 0.15, 0.2, 0.08, 0.005),
    "metal": Material((0.76, 0.76, 0.78), 0.28, 1.0, 0.0),
}
"""Presets by name; scene organs choose one with ``appearance``. The surface detail
is chosen by eye after laparoscopic footage: the liver's capsule mottled by its
lobules, serosa and peritoneum threaded with capillaries, fat in lobules
with a bumpy surface, the vessels' walls nearly smooth (not measured); the liver's
parenchyma lets the vessels under it show through."""

VESSEL_APPEARANCES = ("artery", "vein", "bile_duct")
"""The presets of the organs that tint tissue with ``subsurface`` above them."""

SUBSURFACE_DEPTH = 0.0015
"""[m] the depth over which a vessel under the surface fades from view by a factor
e: tissue at distance d from a vessel takes exp(-d / SUBSURFACE_DEPTH) of its
colour (weighted by the material's ``subsurface``). Liver parenchyma scatters red
light over about a millimetre; chosen by eye so that a vessel shows through the
last 2-3 mm above it (not measured)."""

INSTRUMENT = "metal"

DETAIL = ("mottling", "vessels", "bump", "scale")
"""The surface-detail parameters of a :class:`Material`."""

SCALARS = ("roughness", "metalness", "mucus", "subsurface") + DETAIL
"""The per-material scalars of the material table."""

CHAR_ALBEDO = (0.05, 0.03, 0.02)
"""Linear RGB albedo of fully charred tissue: the dark brown-black of an
electrocautery wound, chosen by eye to look like cauterised liver in endoscopic
video (not measured)."""

CHAR_ROUGHNESS = 0.7
"""Roughness of fully charred tissue: dry and rough, with the mucus film gone; chosen
by eye like :data:`CHAR_ALBEDO`."""

BLOOD_ALBEDO = (0.28, 0.012, 0.01)
"""Linear RGB albedo of a blood film thick enough to hide the tissue: the dark red of
fresh blood on tissue in endoscopic video (chosen by eye, not measured)."""
BLOOD_ROUGHNESS = 0.15
"""Roughness of blood: a wet, glossy liquid, under a full mucus-like film."""
BLOOD_FILM = 1e-4
"""[m] the film thickness over which blood hides the tissue by a factor e: coverage
1 - exp(-thickness / BLOOD_FILM)."""


def material_table(materials: list[Material]) -> dict[str, np.ndarray]:
    """Per-material arrays for upload: ``albedo`` (M, 3) and the :data:`SCALARS`
    (M,), all float32."""
    table = {"albedo": np.array([m.albedo for m in materials], np.float32).reshape(-1, 3)}
    for name in SCALARS:
        table[name] = np.array([getattr(m, name) for m in materials], np.float32)
    return table
