"""Small intestine and mesentery rest geometry (seed 001 §3.1-3.2, Fig. 5-6).

The main vessel (mesentery root) is the axis of a cylinder of ``cylinder_radius``
(15 cm): here the z axis, centred at the origin, the vessel segment being
``|z| <= vessel_length / 2`` (10 cm); y is up. The intestine is a folded sine
curve on the cylinder: going around the axis by ``theta`` it oscillates along z,
``z = A sin(folds * 2 pi s)``, ``theta = Theta s`` for ``s`` in [0, 1], with
``Theta = 2 pi folds / (folds + 1)`` so a gap of one fold's width, centred at the
top, keeps the two ends apart. The mesentery is the surface of the segments
linking the axis to the curve. The mechanical model is ``rows`` sets of
``points_per_row`` masses (seed 001: 4 x 100): row 0 on the curve at equal arc
length, row ``rows - 1`` on the axis (the root, fixed by the scene), the others
evenly on the linking segments.

The amplitude ``A`` is solved numerically so that the sampled intestine (row 0,
the polyline the springs and the skinned tube follow) is ``length`` (4 m) long;
the folds are so sharp that the underlying sine is ~8 % longer.
Default ``folds = 10``: adjacent passes are 4.3 cm apart at mid-height and any two
row-0 points more than 25 cm apart along the intestine stay >= 4.8 cm apart
(> 2 x intestine_radius), so no two passes of the 2 cm tube intersect.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from taichi_lap.core.geometry import SpringSheet, arc_length
from taichi_lap.core.params import Param

from .generator import Generator


def fold_curve(amplitude: float, folds: int, radius: float, n: int) -> np.ndarray:
    """``n`` points of the folded sine on the cylinder (axis z, gap centred at +y)."""
    s = np.linspace(0.0, 1.0, n)
    span = 2.0 * np.pi * folds / (folds + 1.0)
    theta = 0.5 * np.pi + 0.5 * (2.0 * np.pi - span) + span * s
    return np.stack(
        [
            radius * np.cos(theta),
            radius * np.sin(theta),
            amplitude * np.sin(2.0 * np.pi * folds * s),
        ],
        axis=1,
    )


def _sample(amplitude, folds, radius, count):
    """``count`` points at equal arc length along the (densely sampled) curve."""
    dense = fold_curve(amplitude, folds, radius, max(4000, 400 * folds))
    s = arc_length(dense)
    t = np.linspace(0.0, s[-1], count)
    return np.stack([np.interp(t, s, dense[:, k]) for k in range(3)], axis=1)


def _polyline_length(p):
    return float(arc_length(p)[-1])


def solve_amplitude(length: float, folds: int, radius: float, count: int) -> float:
    """Fold amplitude [m] giving a row-0 polyline of ``length`` [m]."""

    def excess(a):
        return _polyline_length(_sample(a, folds, radius, count)) - length

    lo = 1e-6
    if excess(lo) >= 0.0:
        raise ValueError("intestine length too short for the cylinder: nothing to fold")
    hi = length / (4.0 * folds)
    while excess(hi) < 0.0:
        hi *= 2.0
        if hi > 100.0 * length:
            raise ValueError("cannot reach the intestine length with these points")
    return brentq(excess, lo, hi, xtol=1e-12, rtol=1e-12)


def _build(params: dict) -> SpringSheet:
    R = float(params["cylinder_radius"])
    folds, rows, count = int(params["folds"]), int(params["rows"]), int(params["points_per_row"])
    amp = solve_amplitude(float(params["length"]), folds, R, count)
    gut = _sample(amp, folds, R, count)
    # root: the same points projected on the axis, z squeezed into the vessel segment
    half = 0.5 * float(params["vessel_length"])
    root = np.zeros_like(gut)
    root[:, 2] = gut[:, 2] * min(1.0, half / amp)
    w = (np.arange(rows) / (rows - 1))[:, None, None]
    sheet = (1.0 - w) * gut[None] + w * root[None]
    radius = np.full(rows, 0.5 * float(params["mesentery_thickness"]))
    radius[0] = float(params["intestine_radius"])
    return SpringSheet(rows=sheet, row_radius=radius)


GENERATORS = [
    Generator(
        "intestine",
        _build,
        {
            "length": Param("float", 4.0, "intestine length (row-0 polyline)", 0.5, 10.0, unit="m"),
            "cylinder_radius": Param(
                "float",
                0.15,
                "radius of the cylinder carrying the folds (mesentery width)",
                0.03,
                0.5,
                unit="m",
            ),
            "vessel_length": Param(
                "float",
                0.10,
                "length of the main vessel (mesentery root) on the z axis",
                0.01,
                0.5,
                unit="m",
            ),
            "folds": Param("int", 10, "sine periods around the cylinder", 1, 64),
            "intestine_radius": Param(
                "float", 0.02, "intestine tube radius (row 0)", 0.005, 0.05, unit="m"
            ),
            "mesentery_thickness": Param(
                "float", 0.01, "mesentery thickness", 0.001, 0.05, unit="m"
            ),
            "rows": Param("int", 4, "mass rows from intestine (0) to root", 2, 16),
            "points_per_row": Param("int", 100, "masses per row", 4, 2000),
        },
        "spring_sheet",
        "Intestine + mesentery mass-spring rest geometry (seed 001 §3).",
    ),
]
