"""Compiled (numba) per-vehicle kernels of the true plant, its disturbances and the lumped wrench.

Same equations as :mod:`vtol_impedance.sim.plant` and :mod:`vtol_impedance.sim.disturbances` (the
NumPy reference backend and test oracle); ``tests/test_compiled.py`` proves they agree.
State layout as in :mod:`vtol_impedance.sim.plant`: ``[p_com_W, v_com_W, q_WB, omega_B, f_rotor (n), r_pend_W,
r_pend_dot_W]`` (``13 + n + 6``). Rotor forces act through the true effectiveness matrix ``E`` here, while
the NumPy plant sums the rotors' cross products: the parity tests tie the two.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..conventions import G
from ..sim.disturbances import ENC_PARAMS, Disturbance
from ..sim.plant import PlantArrays
from .algebra import _Q9, _QMC, _mv9, _Qd9, _solve9, _t9

# plant parameter row: fixed part, then E (4 x n, row-major) at PP_ROT, f_min (n), f_max (n)
PP_MASS, PP_I, PP_IINV, PP_C, PP_CONTACT = 0, 1, 10, 19, 22
PP_TUP, PP_TDN, PP_DRAG, PP_GROUND, PP_KG, PP_CG, PP_BG = 25, 26, 27, 28, 29, 30, 31
PP_INV_M, PP_INV_TUP, PP_INV_TDN = 32, 33, 34  # reciprocals: multiplications on the hot path
PP_PM, PP_PL = 35, 36  # pendulum mass (0: none) and link length
PP_NR, PP_ROT = 37, 38


def pp_size(n_rotors: int) -> int:
    return PP_ROT + 6 * n_rotors


def pack_plant(P: PlantArrays) -> np.ndarray:
    """Plant parameter rows ``(B, pp_size(n))`` from plant arrays with batch shape ``(B,)``."""
    B = P.mass.shape[0]
    nr = P.spins.shape[-1]
    pp = np.empty((B, pp_size(nr)))
    pp[:, PP_MASS] = P.mass
    pp[:, PP_I : PP_I + 9] = P.I_com.reshape(B, 9)
    pp[:, PP_IINV : PP_IINV + 9] = P.I_com_inv.reshape(B, 9)
    pp[:, PP_C : PP_C + 3] = P.c_B
    pp[:, PP_CONTACT : PP_CONTACT + 3] = P.r_contact_B
    pp[:, PP_NR] = nr
    pp[:, PP_ROT : PP_ROT + 4 * nr] = P.E.reshape(B, 4 * nr)
    pp[:, PP_ROT + 4 * nr : PP_ROT + 5 * nr] = P.f_min.reshape(B, nr)
    pp[:, PP_ROT + 5 * nr : PP_ROT + 6 * nr] = P.f_max.reshape(B, nr)
    for idx, arr in (
        (PP_TUP, P.tau_up),
        (PP_TDN, P.tau_down),
        (PP_DRAG, P.rotor_drag),
        (PP_GROUND, P.ground),
        (PP_KG, P.k_ground),
        (PP_CG, P.c_ground),
        (PP_BG, P.b_ground),
        (PP_PM, P.pend_m),
        (PP_PL, P.pend_L),
    ):
        pp[:, idx] = arr
    pp[:, PP_INV_M] = 1.0 / P.mass
    # a zero time constant means no lag (the engine sets the rotor force directly)
    pp[:, PP_INV_TUP] = np.where(P.tau_up > 0, 1.0 / np.maximum(P.tau_up, 1e-12), 0.0)
    pp[:, PP_INV_TDN] = np.where(P.tau_down > 0, 1.0 / np.maximum(P.tau_down, 1e-12), 0.0)
    return pp


def pack_disturbances(items: list[Disturbance]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(codes (D,), params (D, ENC_PARAMS), series (D, n, 6))`` of prepared disturbances."""
    enc = [d.encode() for d in items]
    D = len(enc)
    codes = np.array([e[0] for e in enc], dtype=np.int64)
    params = np.array([e[1] for e in enc]).reshape(D, ENC_PARAMS)
    n = max([1] + [len(e[2]) for e in enc if e[2] is not None])
    series = np.zeros((D, n, 6))
    lengths = np.zeros(D)
    for i, e in enumerate(enc):
        if e[2] is not None:
            series[i, : len(e[2])] = e[2]
            lengths[i] = len(e[2])
    # the last parameter slot carries the series length
    params[:, ENC_PARAMS - 1] = lengths
    return codes, params, series


@njit(cache=True, error_model="numpy")
def quat_to_R(q, R):
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True, error_model="numpy")
def euler_from_R(R, eta):
    eta[0] = math.atan2(R[2, 1], R[2, 2])
    eta[1] = -math.asin(min(max(R[2, 0], -1.0), 1.0))
    eta[2] = math.atan2(R[1, 0], R[0, 0])


@njit(cache=True, inline="always", error_model="numpy")
def _R_of(s, i0):
    """Rotation of the quaternion ``s[i0:i0+4]`` as a 9-tuple (row major); no slicing, no allocation."""
    w, x, y, z = s[i0], s[i0 + 1], s[i0 + 2], s[i0 + 3]
    return (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )


@njit(cache=True, inline="always", error_model="numpy")
def _origin(pp, x, R):
    """Body-origin position and velocity (6-tuple) as :func:`vtol_impedance.sim.plant.origin_kinematics`."""
    c0, c1, c2 = pp[PP_C], pp[PP_C + 1], pp[PP_C + 2]
    w0, w1, w2 = x[10], x[11], x[12]
    a0, a1, a2 = w1 * c2 - w2 * c1, w2 * c0 - w0 * c2, w0 * c1 - w1 * c0
    return (
        x[0] - (R[0] * c0 + R[1] * c1 + R[2] * c2),
        x[1] - (R[3] * c0 + R[4] * c1 + R[5] * c2),
        x[2] - (R[6] * c0 + R[7] * c1 + R[8] * c2),
        x[3] - (R[0] * a0 + R[1] * a1 + R[2] * a2),
        x[4] - (R[3] * a0 + R[4] * a1 + R[5] * a2),
        x[5] - (R[6] * a0 + R[7] * a1 + R[8] * a2),
    )


@njit(cache=True, error_model="numpy")
def origin_kinematics(pp, x, R, p_o, v_o):
    """Array form of :func:`_origin` for a 3x3 ``R``."""
    o = _origin(pp, x, (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2]))
    for i in range(3):
        p_o[i] = o[i]
        v_o[i] = o[3 + i]


@njit(cache=True, inline="always", error_model="numpy")
def _moment_B(R, r0, r1, r2, f0, f1, f2):
    """Body-frame moment ``r_B x (R^T f_W)`` of a world force ``f_W`` acting at the body point ``r_B``."""
    b0 = R[0] * f0 + R[3] * f1 + R[6] * f2
    b1 = R[1] * f0 + R[4] * f1 + R[7] * f2
    b2 = R[2] * f0 + R[5] * f1 + R[8] * f2
    return r1 * b2 - r2 * b1, r2 * b0 - r0 * b2, r0 * b1 - r1 * b0


@njit(cache=True, error_model="numpy")
def add_disturbances(t, p0, p1, p2, v0, v1, v2, R, codes, dparams, series, env):
    """Write the sum of the encoded disturbances into ``env = [f_W, tau_B]``, as
    :class:`vtol_impedance.sim.disturbances.DisturbanceSet`. ``R`` is the rotation as a row-major 9-tuple;
    ``p``, ``v`` the body origin's position and velocity (world)."""
    f0 = f1 = f2 = t0 = t1 = t2 = 0.0
    for d in range(codes.shape[0]):
        code = codes[d]
        P = dparams[d]  # one view per disturbance
        if code <= 4:
            if code == 0:
                k = 1.0
            elif code == 1:
                k = 1.0 if P[6] <= t < P[7] else 0.0
            elif code == 2:
                k = min(max((t - P[6]) / (P[7] - P[6]), 0.0), 1.0)
            elif code == 3:
                k = math.sin(2 * math.pi * P[6] * (t - P[8]) + P[7]) if t >= P[8] else 0.0
            else:
                s = (t - P[6]) / P[7]
                k = math.sin(math.pi * s) if 0.0 <= s <= 1.0 else 0.0
            f0 += k * P[0]
            f1 += k * P[1]
            f2 += k * P[2]
            t0 += k * P[3]
            t1 += k * P[4]
            t2 += k * P[5]
        elif code == 5:
            j = min(int(t / P[0]), int(P[ENC_PARAMS - 1]) - 1)
            f0 += series[d, j, 0]
            f1 += series[d, j, 1]
            f2 += series[d, j, 2]
            t0 += series[d, j, 3]
            t1 += series[d, j, 4]
            t2 += series[d, j, 5]
        elif code == 7:  # wall: spring-damper with regularised Coulomb friction
            n0, n1, n2 = P[3], P[4], P[5]
            pen = P[9] - ((p0 - P[0]) * n0 + (p1 - P[1]) * n1 + (p2 - P[2]) * n2)
            if pen > 0:
                vn = v0 * n0 + v1 * n1 + v2 * n2
                fn = max(P[6] * pen - P[7] * vn, 0.0)
                s0, s1, s2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
                k = P[8] * fn / max(math.sqrt(s0 * s0 + s1 * s1 + s2 * s2), P[10])
                a0, a1, a2 = fn * n0 - k * s0, fn * n1 - k * s1, fn * n2 - k * s2
                f0 += a0
                f1 += a1
                f2 += a2
                # contact point -radius n (world) from the origin, into the body frame
                c0 = -P[9] * (R[0] * n0 + R[3] * n1 + R[6] * n2)
                c1 = -P[9] * (R[1] * n0 + R[4] * n1 + R[7] * n2)
                c2 = -P[9] * (R[2] * n0 + R[5] * n1 + R[8] * n2)
                m0, m1, m2 = _moment_B(R, c0, c1, c2, a0, a1, a2)
                t0 += m0
                t1 += m1
                t2 += m2
        elif t >= P[12]:  # fan jet
            r0, r1, r2 = p0 - P[0], p1 - P[1], p2 - P[2]
            s = r0 * P[3] + r1 * P[4] + r2 * P[5]
            rr = r0 * r0 + r1 * r1 + r2 * r2 - s * s
            n = int(P[ENC_PARAMS - 1])
            gust = series[d, min(int(t / P[13]), n - 1), 0] if n > 0 else 0.0
            mag = P[6] * P[7] / max(s, 0.5 * P[7]) * math.exp(-rr / (2 * P[8] ** 2)) * (1.0 + gust)
            if not s > 0:
                mag = 0.0
            a0, a1, a2 = mag * P[3], mag * P[4], mag * P[5]
            f0 += a0
            f1 += a1
            f2 += a2
            m0, m1, m2 = _moment_B(R, P[9], P[10], P[11], a0, a1, a2)
            t0 += m0
            t1 += m1
            t2 += m2
    env[0] = f0
    env[1] = f1
    env[2] = f2
    env[3] = t0
    env[4] = t1
    env[5] = t2


@njit(cache=True, error_model="numpy", inline="always")
def _ground(pp, pz, v0, v1, v2):
    """Ground force at a contact point at depth ``pz`` moving with ``v``, as ``sim.plant._ground_force``."""
    if pz > 0.0 and pp[PP_GROUND] > 0.0:  # the ground pushes, never pulls
        return -pp[PP_BG] * v0, -pp[PP_BG] * v1, min(-(pp[PP_KG] * pz + pp[PP_CG] * v2), 0.0)
    return 0.0, 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _rotor_sums(pp, x, n):
    """``E f``: thrust and the three body moments of the rotor forces ``x[13:13+n]``."""
    e = PP_ROT
    u = tm0 = tm1 = tm2 = 0.0
    for i in range(n):
        fr = x[13 + i]
        u += pp[e + i] * fr
        tm0 += pp[e + n + i] * fr
        tm1 += pp[e + 2 * n + i] * fr
        tm2 += pp[e + 3 * n + i] * fr
    return u, tm0, tm1, tm2


@njit(cache=True, error_model="numpy", inline="always")
def _rotor_lag(pp, x, f_cmd, xd, n, kup, kdn):
    """First-order rotor lag towards the clipped commands, faster up than down."""
    lo = PP_ROT + 4 * n
    for i in range(n):
        g = min(max(f_cmd[i], pp[lo + i]), pp[lo + n + i])
        fr = x[13 + i]
        xd[13 + i] = (g - fr) * (kup if g > fr else kdn)


@njit(cache=True, error_model="numpy", inline="always")
def plant_derivative(pp, x, f_cmd, dist, xd, env):
    """``x_dot`` of the true plant into ``xd``, as :func:`vtol_impedance.sim.plant.plant_derivative`, and the
    external wrench into ``env = [f_ext_W (at the body origin), tau_ext_B]``, as
    :func:`vtol_impedance.sim.plant.environment_wrench` (disturbances, rotor drag, ground at two points).

    ``dist = [f_W, tau_B]`` are the explicit disturbances, evaluated by the caller (once per plant step,
    :func:`disturbance_at`). Written out in one function on purpose: numba's inlining of small
    tuple-returning helpers, or a disturbance call in here, cost three times the arithmetic. Allocation free.
    """
    R = _R_of(x, 6)
    # body-origin position (z only) and velocity, as sim.plant.origin_kinematics
    c0, c1, c2 = pp[PP_C], pp[PP_C + 1], pp[PP_C + 2]
    w0, w1, w2 = x[10], x[11], x[12]
    a0, a1, a2 = w1 * c2 - w2 * c1, w2 * c0 - w0 * c2, w0 * c1 - w1 * c0
    vo0 = x[3] - (R[0] * a0 + R[1] * a1 + R[2] * a2)
    vo1 = x[4] - (R[3] * a0 + R[4] * a1 + R[5] * a2)
    vo2 = x[5] - (R[6] * a0 + R[7] * a1 + R[8] * a2)
    po2 = x[2] - (R[6] * c0 + R[7] * c1 + R[8] * c2)
    fe0, fe1, fe2, te0, te1, te2 = dist[0], dist[1], dist[2], dist[3], dist[4], dist[5]
    # locals only from here on: a store to an array would force reloads through possible aliases
    kd = pp[PP_DRAG]
    fe0 = fe0 - kd * vo0
    fe1 = fe1 - kd * vo1
    fe2 = fe2 - kd * vo2
    g0, g1, g2 = _ground(pp, po2, vo0, vo1, vo2)
    fe0 += g0
    fe1 += g1
    fe2 += g2
    # second contact point (the payload) r_p: from the CoM d = r_p - c
    r0, r1, r2 = pp[PP_CONTACT], pp[PP_CONTACT + 1], pp[PP_CONTACT + 2]
    d0, d1, d2 = r0 - c0, r1 - c1, r2 - c2
    pc2 = x[2] + R[6] * d0 + R[7] * d1 + R[8] * d2
    if pc2 > 0.0 and pp[PP_GROUND] > 0.0:
        e0, e1, e2 = w1 * d2 - w2 * d1, w2 * d0 - w0 * d2, w0 * d1 - w1 * d0
        vc0 = x[3] + R[0] * e0 + R[1] * e1 + R[2] * e2
        vc1 = x[4] + R[3] * e0 + R[4] * e1 + R[5] * e2
        vc2 = x[5] + R[6] * e0 + R[7] * e1 + R[8] * e2
        h0, h1, h2 = _ground(pp, pc2, vc0, vc1, vc2)
        fe0 += h0
        fe1 += h1
        fe2 += h2
        m0, m1, m2 = _moment_B(R, r0, r1, r2, h0, h1, h2)
        te0 += m0
        te1 += m1
        te2 += m2
    n = int(pp[PP_NR])
    if n == 4:  # a literal count lets the compiler unroll the quadrotor's sums
        u, tm0, tm1, tm2 = _rotor_sums(pp, x, 4)
    else:
        u, tm0, tm1, tm2 = _rotor_sums(pp, x, n)
    im = pp[PP_INV_M]
    F0 = -u * R[2] + fe0
    F1 = -u * R[5] + fe1
    F2 = -u * R[8] + fe2
    # the pendulum, jointed at the CoM (sim.plant.link_force): tension from the link constraint
    ip = 13 + n
    ml = pp[PP_PM]
    lk0 = lk1 = lk2 = rdd0 = rdd1 = rdd2 = 0.0
    if ml > 0.0:
        q0, q1, q2 = x[ip], x[ip + 1], x[ip + 2]
        s0, s1, s2 = x[ip + 3], x[ip + 4], x[ip + 5]
        L = max(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2), 1e-9)
        n0, n1, n2 = q0 / L, q1 / L, q2 / L
        T = ((s0 * s0 + s1 * s1 + s2 * s2) / L - (n0 * F0 + n1 * F1 + n2 * F2) * im) / (1.0 / ml + im)
        lk0, lk1, lk2 = T * n0, T * n1, T * n2
        rdd0 = -T / ml * n0 - (F0 + lk0) * im
        rdd1 = -T / ml * n1 - (F1 + lk1) * im
        rdd2 = -T / ml * n2 - (F2 + lk2) * im
    fe0 += lk0  # logged with the external force; acting at the CoM it adds no moment (B below)
    fe1 += lk1
    fe2 += lk2
    B0 = R[0] * F0 + R[3] * F1 + R[6] * F2
    B1 = R[1] * F0 + R[4] * F1 + R[7] * F2
    B2 = R[2] * F0 + R[5] * F1 + R[8] * F2
    i = PP_I
    h0 = pp[i] * w0 + pp[i + 1] * w1 + pp[i + 2] * w2
    h1 = pp[i + 3] * w0 + pp[i + 4] * w1 + pp[i + 5] * w2
    h2 = pp[i + 6] * w0 + pp[i + 7] * w1 + pp[i + 8] * w2
    s0 = tm0 + te0 - (c1 * B2 - c2 * B1) - (w1 * h2 - w2 * h1)
    s1 = tm1 + te1 - (c2 * B0 - c0 * B2) - (w2 * h0 - w0 * h2)
    s2 = tm2 + te2 - (c0 * B1 - c1 * B0) - (w0 * h1 - w1 * h0)
    j = PP_IINV
    wd0 = pp[j] * s0 + pp[j + 1] * s1 + pp[j + 2] * s2
    wd1 = pp[j + 3] * s0 + pp[j + 4] * s1 + pp[j + 5] * s2
    wd2 = pp[j + 6] * s0 + pp[j + 7] * s1 + pp[j + 8] * s2
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    v0, v1, v2 = x[3], x[4], x[5]
    kup, kdn = pp[PP_INV_TUP], pp[PP_INV_TDN]
    xd[0], xd[1], xd[2] = v0, v1, v2
    xd[3] = (F0 + lk0) * im
    xd[4] = (F1 + lk1) * im
    xd[5] = G + (F2 + lk2) * im
    xd[6] = 0.5 * (-qx * w0 - qy * w1 - qz * w2)
    xd[7] = 0.5 * (qw * w0 + qy * w2 - qz * w1)
    xd[8] = 0.5 * (qw * w1 - qx * w2 + qz * w0)
    xd[9] = 0.5 * (qw * w2 + qx * w1 - qy * w0)
    xd[10], xd[11], xd[12] = wd0, wd1, wd2
    if n == 4:
        _rotor_lag(pp, x, f_cmd, xd, 4, kup, kdn)
    else:
        _rotor_lag(pp, x, f_cmd, xd, n, kup, kdn)
    xd[ip], xd[ip + 1], xd[ip + 2] = x[ip + 3], x[ip + 4], x[ip + 5]
    xd[ip + 3], xd[ip + 4], xd[ip + 5] = rdd0, rdd1, rdd2
    env[0], env[1], env[2], env[3], env[4], env[5] = fe0, fe1, fe2, te0, te1, te2


@njit(cache=True, error_model="numpy")
def lowest_contact_depth(pp, x):
    """Depth below ground of the lower contact point, as :func:`vtol_impedance.sim.plant.lowest_contact_depth`."""
    R = _R_of(x, 6)
    c0, c1, c2 = pp[PP_C], pp[PP_C + 1], pp[PP_C + 2]
    z_o = x[2] - (R[6] * c0 + R[7] * c1 + R[8] * c2)
    d0, d1, d2 = pp[PP_CONTACT] - c0, pp[PP_CONTACT + 1] - c1, pp[PP_CONTACT + 2] - c2
    return max(z_o, x[2] + R[6] * d0 + R[7] * d1 + R[8] * d2)


@njit(cache=True, error_model="numpy")
def disturbance_at(pp, x, t, codes, dparams, series, dist):
    """The explicit disturbances ``dist = [f_W, tau_B]`` at ``(t, x)``, as
    :func:`vtol_impedance.sim.plant.disturbance_at`."""
    if codes.shape[0] == 0:
        for i in range(6):
            dist[i] = 0.0
        return
    R = _R_of(x, 6)
    o = _origin(pp, x, R)
    add_disturbances(t, o[0], o[1], o[2], o[3], o[4], o[5], R, codes, dparams, series, dist)


@njit(cache=True, error_model="numpy")
def rk4_step(pp, x, f_cmd, dist, dt, k1, k2, k3, k4, xt, env):
    """One RK4 step in place with the rotor command and the disturbances ``dist`` held over the step;
    ``k1..k4``, ``xt`` (as long as ``x``) and ``env`` (6) are work arrays."""
    ns = x.shape[0]
    plant_derivative(pp, x, f_cmd, dist, k1, env)
    for i in range(ns):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    plant_derivative(pp, xt, f_cmd, dist, k2, env)
    for i in range(ns):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    plant_derivative(pp, xt, f_cmd, dist, k3, env)
    for i in range(ns):
        xt[i] = x[i] + dt * k3[i]
    plant_derivative(pp, xt, f_cmd, dist, k4, env)
    for i in range(ns):
        x[i] = x[i] + (dt / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    inq = 1.0 / math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
    for i in range(6, 10):
        x[i] *= inq
    if pp[PP_PM] > 0.0:  # back on the sphere, as sim.plant.project_pendulum
        ip = ns - 6
        L = max(math.sqrt(x[ip] ** 2 + x[ip + 1] ** 2 + x[ip + 2] ** 2), 1e-9)
        n0, n1, n2 = x[ip] / L, x[ip + 1] / L, x[ip + 2] / L
        vr = x[ip + 3] * n0 + x[ip + 4] * n1 + x[ip + 5] * n2
        x[ip], x[ip + 1], x[ip + 2] = pp[PP_PL] * n0, pp[PP_PL] * n1, pp[PP_PL] * n2
        x[ip + 3] -= vr * n0
        x[ip + 4] -= vr * n1
        x[ip + 5] -= vr * n2


@njit(cache=True, error_model="numpy")
def lumped_wrench(pp, x, xd, R, eta, u_prev, tau_prev, m_nom, cp, f, tau_eta):
    """What the nominal model misses, as :func:`vtol_impedance.sim.loop._lumped_wrench`; the nominal
    inertia is read from the controller row ``cp``."""
    c0, c1, c2 = pp[PP_C], pp[PP_C + 1], pp[PP_C + 2]
    w0, w1, w2 = x[10], x[11], x[12]
    a0, a1, a2 = xd[10], xd[11], xd[12]
    # w_dot x c + w x (w x c)
    u0, u1, u2 = w1 * c2 - w2 * c1, w2 * c0 - w0 * c2, w0 * c1 - w1 * c0
    s0 = (a1 * c2 - a2 * c1) + (w1 * u2 - w2 * u1)
    s1 = (a2 * c0 - a0 * c2) + (w2 * u0 - w0 * u2)
    s2 = (a0 * c1 - a1 * c0) + (w0 * u1 - w1 * u0)
    for i in range(3):
        a_o = xd[3 + i] - (R[i, 0] * s0 + R[i, 1] * s1 + R[i, 2] * s2)
        f[i] = m_nom * (a_o - (G if i == 2 else 0.0)) + u_prev * R[i, 2]
    Q = _Q9(eta[0], eta[1])
    d0, d1, d2 = _solve9(Q, w0, w1, w2)
    qd = _mv9(_Qd9(eta[0], eta[1], d0, d1), d0, d1, d2)
    dd0, dd1, dd2 = _solve9(Q, a0 - qd[0], a1 - qd[1], a2 - qd[2])
    I = (cp[1], cp[2], cp[3], cp[4], cp[5], cp[6], cp[7], cp[8], cp[9])  # noqa: E741
    _, M, C = _QMC(eta[0], eta[1], d0, d1, d2, I)
    me = _mv9(M, dd0, dd1, dd2)
    ce = _mv9(C, d0, d1, d2)
    qt = _mv9(_t9(Q), tau_prev[0], tau_prev[1], tau_prev[2])
    for i in range(3):
        tau_eta[i] = me[i] + ce[i] - qt[i]
