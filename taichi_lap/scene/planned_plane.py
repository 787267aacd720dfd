"""The planned transection of a task (``[task.plane]``, seed 002): a plane and the
planned line in it, as the renderer draws it on the organ and the training goal
measures the wound against it (``docs/training.md``)."""

from __future__ import annotations

import numpy as np

MARK_COLOUR = (0.1, 0.8, 0.45)
"""The planned line's green, as a surgical marker's (in the view and the report)."""


class PlannedPlane:
    """A planned transection: the plane through ``point`` with ``normal``, and the
    line from ``start`` to ``end`` projected into it."""

    SAMPLE = 1e-4  # [m] the line's coverage is counted at points this far apart

    def __init__(self, plane: dict):
        self.normal = np.asarray(plane["normal"], dtype=np.float64)
        self.normal /= np.linalg.norm(self.normal)
        self.point = np.asarray(plane["point"], dtype=np.float64)
        start, end = (
            self.project(np.asarray(plane[k], dtype=np.float64)) for k in ("start", "end")
        )
        self.start = start
        self.length = float(np.linalg.norm(end - start))
        self.along = (end - start) / self.length
        self.tolerance = float(plane["tolerance"])
        self.samples = np.linspace(0.0, self.length, max(2, int(self.length / self.SAMPLE) + 1))

    def project(self, points: np.ndarray) -> np.ndarray:
        """``points`` (..., 3) [m] moved along the normal into the plane."""
        return points - np.multiply.outer((points - self.point) @ self.normal, self.normal)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance [m] of ``points`` (n, 3) from the plane."""
        return np.abs((points - self.point) @ self.normal)

    def reached(self, points: np.ndarray) -> np.ndarray:
        """Which of the line's sample points (a bool per point of :attr:`samples`)
        wound ``points`` (n, 3) within the tolerance of the plane reach: those within
        the tolerance of a wound point's projection onto the line."""
        near = points[self.distance(points) <= self.tolerance]
        s = np.sort((near - self.start) @ self.along)
        if not len(s):
            return np.zeros(len(self.samples), dtype=bool)
        k = np.searchsorted(s, self.samples)
        before, after = s[np.maximum(k - 1, 0)], s[np.minimum(k, len(s) - 1)]
        gap = np.minimum(np.abs(self.samples - before), np.abs(self.samples - after))
        return gap <= self.tolerance
