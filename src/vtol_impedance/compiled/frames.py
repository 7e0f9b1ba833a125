"""Compiled conversion of another simulator's rigid-body state into this package's plant state.

MuJoCo (:mod:`vtol_impedance.sim.mjplant`) gives the body origin's position and velocity in the world
ENU frame, the attitude as a quaternion ENU/FLU and the body rate in FLU; the plant state
(:data:`~.layouts.STATE`) is the centre of mass in NED, the quaternion NED/FRD and the rate in FRD. The
conversion runs for every vehicle and every state a sensor reads in each control period, where NumPy's
per-call overhead would cost more than the physics it converts; ``tests/test_mujoco.py`` ties it to the
written-out NumPy conversion of ``MujocoPlant._convert``.
"""

from __future__ import annotations

import math

from .jit import kernel
from .plant import _R_of


@kernel()
def states_from_enu_flu(qpos, qvel, act, veh, c_B, f_min, f_max, ctrl, lag, n, X):
    """Row ``i`` of ``qpos (R, >=7)``, ``qvel (R, >=6)``, ``act (R, >=n)`` (vehicle ``veh[i]``) into the
    state record ``X[i]``; the pendulum is left at rest (the caller sets it where there is one).

    ``q_WB = q(T_NED_ENU) q_ENU_FLU q(T_FRD_FLU)``: the two frame changes are half-turns about
    ``(1, 1, 0)/sqrt(2)`` and ``x``, which written out give ``(w + z, x + y, x - y, w - z)/sqrt(2)``,
    renormalised here, with the sign that makes ``w >= 0`` (the same rotation). The centre of mass is
    ``c_B`` (body) from the origin. A rotor follows its command at once (``ctrl`` clipped to
    ``[f_min, f_max]``) unless it lags (``lag``), when MuJoCo's activation ``act`` is its force."""
    for i in range(X.shape[0]):
        b = veh[i]
        x = X[i]
        w, a, bb, c = qpos[i, 3], qpos[i, 4], qpos[i, 5], qpos[i, 6]
        q0, q1, q2, q3 = w + c, a + bb, a - bb, w - c
        s = math.copysign(1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3), q0)
        q = x.q_WB
        q[0], q[1], q[2], q[3] = q0 * s, q1 * s, q2 * s, q3 * s
        R = _R_of(q)
        cb = c_B[b]
        w0, w1, w2 = qvel[i, 3], -qvel[i, 4], -qvel[i, 5]  # T_FRD_FLU
        x.omega_B[0], x.omega_B[1], x.omega_B[2] = w0, w1, w2
        u0, u1, u2 = w1 * cb[2] - w2 * cb[1], w2 * cb[0] - w0 * cb[2], w0 * cb[1] - w1 * cb[0]  # omega x c
        p = (qpos[i, 1], qpos[i, 0], -qpos[i, 2])  # T_NED_ENU: a swap and a sign
        v = (qvel[i, 1], qvel[i, 0], -qvel[i, 2])
        for k in range(3):
            x.p_com_W[k] = p[k] + R[3 * k] * cb[0] + R[3 * k + 1] * cb[1] + R[3 * k + 2] * cb[2]
            x.v_com_W[k] = v[k] + R[3 * k] * u0 + R[3 * k + 1] * u1 + R[3 * k + 2] * u2
            x.r_pend_W[k] = 0.0
            x.v_pend_W[k] = 0.0
        for j in range(n):
            x.f_rotor[j] = act[i, j] if lag[b] else min(max(ctrl[b, j], f_min[b, j]), f_max[b, j])
