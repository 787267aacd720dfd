"""Constraint-based haptic rendering of a rigid tool on shape-matched tissue (seed 002 §3.4).

Three tools per servo tick t: the haptic tool q_h (the device), the graphical tool
q_g (the proxy that never penetrates) and the physical tool

    q_p(t) = ω q_g(t-1) + (1 - ω) q_h(t),   ω = 0.95,

which finds the contacts: the tool (its union of implicit shapes, the same the
simulation's contacts use: :mod:`taichi_lap.core.instruments`) is tested against the
surface cluster spheres, then against the particles of the clusters it hits.
The proxy then solves, over the three translational variables,

    min_q  ½ (q - q_h)ᵀ K (q - q_h)   s.t.  C_i(q) ≥ 0 for every contact i,

with C_i the non-penetration constraint of particle i linearised at q_g(t-1). The
distance of a particle from one of the tool's convex shapes, D_i(q), is a convex
function of the translation (distance to a segment or a box), so its first-order
expansion underestimates it and a solution of the linearised QP keeps every contact
at least the particle radius R_i off the tool's surface. The gradient is the paper's ∇(D²) = 2 D n_i; the offset is
written in distances, n_iᵀ(q - q_g(t-1)) ≥ R_i - D_i, which agrees with the
squared form near contact and does not overshoot deep penetrations. The contact
force is h_c = g (q_h - q_g) on the tissue; the device gets -h_c, plus the pull of
grasped tissue (:func:`pull_force`, Hooke's law over the grasped particles' tet edges).

While tissue pushes the simulation's tool, the snapshot carries that tool's tip s
(the two-way coupling of :mod:`taichi_lap.haptics.bridge`): the graphical tool is s
and the contact force h_c = g (q_h - s), a spring from the stylus to the tool the
tissue holds, so the device feels the tissue's push as the simulation finds it.

Particles that moved into the previous proxy can make these constraints
infeasible (tissue squeezed from both sides). The QP is then solved again with
offsets min(R_i - D_i, 0), which q_g(t-1) satisfies by construction: the proxy may
not move deeper into any particle but is not pushed out this tick. Should the
solver still fail, q_g(t-1) is held and the failure logged.

The QP is solved with DAQP (dual active set, MIT licence): a few microseconds for
3 variables and tens of constraints, with infeasibility reported by an exit flag
rather than an exception.
"""

from __future__ import annotations

import enum
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from taichi_lap.core.instruments import ToolGeometry, tool_distance
from taichi_lap.core.mesh import element_edges

log = logging.getLogger("taichi_lap.haptics")

OMEGA = 0.95
GRASP_STIFFNESS = 0.001
NO_BOUND = 1e30


class ProxyStatus(enum.IntEnum):
    """How the graphical tool of a tick was found."""

    FREE = 0  # no contact: q_g = q_h
    CONTACT = 1  # QP with the linearised non-penetration constraints
    RELAXED = 2  # those were infeasible: QP with offsets q_g(t-1) satisfies
    HELD = 3  # the solver failed: q_g(t-1) held
    COUPLED = 4  # tissue pushes the simulation's tool: q_g is that tool


def _positive(owner: str, name: str, value, allow_zero: bool = False) -> float:
    ok = (
        isinstance(value, (int, float))
        and math.isfinite(value)
        and (value >= 0 if allow_zero else value > 0)
    )
    if not ok:
        raise ValueError(
            f"{owner}.{name}: a {'non-negative' if allow_zero else 'positive'} "
            f"finite number was expected, found {value!r}"
        )
    return float(value)


@dataclass(frozen=True)
class ProxySettings:
    """``stiffness``: the diagonal of K [N/m]; ``gain``: g [N/m] of h_c = g (q_h - q_g);
    ``omega``: ω of q_p; ``contact_margin`` [m]: particles this much beyond contact
    with q_p are constrained too; ``max_contacts``: the deepest ones kept;
    ``grasp_stiffness``: k of the pull force [N/m] (seed 002 uses 0.001)."""

    tool: ToolGeometry
    stiffness: tuple[float, float, float] = (1.0, 1.0, 1.0)
    gain: float = 300.0
    omega: float = OMEGA
    contact_margin: float = 0.001
    max_contacts: int = 64
    grasp_stiffness: float = GRASP_STIFFNESS

    def __post_init__(self):
        stiffness = np.asarray(self.stiffness, dtype=np.float64)
        if stiffness.shape != (3,) or not np.all(np.isfinite(stiffness) & (stiffness > 0)):
            raise ValueError(
                f"ProxySettings.stiffness: three positive numbers [N/m] were "
                f"expected, found {self.stiffness!r}"
            )
        _positive("ProxySettings", "gain", self.gain)
        _positive("ProxySettings", "contact_margin", self.contact_margin, allow_zero=True)
        _positive("ProxySettings", "grasp_stiffness", self.grasp_stiffness, allow_zero=True)
        if not (isinstance(self.omega, (int, float)) and 0.0 <= self.omega < 1.0):
            raise ValueError(
                f"ProxySettings.omega: a number in [0, 1) was expected, found {self.omega!r}"
            )
        if not (isinstance(self.max_contacts, int) and self.max_contacts >= 1):
            raise ValueError(
                f"ProxySettings.max_contacts: a positive integer was expected, "
                f"found {self.max_contacts!r}"
            )


@dataclass(frozen=True)
class ProxyResult:
    """One tick: ``graphic_position`` q_g and ``physical_position`` q_p [m], the device
    forces ``contact_force`` = -h_c and ``pull_force`` [N], the constraint count, the
    status and the time [s] spent in the QP solver."""

    graphic_position: np.ndarray
    physical_position: np.ndarray
    contact_force: np.ndarray
    pull_force: np.ndarray
    contacts: int
    status: ProxyStatus
    qp_seconds: float


def ranges(start: np.ndarray, which: np.ndarray) -> np.ndarray:
    """The indices ``start[c]:start[c+1]`` of every ``c`` in ``which``, concatenated."""
    first = start[which]
    counts = start[which + 1] - first
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) + np.repeat(first - ends + counts, counts)


def pull_force(
    grasped: np.ndarray, neighbor: np.ndarray, rest: np.ndarray, stiffness: float = GRASP_STIFFNESS
) -> np.ndarray:
    """Grasp pull force [N] on the tool, seed 002 §3.4 (Hooke's law over tet edges):

        h_p = k Σ_e max(0, |e| - |e0|) ê,   e = p_neighbor - p_grasped,

    for grasped endpoints ``grasped`` (E, 3) [m], their tet neighbours ``neighbor``
    (E, 3) [m], rest lengths ``rest`` (E,) [m] and ``stiffness`` k [N/m]. Only
    stretched edges pull (the paper's max(0, ·)); it is zero at rest."""
    e = np.asarray(neighbor, np.float64) - np.asarray(grasped, np.float64)
    length = np.linalg.norm(e, axis=1)
    stretch = np.maximum(length - np.asarray(rest, np.float64), 0.0)
    scale = np.divide(stretch, length, out=np.zeros_like(length), where=length > 0.0)
    return stiffness * (scale[:, None] * e).sum(axis=0)


def grasp_edges(
    tets: np.ndarray, grasped: np.ndarray, pairs: np.ndarray | None = None
) -> np.ndarray:
    """Unique edges (E, 2) from a grasped particle (column 0) to a neighbour that is
    not grasped (column 1): the edges of ``tets`` (T, 4) and the ``pairs`` (P, 2) of
    organs without tets (struts, sheet edges); all are particle indices."""
    pairs = np.concatenate(
        [
            element_edges(np.asarray(tets, dtype=np.int64).reshape(-1, 4)),
            np.asarray(pairs if pairs is not None else np.zeros((0, 2)), dtype=np.int64).reshape(
                -1, 2
            ),
        ]
    )
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    mark = np.zeros(int(pairs.max(initial=-1)) + 1, dtype=bool)
    grasped = np.asarray(grasped, dtype=np.int64)
    mark[grasped[grasped < len(mark)]] = True
    keep = mark[pairs[:, 0]] & ~mark[pairs[:, 1]]
    return np.unique(pairs[keep], axis=0)


class HapticProxy:
    """The proxy (god-object) of seed 002 §3.4: one :meth:`step` per servo tick."""

    def __init__(self, settings: ProxySettings):
        self.settings = settings
        k = np.asarray(settings.stiffness, dtype=np.float64)
        self._hessian = np.diag(k / k.max())  # the solution depends on K's ratios only
        try:
            import daqp
        except ImportError as exc:
            raise ImportError(
                "the haptic proxy QP needs the daqp package (pip install daqp)"
            ) from exc
        self._qp = daqp.solve
        self._graphic: np.ndarray | None = None
        self._failing = False

    def reset(self):
        """Forget the previous graphical tool: the next step starts at q_h."""
        self._graphic = None

    def step(self, haptic_pose: np.ndarray, scene) -> ProxyResult:
        """Advance one tick from the device pose (4×4 [m]) against ``scene`` (a
        :class:`~taichi_lap.haptics.snapshot.HapticScene`, or None before the first)."""
        q_h = np.array(haptic_pose[:3, 3], dtype=np.float64)
        rotation = np.asarray(haptic_pose[:3, :3], dtype=np.float64)
        q_prev = q_h if self._graphic is None else self._graphic
        status, contacts, qp_seconds, q_g = ProxyStatus.FREE, 0, 0.0, q_h
        omega = self.settings.omega
        q_p = omega * q_prev + (1.0 - omega) * q_h
        pull = np.zeros(3)
        if scene is not None and scene.coupling_tip is not None:
            q_g, status = np.array(scene.coupling_tip, dtype=np.float64), ProxyStatus.COUPLED
        elif scene is not None:
            found = self.contacts(q_p, rotation, scene)
            if len(found):
                q_g, status, contacts, qp_seconds = self._solve(q_h, q_prev, rotation, scene, found)
        if scene is not None and len(scene.grasp_rest):
            world = scene.grasp_local @ np.asarray(haptic_pose[:3, :3]).T + q_h
            pull = pull_force(
                world, scene.grasp_neighbor, scene.grasp_rest, self.settings.grasp_stiffness
            )
        self._graphic = q_g
        return ProxyResult(
            q_g.copy(), q_p, self.settings.gain * (q_g - q_h), pull, contacts, status, qp_seconds
        )

    def contacts(self, q_p: np.ndarray, rotation: np.ndarray, scene) -> np.ndarray:
        """Indices of the particles within contact (plus the margin) of the tool at
        ``q_p`` turned by ``rotation``: tool-sphere tests on the clusters, then
        tool-particle tests on the particles of the clusters hit."""
        tool, margin = self.settings.tool, self.settings.contact_margin
        gap, _, _ = tool_distance(tool, scene.cluster_center, q_p, rotation, gradients=False)
        hit = np.flatnonzero(gap < scene.cluster_radius + margin)
        if not len(hit):
            return hit
        candidates = ranges(scene.cluster_start, hit)
        points = scene.particle_position[candidates].astype(np.float64)
        gap, _, _ = tool_distance(tool, points, q_p, rotation, gradients=False)
        return candidates[gap < scene.particle_radius[candidates] + margin]

    def _solve(self, q_h, q_prev, rotation, scene, found):
        """The QP in Δ = q - q_g(t-1): min ½ (Δ - e)ᵀ K (Δ - e), nᵢᵀ Δ ≥ bᵢ."""
        points = scene.particle_position[found].astype(np.float64)
        gap, gradient, on_axis = tool_distance(self.settings.tool, points, q_prev, rotation)
        normal = -gradient  # into the tool
        if np.any(on_axis):  # no normal: push back towards where q_h came from
            back = q_prev - q_h
            if np.linalg.norm(back) > 1e-12:
                normal[on_axis] = back / np.linalg.norm(back)
            else:
                keep = ~on_axis
                normal, gap, found = normal[keep], gap[keep], found[keep]
        b = scene.particle_radius[found].astype(np.float64) - gap
        if len(b) > self.settings.max_contacts:
            deepest = np.argpartition(-b, self.settings.max_contacts - 1)
            keep = deepest[: self.settings.max_contacts]
            normal, b = normal[keep], b[keep]
        if not len(b):
            return q_h, ProxyStatus.FREE, 0, 0.0
        normal = np.ascontiguousarray(normal)
        f = -self._hessian @ (q_h - q_prev)
        upper = np.full(len(b), NO_BOUND)
        seconds = 0.0
        for status, lower in ((ProxyStatus.CONTACT, b), (ProxyStatus.RELAXED, np.minimum(b, 0.0))):
            start = time.perf_counter()
            delta, _, exitflag, _ = self._qp(self._hessian, f, normal, upper, lower)
            seconds += time.perf_counter() - start
            if exitflag > 0:
                self._failing = False
                return q_prev + delta, status, len(b), seconds
        if not self._failing:
            log.warning(
                "proxy QP failed (DAQP exit flag %d) with %d contacts even with "
                "relaxed offsets; holding the previous graphical tool",
                exitflag,
                len(b),
            )
        self._failing = True
        return q_prev.copy(), ProxyStatus.HELD, len(b), seconds


class SurfaceClusters:
    """What the simulation publishes for collision (seed 002 §3.4): the surface
    particles of a model grouped by shape-matching cluster.

    Surface particles are those the render surface is bound to; their radius is the
    contact radius (the drawn surface's distance from them, 0 where it passes through
    them), so the graphical tool rests on the surface as drawn. Each joins the one
    cluster of its own (whole-organ clusters excepted) whose rest centre is nearest,
    so groups are disjoint and every particle is tested once; surface particles of
    organs without clusters are grouped on a lattice of ``cell`` [m] (default: the
    median cluster radius). Each frame a group's sphere is centred on its particles'
    mean with the radius that bounds their spheres, so however the tissue deforms the
    cluster test misses no particle. ``surface`` (sorted particle indices) replaces
    the built surface's particles: the surface after a dissection
    (:meth:`taichi_lap.session.Session.surface_particles`).
    """

    def __init__(self, data, *, cell: float | None = None, surface=None):
        n = data.particle_count
        if surface is None:
            surface = data.surface_particles()
        on_surface = np.zeros(n, dtype=bool)
        on_surface[surface] = True
        sizes = np.diff(data.cluster_start)
        owner = np.repeat(np.arange(len(sizes)), sizes)
        member = np.asarray(data.cluster_member, dtype=np.int64)
        organ_size = np.bincount(data.organ)[data.organ]
        rest = np.asarray(data.rest_position, dtype=np.float64)
        center = (
            np.stack([np.bincount(owner, rest[member, a], len(sizes)) for a in range(3)], axis=1)
            / np.maximum(sizes, 1)[:, None]
        )
        keep = on_surface[member] & (sizes[owner] < organ_size[member])
        member, owner = member[keep], owner[keep]
        dist = ((rest[member] - center[owner]) ** 2).sum(axis=1)
        order = np.lexsort((dist, member))
        member, owner = member[order], owner[order]
        first = np.r_[True, member[1:] != member[:-1]] if len(member) else np.zeros(0, bool)
        group = np.full(n, -1, dtype=np.int64)
        group[member[first]] = owner[first]
        lonely = surface[group[surface] < 0]
        if len(lonely):
            radii = np.asarray(data.cluster_radius)
            cell = cell or (float(np.median(radii)) if len(radii) else 0.01)
            _, cell_id = np.unique(
                np.floor(rest[lonely] / cell).astype(np.int64), axis=0, return_inverse=True
            )
            group[lonely] = len(sizes) + cell_id.ravel()
        labels = group[surface]
        order = np.argsort(labels, kind="stable")
        self.particles = surface[order]
        counts = np.unique(labels, return_counts=True)[1]
        self.start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.radius = np.asarray(data.contact_radius(), dtype=np.float32)[self.particles]

    @property
    def cluster_count(self) -> int:
        return len(self.start) - 1

    @property
    def particle_count(self) -> int:
        return len(self.particles)

    def spheres(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sphere centres (C, 3) [m], radii (C,) [m] and the grouped particle positions
        (P, 3) [m] for all particle positions ``x`` (N, 3) [m]."""
        positions = np.asarray(x)[self.particles]
        counts = np.diff(self.start)
        center = np.add.reduceat(positions, self.start[:-1], axis=0) / counts[:, None]
        reach = np.linalg.norm(positions - np.repeat(center, counts, axis=0), axis=1) + self.radius
        return center, np.maximum.reduceat(reach, self.start[:-1]), positions

    def publish(self, snapshot, x: np.ndarray, **extra) -> int:
        """Publish this frame to ``snapshot`` (a SceneSnapshot); ``extra`` (grasp edges,
        coupling tip) as in :meth:`SceneSnapshot.publish`. Returns the sequence number."""
        center, radius, positions = self.spheres(x)
        return snapshot.publish(center, radius, self.start, positions, self.radius, **extra)
