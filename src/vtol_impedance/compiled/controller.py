"""Compiled (numba) per-vehicle kernels of the estimator, eqs. (6)-(13), and controller, eqs. (14)-(20).

These run the same equations as :mod:`vtol_impedance.control.impedance` and
:mod:`vtol_impedance.estimator.momentum` (the NumPy reference backend, which stays the readable
definition and the test oracle); ``tests/test_compiled.py`` proves the two agree. Everything here works
on one vehicle, so a batch is a ``prange`` loop over vehicles.

Data (:mod:`.layouts`): the controller's parameters ``p`` (:data:`~.layouts.CONTROLLER`), the shared
design ``d`` (:data:`~.layouts.DESIGN`), the state ``s`` (:data:`~.layouts.CONTROLLER_STATE`) and timing
history ``h`` (:data:`~.layouts.HISTORY` rows), the output ``o`` (:data:`~.layouts.OUTPUT`); the
measurement ``y = [p_W, v_W, eta, eta_dot]`` (12) and the reference ``r = [p_d, v_d, a_d, psi, psi_dot,
psi_ddot]`` (12), with the comply fractions of the world axes (15) or of the world axes and the Euler
angles (18) appended, are flat float rows (what a flight loop has at hand).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import from_dtype, types

from ..control.impedance import ControllerArrays
from ..conventions import MAX_PITCH_RAD, SINGULARITY_COS_EPS, G
from .algebra import _m9, _mm9, _mv9, _solve9, _t9, _v3, turn
from .estimator import estimator_update, pack_design
from .estimator import initial_state as estimator_initial_state
from .jit import kernel
from .layouts import CONTROLLER, CONTROLLER_STATE, DESIGN, HISTORY, OUTPUT, pack
from .vmath import arcsin, arctan2, sin_cos

#: What :func:`control_law` reads of one controller (:data:`~.layouts.CONTROLLER`): built from a record by
#: :func:`law_lane_of`, or from one lane of a block in lanes (:mod:`.lanes_controller`), so that both run the
#: same :func:`law_request`. ``I9`` is the nominal inertia (row-major), ``tan_tilt`` the tangent of the tilt
#: limit; the gains are 3-tuples. ``inv_mass``, ``inv_Md``, ``inv_Mo_d`` are the reciprocals of the nominal mass
#: and of the impedances' apparent masses and inertias, taken once per controller: the law multiplies by them
#: (in lanes a packed division costs as much as a dozen products, and the law had 28 of them a tick; the
#: result parts from the NumPy definition's divisions by rounding only); ``integral_bound`` is the PID
#: integral's bound per axis (:func:`law_integral`), the same division taken once. The rotor layout and
#: limits are not here: the allocation reads them where they are.
LawLane = namedtuple(
    "LawLane",
    ("mass", "I9", "tan_tilt", "min_lift_accel", "compensate", "comply_enable", "integral_limit", "Kp", "Dp", "Ki",
     "Do", "Ko", "Md", "Dd", "Kd", "Mo_d", "Do_d", "Ko_d", "inv_mass", "inv_Md", "inv_Mo_d", "integral_bound"),
)  # fmt: skip

#: What :func:`law_request` reads of the shared design (:data:`~.layouts.DESIGN`), by :func:`law_design`: values
#: a lane loop holds in registers (a record read inside the loop could alias the rows it writes).
LawDesign = namedtuple("LawDesign", ("Ts", "filt_wn", "filt_zeta", "dv", "da", "lag", "filt_A", "filt_B"))


def pack_controller(P: ControllerArrays) -> tuple[np.ndarray, np.ndarray]:
    """``(p (B,) CONTROLLER, d (1,) DESIGN)`` from compiled NumPy controller arrays with batch shape ``(B,)``."""
    p = pack(CONTROLLER, P, P.mass.shape[0], n_rotors=P.E.shape[-1])
    d = pack_design(P.est, filt_wn=P.filt.wn, filt_zeta=P.filt.zeta, filt_Ad=P.filt.Ad, filt_Bd=P.filt.Bd)
    return p, d


def initial_state(p: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fresh controller states ``(B,)`` and timing histories ``(B, H)``: nothing started, held thrust m g."""
    s, h = estimator_initial_state(d, p.shape[0])
    s["thrust_prev"] = p["mass"] * G
    return s, h


def new_output(batch: int) -> np.ndarray:
    """Output records ``(batch,)``."""
    return np.zeros(batch, dtype=OUTPUT)


@kernel(inline="always")
def thrust_and_attitude(mu_bar, psi, m, tan_tilt, min_lift, vector):
    """Eq. (16) solved in NED with the tilt and lift limits of :func:`vtol_impedance.control.thrust_and_attitude`
    (``tan_tilt``: the tangent of the tilt limit; ``vector``, a literal: the sines of :mod:`.vmath`)."""
    vert = G - mu_bar[2]
    vert_c = max(vert, min_lift)
    h_norm = math.sqrt(mu_bar[0] * mu_bar[0] + mu_bar[1] * mu_bar[1])
    h_max = vert_c * tan_tilt
    scale = h_max / max(h_norm, 1e-300) if h_norm > h_max else 1.0
    m1 = mu_bar[0] * scale
    m2 = mu_bar[1] * scale
    a = math.sqrt(m1 * m1 + m2 * m2 + vert_c * vert_c)  # eq. (20a): u = m a
    sp, cp = sin_cos(psi, vector)
    phi = arcsin(min(max((m2 * cp - m1 * sp) / a, -1.0), 1.0), vector)  # eq. (20b)
    theta = arctan2(-(m1 * cp + m2 * sp), vert_c, vector)  # eq. (20c)
    return m * a, phi, theta, (vert < min_lift) or (scale < 1.0)


@kernel(inline="always")
def _wrap(a, vector):
    """``a`` into ``[-pi, pi)``, as :func:`vtol_impedance.model.kinematics.wrap_angle`."""
    return turn(a + math.pi, vector) - math.pi


@kernel(inline="always")
def yaw_room(e, f_min, f_max, u, t0, t1, t2, a_lo, a_hi, flat_bad):
    """Step 0 of :func:`_allocate` for one rotor (``e``: its row of ``E_pinv``, limits ``f_min``, ``f_max``): its
    force ``base`` at the requested thrust and roll/pitch moments, and the range ``[a_lo, a_hi]`` of yaw scales
    (narrowed from the one given) that keeps it within its limits; ``flat_bad``: a rotor without yaw share out of
    its limits already. Selects, not branches: the same arithmetic in lanes (:mod:`.lanes_controller`)."""
    tol = 1e-12 * max(abs(f_max), 1.0)
    lo_i, hi_i = f_min - tol, f_max + tol
    base = e[0] * u + e[1] * t0 + e[2] * t1
    y = e[3] * t2
    up, down = (hi_i - base) / y, (lo_i - base) / y
    a_hi = min(a_hi, up) if y > 0 else (min(a_hi, down) if y < 0 else a_hi)
    a_lo = max(a_lo, down) if y > 0 else (max(a_lo, up) if y < 0 else a_lo)
    flat_bad = flat_bad or (not (y > 0 or y < 0) and (base < lo_i or base > hi_i))
    return base, a_lo, a_hi, flat_bad


@kernel(inline="always")
def yaw_fits(a_lo, a_hi, flat_bad):
    """Whether step 0 of :func:`_allocate` holds (full roll/pitch with some yaw), and its yaw scale."""
    return (not flat_bad) and a_lo <= a_hi and a_hi >= 0.0, min(max(a_hi, 0.0), 1.0)


@kernel(inline="always")
def with_yaw(base, ys, e3, t2, f_min, f_max):
    """A rotor's force: ``base`` plus the yaw share ``e3 t2`` scaled by ``ys``, within its limits."""
    return min(max(base + ys * e3 * t2, f_min), f_max)


@kernel()
def _allocate(p, u, t0, t1, t2, f):
    """Prioritised inverse of eq. (4) for any rotor layout, as :func:`vtol_impedance.model.mixer.allocate`.

    Writes the rotor forces to ``f``; returns ``(saturated, rp_scale, yaw_scale)``. Allocation free:
    per-rotor quantities are recomputed from ``p.E_pinv`` (rows: thrust, roll, pitch, yaw shares).
    """
    n = p.n_rotors
    Ep, f_min, f_max = p.E_pinv, p.f_min, p.f_max
    # 0. full roll/pitch at the requested thrust, with the largest yaw scale that fits, if any does
    a_lo, a_hi, flat_bad = 0.0, 1.0, False
    for i in range(n):
        e = (Ep[i, 0], Ep[i, 1], Ep[i, 2], Ep[i, 3])
        f[i], a_lo, a_hi, flat_bad = yaw_room(e, f_min[i], f_max[i], u, t0, t1, t2, a_lo, a_hi, flat_bad)
    fits, ys = yaw_fits(a_lo, a_hi, flat_bad)
    if fits:
        for i in range(n):
            f[i] = with_yaw(f[i], ys, Ep[i, 3], t2, f_min[i], f_max[i])
        return ys < 1.0 - 1e-9, 1.0, ys
    # 1. feasible collective with equal shares
    u_lo, u_hi = -math.inf, math.inf
    for i in range(n):
        u_lo = max(u_lo, f_min[i] / Ep[i, 0])
        u_hi = min(u_hi, f_max[i] / Ep[i, 0])
    u_c = min(max(u, u_lo), u_hi)
    dmax = p.thrust_shift_max * u_c
    # 2. roll/pitch: rotor i needs a_i - k b_i <= delta <= c_i - k b_i, |delta| <= dmax
    k = 1.0
    for i in range(n):
        a_i = f_min[i] / Ep[i, 0] - u_c
        c_i = f_max[i] / Ep[i, 0] - u_c
        b_i = (Ep[i, 1] * t0 + Ep[i, 2] * t1) / Ep[i, 0]
        if b_i < 0:
            k = min(k, (dmax - a_i) / -b_i)
        elif b_i > 0:
            k = min(k, (c_i + dmax) / b_i)
        for j in range(n):
            b_j = (Ep[j, 1] * t0 + Ep[j, 2] * t1) / Ep[j, 0]
            if b_j - b_i > 0:
                c_j = f_max[j] / Ep[j, 0] - u_c
                k = min(k, (c_j - a_i) / (b_j - b_i))
    k = max(k, 0.0)
    d_lo, d_hi = -dmax, dmax
    for i in range(n):
        b_i = (Ep[i, 1] * t0 + Ep[i, 2] * t1) / Ep[i, 0]
        d_lo = max(d_lo, f_min[i] / Ep[i, 0] - u_c - k * b_i)
        d_hi = min(d_hi, f_max[i] / Ep[i, 0] - u_c - k * b_i)
    delta = min(max(0.0, d_lo), max(d_lo, d_hi))
    # 3. yaw with what is left
    ys = 1.0
    for i in range(n):
        base = Ep[i, 0] * (u_c + delta) + k * (Ep[i, 1] * t0 + Ep[i, 2] * t1)
        f[i] = base
        y = Ep[i, 3] * t2
        tol = 1e-12 * max(abs(f_max[i]), 1.0)
        if y > 0:
            ys = min(ys, (f_max[i] + tol - base) / y)
        elif y < 0:
            ys = min(ys, (f_min[i] - tol - base) / y)
    ys = min(max(ys, 0.0), 1.0)
    for i in range(n):
        f[i] = min(max(f[i] + ys * Ep[i, 3] * t2, f_min[i]), f_max[i])
    shift = u_c + delta - u
    sat = k < 1.0 - 1e-9 or ys < 1.0 - 1e-9 or abs(shift) > 1e-9 * max(abs(u), 1.0)
    return sat, k, ys


@kernel(inline="always")
def _mix_row(p, f, row):
    """Row ``row`` of ``E f``, eq. (4): the thrust (0) or a body moment (1-3) of the rotor forces ``f``."""
    acc = 0.0
    for i in range(p.n_rotors):
        acc += p.E[row, i] * f[i]  # eq. (4)
    return acc


@kernel(inline="always")
def _impedance_axis(p, integral, r, i, m, e, ev, fh, fl, fdot, lead):
    """``mu_bar`` on world axis ``i``: eq. (18a) with compensation (``integral``: the PID integral on that axis),
    blended with the comply impedance (which feeds forward ``fl``, the estimate with its filter delay taken out,
    and leads its command by ``lead`` seconds), as :func:`vtol_impedance.control.impedance.controller_step`."""
    lam = 0.0
    if len(r) >= 15:
        lam = min(max(r[12 + i], 0.0), 1.0) if p.comply_enable > 0.5 else 0.0
    dd, kd = p.Dd[i], p.Kd[i]
    im, imd = p.inv_mass, p.inv_Md[i]  # 1 / m, 1 / M_d: products, not divisions (LawLane)
    kp = (1.0 - lam) * p.Kp[i] + lam * m * kd * imd
    dp = (1.0 - lam) * p.Dp[i] + lam * m * dd * imd
    ff = (1.0 - lam) * p.compensate * fh + lam * (1.0 - m * imd) * fl  # f_hat of eq. (16)
    mu = r[6 + i] - (dp * ev + kp * e + (1.0 - lam) * p.Ki[i] * integral) * im - ff * im  # eqs. (18a), (16)
    acc = (fl - dd * ev - kd * e) * imd
    rate = -dd * acc * imd + (imd - im) * fdot
    return mu + lam * lead * rate


@kernel(inline="always")
def _attitude_axis(p, d, r, i, tb, eta_d_ddot, de, ee, th, la, th_dot):
    """``tau_bar`` on Euler angle ``i`` blended with ``M_o e'' + D_o e' + K_o e = tau_ext_eta``, and the
    moment (14) cancels; both use the estimate ``th`` advanced (at its rate ``th_dot``) by G's delay and the
    attitude latency ``la``, as :func:`vtol_impedance.control.impedance.controller_step`."""
    lam = min(max(r[15 + i], 0.0), 1.0)
    lead = th + (d.lag[3 + i] + la) * th_dot
    comply = eta_d_ddot - (p.Do_d[i] * de + p.Ko_d[i] * ee - lead) * p.inv_Mo_d[i]
    return (1.0 - lam) * tb + lam * comply, th + lam * (lead - th)


@kernel()
def controller_step(p, d, s, h, y, r, o):
    """One control period for one vehicle; updates ``s``, ``h`` in place and writes ``o``. Mirrors
    :func:`vtol_impedance.control.impedance.controller_step`, with no heap allocation: the estimator's
    sample (eqs. (6)-(13)), then :func:`control_law`."""
    Q, M, C, w = estimator_update(d, s, h, p.mass, nominal_inertia(p), y[3], y[4], y[5], y[6], y[7], y[8], y[9], y[10],
                                  y[11])  # fmt: skip
    rd = s.r_dot
    control_law(p, d, s, y, r, o, Q, M, C, w, (rd[0], rd[1], rd[2], rd[3], rd[4], rd[5]))


@kernel(inline="always")
def nominal_inertia(p):
    """The controller's nominal inertia ``p.I_B`` as a row-major 9-tuple."""
    return _m9(p.I_B)


@kernel(inline="always")
def law_lane_of(p):
    """The :data:`LawLane` of a :data:`~.layouts.CONTROLLER` record."""
    return LawLane(
        p.mass, nominal_inertia(p), math.tan(p.tilt_max), p.min_lift_accel, p.compensate, p.comply_enable,
        p.integral_limit, _v3(p.Kp), _v3(p.Dp), _v3(p.Ki), _v3(p.Do), _v3(p.Ko), _v3(p.Md), _v3(p.Dd), _v3(p.Kd),
        _v3(p.Mo_d), _v3(p.Do_d), _v3(p.Ko_d), 1.0 / p.mass, (1.0 / p.Md[0], 1.0 / p.Md[1], 1.0 / p.Md[2]),
        (1.0 / p.Mo_d[0], 1.0 / p.Mo_d[1], 1.0 / p.Mo_d[2]), (_bound(p, 0), _bound(p, 1), _bound(p, 2)),
    )  # fmt: skip


@kernel(inline="always")
def _bound(p, i):
    """The PID integral's bound on axis ``i`` (m s) of the controller record ``p``: ``limit / Ki``."""
    return p.integral_limit / max(p.Ki[i], 1e-12)


@kernel(inline="always")
def control_law(p, d, s, y, r, o, Q, M, C, w, rd):
    """Eqs. (14)-(20) of one period given the estimator's sample: ``Q``, ``M``, ``C`` at the measured attitude
    (9-tuples), the estimate ``w = [f_hat_ext_W; tau_hat_ext_eta]`` and its rate ``rd`` (6-tuples). Updates the
    controller's part of ``s`` (attitude filter, integral, held command) and writes ``o``: :func:`law_request`,
    the allocation (:func:`_allocate`) and :func:`law_integral`, as a block in lanes runs them
    (:mod:`.lanes_controller`)."""
    c = law_lane_of(p)
    integral = (s.integral[0], s.integral[1], s.integral[2])
    filt = (s.filt_started, s.filt_x[0], s.filt_x[1], s.filt_xd[0], s.filt_xd[1])
    req, tr, tilt_lim, mb, ep, fx, ed, hb = law_request(c, law_design(d), y, r, Q, M, C, w, rd, integral, filt, False)
    sat, rp_scale, yaw_scale = _allocate(p, req, tr[0], tr[1], tr[2], o.f_rotor)
    u_out = _mix_row(p, o.f_rotor, 0)
    to = (_mix_row(p, o.f_rotor, 1), _mix_row(p, o.f_rotor, 2), _mix_row(p, o.f_rotor, 3))
    integral = law_integral(c, d.Ts, integral, ep, sat or tilt_lim)
    s.filt_started = True
    s.filt_x[0], s.filt_x[1], s.filt_xd[0], s.filt_xd[1] = fx
    s.integral[0], s.integral[1], s.integral[2] = integral
    s.thrust_prev = u_out
    s.tau_B_prev[0], s.tau_B_prev[1], s.tau_B_prev[2] = to
    put_output(o, u_out, to, sat, req, tr, w, hb, ed, r, mb, tilt_lim, rp_scale, yaw_scale)


@kernel(inline="always")
def law_design(d):
    """The :data:`LawDesign` of a :data:`~.layouts.DESIGN` record."""
    A, B = d.filt_Ad, d.filt_Bd  # noqa: N806
    return LawDesign(d.Ts, d.filt_wn, d.filt_zeta, d.dv, d.da, (d.lag[0], d.lag[1], d.lag[2], d.lag[3], d.lag[4],
                     d.lag[5]), (A[0, 0], A[0, 1], A[1, 0], A[1, 1]), (B[0], B[1]))  # fmt: skip


@kernel(inline="always")
def law_request(c, d, y, r, Q, M, C, w, rd, integral, filt, vector):
    """Eqs. (14)-(20) of one period up to the rotor allocation, for the controller ``c`` (a :data:`LawLane`) and
    the design ``d`` (a :data:`LawDesign`) with
    the PID ``integral`` (3) and the attitude filter ``filt = (started, phi, theta, phi_dot, theta_dot)`` it
    carries, the measurement ``y`` (12) and reference ``r`` (:func:`control_law`'s rows) and the estimator's
    sample. Returns the thrust and body moments requested, whether the tilt or lift limit acted, ``mu_bar``, the
    position error (3), the filter's next state (4), the filtered attitude command ``(phi, theta, phi_dot,
    theta_dot)`` of this period and the estimated moment in body axes. ``vector`` (a literal): the sines of
    :mod:`.vmath`, for code in lanes."""
    Ts, fwn, fz = d.Ts, d.filt_wn, d.filt_zeta
    m = c.mass
    I = c.I9  # noqa: E741
    comp = c.compensate
    p0, p1, p2, v0, v1, v2 = y[0], y[1], y[2], y[3], y[4], y[5]
    e0, e1, e2, d0, d1, d2 = y[6], y[7], y[8], y[9], y[10], y[11]
    fh0, fh1, fh2, th0, th1, th2 = w
    # the force estimate with G's low-frequency delay taken out (used by "comply"): f_hat + lag f_hat_dot
    lv, la = Ts * d.dv, Ts * d.da  # the latencies the force and moment channels see
    fl0 = fh0 + (d.lag[0] + lv) * rd[0]
    fl1 = fh1 + (d.lag[1] + lv) * rd[1]
    fl2 = fh2 + (d.lag[2] + lv) * rd[2]
    lead = 2.0 * fz / fwn  # the attitude filter's delay: how late the force follows the command

    # position impedance (18a), compensation, eq. (16); per axis, "comply" blends the rejecting law
    # (lam = 0) with M_d e'' + D_d e' + K_d e = f_ext (lam = 1)
    ep0, ep1, ep2 = p0 - r[0], p1 - r[1], p2 - r[2]
    mb0 = _impedance_axis(c, integral[0], r, 0, m, ep0, v0 - r[3], fh0, fl0, rd[0], lead)  # eqs. (18a), (16)
    mb1 = _impedance_axis(c, integral[1], r, 1, m, ep1, v1 - r[4], fh1, fl1, rd[1], lead)
    mb2 = _impedance_axis(c, integral[2], r, 2, m, ep2, v2 - r[5], fh2, fl2, rd[2], lead)
    psi_d = r[9]
    # eqs. (16), (20)
    thrust_req, phi_d, theta_d, tilt_lim = thrust_and_attitude((mb0, mb1, mb2), psi_d, m, c.tan_tilt,
                                                               c.min_lift_accel, vector)  # fmt: skip

    # attitude filter on (phi_d, theta_d): value, rate and acceleration of the filtered attitude (it starts
    # at its first command, at rest)
    started = filt[0]
    ed0 = filt[1] if started else phi_d
    ed1 = filt[2] if started else theta_d
    edd0 = filt[3] if started else 0.0
    edd1 = filt[4] if started else 0.0
    eddd0 = fwn * fwn * (phi_d - ed0) - 2.0 * fz * fwn * edd0
    eddd1 = fwn * fwn * (theta_d - ed1) - 2.0 * fz * fwn * edd1
    A, B = d.filt_A, d.filt_B  # row-major 2 x 2, 2
    fx = (
        A[0] * ed0 + A[1] * edd0 + B[0] * phi_d,
        A[0] * ed1 + A[1] * edd1 + B[0] * theta_d,
        A[2] * ed0 + A[3] * edd0 + B[1] * phi_d,
        A[2] * ed1 + A[3] * edd1 + B[1] * theta_d,
    )

    # attitude impedance (18b) and torque (14)
    ee0, ee1, ee2 = _wrap(e0 - ed0, vector), _wrap(e1 - ed1, vector), _wrap(e2 - psi_d, vector)
    de0, de1, de2 = d0 - edd0, d1 - edd1, d2 - r[10]
    ce = _mv9(C, de0, de1, de2)
    k0 = ce[0] + c.Do[0] * de0 + c.Ko[0] * ee0  # eq. (18b): (D_o + C) e' + K_o e
    k1 = ce[1] + c.Do[1] * de1 + c.Ko[1] * ee1
    k2 = ce[2] + c.Do[2] * de2 + c.Ko[2] * ee2
    s0, s1, s2 = _solve9(M, k0, k1, k2)
    tb0, tb1, tb2 = eddd0 - s0, eddd1 - s1, r[11] - s2  # eq. (18b)
    tc0, tc1, tc2 = th0, th1, th2  # the moment (14) cancels
    if len(r) >= 18:  # per Euler angle, "comply" blends in its own law
        on = c.comply_enable > 0.5
        a0, b0 = _attitude_axis(c, d, r, 0, tb0, eddd0, de0, ee0, th0, la, rd[3])
        a1, b1 = _attitude_axis(c, d, r, 1, tb1, eddd1, de1, ee1, th1, la, rd[4])
        a2, b2 = _attitude_axis(c, d, r, 2, tb2, r[11], de2, ee2, th2, la, rd[5])
        tb0, tc0 = (a0, b0) if on else (tb0, tc0)
        tb1, tc1 = (a1, b1) if on else (tb1, tc1)
        tb2, tc2 = (a2, b2) if on else (tb2, tc2)
    QT = _t9(Q)
    cd = _mv9(C, d0, d1, d2)
    g0, g1, g2 = _solve9(QT, cd[0] - comp * tc0, cd[1] - comp * tc1, cd[2] - comp * tc2)  # eq. (14)
    iq = _mv9(_mm9(I, Q), tb0, tb1, tb2)
    tr = (iq[0] + g0, iq[1] + g1, iq[2] + g2)  # eq. (14)
    hb = _solve9(QT, th0, th1, th2)
    return thrust_req, tr, tilt_lim, (mb0, mb1, mb2), (ep0, ep1, ep2), fx, (ed0, ed1, edd0, edd1), hb


@kernel(inline="always")
def _integral_axis(bound, x, e, Ts, freeze):
    """One axis of the PID integral: ``x + Ts e`` unless ``freeze`` (anti-windup), within ``bound``
    (:data:`LawLane`'s ``integral_bound``: the integral limit over ``Ki``)."""
    x = x if freeze else x + Ts * e
    return min(max(x, -bound), bound)


@kernel(inline="always")
def law_integral(c, Ts, integral, ep, freeze):
    """The PID integral after a period with position error ``ep``, frozen while the allocation saturated or a
    tilt or lift limit acted (anti-windup)."""
    return (
        _integral_axis(c.integral_bound[0], integral[0], ep[0], Ts, freeze),
        _integral_axis(c.integral_bound[1], integral[1], ep[1], Ts, freeze),
        _integral_axis(c.integral_bound[2], integral[2], ep[2], Ts, freeze),
    )


@kernel(inline="always")
def put_output(o, u_out, to, sat, req, tr, w, hb, ed, r, mb, tilt_lim, rp_scale, yaw_scale):
    """The :data:`~.layouts.OUTPUT` record ``o`` of a period (its rotor forces are written by the allocation):
    thrust and moments given ``u_out``, ``to`` and requested ``req``, ``tr``, the estimate ``w`` (and its moment
    in body axes ``hb``), the attitude command ``ed`` (of :func:`law_request`) with the reference ``r``'s yaw,
    ``mu_bar`` and the limits that acted."""
    o.thrust = u_out
    o.tau_B[0], o.tau_B[1], o.tau_B[2] = to
    o.saturated = sat
    o.thrust_request = req
    o.tau_B_request[0], o.tau_B_request[1], o.tau_B_request[2] = tr
    o.f_hat_W[0], o.f_hat_W[1], o.f_hat_W[2] = w[0], w[1], w[2]
    o.tau_hat_eta[0], o.tau_hat_eta[1], o.tau_hat_eta[2] = w[3], w[4], w[5]
    o.tau_hat_B[0], o.tau_hat_B[1], o.tau_hat_B[2] = hb
    o.eta_d[0], o.eta_d[1], o.eta_d[2] = ed[0], ed[1], r[9]
    o.eta_d_dot[0], o.eta_d_dot[1], o.eta_d_dot[2] = ed[2], ed[3], r[10]
    o.mu_bar[0], o.mu_bar[1], o.mu_bar[2] = mb
    o.tilt_limited = tilt_lim
    o.rp_scale = rp_scale
    o.yaw_scale = yaw_scale


#: Largest magnitude accepted per measurement ``y = [p_W (m), v_W (m/s), eta (rad), eta_dot (rad/s)]`` and
#: reference ``r = [p_d (m), v_d (m/s), a_d (m/s^2), psi (rad), psi_dot (rad/s), psi_ddot (rad/s^2)]``:
#: far beyond any multirotor, well inside float64 (a 1e308 would overflow the arithmetic).
PLAUSIBLE = np.array([1e6] * 3 + [1e4] * 3 + [1e3] * 3 + [1e4] * 3)
PLAUSIBLE_REF = np.array([1e6] * 3 + [1e4] * 3 + [1e5] * 3 + [1e3, 1e4, 1e5])

OK, NON_FINITE, SINGULAR, WRONG_SHAPE, COMPLY_RANGE, IMPLAUSIBLE, PITCH_RANGE = 0, 1, 2, 3, 4, 5, 6


def _records(dtype: np.dtype, ndim: int = 1) -> types.Array:
    return types.Array(from_dtype(dtype), ndim, "C")


_ROW = types.Array(types.float64, 1, "C")
_CHECKED = types.int64(
    _records(CONTROLLER), _records(DESIGN), _records(CONTROLLER_STATE), _records(HISTORY, 2), types.int64, _ROW, _ROW,
    _records(OUTPUT),
)  # fmt: skip


@kernel(_CHECKED)
def checked_step(p, d, s, h, b, y, r, o):
    """:func:`controller_step` for vehicle ``b`` of the arrays ``p``, ``s``, ``h``, ``o`` after input checks;
    returns :data:`OK` or why it refused (the state is then unchanged): :data:`NON_FINITE`, :data:`SINGULAR`
    (|cos theta| below the threshold of :mod:`vtol_impedance.conventions`), :data:`PITCH_RANGE` (|theta|
    beyond pi/2: not a ZYX pitch), :data:`WRONG_SHAPE`,
    :data:`COMPLY_RANGE` (a comply fraction outside [0, 1]) or :data:`IMPLAUSIBLE` (beyond :data:`PLAUSIBLE`:
    finite but no vehicle's; it would poison the state). The caller's signature check refuses anything but
    C-contiguous float64 rows (a float32 or strided input would otherwise compile a new specialisation)."""
    if y.shape[0] != 12 or (r.shape[0] != 12 and r.shape[0] != 15 and r.shape[0] != 18):
        return WRONG_SHAPE
    for i in range(12):
        if not (math.isfinite(y[i]) and math.isfinite(r[i])):
            return NON_FINITE
    for i in range(12):
        if abs(y[i]) > PLAUSIBLE[i] or abs(r[i]) > PLAUSIBLE_REF[i]:
            return IMPLAUSIBLE
    for i in range(12, r.shape[0]):
        if not (0.0 <= r[i] <= 1.0):
            return COMPLY_RANGE
    if abs(y[7]) > MAX_PITCH_RAD:
        return PITCH_RANGE
    if abs(math.cos(y[7])) < SINGULARITY_COS_EPS:
        return SINGULAR
    controller_step(p[b], d[0], s[b], h[b], y, r, o[b])
    return OK


@kernel(_CHECKED)
def _no_step(p, d, s, h, b, y, r, o):
    """Nothing, with :func:`checked_step`'s signature: what calling it costs (``bench``)."""
    return OK


def checked_step_entry(probe: bool = False):
    """:func:`checked_step`'s compiled entry point: the same call without numba's dispatch (about a
    microsecond). Its caller must pass exactly the signature's types (it is not checked again).
    ``probe``: the entry point of a kernel that does nothing with the same arguments (the call's cost)."""
    return (_no_step if probe else checked_step).overloads[_CHECKED.args].entry_point


@kernel()
def step_one(p, d, s, h, b, y, r, o):
    """:func:`controller_step` for vehicle ``b`` of the arrays (inputs checked by the caller)."""
    controller_step(p[b], d[0], s[b], h[b], y, r, o[b])


@kernel()
def allocate_one(p, u, t0, t1, t2, o):
    """:func:`_allocate` for ``p[0]`` into ``o[0].f_rotor`` (the allocator alone, for its tests)."""
    return _allocate(p[0], u, t0, t1, t2, o[0].f_rotor)
