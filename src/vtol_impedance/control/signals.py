"""The controller's inputs and outputs."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Measurement(NamedTuple):
    """What the controller and estimator receive, each ``(..., 3)``.

    ``p_W``, ``v_W``: position and velocity of the body origin in the world NED frame (motion capture);
    ``eta``: ZYX Euler angles; ``eta_dot``: Euler-angle rates (from the gyro via ``Q^{-1} omega_B``).
    """

    p_W: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    eta_dot: np.ndarray


class Reference(NamedTuple):
    """Desired flat outputs: position, velocity, acceleration ``(..., 3)`` in W, and yaw with two derivatives."""

    p_W: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    psi: np.ndarray
    psi_dot: np.ndarray
    psi_ddot: np.ndarray


class ControlOutput(NamedTuple):
    """Everything one controller step produces.

    ``thrust_request``/``tau_B_request`` come from eqs. (16)-(20) and (14); ``thrust``/``tau_B`` are what
    the allocated rotor forces ``f_rotor`` produce (they differ when ``saturated``). The wrench estimate is
    ``f_hat_W`` (world frame, N), ``tau_hat_eta`` (Euler coordinates, as in eq. (5b)) and ``tau_hat_B``
    (the same moment in the body frame, ``Q^{-T} tau_hat_eta``).
    """

    thrust: np.ndarray
    tau_B: np.ndarray
    f_rotor: np.ndarray
    saturated: np.ndarray
    thrust_request: np.ndarray
    tau_B_request: np.ndarray
    f_hat_W: np.ndarray
    tau_hat_eta: np.ndarray
    tau_hat_B: np.ndarray
    eta_d: np.ndarray
    eta_d_dot: np.ndarray
    mu_bar: np.ndarray
    tilt_limited: np.ndarray
