"""Truss structure pre-processing (seed 000 §3.3, Alg. 2) and its effect."""

import math

import numpy as np
import pytest
from taichi_lap.scenes.anatomy import GENERATORS

from taichi_lap.core.geometry import TriangleMesh
from taichi_lap.preprocess.truss import generate_truss, vertex_normals
from tests.archrun import assert_backend_matches_cpu
from tests.helpers import simulation, state_after

THRESHOLD = math.pi / 3
CONE = 0.35
K_MIN = 0.05


def gland(subdivisions=2) -> TriangleMesh:
    """The ellipsoid gland, jittered: a symmetric mesh sends rays exactly through
    vertices, where the nearest face is a tie."""
    params = {k: p.default for k, p in GENERATORS["ellipsoid"].params.items()}
    params["subdivisions"] = subdivisions
    mesh = GENERATORS["ellipsoid"].build(params)
    jitter = np.random.default_rng(7).normal(0.0, 2e-4, mesh.vertices.shape)
    return TriangleMesh(mesh.vertices + jitter, mesh.triangles)


def alg2_by_loops(mesh: TriangleMesh) -> tuple[dict, dict]:
    """Alg. 2 written out with plain loops (independent of the vectorised code).
    Returns the merged strut stiffness and, per vertex, the (length, k) of the
    struts it generated."""
    v, f = mesh.vertices, mesh.triangles
    normals, face_normals = vertex_normals(mesh)
    result, per_vertex = {}, {}
    for i in range(len(v)):
        best, best_t = None, math.inf
        for k, (a, b, c) in enumerate(f):
            if np.dot(normals[i], face_normals[k]) >= 0:
                continue
            d = -normals[i]
            e1, e2 = v[b] - v[a], v[c] - v[a]
            h = np.cross(d, e2)
            det = np.dot(e1, h)
            if abs(det) < 1e-18:
                continue
            s = v[i] - v[a]
            u = np.dot(s, h) / det
            q = np.cross(s, e1)
            w = np.dot(d, q) / det
            t = np.dot(e2, q) / det
            if u >= 0 and w >= 0 and u + w <= 1 and 1e-9 < t < best_t:
                best, best_t = k, t
        if best is None:
            continue
        axis = v[f[best]].mean(axis=0) - v[i]
        axis /= np.linalg.norm(axis)
        struts = []
        for j in range(len(v)):
            rel = v[j] - v[i]
            dist = np.linalg.norm(rel)
            if (
                j != i
                and np.dot(rel, axis) >= math.cos(CONE) * dist
                and np.dot(normals[i], normals[j]) < math.cos(THRESHOLD)
            ):
                struts.append((j, dist))
        if not struts:
            continue
        d_min, d_max = min(s[1] for s in struts), max(s[1] for s in struts)
        per_vertex[i] = []
        for j, dist in struts:
            k = min((dist - d_max) / (d_min - d_max) + K_MIN if d_max > d_min else 1.0, 1.0)
            key = (min(i, j), max(i, j))
            result[key] = max(result.get(key, 0.0), k)
            per_vertex[i].append((dist, k))
    return result, per_vertex


def test_struts_respect_bending_threshold_and_match_alg2():
    mesh = gland(subdivisions=1)
    truss = generate_truss(mesh, cone_angle=CONE, bending_threshold=THRESHOLD, min_stiffness=K_MIN)
    normals, _ = vertex_normals(mesh)
    assert len(truss.pairs) > 50
    cosines = np.einsum("ij,ij->i", normals[truss.pairs[:, 0]], normals[truss.pairs[:, 1]])
    assert cosines.max() < math.cos(THRESHOLD)
    expected, _ = alg2_by_loops(mesh)
    got = {tuple(p): k for p, k in zip(truss.pairs.tolist(), truss.stiffness)}
    assert set(got) == set(expected)
    assert max(abs(got[p] - expected[p]) for p in got) < 1e-12
    assert truss.stiffness.min() >= K_MIN - 1e-12 and truss.stiffness.max() <= 1.0


def test_shortest_strut_of_each_vertex_is_the_stiffest():
    """Per generating vertex (Alg. 2 lines 19-29): the shortest strut has k = 1 (the
    clipped 1 + k_min), the longest k_min, and k falls with length in between."""
    _, per_vertex = alg2_by_loops(gland(subdivisions=1))
    assert len(per_vertex) > 20
    for struts in per_vertex.values():
        struts.sort()
        lengths, k = np.array(struts).T
        assert k[0] == 1.0
        if lengths[-1] > lengths[0]:
            assert abs(k[-1] - K_MIN) < 1e-12
        assert np.all(np.diff(k) <= 1e-12)


def organ(cone_angle):
    return {
        "name": "gland",
        "model": "truss",
        "geometry": {"generator": "ellipsoid", "radii": [0.02, 0.014, 0.016], "subdivisions": 2},
        "material": {"cone_angle": cone_angle, "edge_stiffness": 1.0, "damping": 2.0},
    }


def test_truss_holds_the_gland_up_where_edges_alone_collapse():
    floor = {"point": [0, -0.014, 0], "normal": [0, 1, 0], "friction": 0.5}
    heights = {}
    for cone in (0.35, 0.01):
        _, data, _, state, control, solver = simulation(
            [organ(cone)], planes=[floor], iterations=10, substeps=4
        )
        for _ in range(90):
            solver.step(state, control, 1 / 60)
        x = state.x.to_numpy()
        heights[cone] = np.ptp(x[:, 1]) / np.ptp(data.rest_position[:, 1])
    assert heights[0.35] > 0.85
    assert heights[0.01] < 0.5


def compute_gland_case() -> dict:
    """The truss gland settling on the floor for 30 frames (run on any backend)."""
    floor = {"point": [0, -0.014, 0], "normal": [0, 1, 0], "friction": 0.5}
    return state_after([organ(0.35)], 30, planes=[floor], iterations=10, substeps=4)


@pytest.mark.vulkan
def test_vulkan_agrees_with_cpu():
    assert_backend_matches_cpu("tests.test_truss:compute_gland_case", 1e-4)
