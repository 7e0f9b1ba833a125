"""The controller's inputs and outputs."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import batched

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


class _MeasurementFields(NamedTuple):
    p_W: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    eta_dot: np.ndarray | None = None
    omega_B: np.ndarray | None = None


class Measurement(_MeasurementFields):
    """What the controller and estimator receive, each ``(..., 3)``.

    ``p_W``, ``v_W``: position (m) and velocity (m/s) of the body origin in the world NED frame (motion
    capture); ``eta``: ZYX Euler angles ``[phi, theta, psi]`` (rad); and the attitude rate as *either*
    ``eta_dot`` (Euler-angle rates, rad/s) *or* ``omega_B`` (the gyro's body rates, FRD, rad/s), from which
    :class:`~vtol_impedance.Controller` computes ``eta_dot = Q(eta)^{-1} omega_B`` (eq. (1c)).
    The pure :func:`~vtol_impedance.control.controller_step` needs ``eta_dot``. Built with real numbers of
    these shapes, or refused with an :class:`~vtol_impedance.errors.InputError` naming the field.
    """

    __slots__ = ()

    def __new__(
        cls,
        p_W: np.ndarray,
        v_W: np.ndarray,
        eta: np.ndarray,
        eta_dot: np.ndarray | None = None,
        omega_B: np.ndarray | None = None,
    ) -> Measurement:
        return tuple.__new__(
            cls,
            (
                batched("p_W", p_W, (3,)),
                batched("v_W", v_W, (3,)),
                batched("eta", eta, (3,)),
                None if eta_dot is None else batched("eta_dot", eta_dot, (3,)),
                None if omega_B is None else batched("omega_B", omega_B, (3,)),
            ),
        )

    @classmethod
    def from_frames(
        cls,
        p: np.ndarray,
        v: np.ndarray,
        q: np.ndarray,
        omega: np.ndarray,
        *,
        world: str,
        body: str,
        quat_order: str,
        quat_direction: str = "body-to-world",
    ) -> Measurement:
        """The measurement from another tool's conventions: position ``p`` (m) and velocity ``v`` (m/s) of
        the body origin in ``world`` (``"ned"``, or ``"enu"``: ROS, Gazebo, MuJoCo, most simulators), the
        attitude as a unit quaternion ``q`` (``quat_order`` ``"wxyz"``, or ``"xyzw"``: SciPy, ROS;
        ``quat_direction`` ``"body-to-world"`` or ``"world-to-body"``) and the gyro's body rates ``omega``
        (rad/s) in ``body`` (``"frd"``, or ``"flu"``). Returns world NED, ZYX Euler angles of the NED/FRD
        attitude and ``omega_B`` in FRD (:mod:`vtol_impedance.model.frames`). Batches: ``(..., 3)`` and
        ``(..., 4)``. ``world``, ``body`` and ``quat_order`` have no default: they are what this method is for,
        and a guessed one (a SciPy quaternion taken as scalar-first) is still a unit quaternion, wrong."""
        from ..errors import as_finite
        from ..model.frames import body_vector_to_frd, eta_ned_frd, quaternion_rotation, world_vector_to_ned

        R = quaternion_rotation(as_finite("q (quaternion)", q, (4,)), quat_order, quat_direction)
        return cls(
            world_vector_to_ned(as_finite("p (position)", p, (3,)), world),
            world_vector_to_ned(as_finite("v (velocity)", v, (3,)), world),
            eta_ned_frd(R, world, body),
            omega_B=body_vector_to_frd(as_finite("omega (body rates)", omega, (3,)), body),
        )


def comply6(comply: np.ndarray | float) -> np.ndarray:
    """Comply fractions ``(..., 6)`` for ``[x, y, z, roll, pitch, yaw]`` from 1, 3 (the world axes; the
    attitude rejects) or 6 values."""
    c = np.asarray(comply, dtype=float)
    if c.shape[-1:] == (6,):
        return c
    if c.shape[-1:] != (3,):
        c = np.broadcast_to(c[..., None], c.shape + (3,))  # one fraction: the world axes
    return np.concatenate([c, np.zeros_like(c)], -1)


class _ReferenceFields(NamedTuple):
    p_W: np.ndarray
    v_W: np.ndarray = _ZERO3
    a_W: np.ndarray = _ZERO3
    psi: np.ndarray | float = 0.0
    psi_dot: np.ndarray | float = 0.0
    psi_ddot: np.ndarray | float = 0.0
    comply: np.ndarray | float = 0.0


class Reference(_ReferenceFields):
    """Desired flat outputs: position ``p_W`` (m), velocity ``v_W`` (m/s), acceleration ``a_W`` (m/s^2), each
    ``(..., 3)`` in the world NED frame, and yaw ``psi`` (rad) with two derivatives.

    ``comply`` (0..1 per world axis ``[x, y, z]``, or per world axis and Euler angle ``[x, y, z, roll,
    pitch, yaw]``; with three the attitude rejects) chooses the interaction behaviour of a controller
    built with ``variant="comply"``: 0 rejects the external force or moment (PD+C, stiff), 1 yields to
    it with the set impedance (``M_d, D_d, K_d``; ``M_o, D_o, K_o``), values in between blend the two. The
    controller takes the fractions as given, tick by tick: a caller that switches should ramp through the
    values in between, as the scenarios' trajectories do (``blend_s``), since a step from 0 to 1 steps the
    commands. Other variants ignore it.

    Everything but ``p_W`` defaults to zero, so ``Reference(np.array([0, 0, -1.0]))`` holds a point 1 m up
    with the nose north. Built with real numbers of these shapes, or refused with an
    :class:`~vtol_impedance.errors.InputError` naming the field.
    """

    __slots__ = ()

    def __new__(
        cls,
        p_W: np.ndarray,
        v_W: np.ndarray = _ZERO3,
        a_W: np.ndarray = _ZERO3,
        psi: np.ndarray | float = 0.0,
        psi_dot: np.ndarray | float = 0.0,
        psi_ddot: np.ndarray | float = 0.0,
        comply: np.ndarray | float = 0.0,
    ) -> Reference:
        return tuple.__new__(
            cls,
            (
                batched("p_W", p_W, (3,)),
                batched("v_W", v_W, (3,)),
                batched("a_W", a_W, (3,)),
                batched("psi", psi),
                batched("psi_dot", psi_dot),
                batched("psi_ddot", psi_ddot),
                batched("comply", comply),
            ),
        )

    @classmethod
    def from_frames(
        cls,
        p: np.ndarray,
        v: np.ndarray = _ZERO3,
        a: np.ndarray = _ZERO3,
        heading: np.ndarray | float = 0.0,
        heading_rate: np.ndarray | float = 0.0,
        heading_acc: np.ndarray | float = 0.0,
        comply: np.ndarray | float = 0.0,
        *,
        world: str,
    ) -> Reference:
        """The reference from another tool's world frame: position, velocity and acceleration in ``world``
        (``"ned"`` or ``"enu"``) and the heading with its rate and acceleration in that world's convention
        (ENU: counter-clockwise from east, so the default 0 is nose east; NED: clockwise from north).
        ``comply`` gives the world axes in ``world``'s order too (ENU ``[east, north, up]``, reordered
        here to NED's ``[north, east, down]``); its Euler-angle fractions (six values) are not reordered.
        ``world`` has no default: it is what this method is for."""
        from ..errors import as_finite
        from ..model.frames import heading_rate_to_ned, heading_to_ned, world_axes_to_ned, world_vector_to_ned

        try:
            c = np.array(comply, dtype=float)
        except (TypeError, ValueError):
            c = None  # not numbers: the controller's step names the value
        if c is not None and c.shape[-1:] in ((3,), (6,)):  # per axis: the world axes reordered
            c[..., :3] = world_axes_to_ned(c[..., :3], world)
        else:
            c = comply
        return cls(
            *(world_vector_to_ned(as_finite(n, x, (3,)), world) for n, x in (("p", p), ("v", v), ("a", a))),
            heading_to_ned(as_finite("heading", heading), world),
            heading_rate_to_ned(as_finite("heading_rate", heading_rate), world),
            heading_rate_to_ned(as_finite("heading_acc", heading_acc), world),
            c,
        )


class ControlOutput(NamedTuple):
    """Everything one controller step produces.

    ``thrust_request``/``tau_B_request`` come from eqs. (16)-(20) and (14); ``thrust``/``tau_B`` are what
    the allocated rotor forces ``f_rotor`` produce (they differ when ``saturated``). The wrench estimate is
    ``f_hat_W`` (world frame, N), ``tau_hat_eta`` (Euler coordinates, as in eq. (5b)) and ``tau_hat_B``
    (the same moment in the body frame, ``Q^{-T} tau_hat_eta``). What the limits took: ``tilt_limited``
    (the tilt or lift bound of eq. (16) acted), ``rp_scale`` and ``yaw_scale`` (the share of the roll/pitch
    and yaw torque the rotors could give, 1 when all of it). For one vehicle ``thrust`` and the flags are
    plain Python numbers and the vectors ``(3,)`` arrays.
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
    rp_scale: np.ndarray
    yaw_scale: np.ndarray
