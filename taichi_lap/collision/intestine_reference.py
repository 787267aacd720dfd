"""Reference for the intestine self-collision (seed 001 §7, Fig. 14): the exact O(n²)
detector over every non-neighbouring element pair, and the grouping of element pairs
into colliding regions. Like :mod:`taichi_lap.sim.reference` it is a reference, not
part of a running scene: the tests and ``perf/bench_intestine_cd.py`` measure the
stochastic detector (:mod:`.intestine`) against it, as the paper does."""

from __future__ import annotations

import numpy as np
import taichi as ti

from taichi_lap.collision.intestine import IntestineCollision
from taichi_lap.core.fields import FieldGroup, FieldOwner
from taichi_lap.kernels.collision import intestine as kernels


def region_labels(pairs: np.ndarray, neighbour: np.ndarray) -> np.ndarray:
    """Connected groups of element pairs (n, 2): two pairs are connected when each
    element of one is the same as or adjacent to (``neighbour`` (E, >= 3), the
    first three columns) the corresponding element of the other. Returns a label
    per pair (NumPy/SciPy, for tests and benchmarks)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return np.zeros(0, dtype=np.int64)
    size = len(neighbour) + 1
    key = pairs[:, 0] * size + pairs[:, 1]
    order = np.argsort(key)
    around_a = np.concatenate([pairs[:, :1], neighbour[pairs[:, 0], :3]], axis=1)
    around_b = np.concatenate([pairs[:, 1:], neighbour[pairs[:, 1], :3]], axis=1)
    a2 = np.repeat(around_a, 4, axis=1)
    b2 = np.tile(around_b, (1, 4))
    wanted = np.minimum(a2, b2) * size + np.maximum(a2, b2)
    slot = np.minimum(np.searchsorted(key[order], wanted), len(key) - 1)
    hit = (a2 >= 0) & (b2 >= 0) & (key[order][slot] == wanted)
    rows = np.nonzero(hit)[0]
    graph = coo_matrix((np.ones(len(rows)), (rows, order[slot[hit]])), shape=(len(pairs),) * 2)
    return connected_components(graph, directed=False)[1]


@ti.data_oriented
class ExactDetector(FieldOwner):
    """Every non-neighbouring (segment, element) pair with gap < ``skin`` [m] (0:
    the colliding pairs), O(n²): ground truth for the stochastic detector."""

    def __init__(self, collision: IntestineCollision, capacity: int = 1 << 18, skin: float = 0.0):
        self.collision = collision
        self.capacity, self.skin = int(capacity), float(skin)
        group = FieldGroup()
        self.centre = group.field(ti.f32, collision.element_count, vector=3)
        self.bound = group.field(ti.f32, collision.element_count)
        self.pair_a = group.field(ti.i32, self.capacity)
        self.pair_b = group.field(ti.i32, self.capacity)
        self.pair_gap = group.field(ti.f32, self.capacity)
        self.count = group.field(ti.i32, None)
        group.finalize()
        self._group = group

    def run(self, positions):
        """Launch the O(n²) test at ``positions`` (a particle field) [m]."""
        kernels.exact_collisions(self.collision, self, positions)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (n, 2) of the last :meth:`run` in (a, b) order, and their gaps [m]."""
        n = int(self.count[None])
        if n > self.capacity:
            raise RuntimeError(f"{n} pairs in contact exceed the capacity {self.capacity}")
        pairs = np.stack([self.pair_a.to_numpy()[:n], self.pair_b.to_numpy()[:n]], axis=1)
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        return pairs[order], self.pair_gap.to_numpy()[:n][order]

    def detect(self, positions) -> np.ndarray:
        """Colliding pairs (n, 2) at ``positions``, in (a, b) order."""
        self.run(positions)
        pairs, gaps = self.pairs()
        return pairs[gaps < 0.0]
