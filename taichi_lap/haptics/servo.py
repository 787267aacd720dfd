"""The 1 kHz haptic servo process (seed 002 §3.4; design notes: multi-rate loop, safety).

Taichi kernel launches hold the GIL, so the servo cannot be a thread of the
simulation: :class:`ServoProcess` runs it in a child process started with the
'spawn' method. Each tick, on absolute 1 ms deadlines, it

1. takes the newest scene snapshot (:class:`~taichi_lap.haptics.snapshot.SnapshotReader`),
2. reads the device pose and buttons,
3. runs the proxy (:class:`~taichi_lap.haptics.proxy.HapticProxy`): contact and pull force,
4. filters the force (:class:`~taichi_lap.haptics.safety.ForceSafety`; the watchdog
   watches the snapshot's timestamp: older than 100 ms fades to zero in 50 ms),
5. sends it to the device,
6. writes poses, forces and counters back (:class:`~taichi_lap.haptics.feedback.ServoFeedback`)
   and records the tick in the feedback ring: period, compute time, device pose,
   buttons and the force sent (the simulation appends these to a session record).

Timing: the process asks for SCHED_FIFO (priority 80) and warns once when refused;
it sleeps until ~300 µs before each deadline and busy-waits the rest; the garbage
collector is frozen and disabled in the loop; it can be pinned to a CPU. A stop
request, SIGTERM or any error zeroes the device force before anything else; Ctrl-C
is left to the simulation process, which stops the servo.
"""

from __future__ import annotations

import functools
import gc
import logging
import math
import multiprocessing
import os
import signal
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from taichi_lap.core.frames import turned_about_axis, twist
from taichi_lap.haptics.device import HapticDevice
from taichi_lap.haptics.feedback import ServoFeedback, ServoState, ToolFeedback
from taichi_lap.haptics.proxy import HapticProxy, ProxySettings, ProxyStatus
from taichi_lap.haptics.safety import ForceSafety
from taichi_lap.haptics.snapshot import SceneSnapshot

log = logging.getLogger("taichi_lap.haptics")


@dataclass(frozen=True)
class ServoSettings:
    """``period`` [s] between ticks; ``spin`` [s] busy-waited before each deadline;
    ``fifo_priority``: SCHED_FIFO priority asked for (None: do not ask); ``cpu``: pin
    the servo to this CPU (None: no pinning); ``max_rate`` [N/s], ``watchdog_timeout``
    and ``fade_time`` [s]: the force-safety filter; ``ticks``: ring length of the tick
    statistics; ``missed_period`` [s]: a period longer than this counts as missed."""

    period: float = 0.001
    spin: float = 0.0003
    fifo_priority: int | None = 80
    cpu: int | None = None
    max_rate: float = 100.0
    watchdog_timeout: float = 0.100
    fade_time: float = 0.050
    ticks: int = 65536
    missed_period: float = 0.002

    def __post_init__(self):
        for name in ("period", "max_rate", "watchdog_timeout", "fade_time", "missed_period"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"ServoSettings.{name}: a positive number was expected, found {value!r}"
                )
        if not (isinstance(self.spin, (int, float)) and 0 <= self.spin <= self.period):
            raise ValueError(
                f"ServoSettings.spin: a time [s] from 0 to the period was "
                f"expected, found {self.spin!r}"
            )


class ScriptedHapticDevice(HapticDevice):
    """A pure-Python device for tests and benchmarks: the stylus tip follows
    ``keyframes`` ``[(time [s], (x, y, z) [m]), ...]`` linearly from construction
    (cyclically with ``loop``), with a ``rotation`` (3×3) turned about its own z (the
    shaft) at ``roll_rate`` [rad/s]. ``fail_after`` [s] makes :meth:`pose` raise from
    then on, as a device fault would."""

    def __init__(
        self,
        keyframes=((0.0, (0.0, 0.0, 0.0)),),
        *,
        rotation=None,
        roll_rate: float = 0.0,
        max_force: float = 0.88,
        buttons: int = 0,
        loop: bool = False,
        fail_after: float | None = None,
    ):
        times = np.array([float(t) for t, _ in keyframes])
        self._tips = np.array([np.asarray(p, dtype=np.float64) for _, p in keyframes])
        if len(times) == 0 or self._tips.shape != (len(times), 3) or np.any(np.diff(times) < 0):
            raise ValueError(
                "ScriptedHapticDevice: keyframes [(time [s], (x, y, z) [m]), ...] "
                f"with non-decreasing times were expected, found {keyframes!r}"
            )
        self._times = times
        self._pose = np.eye(4)
        self._rotation = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
        self._roll_rate = float(roll_rate)
        self._max_force, self._buttons = float(max_force), int(buttons)
        self._loop, self._fail_after = loop and times[-1] > 0, fail_after
        self.force = np.zeros(3)  # the last force set [N]
        self._start = time.monotonic()

    @property
    def max_force(self) -> float:
        return self._max_force

    def pose(self) -> np.ndarray:
        t = time.monotonic() - self._start
        if self._fail_after is not None and t >= self._fail_after:
            raise RuntimeError(f"scripted device fault after {self._fail_after} s")
        self._pose[:3, :3] = turned_about_axis(self._rotation, self._roll_rate * t)
        if self._loop:
            t %= self._times[-1]
        for axis in range(3):
            self._pose[axis, 3] = np.interp(t, self._times, self._tips[:, axis])
        return self._pose.copy()

    def buttons(self) -> int:
        return self._buttons

    def set_force(self, force_newtons, *, snapshot_time: float | None = None):
        self.force = np.array(force_newtons, dtype=np.float64)

    def close(self):
        self.force = np.zeros(3)


def _realtime(settings: ServoSettings) -> bool:
    """Pin to ``settings.cpu`` and ask for SCHED_FIFO; whether FIFO was granted."""
    if settings.cpu is not None:
        os.sched_setaffinity(0, {settings.cpu})
    if settings.fifo_priority is None:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(settings.fifo_priority))
        return True
    except (AttributeError, OSError) as exc:
        log.warning(
            "SCHED_FIFO priority %d was refused (%s): the haptic servo runs at normal "
            "priority and may miss ticks beside the simulation",
            settings.fifo_priority,
            exc,
        )
        return False


def _sleep_until(deadline: float, spin: float):
    """Sleep until ``spin`` [s] before ``deadline`` (monotonic [s]), then busy-wait."""
    remaining = deadline - time.monotonic()
    if remaining > spin:
        time.sleep(remaining - spin)
    while time.monotonic() < deadline:
        pass


class _Servo:
    """The loop's state inside the servo process."""

    def __init__(
        self,
        snapshot: SceneSnapshot,
        device: HapticDevice,
        proxy: ProxySettings,
        settings: ServoSettings,
        feedback: ServoFeedback,
    ):
        self.reader = snapshot.reader()
        self.device, self.feedback, self.settings = device, feedback, settings
        self.proxy = HapticProxy(proxy)
        self.safety = ForceSafety(
            device.max_force,
            settings.max_rate,
            watchdog_timeout=settings.watchdog_timeout,
            fade_time=settings.fade_time,
        )
        self.tick = self.missed = self.fallbacks = self.failures = self.buttons = 0
        self.max_sent = 0.0
        self.haptic = np.eye(4)  # the last device pose [m]
        self.roll = 0.0  # the stylus's turn about its shaft since the first tick [rad]
        self.force = np.zeros(3)  # the last force sent [N]
        self.terminated = False  # set by SIGTERM

    def on_signal(self, signum, _frame):
        """SIGTERM (``Process.terminate``, or the parent's exit) stops the loop cleanly."""
        self.terminated = True

    def run(self, stop, ready):
        """Tick on absolute deadlines until ``stop`` is set; set ``ready`` after the
        first tick."""
        period, spin, late = self.settings.period, self.settings.spin, self.settings.missed_period
        deadline = time.monotonic()
        previous = deadline - period
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            while not (stop.is_set() or self.terminated):
                _sleep_until(deadline, spin)
                start = time.monotonic()
                qp = self.step(start)
                if self.tick == 1:
                    ready.set()
                self.missed += start - previous > late
                self.feedback.record_tick(
                    start - previous,
                    time.monotonic() - start,
                    qp,
                    clock=start,
                    tip=self.haptic[:3, 3],
                    direction=self.haptic[:3, 2],  # the tool frame's z: tip to handle
                    roll=self.roll,
                    buttons=self.buttons,
                    force=self.force,
                )
                previous = start
                deadline += period
                now = time.monotonic()
                if deadline < now:  # the tick overran the next deadline: restart the grid
                    deadline = now
        finally:
            gc.enable()
            gc.unfreeze()

    def step(self, now: float) -> float:
        """One tick (steps 1-6 of the module docstring); the QP time [s]."""
        self.reader.poll()
        scene = self.reader.scene
        haptic = self.device.pose()
        if self.tick:
            self.roll += twist(self.haptic[:3, :3], haptic[:3, :3])
        self.haptic = haptic
        self.buttons = buttons = self.device.buttons()
        result = self.proxy.step(haptic, scene)
        stamp = -math.inf if scene is None else scene.timestamp
        force = self.safety.filter(result.contact_force + result.pull_force, now, stamp)
        self.device.set_force(force, snapshot_time=stamp)
        self.force = force
        self.fallbacks += result.status == ProxyStatus.RELAXED
        self.failures += result.status == ProxyStatus.HELD
        self.max_sent = max(self.max_sent, float(np.linalg.norm(force)))
        graphic = np.array(haptic, dtype=np.float64)
        graphic[:3, 3] = result.graphic_position
        self.tick += 1
        self.write(
            haptic,
            graphic,
            buttons,
            force,
            result.contact_force,
            result.pull_force,
            result.contacts,
            int(result.status),
            -1 if scene is None else scene.sequence,
        )
        return result.qp_seconds

    def write(self, haptic, graphic, buttons, force, contact, pull, contacts, status, sequence):
        self.feedback.write(
            ToolFeedback(
                tick=self.tick,
                time=time.monotonic(),
                haptic_pose=haptic,
                graphic_pose=graphic,
                buttons=buttons,
                force=force,
                contact_force=contact,
                pull_force=pull,
                contacts=contacts,
                proxy_status=status,
                snapshot_sequence=sequence,
                missed_2ms=self.missed,
                qp_fallbacks=self.fallbacks,
                qp_failures=self.failures,
                max_force_sent=self.max_sent,
                roll=self.roll,
            )
        )

    def zero_force(self):
        """Stop force output: latch the safety filter, send zero, then record it."""
        self.safety.fault()
        self.device.set_force(np.zeros(3), snapshot_time=time.monotonic())
        self.force = zero = np.zeros(3)
        self.write(
            self.haptic, self.haptic, self.buttons, zero, zero, zero, 0, int(ProxyStatus.FREE), -1
        )


def _servo_main(
    snapshot_name: str,
    feedback_name: str,
    device_factory,
    proxy: ProxySettings,
    settings: ServoSettings,
    stop,
    ready,
):
    """Entry point of the servo process. Ctrl-C is left to the simulation process,
    which stops the servo through ``stop``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    feedback = ServoFeedback.attach(feedback_name)
    snapshot = device = servo = None
    try:
        feedback.fifo_granted = _realtime(settings)
        snapshot = SceneSnapshot.attach(snapshot_name)
        device = device_factory()
        servo = _Servo(snapshot, device, proxy, settings, feedback)
        signal.signal(signal.SIGTERM, servo.on_signal)
        feedback.set_state(ServoState.RUNNING)
        servo.run(stop, ready)
        servo.zero_force()
        feedback.set_state(ServoState.STOPPED)
    except BaseException as exc:
        if device is not None:  # force output stops before anything else
            try:
                if servo is not None:
                    servo.zero_force()
                else:
                    device.set_force(np.zeros(3), snapshot_time=time.monotonic())
            except BaseException as zero_exc:
                log.error("zero force after a servo error failed: %s", zero_exc)
        feedback.set_state(ServoState.FAULTED, f"{type(exc).__name__}: {exc}")
        log.error("haptic servo stopped: %s: %s", type(exc).__name__, exc)
    finally:
        if device is not None:
            device.close()
        for region in (snapshot, feedback):
            if region is not None:
                region.close()


class ServoProcess:
    """Runs the servo for one device in a child process.

    ``snapshot_name``: the :class:`SceneSnapshot` the simulation publishes to;
    ``device``: a picklable callable returning the :class:`HapticDevice`, called in the
    child (a class, or ``functools.partial(OpenHapticsDevice, name, library=...)``).
    :meth:`start` returns once the device is open and the first tick written;
    :attr:`feedback` gives poses, forces and tick statistics; :meth:`stop` (or
    leaving a ``with`` block) stops it and zeroes the force; :meth:`close` also
    unlinks the feedback region.
    """

    def __init__(
        self,
        snapshot_name: str,
        device: Callable[[], HapticDevice],
        proxy: ProxySettings,
        settings: ServoSettings = ServoSettings(),
    ):
        self.settings = settings
        self.feedback = ServoFeedback.create(ticks=settings.ticks)
        context = multiprocessing.get_context("spawn")
        self._stop, self._ready = context.Event(), context.Event()
        self._process = context.Process(
            target=_servo_main,
            name="taichi-lap-servo",
            daemon=True,
            args=(
                snapshot_name,
                self.feedback.name,
                device,
                proxy,
                settings,
                self._stop,
                self._ready,
            ),
        )

    @property
    def exitcode(self) -> int | None:
        return self._process.exitcode

    def is_alive(self) -> bool:
        return self._process.is_alive()

    def start(self, timeout: float = 30.0) -> "ServoProcess":
        """Start the child; raise RuntimeError naming its error if it fails to start."""
        self._process.start()
        deadline = time.monotonic() + timeout
        while not self._ready.wait(0.02):
            if not self._process.is_alive() or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(
                    "the haptic servo process did not start: "
                    + (self.feedback.message or f"no ready signal in {timeout} s")
                )
        return self

    def stop(self, timeout: float = 5.0):
        """Ask the loop to stop (it zeroes the force and closes the device) and wait."""
        self._stop.set()
        if self._process.pid is None:
            return
        for action in (self._process.terminate, self._process.kill):
            self._process.join(timeout)
            if not self._process.is_alive():
                return
            log.error(
                "the haptic servo process did not stop within %s s; %s", timeout, action.__name__
            )
            action()
        self._process.join(timeout)

    def close(self):
        """Stop, then unlink the feedback region."""
        self.stop()
        self.feedback.close()

    def __enter__(self) -> "ServoProcess":
        return self.start() if self._process.pid is None else self

    def __exit__(self, *exc):
        self.close()


def scripted_device(keyframes, **kwargs) -> Callable[[], ScriptedHapticDevice]:
    """A picklable factory of :class:`ScriptedHapticDevice` for :class:`ServoProcess`."""
    return functools.partial(ScriptedHapticDevice, tuple(keyframes), **kwargs)
