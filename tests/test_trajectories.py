"""The state-regression guard: each built-in scene, run as :mod:`tests.trajectories`
describes, keeps the positions of its stored reference within the scene's tolerance,
on the CPU backend and on the compared backend (regenerate deliberately: ``python -m
tests.trajectories``). Vulkan, a software driver in CI, runs the scene's short
``vulkan_frames``; another backend runs all of its frames."""

import pytest

from tests.archrun import COMPARE_ARCH, run_on_arch
from tests.trajectories import RUNS, load_reference, max_difference, run_scene


def assert_within_tolerance(name: str, result: dict, tolerance: float):
    differences = max_difference(load_reference(name), result)
    assert max(differences.values()) <= tolerance, (
        f"{name} left its reference trajectory (tolerance {tolerance:g} m): {differences}"
    )


@pytest.mark.parametrize("name", sorted(RUNS))
def test_scene_follows_its_reference_trajectory(name):
    assert_within_tolerance(name, run_scene(name), RUNS[name].tolerance)


@pytest.mark.vulkan
@pytest.mark.parametrize(
    "name",
    [  # the liver's and rectum's kernels are compared one by one in the default run
        pytest.param(name, marks=pytest.mark.long) if name != "intestine" else name
        for name in sorted(RUNS)
    ],
)
def test_scene_follows_its_reference_trajectory_on_vulkan(name):
    run = RUNS[name]
    assert_within_tolerance(
        name,
        run_on_arch(
            COMPARE_ARCH,
            "tests.trajectories:run_scene",
            name=name,
            frames=run.vulkan_frames if COMPARE_ARCH == "vulkan" else None,
        ),
        run.vulkan_tolerance or run.tolerance,
    )
