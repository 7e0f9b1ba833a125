"""The control law, eqs. (14)-(20), of a block of vehicles in SIMD lanes.

After a block's estimators sample in lanes (:mod:`.lanes_estimator`), :func:`law_lanes` runs each lane's
:func:`~.controller.law_request` (a :data:`~.controller.LawLane` read from the rows), then the allocation's
first step for every lane (:func:`~.controller.yaw_room`, :func:`~.controller.yaw_fits`,
:func:`~.controller.with_yaw`: full roll and pitch with the largest yaw that fits); the rare lane where that
step does not hold takes the whole allocation vehicle by vehicle (:func:`fix_allocation`). :func:`finish_lanes`
then sums ``E f`` (eq. (4)), updates the PID integral (:func:`~.controller.law_integral`) and hands the rotor
commands and the held thrust and moments to the plant's and the estimators' rows. The arithmetic is that of
:func:`~.controller.control_law`, not a copy of it; the sines come from :mod:`.vmath`, so a lane's command parts
from the vehicle-by-vehicle one by their last bits (``tests/test_lanes_controller.py``). A vehicle's record
(:data:`~.layouts.OUTPUT`, for its metrics and log) is read back by :func:`get_output`.

Rows (:data:`~.lanes.W` doubles each) of the buffer ``cb`` (:func:`new_law_buffer`): the :data:`LawLane` (58),
the allocation's ``E_pinv`` (four per rotor), ``E`` (four per rotor), the rotor limits; the state the law
carries (the attitude filter (5), the integral (3)); the measurement (12); the law's request (thrust, moments,
whether a limit acted, ``mu_bar``, the position error, the filter's next state, the attitude command, the
estimated moment in body axes: 22); the allocation's first step (whether it held, saturation and scales: 4),
each rotor's force before yaw and its command; the thrust and moments given (4); a copy of the estimator's
sample (``Q``, ``M``, ``C``, the estimate and its rate: 39), so that the law's loop reads one buffer; the
tick's window-metric terms (5, :func:`metric_terms_lanes`).
"""

from __future__ import annotations

from ..model.vehicle import MAX_ROTORS
from .controller import (
    LawLane,
    _allocate,
    law_design,
    law_integral,
    law_request,
    put_output,
    with_yaw,
    yaw_fits,
    yaw_room,
)
from .jit import kernel
from .lanes import W, aligned_zeros, observed_rows, put_command_row, put_held
from .lanes_estimator import _CC, _MM, _QQ, _RD, _WH, _six, _three, put_command_held, sample_at
from .metrics import summed, tick_terms

_R = MAX_ROTORS
_LP = 0  # LawLane: mass, I9 (9), tan_tilt, min_lift, compensate, comply, integral_limit, 11 gains (3 each),
#  1 / mass, 1 / Md (3), 1 / Mo_d (3), the integral's bound (3)
_EP = _LP + 58  # E_pinv[r, c] at row _EP + 4 r + c
_EE = _EP + 4 * _R  # E[c, r] at row _EE + 4 r + c
_FMIN = _EE + 4 * _R
_FMAX = _FMIN + _R
_ST = _FMAX + _R  # filter: started, phi, theta, phi_dot, theta_dot; integral (3)
_YY = _ST + 8  # the measurement y (12)
_RQ = _YY + 12  # thrust, moments (3), limited, mu_bar (3), position error (3), next filter (4), command (4), hb (3)
_AL = _RQ + 22  # whether the allocation's first step held, saturated, rp_scale, yaw_scale
_BASE = _AL + 4  # each rotor's force before yaw
_F = _BASE + _R  # each rotor's command
_U = _F + _R  # thrust and moments given (E f)
_SM = _U + 4  # the estimator's sample: Q, M, C (9 each), the estimate and its rate (6 each)
_MT = _SM + 39  # the tick's window-metric terms: e2, ev2, fe2, te2, sat
ROWS = _MT + 5


@kernel()
def new_law_buffer():
    """A zeroed control-law buffer (``ROWS * W`` doubles, 64-byte aligned: :func:`~.lanes.aligned_zeros`)."""
    return aligned_zeros(ROWS * W)


@kernel(inline="always")
def _at(cb, row, i):
    return cb[row * W + i]


@kernel(inline="always")
def _nine(cb, row, i):
    return _three(cb, row, i) + _three(cb, row + 3, i) + _three(cb, row + 6, i)


@kernel(inline="always")
def _copy_rows(dst, at, src, row, n):
    """Rows ``at .. at + n - 1`` of ``dst`` take rows ``row ..`` of ``src``."""
    for j in range(n * W):
        dst[at * W + j] = src[row * W + j]


@kernel(inline="always")
def _put(cb, row, i, v):
    """Rows ``row ..`` of lane ``i`` take the tuple ``v`` (unrolled: the lane loops stay vector code)."""
    for j in range(len(v)):
        cb[(row + j) * W + i] = v[j]


@kernel(inline="always")
def _law_at(cb, i):
    """Lane ``i``'s :data:`LawLane` (the order of :func:`put_law`)."""
    k = _LP * W + i

    def at(j):
        return cb[k + j * W]

    def g(j):
        return (at(j), at(j + 1), at(j + 2))

    return LawLane(
        at(0), (at(1), at(2), at(3), at(4), at(5), at(6), at(7), at(8), at(9)), at(10), at(11), at(12), at(13),
        at(14), g(15), g(18), g(21), g(24), g(27), g(30), g(33), g(36), g(39), g(42), g(45), at(48), g(49), g(52),
        g(55),
    )  # fmt: skip


@kernel()
def put_law(cb, i, c, p):
    """Lane ``i`` takes the controller of the record ``p`` (its :data:`LawLane` ``c``, rotor layout and limits)."""
    k = _LP * W + i
    cb[k] = c.mass
    for j in range(9):
        cb[k + (1 + j) * W] = c.I9[j]
    head = (c.tan_tilt, c.min_lift_accel, c.compensate, c.comply_enable, c.integral_limit)
    for j in range(5):
        cb[k + (10 + j) * W] = head[j]
    gains = (c.Kp, c.Dp, c.Ki, c.Do, c.Ko, c.Md, c.Dd, c.Kd, c.Mo_d, c.Do_d, c.Ko_d)
    for g in range(11):
        for j in range(3):
            cb[k + (15 + 3 * g + j) * W] = gains[g][j]
    cb[k + 48 * W] = c.inv_mass
    for j in range(3):
        cb[k + (49 + j) * W] = c.inv_Md[j]
        cb[k + (52 + j) * W] = c.inv_Mo_d[j]
        cb[k + (55 + j) * W] = c.integral_bound[j]
    for r in range(p.n_rotors):
        for c4 in range(4):
            cb[(_EP + 4 * r + c4) * W + i] = p.E_pinv[r, c4]
            cb[(_EE + 4 * r + c4) * W + i] = p.E[c4, r]
        cb[(_FMIN + r) * W + i] = p.f_min[r]
        cb[(_FMAX + r) * W + i] = p.f_max[r]


@kernel()
def put_law_state(cb, i, s):
    """Lane ``i`` takes what the law carries of the state record ``s`` (attitude filter, PID integral, the
    thrust and moments held)."""
    _put(cb, _ST, i, (1.0 if s.filt_started else 0.0, s.filt_x[0], s.filt_x[1], s.filt_xd[0], s.filt_xd[1]))
    _put(cb, _ST + 5, i, (s.integral[0], s.integral[1], s.integral[2]))
    _put(cb, _U, i, (s.thrust_prev, s.tau_B_prev[0], s.tau_B_prev[1], s.tau_B_prev[2]))


@kernel()
def get_law_state(cb, i, s):
    """The record ``s`` takes lane ``i``'s law state and the thrust and moments it holds (inverse of
    :func:`put_law_state`)."""
    s.filt_started = cb[_ST * W + i] > 0.5
    s.filt_x[0], s.filt_x[1] = _at(cb, _ST + 1, i), _at(cb, _ST + 2, i)
    s.filt_xd[0], s.filt_xd[1] = _at(cb, _ST + 3, i), _at(cb, _ST + 4, i)
    for j in range(3):
        s.integral[j] = _at(cb, _ST + 5 + j, i)
        s.tau_B_prev[j] = _at(cb, _U + 1 + j, i)
    s.thrust_prev = _at(cb, _U, i)


@kernel(inline="always")
def put_measurement(cb, i, y):
    """Lane ``i``'s measurement ``y = [p_W, v_W, eta, eta_dot]``."""
    for j in range(12):
        cb[(_YY + j) * W + i] = y[j]


@kernel(inline="always")
def _row18(r):
    """The reference row (18: with every comply fraction) as a tuple."""
    return (r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], r[12], r[13], r[14], r[15], r[16],
            r[17])  # fmt: skip


@kernel(inline="always")
def put_measurement_rows(cb, src, row):
    """Every lane's measurement from rows ``row .. row + 11`` (``y``) of another buffer of rows."""
    for j in range(12 * W):
        cb[_YY * W + j] = src[row * W + j]


@kernel()
def law_lanes(cb, eb, d, r, n_rotors):
    """Every lane's :func:`~.controller.law_request` given its estimator's sample (``eb``, after
    :func:`~.lanes_estimator.estimate_lanes`) and the reference row ``r`` (the same for all), then the
    allocation's first step over ``n_rotors`` rotors (a literal count keeps the loop vector code); returns
    whether it held in every lane (else :func:`fix_allocation` the lanes where :func:`allocation_held` is
    false)."""
    g = law_design(d)  # read before the lane loop: values, not loads that might alias the rows
    rt = _row18(r)
    # the sample into rows of cb: the lane loop then reads and writes one buffer at fixed distances, with no
    # run-time check that two buffers do not overlap (too many for the vectoriser)
    _copy_rows(cb, _SM, eb, _QQ, 9)
    _copy_rows(cb, _SM + 9, eb, _MM, 9)
    _copy_rows(cb, _SM + 18, eb, _CC, 9)
    _copy_rows(cb, _SM + 27, eb, _WH, 6)
    _copy_rows(cb, _SM + 33, eb, _RD, 6)
    held = 0
    for i in range(W):  # vectorised: one lane per vehicle
        c = _law_at(cb, i)
        y = (_at(cb, _YY, i), _at(cb, _YY + 1, i), _at(cb, _YY + 2, i), _at(cb, _YY + 3, i), _at(cb, _YY + 4, i),
             _at(cb, _YY + 5, i), _at(cb, _YY + 6, i), _at(cb, _YY + 7, i), _at(cb, _YY + 8, i),
             _at(cb, _YY + 9, i), _at(cb, _YY + 10, i), _at(cb, _YY + 11, i))  # fmt: skip
        Q, M, C, w, rd = (
            _nine(cb, _SM, i),
            _nine(cb, _SM + 9, i),
            _nine(cb, _SM + 18, i),
            _six(cb, _SM + 27, i),
            _six(cb, _SM + 33, i),
        )  # noqa: N806
        filt = (_at(cb, _ST, i) > 0.5, _at(cb, _ST + 1, i), _at(cb, _ST + 2, i), _at(cb, _ST + 3, i),
                _at(cb, _ST + 4, i))  # fmt: skip
        req, tr, lim, mb, ep, fx, ed, hb = law_request(c, g, y, rt, Q, M, C, w, rd, _three(cb, _ST + 5, i), filt,
                                                       True)  # fmt: skip
        _put(cb, _RQ, i, (req, tr[0], tr[1], tr[2], 1.0 if lim else 0.0))
        _put(cb, _RQ + 5, i, mb)
        _put(cb, _RQ + 8, i, ep)
        _put(cb, _RQ + 11, i, fx)
        _put(cb, _RQ + 15, i, ed)
        _put(cb, _RQ + 19, i, hb)
        # the allocation's first step: full roll/pitch at the requested thrust, with the largest yaw that fits
        a_lo, a_hi, flat = 0.0, 1.0, False
        for k in range(n_rotors):  # unrolled where the count is a literal: the lane loop stays vector code
            e = (_at(cb, _EP + 4 * k, i), _at(cb, _EP + 4 * k + 1, i), _at(cb, _EP + 4 * k + 2, i),
                 _at(cb, _EP + 4 * k + 3, i))  # fmt: skip
            lo, hi = _at(cb, _FMIN + k, i), _at(cb, _FMAX + k, i)
            base, a_lo, a_hi, flat = yaw_room(e, lo, hi, req, tr[0], tr[1], tr[2], a_lo, a_hi, flat)
            cb[(_BASE + k) * W + i] = base
        fits, ys = yaw_fits(a_lo, a_hi, flat)
        for k in range(n_rotors):
            e3, lo, hi = _at(cb, _EP + 4 * k + 3, i), _at(cb, _FMIN + k, i), _at(cb, _FMAX + k, i)
            cb[(_F + k) * W + i] = with_yaw(_at(cb, _BASE + k, i), ys, e3, tr[2], lo, hi)
        _put(cb, _AL, i, (1.0 if fits else 0.0, 1.0 if ys < 1.0 - 1e-9 else 0.0, 1.0, ys))
        held += 1 if fits else 0
    return held == W


@kernel(inline="always")
def allocation_held(cb, i):
    """Whether the allocation's first step held in lane ``i`` (:func:`law_lanes`)."""
    return cb[_AL * W + i] > 0.5


@kernel()
def fix_allocation(cb, i, p, f):
    """Lane ``i``'s whole allocation (:func:`~.controller._allocate` with the controller record ``p``, ``f``
    scratch of its rotor count), where its first step did not hold."""
    sat, rp_scale, yaw_scale = _allocate(p, _at(cb, _RQ, i), _at(cb, _RQ + 1, i), _at(cb, _RQ + 2, i),
                                         _at(cb, _RQ + 3, i), f)  # fmt: skip
    for k in range(p.n_rotors):
        cb[(_F + k) * W + i] = f[k]
    _put(cb, _AL + 1, i, (1.0 if sat else 0.0, rp_scale, yaw_scale))


@kernel()
def finish_lanes(cb, eb, buf, d, n_rotors):
    """Every lane after its allocation: ``E f`` (eq. (4): the thrust and moments given), the PID integral
    (:func:`~.controller.law_integral`), the attitude filter's next state; the rotor commands into the plant's
    rows ``buf``, the thrust and moments held over the period into ``buf``'s and the estimators' ``eb``."""
    Ts = d.Ts
    for j in range(4):
        for i in range(W):
            cb[(_U + j) * W + i] = 0.0
    for k in range(n_rotors):  # eq. (4), summed in rotor order as controller._mix_row
        for i in range(W):  # vectorised: one lane per vehicle
            f = _at(cb, _F + k, i)
            for j in range(4):
                cb[(_U + j) * W + i] += cb[(_EE + 4 * k + j) * W + i] * f
    for i in range(W):  # vectorised: one lane per vehicle
        c = _law_at(cb, i)
        freeze = _at(cb, _AL + 1, i) > 0.5 or _at(cb, _RQ + 4, i) > 0.5
        _put(cb, _ST + 5, i, law_integral(c, Ts, _three(cb, _ST + 5, i), _three(cb, _RQ + 8, i), freeze))
        _put(cb, _ST, i, (1.0, _at(cb, _RQ + 11, i), _at(cb, _RQ + 12, i), _at(cb, _RQ + 13, i),
                          _at(cb, _RQ + 14, i)))  # fmt: skip
        u, to = _at(cb, _U, i), _three(cb, _U + 1, i)
        put_held(buf, i, u, to)
        put_command_held(eb, i, u, to)
    for k in range(n_rotors):
        for i in range(W):
            put_command_row(buf, k, i, cb[(_F + k) * W + i])


@kernel()
def get_output(cb, eb, i, r, o):
    """The :data:`~.layouts.OUTPUT` record ``o`` of lane ``i`` after :func:`finish_lanes` (``r``: the reference
    row the law was given), as :func:`~.controller.control_law` writes it."""
    for k in range(_R):
        o.f_rotor[k] = _at(cb, _F + k, i)
    _, _, _, w, _ = sample_at(eb, i)
    tr = _three(cb, _RQ + 1, i)
    ed = (_at(cb, _RQ + 15, i), _at(cb, _RQ + 16, i), _at(cb, _RQ + 17, i), _at(cb, _RQ + 18, i))
    put_output(o, _at(cb, _U, i), _three(cb, _U + 1, i), _at(cb, _AL + 1, i) > 0.5, _at(cb, _RQ, i), tr, w,
               _three(cb, _RQ + 19, i), ed, r, _three(cb, _RQ + 5, i), _at(cb, _RQ + 4, i) > 0.5,
               _at(cb, _AL + 2, i), _at(cb, _AL + 3, i))  # fmt: skip


@kernel(inline="always")
def metric_terms_lanes(cb, buf, r):
    """The window metrics' terms of the tick for every lane (:func:`~.metrics.tick_terms` and the
    saturation flag, as one vehicle's ``_accumulate`` takes them from its record) into rows read by
    :func:`metric_terms_at`: after :func:`finish_lanes` (the estimate, the flags) and
    :func:`~.lanes.observe_lanes` (the body origin's motion, the lumped wrench of ``buf``); ``r`` is the
    tick's reference row (its first six, ``p_ref`` and ``v_ref`` at the tick, are what the metrics read)."""
    rr = (r[0], r[1], r[2], r[3], r[4], r[5])  # read before the loop: it might alias the rows written
    for i in range(W):  # vectorised: one lane per vehicle
        _, f_l, t_l, p_o, v_o = observed_rows(buf, i)
        e2, ev2, fe2, te2 = tick_terms(p_o, v_o, rr, _three(cb, _SM + 27, i), _three(cb, _SM + 30, i), f_l, t_l)
        k = _MT * W + i
        cb[k] = e2
        cb[k + W] = ev2
        cb[k + 2 * W] = fe2
        cb[k + 3 * W] = te2
        cb[k + 4 * W] = 1.0 if (_at(cb, _AL + 1, i) > 0.5 or _at(cb, _RQ + 4, i) > 0.5) else 0.0


@kernel(inline="always")
def metric_terms_at(cb, i):
    """Lane ``i``'s ``(e2, ev2, fe2, te2, sat)`` of :func:`metric_terms_lanes`."""
    k = _MT * W + i
    return cb[k], cb[k + W], cb[k + 2 * W], cb[k + 3 * W], cb[k + 4 * W]


N_SUMS = 9  #: rows of the window metrics' running sums in lanes (the fields of ``ACCUMULATORS``, in order)


@kernel()
def add_terms_lanes(cb, A, t, win, flying):  # noqa: N803
    """The running sums ``A`` (:data:`N_SUMS` rows of :data:`~.lanes.W`: :func:`put_sums`) of the lanes
    ``flying`` take the tick's terms of :func:`metric_terms_lanes` (:func:`~.metrics.summed`, as one
    vehicle's record takes them); the other lanes keep theirs."""
    for i in range(W):  # vectorised: one lane per vehicle
        e2, ev2, fe2, te2, sat = metric_terms_at(cb, i)
        s = (A[i], A[W + i], A[2 * W + i], A[3 * W + i], A[4 * W + i], A[5 * W + i], A[6 * W + i], A[7 * W + i],
             A[8 * W + i])  # fmt: skip
        v = summed(s, t, win, e2, ev2, fe2, te2, sat) if flying[i] else s
        A[i], A[W + i], A[2 * W + i], A[3 * W + i], A[4 * W + i] = v[0], v[1], v[2], v[3], v[4]
        A[5 * W + i], A[6 * W + i], A[7 * W + i], A[8 * W + i] = v[5], v[6], v[7], v[8]


@kernel(inline="always")
def put_sums(A, i, a):  # noqa: N803
    """Lane ``i`` of the sums ``A`` takes the record ``a`` (:data:`~.layouts.ACCUMULATORS`)."""
    A[i], A[W + i], A[2 * W + i], A[3 * W + i], A[4 * W + i] = a.n, a.e2, a.e_max, a.ev2, a.f2
    A[5 * W + i], A[6 * W + i], A[7 * W + i], A[8 * W + i] = a.t2, a.sat, a.n_tail, a.e_tail


@kernel(inline="always")
def get_sums(A, i, a):  # noqa: N803
    """The record ``a`` takes lane ``i`` of the sums ``A``."""
    a.n, a.e2, a.e_max, a.ev2, a.f2, a.t2 = A[i], A[W + i], A[2 * W + i], A[3 * W + i], A[4 * W + i], A[5 * W + i]
    a.sat, a.n_tail, a.e_tail = A[6 * W + i], A[7 * W + i], A[8 * W + i]
