"""Procedural liver and intrahepatic vessel trees (seed 002 §3.2, Table 1).

Liver frame (supine patient): x toward the patient's left (the right lobe lies at
-x), y up = anterior, z cranial. The visceral ("inferior") surface is the
flattened -y side; the hilum is on it. At ``scale = 1`` the liver measures about
24.5 x 10.5 x 15 cm and holds 1.78 L, so a BCC lattice of 2.9 mm spacing gives
about 146k particles as in seed 002 Table 1.

Vessels (seed 002 Table 1 lists bile duct, hepatic artery, hepatic vein, portal
vein) are centreline trees grown from hand-set first branches and regular
bifurcations; each branch is cut where it would come closer than
``(radius + 2 mm) * scale`` to the liver surface. The portal vein (6 -> 2 mm)
enters at the hilum; hepatic artery (2.5 -> 1 mm) and bile duct (3 -> 1.5 mm)
follow its branches at an offset on either side (the portal triad); three hepatic
veins (5 -> 2 mm) converge posteriorly and cranially, where the IVC would be.
"""

from __future__ import annotations

import numpy as np

from taichi_lap.core.geometry import Solid, arc_length
from taichi_lap.core.params import Param

from . import sdf as S
from . import tubes
from .generator import Generator

_CAL = 0.9869  # brings the scale-1 volume to 1.78 L (measured on a 0.8 mm grid)
CLEARANCE = 0.002  # [m] at scale 1: centreline points stay (r + CLEARANCE) inside
_BOUNDS = (np.array([-0.1240, -0.0410, -0.0760]), np.array([0.1250, 0.0680, 0.0760]))


def _raw(p: np.ndarray) -> np.ndarray:
    """Unnormalised liver field before calibration: smooth union of three ellipsoids
    (right lobe, left lobe, thin left tip) cut by a tilted plane (visceral side)."""
    right = S.ellipsoid(p, (-0.045, 0.006, 0.0), (0.080, 0.062, 0.076))
    left = S.ellipsoid(p, (0.035, 0.010, 0.008), (0.070, 0.034, 0.056))
    tip = S.ellipsoid(p, (0.090, 0.008, 0.016), (0.036, 0.016, 0.030))
    d = S.smooth_union(S.smooth_union(right, left, 0.03), tip, 0.015)
    floor = S.plane(p, (0.0, -0.030, 0.0), (0.15, -1.0, 0.05))
    return S.smooth_intersection(d, floor, 0.015)


def _unit_sdf(p) -> np.ndarray:
    """Liver distance estimate at scale 1 [m]: the field divided by its gradient
    norm (first-order distance; |grad| = 1 on the surface despite the blends)."""
    q = np.asarray(p, float).reshape(-1, 3) / _CAL
    g = np.linalg.norm(S.gradient(_raw, q, 1e-5), axis=1)
    return _CAL * _raw(q) / np.clip(g, 0.5, 2.0)


def liver_sdf(scale: float = 1.0) -> S.Sdf:
    """Signed distance estimate of the liver at ``scale`` [m]."""
    return S.scaled(_unit_sdf, float(scale))


def liver_bounds(scale: float = 1.0):
    lo, hi = _BOUNDS
    return (lo * scale, hi * scale)


def _build_liver(params: dict) -> Solid:
    s = float(params["scale"])
    return Solid(bounds=liver_bounds(s), sdf=liver_sdf(s))


# ---------------------------------------------------------------- vessel trees
# A tree is (start [m], inward direction or None, root nodes, root radius [mm]); a
# node is (first direction, last direction, length [mm], end radius [mm], children):
# the branch curves from its first to its last direction, children start at its end.
# A start with an inward direction is a surface point, moved inward until deep enough.


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _rotate(v, axis, angle):
    """Rodrigues rotation of ``v`` about unit ``axis`` by ``angle`` [rad]."""
    return (
        v * np.cos(angle)
        + np.cross(axis, v) * np.sin(angle)
        + axis * (axis @ v) * (1 - np.cos(angle))
    )


def _node(d0, d1, length, r_end, kids=()):
    return (_unit(d0), _unit(d1), length, r_end, tuple(kids))


def _forks(d, levels, length, radii, angle=0.6, roll=0.5 * np.pi, roll_step=0.25 * np.pi):
    """``levels`` more binary splits below direction ``d``: children leave at
    +-``angle`` [rad] in a plane turned by ``roll`` about ``d`` from the vertical
    (``roll_step`` more per level), then bend half-way back toward ``d``; each
    level is 0.75 x shorter [mm]; ``radii[i]`` [mm] ends level i."""
    if levels == 0:
        return ()
    ref = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    axis = _rotate(_unit(np.cross(d, ref)), d, roll)
    out = []
    for sgn in (1.0, -1.0):
        c = _unit(_rotate(d, axis, sgn * angle))
        e = _unit(c + d)
        out.append(
            _node(
                c,
                e,
                length,
                radii[0],
                _forks(e, levels - 1, 0.75 * length, radii[1:], angle, roll + roll_step, roll_step),
            )
        )
    return out


def _portal_spec():
    """Trunk up from the hilum, right and left portal veins, two more splits each."""
    trunk = _unit((-0.2, 1.0, 0.0))
    right = _node(
        (-1, 0.1, -0.1),
        (-1, 0.0, -0.2),
        30,
        4.2,
        _forks(_unit((-1, 0.0, -0.2)), 2, 36, (3.0, 2.0), 0.65),
    )
    left = _node(
        (1, 0.05, -0.1),
        (1, -0.05, -0.25),
        45,
        3.6,
        _forks(_unit((1, -0.05, -0.25)), 2, 28, (2.8, 2.0)),
    )
    hilum = np.array([-0.010, -0.035, -0.010])
    return (hilum, np.array([0.0, 1.0, 0.0]), [_node(trunk, trunk, 18, 5.2, [right, left])], 6.0)


def _hepatic_vein_spec():
    """Right, middle and left hepatic veins leaving the posterior-cranial confluence."""
    rdir, mdir, ldir = _unit((-0.8, 0.45, -1)), _unit((0.1, 0.7, -1)), _unit((1, 0.2, -0.3))
    roots = [
        _node((-1, 0.2, -0.4), rdir, 70, 3.2, _forks(rdir, 2, 30, (2.6, 2.0))),
        _node((0.0, 0.5, -1), mdir, 60, 3.2, _forks(mdir, 2, 26, (2.6, 2.0))),
        _node((1, 0.2, -0.1), ldir, 60, 3.0, _forks(ldir, 2, 24, (2.5, 2.0))),
    ]
    return (np.array([-0.020, -0.004, 0.054]), None, roots, 5.0)


def _triad_radius(r_portal, kind):
    """Hepatic artery 2.5 -> 1 mm and bile duct 3 -> 1.5 mm as the portal goes 6 -> 2 mm."""
    t = np.clip((np.asarray(r_portal) - 0.002) / 0.004, 0.0, 1.0)
    return {"hepatic_artery": 0.001 + 0.0015 * t, "bile_duct": 0.0015 + 0.0015 * t}[kind]


_GAP = 0.0005  # [m] between the portal wall and an accompanying vessel's wall


def _portal_margin(r):
    """Portal clearance that leaves the offset bile duct (the thicker companion) its own."""
    rb = _triad_radius(r, "bile_duct")
    return r + 2 * rb + _GAP + CLEARANCE + 0.0005


def _grow(spec, f, margin):
    """Grow the tree ``spec`` inside ``f`` (scale 1). Returns branches as
    ``[(points (n, 3), radii (n,), parent index or -1)]`` on dense curves."""
    start, inward, roots, r_root = spec
    r_root *= 1e-3
    if inward is not None:  # march from the surface point inward until deep enough
        for _ in range(200):
            if -f(start[None])[0] >= margin(r_root):
                break
            start = start + 0.0005 * inward
    out = []

    def walk(node, s, r0, parent):
        d0, d1, length, r1, kids = node
        L = length * 1e-3
        r1 = min(r1 * 1e-3, r0)
        ctrl = [s, s + 0.5 * L * d0, s + 0.5 * L * d0 + 0.5 * L * d1]
        pts = tubes.catmull_rom(ctrl, 24)
        acc = arc_length(pts)
        rad = r0 + (r1 - r0) * acc / acc[-1]
        ok = -f(pts) >= margin(rad)
        n = len(pts) if ok.all() else int(np.argmin(ok))
        if n < 2 or acc[n - 1] < 1.5 * r1:
            return
        out.append((pts[:n], rad[:n], parent))
        me = len(out) - 1
        for kid in kids:
            walk(kid, pts[n - 1], rad[n - 1], me)

    for node in roots:
        walk(node, start, r_root, -1)
    return out


def _offset_tree(portal, kind, f):
    """Companion vessel ``kind`` beside each portal branch at ``+N`` (artery) or
    ``-N`` (bile duct). ``N`` is rotation-minimising, twisted along each branch so
    that at a bifurcation it is normal to the plane of the two children: the
    companions then pass beside, not through, the sibling branches. Each child
    continues from its parent's companion end; cut where too close to the surface."""
    sign = 1.0 if kind == "hepatic_artery" else -1.0
    kids = {}
    for i, (pts, _, parent) in enumerate(portal):
        kids.setdefault(parent, []).append(_unit(pts[1] - pts[0]))
    out, idx, end_n = [], {}, {}
    for i, (pts, r_p, parent) in enumerate(portal):
        if parent >= 0 and parent not in idx:
            continue
        T, N, B = tubes.rmf_frames(pts, end_n.get(parent, np.array([0.0, 0.0, 1.0])))
        if len(kids.get(i, [])) >= 2:
            target = np.cross(kids[i][0], kids[i][1])
            target -= (target @ T[-1]) * T[-1]
            if np.linalg.norm(target) > 1e-9:
                target = _unit(target) * np.sign(target @ N[-1] or 1.0)
                theta = np.arctan2(np.cross(N[-1], target) @ T[-1], N[-1] @ target)
                phi = theta * (arc_length(pts) / arc_length(pts)[-1])[:, None]
                N = np.cos(phi) * N + np.sin(phi) * B
        r = _triad_radius(r_p, kind)
        q = pts + sign * (r_p + r + _GAP)[:, None] * N
        ok = -f(q) >= r + CLEARANCE
        n = len(q) if ok.all() else int(np.argmin(ok))
        if n < 2:
            continue
        out.append((q[:n], r[:n], idx.get(parent, -1)))
        if n == len(q):
            idx[i], end_n[i] = len(out) - 1, N[-1]
    return out


VESSELS = ("bile_duct", "hepatic_artery", "hepatic_vein", "portal_vein")


def vessel_branches(vessel: str, scale: float = 1.0):
    """Centreline tree of ``vessel`` at ``scale``: ``[(points, radii, parent)]``
    on dense curves [m] (deterministic)."""
    if vessel not in VESSELS:
        raise ValueError(f"unknown vessel {vessel!r}; choose one of {VESSELS}")
    f = liver_sdf(1.0)
    if vessel == "hepatic_vein":
        tree = _grow(_hepatic_vein_spec(), f, lambda r: r + CLEARANCE + 0.0005)
    else:
        tree = _grow(_portal_spec(), f, _portal_margin)
        if vessel != "portal_vein":
            tree = _offset_tree(tree, vessel, f)
    return [(p * scale, r * scale, k) for p, r, k in tree]


def _build_vessel(params: dict) -> Solid:
    s = float(params["scale"])
    m = int(params["segments_around"])
    meshes, pieces = [], []
    for pts, rad, _ in vessel_branches(params["vessel"], s):
        q, r = tubes.resample(pts, rad, 1.0)
        pieces.append((q, r))
        meshes.append(tubes.tube_mesh(q, r, m, "round"))
    tree = tubes.TubeTree(pieces)
    surface = tubes.concatenate(meshes)
    lo = np.minimum(surface.vertices.min(0), tree.bounds[0])
    hi = np.maximum(surface.vertices.max(0), tree.bounds[1])
    return Solid(bounds=(lo, hi), sdf=tree, surface=surface)


_SCALE = Param("float", 1.0, "uniform size factor (1 = adult liver, 1.78 L)", 0.1, 3.0)

GENERATORS = [
    Generator(
        "liver",
        _build_liver,
        {"scale": _SCALE},
        "solid",
        "Liver parenchyma (seed 002 §3.2): smooth union of lobes, 1.78 L at scale 1.",
    ),
    Generator(
        "liver_vessel",
        _build_vessel,
        {
            "vessel": Param(
                "str", "portal_vein", "which intrahepatic vessel tree", choices=VESSELS
            ),
            "scale": _SCALE,
            "segments_around": Param("int", 12, "vertices around each tube ring", 6, 64),
        },
        "solid",
        "Intrahepatic vessel tree inside the liver of the same scale (seed 002 Table 1).",
    ),
]
