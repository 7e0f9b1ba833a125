"""The plant of a block of vehicles in SIMD lanes: structure-of-arrays, one lane per vehicle.

:func:`vtol_impedance.compiled.engine.run_block_lanes` flies a batch a block of :data:`W` vehicles at a time.
Between two control ticks each block takes ``n_sub`` RK4 steps of its plants (the bulk of a batch's work),
and those run here over a buffer ``buf`` of :data:`ROWS` rows of :data:`W` doubles: one row per named
quantity (a plant parameter, a state, a rotor's command, a stage's thrust), one column per vehicle. The
loops over the lanes are innermost and free of calls, memory-dependent branches and transcendental functions,
so LLVM turns them into packed vector instructions (``tests/test_lanes.py`` reads the machine code for them).
:data:`W` is a compile-time constant: the rows of one buffer then sit at constant distances, which is what
lets the vectoriser prove that no lane's store reaches another lane's load without run-time checks.

The arithmetic is that of :mod:`.plant`, not a copy of it: every lane calls :func:`~.plant.rotor_rk4` and
:func:`~.plant.body_rk4` with a :data:`~.plant.PlantLane` read from the rows, as one vehicle's
:func:`~.plant.rk4_step` does with its record.

Rows (each :data:`W` wide): the :data:`~.plant.PlantLane` (:data:`N_LANE` rows), the body's 19 states,
then per rotor (:data:`~vtol_impedance.model.vehicle.MAX_ROTORS` rows each) its force, command, lower and upper
limit, the true effectiveness ``E`` (four rows per rotor), the held disturbance ``[f_W, tau_B]`` (6) and
the four stages' ``E f`` (16), the controller's nominal mass and inertia and the command it held over the last
period (14), what a tick observes of the truth (21, :func:`observe_lanes`) and each lane's failure code. A
vehicle with fewer rotors has zero rows for the others (zero force, limits and effect), which add exact zeros
to the sums.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..model.vehicle import MAX_ROTORS
from .jit import kernel
from .plant import (
    QUAT_NEAR,
    PlantLane,
    body_rk4,
    clip_command,
    failure_of,
    instant_force,
    inv_norm,
    inv_norm_near,
    measured,
    observed,
    plant_is_plain,
    quat_norm2,
    rotor_rk4,
    truth_of,
    unit_quaternion,
)

#: Vehicles per block. 16 doubles are two AVX-512 or four AVX2 registers per row; a block's buffer
#: (:data:`ROWS` x 16 x 8 bytes, 23 kB) stays in a core's L1 cache through its plant steps.
W = 16
assert W == 16  # load_row and store_row are written out for 16 lanes

_R = MAX_ROTORS
N_LANE = 39  # rows of a PlantLane: 1 + 9 + 9 + 3 + 3 + 1 + 1 + 3 + 3 + 6
_PL = 0
_S = _PL + N_LANE  # body states, as plant._body_of
_F = _S + 19  # rotor forces
_FC = _F + _R  # rotor commands
_FMIN = _FC + _R
_FMAX = _FMIN + _R
_E = _FMAX + _R  # E[c, r] at row _E + 4 r + c
_D = _E + 4 * _R  # [f_W, tau_B]
_U = _D + 6  # E f at stage j: rows _U + 4 j .. + 3
_N = _U + 16  # the controller's nominal mass and inertia (10), the command held over the last period (4)
_O = _N + 14  # what the tick observes of the truth (plant.observed): eta, f_l, t_l, p_o, v_o (15), the wrench (6)
_X = _O + 21  # why each lane must stop (plant.failure_of)
_K = _X + 1  # a step's new body states, before step_lanes keeps them (19)
_T = _K + 19  # at how many of the step's stages the ground acted on the lane, or would have (plant.body_rk4)
_Q = _T + 1  # whether the step left the lane's quaternion far from unit norm (plant.inv_norm: 1, else 0)
_C = _Q + 1  # whether the ground acted on a lane in the block's last step (the row's first value)
ROWS = _C + 1

#: The states the disturbances read, as a record's fields (:func:`state_view`).
StateView = namedtuple("StateView", ("p_com_W", "v_com_W", "q_WB", "omega_B"))


@kernel(inline="always")
def aligned_zeros(n):
    """``n`` zeros from a 64-byte boundary. Numba's arrays start at 32 bytes; then half of them put every row of
    :data:`W` doubles across two cache lines, and a 512-bit load or store of a row's half touches both (one
    block's RK4 step measured 1.10 times slower so, the buffers' alignment their only difference)."""
    raw = np.zeros(n + 8)
    k = ((-raw.ctypes.data) % 64) // 8
    return raw[k : k + n]


@kernel()
def new_buffer():
    """A zeroed block buffer (``ROWS * W`` doubles, 64-byte aligned)."""
    return aligned_zeros(ROWS * W)


@kernel(inline="always")
def load_row(a, k):
    """The :data:`W` values of ``a`` from index ``k``, all loaded before anything is stored.

    For rows at a place known only at run time (a ring's slot): there a lane loop stays scalar, as the
    compiler cannot tell the row from the ones the loop writes, and a signed index also takes a wrap-around
    select per lane. An unsigned ``k`` and loads ahead of the stores (:func:`store_row`) are packed moves."""
    u = np.uint64
    k = u(k)
    return (a[k], a[k + u(1)], a[k + u(2)], a[k + u(3)], a[k + u(4)], a[k + u(5)], a[k + u(6)], a[k + u(7)],
            a[k + u(8)], a[k + u(9)], a[k + u(10)], a[k + u(11)], a[k + u(12)], a[k + u(13)], a[k + u(14)],
            a[k + u(15)])  # fmt: skip


@kernel(inline="always")
def store_row(a, k, t):
    """``a`` from index ``k`` takes the :data:`W` values ``t`` (:func:`load_row`)."""
    u = np.uint64
    k = u(k)
    a[k], a[k + u(1)], a[k + u(2)], a[k + u(3)], a[k + u(4)], a[k + u(5)], a[k + u(6)], a[k + u(7)] = t[:8]
    a[k + u(8)], a[k + u(9)], a[k + u(10)], a[k + u(11)], a[k + u(12)], a[k + u(13)], a[k + u(14)] = t[8:15]
    a[k + u(15)] = t[15]


@kernel(inline="always")
def copy_row(dst, at, src, k):
    """Row ``at`` (an index) of ``dst`` takes the :data:`W` values of ``src`` from index ``k``."""
    store_row(dst, at, load_row(src, k))


@kernel(inline="always")
def put_plant(buf, i, pp, pl):
    """Lane ``i`` takes the plant of the record ``pp`` whose :data:`~.plant.PlantLane` is ``pl``."""
    k = _PL * W + i
    buf[k] = pl.inv_mass
    for j in range(9):
        buf[k + (1 + j) * W] = pl.I_com[j]
        buf[k + (10 + j) * W] = pl.I_com_inv[j]
    for j in range(3):
        buf[k + (19 + j) * W] = pl.c_B[j]
        buf[k + (22 + j) * W] = pl.r_contact_B[j]
        buf[k + (27 + j) * W] = pl.lin_drag_B[j]
        buf[k + (30 + j) * W] = pl.quad_drag_B[j]
    buf[k + 25 * W] = pl.inv_tau_up
    buf[k + 26 * W] = pl.inv_tau_down
    buf[k + 33 * W] = pl.ground
    buf[k + 34 * W] = pl.k_ground
    buf[k + 35 * W] = pl.c_ground
    buf[k + 36 * W] = pl.b_ground
    buf[k + 37 * W] = pl.pend_m
    buf[k + 38 * W] = pl.pend_L
    for r in range(_R):
        buf[(_FMIN + r) * W + i] = pp.f_min[r]
        buf[(_FMAX + r) * W + i] = pp.f_max[r]
        for c in range(4):
            buf[(_E + 4 * r + c) * W + i] = pp.E[c, r]


@kernel(inline="always")
def _plant_at(buf, i):
    """The :data:`~.plant.PlantLane` of lane ``i`` (the order of :func:`put_plant`)."""
    k = _PL * W + i

    def at(j):
        return buf[k + j * W]

    return PlantLane(
        at(0),
        (at(1), at(2), at(3), at(4), at(5), at(6), at(7), at(8), at(9)),
        (at(10), at(11), at(12), at(13), at(14), at(15), at(16), at(17), at(18)),
        (at(19), at(20), at(21)),
        (at(22), at(23), at(24)),
        at(25),
        at(26),
        (at(27), at(28), at(29)),
        (at(30), at(31), at(32)),
        at(33), at(34), at(35), at(36), at(37), at(38),
    )  # fmt: skip


@kernel(inline="always")
def _body_at(buf, i):
    """Lane ``i``'s body states (the tuple of :func:`~.plant._body_of`)."""
    return _body_rows(buf, _S, i)


@kernel(inline="always")
def _body_rows(buf, row, i):
    """Lane ``i``'s 19 values from the row ``row`` (the body states, or a step's new ones)."""
    k = row * W + i

    def at(j):
        return buf[k + j * W]

    return (at(0), at(1), at(2), at(3), at(4), at(5), at(6), at(7), at(8), at(9), at(10), at(11), at(12), at(13),
            at(14), at(15), at(16), at(17), at(18))  # fmt: skip


@kernel(inline="always")
def _put_body(buf, row, i, s):
    """Lane ``i``'s 19 values ``s`` into the rows from ``row`` (:func:`_body_rows`)."""
    _put_states(buf, row, i, s, True)


@kernel(inline="always")
def _put_states(buf, row, i, s, full):
    """:func:`_put_body`, or with ``full`` false (a literal) the first 13 values only: the rigid body's, not
    the pendulum's, which a plain block's step leaves as they are (:func:`~.plant.body_rk4`)."""
    k = row * W + i
    buf[k] = s[0]
    buf[k + W] = s[1]
    buf[k + 2 * W] = s[2]
    buf[k + 3 * W] = s[3]
    buf[k + 4 * W] = s[4]
    buf[k + 5 * W] = s[5]
    buf[k + 6 * W] = s[6]
    buf[k + 7 * W] = s[7]
    buf[k + 8 * W] = s[8]
    buf[k + 9 * W] = s[9]
    buf[k + 10 * W] = s[10]
    buf[k + 11 * W] = s[11]
    buf[k + 12 * W] = s[12]
    if full:
        buf[k + 13 * W] = s[13]
        buf[k + 14 * W] = s[14]
        buf[k + 15 * W] = s[15]
        buf[k + 16 * W] = s[16]
        buf[k + 17 * W] = s[17]
        buf[k + 18 * W] = s[18]


@kernel(inline="always")
def put_state(buf, i, x):
    """Lane ``i`` takes the state record ``x`` (:data:`~.layouts.STATE`)."""
    k = _S * W + i
    for j in range(3):
        buf[k + j * W] = x.p_com_W[j]
        buf[k + (3 + j) * W] = x.v_com_W[j]
        buf[k + (10 + j) * W] = x.omega_B[j]
        buf[k + (13 + j) * W] = x.r_pend_W[j]
        buf[k + (16 + j) * W] = x.v_pend_W[j]
    for j in range(4):
        buf[k + (6 + j) * W] = x.q_WB[j]
    put_rotors(buf, i, x)


@kernel(inline="always")
def put_rotors(buf, i, x):
    """Lane ``i``'s rotor forces from the state record ``x``."""
    for r in range(_R):
        buf[(_F + r) * W + i] = x.f_rotor[r]


@kernel(inline="always")
def get_state(buf, i, x):
    """The state record ``x`` takes lane ``i``'s state (the inverse of :func:`put_state`)."""
    k = _S * W + i
    for j in range(3):
        x.p_com_W[j] = buf[k + j * W]
        x.v_com_W[j] = buf[k + (3 + j) * W]
        x.omega_B[j] = buf[k + (10 + j) * W]
        x.r_pend_W[j] = buf[k + (13 + j) * W]
        x.v_pend_W[j] = buf[k + (16 + j) * W]
    for j in range(4):
        x.q_WB[j] = buf[k + (6 + j) * W]
    for r in range(_R):
        x.f_rotor[r] = buf[(_F + r) * W + i]


@kernel(inline="always")
def state_view(buf, i):
    """Lane ``i``'s position, velocity, attitude and rate with a state record's field names, for the
    disturbances (:func:`~.plant.disturbance_at`)."""
    s = _body_at(buf, i)
    return StateView((s[0], s[1], s[2]), (s[3], s[4], s[5]), (s[6], s[7], s[8], s[9]), (s[10], s[11], s[12]))


@kernel(inline="always")
def put_command(buf, i, f_cmd, n):
    """Lane ``i``'s rotor commands (the first ``n``)."""
    for r in range(n):
        buf[(_FC + r) * W + i] = f_cmd[r]


@kernel(inline="always")
def put_command_row(buf, r, i, f):
    """Lane ``i``'s command ``f`` of rotor ``r``."""
    buf[(_FC + r) * W + i] = f


@kernel(inline="always")
def put_disturbance(buf, i, dist):
    """Lane ``i``'s disturbance ``[f_W, tau_B]`` held over the next step."""
    for j in range(6):
        buf[(_D + j) * W + i] = dist[j]


@kernel(inline="always")
def step_lanes(buf, n_rotors, dt, full):
    """One RK4 step of every lane of ``buf`` with its command and disturbance held (as
    :func:`~.plant.rk4_step` of each): the rotors, their stages' ``E f`` summed in rotor order
    (:func:`_rotors_in_lanes` for a literal count of four, else :func:`_rotors_across_lanes`), then the
    body (:func:`_bodies_plain` or :func:`_bodies_full`), then the quaternions' norms
    (:func:`~.plant.inv_norm`). ``full`` false (a literal) where no lane has a pendulum or quadratic drag
    and no massless link moves (:func:`block_is_plain`): the same states, without their arithmetic.

    Each form of the bodies' step is a function of its own, called rather than inlined (the whole step's
    one compiled copy for every rotor count). Inlined at the engine's three call sites, the plain one in
    two forms, they made the engine's cold compile take 16.1 GB of memory and 14 minutes on two cores;
    called (and :func:`observe_lanes`'s loop too), 5.4 GB and 4 minutes, for a block's step 2 % slower
    (nineteenth stop, the performance guide)."""
    if n_rotors == 4:  # a literal: the quadrotor's rotors inside the lanes' loop, their sums in registers
        _rotors_in_lanes(buf, 4, dt)
    else:
        _rotors_across_lanes(buf, n_rotors, dt)
    if full:
        _bodies_full(buf, dt)
    else:
        _bodies_plain(buf, dt)
    # the new states kept, the quaternions back to unit norm (plant.inv_norm, lane by lane the same numbers):
    # products only where every lane of the block is near 1, as in flight; else each lane as its own vehicle.
    # full false: the step wrote no pendulum rows into _K, and none is read from them (_put_states)
    if row_sum(buf, _Q) == 0.0:
        for i in range(W):  # vectorised: one lane per vehicle
            s = _body_rows(buf, _K, i)
            _put_states(buf, _S, i, unit_quaternion(s, inv_norm_near(quat_norm2(s))), full)
    else:
        for i in range(W):
            s = _body_rows(buf, _K, i)
            _put_states(buf, _S, i, unit_quaternion(s, inv_norm(quat_norm2(s))), full)


@kernel(inline="always")
def _rotors_in_lanes(buf, n_rotors, dt):
    """Every lane's rotors' RK4 step (:func:`~.plant.rotor_rk4`, kept in their rows) and their ``E f`` at the
    four stages, summed in rotor order (as :func:`~.plant._rotor_stages`) in registers and written once, into
    the rows :func:`_body_lanes` reads. ``n_rotors`` a literal: LLVM unrolls the rotors and vectorises the
    lanes' loop, with half the instructions of :func:`_rotors_across_lanes` (no row read and written again
    per rotor; the same numbers). Written out in one function on purpose: a rotor's step as a called
    helper taking its index kept the loop scalar (twentieth stop, the performance guide)."""
    for i in range(W):  # vectorised: one lane per vehicle
        up, down = buf[(_PL + 25) * W + i], buf[(_PL + 26) * W + i]
        a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = c0 = c1 = c2 = c3 = d0 = d1 = d2 = d3 = 0.0
        for r in range(n_rotors):
            g = clip_command(buf[(_FC + r) * W + i], buf[(_FMIN + r) * W + i], buf[(_FMAX + r) * W + i])
            f1 = buf[(_F + r) * W + i]
            f, f2, f3, f4 = rotor_rk4(up, down, g, f1, dt)
            buf[(_F + r) * W + i] = f
            k = (_E + 4 * r) * W + i
            e0, e1, e2, e3 = buf[k], buf[k + W], buf[k + 2 * W], buf[k + 3 * W]
            a0, a1, a2, a3 = a0 + e0 * f1, a1 + e1 * f1, a2 + e2 * f1, a3 + e3 * f1
            b0, b1, b2, b3 = b0 + e0 * f2, b1 + e1 * f2, b2 + e2 * f2, b3 + e3 * f2
            c0, c1, c2, c3 = c0 + e0 * f3, c1 + e1 * f3, c2 + e2 * f3, c3 + e3 * f3
            d0, d1, d2, d3 = d0 + e0 * f4, d1 + e1 * f4, d2 + e2 * f4, d3 + e3 * f4
        k = _U * W + i
        buf[k], buf[k + W], buf[k + 2 * W], buf[k + 3 * W] = a0, a1, a2, a3
        buf[k + 4 * W], buf[k + 5 * W], buf[k + 6 * W], buf[k + 7 * W] = b0, b1, b2, b3
        buf[k + 8 * W], buf[k + 9 * W], buf[k + 10 * W], buf[k + 11 * W] = c0, c1, c2, c3
        buf[k + 12 * W], buf[k + 13 * W], buf[k + 14 * W], buf[k + 15 * W] = d0, d1, d2, d3


@kernel(inline="always")
def _rotors_across_lanes(buf, n_rotors, dt):
    """:func:`_rotors_in_lanes` for a count known only at run time: the rotors one at a time across the
    lanes, their sums through the rows (a loop inside the lanes' loop would not vectorise)."""
    for j in range(16):
        for i in range(W):
            buf[(_U + j) * W + i] = 0.0
    for r in range(n_rotors):
        for i in range(W):  # vectorised: one lane per vehicle
            up, down = buf[(_PL + 25) * W + i], buf[(_PL + 26) * W + i]
            g = clip_command(buf[(_FC + r) * W + i], buf[(_FMIN + r) * W + i], buf[(_FMAX + r) * W + i])
            f1 = buf[(_F + r) * W + i]
            f, f2, f3, f4 = rotor_rk4(up, down, g, f1, dt)
            buf[(_F + r) * W + i] = f
            for c in range(4):
                e = buf[(_E + 4 * r + c) * W + i]
                buf[(_U + c) * W + i] += e * f1
                buf[(_U + 4 + c) * W + i] += e * f2
                buf[(_U + 8 + c) * W + i] += e * f3
                buf[(_U + 12 + c) * W + i] += e * f4


@kernel()
def _bodies_plain(buf, dt):
    """The body's step of a block whose lanes have no pendulum or quadratic drag, into the rows from
    :data:`_K`. It leaves out the ground (``contact`` false in :func:`~.plant.body_derivative`) unless it
    acted on a lane in the block's last step; a step in which it would have acted on a lane at one of its
    stages is taken again with it, from the same states. The ground's forces are exact zeros where no
    contact point is below it, so either way each lane's numbers are its own vehicle's ``rk4_step``'s. In
    flight no lane is near the ground and the step is 13 % faster; a touchdown costs one step twice, a block
    resting on the ground takes the step with the ground at once (flag :data:`_C`). Whether to take either
    path comes from the rows of flags the lane loop writes, summed over the lanes (:func:`row_sum`)."""
    contact = buf[_C * W] > 0.0
    if not contact:
        _body_lanes(buf, dt, False, False)
        contact = row_sum(buf, _T) > 0.0
    if contact:
        _body_lanes(buf, dt, False, True)
        buf[_C * W] = 1.0 if row_sum(buf, _T) > 0.0 else 0.0


@kernel()
def _bodies_full(buf, dt):
    """The body's step of a block with a pendulum or quadratic drag in a lane, with the ground (one form
    for every rotor count: a compiled copy fewer)."""
    _body_lanes(buf, dt, True, True)


@kernel(inline="always")
def _body_lanes(buf, dt, full, contact):
    """Every lane's body step (:func:`~.plant.body_rk4`, ``full`` and ``contact`` literals) into the rows
    from :data:`_K`, and into :data:`_T` whether the ground acted on the lane, or would have."""
    for i in range(W):  # vectorised: one lane per vehicle
        u, dd = _U * W + i, _D * W + i
        s, touch = body_rk4(
            _plant_at(buf, i), _body_at(buf, i), _four(buf, u), _four(buf, u + 4 * W), _four(buf, u + 8 * W),
            _four(buf, u + 12 * W), (buf[dd], buf[dd + W], buf[dd + 2 * W], buf[dd + 3 * W], buf[dd + 4 * W],
            buf[dd + 5 * W]), dt, full, contact,
        )  # fmt: skip
        _put_states(buf, _K, i, s, full)
        buf[_T * W + i] = touch
        buf[_Q * W + i] = 0.0 if abs(quat_norm2(s) - 1.0) <= QUAT_NEAR else 1.0  # as plant.inv_norm


@kernel(inline="always")
def row_sum(buf, row):
    """The sum of the row ``row``'s :data:`W` values, as a tree of halves (fifteen additions, not a chain of
    sixteen dependent ones; the rows summed here hold small integers, exact in any order)."""
    a = load_row(buf, row * W)
    h = (a[0] + a[8], a[1] + a[9], a[2] + a[10], a[3] + a[11], a[4] + a[12], a[5] + a[13], a[6] + a[14],
         a[7] + a[15])  # fmt: skip
    return ((h[0] + h[4]) + (h[2] + h[6])) + ((h[1] + h[5]) + (h[3] + h[7]))


@kernel(inline="always")
def block_is_plain(buf):
    """Whether no lane of ``buf`` has a pendulum or quadratic drag (:func:`~.plant.plant_is_plain`), nor a
    pendulum's link moving (``v_pend_W``, which then stays as it is): then :func:`step_lanes` may take
    ``full`` false."""
    for i in range(W):
        k = (_S + 16) * W + i
        if not plant_is_plain(_plant_at(buf, i)) or buf[k] != 0.0 or buf[k + W] != 0.0 or buf[k + 2 * W] != 0.0:
            return False
    return True


@kernel(inline="always")
def _four(buf, k):
    """Rows ``k``, ``k + W``, ``k + 2 W``, ``k + 3 W`` of one lane (a stage's thrust and moments)."""
    return buf[k], buf[k + W], buf[k + 2 * W], buf[k + 3 * W]


@kernel(inline="always")
def put_nominal(buf, i, mass, I9):
    """Lane ``i``'s controller's nominal mass and inertia (row-major 9-tuple), for the lumped wrench."""
    buf[_N * W + i] = mass
    for j in range(9):
        buf[(_N + 1 + j) * W + i] = I9[j]


@kernel(inline="always")
def put_held(buf, i, u, tau):
    """Lane ``i``'s command held over the period that starts: thrust ``u`` and body moments ``tau``."""
    put_command_rows(buf, _N + 10, i, u, tau)


@kernel(inline="always")
def put_command_rows(buf, row, i, u, tau):
    """Rows ``row .. row + 3`` of lane ``i`` of a buffer of rows :data:`W` wide: thrust ``u``, body moments ``tau``."""
    buf[row * W + i] = u
    for j in range(3):
        buf[(row + 1 + j) * W + i] = tau[j]


@kernel(inline="always")
def _sum_rotors(buf, n_rotors):
    """``E f`` of every lane's rotor forces into rows ``_U .. _U + 3``, summed in rotor order (as
    :func:`~.plant.truth_at` sums them)."""
    for j in range(4):
        for i in range(W):
            buf[(_U + j) * W + i] = 0.0
    for r in range(n_rotors):
        for i in range(W):  # vectorised: one lane per vehicle
            f = buf[(_F + r) * W + i]
            for c in range(4):
                buf[(_U + c) * W + i] += buf[(_E + 4 * r + c) * W + i] * f


@kernel(inline="always")
def observe_lanes(buf, n_rotors, full):
    """The truth at a control tick for every lane, as one vehicle's :func:`~.plant.truth_at` and
    :func:`~.plant.observed` give it, into the rows read by :func:`observed_at`: the state, rotor forces and
    disturbance the lanes hold, the command held over the last period. ``full``: as :func:`step_lanes`. The
    lanes' loop is a called function in either form, as the bodies' step (:func:`_truths_plain`,
    :func:`_truths_full`): once a tick, the call costs nothing to speak of, and the engine's compile a form
    fewer."""
    _sum_rotors(buf, n_rotors)
    if full:
        _truths_full(buf)
    else:
        _truths_plain(buf)


@kernel()
def _truths_plain(buf):
    """:func:`observe_lanes`'s loop over the lanes, for a block without a pendulum or quadratic drag."""
    _truth_lanes(buf, False)


@kernel()
def _truths_full(buf):
    """:func:`observe_lanes`'s loop over the lanes, with the whole plant (every rotor count)."""
    _truth_lanes(buf, True)


@kernel(inline="always")
def _truth_lanes(buf, full):
    """Every lane's truth (:func:`~.plant.truth_of`, ``full`` a literal) and what its tick observes of it."""
    for i in range(W):  # vectorised: one lane per vehicle
        u, dd, nn = _U * W + i, _D * W + i, _N * W + i
        pl, s = _plant_at(buf, i), _body_at(buf, i)
        dist = (buf[dd], buf[dd + W], buf[dd + 2 * W], buf[dd + 3 * W], buf[dd + 4 * W], buf[dd + 5 * W])
        a_o, w_dot, env = truth_of(pl, s, buf[u], buf[u + W], buf[u + 2 * W], buf[u + 3 * W], dist, full)
        I9 = (buf[nn + W], buf[nn + 2 * W], buf[nn + 3 * W], buf[nn + 4 * W], buf[nn + 5 * W], buf[nn + 6 * W],
              buf[nn + 7 * W], buf[nn + 8 * W], buf[nn + 9 * W])  # fmt: skip
        tau = (buf[nn + 11 * W], buf[nn + 12 * W], buf[nn + 13 * W])
        eta, f_l, t_l, p_o, v_o = observed(pl.c_B, s, a_o, w_dot, buf[nn + 10 * W], tau, buf[nn], I9)
        k = _O * W + i
        for j in range(3):
            buf[k + j * W] = eta[j]
            buf[k + (3 + j) * W] = f_l[j]
            buf[k + (6 + j) * W] = t_l[j]
            buf[k + (9 + j) * W] = p_o[j]
            buf[k + (12 + j) * W] = v_o[j]
        for j in range(6):
            buf[k + (15 + j) * W] = env[j]


@kernel(inline="always")
def observed_at(buf, i):
    """Lane ``i``'s ``(eta, f_l, t_l, p_o, v_o)`` and wrench ``[f_ext_W, tau_ext_B]`` of :func:`observe_lanes`."""
    k = _O * W + i
    env = (buf[k + 15 * W], buf[k + 16 * W], buf[k + 17 * W], buf[k + 18 * W], buf[k + 19 * W], buf[k + 20 * W])
    return observed_rows(buf, i), env


@kernel(inline="always")
def observed_rows(buf, i):
    """Lane ``i``'s ``(eta, f_l, t_l, p_o, v_o)`` of :func:`observe_lanes` (3-tuples)."""
    k = _O * W + i

    def three(j):
        return buf[k + j * W], buf[k + (j + 1) * W], buf[k + (j + 2) * W]

    return three(0), three(3), three(6), three(9), three(12)


@kernel(inline="always")
def failure_lanes(buf, n_rotors):
    """Every lane's :func:`~.plant.failure_of` into the row read by :func:`failure_at`."""
    for i in range(W):
        buf[(_U + 4) * W + i] = 0.0
    for r in range(n_rotors):
        for i in range(W):
            buf[(_U + 4) * W + i] += buf[(_F + r) * W + i]
    for i in range(W):  # vectorised: one lane per vehicle
        buf[_X * W + i] = failure_of(_plant_at(buf, i), _body_at(buf, i), buf[(_U + 4) * W + i])


@kernel(inline="always")
def failure_at(buf, i):
    """Lane ``i``'s failure code of :func:`failure_lanes` (0: it flies on)."""
    return int(buf[_X * W + i])


@kernel(inline="always")
def instant_rotors_lane(buf, i, up_now, down_now, f_cmd, f_min, f_max, n):
    """Lane ``i``'s rotors follow their commands at once in a direction without lag (:func:`~.plant.instant_force`)."""
    for r in range(n):
        k = (_F + r) * W + i
        buf[k] = instant_force(up_now, down_now, clip_command(f_cmd[r], f_min[r], f_max[r]), buf[k])


# The sensors of a block (:func:`measure_lanes`): rows of W in the buffer ``sb`` (:func:`new_sensor_buffer`).
_SN = 0  # the tick's noise draws (12, in the order of y)
NOISE_ROW = _SN  #: the sensor buffer's first noise row (:func:`.noise.normals_lanes` draws into it)
_SC = _SN + 12  # the CoM in the body, c_B (3)
_SX = _SC + 3  # the states read: motion capture p, v, q, w (13), IMU q, w (7)
_SY = _SX + 20  # the measurement y (12)
_SR = _SY + 12  # the ring of past states: slot s at rows _SR + 13 s .. (p, v, q, w)
SENSED = _SY  #: the first of the sensor buffer's rows holding the measurement


@kernel()
def new_sensor_buffer(H):
    """A zeroed sensor buffer with a ring of ``H`` past states (64-byte aligned: :func:`aligned_zeros`)."""
    return aligned_zeros((_SR + 13 * H) * W)


@kernel()
def put_sensors(sb, i, pp, hist_b):
    """Lane ``i`` takes the sensors of a vehicle: its CoM offset (plant record ``pp``) and its ring of past
    states ``hist_b`` (records, the slots as they are)."""
    for j in range(3):
        sb[(_SC + j) * W + i] = pp.c_B[j]
    for s in range(hist_b.shape[0]):
        k = (_SR + 13 * s) * W + i
        x = hist_b[s]
        for j in range(3):
            sb[k + j * W] = x.p_com_W[j]
            sb[k + (3 + j) * W] = x.v_com_W[j]
            sb[k + (10 + j) * W] = x.omega_B[j]
        for j in range(4):
            sb[k + (6 + j) * W] = x.q_WB[j]


@kernel()
def get_sensors(sb, i, hist_b):
    """The ring of records ``hist_b`` takes lane ``i``'s past states (what :func:`put_sensors` put, as the plant
    went on: the states the sensors read; the other fields are not read)."""
    for s in range(hist_b.shape[0]):
        k = (_SR + 13 * s) * W + i
        x = hist_b[s]
        for j in range(3):
            x.p_com_W[j] = sb[k + j * W]
            x.v_com_W[j] = sb[k + (3 + j) * W]
            x.omega_B[j] = sb[k + (10 + j) * W]
        for j in range(4):
            x.q_WB[j] = sb[k + (6 + j) * W]


@kernel(inline="always")
def keep_state(sb, buf, slot):
    """Every lane's position, velocity, attitude and rate (13 rows) into the ring's ``slot``."""
    for j in range(13):
        copy_row(sb, (_SR + 13 * slot + j) * W, buf, (_S + j) * W)


@kernel()
def measure_lanes(sb, slot_mocap, slot_imu, sigma):
    """Every lane's measurement (:func:`~.plant.measured`, with the sines of :mod:`.vmath`) from the ring's
    slots the motion capture and the IMU read and the tick's noise; ``sigma = [pos, vel, att, gyro]``."""
    for j in range(13):  # the states read into fixed rows: the lane loop then reads at fixed distances only
        copy_row(sb, (_SX + j) * W, sb, (_SR + 13 * slot_mocap + j) * W)
    for j in range(7):
        copy_row(sb, (_SX + 13 + j) * W, sb, (_SR + 13 * slot_imu + 6 + j) * W)
    sg = (sigma[0], sigma[1], sigma[2], sigma[3])
    for i in range(W):  # vectorised: one lane per vehicle
        c, p, v, q, w, qi, wi, noise = _sensed_at(sb, i)
        y = measured(c, p, v, q, w, qi, wi, sg, noise, True)
        for j in range(12):
            sb[(_SY + j) * W + i] = y[j]


@kernel(inline="always")
def _sensed_at(sb, i):
    """Lane ``i``'s ``c_B``, the motion-capture state read ``(p, v, q, w)``, the IMU's ``(q, w)`` and the noise."""
    k = i

    def at(row):
        return sb[row * W + k]

    def three(row):
        return (at(row), at(row + 1), at(row + 2))

    q = (at(_SX + 6), at(_SX + 7), at(_SX + 8), at(_SX + 9))
    qi = (at(_SX + 13), at(_SX + 14), at(_SX + 15), at(_SX + 16))
    noise = three(_SN) + three(_SN + 3) + three(_SN + 6) + three(_SN + 9)
    return three(_SC), three(_SX), three(_SX + 3), q, three(_SX + 10), qi, three(_SX + 17), noise


@kernel(inline="always")
def measurement_at(sb, i, y):
    """Lane ``i``'s measurement of the last :func:`measure_lanes` into ``y`` (12)."""
    for j in range(12):
        y[j] = sb[(_SY + j) * W + i]
