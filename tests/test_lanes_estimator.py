"""The momentum-based estimator of a block of vehicles in SIMD lanes (``compiled.lanes_estimator``, thirteenth
stop): sixteen vehicles with their own masses and inertias, fed sixteen different flights (attitudes across the
+-pi wrap, fractional sensor delays, a rotor model, orders 1 to 3), give each sample's estimate and its rate as
the vehicle-by-vehicle estimator does, and hand back the same state and history; its loops are vector code."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from vtol_impedance.compiled.estimator import pack_design, sample_one
from vtol_impedance.compiled.jit import FLAGS
from vtol_impedance.compiled.lanes import W
from vtol_impedance.compiled.lanes_estimator import (
    estimate_lanes,
    get_estimator,
    new_estimator_buffer,
    put_command_held,
    put_estimator,
    put_measured,
    sample_at,
)
from vtol_impedance.compiled.layouts import CONTROLLER_STATE, HISTORY
from vtol_impedance.estimator.momentum import EstimatorParams, design

TS = 0.01
K0 = 20  # the sample after which the lanes take over


@njit(**{**FLAGS, "cache": False})
def _in_lanes(d, S, EH, mass, I, V, E, DE, U, TAU, k0, out):  # noqa: E741, N803
    """Samples ``k0 + 1 .. K-1`` of every lane (``S``, ``EH`` hold the estimators after sample ``k0``):
    ``out[k, i] = [w_hat, r_dot, Q, M, C]``; the records take the lanes' state at the end."""
    eb = new_estimator_buffer(EH.shape[1])
    head = 3  # any slot: the ring is the history read from its newest
    y = np.zeros(12)
    for i in range(W):
        I9 = (
            I[i, 0, 0],
            I[i, 0, 1],
            I[i, 0, 2],
            I[i, 1, 0],
            I[i, 1, 1],
            I[i, 1, 2],
            I[i, 2, 0],
            I[i, 2, 1],
            I[i, 2, 2],
        )  # noqa: N806
        put_estimator(eb, i, S[i], EH[i], head % EH.shape[1], mass[i], I9)
    head = head % EH.shape[1]
    for k in range(k0 + 1, V.shape[0]):
        for i in range(W):
            put_command_held(eb, i, U[k - 1, i], TAU[k - 1, i])
            for j in range(3):
                y[3 + j], y[6 + j], y[9 + j] = V[k, i, j], E[k, i, j], DE[k, i, j]
            put_measured(eb, i, y)
        head = estimate_lanes(eb, d[0], head)
        for i in range(W):
            Q, M, C, w, rd = sample_at(eb, i)  # noqa: N806
            for j in range(6):
                out[k, i, j], out[k, i, 6 + j] = w[j], rd[j]
            for j in range(9):
                out[k, i, 12 + j], out[k, i, 21 + j], out[k, i, 30 + j] = Q[j], M[j], C[j]
    for i in range(W):
        get_estimator(eb, i, S[i], EH[i], head)


def _flights(rng, K):
    """Sixteen flights of ``K`` samples: velocities, Euler angles (yaw winding through +-pi), their rates
    (not the angles' differences: a gyro's noise), thrusts and moments."""
    t = np.arange(K)[:, None] * TS
    ph = rng.uniform(0, 2 * np.pi, (1, W))
    V = np.stack(
        [np.sin(3 * t + ph), np.cos(2 * t + ph), 0.3 * np.sin(5 * t + 0 * ph)], -1
    ) + 0.01 * rng.standard_normal((K, W, 3))  # noqa: N806
    psi = np.mod(rng.uniform(-np.pi, np.pi, (1, W)) + 4.0 * t + np.pi, 2 * np.pi) - np.pi
    E = np.stack([0.3 * np.sin(4 * t + ph), 0.25 * np.cos(3 * t + ph), psi], -1)  # noqa: N806
    DE = np.stack(
        [1.2 * np.cos(4 * t + ph), -0.75 * np.sin(3 * t + ph), 4.0 + 0 * t + 0 * ph], -1
    ) + 0.05 * rng.standard_normal((K, W, 3))  # noqa: N806
    U = 15.0 + 3.0 * np.sin(7 * t + ph) + rng.standard_normal((K, W))  # noqa: N806
    TAU = 0.2 * rng.standard_normal((K, W, 3))  # noqa: N806
    return V, E, DE, U, TAU


@pytest.mark.parametrize(
    "params",
    [
        EstimatorParams(wn=8.0, order=1, prototype="binomial"),
        EstimatorParams(wn=12.0, order=2, velocity_delay=0.02, attitude_delay=0.0137, rotor_tau=0.03),
        EstimatorParams(
            wn=15.0, order=3, prototype="butterworth", velocity_delay=0.045, attitude_delay=0.003, rotor_tau=0.01
        ),
    ],
    ids=["order1", "order2-delays-rotor", "order3-delays"],
)
def test_the_estimators_in_lanes_sample_as_each_vehicle_does(rng, params):
    des = design(params, TS)
    d = pack_design(des)
    K = 300
    V, E, DE, U, TAU = _flights(rng, K)  # noqa: N806
    mass = rng.uniform(0.5, 3.0, W)
    I = np.array([np.diag(rng.uniform(0.005, 0.05, 3)) + 1e-4 * (np.ones((3, 3)) - np.eye(3)) for _ in range(W)])  # noqa: E741
    # the vehicle-by-vehicle estimator at every sample; the lanes take over after sample K0
    S, EH = np.zeros(W, dtype=CONTROLLER_STATE), np.zeros((W, des.H), dtype=HISTORY)  # noqa: N806
    ref = np.zeros((K, W, 12))
    out9 = np.zeros(9)
    lanes_S, lanes_EH = None, None  # noqa: N806
    for k in range(K):
        for i in range(W):
            I9 = tuple(I[i].ravel())  # noqa: N806
            j = max(k - 1, 0)
            sample_one(d, S[i : i + 1], EH[i : i + 1], mass[i], I9, V[k, i], E[k, i], DE[k, i], U[j, i], TAU[j, i],
                       k == 0, out9)  # fmt: skip
            ref[k, i, :6], ref[k, i, 6:] = S[i]["w_hat"], S[i]["r_dot"]
        if k == K0:  # the lanes take over a history of distinct rows (the first sample fills it with one)
            lanes_S, lanes_EH = S.copy(), EH.copy()  # noqa: N806
            lanes_S["thrust_prev"], lanes_S["tau_B_prev"] = U[K0], TAU[K0]
    out = np.zeros((K, W, 39))
    assert des.H < K0
    _in_lanes(d, lanes_S, lanes_EH, mass, I, V, E, DE, U, TAU, K0, out)
    ks = slice(K0 + 1, None)
    assert np.abs(ref[ks, :, :6]).max() > 1.0  # the flights excite the estimate: a comparison of zeros tests nothing
    for cols, what in ((slice(0, 6), "estimate"), (slice(6, 12), "its rate")):
        scale = np.abs(ref[ks, :, cols]).max(axis=(0, 1))
        err = np.abs(out[ks, :, cols] - ref[ks, :, cols]).max(axis=(0, 1))
        assert np.all(err <= 1e-11 * scale), (what, err / scale)
    # Q of eq. (1c) at the measured attitude, independently
    ph, th = E[ks, :, 0], E[ks, :, 1]
    Q = np.stack([np.ones_like(ph), 0 * ph, -np.sin(th), 0 * ph, np.cos(ph), np.sin(ph) * np.cos(th), 0 * ph,  # noqa: N806
                  -np.sin(ph), np.cos(ph) * np.cos(th)], -1)  # fmt: skip
    np.testing.assert_allclose(out[ks, :, 12:21], Q, atol=1e-15)
    M = np.einsum("kiba,ibc,kicd->kiad", Q.reshape(K - K0 - 1, W, 3, 3), I, Q.reshape(K - K0 - 1, W, 3, 3))  # noqa: N806
    np.testing.assert_allclose(out[ks, :, 21:30], M.reshape(K - K0 - 1, W, 9), rtol=1e-13, atol=1e-17)
    # the state handed back is the vehicle-by-vehicle estimator's after its last sample
    for name in ("x", "q_prev", "Q_prev", "C_prev", "eta_dot_prev", "w_hat", "r_dot", "act"):
        np.testing.assert_allclose(lanes_S[name], S[name], rtol=1e-10, atol=1e-12, err_msg=name)
    for name in ("act", "eta"):
        np.testing.assert_allclose(lanes_EH[name], EH[name], rtol=1e-12, atol=1e-15, err_msg=name)


def test_the_estimator_loops_are_vector_code():
    """The sample's arithmetic (``Q``, ``M``, ``C``, the momentum, the residual of eq. (8) with its sines) compiles
    to packed FMAs: a call or a branch on a lane's value would leave the loop scalar."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if not re.search(r"\bavx2\b", flags):
        pytest.skip("no AVX2 on this machine")

    @njit(**{**FLAGS, "cache": False})
    def one(eb, d):
        return estimate_lanes(eb, d[0], 0)

    d = pack_design(design(EstimatorParams(order=2), TS))
    one(new_estimator_buffer(int(d[0]["H"])), d)
    asm = one.inspect_asm(one.signatures[0])
    packed = len(re.findall(r"vfn?m(?:add|sub)\w*pd\s+%[yz]mm", asm))
    scalar = len(re.findall(r"vfn?m(?:add|sub)\w*sd\s", asm))
    # a scalar main loop measured 54 packed and 358 scalar; the general order's filter stays scalar code
    assert packed >= 200 and packed > scalar, (packed, scalar)
    assert math.isfinite(packed)
