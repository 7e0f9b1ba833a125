"""Compiled closed loop: one ``prange`` iteration per vehicle, time in blocks driven from Python.

Per control period it does exactly what :func:`vtol_impedance.sim.loop.run_closed_loop` does with the
NumPy backend (read delayed noisy sensors, controller step, log, hold the rotor command for
``n_sub`` RK4 plant steps, check for divergence), using the kernels of :mod:`.controller` and
:mod:`.plant`. Randomness is drawn outside, in NumPy, and passed in per block, so both backends
consume the same numbers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..sim.loop import CRASH_DEPTH_M
from ..sim.result import ROW_BASE
from ..sim.result import SIGNAL_OFFSETS as _OFF
from .algebra import _Q9, _solve9
from .controller import (
    O_ETA_D,
    O_F,
    O_FHAT,
    O_RP,
    O_SAT,
    O_TAU,
    O_TAU_REQ,
    O_TAUHAT_B,
    O_TAUHAT_ETA,
    O_THRUST,
    O_THRUST_REQ,
    O_TILT,
    O_YAW,
    OUT_SIZE,
    controller_step,
)
from .plant import (
    PP_GROUND,
    PP_NR,
    PP_ROT,
    PP_TDN,
    PP_TUP,
    _origin,
    _R_of,
    disturbance_at,
    euler_from_R,
    lowest_contact_depth,
    lumped_wrench,
    origin_kinematics,
    plant_derivative,
    quat_to_R,
    rk4_step,
)

# failure codes (see REASONS)
FAIL_NONE, FAIL_NAN, FAIL_TILT, FAIL_FAR, FAIL_CRASH = 0, 1, 2, 3, 4
# metric accumulators per vehicle
A_N, A_E2, A_EMAX, A_EV2, A_F2, A_T2, A_SAT, A_NT, A_ET = 0, 1, 2, 3, 4, 5, 6, 7, 8
N_ACC = 9

_P, _V, _ETA, _OM = _OFF["p_W"][0], _OFF["v_W"][0], _OFF["eta"][0], _OFF["omega_B"][0]
_PR, _VR, _PSIR = _OFF["p_ref_W"][0], _OFF["v_ref_W"][0], _OFF["psi_ref"][0]
_PM, _VM, _ETAM, _ETAD = _OFF["p_meas_W"][0], _OFF["v_meas_W"][0], _OFF["eta_meas"][0], _OFF["eta_d"][0]
_TREQ, _TAUREQ, _THR, _TAU = _OFF["thrust_request"][0], _OFF["tau_B_request"][0], _OFF["thrust"][0], _OFF["tau_B"][0]
_SAT, _TILT, _RPS, _YAWS = _OFF["saturated"][0], _OFF["tilt_limited"][0], _OFF["rp_scale"][0], _OFF["yaw_scale"][0]
_FEXT, _TEXTB, _TEXTE = _OFF["f_ext_W"][0], _OFF["tau_ext_B"][0], _OFF["tau_ext_eta"][0]
_FL, _TL = _OFF["f_lumped_W"][0], _OFF["tau_lumped_eta"][0]
_FH, _THE, _THB = _OFF["f_hat_W"][0], _OFF["tau_hat_eta"][0], _OFF["tau_hat_B"][0]


@njit(cache=True)
def _ago(hist, count, head, k):
    H = hist.shape[0]
    kk = min(k, count - 1)
    return hist[(head - kk) % H]


@njit(cache=True, parallel=True)
def run_block(
    k0,
    k1,
    Ts,
    dt,
    n_sub,
    X,
    hist,
    hcount,
    hhead,
    k_mocap,
    k_imu,
    sigma,
    noise,
    CS,
    cp,
    sh,
    pp,
    codes,
    dparams,
    series,
    refs,
    alive,
    fail_time,
    fail_code,
    x_park,
    logs,
    dec,
    acc,
    win,
    thrust_idx,
):
    """Advance every live vehicle from control tick ``k0`` to ``k1``.

    ``logs (B, n_log, W)`` gets row ``k // dec`` when ``dec > 0`` and ``k % dec == 0``; ``acc`` collects the
    window metrics (``win = [t0, t1, tail_start]``).
    """
    B = X.shape[0]
    for b in prange(B):
        if not alive[b]:
            continue
        x = X[b]
        pp_b = pp[b]
        cp_b = cp[b]
        cs_b = CS[b]
        hist_b = hist[b]
        y = np.empty(12)
        o = np.empty(OUT_SIZE)
        R = np.empty((3, 3))
        p_o = np.empty(3)
        v_o = np.empty(3)
        eta = np.empty(3)
        ns = x.shape[0]
        nr = int(pp_b[PP_NR])
        xd = np.empty(ns)
        env = np.empty(6)  # [f_ext_W, tau_ext_B] at the logged instant
        env_w = np.empty(6)  # scratch for the RK4 stages
        dist = np.empty(6)  # explicit disturbances, held over each plant step
        f_l = np.empty(3)
        t_l = np.empty(3)
        tau_prev = np.empty(3)
        fcmd = np.empty(nr)
        w1, w2, w3, w4, wt = np.empty(ns), np.empty(ns), np.empty(ns), np.empty(ns), np.empty(ns)
        i_thr = thrust_idx
        up_now, down_now = pp_b[PP_TUP] <= 0, pp_b[PP_TDN] <= 0  # directions without lag
        for k in range(k0, k1):
            t = k * Ts
            # sensors: delayed state, noise drawn outside
            xm = _ago(hist_b, hcount[b], hhead[b], k_mocap)
            om_ = _origin(pp_b, xm, _R_of(xm, 6))
            xi = _ago(hist_b, hcount[b], hhead[b], k_imu)
            Ri = _R_of(xi, 6)
            j = k - k0
            y[6] = math.atan2(Ri[7], Ri[8]) + sigma[2] * noise[b, j, 6]
            y[7] = -math.asin(min(max(Ri[6], -1.0), 1.0)) + sigma[2] * noise[b, j, 7]
            y[8] = math.atan2(Ri[3], Ri[0]) + sigma[2] * noise[b, j, 8]
            ed = _solve9(
                _Q9(y[6], y[7]),
                xi[10] + sigma[3] * noise[b, j, 9],
                xi[11] + sigma[3] * noise[b, j, 10],
                xi[12] + sigma[3] * noise[b, j, 11],
            )
            for i in range(3):
                y[9 + i] = ed[i]
                y[i] = om_[i] + sigma[0] * noise[b, j, i]
                y[3 + i] = om_[3 + i] + sigma[1] * noise[b, j, 3 + i]
            u_prev = CS[b, i_thr]
            for i in range(3):
                tau_prev[i] = CS[b, i_thr + 1 + i]
            r = refs[k]
            controller_step(cp_b, sh, cs_b, y, r, o)
            for i in range(nr):
                fcmd[i] = o[O_F + i]

            # true and lumped wrenches at t_k
            disturbance_at(pp_b, x, t, codes, dparams, series, dist)
            plant_derivative(pp_b, x, fcmd, dist, xd, env)
            quat_to_R(x[6:10], R)
            euler_from_R(R, eta)
            lumped_wrench(pp_b, x, xd, R, eta, u_prev, tau_prev, cp_b[0], cp_b, f_l, t_l)
            origin_kinematics(pp_b, x, R, p_o, v_o)

            if win[0] <= t <= win[1]:
                e2 = 0.0
                ev2 = 0.0
                fe2 = 0.0
                te2 = 0.0
                for i in range(3):
                    e2 += (p_o[i] - r[i]) ** 2
                    ev2 += (v_o[i] - r[3 + i]) ** 2
                    fe2 += (o[O_FHAT + i] - f_l[i]) ** 2
                    te2 += (o[O_TAUHAT_ETA + i] - t_l[i]) ** 2
                acc[b, A_N] += 1.0
                acc[b, A_E2] += e2
                acc[b, A_EMAX] = max(acc[b, A_EMAX], math.sqrt(e2))
                acc[b, A_EV2] += ev2
                acc[b, A_F2] += fe2
                acc[b, A_T2] += te2
                acc[b, A_SAT] += max(o[O_SAT], o[O_TILT])
                if t >= win[2]:
                    acc[b, A_NT] += 1.0
                    acc[b, A_ET] += math.sqrt(e2)

            if dec > 0 and k % dec == 0:
                row = logs[b, k // dec]
                Q2 = _Q9(eta[0], eta[1])
                for i in range(3):
                    row[_P + i] = p_o[i]
                    row[_V + i] = v_o[i]
                    row[_ETA + i] = eta[i]
                    row[_OM + i] = x[10 + i]
                    row[_PR + i] = r[i]
                    row[_VR + i] = r[3 + i]
                    row[_PM + i] = y[i]
                    row[_VM + i] = y[3 + i]
                    row[_ETAM + i] = y[6 + i]
                    row[_ETAD + i] = o[O_ETA_D + i]
                    row[_TAUREQ + i] = o[O_TAU_REQ + i]
                    row[_TAU + i] = o[O_TAU + i]
                    row[_FEXT + i] = env[i]
                    row[_TEXTB + i] = env[3 + i]
                    row[_TEXTE + i] = Q2[i] * env[3] + Q2[3 + i] * env[4] + Q2[6 + i] * env[5]
                    row[_FL + i] = f_l[i]
                    row[_TL + i] = t_l[i]
                    row[_FH + i] = o[O_FHAT + i]
                    row[_THE + i] = o[O_TAUHAT_ETA + i]
                    row[_THB + i] = o[O_TAUHAT_B + i]
                row[_PSIR] = r[9]
                row[_TREQ] = o[O_THRUST_REQ]
                row[_THR] = o[O_THRUST]
                row[_SAT] = o[O_SAT]
                row[_TILT] = o[O_TILT]
                row[_RPS] = o[O_RP]
                row[_YAWS] = o[O_YAW]
                for i in range(nr):
                    row[ROW_BASE + i] = fcmd[i]
                    row[ROW_BASE + nr + i] = x[13 + i]

            # hold the command over the period
            if up_now or down_now:  # a rotor follows its command at once in a direction without lag
                for i in range(nr):
                    g = min(max(fcmd[i], pp_b[PP_ROT + 4 * nr + i]), pp_b[PP_ROT + 5 * nr + i])
                    if (up_now and g > x[13 + i]) or (down_now and g < x[13 + i]):
                        x[13 + i] = g
            for j in range(n_sub):
                disturbance_at(pp_b, x, t + j * dt, codes, dparams, series, dist)
                rk4_step(pp_b, x, fcmd, dist, dt, w1, w2, w3, w4, wt, env_w)
                H = hist.shape[1]
                hhead[b] = (hhead[b] + 1) % H
                hist[b, hhead[b]] = x
                hcount[b] = min(hcount[b] + 1, H)

            # divergence check, as sim.loop._check_vehicles
            code = FAIL_NONE
            for i in range(ns):
                if not math.isfinite(x[i]):
                    code = FAIL_NAN
            if code == FAIL_NONE:
                quat_to_R(x[6:10], R)
                if math.acos(min(max(R[2, 2], -1.0), 1.0)) > 80.0 * math.pi / 180.0:
                    code = FAIL_TILT
                elif math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) > 1e3:
                    code = FAIL_FAR
                elif pp_b[PP_GROUND] > 0 and lowest_contact_depth(pp_b, x) > CRASH_DEPTH_M:
                    code = FAIL_CRASH
            if code != FAIL_NONE:
                alive[b] = False
                fail_code[b] = code
                fail_time[b] = t + Ts
                x[:] = x_park[b]
                break
