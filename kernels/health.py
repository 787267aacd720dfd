"""Simulation-fault detection: non-finite values and runaway velocities.

Uses the IEEE-754 exponent bits rather than ``x != x`` comparisons, which fast-math
code generation (the default in Taichi) may fold away.
"""

import taichi as ti

EXPONENT_MASK = 0x7F800000
NO_FAULT = 2**31 - 1
"""``fault_particle`` while no particle faulted (faults keep the lowest index)."""


@ti.func
def is_finite_vec(u):
    """True when every component of ``u`` is a finite f32 (neither inf nor NaN)."""
    finite = True
    for k in ti.static(range(u.n)):
        if (ti.bit_cast(u[k], ti.i32) & EXPONENT_MASK) == EXPONENT_MASK:
            finite = False
    return finite


@ti.func
def report_fault(state: ti.template(), i, x, v, speed_limit):
    """Flag particle ``i`` in ``state.fault`` when ``x`` [m] or ``v`` [m/s] is not
    finite or ``|v|`` exceeds ``speed_limit`` [m/s]; keeps the lowest such index."""
    if not (is_finite_vec(x) and is_finite_vec(v)) or v.norm_sqr() > speed_limit * speed_limit:
        state.fault[None] = 1
        ti.atomic_min(state.fault_particle[None], i)
