"""Model statistics in the form of seed 002 Table 1 (vertices, triangles,
tetrahedra, physical particles, clusters, average cluster radius)."""

from __future__ import annotations

import numpy as np

from taichi_lap.preprocess.model_data import ModelData

COLUMNS = ("vertices", "triangles", "particles", "tets", "clusters", "avg_cluster_radius")


def model_statistics(data: ModelData) -> dict:
    """``{"organs": [...], "totals": {...}}``; radii in metres."""
    organs = []
    for o in data.organs:
        radii = data.cluster_radius[o.clusters[0] : o.clusters[1]]
        organs.append(
            {
                "name": o.name,
                "model": o.model,
                "vertices": o.surface_vertices[1] - o.surface_vertices[0],
                "triangles": o.triangles[1] - o.triangles[0],
                "particles": o.particles[1] - o.particles[0],
                "tets": o.tets[1] - o.tets[0],
                "clusters": o.clusters[1] - o.clusters[0],
                "avg_cluster_radius": float(radii.mean()) if len(radii) else 0.0,
                "struts": o.struts,
                "springs": o.springs,
            }
        )
    totals = {k: int(sum(o[k] for o in organs)) for k in COLUMNS[:-1]}
    sizes = np.diff(data.cluster_start)
    totals.update(
        {
            "avg_cluster_radius": float(data.cluster_radius.mean())
            if len(data.cluster_radius)
            else 0.0,
            "cluster_memberships": int(sizes.sum()),
            "particles_per_cluster": float(totals["particles"] / max(totals["clusters"], 1)),
            "members_per_cluster": float(sizes.mean()) if len(sizes) else 0.0,
            "distance_constraints": int(len(data.distance_pair)),
            "long_range_attachments": int(len(data.lra_particle)),
            "springs": int(len(data.spring_pair)),
            "pinned": int(data.pinned.sum()),
        }
    )
    return {"organs": organs, "totals": totals}


def format_table(stats: dict) -> str:
    """A text table like seed 002 Table 1 (radius in cm)."""
    head = (
        f"{'organ':<18}{'model':<16}{'vertices':>9}{'triangles':>10}{'particles':>10}"
        f"{'tets':>9}{'clusters':>9}{'radius/cm':>10}"
    )
    lines = [head, "-" * len(head)]
    rows = stats["organs"] + [dict(stats["totals"], name="total", model="")]
    for r in rows:
        lines.append(
            f"{r['name']:<18}{r['model']:<16}{r['vertices']:>9}{r['triangles']:>10}"
            f"{r['particles']:>10}{r['tets']:>9}{r['clusters']:>9}"
            f"{100 * r['avg_cluster_radius']:>10.2f}"
        )
    t = stats["totals"]
    lines.append(
        f"cluster memberships {t['cluster_memberships']} "
        f"({t['members_per_cluster']:.0f} per cluster, {t['particles_per_cluster']:.1f} "
        f"particles per cluster count); distance constraints {t['distance_constraints']}, "
        f"LRAs {t['long_range_attachments']}, springs {t['springs']}, pinned {t['pinned']}"
    )
    return "\n".join(lines)
