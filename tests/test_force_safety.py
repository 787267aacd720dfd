"""The force-safety filter: clamp, non-finite guard, rate limit, watchdog fade, fault latch."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from taichi_lap.haptics import ForceSafety

TICK = 0.001  # [s], 1 kHz servo


def run(safety: ForceSafety, forces, t0: float = 0.0, snapshot_times=None) -> np.ndarray:
    """Filter one force per tick from ``t0``; snapshots are fresh unless given."""
    out = []
    for k, force in enumerate(forces):
        now = t0 + k * TICK
        out.append(safety.filter(force, now, now if snapshot_times is None else snapshot_times[k]))
    return np.array(out)


def test_clamps_magnitude_to_max_force_keeping_direction():
    safety = ForceSafety(max_force=1.0, max_rate=1e6)
    out = run(safety, [[3.0, 4.0, 0.0]] * 3)
    np.testing.assert_allclose(out[-1], [0.6, 0.8, 0.0])
    np.testing.assert_allclose(run(safety, [[0.0, -0.5, 0.0]], t0=1.0)[-1], [0.0, -0.5, 0.0])


def test_non_finite_force_becomes_zero_and_logs_once_per_burst(caplog):
    safety = ForceSafety(max_force=1.0, max_rate=1e6)
    nan, inf = float("nan"), float("inf")
    forces = [[0.5, 0, 0], [nan, 0.2, 0], [0, inf, 0], [nan, nan, nan], [0.5, 0, 0], [0, 0, -inf]]
    with caplog.at_level(logging.WARNING, logger="taichi_lap.haptics"):
        out = run(safety, forces)
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[[1, 2, 3, 5]], np.zeros((4, 3)))
    np.testing.assert_allclose(out[4], [0.5, 0, 0])
    warnings = [r for r in caplog.records if "non-finite force" in r.getMessage()]
    assert len(warnings) == 2 and safety.nonfinite_count == 4


def test_rate_limit_bounds_every_step_rising_and_falling_alike():
    safety = ForceSafety(max_force=2.0, max_rate=100.0)
    out = run(safety, [[0.0, 0, 0]] + [[1.0, 0, 0]] * 30 + [[0.0, 0, 0]] * 30)
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert steps.max() <= 100.0 * TICK + 1e-12
    rise = np.argmax(out[1:, 0] >= 1.0 - 1e-12)
    fall = np.argmax(out[31:, 0] <= 1e-12)
    assert rise == fall == 9  # 1 N at 0.1 N per tick, up and down


def test_stall_does_not_let_force_jump():
    safety = ForceSafety(max_force=2.0, max_rate=100.0, max_dt=0.002)
    run(safety, [[0.0, 0, 0]] * 5)
    out = safety.filter([1.0, 0, 0], now=0.5, snapshot_time=0.5)  # 0.5 s since the last tick
    assert np.linalg.norm(out) == pytest.approx(100.0 * 0.002)
    backwards = safety.filter([1.0, 0, 0], now=0.4, snapshot_time=0.4)  # clock went back
    np.testing.assert_array_equal(backwards, out)


def test_watchdog_fades_stale_snapshot_to_zero_within_fade_time():
    safety = ForceSafety(max_force=1.0, max_rate=1e6, watchdog_timeout=0.100, fade_time=0.050)
    snapshot = 0.0
    ticks = 200
    # the commanded force even rises while the snapshot is stale: the output must not
    forces = [[0.8 + 0.001 * k, 0, 0] for k in range(ticks)]
    out = run(safety, forces, t0=0.0, snapshot_times=[snapshot] * ticks)
    magnitude = np.linalg.norm(out, axis=1)
    age = np.arange(ticks) * TICK
    fresh = (age > 0.0) & (age <= 0.100)  # the first call only starts the clock
    np.testing.assert_allclose(magnitude[fresh], 0.8 + age[fresh])
    stale = magnitude[age > 0.100]
    assert np.all(np.diff(stale) <= 1e-12)
    assert np.all(magnitude[age >= 0.150 - 1e-9] <= 1e-12)  # 0.1 + 0.05 rounds up
    assert np.all(magnitude[age >= 0.151] == 0.0)
    halfway = np.argmin(np.abs(age - 0.125))
    assert magnitude[halfway] == pytest.approx(0.5 * magnitude[100], rel=0.05)  # linear


def test_fresh_snapshot_after_watchdog_ramps_back_at_max_rate():
    safety = ForceSafety(max_force=1.0, max_rate=100.0)
    run(safety, [[0.5, 0, 0]] * 10)
    stale = run(safety, [[0.5, 0, 0]] * 200, t0=0.010, snapshot_times=[0.010] * 200)
    assert np.all(stale[-10:] == 0.0)
    fresh = run(safety, [[0.5, 0, 0]] * 3, t0=0.210)
    np.testing.assert_allclose(fresh[:, 0], [0.1, 0.2, 0.3])


def test_fault_zeroes_at_once_and_latches_until_reset():
    safety = ForceSafety(max_force=1.0, max_rate=100.0)
    run(safety, [[0.0, 0.9, 0]] * 20)
    safety.fault()
    assert safety.faulted
    np.testing.assert_array_equal(safety.output, np.zeros(3))
    np.testing.assert_array_equal(run(safety, [[0.0, 0.9, 0]] * 20, t0=0.02), np.zeros((20, 3)))
    safety.reset()
    after = run(safety, [[0.0, 0.9, 0]] * 2, t0=0.05)
    np.testing.assert_allclose(after[:, 1], [0.0, 0.1])  # restarts from zero


def test_filter_is_deterministic():
    rng = np.random.default_rng(7)
    forces = rng.normal(scale=2.0, size=(300, 3))
    snapshots = np.repeat(np.arange(0, 0.3, 0.05), 50)
    a = run(ForceSafety(1.0, 50.0), forces, snapshot_times=snapshots)
    b = run(ForceSafety(1.0, 50.0), forces, snapshot_times=snapshots)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"max_force": 0.0}, "max_force"),
        ({"max_rate": float("inf")}, "max_rate"),
        ({"fade_time": -1.0}, "fade_time"),
    ],
)
def test_rejects_non_positive_settings(kwargs, name):
    settings = {"max_force": 1.0, "max_rate": 10.0, **kwargs}
    with pytest.raises(ValueError, match=f"ForceSafety.{name}: a positive finite number"):
        ForceSafety(**settings)


def test_rejects_force_that_is_not_a_3_vector():
    with pytest.raises(ValueError, match="force 3-vector"):
        ForceSafety(1.0, 10.0).filter([1.0, 2.0], now=0.0, snapshot_time=0.0)
