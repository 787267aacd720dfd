"""Test setup: one Taichi init per process, on the CPU backend unless
``$TAICHI_LAP_TEST_ARCH`` names another (``cuda``: the whole suite on a GPU).

Kernel tests marked ``vulkan`` also run their computation on ``ti.vulkan`` (or the
backend ``$TAICHI_LAP_COMPARE_ARCH`` names) in a child process (Taichi should be
initialised once per process) through :func:`tests.archrun.run_on_arch`, and compare
the arrays with the CPU run.
"""

import os

import pytest

from taichi_lap import runtime

TEST_ARCH = os.environ.get("TAICHI_LAP_TEST_ARCH", "cpu")


@pytest.fixture(scope="session", autouse=True)
def taichi_backend(tmp_path_factory):
    """Initialise Taichi once, on :data:`TEST_ARCH` (the CPU with a fixed thread
    count); built models are cached in a temporary folder, not the user's cache."""
    os.environ["TAICHI_LAP_CACHE"] = str(tmp_path_factory.mktemp("model-cache"))
    runtime.init(TEST_ARCH, threads=2 if TEST_ARCH == "cpu" else None)
    yield
