"""Test setup: one Taichi init per process, on the CPU backend.

Kernel tests marked ``vulkan`` also run their computation on ``ti.vulkan`` in a
child process (Taichi should be initialised once per process) through
:func:`tests.archrun.run_on_arch`, and compare the arrays with the CPU run.
"""

import os

import pytest

from taichi_lap import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu(tmp_path_factory):
    """Initialise Taichi once, on the CPU, with a fixed thread count; built models
    are cached in a temporary folder, not the user's cache."""
    os.environ["TAICHI_LAP_CACHE"] = str(tmp_path_factory.mktemp("model-cache"))
    runtime.init("cpu", threads=2)
    yield
