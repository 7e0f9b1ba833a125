"""The momentum-based estimator, eqs. (6)-(13), of a block of vehicles in SIMD lanes.

:func:`vtol_impedance.compiled.engine.run_block_lanes` flies :data:`~.lanes.W` vehicles a block; once every
vehicle of a block has started (its first sample fills the history, and runs in :func:`~.estimator.estimator_update`
vehicle by vehicle), each control tick's estimator sample runs here for the whole block, then each vehicle's
:func:`~.controller.control_law` reads its result. The design (order, filter matrices, delays) is shared by the
run, so every loop bound and history index is the same for all lanes: only the values differ, one lane per
vehicle. The arithmetic is that of :mod:`.estimator`, not a copy of it: :func:`~.estimator.rotor_model`,
:func:`~.estimator.lerp`, :func:`~.estimator.lerp_angle`, :func:`~.estimator.residual` and
:func:`~.algebra._QMC`, with the sines of :mod:`.vmath` (code in lanes); only the filter's matrix products are
written over rows. The estimates part from the vehicle-by-vehicle estimator by those sines' last bits
(``tests/test_lanes_estimator.py``).

Rows (:data:`~.lanes.W` doubles each) of the buffer ``eb`` (:func:`new_estimator_buffer`): the measurement
``[v_W, eta, eta_dot]`` (9), the command held over the period that ends (4), the nominal mass and inertia
(10), the rotor model's output (4), the previous sample's momentum (6), ``Q`` and ``C`` (9 each: the previous
sample's until a sample, this one's after it), the previous Euler rates (3), ``M`` (9), the estimate and its
rate (6 each), the residual (6), the history values a sample reads (10), the newest history row (7), the filter
states (6 x :data:`~.layouts.MAX_ORDER`) and their update (:data:`~.layouts.MAX_ORDER`), the two history slots a
gather reads (2); then the history as a ring of ``H`` slots of 7 rows (the command through the rotor model (4),
the attitude (3)), ``head`` the newest.
"""

from __future__ import annotations

from .algebra import _QMC, _mv9
from .estimator import history_split, lerp, lerp_angle, residual, rotor_model
from .jit import kernel
from .lanes import W, aligned_zeros, copy_row, put_command_rows
from .layouts import MAX_ORDER

_Y = 0  # v_W (3), eta (3), eta_dot (3)
_CMD = 9  # thrust, tau_B held over the period that ends
_NOM = 13  # nominal mass, inertia (row-major 9)
_ACT = 23  # the rotor model's output
_QP = 27  # momentum (eq. (6)) at the previous sample
_QQ = 33  # Q (eq. (1c))
_CC = 42  # C (eq. (3b))
_DP = 51  # the previous sample's Euler rates
_MM = 54  # M (eq. (3b))
_WH = 63  # [f_hat_ext_W; tau_hat_ext_eta]
_RD = 69  # its rate
_WB = 75  # the residual w_bar
_GA = 81  # u_w, tau (3), the attitude at d_att + 1 (3) and at d_att (3)
_H0 = 91  # the newest history row: act (4), eta (3)
_XF = 98  # filter state of channel ch, index j: row _XF + MAX_ORDER ch + j
_XN = _XF + 6 * MAX_ORDER  # the filter's update
_GS = _XN + MAX_ORDER  # the two history slots a gather reads, at fixed rows
_RING = _GS + 2


@kernel()
def new_estimator_buffer(H):
    """A zeroed estimator buffer for a history of ``H`` rows (64-byte aligned: :func:`~.lanes.aligned_zeros`)."""
    return aligned_zeros((_RING + 7 * H) * W)


@kernel(inline="always")
def _three(eb, row, i):
    """Rows ``row .. row + 2`` of lane ``i``."""
    k = row * W + i
    return eb[k], eb[k + W], eb[k + 2 * W]


@kernel(inline="always")
def _six(eb, row, i):
    a, b = _three(eb, row, i), _three(eb, row + 3, i)
    return a[0], a[1], a[2], b[0], b[1], b[2]


@kernel(inline="always")
def _nine(eb, row, i):
    a, b, c = _three(eb, row, i), _three(eb, row + 3, i), _three(eb, row + 6, i)
    return a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]


@kernel(inline="always")
def _put3(eb, row, i, v):
    """Rows ``row .. row + 2`` of lane ``i`` take the tuple ``v`` (written out: the lane loops stay vector code)."""
    k = row * W + i
    eb[k], eb[k + W], eb[k + 2 * W] = v[0], v[1], v[2]


@kernel(inline="always")
def _put6(eb, row, i, v):
    _put3(eb, row, i, (v[0], v[1], v[2]))
    _put3(eb, row + 3, i, (v[3], v[4], v[5]))


@kernel(inline="always")
def _put9(eb, row, i, v):
    _put3(eb, row, i, (v[0], v[1], v[2]))
    _put3(eb, row + 3, i, (v[3], v[4], v[5]))
    _put3(eb, row + 6, i, (v[6], v[7], v[8]))


@kernel(inline="always")
def _put_rows(eb, row, i, v):
    """Lane ``i``'s rows from ``row`` take the values of the record field ``v``."""
    for j in range(len(v)):
        eb[(row + j) * W + i] = v[j]


@kernel()
def put_estimator(eb, i, s, h, head, mass, I9):  # noqa: N803
    """Lane ``i`` takes the estimator of the state record ``s`` and history ``h`` (most recent first) of a
    vehicle whose estimator has started, and its controller's nominal ``mass`` and inertia ``I9``; the ring's
    newest slot is ``head``."""
    H = h.shape[0]
    eb[_NOM * W + i] = mass
    _put_rows(eb, _NOM + 1, i, I9)
    put_command_rows(eb, _CMD, i, s.thrust_prev, s.tau_B_prev)
    _put_rows(eb, _ACT, i, s.act)
    _put_rows(eb, _QP, i, s.q_prev)
    _put_rows(eb, _QQ, i, s.Q_prev)
    _put_rows(eb, _CC, i, s.C_prev)
    _put_rows(eb, _DP, i, s.eta_dot_prev)
    _put_rows(eb, _WH, i, s.w_hat)
    _put_rows(eb, _RD, i, s.r_dot)
    for ch in range(6):
        _put_rows(eb, _XF + MAX_ORDER * ch, i, s.x[ch])
    for j in range(H):
        slot = _RING + 7 * ((head - j) % H)
        _put_rows(eb, slot, i, h[j].act)
        _put_rows(eb, slot + 4, i, h[j].eta)


@kernel()
def get_estimator(eb, i, s, h, head):
    """The records ``s``, ``h`` take lane ``i``'s estimator (the inverse of :func:`put_estimator`)."""
    H = h.shape[0]
    for j in range(4):
        s.act[j] = eb[(_ACT + j) * W + i]
    for j in range(6):
        s.q_prev[j] = eb[(_QP + j) * W + i]
        s.w_hat[j] = eb[(_WH + j) * W + i]
        s.r_dot[j] = eb[(_RD + j) * W + i]
        for c in range(MAX_ORDER):
            s.x[j, c] = eb[(_XF + MAX_ORDER * j + c) * W + i]
    for j in range(9):
        s.Q_prev[j] = eb[(_QQ + j) * W + i]
        s.C_prev[j] = eb[(_CC + j) * W + i]
    for j in range(3):
        s.eta_dot_prev[j] = eb[(_DP + j) * W + i]
    for j in range(H):
        slot = _RING + 7 * ((head - j) % H)
        for c in range(4):
            h[j].act[c] = eb[(slot + c) * W + i]
        for c in range(3):
            h[j].eta[c] = eb[(slot + 4 + c) * W + i]


@kernel(inline="always")
def put_measured(eb, i, y):
    """Lane ``i``'s measurement ``y = [p_W, v_W, eta, eta_dot]`` (the estimator reads the last nine)."""
    for j in range(9):
        eb[(_Y + j) * W + i] = y[3 + j]


@kernel(inline="always")
def put_measured_rows(eb, src, row):
    """Every lane's measurement from rows ``row .. row + 11`` (``y``) of another buffer of rows (the last nine)."""
    for j in range(9 * W):
        eb[_Y * W + j] = src[(row + 3) * W + j]


@kernel(inline="always")
def put_command_held(eb, i, u, tau):
    """Lane ``i``'s command held over the period that starts: thrust ``u`` and body moments ``tau``."""
    put_command_rows(eb, _CMD, i, u, tau)


@kernel(inline="always")
def sample_at(eb, i):
    """Lane ``i``'s ``Q, M, C`` (9-tuples), estimate and rate (6-tuples) of the last :func:`estimate_lanes`."""
    return _nine(eb, _QQ, i), _nine(eb, _MM, i), _nine(eb, _CC, i), _six(eb, _WH, i), _six(eb, _RD, i)


@kernel(inline="always")
def _gather(eb, dst, head, H, d, col, angle):
    """Row ``dst`` takes history column ``col`` (0-3: the command, 4-6: the attitude) ``d`` periods back."""
    j, g = history_split(d)
    # the two slots' rows into fixed rows first (copy_row): the lane loop then reads at fixed distances
    copy_row(eb, _GS * W, eb, (_RING + 7 * ((head - j) % H) + col) * W)
    copy_row(eb, (_GS + 1) * W, eb, (_RING + 7 * ((head - j - 1) % H) + col) * W)
    for i in range(W):  # vectorised: one lane per vehicle
        if angle:
            eb[dst * W + i] = lerp_angle(eb[_GS * W + i], eb[(_GS + 1) * W + i], g, True)
        else:
            eb[dst * W + i] = lerp(eb[_GS * W + i], eb[(_GS + 1) * W + i], g)


@kernel()
def estimate_lanes(eb, d, head):
    """One estimator sample of every lane, as :func:`~.estimator.estimator_update` of each (a vehicle that has
    started): reads the measurement and held command rows, leaves ``Q, M, C``, the estimate and its rate in the
    rows :func:`sample_at` reads. ``d`` is the shared design record; returns the ring's new ``head``."""
    n, H, Ts, alpha, gamma = d.order, d.H, d.Ts, d.alpha, d.gamma
    for c in range(4):  # the held command through the rotor model
        for i in range(W):  # vectorised: one lane per vehicle
            mean, now = rotor_model(eb[(_CMD + c) * W + i], eb[(_ACT + c) * W + i], alpha, gamma)
            eb[(_H0 + c) * W + i] = mean
            eb[(_ACT + c) * W + i] = now
    for j in range(3 * W):
        eb[(_H0 + 4) * W + j] = eb[(_Y + 3) * W + j]
    head = head + 1 if head + 1 < H else 0
    for j in range(7):  # the newest history row into the ring
        copy_row(eb, (_RING + 7 * head + j) * W, eb, (_H0 + j) * W)
    # the history a sample reads: the thrust on the velocity's window, the moments on the attitude's
    _gather(eb, _GA, head, H, d.dv, 0, False)
    for c in range(3):
        _gather(eb, _GA + 1 + c, head, H, d.da, 1 + c, False)
        _gather(eb, _GA + 4 + c, head, H, d.d_att + 1.0, 4 + c, True)
        _gather(eb, _GA + 7 + c, head, H, d.d_att, 4 + c, True)
    for i in range(W):  # vectorised: one lane per vehicle
        m = eb[_NOM * W + i]
        I9 = _nine(eb, _NOM + 1, i)  # noqa: N806
        v, e, de = _three(eb, _Y, i), _three(eb, _Y + 3, i), _three(eb, _Y + 6, i)
        Q, M, C = _QMC(e[0], e[1], de[0], de[1], de[2], I9, True)  # noqa: N806
        qa = _mv9(M, de[0], de[1], de[2])
        q = (m * v[0], m * v[1], m * v[2], qa[0], qa[1], qa[2])  # eq. (6)
        u_w, t = eb[_GA * W + i], _three(eb, _GA + 1, i)
        ea, e_b = _three(eb, _GA + 4, i), _three(eb, _GA + 7, i)
        w_bar = residual(q, _six(eb, _QP, i), Ts, ea, e_b, u_w, t, m, _nine(eb, _QQ, i), _nine(eb, _CC, i),
                         _three(eb, _DP, i), Q, C, de, True)  # fmt: skip
        _put6(eb, _WB, i, w_bar)
        _put6(eb, _QP, i, q)
        _put9(eb, _QQ, i, Q)
        _put9(eb, _CC, i, C)
        _put9(eb, _MM, i, M)
        _put3(eb, _DP, i, de)
    if n == 2:  # a literal order lets the compiler unroll the filter into one loop over the lanes
        _filter_lanes(eb, d, 2)
    else:
        _filter_lanes(eb, d, n)
    return head


@kernel(inline="always")
def _filter_lanes(eb, d, n):
    """Eq. (11), discretised (exact ZOH), for every lane: the filter ``G`` of order ``n`` driven by the residual,
    the estimate and its rate, as :func:`~.estimator.estimator_update` (the same sums in the same order)."""
    Ad, Bd, Cm, CA, CB = d.Ad, d.Bd, d.C, d.CA, d.CB  # noqa: N806
    for i in range(W):  # vectorised where ``n`` is a literal: one lane per vehicle
        for ch in range(6):
            x = _XF + MAX_ORDER * ch
            wb = eb[(_WB + ch) * W + i]
            for r in range(n):
                acc = Bd[ch, r] * wb
                for j in range(n):
                    acc += Ad[ch, r, j] * eb[(x + j) * W + i]
                eb[(_XN + r) * W + i] = acc
            est, rate = 0.0, CB[ch] * wb
            for r in range(n):
                xr = eb[(_XN + r) * W + i]
                eb[(x + r) * W + i] = xr
                est += Cm[ch, r] * xr  # eq. (11): the estimate
                rate += CA[ch, r] * xr
            eb[(_WH + ch) * W + i] = est
            eb[(_RD + ch) * W + i] = rate
