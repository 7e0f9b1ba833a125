"""Rigid-body dynamics in Euler coordinates, eqs. (3), (5)-(8) of Ruggiero et al. (2014).

Shapes: ``eta``, ``eta_dot``, ``v_W``: ``(..., 3)``; ``I_B``: ``(..., 3, 3)``; ``mass``, ``thrust``: ``(...)``.

Frames: ``tau_B`` is a moment in the body frame; a *generalized* moment in Euler-angle
coordinates, such as ``tau_ext`` of eq. (5b), is named ``*_eta``. They are related by
``tau_eta = Q(eta)^T tau_B`` and ``tau_B = Q(eta)^{-T} tau_eta``.
"""

from __future__ import annotations

import numpy as np

from ..conventions import E3, GRAVITY_W
from ..errors import batched
from .kinematics import (
    check_euler_regular,
    euler_rate_matrix_Q,
    euler_rate_matrix_Q_dot,
    rotation_zyx,
    skew,
)


def matvec(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Batched ``A @ x`` for ``A (..., n, m)`` and ``x (..., m)``."""
    return np.einsum("...ij,...j->...i", A, x)


def transpose(A: np.ndarray) -> np.ndarray:
    """Swap the last two axes."""
    return np.swapaxes(A, -1, -2)


def inertia_matrix_M(eta: np.ndarray, I_B: np.ndarray) -> np.ndarray:
    """``M(eta) = Q^T I_B Q``, eq. (3b); symmetric positive definite away from theta = +-pi/2."""
    I_B = batched("I_B", I_B, (3, 3))
    Q = euler_rate_matrix_Q(eta)
    return transpose(Q) @ I_B @ Q  # eq. (3b)


def coriolis_matrix_C(eta: np.ndarray, eta_dot: np.ndarray, I_B: np.ndarray) -> np.ndarray:
    """Coriolis matrix of eq. (3b) chosen so that property (7), ``M_dot = C + C^T``, holds.

    ``C(eta, eta_dot) = Q^T S(I_B Q eta_dot)^T Q + Q^T I_B Q_dot``.

    The paper prints ``C = Q^T S(Q eta_dot) I_B Q + Q^T I_B Q_dot``. Both give the same vector
    ``C eta_dot`` (since ``w x I w = -(I w) x w``), so the model (3b) and the torque (14) are unchanged,
    but the printed factorisation violates (7) for a non-spherical inertia (``C + C^T - M_dot =
    Q^T (S(w) I - I S(w)) Q``). The estimator (8), (11) uses ``C^T eta_dot`` and (18b) uses
    ``C e_eta_dot``, both of which need (7); with the printed ``C`` the estimator would report a
    spurious moment whenever the vehicle rotates. ``tests/test_model.py`` checks (7) numerically.
    """
    I_B = batched("I_B", I_B, (3, 3))
    Q = euler_rate_matrix_Q(eta)
    Qd = euler_rate_matrix_Q_dot(eta, eta_dot)
    eta_dot = batched("eta_dot", eta_dot, (3,))
    QT = transpose(Q)
    h_B = matvec(I_B, matvec(Q, eta_dot))  # body angular momentum
    return QT @ transpose(skew(h_B)) @ Q + QT @ I_B @ Qd  # C of eq. (3b), satisfying (7)


def generalized_momentum(
    v_W: np.ndarray, eta: np.ndarray, eta_dot: np.ndarray, mass: np.ndarray, I_B: np.ndarray
) -> np.ndarray:
    """``q = [m p_dot; M(eta) eta_dot]``, eq. (6); returns ``(..., 6)``."""
    lin = batched("mass", mass)[..., None] * batched("v_W", v_W, (3,))
    ang = matvec(inertia_matrix_M(eta, I_B), batched("eta_dot", eta_dot, (3,)))
    return np.concatenate([lin, ang], -1)  # eq. (6)


def momentum_rate_known(
    eta: np.ndarray,
    eta_dot: np.ndarray,
    thrust: np.ndarray,
    tau_B: np.ndarray,
    mass: np.ndarray,
    I_B: np.ndarray,
) -> np.ndarray:
    """The known part ``beta`` of the momentum rate, eq. (8) without the external wrench.

    ``beta = [-u R(eta) e3 + m g_W;  Q^T tau_B + C^T eta_dot]``, so that ``q_dot = beta + [f_ext_W; tau_ext_eta]``.
    """
    tau_B = batched("tau_B", tau_B, (3,))
    return np.concatenate(  # eq. (8)
        [momentum_rate_linear(eta, thrust, mass), momentum_rate_angular(eta, eta_dot, tau_B, I_B)], -1
    )


def momentum_rate_linear(eta: np.ndarray, thrust: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """The linear part of ``beta`` in eq. (8): ``-u R(eta) e3 + m g_W`` (world NED, N)."""
    R = rotation_zyx(eta)
    # eq. (8), linear part
    return -batched("thrust", thrust)[..., None] * R[..., :, 2] + batched("mass", mass)[..., None] * GRAVITY_W


def momentum_rate_angular(eta: np.ndarray, eta_dot: np.ndarray, tau_B: np.ndarray, I_B: np.ndarray) -> np.ndarray:
    """The angular part of ``beta`` in eq. (8): ``Q^T tau_B + C^T eta_dot`` (Euler coordinates, N m)."""
    Q = euler_rate_matrix_Q(eta)
    C = coriolis_matrix_C(eta, eta_dot, I_B)
    return matvec(transpose(Q), tau_B) + matvec(transpose(C), eta_dot)  # eq. (8), angular part


def euler_moment_from_body(tau_B: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Generalized moment in Euler coordinates ``tau_eta = Q(eta)^T tau_B``."""
    return matvec(transpose(euler_rate_matrix_Q(eta)), batched("tau_B", tau_B, (3,)))


def body_moment_from_euler(tau_eta: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Body-frame moment ``tau_B = Q(eta)^{-T} tau_eta`` (eq. (5b) read in the body frame).

    Raises :class:`~vtol_impedance.errors.SingularityError` at theta = +-pi/2, where ``Q`` has no inverse (a
    solve there returned moments of 1e16 N m instead of an error).
    """
    tau_eta = batched("tau_eta", tau_eta, (3,))
    eta = batched("eta", eta, (3,))
    check_euler_regular(eta)
    QT = transpose(euler_rate_matrix_Q(eta))
    return np.linalg.solve(QT, tau_eta[..., None])[..., 0]


def thrust_direction_W(eta: np.ndarray) -> np.ndarray:
    """``R(eta) e3``: the body z axis in the world frame; thrust pushes along its negative."""
    return matvec(rotation_zyx(eta), np.broadcast_to(E3, np.shape(eta)))
