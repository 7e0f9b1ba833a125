"""The window metrics of a control tick, as pure pieces: the squared errors of one tick
(:func:`tick_terms`) and their running sums (:func:`summed`, :func:`add_terms` on a record), the
definitions of :func:`vtol_impedance.analysis.metrics`. The vehicle-by-vehicle engine calls them with its
records; the lanes take the terms of a whole block at once (:func:`~.lanes_controller.metric_terms_lanes`)
and, in a flight without a log, keep the sums in lanes too (:func:`~.lanes_controller.add_terms_lanes`)."""

from __future__ import annotations

import math

from .jit import kernel


@kernel(inline="always")
def tick_terms(p_o, v_o, r, f_hat, tau_hat, f_l, t_l):
    """``(e2, ev2, fe2, te2)``: the squared position and velocity errors of the body origin (``p_o``,
    ``v_o``, world) against the reference row ``r`` (``p_ref``, ``v_ref`` first), and of the estimate
    (``f_hat`` world, ``tau_hat`` Euler coordinates) against the lumped wrench ``f_l``, ``t_l``."""
    e2 = ev2 = fe2 = te2 = 0.0
    for i in range(3):
        e2 += (p_o[i] - r[i]) ** 2
        ev2 += (v_o[i] - r[3 + i]) ** 2
        fe2 += (f_hat[i] - f_l[i]) ** 2
        te2 += (tau_hat[i] - t_l[i]) ** 2
    return e2, ev2, fe2, te2


@kernel(inline="always")
def summed(s, t, win, e2, ev2, fe2, te2, sat):
    """The running sums ``s`` (the fields of :data:`~.layouts.ACCUMULATORS` in order: ``n, e2, e_max, ev2,
    f2, t2, sat, n_tail, e_tail``) after a tick at ``t`` with its terms and ``sat`` (1 where the command
    saturated or the tilt was limited), ``win = [t0, t1, tail_start]``."""
    e = math.sqrt(e2)
    tail = t >= win[2]
    return (s[0] + 1.0, s[1] + e2, max(s[2], e), s[3] + ev2, s[4] + fe2, s[5] + te2, s[6] + sat,
            s[7] + 1.0 if tail else s[7], s[8] + e if tail else s[8])  # fmt: skip


@kernel(inline="always")
def add_terms(a, t, win, e2, ev2, fe2, te2, sat):
    """The record ``a`` (:data:`~.layouts.ACCUMULATORS`) takes a tick: :func:`summed`."""
    s = summed((a.n, a.e2, a.e_max, a.ev2, a.f2, a.t2, a.sat, a.n_tail, a.e_tail), t, win, e2, ev2, fe2, te2, sat)
    a.n, a.e2, a.e_max, a.ev2, a.f2, a.t2, a.sat, a.n_tail, a.e_tail = s
