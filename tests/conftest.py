"""Test setup: one Taichi init per process, on the CPU backend unless
``$TAICHI_LAP_TEST_ARCH`` names another (``cuda``: the whole suite on a GPU).

Kernel tests marked ``vulkan`` also run their computation on ``ti.vulkan`` (or the
backend ``$TAICHI_LAP_COMPARE_ARCH`` names) in a child process (Taichi should be
initialised once per process) through :func:`tests.archrun.run_on_arch`, and compare
the arrays with the CPU run.
"""

import os
from pathlib import Path

import pytest

from taichi_lap import runtime

TEST_ARCH = os.environ.get("TAICHI_LAP_TEST_ARCH", "cpu")


def model_cache(tmp_path_factory) -> Path:
    """The run's model cache folder: beside the workers' own temporary folders under
    pytest-xdist (their common parent is the run's), else in this process's."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    folder = base / "model-cache"
    folder.mkdir(exist_ok=True)
    return folder


@pytest.fixture(scope="session", autouse=True)
def taichi_backend(tmp_path_factory):
    """Initialise Taichi once, on :data:`TEST_ARCH` (the CPU with a fixed thread
    count); built models and settled starts are cached in a temporary folder, not the
    user's cache, one folder that the run's workers share (each built the same scenes
    and settled them again; cache files are written atomically)."""
    os.environ["TAICHI_LAP_CACHE"] = str(model_cache(tmp_path_factory))
    runtime.init(TEST_ARCH, threads=2 if TEST_ARCH == "cpu" else None)
    yield


LONGEST_FILES_FIRST = (
    "test_recording.py",
    "test_tool_contact.py",
    "test_trajectories.py",
    "test_dissection_device.py",
    "test_circumsphere.py",
    "test_cli.py",
    "test_session.py",
    "test_haptic_bridge.py",
    "test_wound_collision.py",
    "test_volume_cut.py",
    "test_shape_matching.py",
    "test_sheet_cut.py",
    "test_render.py",
    "test_cautery.py",
    "test_lra.py",
)
"""Test files that took the longest (over a minute each on a 2-core machine), longest
first. The workers take files in the order collected (``--dist loadfile``); in
alphabetical order one of two workers ran the last long file alone for about 90 s
(1287 s against 1198 s with the longest first, simulated from the measured times)."""


def pytest_collection_modifyitems(items):
    """Collect the files of :data:`LONGEST_FILES_FIRST` first, in its order; the
    others follow as before."""
    rank = {name: k for k, name in enumerate(LONGEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
