"""Compiled (numba) per-vehicle kernels of the true plant, its disturbances and the lumped wrench.

Same equations as :mod:`vtol_impedance.sim.plant` and :mod:`vtol_impedance.sim.disturbances` (the NumPy
reference backend and test oracle); ``tests/test_compiled.py`` proves they agree. The plant ``pp`` is a
:data:`~.layouts.PLANT` record, its state ``x`` a :data:`~.layouts.STATE` record: position and velocity of
the CoM (world NED), the attitude as a unit quaternion (renormalised after every RK4 step: no
trigonometry in the plant and no singularity at 90 deg pitch), the body rate, the rotor forces and the
pendulum. Rotor forces act through the true effectiveness matrix ``E`` here, while the NumPy plant sums
the rotors' cross products: the parity tests tie the two. Disturbances are :data:`~.layouts.DISTURBANCE`
records with their sampled series ``series (D, n, 6)``.
"""

from __future__ import annotations

import math

from ..conventions import G
from .algebra import _Q9, _QMC, _mv9, _Qd9, _solve9, _t9
from .jit import kernel
from .layouts import KIND, PUSH

_CONSTANT, _STEP, _RAMP, _SINUSOID = KIND["constant"], KIND["step"], KIND["ramp"], KIND["sinusoid"]
_SERIES, _WALL = KIND["series"], KIND["wall"]


@kernel(inline="always")
def _R_of(q):
    """Rotation body -> world of the unit quaternion ``q = [w, x, y, z]`` as a row-major 9-tuple."""
    w, x, y, z = q[0], q[1], q[2], q[3]
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


@kernel(inline="always")
def euler_of(R):
    """ZYX Euler angles ``(phi, theta, psi)`` of a row-major rotation 9-tuple."""
    return math.atan2(R[7], R[8]), -math.asin(min(max(R[6], -1.0), 1.0)), math.atan2(R[3], R[0])


@kernel(inline="always")
def _origin(pp, x, R):
    """Body-origin position and velocity (6-tuple, world) as :func:`vtol_impedance.sim.plant.origin_kinematics`."""
    c, w = pp.c_B, x.omega_B
    a0, a1, a2 = w[1] * c[2] - w[2] * c[1], w[2] * c[0] - w[0] * c[2], w[0] * c[1] - w[1] * c[0]
    p, v = x.p_com_W, x.v_com_W
    return (
        p[0] - (R[0] * c[0] + R[1] * c[1] + R[2] * c[2]),
        p[1] - (R[3] * c[0] + R[4] * c[1] + R[5] * c[2]),
        p[2] - (R[6] * c[0] + R[7] * c[1] + R[8] * c[2]),
        v[0] - (R[0] * a0 + R[1] * a1 + R[2] * a2),
        v[1] - (R[3] * a0 + R[4] * a1 + R[5] * a2),
        v[2] - (R[6] * a0 + R[7] * a1 + R[8] * a2),
    )


@kernel(inline="always")
def _moment_B(R, r0, r1, r2, f0, f1, f2):
    """Body-frame moment ``r_B x (R^T f_W)`` of a world force ``f_W`` acting at the body point ``r_B``."""
    b0 = R[0] * f0 + R[3] * f1 + R[6] * f2
    b1 = R[1] * f0 + R[4] * f1 + R[7] * f2
    b2 = R[2] * f0 + R[5] * f1 + R[8] * f2
    return r1 * b2 - r2 * b1, r2 * b0 - r0 * b2, r0 * b1 - r1 * b0


@kernel()
def add_disturbances(t, p0, p1, p2, v0, v1, v2, R, dists, series, env):
    """Write the sum of the disturbances into ``env = [f_W, tau_B]``, as
    :class:`vtol_impedance.sim.disturbances.DisturbanceSet`. ``R`` is the rotation as a row-major 9-tuple;
    ``p``, ``v`` the body origin's position and velocity (world)."""
    f0 = f1 = f2 = t0 = t1 = t2 = 0.0
    for i in range(dists.shape[0]):
        d = dists[i]
        kind = d.kind
        if kind <= PUSH:  # a wrench times a profile of time
            if kind == _CONSTANT:
                k = 1.0
            elif kind == _STEP:
                k = 1.0 if d.t_on <= t < d.t_off else 0.0
            elif kind == _RAMP:
                k = min(max((t - d.t_on) / (d.t_off - d.t_on), 0.0), 1.0)
            elif kind == _SINUSOID:
                k = math.sin(2 * math.pi * d.freq_hz * (t - d.t_on) + d.phase) if t >= d.t_on else 0.0
            else:
                s = (t - d.t_on) / d.duration
                k = math.sin(math.pi * s) if 0.0 <= s <= 1.0 else 0.0
            f0 += k * d.force_W[0]
            f1 += k * d.force_W[1]
            f2 += k * d.force_W[2]
            t0 += k * d.torque_B[0]
            t1 += k * d.torque_B[1]
            t2 += k * d.torque_B[2]
        elif kind == _SERIES:
            j = min(int(t / d.sample_dt), d.n_samples - 1)
            f0 += series[i, j, 0]
            f1 += series[i, j, 1]
            f2 += series[i, j, 2]
            t0 += series[i, j, 3]
            t1 += series[i, j, 4]
            t2 += series[i, j, 5]
        elif kind == _WALL:  # spring-damper with regularised Coulomb friction
            n0, n1, n2 = d.normal_W[0], d.normal_W[1], d.normal_W[2]
            q = d.point_W
            pen = d.radius - ((p0 - q[0]) * n0 + (p1 - q[1]) * n1 + (p2 - q[2]) * n2)
            if pen > 0:
                vn = v0 * n0 + v1 * n1 + v2 * n2
                fn = max(d.stiffness * pen - d.damping * vn, 0.0)
                s0, s1, s2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
                k = d.friction * fn / max(math.sqrt(s0 * s0 + s1 * s1 + s2 * s2), d.slip_speed)
                a0, a1, a2 = fn * n0 - k * s0, fn * n1 - k * s1, fn * n2 - k * s2
                f0 += a0
                f1 += a1
                f2 += a2
                # contact point -radius n (world) from the origin, into the body frame
                c0 = -d.radius * (R[0] * n0 + R[3] * n1 + R[6] * n2)
                c1 = -d.radius * (R[1] * n0 + R[4] * n1 + R[7] * n2)
                c2 = -d.radius * (R[2] * n0 + R[5] * n1 + R[8] * n2)
                m0, m1, m2 = _moment_B(R, c0, c1, c2, a0, a1, a2)
                t0 += m0
                t1 += m1
                t2 += m2
        elif t >= d.t_on:  # fan jet
            q, u = d.point_W, d.normal_W
            r0, r1, r2 = p0 - q[0], p1 - q[1], p2 - q[2]
            s = r0 * u[0] + r1 * u[1] + r2 * u[2]
            rr = r0 * r0 + r1 * r1 + r2 * r2 - s * s
            n = d.n_samples
            gust = series[i, min(int(t / d.sample_dt), n - 1), 0] if n > 0 else 0.0
            mag = d.mean_force * d.ref_distance / max(s, 0.5 * d.ref_distance)
            mag *= math.exp(-rr / (2 * d.width**2)) * (1.0 + gust)
            if not s > 0:
                mag = 0.0
            a0, a1, a2 = mag * u[0], mag * u[1], mag * u[2]
            f0 += a0
            f1 += a1
            f2 += a2
            c = d.cop_offset_B
            m0, m1, m2 = _moment_B(R, c[0], c[1], c[2], a0, a1, a2)
            t0 += m0
            t1 += m1
            t2 += m2
    env[0], env[1], env[2], env[3], env[4], env[5] = f0, f1, f2, t0, t1, t2


@kernel(inline="always")
def _ground(pp, pz, v0, v1, v2):
    """Ground force at a contact point at depth ``pz`` moving with ``v``, as ``sim.plant._ground_force``."""
    if pz > 0.0 and pp.ground > 0.0:  # the ground pushes, never pulls
        return -pp.b_ground * v0, -pp.b_ground * v1, min(-(pp.k_ground * pz + pp.c_ground * v2), 0.0)
    return 0.0, 0.0, 0.0


@kernel(inline="always")
def _rotor_sums(pp, f, n):
    """``E f``, eq. (4) with the true geometry: thrust and the three body moments of the rotor forces."""
    E = pp.E
    u = tm0 = tm1 = tm2 = 0.0
    for i in range(n):
        u += E[0, i] * f[i]
        tm0 += E[1, i] * f[i]
        tm1 += E[2, i] * f[i]
        tm2 += E[3, i] * f[i]
    return u, tm0, tm1, tm2


@kernel(inline="always")
def _rotor_lag(pp, f, f_cmd, f_dot, n):
    """First-order rotor lag towards the clipped commands, faster up than down."""
    for i in range(n):
        g = min(max(f_cmd[i], pp.f_min[i]), pp.f_max[i])
        f_dot[i] = (g - f[i]) * (pp.inv_tau_up if g > f[i] else pp.inv_tau_down)


@kernel(inline="always")
def plant_derivative(pp, x, f_cmd, dist, xd, env):
    """``x_dot`` of the true plant into ``xd``, as :func:`vtol_impedance.sim.plant.plant_derivative`, and the
    external wrench into ``env = [f_ext_W (at the body origin), tau_ext_B]``, as
    :func:`vtol_impedance.sim.plant.environment_wrench` (disturbances, rotor drag, ground at two points).

    ``dist = [f_W, tau_B]`` are the explicit disturbances, evaluated by the caller (once per plant step,
    :func:`disturbance_at`). Newton-Euler about the CoM: ``m a = m g - u R e3 + f_env``,
    ``I w_dot = tau - c x F_B - w x I w``. Allocation free.
    """
    R = _R_of(x.q_WB)
    c, w = pp.c_B, x.omega_B
    w0, w1, w2 = w[0], w[1], w[2]
    v0, v1, v2 = x.v_com_W[0], x.v_com_W[1], x.v_com_W[2]
    # body-origin depth and velocity, as sim.plant.origin_kinematics
    a0, a1, a2 = w1 * c[2] - w2 * c[1], w2 * c[0] - w0 * c[2], w0 * c[1] - w1 * c[0]
    vo0 = v0 - (R[0] * a0 + R[1] * a1 + R[2] * a2)
    vo1 = v1 - (R[3] * a0 + R[4] * a1 + R[5] * a2)
    vo2 = v2 - (R[6] * a0 + R[7] * a1 + R[8] * a2)
    zo = x.p_com_W[2] - (R[6] * c[0] + R[7] * c[1] + R[8] * c[2])
    # environment: disturbances, rotor drag, ground under the origin
    kd = pp.rotor_drag
    g0, g1, g2 = _ground(pp, zo, vo0, vo1, vo2)
    fe0 = dist[0] - kd * vo0 + g0
    fe1 = dist[1] - kd * vo1 + g1
    fe2 = dist[2] - kd * vo2 + g2
    te0, te1, te2 = dist[3], dist[4], dist[5]
    # second contact point (the payload) r_p: from the CoM d = r_p - c
    r = pp.r_contact_B
    d0, d1, d2 = r[0] - c[0], r[1] - c[1], r[2] - c[2]
    zc = x.p_com_W[2] + R[6] * d0 + R[7] * d1 + R[8] * d2
    if zc > 0.0 and pp.ground > 0.0:
        e0, e1, e2 = w1 * d2 - w2 * d1, w2 * d0 - w0 * d2, w0 * d1 - w1 * d0
        h0, h1, h2 = _ground(
            pp, zc, v0 + R[0] * e0 + R[1] * e1 + R[2] * e2, v1 + R[3] * e0 + R[4] * e1 + R[5] * e2,
            v2 + R[6] * e0 + R[7] * e1 + R[8] * e2,
        )  # fmt: skip
        fe0 += h0
        fe1 += h1
        fe2 += h2
        m0, m1, m2 = _moment_B(R, r[0], r[1], r[2], h0, h1, h2)
        te0 += m0
        te1 += m1
        te2 += m2
    n = pp.n_rotors
    if n == 4:  # a literal count lets the compiler unroll the quadrotor's sums
        u, tm0, tm1, tm2 = _rotor_sums(pp, x.f_rotor, 4)
    else:
        u, tm0, tm1, tm2 = _rotor_sums(pp, x.f_rotor, n)
    im = pp.inv_mass
    F0 = -u * R[2] + fe0
    F1 = -u * R[5] + fe1
    F2 = -u * R[8] + fe2
    # the pendulum, jointed at the CoM (sim.plant.link_force): tension from the link constraint
    ml = pp.pend_m
    lk0 = lk1 = lk2 = rdd0 = rdd1 = rdd2 = 0.0
    if ml > 0.0:
        q, s = x.r_pend_W, x.v_pend_W
        L = max(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), 1e-9)
        n0, n1, n2 = q[0] / L, q[1] / L, q[2] / L
        T = ((s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / L - (n0 * F0 + n1 * F1 + n2 * F2) * im) / (1.0 / ml + im)
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
    I, Ii = pp.I_com, pp.I_com_inv
    h0 = I[0, 0] * w0 + I[0, 1] * w1 + I[0, 2] * w2
    h1 = I[1, 0] * w0 + I[1, 1] * w1 + I[1, 2] * w2
    h2 = I[2, 0] * w0 + I[2, 1] * w1 + I[2, 2] * w2
    s0 = tm0 + te0 - (c[1] * B2 - c[2] * B1) - (w1 * h2 - w2 * h1)
    s1 = tm1 + te1 - (c[2] * B0 - c[0] * B2) - (w2 * h0 - w0 * h2)
    s2 = tm2 + te2 - (c[0] * B1 - c[1] * B0) - (w0 * h1 - w1 * h0)
    qw, qx, qy, qz = x.q_WB[0], x.q_WB[1], x.q_WB[2], x.q_WB[3]
    xd.p_com_W[0], xd.p_com_W[1], xd.p_com_W[2] = v0, v1, v2
    xd.v_com_W[0] = (F0 + lk0) * im
    xd.v_com_W[1] = (F1 + lk1) * im
    xd.v_com_W[2] = G + (F2 + lk2) * im
    xd.q_WB[0] = 0.5 * (-qx * w0 - qy * w1 - qz * w2)
    xd.q_WB[1] = 0.5 * (qw * w0 + qy * w2 - qz * w1)
    xd.q_WB[2] = 0.5 * (qw * w1 - qx * w2 + qz * w0)
    xd.q_WB[3] = 0.5 * (qw * w2 + qx * w1 - qy * w0)
    xd.omega_B[0] = Ii[0, 0] * s0 + Ii[0, 1] * s1 + Ii[0, 2] * s2
    xd.omega_B[1] = Ii[1, 0] * s0 + Ii[1, 1] * s1 + Ii[1, 2] * s2
    xd.omega_B[2] = Ii[2, 0] * s0 + Ii[2, 1] * s1 + Ii[2, 2] * s2
    if n == 4:
        _rotor_lag(pp, x.f_rotor, f_cmd, xd.f_rotor, 4)
    else:
        _rotor_lag(pp, x.f_rotor, f_cmd, xd.f_rotor, n)
    for i in range(3):
        xd.r_pend_W[i] = x.v_pend_W[i]
    xd.v_pend_W[0], xd.v_pend_W[1], xd.v_pend_W[2] = rdd0, rdd1, rdd2
    env[0], env[1], env[2], env[3], env[4], env[5] = fe0, fe1, fe2, te0, te1, te2


@kernel()
def lowest_contact_depth(pp, x):
    """Depth below ground of the lower contact point, as :func:`vtol_impedance.sim.plant.lowest_contact_depth`."""
    R = _R_of(x.q_WB)
    c, r, z = pp.c_B, pp.r_contact_B, x.p_com_W[2]
    z_o = z - (R[6] * c[0] + R[7] * c[1] + R[8] * c[2])
    return max(z_o, z + R[6] * (r[0] - c[0]) + R[7] * (r[1] - c[1]) + R[8] * (r[2] - c[2]))


@kernel()
def disturbance_at(pp, x, t, dists, series, dist):
    """The explicit disturbances ``dist = [f_W, tau_B]`` at ``(t, x)``, as
    :func:`vtol_impedance.sim.plant.disturbance_at`."""
    if dists.shape[0] == 0:
        for i in range(6):
            dist[i] = 0.0
        return
    R = _R_of(x.q_WB)
    o = _origin(pp, x, R)
    add_disturbances(t, o[0], o[1], o[2], o[3], o[4], o[5], R, dists, series, dist)


@kernel(inline="always")
def _stage(out, x, h, k, n):
    """``out = x + h k`` over every field of the state (``n`` rotors)."""
    for i in range(3):
        out.p_com_W[i] = x.p_com_W[i] + h * k.p_com_W[i]
        out.v_com_W[i] = x.v_com_W[i] + h * k.v_com_W[i]
        out.omega_B[i] = x.omega_B[i] + h * k.omega_B[i]
        out.r_pend_W[i] = x.r_pend_W[i] + h * k.r_pend_W[i]
        out.v_pend_W[i] = x.v_pend_W[i] + h * k.v_pend_W[i]
    for i in range(4):
        out.q_WB[i] = x.q_WB[i] + h * k.q_WB[i]
    for i in range(n):
        out.f_rotor[i] = x.f_rotor[i] + h * k.f_rotor[i]


@kernel(inline="always")
def _rk4_sum(x, h, k1, k2, k3, k4, n):
    """``x += h/6 (k1 + 2 k2 + 2 k3 + k4)`` over every field."""
    for i in range(3):
        x.p_com_W[i] += h * (k1.p_com_W[i] + 2.0 * k2.p_com_W[i] + 2.0 * k3.p_com_W[i] + k4.p_com_W[i])
        x.v_com_W[i] += h * (k1.v_com_W[i] + 2.0 * k2.v_com_W[i] + 2.0 * k3.v_com_W[i] + k4.v_com_W[i])
        x.omega_B[i] += h * (k1.omega_B[i] + 2.0 * k2.omega_B[i] + 2.0 * k3.omega_B[i] + k4.omega_B[i])
        x.r_pend_W[i] += h * (k1.r_pend_W[i] + 2.0 * k2.r_pend_W[i] + 2.0 * k3.r_pend_W[i] + k4.r_pend_W[i])
        x.v_pend_W[i] += h * (k1.v_pend_W[i] + 2.0 * k2.v_pend_W[i] + 2.0 * k3.v_pend_W[i] + k4.v_pend_W[i])
    for i in range(4):
        x.q_WB[i] += h * (k1.q_WB[i] + 2.0 * k2.q_WB[i] + 2.0 * k3.q_WB[i] + k4.q_WB[i])
    for i in range(n):
        x.f_rotor[i] += h * (k1.f_rotor[i] + 2.0 * k2.f_rotor[i] + 2.0 * k3.f_rotor[i] + k4.f_rotor[i])


@kernel()
def rk4_step(pp, x, f_cmd, dist, dt, work, env):
    """One RK4 step of ``x`` in place with the rotor command and the disturbances ``dist`` held over the step;
    ``work`` holds five state records (the four slopes and a stage), ``env`` (6) is scratch.

    The quaternion is renormalised after the step (RK4 keeps its norm to the method's order only) and the
    pendulum put back on its sphere, as :func:`vtol_impedance.sim.plant.rk4_step`."""
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]
    n = pp.n_rotors
    plant_derivative(pp, x, f_cmd, dist, k1, env)
    _stage(xt, x, 0.5 * dt, k1, n)
    plant_derivative(pp, xt, f_cmd, dist, k2, env)
    _stage(xt, x, 0.5 * dt, k2, n)
    plant_derivative(pp, xt, f_cmd, dist, k3, env)
    _stage(xt, x, dt, k3, n)
    plant_derivative(pp, xt, f_cmd, dist, k4, env)
    _rk4_sum(x, dt / 6.0, k1, k2, k3, k4, n)
    q = x.q_WB
    inq = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] *= inq
    if pp.pend_m > 0.0:  # back on the sphere, as sim.plant.project_pendulum
        r, v = x.r_pend_W, x.v_pend_W
        L = max(math.sqrt(r[0] ** 2 + r[1] ** 2 + r[2] ** 2), 1e-9)
        n0, n1, n2 = r[0] / L, r[1] / L, r[2] / L
        vr = v[0] * n0 + v[1] * n1 + v[2] * n2
        r[0], r[1], r[2] = pp.pend_L * n0, pp.pend_L * n1, pp.pend_L * n2
        v[0] -= vr * n0
        v[1] -= vr * n1
        v[2] -= vr * n2


@kernel()
def lumped_wrench(pp, x, xd, R, eta, u_prev, tau_prev, m_nom, I_nom, f, tau_eta):
    """What the nominal model (mass ``m_nom``, inertia ``I_nom`` as a 9-tuple) misses, as
    :func:`vtol_impedance.sim.loop._lumped_wrench`: ``f`` (world) and ``tau_eta`` (Euler coordinates)."""
    c, w, wd = pp.c_B, x.omega_B, xd.omega_B
    w0, w1, w2 = w[0], w[1], w[2]
    a0, a1, a2 = wd[0], wd[1], wd[2]
    # acceleration of the origin: a_com - R (w_dot x c + w x (w x c))
    u0, u1, u2 = w1 * c[2] - w2 * c[1], w2 * c[0] - w0 * c[2], w0 * c[1] - w1 * c[0]
    s0 = (a1 * c[2] - a2 * c[1]) + (w1 * u2 - w2 * u1)
    s1 = (a2 * c[0] - a0 * c[2]) + (w2 * u0 - w0 * u2)
    s2 = (a0 * c[1] - a1 * c[0]) + (w0 * u1 - w1 * u0)
    for i in range(3):
        a_o = xd.v_com_W[i] - (R[3 * i] * s0 + R[3 * i + 1] * s1 + R[3 * i + 2] * s2)
        f[i] = m_nom * (a_o - (G if i == 2 else 0.0)) + u_prev * R[3 * i + 2]
    Q = _Q9(eta[0], eta[1])
    d0, d1, d2 = _solve9(Q, w0, w1, w2)
    qd = _mv9(_Qd9(eta[0], eta[1], d0, d1), d0, d1, d2)
    dd0, dd1, dd2 = _solve9(Q, a0 - qd[0], a1 - qd[1], a2 - qd[2])
    _, M, C = _QMC(eta[0], eta[1], d0, d1, d2, I_nom)
    me = _mv9(M, dd0, dd1, dd2)
    ce = _mv9(C, d0, d1, d2)
    qt = _mv9(_t9(Q), tau_prev[0], tau_prev[1], tau_prev[2])
    for i in range(3):
        tau_eta[i] = me[i] + ce[i] - qt[i]
