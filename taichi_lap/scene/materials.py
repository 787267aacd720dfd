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
    ``metalness`` and ``mucus`` (wet-layer weight) in [0, 1]."""

    albedo: tuple[float, float, float]
    roughness: float
    metalness: float
    mucus: float


PRESETS: dict[str, Material] = {
    "liver": Material((0.36, 0.075, 0.055), 0.45, 0.0, 0.65),
    "mucosa": Material((0.62, 0.24, 0.21), 0.5, 0.0, 0.8),
    "serosa": Material((0.78, 0.46, 0.40), 0.45, 0.0, 0.7),
    "fascia": Material((0.80, 0.68, 0.60), 0.55, 0.0, 0.45),
    "fat": Material((0.86, 0.68, 0.34), 0.4, 0.0, 0.5),
    "peritoneum": Material((0.70, 0.38, 0.33), 0.45, 0.0, 0.75),
    "artery": Material((0.62, 0.09, 0.075), 0.35, 0.0, 0.6),
    "vein": Material((0.22, 0.09, 0.20), 0.35, 0.0, 0.6),
    "bile_duct": Material((0.46, 0.50, 0.18), 0.4, 0.0, 0.55),
    "polyp": Material((0.72, 0.26, 0.27), 0.45, 0.0, 0.75),
    "gland": Material((0.74, 0.45, 0.36), 0.5, 0.0, 0.5),
    "metal": Material((0.76, 0.76, 0.78), 0.28, 1.0, 0.0),
}
"""Presets by name; scene organs choose one with ``appearance``."""

INSTRUMENT = "metal"

CHAR_ALBEDO = (0.05, 0.03, 0.02)
"""Linear RGB albedo of fully charred tissue: the dark brown-black of an
electrocautery wound, chosen by eye to look like cauterised liver in endoscopic
video (not measured)."""

CHAR_ROUGHNESS = 0.7
"""Roughness of fully charred tissue: dry and rough, with the mucus film gone; chosen
by eye like :data:`CHAR_ALBEDO`."""


def material_table(materials: list[Material]) -> dict[str, np.ndarray]:
    """Per-material arrays for upload: ``albedo`` (M, 3), ``roughness``,
    ``metalness``, ``mucus`` (M,), all float32."""
    return {
        "albedo": np.array([m.albedo for m in materials], np.float32).reshape(-1, 3),
        "roughness": np.array([m.roughness for m in materials], np.float32),
        "metalness": np.array([m.metalness for m in materials], np.float32),
        "mucus": np.array([m.mucus for m in materials], np.float32),
    }
