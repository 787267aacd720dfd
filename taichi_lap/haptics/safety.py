"""The force-safety filter every device force passes, once per servo tick.

Seed 002 §3.4 renders contact and pull forces at ~1 kHz on a Geomagic Touch; the
design's "Safety of the haptic path" asks that forces be clamped to the device's
nominal maximum continuous force, purged of NaN/inf, rate-limited, faded out when
the simulation snapshot is stale, and cut at once on a fault. Pure NumPy and
deterministic: the output depends only on the sequence of calls.
"""

from __future__ import annotations

import logging
import math

import numpy as np

log = logging.getLogger("taichi_lap.haptics")


def _positive(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(
            f"ForceSafety.{name}: a positive finite number was expected, found {value!r}"
        )
    return float(value)


class ForceSafety:
    """Filters commanded forces [N] into forces safe to send to a device.

    Each :meth:`filter` call, in order:

    1. a force with any NaN/inf component becomes zero (a partly finite vector has no
       meaningful direction); the first of a burst is logged as a warning;
    2. its magnitude is clamped to ``max_force`` [N];
    3. the change from the previous output is limited to ``max_rate * dt`` [N] in
       norm, the same for rising and falling forces; ``dt`` [s] is the time since the
       previous call capped at ``max_dt`` (default 2 ms, two 1 kHz ticks), so a
       stalled servo loop resumes as if one tick had passed instead of jumping; the
       first call after construction or :meth:`reset` (no previous tick) keeps zero;
    4. watchdog: once the snapshot is older than ``watchdog_timeout`` [s] the output
       magnitude is capped by an envelope falling linearly from the magnitude at the
       first stale tick to zero ``fade_time`` [s] after the snapshot went stale, and
       it never rises while stale; fresh snapshots ramp back in at ``max_rate``;
    5. after :meth:`fault` the output is zero until :meth:`reset`.

    The watchdog and the fault act after the rate limit, so neither is slowed by it.
    """

    def __init__(
        self,
        max_force: float,
        max_rate: float,
        *,
        watchdog_timeout: float = 0.100,
        fade_time: float = 0.050,
        max_dt: float = 0.002,
    ):
        self.max_force = _positive("max_force", max_force)  # [N]
        self.max_rate = _positive("max_rate", max_rate)  # [N/s]
        self.watchdog_timeout = _positive("watchdog_timeout", watchdog_timeout)  # [s]
        self.fade_time = _positive("fade_time", fade_time)  # [s]
        self.max_dt = _positive("max_dt", max_dt)  # [s]
        self.nonfinite_count = 0
        self._faulted = False
        self._reset_state()

    def _reset_state(self):
        self._output = np.zeros(3)
        self._last_time: float | None = None
        self._in_nonfinite_burst = False
        self._fade_from: float | None = None  # output magnitude [N] at the first stale tick

    @property
    def faulted(self) -> bool:
        """True from :meth:`fault` until :meth:`reset`."""
        return self._faulted

    @property
    def output(self) -> np.ndarray:
        """The last force returned [N]."""
        return self._output.copy()

    def fault(self):
        """Force zero output at once and latch it until :meth:`reset`."""
        self._faulted = True
        self._output = np.zeros(3)

    def reset(self):
        """Clear a fault; the output restarts from zero and ramps at ``max_rate``."""
        self._faulted = False
        self._reset_state()

    def filter(self, force, now: float, snapshot_time: float) -> np.ndarray:
        """The safe force [N] for this tick.

        ``force`` is the commanded 3-vector [N], ``now`` the tick time [s] and
        ``snapshot_time`` [s] the time of the simulation snapshot the force came from,
        on the same clock (``time.monotonic()``).
        """
        target = np.array(force, dtype=np.float64)
        if target.shape != (3,):
            raise ValueError(
                f"ForceSafety.filter: a force 3-vector [N] was expected, found shape {target.shape}"
            )
        dt = 0.0 if self._last_time is None else now - self._last_time
        self._last_time = now
        if self._faulted:
            self._output = np.zeros(3)
            return self._output.copy()
        target = self._finite(target)
        magnitude = float(np.linalg.norm(target))
        if magnitude > self.max_force:
            target *= self.max_force / magnitude
        step = self.max_rate * (min(max(dt, 0.0), self.max_dt) if math.isfinite(dt) else 0.0)
        delta = target - self._output
        change = float(np.linalg.norm(delta))
        if change > step:
            delta *= step / change
        out = self._output + delta
        out = self._watchdog(out, now - snapshot_time)
        self._output = out
        return out.copy()

    def _finite(self, target: np.ndarray) -> np.ndarray:
        if np.all(np.isfinite(target)):
            self._in_nonfinite_burst = False
            return target
        self.nonfinite_count += 1
        if not self._in_nonfinite_burst:
            log.warning(
                "non-finite force %s N replaced by zero (further non-finite forces "
                "are not logged until a finite one arrives)",
                target.tolist(),
            )
            self._in_nonfinite_burst = True
        return np.zeros(3)

    def _watchdog(self, out: np.ndarray, age: float) -> np.ndarray:
        """Cap ``out`` by the fade envelope when the snapshot is ``age`` [s] old."""
        if math.isfinite(age) and age <= self.watchdog_timeout:
            self._fade_from = None
            return out
        previous = float(np.linalg.norm(self._output))
        if self._fade_from is None:
            self._fade_from = previous
        gain = 0.0
        if math.isfinite(age):
            gain = min(max(1.0 - (age - self.watchdog_timeout) / self.fade_time, 0.0), 1.0)
        ceiling = min(previous, self._fade_from * gain)
        magnitude = float(np.linalg.norm(out))
        if magnitude > ceiling:
            out = out * (ceiling / magnitude) if ceiling > 0.0 else np.zeros(3)
        return out
