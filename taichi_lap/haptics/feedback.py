"""The servo's feedback region (servo → simulation, 1 kHz; seed 002 §3.4): haptic and
graphical tool poses, buttons, forces, counters, the servo state and a ring of
ticks (times, device pose, buttons, force sent), behind the two-slot seqlock of
:mod:`taichi_lap.haptics.snapshot`."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from taichi_lap.haptics.snapshot import (
    FEEDBACK_MAGIC,
    HEADER_WORDS,
    MESSAGE_BYTES,
    _capacity,
    _Region,
)


class ServoState(enum.IntEnum):
    """Life cycle of the servo process, as written in the feedback region."""

    STARTING = 0
    RUNNING = 1
    STOPPED = 2
    FAULTED = 3


@dataclass(frozen=True)
class ToolFeedback:
    """One servo tick as the simulation reads it back.

    ``haptic_pose`` and ``graphic_pose``: 4×4 row-major transforms [m] of the device
    stylus and of the non-penetrating proxy (seed 002 §3.4: q_h and q_g); ``force``
    [N] is what the device was sent (after the safety filter), ``contact_force`` and
    ``pull_force`` [N] what the proxy and the grasp asked for; the tissue receives
    ``-contact_force``. ``roll`` [rad]: the stylus's turn about its shaft since the
    first tick (the twists between its readings summed, unwrapped). Counters run
    since the servo started.
    """

    tick: int
    time: float
    haptic_pose: np.ndarray
    graphic_pose: np.ndarray
    buttons: int
    force: np.ndarray
    contact_force: np.ndarray
    pull_force: np.ndarray
    contacts: int
    proxy_status: int
    snapshot_sequence: int
    missed_2ms: int
    qp_fallbacks: int
    qp_failures: int
    max_force_sent: float
    roll: float = 0.0


_INT_FIELDS = (
    "tick",
    "buttons",
    "contacts",
    "proxy_status",
    "snapshot_sequence",
    "missed_2ms",
    "qp_fallbacks",
    "qp_failures",
)
_FLOAT_FIELDS = ("time", "max_force_sent", "roll")
_ARRAY_FIELDS = (
    ("haptic_pose", (4, 4)),
    ("graphic_pose", (4, 4)),
    ("force", (3,)),
    ("contact_force", (3,)),
    ("pull_force", (3,)),
)
_FEEDBACK_FIELDS = [
    ("ints", np.int64, (len(_INT_FIELDS),)),
    ("floats", np.float64, (len(_FLOAT_FIELDS),)),
] + [(name, np.float64, shape) for name, shape in _ARRAY_FIELDS]
CAPACITY_WORD, STATE_WORD, FIFO_WORD, RING_WORD, MESSAGE_WORD = 2, 3, 4, 5, 6


RING_TIMES = ("period", "compute", "qp")
RING_INPUT = ("clock", "tip", "direction", "roll", "buttons", "force")


def _ring_fields(ticks: int):
    return [(name, np.float64, (ticks,)) for name in RING_TIMES + ("clock",)] + [
        ("tip", np.float64, (ticks, 3)),
        ("direction", np.float64, (ticks, 3)),
        ("roll", np.float64, (ticks,)),
        ("buttons", np.int64, (ticks,)),
        ("force", np.float64, (ticks, 3)),
        ("message", np.uint8, (MESSAGE_BYTES,)),
    ]


class ServoFeedback:
    """The feedback region (one writer: the servo process).

    Tool state goes through two seqlock slots (:meth:`write`, :meth:`read`); every
    tick's period, compute and QP times [s], clock [s], device tip [m], shaft
    direction and roll [rad], buttons and force sent [N] go into a ring of ``ticks`` entries
    (:meth:`record_tick`; read with :meth:`tick_history` and :meth:`ticks_since`); the
    servo state, whether SCHED_FIFO was granted and a fault message are single words.
    """

    def __init__(self, region: _Region):
        self._region, self._header = region, region.header
        self.ticks_capacity = int(region.header[CAPACITY_WORD])

    @classmethod
    def create(cls, *, ticks: int = 65536, name: str | None = None) -> "ServoFeedback":
        """A new region whose tick ring holds the last ``ticks`` ticks."""
        ticks = _capacity("ServoFeedback.create: ticks", ticks)
        region = _Region.create(name, FEEDBACK_MAGIC, _FEEDBACK_FIELDS, _ring_fields(ticks))
        region.header[2:] = ticks, ServoState.STARTING, -1, 0, 0, 0
        return cls(region)

    @classmethod
    def attach(cls, name: str) -> "ServoFeedback":
        shm = shared_memory.SharedMemory(name=name)
        ticks = int(np.ndarray((HEADER_WORDS,), np.int64, buffer=shm.buf)[CAPACITY_WORD])
        return cls(_Region(shm, FEEDBACK_MAGIC, _FEEDBACK_FIELDS, _ring_fields(ticks), False))

    @property
    def name(self) -> str:
        return self._region.shm.name

    def write(self, tool: ToolFeedback):
        """Publish one tick's tool state."""
        slot = self._region.begin()
        slot["ints"][:] = [getattr(tool, name) for name in _INT_FIELDS]
        slot["floats"][:] = [getattr(tool, name) for name in _FLOAT_FIELDS]
        for name, _ in _ARRAY_FIELDS:
            slot[name][:] = getattr(tool, name)
        self._region.end()

    def read(self) -> ToolFeedback | None:
        """The newest tick's tool state, or None before the first tick."""
        out = {}

        def copy(slot):
            out.update({name: view.copy() for name, view in slot.items()})

        if self._region.read(copy) <= 0:
            return None
        ints, floats = out.pop("ints"), out.pop("floats")
        return ToolFeedback(
            **{k: int(v) for k, v in zip(_INT_FIELDS, ints)},
            **{k: float(v) for k, v in zip(_FLOAT_FIELDS, floats)},
            **out,
        )

    def record_tick(
        self,
        period: float,
        compute: float,
        qp: float,
        *,
        clock: float,
        tip,
        direction,
        buttons: int,
        force,
        roll: float = 0.0,
    ):
        """Append one tick to the ring: its period, compute time and QP time [s], its
        ``clock`` [s] (``time.monotonic()``), the device's ``tip`` [m], shaft
        ``direction`` and ``roll`` [rad], ``buttons`` and the ``force`` sent [N]. The
        count is published after the entry, so a reader never sees a half-written
        tick."""
        count = int(self._header[RING_WORD])
        i = count % self.ticks_capacity
        extra = self._region.extra
        extra["period"][i], extra["compute"][i], extra["qp"][i] = period, compute, qp
        extra["clock"][i], extra["buttons"][i], extra["roll"][i] = clock, buttons, roll
        extra["tip"][i], extra["direction"][i], extra["force"][i] = tip, direction, force
        self._header[RING_WORD] = count + 1

    def _ring(self, names, begin: int, count: int) -> dict[str, np.ndarray]:
        order = np.arange(begin, count) % self.ticks_capacity
        return {k: self._region.extra[k][order] for k in names}

    def tick_history(self) -> dict[str, np.ndarray]:
        """The ring's ``period``, ``compute`` and ``qp`` times [s], oldest first, and
        ``count``: ticks recorded in all (the ring keeps the last ``ticks``)."""
        count = int(self._header[RING_WORD])
        out = self._ring(RING_TIMES, count - min(count, self.ticks_capacity), count)
        out["count"] = count
        return out

    def ticks_since(self, seen: int) -> tuple[dict[str, np.ndarray], int, int]:
        """The device input of the ticks after the first ``seen`` (``clock``, ``tip``,
        ``direction``, ``roll``, ``buttons``, ``force``, oldest first), the new count, and how
        many of those ticks the ring no longer holds (or the servo overwrote while they
        were read)."""
        count = int(self._header[RING_WORD])
        begin = max(seen, count - self.ticks_capacity)
        ticks = self._ring(RING_INPUT, begin, count)
        # the servo kept ticking while they were copied: drop the oldest it wrote over
        overwritten = max(int(self._header[RING_WORD]) - self.ticks_capacity - begin, 0)
        if overwritten:
            ticks = {name: values[overwritten:] for name, values in ticks.items()}
        return ticks, count, begin + overwritten - seen

    @property
    def state(self) -> ServoState:
        return ServoState(int(self._header[STATE_WORD]))

    @property
    def fifo_granted(self) -> bool | None:
        """Whether SCHED_FIFO was granted to the servo; None until it asked."""
        word = int(self._header[FIFO_WORD])
        return None if word < 0 else bool(word)

    @fifo_granted.setter
    def fifo_granted(self, granted: bool):
        self._header[FIFO_WORD] = int(granted)

    @property
    def message(self) -> str:
        """Why the servo faulted ("" otherwise)."""
        n = int(self._header[MESSAGE_WORD])
        return bytes(self._region.extra["message"][:n]).decode(errors="replace")

    def set_state(self, state: ServoState, message: str = ""):
        """Record the servo state, the message first (truncated to fit)."""
        data = message.encode()[:MESSAGE_BYTES]
        self._region.extra["message"][: len(data)] = np.frombuffer(data, np.uint8)
        self._header[MESSAGE_WORD] = len(data)
        self._header[STATE_WORD] = int(state)

    def close(self):
        """Detach; the creator also unlinks the region."""
        if self._region is not None:
            self._header = None
            self._region.close()
            self._region = None
