"""Per-particle adjacency in compressed-row form, so kernels gather instead of
scattering with float atomics (bit-identical runs on one backend and thread count)."""

from __future__ import annotations

import numpy as np


def incidence(owner: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Group the rows ``0..len(owner)-1`` by ``owner`` (values in ``[0, count)``).

    Returns ``(start, rows)``: the rows owned by ``i`` are
    ``rows[start[i]:start[i + 1]]``, in increasing row order."""
    owner = np.asarray(owner, dtype=np.int64)
    order = np.argsort(owner, kind="stable")
    start = np.zeros(count + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=count), out=start[1:])
    return start, order


def both_ends(pairs: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For undirected pairs ``(E, 2)``: ``(start, edge, other)`` listing, for each
    particle, the edges touching it and the particle at their other end."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    edge = np.concatenate([np.arange(len(pairs)), np.arange(len(pairs))])
    start, rows = incidence(owner, count)
    return start, edge[rows], other[rows]


def rows_of(start: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The row indices ``start[i]:start[i + 1]`` of every ``i`` in ``ids``, in order
    (a vectorised gather of several compressed rows)."""
    ids = np.asarray(ids, dtype=np.int64)
    return rows_of_extents(start[ids], start[ids + 1] - start[ids])


def rows_of_extents(begin: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The rows ``begin[k]..begin[k] + counts[k]`` of every k, in order."""
    begin, counts = np.asarray(begin, dtype=np.int64), np.asarray(counts, dtype=np.int64)
    offsets = np.repeat(begin - np.cumsum(counts) + counts, counts)
    return offsets + np.arange(counts.sum(), dtype=np.int64)


def owners_of(start: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """For the rows :func:`rows_of` gives for ``ids``: the position in ``ids`` each
    belongs to."""
    ids = np.asarray(ids, dtype=np.int64)
    return np.repeat(np.arange(len(ids)), start[ids + 1] - start[ids])
