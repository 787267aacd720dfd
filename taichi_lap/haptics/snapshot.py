"""Shared memory between the simulation and the haptic servo process (seed 002 §3.4).

Taichi kernel launches hold the GIL, so the 1 kHz servo runs in its own process.
Two regions of :mod:`multiprocessing.shared_memory` connect them:

* :class:`SceneSnapshot` (simulation → servo, ≥ 30 Hz): the surface cluster spheres,
  the surface particles grouped by cluster, the grasped tet edges, the scene tool's
  tip while tissue pushes it (the coupling, :mod:`taichi_lap.haptics.bridge`), a
  ``time.monotonic()`` stamp [s] and a sequence number;
* :class:`~taichi_lap.haptics.feedback.ServoFeedback` (servo → simulation, 1 kHz): haptic and graphical tool
  poses, buttons, forces, counters, the servo state and a ring of per-tick times.

Each region holds two slots behind seqlock version counters: the writer makes a
slot's version odd, copies, then makes it even (``2 * sequence``); a reader copies
the newest even slot and retries when its version changed during the copy. With
two slots a writer preempted mid-copy leaves the previous snapshot whole, so the
reader never spins on it. One writer per region. Arrays are NumPy views over the
shared buffer: nothing is pickled after creation. Stores become visible in program
order on x86-64 (total store order), which the version protocol relies on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

ALIGN = 64  # [bytes] every array starts on its own cache line
READ_RETRIES = 1000  # torn reads tolerated in one read before giving up for this tick
SCENE_MAGIC, FEEDBACK_MAGIC, LAYOUT_VERSION = 0x5441_4C41_5053_4E50, 0x5441_4C41_5046_4442, 4
HEADER_WORDS = 8
MESSAGE_BYTES = 512
SUCCESSOR_WORD = 5  # scene header: bytes of the successor region's name (0: none)
SUCCESSOR_BYTES = 256
GROWTH = 1.5  # a moved snapshot's capacities: this times the rows that did not fit


class SnapshotCapacityError(ValueError):
    """More clusters, particles or grasp edges than the capacity given at creation."""


def _layout(fields, offset: int) -> tuple[dict, int]:
    """Byte offsets of ``(name, dtype, shape)`` fields from ``offset``, each aligned."""
    out = {}
    for name, dtype, shape in fields:
        offset = -(-offset // ALIGN) * ALIGN
        out[name] = (offset, np.dtype(dtype), shape)
        offset += np.dtype(dtype).itemsize * int(np.prod(shape))
    return out, offset


def _views(buf, layout: dict) -> dict[str, np.ndarray]:
    return {
        name: np.ndarray(shape, dtype, buffer=buf, offset=off)
        for name, (off, dtype, shape) in layout.items()
    }


# The scene arrays: shared dtype, row shape, which count sizes them (1 clusters,
# 2 particles, 3 grasp edges), extra rows, and the dtype of the servo's copy.
_SCENE_ARRAYS = {
    "cluster_center": (np.float32, (3,), 1, 0, np.float64),
    "cluster_radius": (np.float32, (), 1, 0, np.float64),
    "cluster_start": (np.int32, (), 1, 1, np.int64),
    "particle_position": (np.float32, (3,), 2, 0, np.float32),
    "particle_radius": (np.float32, (), 2, 0, np.float32),
    "grasp_local": (np.float32, (3,), 3, 0, np.float64),
    "grasp_neighbor": (np.float32, (3,), 3, 0, np.float64),
    "grasp_rest": (np.float32, (), 3, 0, np.float64),
}


def _scene_fields(counts, private: bool = False):
    """``(name, dtype, shape)`` of a scene slot (``counts``: 0, clusters, particles,
    grasp edges), or of the servo's private copy. ``coupling``: the coupled tool's tip
    [m] and 1, or zeros when no tissue pushes the tool."""
    fixed = [("counts", np.int64, (4,)), ("timestamp", np.float64, (1,))]
    return (
        fixed
        + [("coupling", np.float64, (4,))]
        + [
            (name, copy if private else shared, (counts[i] + extra,) + row)
            for name, (shared, row, i, extra, copy) in _SCENE_ARRAYS.items()
        ]
    )


class _Region:
    """A shared-memory block: an int64 header, two slot versions, two slots of
    fields, and unslotted ``extra`` fields (rings, messages)."""

    def __init__(self, shm, magic: int, slot_fields, extra_fields, owner: bool):
        self.shm, self.owner = shm, owner
        self.header = np.ndarray((HEADER_WORDS,), np.int64, buffer=shm.buf)
        if owner:
            self.header[:2] = magic, LAYOUT_VERSION
        elif self.header[0] != magic or self.header[1] != LAYOUT_VERSION:
            found = int(self.header[0])
            self.header = None
            shm.close()
            raise ValueError(
                f"shared memory {shm.name!r}: a taichi-lap region of layout "
                f"{LAYOUT_VERSION} was expected, found magic {found:#x}"
            )
        self.versions = np.ndarray((2,), np.uint64, buffer=shm.buf, offset=ALIGN)
        first, second, extra, _ = self.layout(slot_fields, extra_fields)
        self.slots = (_views(shm.buf, first), _views(shm.buf, second))
        self.extra = _views(shm.buf, extra)
        self._next = int(self.versions.max()) // 2  # sequence number of the next write

    @staticmethod
    def layout(slot_fields, extra_fields):
        """Layouts of both slots and the extra fields, and the total size [bytes]."""
        first, end = _layout(slot_fields, 2 * ALIGN)
        second, end = _layout(slot_fields, end)
        extra, end = _layout(extra_fields, end)
        return first, second, extra, end

    @classmethod
    def create(cls, name, magic: int, slot_fields, extra_fields) -> "_Region":
        size = cls.layout(slot_fields, extra_fields)[3]
        shm = shared_memory.SharedMemory(name=name, create=True, size=size)
        return cls(shm, magic, slot_fields, extra_fields, True)

    def begin(self) -> dict[str, np.ndarray]:
        """Mark the next slot as being written (odd version) and return its views."""
        seq = self._next
        self.versions[seq & 1] = 2 * seq + 1
        return self.slots[seq & 1]

    def end(self) -> int:
        """Publish the slot :meth:`begin` returned; its sequence number (from 1)."""
        seq = self._next
        self.versions[seq & 1] = 2 * seq + 2
        self._next = seq + 1
        return seq + 1

    def newest(self) -> int:
        """The version of the newest complete slot (0 when none)."""
        v0, v1 = int(self.versions[0]), int(self.versions[1])
        return max(0 if v0 & 1 else v0, 0 if v1 & 1 else v1)

    def read(self, copy) -> int:
        """``copy(slot)`` from the newest complete slot until no write overlapped it;
        the version read, 0 when nothing was published, -1 after :data:`READ_RETRIES`
        torn reads."""
        for _ in range(READ_RETRIES):
            version = self.newest()
            if version == 0:
                return 0
            slot = (version // 2 - 1) & 1
            copy(self.slots[slot])
            if int(self.versions[slot]) == version:
                return version
        return -1

    def close(self):
        self.header = self.versions = self.slots = self.extra = None  # release the views
        self.shm.close()
        if self.owner:
            self.shm.unlink()


def _capacity(name: str, value) -> int:
    if not (isinstance(value, (int, np.integer)) and value >= 1):
        raise ValueError(f"{name}: a capacity of at least 1 was expected, found {value!r}")
    return int(value)


def _rows(what: str, values, count: int, row: tuple, capacity: int, dtype) -> np.ndarray:
    """``values`` as ``dtype`` rows of shape ``row``, ``count`` of them (-1: any)."""
    array = np.asarray(values, dtype=dtype)
    if array.ndim != 1 + len(row) or array.shape[1:] != row or (count >= 0 and len(array) != count):
        dims = [str(count) if count >= 0 else "n"] + [str(s) for s in row]
        expected = f"({', '.join(dims)}{',' if len(dims) == 1 else ''})"
        raise ValueError(f"{what}: an array of shape {expected} was expected, found {array.shape}")
    if len(array) > capacity:
        raise SnapshotCapacityError(
            f"{what}: {len(array)} rows exceed the capacity of "
            f"{capacity} given when the snapshot was created"
        )
    return array


_SUCCESSOR_FIELDS = (("successor", np.uint8, (SUCCESSOR_BYTES,)),)
"""The scene region's unslotted field: the name of the region it moved to."""


def _scene_region(name: str | None, counts: tuple) -> _Region:
    """A new scene region (``counts``: 0, clusters, particles, grasp edges)."""
    region = _Region.create(name, SCENE_MAGIC, _scene_fields(counts), _SUCCESSOR_FIELDS)
    region.header[2:5] = counts[1:]
    return region


def _attached_scene_region(name: str) -> _Region:
    """The scene region another process created under ``name``."""
    shm = shared_memory.SharedMemory(name=name)
    counts = (0,) + tuple(int(v) for v in np.ndarray((5,), np.int64, buffer=shm.buf)[2:5])
    return _Region(shm, SCENE_MAGIC, _scene_fields(counts), _SUCCESSOR_FIELDS, False)


@dataclass(frozen=True)
class HapticScene:
    """What the servo collides against, as read from one snapshot.

    Cluster ``c`` is a sphere ``cluster_center[c]`` [m], ``cluster_radius[c]`` [m]
    bounding the spheres of its particles ``cluster_start[c]:cluster_start[c+1]`` in
    ``particle_position`` [m] (radii ``particle_radius`` [m]). Grasp edge ``e`` joins
    a grasped particle at ``grasp_local[e]`` (tool frame [m]) to its tet neighbour at
    ``grasp_neighbor[e]`` (scene [m]) of rest length ``grasp_rest[e]`` [m].
    ``coupling_tip`` [m]: where the simulation holds the tool while tissue pushes it
    (the proxy is then coupled to it), else None.
    """

    sequence: int
    timestamp: float
    cluster_center: np.ndarray
    cluster_radius: np.ndarray
    cluster_start: np.ndarray
    particle_position: np.ndarray
    particle_radius: np.ndarray
    grasp_local: np.ndarray
    grasp_neighbor: np.ndarray
    grasp_rest: np.ndarray
    coupling_tip: np.ndarray | None = None


class SceneSnapshot:
    """The simulation's side of the scene region; also what the servo attaches to.

    ``SceneSnapshot.create(clusters=, particles=, grasp_edges=)`` allocates for those
    capacities; the servo process calls ``SceneSnapshot.attach(name)`` and reads with
    :meth:`reader`. The creator's :meth:`close` unlinks the block.

    A surface that outgrows the capacities (a wound exposes particles from inside)
    moves the snapshot (:meth:`reserve`): the creator makes a larger region, carries
    its sequence numbers on and writes the new region's name into the old one's
    header; the attached side follows at its next :meth:`follow` (the reader's
    poll). The creator keeps the regions it left until :meth:`close`, so a servo
    that has not followed yet still finds each one.
    """

    def __init__(self, region: _Region):
        self._region = region
        self._retired: list[_Region] = []  # regions moved from (creator only)
        self._take_capacities()

    def _take_capacities(self):
        self._capacities = (0,) + tuple(int(v) for v in self._region.header[2:5])  # by count
        self.capacity = dict(zip(("clusters", "particles", "grasp_edges"), self._capacities[1:]))

    @classmethod
    def create(
        cls, *, clusters: int, particles: int, grasp_edges: int = 1024, name: str | None = None
    ) -> "SceneSnapshot":
        """A new region for at most ``clusters`` spheres, ``particles`` surface
        particles and ``grasp_edges`` grasped tet edges."""
        counts = (
            0,
            _capacity("SceneSnapshot.create: clusters", clusters),
            _capacity("SceneSnapshot.create: particles", particles),
            _capacity("SceneSnapshot.create: grasp_edges", grasp_edges),
        )
        return cls(_scene_region(name, counts))

    @classmethod
    def attach(cls, name: str) -> "SceneSnapshot":
        """The region another process created under ``name``."""
        return cls(_attached_scene_region(name))

    def reserve(self, *, clusters: int = 0, particles: int = 0, grasp_edges: int = 0) -> bool:
        """Make room for that many rows (creator only): when one exceeds its capacity,
        move to a new region with :data:`GROWTH` times the rows that did not fit (the
        others keep theirs). True when the snapshot moved; the next :meth:`publish`
        writes to the new region."""
        wanted = (0, int(clusters), int(particles), int(grasp_edges))
        if all(w <= c for w, c in zip(wanted, self._capacities)):
            return False
        counts = tuple(
            c if w <= c else math.ceil(GROWTH * w) for w, c in zip(wanted, self._capacities)
        )
        old, region = self._region, _scene_region(None, counts)
        region._next = old._next  # sequence numbers go on: the reader compares versions
        name = region.shm.name.encode()
        old.extra["successor"][: len(name)] = np.frombuffer(name, np.uint8)
        old.header[SUCCESSOR_WORD] = len(name)  # after the name (stores stay in order)
        self._retired.append(old)
        self._region = region
        self._take_capacities()
        return True

    def follow(self):
        """Attached side: move to the region the creator moved to, through every move
        since (one header load when there was none; the creator's region never has a
        successor)."""
        while self._region.header[SUCCESSOR_WORD]:
            old = self._region
            name = bytes(old.extra["successor"][: int(old.header[SUCCESSOR_WORD])]).decode()
            self._region = _attached_scene_region(name)
            old.close()
            self._take_capacities()

    @property
    def name(self) -> str:
        return self._region.shm.name

    def publish(
        self,
        cluster_center,
        cluster_radius,
        cluster_start,
        particle_position,
        particle_radius,
        *,
        grasp_local=None,
        grasp_neighbor=None,
        grasp_rest=None,
        coupling_tip=None,
        timestamp: float | None = None,
    ) -> int:
        """Write one snapshot; return its sequence number (1, 2, ...).

        ``cluster_center`` (C, 3) [m], ``cluster_radius`` (C,) [m], ``cluster_start``
        (C + 1,) ranges into ``particle_position`` (P, 3) [m]; ``particle_radius`` [m]
        is one value or (P,); grasp edges and ``coupling_tip`` (3,) [m] as in
        :class:`HapticScene` (default none);
        ``timestamp`` [s] defaults to ``time.monotonic()`` now. Raises
        :class:`SnapshotCapacityError` beyond the capacities given at creation.
        """
        no_grasp = np.zeros((0, 3))
        grasp_rest = no_grasp[:, 0] if grasp_rest is None else grasp_rest
        given = dict(
            cluster_center=cluster_center,
            cluster_radius=cluster_radius,
            cluster_start=cluster_start,
            particle_position=particle_position,
            particle_radius=particle_radius,
            grasp_local=no_grasp if grasp_local is None else grasp_local,
            grasp_neighbor=no_grasp if grasp_neighbor is None else grasp_neighbor,
            grasp_rest=grasp_rest,
        )
        counts, arrays = [0, -1, -1, -1], {}
        for name, (dtype, row, i, extra, _) in _SCENE_ARRAYS.items():
            values = given[name]
            if name == "particle_radius" and np.ndim(values) == 0:
                values = np.full(counts[2], values)
            arrays[name] = _rows(
                f"publish: {name}",
                values,
                counts[i] + extra if counts[i] >= 0 else -1,
                row,
                self._capacities[i] + extra,
                dtype,
            )
            counts[i] = len(arrays[name]) - extra
        coupling = np.zeros(4)
        if coupling_tip is not None:
            coupling[:3] = _rows("publish: coupling_tip", coupling_tip, 3, (), 3, np.float64)
            coupling[3] = 1.0
        start = arrays["cluster_start"]
        if start[0] != 0 or start[-1] != counts[2] or np.any(np.diff(start) < 0):
            raise ValueError(
                f"publish: cluster_start: non-decreasing offsets from 0 to the "
                f"{counts[2]} particles were expected, found {start[0]}..{start[-1]}"
            )
        region = self._region
        slot = region.begin()
        slot["counts"][:] = region._next + 1, counts[1], counts[2], counts[3]
        slot["timestamp"][0] = time.monotonic() if timestamp is None else float(timestamp)
        slot["coupling"][:] = coupling
        for name, values in arrays.items():
            slot[name][: len(values)] = values
        return region.end()

    def reader(self) -> "SnapshotReader":
        return SnapshotReader(self)

    def close(self):
        """Detach; the creator also unlinks the region and those it moved from."""
        if self._region is not None:
            for region in [*self._retired, self._region]:
                region.close()
            self._retired, self._region = [], None


class SnapshotReader:
    """Copies the newest complete snapshot into private buffers (the servo's side).

    :meth:`poll` is cheap when nothing new was published (three header loads); a new
    snapshot is copied into the spare of two private buffer sets, so a torn read
    never spoils the scene in use. :attr:`scene` is None until the first snapshot.
    A snapshot that moved (:meth:`SceneSnapshot.reserve`) is followed, with private
    buffers of the new capacities; the scene in use stays until the new region's
    first snapshot.
    """

    def __init__(self, snapshot: SceneSnapshot):
        self._snapshot = snapshot
        self._region = None
        self._spare = 0
        self._version = 0
        self.scene: HapticScene | None = None
        self.torn_reads = 0
        self._take_region()

    def _take_region(self):
        """Buffers for the snapshot's region (at start and after it moved)."""
        self._region = self._snapshot._region
        self._capacities = self._snapshot._capacities
        self._buffers = [
            {
                name: np.zeros(shape, dtype)
                for name, dtype, shape in _scene_fields(self._capacities, private=True)
            }
            for _ in range(2)
        ]

    def poll(self) -> bool:
        """Take the newest snapshot if one was published since; True when taken."""
        self._snapshot.follow()
        if self._snapshot._region is not self._region:
            self._take_region()
        if self._region.newest() == self._version:
            return False
        buffers = self._buffers[self._spare]
        counts = buffers["counts"]

        def copy(slot):
            counts[:] = slot["counts"]
            buffers["timestamp"][:] = slot["timestamp"]
            buffers["coupling"][:] = slot["coupling"]
            counts[1:] = np.clip(counts[1:], 0, self._capacities[1:])  # a torn read's counts
            for name, (_, _, i, extra, _) in _SCENE_ARRAYS.items():
                n = int(counts[i]) + extra
                buffers[name][:n] = slot[name][:n]

        version = self._region.read(copy)
        if version <= 0:
            self.torn_reads += version < 0
            return False
        self._version = version
        self._spare ^= 1
        coupling = buffers["coupling"]
        self.scene = HapticScene(
            sequence=int(counts[0]),
            timestamp=float(buffers["timestamp"][0]),
            coupling_tip=coupling[:3] if coupling[3] else None,
            **{
                name: buffers[name][: int(counts[i]) + extra]
                for name, (_, _, i, extra, _) in _SCENE_ARRAYS.items()
            },
        )
        return True
