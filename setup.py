"""Package discovery (the metadata is in pyproject.toml).

``kernels/``, ``scenes/`` and ``perf/`` install as ``taichi_lap.kernels``,
``taichi_lap.scenes`` and ``taichi_lap.perf``, so the only top-level import name is
``taichi_lap``. Every package below the four folders is found here, so a new one cannot
be left out of the wheel."""

from setuptools import find_packages, setup

MAPPED = {"taichi_lap.kernels": "kernels", "taichi_lap.scenes": "scenes", "taichi_lap.perf": "perf"}


def packages() -> list[str]:
    found = find_packages(include=["taichi_lap", "taichi_lap.*"])
    for name, folder in MAPPED.items():
        found += [name] + [f"{name}.{sub}" for sub in find_packages(folder)]
    return found


setup(packages=packages(), package_dir=MAPPED)
