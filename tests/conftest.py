"""Test setup: one Taichi init per process, on the CPU backend.

Kernel tests marked ``vulkan`` also run their computation on ``ti.vulkan`` in a
child process (Taichi should be initialised once per process) through
:func:`tests.archrun.run_on_arch`, and compare the arrays with the CPU run.
"""

import pytest

from taichi_lap import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu():
    """Initialise Taichi once, on the CPU, with a fixed thread count."""
    runtime.init("cpu", threads=2)
    yield
