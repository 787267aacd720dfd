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
from taichi_lap import session as session_mod

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


MAX_WORKERS = 4
"""Most test processes ``-n auto`` starts (pyproject's addopts): one per core the run
may use, up to this many (each holds its scenes' models and compiled kernels, 1-3 GB)."""


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: a worker per usable core, at most :data:`MAX_WORKERS`."""
    return max(1, min(len(os.sched_getaffinity(0)), MAX_WORKERS))


@pytest.fixture(scope="session", autouse=True)
def taichi_backend(tmp_path_factory):
    """Initialise Taichi once, on :data:`TEST_ARCH` (the CPU with one thread: the
    workers already share out the cores; three workers with two threads each ran three
    heavy test files in 305 s, with one thread 276 s); built models and settled starts
    are cached in a temporary folder, not the user's cache, one folder that the run's
    workers share (each built the same scenes and settled them again; cache files are
    written atomically)."""
    os.environ["TAICHI_LAP_CACHE"] = str(model_cache(tmp_path_factory))
    runtime.init(TEST_ARCH, threads=1 if TEST_ARCH == "cpu" else None)
    session_mod.keep_closed_sessions(KEPT_SESSIONS)
    yield


KEPT_SESSIONS = 1000
"""Closed sessions a test process keeps for reuse: all of them. Freeing one's fields
would make Taichi compile every kernel of the process again; not closing them keeps
the same fields allocated."""

_made_in_test: list | None = None
"""The sessions the running test made (:func:`pytest_runtest_call`)."""

_session_init = session_mod.Session.__init__


def _tracked_init(self, *args, **kwargs):
    _session_init(self, *args, **kwargs)
    if _made_in_test is not None:
        _made_in_test.append(self)


session_mod.Session.__init__ = _tracked_init


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    """Close the sessions a test made (not those of its fixtures) when it ends, so that
    later tests of the same scene in this process take their fields and compiled
    kernels instead of compiling every kernel again (half the suite's time went to
    compiling). Reuse resets the state, the tools and the topology; a test that
    changes a session beyond that (its solver, its model's fields) is marked
    ``keeps_sessions`` and leaves its sessions unclosed."""
    global _made_in_test
    _made_in_test = [] if item.get_closest_marker("keeps_sessions") is None else None
    try:
        yield
    finally:
        made, _made_in_test = _made_in_test or [], None
        for session in made:
            session.close()
        free_kept_sessions_near_the_tree_limit()


TREE_BUDGET = 384
"""SNode tree ids a test process may hand out before it frees the sessions it keeps
(Taichi holds at most :data:`~taichi_lap.runtime.SNODE_TREE_LIMIT` trees; a worker of
a two-worker run reached 428 with every session kept, and a CI run crashed there).
The room left is for a test file's trees that no session holds (renderers, test
objects): the most one took was 124."""

_freed_at = 0
"""The tree ids handed out when the kept sessions were last freed."""


def free_kept_sessions_near_the_tree_limit():
    """Free the sessions kept for reuse (their kernels compile again) once the tree
    ids handed out pass :data:`TREE_BUDGET` and grew since the last time: Taichi
    gives the freed ids to new trees first, so the count grows again only when they
    are spent."""
    global _freed_at
    trees = runtime.snode_trees()
    if trees >= TREE_BUDGET and trees > _freed_at:
        session_mod.release_parked()
        _freed_at = trees


LONGEST_FILES_FIRST = (
    "test_task_liver.py",  # (not in the default run: marked scene_task)
    "test_task_rectum.py",
    "test_recording.py",
    "test_tool_contact.py",
    "test_circumsphere.py",
    "test_render.py",
    "test_cli.py",
    "test_spring_sheets.py",
    "test_dissection_device.py",
    "test_wound_collision.py",
    "test_session.py",
    "test_sheet_cut.py",
    "test_volume_cut.py",
    "test_one_sided.py",
    "test_wall_cut.py",
    "test_trajectories.py",
    "test_cautery.py",
)
"""Test files that took the longest (over 40 s each on a 2-core machine), longest
first. The workers take files in the order collected (``--dist loadfile``); in
alphabetical order one of two workers ran the last long file alone for about 90 s
(1287 s against 1198 s with the longest first, simulated from the measured times)."""


def pytest_collection_modifyitems(items):
    """Collect the files of :data:`LONGEST_FILES_FIRST` first, in its order; the
    others follow as before."""
    rank = {name: k for k, name in enumerate(LONGEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
