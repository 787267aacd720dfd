"""OpenHaptics devices (Geomagic Touch, as in seed 002 §3.4) through libHD and ctypes.

Follows the HDAPI of the OpenHaptics 3.0 headers: an asynchronous servo callback at
``HD_MAX_SCHEDULER_PRIORITY`` runs on libHD's scheduler thread at 1 kHz, reads
``HD_CURRENT_TRANSFORM`` (16 doubles, column-major, [mm]) and ``HD_CURRENT_BUTTONS``,
and writes ``HD_CURRENT_FORCE`` [N] after :class:`~taichi_lap.haptics.safety.ForceSafety`.
The callback needs the GIL each tick: run devices in the haptics process, never beside
Taichi kernels (a launch holds the GIL throughout).
"""

from __future__ import annotations

import atexit
import ctypes
import ctypes.util
import logging
import os
import queue
import sys
import threading
import time
from ctypes import POINTER, c_char_p, c_double, c_int, c_uint, c_ulong, c_ushort, c_void_p
from dataclasses import dataclass

import numpy as np

from taichi_lap.haptics.device import HapticDevice, WorkspaceMapping
from taichi_lap.haptics.safety import ForceSafety

log = logging.getLogger("taichi_lap.haptics")

# Values from the OpenHaptics 3.0 headers (hdDefines.h).
HD_DEFAULT_DEVICE = None
HD_INVALID_HANDLE = 0xFFFFFFFF
HD_SUCCESS = 0x0000
HD_CALLBACK_CONTINUE = 1
HD_CURRENT_BUTTONS = 0x2000
HD_CURRENT_TRANSFORM = 0x2052
HD_DEVICE_MODEL_TYPE = 0x2501
HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604
HD_CURRENT_FORCE = 0x2700
HD_FORCE_OUTPUT = 0x4000
HD_MAX_SCHEDULER_PRIORITY = 65535
HD_CALIBRATION_OK, HD_CALIBRATION_NEEDS_UPDATE, HD_CALIBRATION_NEEDS_MANUAL_INPUT = (
    0x5000,
    0x5001,
    0x5002,
)
HD_CALIBRATION_ENCODER_RESET, HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL = 1, 2, 4
SERVO_RATE_HZ = 1000

ERROR_NAMES = {
    0x100: "HD_INVALID_ENUM",
    0x101: "HD_INVALID_VALUE",
    0x102: "HD_INVALID_OPERATION",
    0x103: "HD_INVALID_INPUT_TYPE",
    0x104: "HD_BAD_HANDLE",
    0x200: "HD_WARM_MOTORS",
    0x201: "HD_EXCEEDED_MAX_FORCE",
    0x204: "HD_FORCE_ERROR",
    0x202: "HD_EXCEEDED_MAX_FORCE_IMPULSE",
    0x203: "HD_EXCEEDED_MAX_VELOCITY",
    0x300: "HD_DEVICE_FAULT",
    0x301: "HD_DEVICE_ALREADY_INITIATED",
    0x302: "HD_COMM_ERROR",
    0x303: "HD_COMM_CONFIG_ERROR",
    0x304: "HD_TIMER_ERROR",
    0x400: "HD_ILLEGAL_BEGIN",
    0x401: "HD_ILLEGAL_END",
    0x402: "HD_FRAME_ERROR",
    0x500: "HD_INVALID_PRIORITY",
    0x501: "HD_SCHEDULER_FULL",
    0x600: "HD_INVALID_LICENSE",
}
CALIBRATION_NAMES = {
    0x5000: "HD_CALIBRATION_OK",
    0x5001: "HD_CALIBRATION_NEEDS_UPDATE",
    0x5002: "HD_CALIBRATION_NEEDS_MANUAL_INPUT",
}
CALIBRATION_STYLES = {
    1: "HD_CALIBRATION_ENCODER_RESET",
    2: "HD_CALIBRATION_AUTO",
    4: "HD_CALIBRATION_INKWELL",
}
LIBRARY_NAMES = (
    ("HD.dll",)
    if sys.platform == "win32"
    else ("libHD.so", "libHD.so.3.0", "libHD.so.3.0.0", "libHD.so.3.4")
)
MAX_ERRORS_DRAINED = 256  # bound on one drain of the error stack
TICK_WAIT = 0.050  # [s] longest wait for servo ticks (first pose; zero force on close)


class OpenHapticsError(RuntimeError):
    """libHD is missing, or an HDAPI call reported errors (named in the message)."""


class _HDErrorInfo(ctypes.Structure):
    _fields_ = [("errorCode", c_uint), ("internalErrorCode", c_int), ("hHD", c_uint)]


_SchedulerCallback = ctypes.CFUNCTYPE(c_uint, c_void_p)

_SIGNATURES = {  # name: (restype, argtypes)
    **{
        name: (None, [c_uint])
        for name in (
            "hdDisableDevice",
            "hdMakeCurrentDevice",
            "hdBeginFrame",
            "hdEndFrame",
            "hdEnable",
            "hdDisable",
            "hdUpdateCalibration",
        )
    },
    "hdInitDevice": (c_uint, [c_char_p]),
    "hdGetDoublev": (None, [c_uint, POINTER(c_double)]),
    "hdGetIntegerv": (None, [c_uint, POINTER(c_int)]),
    "hdSetDoublev": (None, [c_uint, POINTER(c_double)]),
    "hdGetString": (c_char_p, [c_uint]),
    "hdGetError": (_HDErrorInfo, []),
    "hdCheckCalibration": (c_uint, []),
    "hdSetSchedulerRate": (None, [c_ulong]),
    "hdStartScheduler": (None, []),
    "hdStopScheduler": (None, []),
    "hdScheduleAsynchronous": (c_ulong, [_SchedulerCallback, c_void_p, c_ushort]),
    "hdUnschedule": (None, [c_ulong]),
}


@dataclass(frozen=True)
class HDError:
    """One entry of the HDAPI error stack."""

    code: int
    internal_code: int
    handle: int
    text: str

    @property
    def name(self) -> str:
        return ERROR_NAMES.get(self.code, f"unknown HD error 0x{self.code:x}")

    def __str__(self):
        where = "" if self.handle == HD_INVALID_HANDLE else f" on device {self.handle}"
        text = f": {self.text}" if self.text else ""
        return f"{self.name} (0x{self.code:03x}, internal {self.internal_code}){where}{text}"


class _Library:
    """One loaded libHD: its functions, its one scheduler and the devices open on it."""

    loaded: dict[str, "_Library"] = {}

    def __init__(self, cdll: ctypes.CDLL, name: str):
        for symbol, (restype, argtypes) in _SIGNATURES.items():
            try:
                function = getattr(cdll, symbol)
            except AttributeError:
                raise OpenHapticsError(
                    f"{name} was loaded but is not libHD: it lacks the HDAPI function {symbol}"
                ) from None
            function.restype, function.argtypes = restype, argtypes
        self.hd = cdll
        self.error_string = getattr(cdll, "hdGetErrorString", None)
        if self.error_string is not None:
            self.error_string.restype, self.error_string.argtypes = c_char_p, [c_uint]
        self.lock = threading.RLock()  # opening and closing; never taken on the servo thread
        self.devices: dict[int, OpenHapticsDevice] = {}
        self.scheduler_running = False

    @classmethod
    def load(cls, library: str | None) -> "_Library":
        """The library at ``library``, else the first libHD found on the usual names."""
        if library is not None:
            candidates, tried = [str(library)], []
        else:
            found = ctypes.util.find_library("HD")
            candidates = ([found] if found else []) + list(LIBRARY_NAMES)
            tried = [] if found else ["ctypes.util.find_library('HD') (found nothing)"]
        for name in candidates:
            key = os.path.realpath(name) if os.sep in name else name  # one entry per file
            if key in cls.loaded:
                return cls.loaded[key]
            try:
                cdll = ctypes.CDLL(name)
            except OSError as exc:
                tried.append(f"{name} ({exc})")
                continue
            cls.loaded[key] = cls(cdll, name)
            return cls.loaded[key]
        raise OpenHapticsError(
            "the OpenHaptics HDAPI library libHD could not be loaded; tried "
            + "; ".join(tried)
            + ". Install the OpenHaptics runtime and the "
            "device driver, or pass library=PATH"
        )

    def drain_errors(self, caller: int, route: bool = True) -> list[HDError]:
        """Pop the whole error stack. With ``route``, errors of other open devices go to
        those devices; the rest (the caller's, unattributed ones) are returned."""
        mine = []
        for _ in range(MAX_ERRORS_DRAINED):
            info = self.hd.hdGetError()
            if info.errorCode == HD_SUCCESS:
                break
            text = self.error_string(info.errorCode) if self.error_string else None
            error = HDError(
                int(info.errorCode),
                int(info.internalErrorCode),
                int(info.hHD),
                text.decode(errors="replace") if text else "",
            )
            owner = self.devices.get(error.handle)
            if route and owner is not None and error.handle != caller:
                owner.servo_errors.put(error)
            else:
                mine.append(error)
        return mine

    def check(self, what: str, caller: int = HD_INVALID_HANDLE):
        """Raise :class:`OpenHapticsError` naming every error ``what`` left on the stack."""
        errors = self.drain_errors(caller)
        if errors:
            raise OpenHapticsError(f"{what} failed: " + "; ".join(map(str, errors)))

    def start_scheduler(self):
        self.hd.hdSetSchedulerRate(SERVO_RATE_HZ)
        self.hd.hdStartScheduler()
        self.check("hdStartScheduler")
        self.scheduler_running = True

    def stop_scheduler(self):
        self.hd.hdStopScheduler()
        self.scheduler_running = False


class OpenHapticsDevice(HapticDevice):
    """One OpenHaptics device, opened on construction and serviced at 1 kHz.

    ``name``: the device name configured in the driver ("Left Device"), None for the
    default; ``library``: a path or name of libHD (default: searched); ``mapping``:
    workspace [mm] to scene [m]; ``max_rate`` [N/s], ``watchdog_timeout`` and
    ``fade_time`` [s]: the force-safety filter; ``calibration_style`` (1 encoder reset,
    2 auto, 4 inkwell): for ``hdUpdateCalibration`` on ``HD_CALIBRATION_NEEDS_UPDATE``.

    Closing (``close()``, a ``with`` block also left by Ctrl-C, or interpreter exit)
    commands zero force for two ticks, then calls ``hdStopScheduler`` (with the last
    open device), ``hdUnschedule``, ``hdDisable(HD_FORCE_OUTPUT)``, ``hdDisableDevice``.
    An HDAPI error in the servo callback zeroes the force and disables force output at
    once; :attr:`fault` then names the errors and :meth:`set_force` raises.
    """

    def __init__(
        self,
        name: str | None = None,
        library: str | None = None,
        mapping: WorkspaceMapping = WorkspaceMapping(),
        *,
        max_rate: float = 100.0,
        watchdog_timeout: float = 0.100,
        fade_time: float = 0.050,
        calibration_style: int = HD_CALIBRATION_INKWELL,
    ):
        if calibration_style not in CALIBRATION_STYLES:
            raise ValueError(
                f"calibration_style: one of {sorted(CALIBRATION_STYLES)} was "
                f"expected, found {calibration_style!r}"
            )
        self.name = name
        self.mapping = mapping
        self.handle = HD_INVALID_HANDLE
        self.model = ""
        self.calibration = HD_CALIBRATION_OK
        self.servo_errors: queue.SimpleQueue[HDError] = queue.SimpleQueue()
        self.fault: str | None = None
        self._lib = _Library.load(library)
        self._max_force = 0.0
        self._safety: ForceSafety | None = None
        self._safety_args = (max_rate, watchdog_timeout, fade_time)
        self._schedule: int | None = None
        self._callback = _SchedulerCallback(self._servo_tick)  # referenced while scheduled
        self._transform = (c_double * 16)()
        self._buttons = c_int(0)
        self._force = (c_double * 3)()
        self._latest = (mapping.to_scene(np.eye(4)), 0)  # (pose [m], buttons), swapped whole
        self._command = (np.zeros(3), time.monotonic())  # (force [N], snapshot time [s])
        self._stopping = False
        self._ticks = 0
        self._closed = False
        self._open(calibration_style)

    def __repr__(self):
        handle = "" if self.handle == HD_INVALID_HANDLE else f", handle={self.handle}"
        return f"OpenHapticsDevice({self.name or 'default device'!r}{handle})"

    def _open(self, calibration_style: int):
        lib, hd = self._lib, self._lib.hd
        with lib.lock:
            if lib.scheduler_running:  # devices are initialised with the scheduler stopped
                lib.stop_scheduler()
            try:
                for error in lib.drain_errors(HD_INVALID_HANDLE):  # others' go to them
                    log.warning("libHD reported before hdInitDevice: %s", error)
                handle = hd.hdInitDevice(self.name.encode() if self.name else HD_DEFAULT_DEVICE)
                errors = lib.drain_errors(handle, route=False)  # all from this call
                if handle != HD_INVALID_HANDLE:
                    self.handle = handle  # released below if anything fails
                if handle == HD_INVALID_HANDLE or errors:
                    raise OpenHapticsError(
                        f"hdInitDevice({self.name or 'HD_DEFAULT_DEVICE'!r}) failed: "
                        + ("; ".join(map(str, errors)) or "HD_INVALID_HANDLE returned")
                    )
                self._read_properties(calibration_style)
                lib.devices[handle] = self
                self._schedule = hd.hdScheduleAsynchronous(
                    self._callback, None, HD_MAX_SCHEDULER_PRIORITY
                )
                lib.check(f"{self!r}: hdScheduleAsynchronous", handle)
                lib.start_scheduler()
                self._wait_ticks(1)  # the first pose
            except BaseException:
                if lib.scheduler_running and set(lib.devices) <= {self.handle}:
                    lib.stop_scheduler()
                self._release()
                if lib.devices and not lib.scheduler_running:  # for the other devices
                    lib.start_scheduler()
                raise

    def _read_properties(self, calibration_style: int):
        """Model, nominal maximum continuous force, force output, calibration."""
        lib, hd = self._lib, self._lib.hd
        hd.hdMakeCurrentDevice(self.handle)
        model = hd.hdGetString(HD_DEVICE_MODEL_TYPE)
        self.model = model.decode(errors="replace") if model else ""
        value = (c_double * 1)()
        hd.hdGetDoublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE, value)
        lib.check(
            f"{self!r}: reading HD_DEVICE_MODEL_TYPE and HD_NOMINAL_MAX_CONTINUOUS_FORCE",
            self.handle,
        )
        if not (np.isfinite(value[0]) and value[0] > 0):
            raise OpenHapticsError(
                f"{self!r}: HD_NOMINAL_MAX_CONTINUOUS_FORCE: a positive "
                f"force [N] was expected, found {value[0]}"
            )
        self._max_force = float(value[0])
        self._safety = ForceSafety(
            self._max_force,
            self._safety_args[0],
            watchdog_timeout=self._safety_args[1],
            fade_time=self._safety_args[2],
        )
        hd.hdEnable(HD_FORCE_OUTPUT)
        lib.check(f"{self!r}: hdEnable(HD_FORCE_OUTPUT)", self.handle)
        self.calibration = hd.hdCheckCalibration()
        if self.calibration == HD_CALIBRATION_NEEDS_UPDATE:
            hd.hdUpdateCalibration(calibration_style)
            lib.check(
                f"{self!r}: hdUpdateCalibration({CALIBRATION_STYLES[calibration_style]})",
                self.handle,
            )
            self.calibration = hd.hdCheckCalibration()
        if self.calibration != HD_CALIBRATION_OK:
            log.warning(
                "%r: calibration status %s%s",
                self,
                CALIBRATION_NAMES.get(self.calibration, hex(self.calibration)),
                " (place the stylus in its inkwell)"
                if self.calibration == HD_CALIBRATION_NEEDS_MANUAL_INPUT
                else "",
            )

    @property
    def max_force(self) -> float:
        """Nominal maximum continuous force [N] read from the device."""
        return self._max_force

    def pose(self) -> np.ndarray:
        """Latest stylus pose: 4×4 row-major, translation mapped to the scene [m]."""
        return np.array(self._latest[0])

    def buttons(self) -> int:
        """Latest ``HD_CURRENT_BUTTONS`` bitmask (HD_DEVICE_BUTTON_1 = 1, _2 = 2, ...)."""
        return self._latest[1]

    def set_force(self, force_newtons: np.ndarray, *, snapshot_time: float | None = None):
        """Command a force [N] in scene (= device) axes; see :class:`HapticDevice`."""
        if self.fault is not None:
            raise OpenHapticsError(f"{self!r}: force output stopped after {self.fault}")
        if self._closed:
            raise OpenHapticsError(f"{self!r} is closed")
        force = np.array(force_newtons, dtype=np.float64)
        if force.shape != (3,):
            raise ValueError(
                f"set_force: a force 3-vector [N] was expected, found shape {force.shape}"
            )
        stamp = time.monotonic() if snapshot_time is None else float(snapshot_time)
        self._command = (force, stamp)

    def _servo_tick(self, _user) -> int:
        """One servo tick, on libHD's scheduler thread; never raises into C."""
        hd, handle = self._lib.hd, self.handle
        in_frame = False
        try:
            hd.hdBeginFrame(handle)
            in_frame = True
            hd.hdGetDoublev(HD_CURRENT_TRANSFORM, self._transform)
            hd.hdGetIntegerv(HD_CURRENT_BUTTONS, self._buttons)
            errors = self._take_errors()
            if errors or self._stopping:
                self._safety.fault()
            force, stamp = self._command
            self._force[:] = self._safety.filter(force, time.monotonic(), stamp).tolist()
            hd.hdSetDoublev(HD_CURRENT_FORCE, self._force)
            hd.hdEndFrame(handle)
            in_frame = False
            errors += self._take_errors()
            if errors:
                self._stop_force_output("; ".join(map(str, errors)))
            transform = np.ctypeslib.as_array(self._transform).reshape(4, 4).T  # column-major
            self._latest = (self.mapping.to_scene(transform), int(self._buttons.value))
        except BaseException as exc:  # nothing may propagate into libHD
            try:
                if in_frame:  # finish this frame with zero force
                    self._force[:] = [0.0, 0.0, 0.0]
                    hd.hdSetDoublev(HD_CURRENT_FORCE, self._force)
                    hd.hdEndFrame(handle)
                self._stop_force_output(f"the servo callback raised {type(exc).__name__}: {exc}")
            except BaseException:
                self.fault = self.fault or f"the servo callback raised {type(exc).__name__}"
        self._ticks += 1
        return HD_CALLBACK_CONTINUE

    def _take_errors(self) -> list[HDError]:
        errors = self._lib.drain_errors(self.handle)
        while not self.servo_errors.empty():
            errors.append(self.servo_errors.get_nowait())
        return errors

    def _stop_force_output(self, reason: str):
        """Zero force and disable force output (servo thread), then log and record ``reason``.

        The log record is written before ``fault`` is set, so whoever sees the fault
        also finds it in the log."""
        self._safety.fault()
        self._lib.hd.hdMakeCurrentDevice(self.handle)
        self._lib.hd.hdDisable(HD_FORCE_OUTPUT)
        if self.fault is None:
            log.error("%r: force output stopped: %s", self, reason)
            self.fault = reason

    def close(self):
        """Zero the force, stop servicing the device and release it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        lib = self._lib
        with lib.lock:
            try:
                if self._schedule is not None and lib.scheduler_running:
                    self._stopping = True
                    self._wait_ticks(2)  # the tick under way may still send the old force
            finally:
                if lib.scheduler_running and set(lib.devices) <= {self.handle}:
                    lib.stop_scheduler()
                self._release()

    def _wait_ticks(self, count: int):
        """Sleep until ``count`` more servo ticks ran, or :data:`TICK_WAIT` passed."""
        target, deadline = self._ticks + count, time.monotonic() + TICK_WAIT
        while self._ticks < target and time.monotonic() < deadline:
            time.sleep(0.001)

    def _release(self):
        """Unschedule, disable force output, disable the device (lock held); errors
        these calls report are logged."""
        hd = self._lib.hd
        if self._schedule is not None:
            hd.hdUnschedule(self._schedule)
            self._schedule = None
        if self.handle != HD_INVALID_HANDLE:
            hd.hdMakeCurrentDevice(self.handle)
            hd.hdDisable(HD_FORCE_OUTPUT)
            hd.hdDisableDevice(self.handle)
            self._lib.devices.pop(self.handle, None)
        self._closed = True
        for error in self._lib.drain_errors(self.handle):
            log.warning("%r: while releasing: %s", self, error)


@atexit.register
def _close_all():
    """Release every device still open when the interpreter exits."""
    for lib in list(_Library.loaded.values()):
        for device in list(lib.devices.values()):
            device.close()
