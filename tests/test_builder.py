"""Model building: clusters (seed 002 §3.2), joins, surface binding, the model cache."""

from dataclasses import replace
from pathlib import Path

import numpy as np

from taichi_lap import scene as scene_mod
from taichi_lap.preprocess import cache
from taichi_lap.preprocess import clusters as clustering
from taichi_lap.preprocess.assemble import assemble
from taichi_lap.scene.schema import MATERIAL_PARAMS
from taichi_lap.session import Session

SMALL = {"scene.detail": 0.03}


def test_lattice_clusters_cover_every_particle_and_overlap_by_one_radius():
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.03, 0.03, size=(4000, 3))
    radius = 0.01
    c = clustering.lattice_clusters(points, radius)
    owners = np.bincount(c.members, minlength=len(points))
    assert owners.min() >= 1
    assert owners.mean() > 2.5  # overlapping: each particle is shared
    for k in range(c.count):
        members = c.members[c.start[k] : c.start[k + 1]]
        assert np.linalg.norm(points[members] - c.center[k], axis=1).max() <= radius * (1 + 1e-9)
    gaps = np.linalg.norm(c.center[:, None] - c.center[None], axis=2)
    np.fill_diagonal(gaps, np.inf)
    assert np.isclose(gaps.min(axis=1), radius).all()  # neighbours one radius apart


def test_auto_radius_gives_fifty_particles_per_cluster_count():
    session = Session(
        scene_mod.from_tables(
            [
                {
                    "name": "ball",
                    "model": "tet_clusters",
                    "geometry": {"generator": "sphere", "radius": 0.05},
                    "material": {"particle_spacing": 0.004, "organ_cluster": False},
                }
            ]
        ),
        use_cache=False,
        progress=False,
    )
    ratio = session.model.particle_count / session.model.cluster_total
    assert 38 < ratio < 62


def test_joined_organs_share_clusters():
    data = assemble(scene_mod.load("liver", SMALL), progress=False)
    liver, vein = data.organs[0], data.organs[1]
    shared = 0
    for c in range(*vein.clusters):
        members = data.cluster_member[data.cluster_start[c] : data.cluster_start[c + 1]]
        in_liver = (members >= liver.particles[0]) & (members < liver.particles[1])
        shared += bool(in_liver.any() and (~in_liver).any())
    assert shared >= 3


def test_surface_binding_reproduces_the_rest_surface():
    """Vessels are bound barycentrically in their tets (seed 002 §3.2): skinning the
    rest particles gives back the generator's tube mesh; the liver capsule is made of
    tet vertices (direct binding)."""
    from taichi_lap.preprocess.organs import make_geometry

    scene = scene_mod.load("liver", SMALL)
    data = assemble(scene, progress=False)
    skinned = np.einsum("vk,vkd->vd", data.surface_weight, data.rest_position[data.surface_index])
    vein = data.organs[1]
    a, b = vein.surface_vertices
    tube = make_geometry(scene.organs[1], scene.source).surface
    assert np.abs(skinned[a:b] - tube.vertices).max() < 1e-9
    assert (np.count_nonzero(data.surface_weight[a:b], axis=1) > 1).mean() > 0.9
    a, b = data.organs[0].surface_vertices
    assert np.array_equal(data.surface_weight[a:b, 0], np.ones(b - a))


def test_second_start_loads_the_cached_model(tmp_path, monkeypatch):
    monkeypatch.setenv("TAICHI_LAP_CACHE", str(tmp_path))
    scene = scene_mod.load("rectum", SMALL)
    first = cache.build_model(scene, progress=False)
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1
    called = []
    monkeypatch.setattr(cache, "assemble", lambda *a, **k: called.append(1))
    second = cache.build_model(scene, progress=False)
    assert not called
    for key, value in first.arrays().items():
        assert np.array_equal(value, second.arrays()[key]), key
    assert [o.name for o in first.organs] == [o.name for o in second.organs]


def test_changed_scene_misses_the_cache_and_corrupt_cache_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("TAICHI_LAP_CACHE", str(tmp_path))
    a = scene_mod.load("rectum", SMALL)
    b = scene_mod.load("rectum", {**SMALL, "organs.rectum.material.stiffness": 0.3})
    assert cache.scene_digest(a) != cache.scene_digest(b)
    cache.build_model(a, progress=False)
    path = next(tmp_path.glob("*.npz"))
    path.write_bytes(b"not a model")
    rebuilt = cache.build_model(a, progress=False)
    assert rebuilt.particle_count > 0
    assert cache.load_model(path).particle_count == rebuilt.particle_count


def test_a_changed_schema_default_misses_the_cache(monkeypatch):
    before = cache.scene_digest(scene_mod.load("rectum", SMALL))
    shape = MATERIAL_PARAMS["shape_matching"]
    monkeypatch.setitem(shape, "organ_cluster", replace(shape["organ_cluster"], default=False))
    assert cache.scene_digest(scene_mod.load("rectum", SMALL)) != before


def test_a_changed_builder_function_misses_the_cache(monkeypatch):
    scene = scene_mod.load("rectum", SMALL)
    before = cache.scene_digest(scene)
    sources = cache.build_sources()
    changed = next(p for p in sources if p.name == "clusters.py")
    read_bytes = Path.read_bytes
    monkeypatch.setattr(
        Path, "read_bytes", lambda self: read_bytes(self) + b"#" * (self == changed)
    )
    assert cache.scene_digest(scene) != before


def test_the_cache_key_covers_every_module_a_build_reads():
    names = {path.name for path in cache.build_sources()}
    assert {
        "organs.py",
        "clusters.py",
        "tetrahedralize.py",
        "truss.py",
        "sheets.py",
        "meshfile.py",
        "liver.py",
        "rectum.py",
        "intestine.py",
        "sdf.py",
    } <= names


def test_two_runs_of_a_scene_are_identical():
    """Two builds of the rectum give the same model, and two runs of its script from
    the settled start the same state: the second run a session that took the first's
    closed fields (as a second session of a scene in one process does), so it starts
    by a reset and compiles nothing."""
    from dataclasses import fields

    from taichi_lap.session import scene_script

    scene = scene_mod.load("rectum", SMALL)
    snapshots = []
    for _ in range(2):
        session = Session(scene, use_cache=False, progress=False)
        script = scene_script(scene)
        for _ in range(20):
            session.step(script.poses(session.state.time))
        snapshots.append(session.state.snapshot())
        session.close()
    for key in snapshots[0]:
        assert np.array_equal(snapshots[0][key], snapshots[1][key]), key
    again = cache.build_model(scene, use_cache=False, progress=False)
    for field in fields(again):
        a, b = getattr(session.data, field.name), getattr(again, field.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b), field.name
