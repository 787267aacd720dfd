"""The benchmarks (installed as ``taichi_lap.perf``): each ``bench_<name>`` module
prints a table and writes JSON (:mod:`taichi_lap.perf.common`); ``taichi-lap bench``
runs them all for each backend asked (:mod:`taichi_lap.bench`)."""

BENCHMARKS = (
    "deform",
    "frame",
    "render",
    "circumsphere",
    "intestine_cd",
    "haptics",
    "contact",
    "topology",
)
"""Every benchmark, in the order ``taichi-lap bench`` runs them."""
