/*
 * A fake OpenHaptics HDAPI library (libHD) for contract tests of the ctypes binding.
 *
 * It exports the HDAPI functions the binding calls, with the signatures, types and
 * constant values of the OpenHaptics 3.0 headers, plus fakehd_* functions to script
 * poses, buttons and calibration, inject errors and read back what the binding did.
 *
 * Devices: "Default Device" (hdInitDevice(NULL)), "Left Device", "Right Device";
 * model "Fake Touch", nominal maximum continuous force 0.88 N, maximum force 3.3 N.
 * A pose is set with fakehd_set_pose(handle, m): 16 doubles, column-major, mm.
 * Each hdEndFrame records the force the device outputs (the commanded force while
 * HD_FORCE_OUTPUT is enabled, zero otherwise); fakehd_forces reads the latest ones.
 * The error stack is one stack for all threads: hdGetError pops the latest error.
 * The scheduler is a pthread ticking at hdSetSchedulerRate (1000 Hz) on absolute
 * CLOCK_MONOTONIC deadlines; it runs the scheduled callbacks in priority order
 * while holding sched_lock, so hdUnschedule returns only between ticks.
 * Lifecycle calls (init, enable, schedule, stop, ...) are logged as text lines,
 * read with fakehd_calls. Strict where the binding could go wrong: a force set
 * outside a frame, a second hdStartScheduler or an unknown enum pushes an error.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

typedef unsigned int HHD, HDenum, HDerror, HDCallbackCode;
typedef unsigned long HDSchedulerHandle, HDulong;
typedef unsigned short HDushort;
typedef const char *HDstring;
typedef struct { HDerror errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;
typedef HDCallbackCode (*HDSchedulerCallback)(void *pUserData);

#define HD_INVALID_HANDLE 0xFFFFFFFFu
enum {  /* values of the OpenHaptics 3.0 headers */
    HD_SUCCESS = 0, HD_CALLBACK_DONE = 0, HD_CURRENT_BUTTONS = 0x2000,
    HD_CURRENT_TRANSFORM = 0x2052, HD_DEVICE_MODEL_TYPE = 0x2501, HD_NOMINAL_MAX_FORCE = 0x2603,
    HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604, HD_CURRENT_FORCE = 0x2700, HD_FORCE_OUTPUT = 0x4000,
    HD_CALIBRATION_OK = 0x5000, HD_CALIBRATION_NEEDS_UPDATE = 0x5001,
    HD_CALIBRATION_STYLES = 1 | 2 | 4, /* ENCODER_RESET | AUTO | INKWELL */
    HD_INVALID_ENUM = 0x100, HD_INVALID_VALUE = 0x101, HD_INVALID_OPERATION = 0x102,
    HD_BAD_HANDLE = 0x104, HD_EXCEEDED_MAX_FORCE = 0x201, HD_DEVICE_FAULT = 0x300,
    HD_DEVICE_ALREADY_INITIATED = 0x301, HD_COMM_CONFIG_ERROR = 0x303, HD_TIMER_ERROR = 0x304,
    HD_ILLEGAL_BEGIN = 0x400, HD_ILLEGAL_END = 0x401, HD_SCHEDULER_FULL = 0x501,
};

#define EXPORT __attribute__((visibility("default")))
#define LOCK() pthread_mutex_lock(&state_lock)
#define UNLOCK() pthread_mutex_unlock(&state_lock)
#define N_DEVICES 3
#define FORCE_LOG 8192
#define MAX_ERRORS 64
#define MAX_CALLBACKS 16
#define CALL_LOG 16384
#define MAX_CONTINUOUS_FORCE 0.88
#define MAX_FORCE 3.3

typedef struct {
    int initialized, force_output, buttons;
    HDenum calibration;
    double pose[16];          /* column-major, translation [mm] at 12..14 */
    double force[3];          /* commanded in the current frame [N] */
    double log[FORCE_LOG][3]; /* output force of each frame [N], a ring */
    unsigned long frames;
} Device;

typedef struct {
    HDSchedulerCallback fn;
    void *user;
    HDushort priority;
    HDSchedulerHandle id;
} Callback;

static const char *const NAMES[N_DEVICES] = {"Default Device", "Left Device", "Right Device"};
static Device devices[N_DEVICES];
static HDErrorInfo errors[MAX_ERRORS];
static int n_errors;
static char calls[CALL_LOG];
static size_t n_calls;
static pthread_mutex_t state_lock = PTHREAD_MUTEX_INITIALIZER; /* devices, errors, calls */

static Callback callbacks[MAX_CALLBACKS]; /* sorted by priority, highest first */
static int n_callbacks, running, stop_requested;
static HDSchedulerHandle next_id = 1;
static HDulong rate = 1000;
static unsigned long ticks;
static pthread_t servo;
static pthread_mutex_t sched_lock = PTHREAD_MUTEX_INITIALIZER; /* taken before state_lock */

static __thread HHD current = HD_INVALID_HANDLE;
static __thread HHD frame = HD_INVALID_HANDLE;
static __thread int on_servo;

static void push_error_locked(HDerror code, HHD h) {
    if (n_errors < MAX_ERRORS) errors[n_errors++] = (HDErrorInfo){code, 0, h};
}

static void push_error(HDerror code, HHD h) { LOCK(); push_error_locked(code, h); UNLOCK(); }

static void record(const char *fmt, ...) {
    va_list args;
    va_start(args, fmt);
    LOCK();
    size_t room = CALL_LOG - n_calls; /* the text, its newline and the final NUL */
    if (room > 2) {
        int n = vsnprintf(calls + n_calls, room - 1, fmt, args);
        n_calls += n < 0 ? 0 : (size_t)n < room - 2 ? (size_t)n : room - 2;
        calls[n_calls++] = '\n';
        calls[n_calls] = '\0';
    }
    UNLOCK();
    va_end(args);
}

static Device *device(HHD h) { return h >= 1 && h <= N_DEVICES ? &devices[h - 1] : NULL; }

/* The calling thread's current device, or NULL after pushing an error (state_lock held). */
static Device *current_locked(void) {
    Device *d = device(current);
    if (!d || !d->initialized) { push_error_locked(HD_BAD_HANDLE, current); return NULL; }
    return d;
}

/* ---- devices ---------------------------------------------------------------- */

EXPORT HHD hdInitDevice(HDstring config) {
    const char *name = config ? config : NAMES[0];
    HHD h = HD_INVALID_HANDLE;
    LOCK();
    for (int i = 0; i < N_DEVICES; i++)
        if (strcmp(name, NAMES[i]) == 0) h = (HHD)i + 1;
    if (h == HD_INVALID_HANDLE) {
        push_error_locked(HD_COMM_CONFIG_ERROR, h);
    } else if (devices[h - 1].initialized) {
        push_error_locked(HD_DEVICE_ALREADY_INITIATED, h);
        h = HD_INVALID_HANDLE;
    } else {
        devices[h - 1].initialized = 1;
        current = h;
    }
    UNLOCK();
    record("hdInitDevice %s -> %d", name, (int)h);
    return h;
}

EXPORT void hdDisableDevice(HHD h) {
    LOCK();
    Device *d = device(h);
    if (!d || !d->initialized) push_error_locked(HD_BAD_HANDLE, h);
    else d->initialized = d->force_output = 0;
    if (current == h) current = HD_INVALID_HANDLE;
    UNLOCK();
    record("hdDisableDevice %u", h);
}

EXPORT void hdMakeCurrentDevice(HHD h) {
    LOCK();
    Device *d = device(h);
    if (!d || !d->initialized) push_error_locked(HD_BAD_HANDLE, h);
    else current = h;
    UNLOCK();
}

EXPORT void hdBeginFrame(HHD h) {
    LOCK();
    Device *d = device(h);
    if (!d || !d->initialized) push_error_locked(HD_BAD_HANDLE, h);
    else if (frame != HD_INVALID_HANDLE) push_error_locked(HD_ILLEGAL_BEGIN, h);
    else { frame = current = h; memset(d->force, 0, sizeof d->force); }
    UNLOCK();
}

EXPORT void hdEndFrame(HHD h) {
    LOCK();
    Device *d = device(h);
    if (!d || frame != h) {
        push_error_locked(HD_ILLEGAL_END, h);
    } else {
        double *out = d->log[d->frames % FORCE_LOG];
        for (int k = 0; k < 3; k++) out[k] = d->force_output ? d->force[k] : 0.0;
        d->frames++;
        frame = HD_INVALID_HANDLE;
    }
    UNLOCK();
}

static void set_enabled(HDenum cap, int on) {
    LOCK();
    Device *d = current_locked();
    if (d && cap == HD_FORCE_OUTPUT) d->force_output = on;
    else if (d) push_error_locked(HD_INVALID_ENUM, current);
    UNLOCK();
    record("%s 0x%x device %u", on ? "hdEnable" : "hdDisable", cap, current);
}

EXPORT void hdEnable(HDenum cap) { set_enabled(cap, 1); }
EXPORT void hdDisable(HDenum cap) { set_enabled(cap, 0); }

/* ---- state ------------------------------------------------------------------ */

EXPORT void hdGetDoublev(HDenum pname, double *out) {
    LOCK();
    Device *d = current_locked();
    if (d) {
        switch (pname) {
        case HD_CURRENT_TRANSFORM: memcpy(out, d->pose, sizeof d->pose); break;
        case HD_CURRENT_FORCE: memcpy(out, d->force, sizeof d->force); break;
        case HD_NOMINAL_MAX_CONTINUOUS_FORCE: out[0] = MAX_CONTINUOUS_FORCE; break;
        case HD_NOMINAL_MAX_FORCE: out[0] = MAX_FORCE; break;
        default: push_error_locked(HD_INVALID_ENUM, current);
        }
    }
    UNLOCK();
}

EXPORT void hdGetIntegerv(HDenum pname, int *out) {
    LOCK();
    Device *d = current_locked();
    if (d && pname == HD_CURRENT_BUTTONS) out[0] = d->buttons;
    else if (d) push_error_locked(HD_INVALID_ENUM, current);
    UNLOCK();
}

EXPORT void hdSetDoublev(HDenum pname, const double *in) {
    LOCK();
    Device *d = current_locked();
    if (d && pname != HD_CURRENT_FORCE) {
        push_error_locked(HD_INVALID_ENUM, current);
    } else if (d && frame != current) {
        push_error_locked(HD_INVALID_OPERATION, current);
    } else if (d) {
        memcpy(d->force, in, sizeof d->force);
        if (sqrt(in[0] * in[0] + in[1] * in[1] + in[2] * in[2]) > MAX_FORCE)
            push_error_locked(HD_EXCEEDED_MAX_FORCE, current);
    }
    UNLOCK();
}

EXPORT HDstring hdGetString(HDenum pname) {
    LOCK();
    Device *d = current_locked();
    HDstring s = NULL;
    if (d && pname == HD_DEVICE_MODEL_TYPE) s = "Fake Touch";
    else if (d) push_error_locked(HD_INVALID_ENUM, current);
    UNLOCK();
    return s;
}

EXPORT HDErrorInfo hdGetError(void) {
    HDErrorInfo e = {HD_SUCCESS, 0, HD_INVALID_HANDLE};
    LOCK();
    if (n_errors > 0) e = errors[--n_errors];
    UNLOCK();
    return e;
}

EXPORT HDstring hdGetErrorString(HDerror code) {
    return code == HD_SUCCESS ? "No error" : code == HD_INVALID_ENUM ? "Invalid enumerant"
         : code == HD_INVALID_VALUE ? "Invalid value" : code == HD_BAD_HANDLE ? "Bad handle"
         : code == HD_INVALID_OPERATION ? "Invalid operation"
         : code == HD_DEVICE_FAULT ? "Device fault"
         : code == HD_COMM_CONFIG_ERROR ? "No device of that name" : "Fake libHD error";
}

EXPORT HDenum hdCheckCalibration(void) {
    LOCK();
    Device *d = current_locked();
    HDenum status = d ? d->calibration : HD_CALIBRATION_OK;
    UNLOCK();
    return status;
}

EXPORT void hdUpdateCalibration(HDenum style) {
    LOCK();
    Device *d = current_locked();
    if (d && (style == 0 || (style & ~HD_CALIBRATION_STYLES) || (style & (style - 1))))
        push_error_locked(HD_INVALID_VALUE, current);
    else if (d && d->calibration == HD_CALIBRATION_NEEDS_UPDATE)
        d->calibration = HD_CALIBRATION_OK;
    UNLOCK();
    record("hdUpdateCalibration %u device %u", style, current);
}

/* ---- scheduler -------------------------------------------------------------- */

static void remove_callback(int i) {  /* sched_lock held */
    memmove(callbacks + i, callbacks + i + 1, (size_t)(n_callbacks - i - 1) * sizeof *callbacks);
    n_callbacks--;
}

static void *servo_main(void *arg) {
    (void)arg;
    on_servo = 1;
    long period = (long)(1000000000.0 / (double)rate);
    struct timespec next, now;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (!__atomic_load_n(&stop_requested, __ATOMIC_ACQUIRE)) {
        next.tv_nsec += period;
        while (next.tv_nsec >= 1000000000L) { next.tv_nsec -= 1000000000L; next.tv_sec++; }
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR) {}
        pthread_mutex_lock(&sched_lock);
        for (int i = 0; i < n_callbacks; i++)
            if (callbacks[i].fn(callbacks[i].user) == HD_CALLBACK_DONE) remove_callback(i--);
        __atomic_add_fetch(&ticks, 1, __ATOMIC_RELEASE);
        pthread_mutex_unlock(&sched_lock);
        clock_gettime(CLOCK_MONOTONIC, &now);  /* more than 10 ticks behind: drop them */
        double behind = (double)(now.tv_sec - next.tv_sec) * 1e9
                      + (double)(now.tv_nsec - next.tv_nsec);
        if (behind > 10.0 * (double)period) next = now;
    }
    return NULL;
}

EXPORT void hdSetSchedulerRate(HDulong hz) {
    if (hz < 100 || hz > 2000 || running) push_error(HD_INVALID_VALUE, current);
    else rate = hz;
    record("hdSetSchedulerRate %lu", hz);
}

EXPORT void hdStartScheduler(void) {
    record("hdStartScheduler");
    if (running) { push_error(HD_INVALID_OPERATION, current); return; }
    __atomic_store_n(&stop_requested, 0, __ATOMIC_RELEASE);
    running = pthread_create(&servo, NULL, servo_main, NULL) == 0;
    if (!running) push_error(HD_TIMER_ERROR, current);
}

EXPORT void hdStopScheduler(void) {
    record("hdStopScheduler");
    if (!running || on_servo) return;
    __atomic_store_n(&stop_requested, 1, __ATOMIC_RELEASE);
    pthread_join(servo, NULL);
    running = 0;
}

EXPORT HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback fn, void *user,
                                                HDushort priority) {
    HDSchedulerHandle id = 0;
    if (!on_servo) pthread_mutex_lock(&sched_lock);
    if (n_callbacks == MAX_CALLBACKS) {
        push_error(HD_SCHEDULER_FULL, current);
    } else {
        int i = n_callbacks++;
        for (; i > 0 && callbacks[i - 1].priority < priority; i--) callbacks[i] = callbacks[i - 1];
        id = next_id++;
        callbacks[i] = (Callback){fn, user, priority, id};
    }
    if (!on_servo) pthread_mutex_unlock(&sched_lock);
    record("hdScheduleAsynchronous %lu priority %u", id, (unsigned)priority);
    return id;
}

EXPORT void hdUnschedule(HDSchedulerHandle id) {
    int found = 0;
    if (!on_servo) pthread_mutex_lock(&sched_lock);
    for (int i = 0; i < n_callbacks && !found; i++)
        if (callbacks[i].id == id) { remove_callback(i); found = 1; }
    if (!on_servo) pthread_mutex_unlock(&sched_lock);
    if (!found) push_error(HD_INVALID_VALUE, current);
    record("hdUnschedule %lu", id);
}

/* ---- test controls ---------------------------------------------------------- */

/* Stop the scheduler and forget all devices, callbacks, errors and logged calls. */
EXPORT void fakehd_reset(void) {
    hdStopScheduler();
    pthread_mutex_lock(&sched_lock);
    n_callbacks = 0, next_id = 1, rate = 1000, ticks = 0;
    pthread_mutex_unlock(&sched_lock);
    LOCK();
    memset(devices, 0, sizeof devices);
    for (int i = 0; i < N_DEVICES; i++) {
        devices[i].calibration = HD_CALIBRATION_OK;
        for (int k = 0; k < 4; k++) devices[i].pose[5 * k] = 1.0;
    }
    n_errors = 0, n_calls = 0, calls[0] = '\0';
    UNLOCK();
    current = frame = HD_INVALID_HANDLE;
}

__attribute__((constructor)) static void fakehd_init(void) { fakehd_reset(); }

/* The stylus transform of device h: 16 doubles, column-major, translation [mm]. */
EXPORT int fakehd_set_pose(HHD h, const double m[16]) {
    Device *d = device(h);
    if (!d) return -1;
    LOCK(); memcpy(d->pose, m, sizeof d->pose); UNLOCK();
    return 0;
}

/* The HD_CURRENT_BUTTONS bitmask of device h. */
EXPORT int fakehd_set_buttons(HHD h, int buttons) {
    Device *d = device(h);
    if (!d) return -1;
    LOCK(); d->buttons = buttons; UNLOCK();
    return 0;
}

/* The status hdCheckCalibration reports for the named device (NULL: the default). */
EXPORT int fakehd_set_calibration(const char *name, HDenum status) {
    for (int i = 0; i < N_DEVICES; i++) {
        if (strcmp(name ? name : NAMES[0], NAMES[i]) == 0) {
            LOCK(); devices[i].calibration = status; UNLOCK();
            return 0;
        }
    }
    return -1;
}

/* Push n errors of device h at once (the last one is popped first). */
EXPORT void fakehd_push_errors(HHD h, const HDerror *codes, int n) {
    LOCK();
    for (int i = 0; i < n; i++) push_error_locked(codes[i], h);
    UNLOCK();
}

EXPORT int fakehd_error_count(void) { LOCK(); int n = n_errors; UNLOCK(); return n; }

/* Copy the output forces [N] of the latest frames of h (at most max, oldest first,
 * 3 doubles each) into out; return how many. */
EXPORT int fakehd_forces(HHD h, double *out, int max) {
    Device *d = device(h);
    if (!d || max < 0) return -1;
    LOCK();
    unsigned long n = d->frames < FORCE_LOG ? d->frames : FORCE_LOG;
    if (n > (unsigned long)max) n = (unsigned long)max;
    for (unsigned long i = 0; i < n; i++)
        memcpy(out + 3 * i, d->log[(d->frames - n + i) % FORCE_LOG], 3 * sizeof(double));
    UNLOCK();
    return (int)n;
}

/* Frames (hdBeginFrame .. hdEndFrame) of device h so far. */
EXPORT unsigned long fakehd_frame_count(HHD h) {
    Device *d = device(h);
    if (!d) return 0;
    LOCK(); unsigned long n = d->frames; UNLOCK();
    return n;
}

/* Scheduler ticks since the last reset. */
EXPORT unsigned long fakehd_tick_count(void) { return __atomic_load_n(&ticks, __ATOMIC_ACQUIRE); }

/* 1 when h is initialized (and, for cap != 0, has capability cap enabled), else 0. */
EXPORT int fakehd_is_enabled(HHD h, HDenum cap) {
    Device *d = device(h);
    if (!d) return 0;
    LOCK();
    int on = d->initialized && (!cap || (cap == HD_FORCE_OUTPUT && d->force_output));
    UNLOCK();
    return on;
}

EXPORT int fakehd_scheduled_count(void) {
    pthread_mutex_lock(&sched_lock); int n = n_callbacks; pthread_mutex_unlock(&sched_lock);
    return n;
}

EXPORT int fakehd_scheduler_running(void) { return running; }

/* Copy the logged lifecycle calls (one per line) into out; return their length. */
EXPORT int fakehd_calls(char *out, int size) {
    if (size <= 0) return -1;
    LOCK();
    int n = (int)n_calls < size - 1 ? (int)n_calls : size - 1;
    memcpy(out, calls, (size_t)n);
    out[n] = '\0';
    UNLOCK();
    return n;
}
