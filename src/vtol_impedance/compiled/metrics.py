"""The window metrics of a control tick, as pure pieces: the squared errors of one tick
(:func:`tick_terms`) and their running sums (:func:`add_terms`), the definitions of
:func:`vtol_impedance.analysis.metrics`. The vehicle-by-vehicle engine calls both with its records; the
lanes take the terms of a whole block at once (:func:`~.lanes_controller.metric_terms_lanes`) and add
each vehicle's to its sums."""

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
def add_terms(a, t, win, e2, ev2, fe2, te2, sat):
    """The running sums :data:`~.layouts.ACCUMULATORS` ``a`` take a tick at ``t`` with its terms and
    ``sat`` (1 where the command saturated or the tilt was limited), ``win = [t0, t1, tail_start]``."""
    a.n += 1.0
    a.e2 += e2
    a.e_max = max(a.e_max, math.sqrt(e2))
    a.ev2 += ev2
    a.f2 += fe2
    a.t2 += te2
    a.sat += sat
    if t >= win[2]:
        a.n_tail += 1.0
        a.e_tail += math.sqrt(e2)
