"""Tool frames (3×3, columns x, y and the shaft from the tip towards the handle):
turning a frame onto a new shaft direction, about its shaft, and the roll a stylus
turned between two readings. NumPy only: the haptic servo process uses them too."""

from __future__ import annotations

import numpy as np


def frame_towards(frame: np.ndarray, direction) -> np.ndarray:
    """``frame`` (3×3, columns) turned by the smallest rotation that takes its third
    column onto the unit ``direction``, so a tool's roll does not jump as it turns;
    the result is made orthonormal again (a tool turned every frame would otherwise
    gather rounding errors that grow with each turn)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    z = frame[:, 2] / np.linalg.norm(frame[:, 2])
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(np.dot(z, d))
    if s < 1e-12:
        if c > 0.0:
            return orthonormal(frame)
        return orthonormal(frame @ np.diag([1.0, -1.0, -1.0]))  # half turn about x
    k = axis / s
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation = np.eye(3) + s * cross + (1.0 - c) * cross @ cross
    return orthonormal(rotation @ frame)


def turned_about_axis(frame: np.ndarray, angle: float) -> np.ndarray:
    """``frame`` (3×3, columns) turned by ``angle`` [rad] about its third column
    (right-handed: a positive angle takes its first column towards its second)."""
    c, s = np.cos(angle), np.sin(angle)
    return frame @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def twist(before: np.ndarray, after: np.ndarray) -> float:
    """The turn [rad] about its third column that takes ``before`` (3×3, columns) to
    ``after`` once ``before`` has been turned onto ``after``'s third column by
    :func:`frame_towards` (a stylus's roll between two of its readings):
    ``turned_about_axis(frame_towards(before, z), twist) == after``. That turn is
    the twist of the swing-twist split of Q = beforeᵀ after about z, whose quaternion
    (w, 0, 0, z) gives 2 atan2(z, w) = 2 atan2(Q10 - Q01, 1 + tr Q) (both scaled by
    4w² ≥ 0); in (-π, π], undefined for a half turn between the readings."""
    q = np.asarray(before, dtype=np.float64).T @ np.asarray(after, dtype=np.float64)
    return float(2.0 * np.arctan2(q[1, 0] - q[0, 1], 1.0 + np.trace(q)))


def orthonormal(frame: np.ndarray) -> np.ndarray:
    """The right-handed orthonormal frame nearest ``frame``'s third column and, in the
    plane across it, its first (Gram-Schmidt from the third column)."""
    z = frame[:, 2] / np.linalg.norm(frame[:, 2])
    x = frame[:, 0] - np.dot(frame[:, 0], z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])
