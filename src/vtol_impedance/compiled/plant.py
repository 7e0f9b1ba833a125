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
from collections import namedtuple

from ..conventions import G
from ..records import CRASH_DEPTH_M, FAIL_CRASH, FAIL_FAR, FAIL_NAN, FAIL_TILT, MAX_DISTANCE_M, MAX_TILT_RAD
from .algebra import _Q9, _QMC, _m9, _mv9, _Qd9, _solve9, _t9, _v3
from .jit import kernel
from .layouts import KIND, PUSH
from .vmath import arcsin, arctan2

_CONSTANT, _STEP, _RAMP, _SINUSOID = KIND["constant"], KIND["step"], KIND["ramp"], KIND["sinusoid"]
_SERIES, _WALL = KIND["series"], KIND["wall"]
_COS_TILT_MAX = math.cos(MAX_TILT_RAD)

#: What the body's dynamics read of a plant, as plain numbers (inertias as row-major 9-tuples): built from a
#: :data:`~.layouts.PLANT` record by :func:`lane_of`, or from one lane of a batch in lanes
#: (:mod:`.lanes`), so that both engines run the same :func:`body_derivative`. The rotors' geometry and limits
#: are not here: the rotor stages read them where they are.
PlantLane = namedtuple(
    "PlantLane",
    ("inv_mass", "I_com", "I_com_inv", "c_B", "r_contact_B", "inv_tau_up", "inv_tau_down", "lin_drag_B",
     "quad_drag_B", "ground", "k_ground", "c_ground", "b_ground", "pend_m", "pend_L"),
)  # fmt: skip


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
def euler_of(R, vector):
    """ZYX Euler angles ``(phi, theta, psi)`` of a row-major rotation 9-tuple (``vector``, a literal: with the
    functions of :mod:`.vmath`, for code in lanes)."""
    phi, psi = arctan2(R[7], R[8], vector), arctan2(R[3], R[0], vector)
    return phi, -arcsin(min(max(R[6], -1.0), 1.0), vector), psi


@kernel(inline="always")
def lane_of(pp):
    """The :data:`PlantLane` of a :data:`~.layouts.PLANT` record."""
    return PlantLane(
        pp.inv_mass, _m9(pp.I_com), _m9(pp.I_com_inv), _v3(pp.c_B), _v3(pp.r_contact_B), pp.inv_tau_up,
        pp.inv_tau_down, _v3(pp.lin_drag_B), _v3(pp.quad_drag_B), pp.ground, pp.k_ground, pp.c_ground, pp.b_ground,
        pp.pend_m, pp.pend_L,
    )  # fmt: skip


@kernel(inline="always")
def plant_is_plain(pl):
    """Whether the :data:`PlantLane` ``pl`` has neither a pendulum nor quadratic drag: its derivative is then
    the same with :func:`body_derivative`'s ``full`` false."""
    q = pl.quad_drag_B
    return not pl.pend_m > 0.0 and q[0] == 0.0 and q[1] == 0.0 and q[2] == 0.0


@kernel(inline="always")
def origin_of(c, p, v, w, R):
    """Body-origin position and velocity (6-tuple, world) of a body whose CoM (at ``c``, body) is at ``p`` moving
    at ``v`` (world) and turning at ``w`` (body), as :func:`vtol_impedance.sim.plant.origin_kinematics`."""
    a0, a1, a2 = w[1] * c[2] - w[2] * c[1], w[2] * c[0] - w[0] * c[2], w[0] * c[1] - w[1] * c[0]
    return (
        p[0] - (R[0] * c[0] + R[1] * c[1] + R[2] * c[2]),
        p[1] - (R[3] * c[0] + R[4] * c[1] + R[5] * c[2]),
        p[2] - (R[6] * c[0] + R[7] * c[1] + R[8] * c[2]),
        v[0] - (R[0] * a0 + R[1] * a1 + R[2] * a2),
        v[1] - (R[3] * a0 + R[4] * a1 + R[5] * a2),
        v[2] - (R[6] * a0 + R[7] * a1 + R[8] * a2),
    )


@kernel(inline="always")
def measured(c_B, p, v, q, w, q_imu, w_imu, sigma, noise, vector):
    """What the sensors report, ``y = [p_W, v_W, eta, eta_dot]`` (12), as
    :func:`vtol_impedance.sim.sensors.measurement`: the body origin's position and velocity (world) of the
    motion-capture state (the CoM's position ``p`` and velocity ``v``, world; attitude quaternion ``q``; body
    rates ``w``; the CoM at ``c_B`` in the body), the ZYX Euler angles of the IMU's attitude ``q_imu`` and the
    Euler rates ``Q(eta)^-1 w_imu`` at the noisy angles, each plus ``sigma[group] * noise`` (``sigma = [pos,
    vel, att, gyro]``, ``noise`` 12 standard normals in the order of ``y``). ``vector`` (a literal): the sines
    of :mod:`.vmath`, for code in lanes."""
    o = origin_of(c_B, p, v, w, _R_of(q))
    phi, theta, psi = euler_of(_R_of(q_imu), vector)
    e0, e1, e2 = phi + sigma[2] * noise[6], theta + sigma[2] * noise[7], psi + sigma[2] * noise[8]
    g0, g1, g2 = w_imu[0] + sigma[3] * noise[9], w_imu[1] + sigma[3] * noise[10], w_imu[2] + sigma[3] * noise[11]
    ed = _solve9(_Q9(e0, e1, vector), g0, g1, g2)
    return (o[0] + sigma[0] * noise[0], o[1] + sigma[0] * noise[1], o[2] + sigma[0] * noise[2],
            o[3] + sigma[1] * noise[3], o[4] + sigma[1] * noise[4], o[5] + sigma[1] * noise[5], e0, e1, e2, ed[0],
            ed[1], ed[2])  # fmt: skip


@kernel(inline="always")
def _origin(pp, x, R):
    """:func:`origin_of` for the plant record ``pp`` in the state ``x`` (a record or a lane's view)."""
    return origin_of(pp.c_B, x.p_com_W, x.v_com_W, x.omega_B, R)


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
def _lag(up, down, g, f):
    """``f_dot`` of one rotor: first-order lag towards its clipped command ``g``, at the rate ``up`` (1/s) when
    rising and ``down`` when falling."""
    return (g - f) * (up if g > f else down)


@kernel(inline="always")
def clip_command(f_cmd, f_min, f_max):
    """A rotor's command within its limits."""
    return min(max(f_cmd, f_min), f_max)


@kernel(inline="always")
def instant_force(up_now, down_now, g, f):
    """A rotor's force ``f`` after its clipped command ``g`` arrives, in a direction without lag (``up_now``:
    no lag rising, ``down_now``: none falling) at once, else unchanged."""
    return g if (up_now and g > f) or (down_now and g < f) else f


@kernel(inline="always")
def rotor_rk4(up, down, g, f1, dt):
    """One rotor's RK4 step towards its clipped command ``g`` (rates ``up``, ``down`` of :func:`_lag`): the new
    force and the force at the second, third and fourth stages (the first is ``f1``)."""
    h2 = 0.5 * dt
    k1 = _lag(up, down, g, f1)
    f2 = f1 + h2 * k1
    k2 = _lag(up, down, g, f2)
    f3 = f1 + h2 * k2
    k3 = _lag(up, down, g, f3)
    f4 = f1 + dt * k3
    k4 = _lag(up, down, g, f4)
    return f1 + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4), f2, f3, f4


@kernel(inline="always")
def _body_of(x):
    """The 19 states other than the rotors as a tuple (held in registers by the RK4 step):
    ``p_com_W, v_com_W, q_WB, omega_B, r_pend_W, v_pend_W``."""
    p, v, q, w, r, s = x.p_com_W, x.v_com_W, x.q_WB, x.omega_B, x.r_pend_W, x.v_pend_W
    return (p[0], p[1], p[2], v[0], v[1], v[2], q[0], q[1], q[2], q[3], w[0], w[1], w[2],
            r[0], r[1], r[2], s[0], s[1], s[2])  # fmt: skip


@kernel(inline="always")
def _set_body(x, s):
    """Write the tuple of :func:`_body_of` back into the record ``x``."""
    for i in range(3):
        x.p_com_W[i] = s[i]
        x.v_com_W[i] = s[3 + i]
        x.omega_B[i] = s[10 + i]
        x.r_pend_W[i] = s[13 + i]
        x.v_pend_W[i] = s[16 + i]
    for i in range(4):
        x.q_WB[i] = s[6 + i]


@kernel(inline="always")
def _aero_W(pp, R, v0, v1, v2, full):
    """The aerodynamic force (world) at the body origin moving at ``v`` (world), as
    :func:`vtol_impedance.sim.plant.aero_force_W`: ``R (-D v_B - |v_B| C v_B)`` with ``v_B = Rᵀ v``; with
    ``full`` false the quadratic term is left out (it is zero: see :func:`body_derivative`)."""
    b0 = R[0] * v0 + R[3] * v1 + R[6] * v2
    b1 = R[1] * v0 + R[4] * v1 + R[7] * v2
    b2 = R[2] * v0 + R[5] * v1 + R[8] * v2
    D, C = pp.lin_drag_B, pp.quad_drag_B
    k0, k1, k2 = D[0], D[1], D[2]
    if full:
        speed = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        k0, k1, k2 = D[0] + speed * C[0], D[1] + speed * C[1], D[2] + speed * C[2]
    f0 = -k0 * b0
    f1 = -k1 * b1
    f2 = -k2 * b2
    return R[0] * f0 + R[1] * f1 + R[2] * f2, R[3] * f0 + R[4] * f1 + R[5] * f2, R[6] * f0 + R[7] * f1 + R[8] * f2


@kernel(inline="always")
def body_derivative(pp, s, u, tm0, tm1, tm2, dist, full, contact):
    """``x_dot`` of the true plant's body and pendulum (the tuple of :func:`_body_of`) for the plant ``pp`` (a
    :data:`PlantLane`), as :func:`vtol_impedance.sim.plant.plant_derivative`, with the rotors' thrust ``u`` and
    body moments ``tm`` (eq. (4), the true ``E``); and the external wrench ``[f_ext_W (at the body origin),
    tau_ext_B]``, as :func:`vtol_impedance.sim.plant.environment_wrench` (disturbances, rotor drag, ground at two
    points).

    ``dist = [f_W, tau_B]`` are the explicit disturbances, evaluated by the caller (once per plant step,
    :func:`disturbance_at`). Newton-Euler about the CoM: ``m a = m g - u R e3 + f_env``,
    ``I w_dot = tau - c x F_B - w x I w``; the quaternion ``q_dot = q (0, w) / 2``. Pure: no memory written.

    ``full`` false leaves out the pendulum and the quadratic drag, for plants that have neither
    (``pend_m = 0``, ``quad_drag_B = 0``: their terms are exact zeros, so the result is the same). A block of
    lanes passes it as a literal where none of its plants has them (:func:`plant_is_plain`), and the compiler
    drops their square roots and divisions, which SIMD lanes would otherwise compute and discard.

    ``contact`` false (a literal) leaves out the ground at both points, a quarter of the arithmetic, which
    lanes otherwise compute in every lane and discard in flight: the result is the same wherever the third
    value returned, ``touch``, is 0 (1 where the ground acts at a point of ``s``, or would: ``ground`` on and
    a point below it). A plain block in lanes (:func:`~.lanes._bodies_plain`) takes its step without it and
    takes it over with it where a lane's ``touch`` was 1 at one of the step's stages; a block with the whole
    step (``full``) always takes it.
    """
    p2, v0, v1, v2 = s[2], s[3], s[4], s[5]
    qw, qx, qy, qz = s[6], s[7], s[8], s[9]
    w0, w1, w2 = s[10], s[11], s[12]
    R = _R_of((qw, qx, qy, qz))
    c = pp.c_B
    # body-origin depth and velocity, as sim.plant.origin_kinematics
    a0, a1, a2 = w1 * c[2] - w2 * c[1], w2 * c[0] - w0 * c[2], w0 * c[1] - w1 * c[0]
    vo0 = v0 - (R[0] * a0 + R[1] * a1 + R[2] * a2)
    vo1 = v1 - (R[3] * a0 + R[4] * a1 + R[5] * a2)
    vo2 = v2 - (R[6] * a0 + R[7] * a1 + R[8] * a2)
    zo = p2 - (R[6] * c[0] + R[7] * c[1] + R[8] * c[2])
    # environment: disturbances, aerodynamic force (sim.plant.aero_force_W), ground under the origin
    ae0, ae1, ae2 = _aero_W(pp, R, vo0, vo1, vo2, full)
    g0 = g1 = g2 = 0.0  # an exact zero where the ground does not act, added as such (bit for bit)
    if contact:
        g0, g1, g2 = _ground(pp, zo, vo0, vo1, vo2)
    fe0 = dist[0] + ae0 + g0
    fe1 = dist[1] + ae1 + g1
    fe2 = dist[2] + ae2 + g2
    te0, te1, te2 = dist[3], dist[4], dist[5]
    # second contact point (the payload) r_p: from the CoM d = r_p - c
    r = pp.r_contact_B
    d0, d1, d2 = r[0] - c[0], r[1] - c[1], r[2] - c[2]
    zc = p2 + R[6] * d0 + R[7] * d1 + R[8] * d2
    if contact and zc > 0.0 and pp.ground > 0.0:
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
    im = pp.inv_mass
    F0 = -u * R[2] + fe0  # eq. (5a): -u R e3 + f_ext
    F1 = -u * R[5] + fe1
    F2 = -u * R[8] + fe2
    # the pendulum, jointed at the CoM (sim.plant.link_force): tension from the link constraint
    ml = pp.pend_m
    lk0 = lk1 = lk2 = rdd0 = rdd1 = rdd2 = 0.0
    if full and ml > 0.0:
        q0, q1, q2, s0, s1, s2 = s[13], s[14], s[15], s[16], s[17], s[18]
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
    I, Ii = pp.I_com, pp.I_com_inv
    h0 = I[0] * w0 + I[1] * w1 + I[2] * w2
    h1 = I[3] * w0 + I[4] * w1 + I[5] * w2
    h2 = I[6] * w0 + I[7] * w1 + I[8] * w2
    m0 = tm0 + te0 - (c[1] * B2 - c[2] * B1) - (w1 * h2 - w2 * h1)  # eq. (2b)
    m1 = tm1 + te1 - (c[2] * B0 - c[0] * B2) - (w2 * h0 - w0 * h2)
    m2 = tm2 + te2 - (c[0] * B1 - c[1] * B0) - (w0 * h1 - w1 * h0)
    x_dot = (
        v0, v1, v2,
        (F0 + lk0) * im, (F1 + lk1) * im, G + (F2 + lk2) * im,  # eqs. (3a), (5a)
        0.5 * (-qx * w0 - qy * w1 - qz * w2), 0.5 * (qw * w0 + qy * w2 - qz * w1),
        0.5 * (qw * w1 - qx * w2 + qz * w0), 0.5 * (qw * w2 + qx * w1 - qy * w0),
        Ii[0] * m0 + Ii[1] * m1 + Ii[2] * m2,
        Ii[3] * m0 + Ii[4] * m1 + Ii[5] * m2,
        Ii[6] * m0 + Ii[7] * m1 + Ii[8] * m2,
        s[16], s[17], s[18], rdd0, rdd1, rdd2,
    )  # fmt: skip
    touch = 1.0 if (pp.ground > 0.0) & ((zo > 0.0) | (zc > 0.0)) else 0.0  # the ground acts, or would
    return x_dot, (fe0, fe1, fe2, te0, te1, te2), touch


@kernel(inline="always")
def truth_at(pp, x, dist):
    """What acts on the state ``x`` with its rotor forces and the disturbances ``dist``, as the NumPy loop's
    truth (``sim.loop._BuiltinPlant.truth``): the body origin's acceleration (world),
    ``w_dot`` (body) and the external wrench ``[f_ext_W, tau_ext_B]`` (:func:`body_derivative`)."""
    if pp.n_rotors == 4:  # a literal count lets the compiler unroll the quadrotor's sums
        u, tm0, tm1, tm2 = _rotor_sums(pp, x.f_rotor, 4)
    else:
        u, tm0, tm1, tm2 = _rotor_sums(pp, x.f_rotor, pp.n_rotors)
    return truth_of(lane_of(pp), _body_of(x), u, tm0, tm1, tm2, dist, True)


@kernel(inline="always")
def truth_of(pl, s, u, tm0, tm1, tm2, dist, full):
    """:func:`truth_at` of the plant ``pl`` (a :data:`PlantLane`) in the body states ``s`` with the rotors'
    thrust ``u`` and moments ``tm`` (the true ``E f``): pure, for one vehicle or a lane. ``full``: as
    :func:`body_derivative`."""
    s_dot, env, _ = body_derivative(pl, s, u, tm0, tm1, tm2, dist, full, True)
    w_dot = (s_dot[10], s_dot[11], s_dot[12])
    R = _R_of((s[6], s[7], s[8], s[9]))
    return origin_acceleration(pl.c_B, s, (s_dot[3], s_dot[4], s_dot[5]), w_dot, R), w_dot, env


@kernel()
def lowest_contact_depth(pp, x):
    """Depth below ground of the lower contact point, as :func:`vtol_impedance.sim.plant.lowest_contact_depth`."""
    return lowest_depth(pp.c_B, pp.r_contact_B, x.p_com_W[2], _R_of(x.q_WB))


@kernel(inline="always")
def lowest_depth(c, r, z, R):
    """:func:`lowest_contact_depth` with the CoM at ``c`` and the second contact at ``r`` (body), the CoM's
    depth ``z`` and the attitude ``R``."""
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
def _axpy(s, h, k):
    """``s + h k`` over the 19 body states."""
    return (s[0] + h * k[0], s[1] + h * k[1], s[2] + h * k[2], s[3] + h * k[3], s[4] + h * k[4],
            s[5] + h * k[5], s[6] + h * k[6], s[7] + h * k[7], s[8] + h * k[8], s[9] + h * k[9],
            s[10] + h * k[10], s[11] + h * k[11], s[12] + h * k[12], s[13] + h * k[13], s[14] + h * k[14],
            s[15] + h * k[15], s[16] + h * k[16], s[17] + h * k[17], s[18] + h * k[18])  # fmt: skip


@kernel(inline="always")
def _rk4_sum(s, h, k1, k2, k3, k4):
    """``s + h (k1 + 2 k2 + 2 k3 + k4)`` over the 19 body states."""
    return _axpy(s, h, _axpy(_axpy(_axpy(k1, 2.0, k2), 2.0, k3), 1.0, k4))


@kernel(inline="always")
def _rotor_stages(pp, f, f_cmd, dt, n):
    """The rotors' RK4 step in place on ``f``, returning ``E f`` (thrust, body moments) at the four stages.

    The rotor lag does not depend on the body's state, so its four stages are computed first, exactly as
    the joint RK4 would, and only their sums enter the body's stages."""
    E = pp.E
    u1 = x1 = y1 = z1 = u2 = x2 = y2 = z2 = u3 = x3 = y3 = z3 = u4 = x4 = y4 = z4 = 0.0
    for i in range(n):
        f1 = f[i]
        g = clip_command(f_cmd[i], pp.f_min[i], pp.f_max[i])
        f[i], f2, f3, f4 = rotor_rk4(pp.inv_tau_up, pp.inv_tau_down, g, f1, dt)
        e0, e1, e2, e3 = E[0, i], E[1, i], E[2, i], E[3, i]
        u1 += e0 * f1
        x1 += e1 * f1
        y1 += e2 * f1
        z1 += e3 * f1
        u2 += e0 * f2
        x2 += e1 * f2
        y2 += e2 * f2
        z2 += e3 * f2
        u3 += e0 * f3
        x3 += e1 * f3
        y3 += e2 * f3
        z3 += e3 * f3
        u4 += e0 * f4
        x4 += e1 * f4
        y4 += e2 * f4
        z4 += e3 * f4
    return (u1, x1, y1, z1), (u2, x2, y2, z2), (u3, x3, y3, z3), (u4, x4, y4, z4)


#: How far from 1 the squared norm of an RK4 step's quaternion may be for :func:`inv_norm_near` (exact to
#: rounding there). A step of ``dt`` at the body rate ``w`` from a unit quaternion leaves it ``h^6 / 72`` below
#: 1, ``h = |w| dt / 2`` (RK4's amplification on a rotation): 1.6e-13 at 30 rad/s and 2.1e-4 at 1,000 rad/s
#: with ``dt = 1 ms``; past about 1,300 rad/s (or a NaN) a step takes the square root.
QUAT_NEAR = 1e-3


@kernel(inline="always")
def inv_norm_near(x):
    """``1 / sqrt(x)`` for ``|x - 1| <= QUAT_NEAR``, in products and sums only: Newton's iteration for the inverse
    square root, twice, from the tangent ``1.5 - x / 2`` (relative errors ``3/8 (x - 1)^2 <= 3.8e-7``, then
    ``2.1e-13``, then below ``1e-25``: the rounding's alone). A packed square root and division cost the lanes
    about 36 cycles per 8 vehicles, at the end of each step's chain of dependences."""
    y = 1.5 - 0.5 * x
    y = y * (1.5 - 0.5 * x * y * y)
    return y * (1.5 - 0.5 * x * y * y)


@kernel(inline="always")
def inv_norm(x):
    """``1 / sqrt(x)``: :func:`inv_norm_near` where it holds, else the square root (a NaN stays NaN)."""
    return inv_norm_near(x) if abs(x - 1.0) <= QUAT_NEAR else 1.0 / math.sqrt(x)


@kernel(inline="always")
def quat_norm2(s):
    """``|q|^2`` of the body states ``s`` (the tuple of :func:`_body_of`)."""
    return s[6] * s[6] + s[7] * s[7] + s[8] * s[8] + s[9] * s[9]


@kernel(inline="always")
def unit_quaternion(s, inq):
    """The body states ``s`` with the quaternion scaled by ``inq`` (:func:`inv_norm` of :func:`quat_norm2`)."""
    return s[:6] + (s[6] * inq, s[7] * inq, s[8] * inq, s[9] * inq) + s[10:]


@kernel(inline="always")
def body_rk4(pl, s, a, b, c, d, dist, dt, full, contact):
    """One RK4 step of the body's 19 states ``s`` (the tuple of :func:`_body_of`) of the plant ``pl``
    (:data:`PlantLane`), with the rotors' ``E f`` at the four stages ``a``, ``b``, ``c``, ``d``
    (:func:`_rotor_stages`) and the disturbances ``dist`` held: the new states with the pendulum put back on
    its sphere, as :func:`vtol_impedance.sim.plant.rk4_step`, and the quaternion as RK4 leaves it, which the
    caller renormalises (RK4 keeps its norm to the method's order only: :func:`unit_quaternion` with
    :func:`inv_norm`; a block in lanes checks the whole block's norms first, :func:`~.lanes.step_lanes`);
    and at how many of the four stages the ground acted, or would have (``touch``, 0 to 4). Pure: one
    vehicle's step or one lane's, alike. ``full`` and ``contact``: as :func:`body_derivative`; ``full`` false
    also leaves the pendulum's six states as they are, for a plant without one whose link does not move
    (``pend_m = 0``, ``v_pend_W = 0``, :func:`~.lanes.block_is_plain`): its derivative is then exactly zero,
    so RK4 would leave them so (``r + h (0 + 2 0 + 2 0 + 0)``), and the lanes skip its arithmetic."""
    h2 = 0.5 * dt
    k1, _, t1 = body_derivative(pl, s, a[0], a[1], a[2], a[3], dist, full, contact)
    k2, _, t2 = body_derivative(pl, _axpy(s, h2, k1), b[0], b[1], b[2], b[3], dist, full, contact)
    k3, _, t3 = body_derivative(pl, _axpy(s, h2, k2), c[0], c[1], c[2], c[3], dist, full, contact)
    k4, _, t4 = body_derivative(pl, _axpy(s, dt, k3), d[0], d[1], d[2], d[3], dist, full, contact)
    n = _rk4_sum(s, dt / 6.0, k1, k2, k3, k4)
    r0, r1, r2, v0, v1, v2 = n[13], n[14], n[15], n[16], n[17], n[18]
    if not full:  # the pendulum's states as they were, without RK4's arithmetic (exact: see the docstring)
        r0, r1, r2, v0, v1, v2 = s[13], s[14], s[15], s[16], s[17], s[18]
    if full and pl.pend_m > 0.0:  # back on the sphere, as sim.plant.project_pendulum
        L = max(math.sqrt(r0**2 + r1**2 + r2**2), 1e-9)
        n0, n1, n2 = r0 / L, r1 / L, r2 / L
        vr = v0 * n0 + v1 * n1 + v2 * n2
        r0, r1, r2 = pl.pend_L * n0, pl.pend_L * n1, pl.pend_L * n2
        v0, v1, v2 = v0 - vr * n0, v1 - vr * n1, v2 - vr * n2
    return (n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7], n[8], n[9], n[10], n[11], n[12], r0, r1, r2, v0, v1,
            v2), t1 + t2 + t3 + t4  # fmt: skip


@kernel()
def rk4_step(pp, x, f_cmd, dist, dt):
    """One RK4 step of ``x`` in place with the rotor command and the disturbances ``dist`` held over the step:
    the rotors (:func:`_rotor_stages`), then the body (:func:`body_rk4`), whose 19 states stay in registers
    through the four stages (tuples, no memory written between them)."""
    if pp.n_rotors == 4:  # a literal count lets the compiler unroll the quadrotor's rotors
        a, b, c, d = _rotor_stages(pp, x.f_rotor, f_cmd, dt, 4)
    else:
        a, b, c, d = _rotor_stages(pp, x.f_rotor, f_cmd, dt, pp.n_rotors)
    s, _ = body_rk4(lane_of(pp), _body_of(x), a, b, c, d, dist, dt, True, True)
    _set_body(x, unit_quaternion(s, inv_norm(quat_norm2(s))))


@kernel(inline="always")
def origin_acceleration(c, s, a_com, wd, R):
    """The body origin's acceleration (world) from the CoM's ``a_com`` (world) and ``wd = w_dot`` (body), the
    body states ``s`` and the CoM ``c`` (body): ``a_com - R (w_dot x c + w x (w x c))``."""
    w0, w1, w2 = s[10], s[11], s[12]
    a0, a1, a2 = wd[0], wd[1], wd[2]
    u0, u1, u2 = w1 * c[2] - w2 * c[1], w2 * c[0] - w0 * c[2], w0 * c[1] - w1 * c[0]
    s0 = (a1 * c[2] - a2 * c[1]) + (w1 * u2 - w2 * u1)
    s1 = (a2 * c[0] - a0 * c[2]) + (w2 * u0 - w0 * u2)
    s2 = (a0 * c[1] - a1 * c[0]) + (w0 * u1 - w1 * u0)
    return (
        a_com[0] - (R[0] * s0 + R[1] * s1 + R[2] * s2),
        a_com[1] - (R[3] * s0 + R[4] * s1 + R[5] * s2),
        a_com[2] - (R[6] * s0 + R[7] * s1 + R[8] * s2),
    )


@kernel(inline="always")
def lumped(a_o, omega, w_dot, R, eta, u_prev, tau_prev, m_nom, I_nom):
    """What the nominal model (mass ``m_nom``, inertia ``I_nom`` as a 9-tuple) misses, as
    :func:`vtol_impedance.sim.loop._lumped_wrench`: ``(f (world), tau_eta (Euler coordinates))``, from the body
    origin's acceleration ``a_o`` (world), the body rate ``omega`` and ``w_dot`` (body), whichever plant computed
    them, and the command ``u_prev``, ``tau_prev`` held over the last period. Pure: tuples in and out."""
    f0 = m_nom * a_o[0] + u_prev * R[2]  # eq. (5a) solved for f_ext
    f1 = m_nom * a_o[1] + u_prev * R[5]
    f2 = m_nom * (a_o[2] - G) + u_prev * R[8]
    Q = _Q9(eta[0], eta[1], True)
    d0, d1, d2 = _solve9(Q, omega[0], omega[1], omega[2])
    qd = _mv9(_Qd9(eta[0], eta[1], d0, d1, True), d0, d1, d2)
    dd0, dd1, dd2 = _solve9(Q, w_dot[0] - qd[0], w_dot[1] - qd[1], w_dot[2] - qd[2])
    _, M, C = _QMC(eta[0], eta[1], d0, d1, d2, I_nom, True)
    me = _mv9(M, dd0, dd1, dd2)
    ce = _mv9(C, d0, d1, d2)
    qt = _mv9(_t9(Q), tau_prev[0], tau_prev[1], tau_prev[2])
    return (f0, f1, f2), (me[0] + ce[0] - qt[0], me[1] + ce[1] - qt[1], me[2] + ce[2] - qt[2])  # eq. (5b)


@kernel(inline="always")
def observed(c, s, a_o, w_dot, u_prev, tau_prev, m_nom, I_nom):
    """What the metrics and the log take of the truth at a control tick, from the body states ``s`` (CoM at
    ``c``, body) and the truth ``a_o``, ``w_dot`` (:func:`truth_of`): the Euler angles, the lumped wrench
    (:func:`lumped`) and the body origin's position and velocity (world). Pure, for one vehicle or a lane."""
    R = _R_of((s[6], s[7], s[8], s[9]))
    eta = euler_of(R, True)  # in lanes: the functions LLVM vectorises
    f_l, t_l = lumped(a_o, (s[10], s[11], s[12]), w_dot, R, eta, u_prev, tau_prev, m_nom, I_nom)
    po = origin_of(c, (s[0], s[1], s[2]), (s[3], s[4], s[5]), (s[10], s[11], s[12]), R)
    return eta, f_l, t_l, (po[0], po[1], po[2]), (po[3], po[4], po[5])


@kernel(inline="always")
def failure_of(pl, s, rotors):
    """Why a vehicle must stop (0: it flies on), as :func:`vtol_impedance.sim.loop.check_vehicles`, from its plant
    ``pl`` (a :data:`PlantLane`), body states ``s`` and the sum of its rotor forces ``rotors`` (only its
    finiteness counts). Pure and free of branches (a float code), for one vehicle or a lane."""
    total = (rotors + s[0] + s[1] + s[2] + s[3] + s[4] + s[5] + s[6] + s[7] + s[8] + s[9] + s[10] + s[11] + s[12]
             + s[13] + s[14] + s[15] + s[16] + s[17] + s[18])  # fmt: skip
    R = _R_of((s[6], s[7], s[8], s[9]))
    crash = (pl.ground > 0.0) & (lowest_depth(pl.c_B, pl.r_contact_B, s[2], R) > CRASH_DEPTH_M)
    code = float(FAIL_CRASH) if crash else 0.0
    code = float(FAIL_FAR) if math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) > MAX_DISTANCE_M else code
    code = float(FAIL_TILT) if R[8] < _COS_TILT_MAX else code
    return code if total - total == 0.0 else float(FAIL_NAN)  # an infinity or NaN anywhere: NaN
