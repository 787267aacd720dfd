"""Backend start-up (taichi_lap.runtime)."""

import logging
import os
import re
import time

import pytest
import taichi as ti
from taichi.lang.exception import TaichiCompilationError

from taichi_lap import runtime


def test_a_stale_cache_lock_is_removed_and_a_fresh_one_kept(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("TI_OFFLINE_CACHE_FILE_PATH", str(tmp_path))
    lock = tmp_path / "ticache.lock"
    lock.write_bytes(b"")
    assert runtime.clear_stale_cache_lock() is None  # just taken: another process's
    assert lock.exists()
    old = time.time() - runtime.STALE_LOCK_SECONDS - 60
    os.utime(lock, (old, old))
    with caplog.at_level(logging.WARNING, logger="taichi_lap"):
        assert runtime.clear_stale_cache_lock() == lock
    assert not lock.exists()
    assert any("stale Taichi cache lock" in r.getMessage() for r in caplog.records)
    assert runtime.clear_stale_cache_lock() is None  # no lock: nothing to do


def test_a_compile_error_still_names_the_file_line_and_source():
    """The shortened source positions (runtime._shorten_source_positions) keep what a
    user needs to find a kernel's mistake."""

    @ti.kernel
    def broken() -> ti.i32:
        return undefined_name  # noqa: F821

    with pytest.raises(TaichiCompilationError) as error:
        broken()
    message = str(error.value)
    assert __file__ in message and re.search(r"line \d+, in broken", message)
    assert "return undefined_name" in message


def test_small_models_loop_serially_on_the_cpu():
    """On the CPU backend a model below SERIAL_BELOW particles runs its per-step loops
    serially (no thread-pool hand-off), a larger one in parallel; the tissue collision
    follows its model. (Runs are bit-identical either way: the reference trajectories,
    stored from parallel runs, hold for the serial ones.)"""
    from taichi_lap import scene as scene_mod
    from taichi_lap.session import Session

    assert runtime.serial_loops(runtime.SERIAL_BELOW - 1)
    assert not runtime.serial_loops(runtime.SERIAL_BELOW)
    with Session(scene_mod.load("rectum", {"scene.detail": 0.05}), progress=False) as session:
        assert session.model.serial and session.model.particle_count < runtime.SERIAL_BELOW
        assert session.solver.collision.serial
        model = session.model
        entries = 2 * model.distance_count + model.lra_count
        assert 0 < entries < runtime.SWEEP_SERIAL_BELOW and model.serial_sweeps
        model.distance_count += runtime.SWEEP_SERIAL_BELOW  # as if its truss were denser
        assert not model.serial_sweeps
