"""A NumPy reference of the cluster shape-matching step (seed 000 Alg. 1), used to
check the Taichi kernels and as the baseline of ``perf/bench_deform.py``.

It follows :mod:`taichi_lap.kernels.shape_matching` operation for operation
(predict with goal pull, gravity and damping; tool and plane contacts;
``shape_iterations`` passes of cluster matching; limited goals and η; velocity
and position update) in float64, vectorised over clusters and particles. Polar
decomposition by SVD with the sign fixed so det R = +1.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.preprocess.model_data import ModelData


class ReferenceShapeMatching:
    """State ``x, v, goal, eta`` as NumPy arrays; ``step`` advances one frame.

    ``planes`` are ``(point, normal, friction)``; ``tools`` capsules
    ``(tip, tail, radius)``. Springs, distance constraints and LRAs are not part of
    the reference (they have their own tests)."""

    def __init__(
        self, data: ModelData, *, substeps: int, shape_iterations: int, gravity, planes=(), tools=()
    ):
        self.substeps, self.iterations = substeps, shape_iterations
        self.gravity = np.asarray(gravity, dtype=np.float64)
        self.planes = [
            (np.asarray(p, float), np.asarray(n, float) / np.linalg.norm(n), float(f))
            for p, n, f in planes
        ]
        self.tools = [(np.asarray(a, float), np.asarray(b, float), float(r)) for a, b, r in tools]
        self.free = ~data.pinned
        self.radius = data.radius.astype(np.float64)
        self.contact_radius = data.contact_radius()
        mat = data.material
        self.alpha, self.recover = mat["stiffness"], mat["recover_rate"]
        self.eta_contact, self.damping = mat["eta_on_contact"], mat["damping"]
        start, member = data.cluster_start, data.cluster_member
        self.start, self.member = start[:-1], member
        self.owner = np.repeat(np.arange(len(start) - 1), np.diff(start))
        self.member_weight = data.fit_mass()[member]  # its weight in the fits
        m = self.member_weight
        self.cluster_mass = np.add.reduceat(m, self.start)
        rest = data.rest_position.astype(np.float64)
        self.rest_center = (
            np.add.reduceat(m[:, None] * rest[member], self.start) / self.cluster_mass[:, None]
        )
        self.offset = rest[member] - self.rest_center[self.owner]
        self.count = np.bincount(member, minlength=len(rest))
        self.x, self.v = rest.copy(), np.zeros_like(rest)
        self.goal, self.eta = rest.copy(), np.zeros(len(rest))
        self.collided = np.zeros(len(rest), dtype=bool)

    def _contacts(self, p: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = p.copy()
        hit = np.zeros(len(p), dtype=bool)
        for a, b, r in self.tools:
            ab = b - a
            t = np.clip((p - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
            closest = a + t[:, None] * ab
            d = p - closest
            dist = np.linalg.norm(d, axis=1)
            reach = r + self.contact_radius
            inside = dist < reach
            normal = np.where(
                dist[:, None] > 1e-9,
                d / np.maximum(dist, 1e-30)[:, None],
                np.array([0.0, 1.0, 0.0]),
            )
            p[inside] = closest[inside] + normal[inside] * reach[inside, None]
            hit |= inside
        for point, n, friction in self.planes:
            depth = self.radius - (p - point) @ n
            below = depth > 0
            p[below] += depth[below, None] * n
            move = p - x
            tangential = move - (move @ n)[:, None] * n
            length = np.linalg.norm(tangential, axis=1)
            limit = friction * depth
            scale = np.where(length <= limit, 1.0, limit / np.maximum(length, 1e-30))
            p[below] -= tangential[below] * scale[below, None]
        return p, hit

    def _match(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cluster mass centres and rotations (Alg. 1 lines 7-11)."""
        m = self.member_weight
        d = p[self.member] - self.rest_center[self.owner]
        center = (
            self.rest_center
            + np.add.reduceat(m[:, None] * d, self.start) / self.cluster_mass[:, None]
        )
        moment = np.add.reduceat(
            m[:, None, None] * d[:, :, None] * self.offset[:, None, :], self.start
        )
        u, _, vt = np.linalg.svd(moment)
        sign = np.sign(np.linalg.det(u @ vt))
        u[:, :, 2] *= sign[:, None]
        return center, u @ vt

    def _limited_goal(self, p, center, rotation) -> tuple[np.ndarray, np.ndarray]:
        """Alg. 1 lines 13-23: averaged cluster goals blended with η."""
        per_member = np.einsum("kij,kj->ki", rotation[self.owner], self.offset) + center[self.owner]
        total = np.zeros_like(p)
        np.add.at(total, self.member, per_member)
        has = self.count > 0
        goal = p.copy()
        goal[has] = total[has] / self.count[has, None]
        eta = np.where(self.collided, self.eta_contact, np.maximum(self.eta - self.recover, 0.0))
        return goal + eta[:, None] * (p - goal), eta

    def substep(self, h: float):
        x = self.x
        v = self.v + self.alpha[:, None] * (self.goal - x) / h + h * self.gravity
        v *= np.maximum(1.0 - self.damping * h, 0.0)[:, None]
        p, hit = self._contacts(x + h * v, x)
        p[~self.free] = x[~self.free]
        self.collided = hit & self.free
        movable = self.free & (self.count > 0)
        for _ in range(self.iterations - 1):
            center, rotation = self._match(p)
            goal, _ = self._limited_goal(p, center, rotation)
            moved, hit = self._contacts(p + self.alpha[:, None] * (goal - p), x)
            p[movable] = moved[movable]
            self.collided |= hit & movable
        center, rotation = self._match(p)
        self.goal, self.eta = self._limited_goal(p, center, rotation)
        self.v = (p - x) / h
        self.x = p

    def step(self, dt: float):
        for _ in range(self.substeps):
            self.substep(dt / self.substeps)
