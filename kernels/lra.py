"""Relaxed long-range attachments for fascia: seed 000 §3.2, Eq. 3.

Each free particle x_i keeps its rest distance d' to each of its attached anchors
x^a (Kim et al. 2012). Seed 000 relaxes the bound so the fascia far from its
attachment can stretch:

    d_LRA = d' + β max(|x^a - x_i| - d', 0)                       (Eq. 3)

and projects x_i back onto the sphere of radius d_LRA around x^a when it is
outside. β = 0 is the hard LRA of Kim et al. The corrections from a particle's
several anchors are averaged, Jacobi style.
"""

import taichi as ti


@ti.func
def lra_correction(model: ti.template(), positions: ti.template(), i, p):
    """Averaged Eq. 3 correction for particle ``i`` at ``p`` [m]; anchors are read
    from ``positions``. Returns a zero vector when no anchor is violated."""
    begin, end = model.lra_begin[i], model.lra_end[i]
    delta = ti.Vector([0.0, 0.0, 0.0])
    if end > begin:
        beta = model.lra_relaxation[i]
        for s in range(begin, end):
            d = p - positions[model.lra_anchor[s]]
            dist = d.norm()
            rest = model.lra_rest[s]
            bound = rest + beta * ti.max(dist - rest, 0.0)
            if dist > bound:
                delta -= (dist - bound) * d / dist
        delta /= end - begin
    return delta
