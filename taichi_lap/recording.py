"""Session recording and replay: every frame's device input and every simulation
event, appended to a ``.tlap`` file while the session runs.

File format, version 2 (all numbers little-endian)::

    header  8 bytes magic 89 54 4C 41 50 0D 0A 1A ("\\x89TLAP\\r\\n\\x1a"), u32 version
    record  u8 tag | u32 length | payload (length bytes) | u32 CRC-32 of tag, length, payload

=====  =======  ==========================================================================
tag    record   payload
=====  =======  ==========================================================================
``E``  event    UTF-8 JSON object ``{"kind", "time" [s], "frame", ...fields}``
``F``  frame    the device input applied before a step: f64 time [s], u32 frame, f64 clock
                [s, monotonic], u8 count, then per tool: u8 tool index, f64[3] tip [m],
                f64[3] direction (tip towards handle), f64 roll [rad], u32 buttons
``T``  tick     a haptic servo tick: f64 clock [s, monotonic], u8 count, then per tool:
                u8 tool index, f32[3] tip [m], f32[3] direction, f32 roll [rad], u32
                buttons, f32[3] force [N]
``S``  stats    UTF-8 JSON ``{"time" [s], "frame", "stages": {stage: wall time [ms]},
                "forces": {tool: [N, N, N]}, "contacts": {tool: {organ: particles}}}``
                of the frame that just ended (after its frame record and events);
                with a task's view target also ``"view": {target: [visible, share]}``
=====  =======  ==========================================================================

The first record is the ``session_start`` event: scene name and source, ``digest``
(sha256 of the scene's values after overrides and its mesh files), ``raw_scene``,
``seed``, ``dt`` [s], ``arch``, ``threads``, ``versions``, ``tools`` (the names tool
indices refer to), ``started`` (UTC) and ``clock``. Then ``device`` events, one frame
record before every step, events as they happen (``EVENT_KINDS``), a stats record
after every frame (stage times and tool forces, for the training metrics), and last
``session_end`` with ``status``, ``frames`` and ``checksum`` (:func:`state_checksum`).

Version 1 files (written before the tools had a roll) are read too: their frame and
tick records lack the roll, which reads as 0.

Why binary records and not JSON lines: a 1 kHz servo tick is 59 bytes here against
about 150 as JSON; poses are stored as their f64 bits (no decimal round trip), which
bit-identical replay needs; the CRC finds a damaged record in the middle, which a
JSON parser may take for valid numbers; the length lets readers skip tags they do
not know, so new record types need no new version (the version changes only when a
layout changes).

Crash safety: the header and ``session_start`` go to a temporary file that is
fsynced and then linked to the final name (never over an existing file), so a
recording on disk always starts complete. The file is opened with ``O_APPEND`` and
every flush is one ``write`` of whole records; frames and events are flushed at
once, ``fsync`` runs at most once a second. A killed run leaves its records up to the last complete one:
the reader (:mod:`taichi_lap.replay`) warns that the file is truncated and keeps what
precedes the cut.

The simulation writes through :class:`SessionRecorder`. The haptic servo keeps its
ticks in the ring of its feedback region; every frame the simulation drains the ring
(``drain_ticks`` of the haptic bridge) and appends the ticks before the frame record,
so the 1 kHz loop never waits on the file.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import os
import platform
import struct
import tempfile
import zlib
from pathlib import Path
from time import monotonic

import numpy as np
import taichi as ti

from taichi_lap.core.errors import InputError, SimulationFault
from taichi_lap.core.files import give_ordinary_mode
from taichi_lap.devices import Pose, applied_poses
from taichi_lap.runtime import current_arch

MAGIC = b"\x89TLAP\r\n\x1a"
VERSION = 2
READABLE_VERSIONS = (1, 2)
HEADER = struct.Struct("<8sI")  # magic, version
RECORD_HEAD = struct.Struct("<BI")  # tag, payload length [bytes]
CRC = struct.Struct("<I")
TAG_EVENT, TAG_FRAME, TAG_TICK, TAG_STATS = b"E"[0], b"F"[0], b"T"[0], b"S"[0]
FRAME_HEAD = struct.Struct("<dIdB")  # time [s], frame, clock [s], tool count
FRAME_TOOL = struct.Struct("<B3d3ddI")  # tool index, tip [m], direction, roll [rad], buttons
TICK_HEAD = struct.Struct("<dB")  # clock [s], tool count
# tool index, tip [m], direction, roll [rad], buttons, force [N]
TICK_TOOL = struct.Struct("<B3f3ffI3f")
# the per-tool layouts of version 1 (no roll)
FRAME_TOOL_V1 = struct.Struct("<B3d3dI")
TICK_TOOL_V1 = struct.Struct("<B3f3fI3f")
MAX_PAYLOAD = 1 << 24  # [bytes]; a longer length field is damage
FSYNC_INTERVAL = 1.0  # [s]
BUFFER_LIMIT = 1 << 16  # [bytes] of buffered ticks written without a flush call
EVENT_KINDS = (
    "session_start",
    "device",
    "session_end",
    "grasp",
    "release",
    "dissect",
    "fragment",
    "cautery_on",
    "cautery_off",
    "cautery",
    "vessel_damage",
    "cut",
    "tear",
    "separated",
    "excised",
)
CHECKSUM_FIELDS = ("x", "v", "goal", "eta", "collided")


def scene_fingerprint(scene) -> tuple[str, dict]:
    """``(digest, raw)``: sha256 of the scene's values (after overrides) and of its
    mesh files, and the values as JSON data."""
    text = json.dumps(scene.raw, sort_keys=True, default=str)
    digest = hashlib.sha256(text.encode())
    for organ in scene.organs:
        if organ.geometry.mesh is not None:
            digest.update(Path(organ.geometry.mesh).read_bytes())
    return digest.hexdigest(), json.loads(text)


def state_checksum(state) -> str:
    """sha256 over the name and little-endian bytes of each State array that evolves
    (``CHECKSUM_FIELDS``), in that order."""
    digest = hashlib.sha256()
    snapshot = state.snapshot()
    for name in CHECKSUM_FIELDS:
        array = snapshot[name]
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<")).tobytes())
    return digest.hexdigest()


def _json_value(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"an event field of type {type(value).__name__} is not JSON data")


def encode_record(tag: int, payload: bytes) -> bytes:
    """One framed record: tag, length, payload, CRC-32."""
    head = RECORD_HEAD.pack(tag, len(payload))
    return head + payload + CRC.pack(zlib.crc32(payload, zlib.crc32(head)))


def encode_event(kind: str, *, time: float, frame: int, **fields) -> bytes:
    """An event record; ``kind`` is one of ``EVENT_KINDS``, fields are JSON data."""
    if kind not in EVENT_KINDS:
        raise ValueError(
            f"event kind: one of {', '.join(EVENT_KINDS)} was expected, found {kind!r}"
        )
    event = {"kind": kind, "time": float(time), "frame": int(frame), **fields}
    return encode_record(TAG_EVENT, json.dumps(event, default=_json_value).encode())


def encode_frame(
    time: float,
    frame: int,
    clock: float,
    poses: dict[str, Pose],
    buttons: dict[str, int] | None = None,
) -> bytes:
    """A frame record: the poses about to be applied to every tool, in tool-index
    order (the order of ``session_start.tools``), and the buttons per tool name."""
    buttons = buttons or {}
    payload = FRAME_HEAD.pack(time, frame, clock, len(poses))
    payload += b"".join(
        FRAME_TOOL.pack(index, *pose.tip, *pose.direction, pose.roll, buttons.get(name, 0))
        for index, (name, pose) in enumerate(poses.items())
    )
    return encode_record(TAG_FRAME, payload)


def encode_stats(
    time: float,
    frame: int,
    timings: dict[str, float],
    forces: dict[str, np.ndarray],
    contacts: dict[str, dict[str, int]] | None = None,
    view: dict[str, tuple[float, float]] | None = None,
) -> bytes:
    """A statistics record of the frame that ended at ``time`` [s]: the wall time
    [ms] of each stage (``physics``, ``topology``, ``heat``, ``render``, ...), the
    force [N] the tissue pushed each tool with and, per tool, the particles of each
    organ touching it (by name; organs not touching it left out); with ``view``, how
    the frame's image showed the task's target (``{name: [visible, share]}``,
    :meth:`~taichi_lap.render.renderer.Renderer.view_of`). The training metrics read
    it (:mod:`taichi_lap.training.metrics`); replay does not need it."""
    stats = {
        "time": float(time),
        "frame": int(frame),
        "stages": {name: float(ms) for name, ms in timings.items()},
        "forces": {name: [float(f) for f in force] for name, force in forces.items()},
        "contacts": {
            name: {organ: int(n) for organ, n in touching.items()}
            for name, touching in (contacts or {}).items()
        },
    }
    if view:
        stats["view"] = {name: [float(v) for v in values] for name, values in view.items()}
    return encode_record(TAG_STATS, json.dumps(stats).encode())


class RecordStream:
    """Appends records to an open recording: buffered, written by :meth:`flush` in one
    ``write`` (``O_APPEND``), fsynced at most once per ``FSYNC_INTERVAL`` and on close.
    ``tools`` are the tool names of ``session_start`` (record indices refer to them)."""

    def __init__(self, path: str, fd: int, tools: list[str]):
        self.path = path
        self.tools = list(tools)
        self._fd = fd
        self._buffer = bytearray()
        self._synced = monotonic()

    @classmethod
    def create(cls, path: str | Path, start: bytes, tools: list[str]) -> "RecordStream":
        """A new recording holding the header and the encoded ``start`` event, made
        atomically; an existing file is never replaced."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            os.write(fd, HEADER.pack(MAGIC, VERSION) + start)
            give_ordinary_mode(fd)
            os.fsync(fd)
            os.link(tmp, path)
        except FileExistsError:
            raise existing_file_error(str(path)) from None
        except OSError:  # no hard links on this file system (FAT, some network shares)
            if path.exists():
                raise existing_file_error(str(path)) from None
            os.replace(tmp, path)
        finally:
            os.close(fd)
            Path(tmp).unlink(missing_ok=True)
        _fsync_directory(path.parent)
        return cls(
            str(path), os.open(path, os.O_WRONLY | os.O_APPEND | getattr(os, "O_BINARY", 0)), tools
        )

    def append(self, record: bytes):
        """Buffer one encoded record; written at the next flush."""
        self._buffer += record
        if len(self._buffer) >= BUFFER_LIMIT:
            self.flush()

    def event(self, kind: str, *, time: float, frame: int, **fields):
        """Write an event at once (see :func:`encode_event`)."""
        self.append(encode_event(kind, time=time, frame=frame, **fields))
        self.flush()

    def tick(self, clock: float, tools: dict[str, tuple[Pose, int, np.ndarray]]):
        """Buffer a haptic tick: ``clock`` [s] (``time.monotonic()``) and per tool name
        its (pose, buttons, force [N]). The caller flushes when it suits its loop."""
        payload = TICK_HEAD.pack(clock, len(tools)) + b"".join(
            TICK_TOOL.pack(
                self.tools.index(name), *pose.tip, *pose.direction, pose.roll, buttons, *force
            )
            for name, (pose, buttons, force) in tools.items()
        )
        self.append(encode_record(TAG_TICK, payload))

    def flush(self):
        """Write the buffered records; fsync when the last one is over a second old."""
        view = memoryview(bytes(self._buffer))
        self._buffer.clear()
        while view:
            view = view[os.write(self._fd, view) :]
        if monotonic() - self._synced >= FSYNC_INTERVAL:
            os.fsync(self._fd)
            self._synced = monotonic()

    def close(self):
        self.flush()
        os.fsync(self._fd)
        os.close(self._fd)


def existing_file_error(path: str, key: str = "") -> InputError:
    """The error for a recording path that exists: recordings are never overwritten."""
    return InputError(
        path,
        key,
        "a new file was expected (recordings are never overwritten), found an existing file",
    )


def _fsync_directory(directory: Path):
    """Make a new directory entry durable (POSIX; elsewhere a no-op)."""
    if hasattr(os, "O_DIRECTORY"):
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def run_settings() -> dict:
    """What a bit-identical replay depends on besides the scene and the input: the
    backend, the CPU thread count (the order of parallel work) and the versions."""
    import taichi_lap

    return {
        "arch": current_arch(),
        "threads": ti.lang.impl.current_cfg().cpu_max_num_threads,
        "versions": {
            "taichi_lap": taichi_lap.__version__,
            "taichi": ".".join(map(str, ti.__version__)),
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
    }


def describe_device(device) -> dict:
    """A device as ``device`` event fields: its class and, where it has one, its source."""
    if device is None:
        return {"device": "none"}
    return {
        "device": type(device).__name__,
        **({"source": device.source} if getattr(device, "source", "") else {}),
    }


class SessionRecorder:
    """Records one :class:`~taichi_lap.session.Session` to ``path``: ``session_start``
    and ``device`` now, a frame before every step (:meth:`record_frame`), events
    (:meth:`record_event`), and ``session_end`` with the state checksum on close. As a
    context manager the end's ``status`` says how the run ended."""

    def __init__(self, path: str | Path, session, device):
        self.session = session
        scene, state = session.scene, session.state
        digest, raw = scene_fingerprint(scene)
        tools = list(applied_poses(scene.tools, {}))
        start = encode_event(
            "session_start",
            time=state.time,
            frame=state.frame,
            scene=scene.settings["name"],
            source=scene.source,
            digest=digest,
            raw_scene=raw,
            seed=scene.settings["seed"],
            dt=session.dt,
            **run_settings(),
            tools=tools,
            clock=monotonic(),
            started=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        )
        self.stream = RecordStream.create(path, start, tools)
        self.closed = False
        self.record_device(device)

    def record_event(self, kind: str, **fields):
        """Append an event stamped with the session's time [s] and frame; written at once."""
        state = self.session.state
        self.stream.event(kind, time=state.time, frame=state.frame, **fields)

    def record_device(self, device):
        """Record which device drives the tools (at start and when it changes)."""
        self.record_event("device", **describe_device(device))

    def record_ticks(self, ticks: list[tuple[float, dict]]):
        """Buffer haptic servo ticks ``(clock, {tool: (pose, buttons, force)})``; they
        are written with the next frame."""
        for clock, tools in ticks:
            self.stream.tick(clock, tools)

    def record_frame(self, poses: dict[str, Pose] | None, buttons: dict[str, int] | None):
        """Append the poses about to be applied (every tool, as :func:`applied_poses`
        places it) and the buttons per tool name, then flush."""
        state = self.session.state
        placed = applied_poses(self.session.scene.tools, poses or {})
        self.stream.append(encode_frame(state.time, state.frame, monotonic(), placed, buttons))
        self.stream.flush()

    def record_stats(
        self,
        timings: dict[str, float],
        forces: dict[str, np.ndarray],
        contacts: dict[str, dict[str, int]],
        view: dict[str, tuple[float, float]] | None = None,
    ):
        """Append the statistics of the frame just stepped (:func:`encode_stats`):
        ``timings`` [ms] per stage, the force [N] on each tool, the particles of each
        organ touching it and how the image showed the task's target; written with
        the next frame."""
        state = self.session.state
        self.stream.append(encode_stats(state.time, state.frame, timings, forces, contacts, view))

    @property
    def path(self) -> str:
        return self.stream.path

    def close(self, status: str = "complete"):
        """Append ``session_end`` (status, frames, checksum) and close the file; once
        closed, closing again does nothing (a window that ended its task closes the
        recording before the window)."""
        if self.closed:
            return
        state = self.session.state
        self.record_event(
            "session_end", status=status, frames=state.frame, checksum=state_checksum(state)
        )
        self.stream.close()
        self.closed = True

    def __enter__(self) -> "SessionRecorder":
        return self

    def __exit__(self, kind, error, traceback):
        self.close(
            "complete"
            if kind is None
            else "interrupted"
            if kind is KeyboardInterrupt
            else f"fault: {error}"
            if kind is SimulationFault
            else f"error: {kind.__name__}"
        )


@contextlib.contextmanager
def maybe_recording(path: str | None, session, device):
    """A :class:`SessionRecorder` for ``path``, or ``None`` when not recording."""
    if path is None:
        yield None
        return
    with SessionRecorder(path, session, device) as recorder:
        yield recorder
