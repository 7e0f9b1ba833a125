"""Compiled closed loop: one ``prange`` iteration per vehicle, time in blocks driven from Python.

Per control period it does exactly what :func:`vtol_impedance.sim.loop.run_closed_loop` does with the
NumPy backend (read delayed noisy sensors, controller step, log, hold the rotor command for ``n_sub``
RK4 plant steps, check for divergence), using the kernels of :mod:`.controller` and :mod:`.plant`.
Sensor noise is each vehicle's stream of :class:`vtol_impedance.sim.sensors.NoiseSource` (NumPy's default
generator seeded by the vehicle's seed), drawn inside the kernel from the generators' states ``rng (4, B)``
(:mod:`.noise`: the same numbers bit for bit), twelve standard normals per tick, in the order the NumPy
backend draws them, so both backends see the same numbers (``tests/test_noise.py``,
``tests/test_compiled.py``) and the draws run in the vehicles' threads (a block's in SIMD lanes). Data layouts
are those of :mod:`.layouts`; the log rows are :data:`vtol_impedance.records.LOG_ROW`.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .algebra import _Q9, _v3
from .controller import controller_step, law_lane_of, nominal_inertia
from .jit import kernel
from .lanes import (
    NOISE_ROW,
    SENSED,
    W,
    aligned_zeros,
    block_is_plain,
    failure_at,
    failure_lanes,
    get_sensors,
    get_state,
    instant_rotors_lane,
    keep_state,
    measure_lanes,
    measurement_at,
    new_buffer,
    new_sensor_buffer,
    observe_lanes,
    observed_at,
    put_command,
    put_disturbance,
    put_held,
    put_nominal,
    put_plant,
    put_sensors,
    put_state,
    state_view,
    step_lanes,
)
from .lanes_controller import (
    N_SUMS,
    add_terms_lanes,
    allocation_held,
    finish_lanes,
    fix_allocation,
    get_law_state,
    get_output,
    get_sums,
    law_lanes,
    metric_terms_at,
    metric_terms_lanes,
    new_law_buffer,
    put_law,
    put_law_state,
    put_measurement_rows,
    put_sums,
)
from .lanes_estimator import (
    estimate_lanes,
    get_estimator,
    new_estimator_buffer,
    put_command_held,
    put_estimator,
    put_measured_rows,
)
from .layouts import OUTPUT
from .metrics import add_terms, tick_terms
from .noise import draw_lanes, new_draw_scratch, standard_normal
from .plant import (
    _body_of,
    clip_command,
    disturbance_at,
    failure_of,
    instant_force,
    lane_of,
    measured,
    observed,
    rk4_step,
    truth_at,
)

_Z3 = (0.0, 0.0, 0.0)
_NO_OBS = (_Z3, _Z3, _Z3, _Z3, _Z3)  # a tick without the truth (:func:`_truth_needed`)
_NO_ENV = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@kernel()
def _ago(hist, count, head, k):
    """The state ``k`` plant steps ago (the oldest kept when fewer are)."""
    H = hist.shape[0]
    return hist[(head - min(k, count - 1)) % H]


@kernel(inline="always")
def _measure(pp, xm, xi, sigma, noise, y):
    """Sensors (:func:`~.plant.measured`) reading the motion-capture state record ``xm`` and the IMU's ``xi``, into
    ``y``. Euler angles are computed here, once per control period."""
    v = measured(pp.c_B, xm.p_com_W, xm.v_com_W, xm.q_WB, xm.omega_B, xi.q_WB, xi.omega_B, sigma, noise, False)
    for i in range(12):
        y[i] = v[i]


@kernel(inline="always")
def _log(row, pp, x, r, y, o, env, eta, f_l, t_l, p_o, v_o):
    """One :data:`~vtol_impedance.records.LOG_ROW`."""
    Q = _Q9(eta[0], eta[1], False)
    for i in range(3):
        row.p_W[i] = p_o[i]
        row.v_W[i] = v_o[i]
        row.eta[i] = eta[i]
        row.omega_B[i] = x.omega_B[i]
        row.p_ref_W[i] = r[i]
        row.v_ref_W[i] = r[3 + i]
        row.p_meas_W[i] = y[i]
        row.v_meas_W[i] = y[3 + i]
        row.eta_meas[i] = y[6 + i]
        row.eta_d[i] = o.eta_d[i]
        row.tau_B_request[i] = o.tau_B_request[i]
        row.tau_B[i] = o.tau_B[i]
        row.f_ext_W[i] = env[i]
        row.tau_ext_B[i] = env[3 + i]
        row.tau_ext_eta[i] = Q[i] * env[3] + Q[3 + i] * env[4] + Q[6 + i] * env[5]  # Q^T tau_ext_B
        row.f_lumped_W[i] = f_l[i]
        row.tau_lumped_eta[i] = t_l[i]
        row.f_hat_W[i] = o.f_hat_W[i]
        row.tau_hat_eta[i] = o.tau_hat_eta[i]
        row.tau_hat_B[i] = o.tau_hat_B[i]
    row.psi_ref = r[9]
    row.thrust_request = o.thrust_request
    row.thrust = o.thrust
    row.saturated = 1.0 if o.saturated else 0.0
    row.tilt_limited = 1.0 if o.tilt_limited else 0.0
    row.rp_scale = o.rp_scale
    row.yaw_scale = o.yaw_scale
    for i in range(pp.n_rotors):
        row.f_rotor_cmd[i] = o.f_rotor[i]
        row.f_rotor[i] = x.f_rotor[i]


@kernel(inline="always")
def _accumulate(a, t, win, p_o, v_o, r, o, f_l, t_l):
    """Running sums of the window metrics (:data:`~.layouts.ACCUMULATORS`), as ``analysis.metrics``."""
    e2, ev2, fe2, te2 = tick_terms(p_o, v_o, r, o.f_hat_W, o.tau_hat_eta, f_l, t_l)
    add_terms(a, t, win, e2, ev2, fe2, te2, 1.0 if (o.saturated or o.tilt_limited) else 0.0)


@kernel(inline="always")
def _failure(pp, x):
    """Why the vehicle must stop (0: it flies on), as :func:`vtol_impedance.sim.loop.check_vehicles`
    (:func:`~.plant.failure_of` of the records)."""
    rotors = 0.0
    for i in range(pp.n_rotors):
        rotors += x.f_rotor[i]
    return int(failure_of(lane_of(pp), _body_of(x), rotors))


@kernel(inline="always")
def _observed(pp_b, p_b, s_b, x, a_o, w_dot):
    """:func:`~.plant.observed` for the records of one vehicle (before its controller steps: the command held
    over the last period)."""
    tau = (s_b.tau_B_prev[0], s_b.tau_B_prev[1], s_b.tau_B_prev[2])
    return observed(_v3(pp_b.c_B), _body_of(x), a_o, w_dot, s_b.thrust_prev, tau, p_b.mass, nominal_inertia(p_b))


@kernel(inline="always")
def _control_tick(k, t, pp_b, p_b, des, s_b, h_b, xm, xi, x, obs, env, sigma, rng, b, r, logs_b, dec, acc_b, win, o,
                  y, noise, rc):  # fmt: skip
    """Control tick ``k`` (time ``t``) of one vehicle, whichever plant flies it: its sensors (:func:`_sense`), the
    controller step (the rotor command in ``o``) given the reference of :func:`_reference`, and the window metrics
    and log row of :func:`_record`. ``y``, ``noise``, ``rc`` (18) are scratch."""
    _sense(pp_b, xm, xi, sigma, rng, b, noise, y)
    controller_step(p_b, des, s_b, h_b, y, _reference(r, rc), o)
    _record(k, t, pp_b, x, obs, env, r, y, o, logs_b, dec, acc_b, win)


@kernel(inline="always")
def _sense(pp_b, xm, xi, sigma, rng, b, noise, y):
    """The measurement ``y`` of the sensors reading the states ``xm`` (motion capture), ``xi`` (IMU), with twelve
    normals from vehicle ``b``'s generator (column ``b`` of ``rng``) in the order of ``NoiseSource.block``
    (``noise``: scratch)."""
    for i in range(12):  # [position, velocity, attitude, gyro]
        noise[i] = standard_normal(rng, b)
    _measure(pp_b, xm, xi, sigma, noise, y)


@kernel(inline="always")
def _reference(r, rc):
    """What the controller is given of the reference row ``r = [p_d, v_d, a_d, psi, psi_dot, psi_ddot, comply (6),
    p_d, v_d at the measurement's time (6)]`` (:func:`vtol_impedance.sim.loop.reference_rows`): its first 18
    with the last six in place of the first six, in ``rc`` (the metrics and log read the first six)."""
    for i in range(18):
        rc[i] = r[i]
    for i in range(6):
        rc[i] = r[18 + i]
    return rc


@kernel(inline="always")
def _record(k, t, pp_b, x, obs, env, r, y, o, logs_b, dec, acc_b, win):
    """Where :func:`_truth_needed`, the window metrics and the log row of tick ``k`` from the truth at ``t``:
    ``obs = (eta, f_l, t_l, p_o, v_o)`` of :func:`~.plant.observed` (taken before the controller stepped),
    ``env = [f_ext_W, tau_ext_B]``, the state ``x``, the reference row ``r``, the measurement ``y`` and the
    controller's output ``o``."""
    if not _truth_needed(k, t, dec, win):
        return
    eta, f_l, t_l, p_o, v_o = obs
    if win[0] <= t <= win[1]:
        _accumulate(acc_b, t, win, p_o, v_o, r, o, f_l, t_l)
    if dec > 0 and k % dec == 0:
        _log(logs_b[k // dec], pp_b, x, r, y, o, env, eta, f_l, t_l, p_o, v_o)


@kernel(inline="always")
def _truth_needed(k, t, dec, win):
    """Whether tick ``k`` (time ``t``) is logged or inside the metrics window: the truth (the lumped wrench,
    the body origin's motion, the external wrench) is computed only then (a batch with ``log="metrics"``
    skips it before its task window)."""
    return (dec > 0 and k % dec == 0) or win[0] <= t <= win[1]


@kernel(parallel=True)
def run_block(k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu, sigma, rng, S, EH, p, d, pp, dists,
              series, refs, alive, fail_time, fail_code, x_park, logs, dec, acc, win):  # fmt: skip
    """Advance every live vehicle from control tick ``k0`` to ``k1``.

    ``X (B,)``: plant states; ``hist (B, H)``, ``hcount``, ``hhead``: each vehicle's ring of past states for
    the sensor delays; ``S (B,)``, ``EH (B, H_est)``: controller states and timing histories; ``p (B,)``,
    ``d (1,)``, ``pp (B,)``: controllers, shared design, plants; ``dists (D,)``, ``series``: disturbances;
    ``refs (N, 24)``: reference samples (:func:`_control_tick`); ``rng (4, B)``: the vehicles' noise generators'
    states (:func:`.noise.generator_states`; drawing advances them). ``logs (B, n_log)`` gets row ``k // dec``
    when ``dec > 0`` and ``k % dec == 0``; ``acc (B,)`` collects the window metrics (``win = [t0, t1, tail_start]``).
    """
    for b in prange(X.shape[0]):
        if alive[b]:  # records are handled in a function of their own: numba's parallel body mishandles them
            _fly(b, k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu, sigma, rng, S, EH, p, d, pp,
                 dists, series, refs, alive, fail_time, fail_code, x_park, logs, dec, acc, win)  # fmt: skip


@kernel()
def _fly(b, k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu, sigma, rng, S, EH, p, d, pp, dists,
         series, refs, alive, fail_time, fail_code, x_park, logs, dec, acc, win):  # fmt: skip
    """Vehicle ``b`` of :func:`run_block` from tick ``k0`` to ``k1`` (or until it fails)."""
    x, pp_b, p_b, s_b, h_b, des = X[b], pp[b], p[b], S[b], EH[b], d[0]
    o_ = _scratch()  # kept: the record below points into it
    o = o_[0]
    y = np.empty(12)
    noise = np.empty(12)
    dist = np.empty(6)  # explicit disturbances, held over each plant step
    rc = np.empty(18)
    has_dists = dists.shape[0] > 0
    for i in range(6):
        dist[i] = 0.0
    H = hist.shape[1]
    head, count = hhead[b], hcount[b]  # the ring's newest slot and fill, kept in registers
    keep = np.empty(n_sub, dtype=np.bool_)  # the plant steps whose state a sensor will read: those
    for js in range(n_sub):  # k_mocap or k_imu plant steps before a tick
        ahead = n_sub - 1 - js
        keep[js] = (k_mocap - ahead) % n_sub == 0 or (k_imu - ahead) % n_sub == 0
    for k in range(k0, k1):
        t = k * Ts
        # the truth at t_k, where it is logged or measured (the rotor-lag rate is not used here)
        obs, env = _NO_OBS, _NO_ENV
        if _truth_needed(k, t, dec, win):
            if has_dists:
                disturbance_at(pp_b, x, t, dists, series, dist)
            a_o, w_dot, env = truth_at(pp_b, x, dist)
            obs = _observed(pp_b, p_b, s_b, x, a_o, w_dot)
        xm, xi = _ago(hist[b], count, head, k_mocap), _ago(hist[b], count, head, k_imu)
        _control_tick(k, t, pp_b, p_b, des, s_b, h_b, xm, xi, x, obs, env, sigma, rng, b, refs[k], logs[b], dec,
                      acc[b], win, o, y, noise, rc)  # fmt: skip
        f_cmd = o.f_rotor
        _instant_rotors(pp_b, x, f_cmd)  # then hold the command over the period
        for js in range(n_sub):
            if has_dists:
                disturbance_at(pp_b, x, t + js * dt, dists, series, dist)
            rk4_step(pp_b, x, f_cmd, dist, dt)
            head = head + 1 if head + 1 < H else 0
            count = min(count + 1, H)
            if keep[js]:
                hist[b, head] = x

        code = _failure(pp_b, x)
        if code != 0:
            alive[b] = False
            fail_code[b] = code
            fail_time[b] = t + Ts
            X[b] = x_park[b]
            break
    hhead[b], hcount[b] = head, count


@kernel(parallel=True)
def run_block_lanes(k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu, sigma, rng, S, EH, p, d, pp, dists,
                    series, refs, alive, fail_time, fail_code, x_park, logs, dec, acc, win):  # fmt: skip
    """:func:`run_block` with the plants, sensors, estimators and control laws in SIMD lanes (:mod:`.lanes`,
    :mod:`.lanes_estimator`, :mod:`.lanes_controller`): one ``prange`` iteration per block of :data:`~.lanes.W`
    vehicles. Per control tick the block's truth is taken in lanes, each lane draws its vehicle's sensor noise
    (:func:`.noise.draw_lanes`), the block's sensors, estimators and control laws run in lanes, the window
    metrics' terms too (:mod:`.metrics`, the functions :func:`run_block` calls), each vehicle's log as in
    :func:`run_block`, then the block's plants take their ``n_sub`` RK4 steps
    together. Same arguments; the same results to 1e-11 (the lanes take their sines from :mod:`.vmath`,
    ``tests/test_lanes.py``)."""
    B = X.shape[0]
    for blk in prange((B + W - 1) // W):
        _fly_lanes(blk * W, min(W, B - blk * W), k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu,
                   sigma, rng, S, EH, p, d, pp, dists, series, refs, alive, fail_time, fail_code, x_park, logs, dec,
                   acc, win)  # fmt: skip


@kernel()
def _fly_lanes(b0, n, k0, k1, Ts, dt, n_sub, X, hist, hcount, hhead, k_mocap, k_imu, sigma, rng, S, EH, p, d, pp,
               dists, series, refs, alive, fail_time, fail_code, x_park, logs, dec, acc, win):  # fmt: skip
    """Vehicles ``b0 .. b0 + n - 1`` of :func:`run_block_lanes` from tick ``k0`` to ``k1``; lanes past ``n``
    repeat the block's first vehicle and are never read back. The lanes hold the states between ticks: the
    records ``X`` are written at the end (or when a vehicle stops), and before a logged tick; the sensors' rings
    ``hist`` (one newest slot ``hhead``, length ``hcount`` for the block), the estimators' and control laws'
    records ``S``, ``EH`` of the vehicles flying at the end (a stopped vehicle's are never read again). Until
    every estimator of the block has taken its first sample (which fills its history) the block's controllers
    step vehicle by vehicle."""
    buf = new_buffer()
    eb = new_estimator_buffer(EH.shape[1])
    cb = new_law_buffer()
    o_ = _scratch()  # kept: the record below points into it
    o = o_[0]
    Y = np.empty((W, 12))  # noqa: N806
    dist, rc = np.empty(6), np.empty(18)
    nr = 0
    for i in range(W):
        b = b0 + (i if i < n else 0)
        put_plant(buf, i, pp[b], lane_of(pp[b]))
        put_state(buf, i, X[b])
        put_nominal(buf, i, p[b].mass, nominal_inertia(p[b]))
        put_held(buf, i, S[b].thrust_prev, S[b].tau_B_prev)
        put_law(cb, i, law_lane_of(p[b]), p[b])
        nr = max(nr, pp[b].n_rotors)
    ncr = p[b0].n_rotors  # the same for every controller of a batch
    plain = block_is_plain(buf)
    head = np.int64(0)  # the estimators' ring: its newest slot, the same in every lane (typed: one signature)
    ready = _put_lanes(eb, cb, b0, n, S, EH, p, head)
    for i in range(6):
        dist[i] = 0.0
    for i in range(W):
        put_disturbance(buf, i, dist)
    has_dists = dists.shape[0] > 0
    H = hist.shape[1]
    sb = new_sensor_buffer(H)  # the sensors' rings of past states, in lanes
    for i in range(W):
        b = b0 + (i if i < n else 0)
        put_sensors(sb, i, pp[b], hist[b])
    head_s, count_s = 0, 1  # the rings' newest slot and length: the same for every vehicle flying in a block
    for i in range(n - 1, -1, -1):
        if alive[b0 + i]:
            head_s, count_s = hhead[b0 + i], hcount[b0 + i]
    keep = np.empty(n_sub, dtype=np.bool_)  # as _fly
    for js in range(n_sub):
        ahead = n_sub - 1 - js
        keep[js] = (k_mocap - ahead) % n_sub == 0 or (k_imu - ahead) % n_sub == 0
    live = 0
    instant = False  # a lane whose rotors follow a command at once in some direction: handled lane by lane
    flying = np.zeros(W, dtype=np.bool_)
    for i in range(n):
        live += 1 if alive[b0 + i] else 0
        flying[i] = alive[b0 + i]
        instant = instant or pp[b0 + i].tau_up <= 0 or pp[b0 + i].tau_down <= 0
    # without a log, the window metrics' sums stay in lanes from the first tick the laws run in lanes to the
    # chunk's end (the same additions in the same order as each vehicle's record would take)
    sums = aligned_zeros(N_SUMS * W)
    in_lanes = False
    st = aligned_zeros(4 * W).view(np.uint64).reshape(4, W)  # the lanes' noise generators (past n: the first's)
    drawn = new_draw_scratch()  # the noise draws' scratch
    for i in range(W):
        for j in range(4):
            st[j, i] = rng[j, b0 + (i if i < n else 0)]
    for k in range(k0, k1):
        if live == 0:
            break
        t = k * Ts
        truth = _truth_needed(k, t, dec, win)
        if truth:  # the truth at t_k for the whole block, in lanes
            if has_dists:
                for i in range(n):
                    if alive[b0 + i]:
                        disturbance_at(pp[b0 + i], state_view(buf, i), t, dists, series, dist)
                        put_disturbance(buf, i, dist)
            if nr == 4 and plain:  # literals, as step_lanes below
                observe_lanes(buf, 4, False)
            elif nr == 4:
                observe_lanes(buf, 4, True)
            else:
                observe_lanes(buf, nr, True)
        draw_lanes(st, sb, NOISE_ROW, 12, drawn)  # the sensors: each lane's noise of the tick, then the measurement
        ago_m, ago_i = min(k_mocap, count_s - 1), min(k_imu, count_s - 1)  # as _ago
        measure_lanes(sb, (head_s - ago_m) % H, (head_s - ago_i) % H, sigma)
        put_measured_rows(eb, sb, SENSED)
        put_measurement_rows(cb, sb, SENSED)
        logged = dec > 0 and k % dec == 0
        rc = _reference(refs[k], rc)  # the same for every vehicle of the tick
        if ready:  # the estimators and control laws, in lanes; the commands into the plants' rows
            head = estimate_lanes(eb, d[0], head)
            if ncr == 4:  # a literal rotor count keeps the law's loop vector code (others: scalar, compiled once)
                held = law_lanes(cb, eb, d[0], rc, 4)
            else:
                held = law_lanes(cb, eb, d[0], rc, ncr)
            if not held:  # a lane whose allocation needs more than its first step
                for i in range(n):
                    if alive[b0 + i] and not allocation_held(cb, i):
                        fix_allocation(cb, i, p[b0 + i], o.f_rotor)
            finish_lanes(cb, eb, buf, d[0], ncr)
        window_only = ready and truth and not logged  # the window's metrics alone: their terms in lanes
        if window_only:
            metric_terms_lanes(cb, buf, refs[k])
            if dec == 0:
                if not in_lanes:
                    for i in range(n):
                        put_sums(sums, i, acc[b0 + i])
                    in_lanes = True
                add_terms_lanes(cb, sums, t, win, flying)
        # nothing of the tick is left to do vehicle by vehicle (the common tick of a flight without a log)
        lanes_only = ready and not logged and not instant and (not truth or in_lanes)
        for i in range(0 if lanes_only else n):
            b = b0 + i
            if not alive[b]:
                continue
            pp_b, s_b = pp[b], S[b]
            up_now, down_now = pp_b.tau_up <= 0, pp_b.tau_down <= 0
            if not ready or logged:
                measurement_at(sb, i, Y[i])
            if not ready:  # a first sample fills the history: vehicle by vehicle
                controller_step(p[b], d[0], s_b, EH[b], Y[i], rc, o)
                put_command(buf, i, o.f_rotor, pp_b.n_rotors)
                put_held(buf, i, s_b.thrust_prev, s_b.tau_B_prev)
                put_command_held(eb, i, s_b.thrust_prev, s_b.tau_B_prev)
            elif (truth and not window_only) or up_now or down_now:  # the record the log and lagless rotors read
                get_output(cb, eb, i, rc, o)
            if window_only and not in_lanes:  # as _record without a log row: the tick is in the window
                e2, ev2, fe2, te2, sat = metric_terms_at(cb, i)
                add_terms(acc[b], t, win, e2, ev2, fe2, te2, sat)
            elif truth:
                obs, env = observed_at(buf, i)
                if logged:  # the log reads the rates and rotor forces of the record
                    get_state(buf, i, X[b])
                _record(k, t, pp_b, X[b], obs, env, refs[k], Y[i], o, logs[b], dec, acc[b], win)
            if up_now or down_now:  # as _instant_rotors, on the lane's rotors
                instant_rotors_lane(buf, i, up_now, down_now, o.f_rotor, pp_b.f_min, pp_b.f_max, pp_b.n_rotors)
        if not ready:
            ready = _put_lanes(eb, cb, b0, n, S, EH, p, head)
        for js in range(n_sub):
            if has_dists:
                for i in range(n):
                    b = b0 + i
                    if alive[b]:
                        disturbance_at(pp[b], state_view(buf, i), t + js * dt, dists, series, dist)
                        put_disturbance(buf, i, dist)
            if nr == 4 and plain:  # literals: the quadrotor's rotors unrolled, no pendulum or quadratic drag
                step_lanes(buf, 4, dt, False)
            elif nr == 4:
                step_lanes(buf, 4, dt, True)
            else:
                step_lanes(buf, nr, dt, True)
            if keep[js]:  # a state a sensor will read, into the rings' slot for this step
                keep_state(sb, buf, (head_s + js + 1) % H)
        head_s, count_s = (head_s + n_sub) % H, min(count_s + n_sub, H)  # the rings advanced by the period
        if nr == 4:
            failure_lanes(buf, 4)
        else:
            failure_lanes(buf, nr)
        for i in range(n):
            b = b0 + i
            code = failure_at(buf, i)
            if alive[b] and code != 0:
                alive[b] = False
                flying[i] = False
                fail_code[b] = code
                fail_time[b] = t + Ts
                X[b] = x_park[b]
                live -= 1
    for i in range(n):
        b = b0 + i
        for j in range(4):
            rng[j, b] = st[j, i]
        if in_lanes:
            get_sums(sums, i, acc[b])
        if alive[b]:
            get_state(buf, i, X[b])
            get_sensors(sb, i, hist[b])
            hhead[b], hcount[b] = head_s, count_s
            if ready:
                get_estimator(eb, i, S[b], EH[b], head)
                get_law_state(cb, i, S[b])


@kernel()
def _put_lanes(eb, cb, b0, n, S, EH, p, head):  # noqa: N803
    """Whether every estimator of the block ``b0 .. b0 + n - 1`` has started (the lanes past ``n`` repeat the
    first); if so the lanes take them (:func:`~.lanes_estimator.put_estimator`, the ring's newest slot ``head``)
    and what their control laws carry (:func:`~.lanes_controller.put_law_state`)."""
    for i in range(n):
        if not S[b0 + i].started:
            return False
    for i in range(W):
        b = b0 + (i if i < n else 0)
        put_estimator(eb, i, S[b], EH[b], head, p[b].mass, nominal_inertia(p[b]))
        put_law_state(cb, i, S[b])
    return True


@kernel(inline="always")
def _instant_rotors(pp_b, x, f_cmd):
    """A rotor follows its command at once in a direction without lag (``tau_up`` or ``tau_down`` zero)."""
    up_now, down_now = pp_b.tau_up <= 0, pp_b.tau_down <= 0
    if up_now or down_now:
        for i in range(pp_b.n_rotors):
            g = clip_command(f_cmd[i], pp_b.f_min[i], pp_b.f_max[i])
            x.f_rotor[i] = instant_force(up_now, down_now, g, x.f_rotor[i])


@kernel()
def control_ticks(k, Ts, XM, XI, X, A_O, W_DOT, ENV, sigma, rng, S, EH, p, d, pp, refs, alive, logs, dec, acc, win, F):
    """Control tick ``k`` of every live vehicle flown by another plant (MuJoCo, :mod:`vtol_impedance.sim.mjplant`),
    which gives the states ``X (B,)``, those the sensors read ``XM``, ``XI`` and the truth at the tick:
    ``A_O (B, 3)`` the body origin's acceleration (world), ``W_DOT (B, 3)`` (body), ``ENV (B, 6)`` the external
    wrench ``[f_ext_W, tau_ext_B]``. Writes the rotor commands to ``F (B, n)``; logs and metrics as
    :func:`run_block`."""
    o_ = _scratch()  # kept: the record below points into it
    o = o_[0]
    y, noise, rc = np.empty(12), np.empty(12), np.empty(18)
    truth = _truth_needed(k, k * Ts, dec, win)
    for b in range(X.shape[0]):
        if alive[b]:
            obs, env = _NO_OBS, _NO_ENV
            if truth:
                a_o = (A_O[b, 0], A_O[b, 1], A_O[b, 2])
                w_dot = (W_DOT[b, 0], W_DOT[b, 1], W_DOT[b, 2])
                obs = _observed(pp[b], p[b], S[b], X[b], a_o, w_dot)
                e = ENV[b]
                env = (e[0], e[1], e[2], e[3], e[4], e[5])
            _control_tick(k, k * Ts, pp[b], p[b], d[0], S[b], EH[b], XM[b], XI[b], X[b], obs, env, sigma, rng, b,
                          refs[k], logs[b], dec, acc[b], win, o, y, noise, rc)  # fmt: skip
            for i in range(F.shape[1]):
                F[b, i] = o.f_rotor[i]


@kernel()
def failure_codes(pp, X, alive, code):
    """Why each live vehicle of ``X (B,)`` must stop (0: it flies on), into ``code (B,)``: the check the
    engine makes after every period, for a plant stepped elsewhere (MuJoCo)."""
    for b in range(X.shape[0]):
        code[b] = _failure(pp[b], X[b]) if alive[b] else 0


@kernel()
def _scratch():
    """A zeroed output record (in an array of one)."""
    return np.zeros(1, dtype=OUTPUT)


@kernel()
def advance(pp, X, f_cmd, t0, n_sub, dt, dists, series):
    """Every vehicle's plant ``X (B,)`` over ``n_sub`` RK4 steps from ``t0`` with the rotor commands
    ``f_cmd (B, n)`` held (open loop: a replay, another simulator's controller)."""
    dist = np.empty(6)
    for b in range(X.shape[0]):
        for j in range(n_sub):
            disturbance_at(pp[b], X[b], t0 + j * dt, dists, series, dist)
            rk4_step(pp[b], X[b], f_cmd[b], dist, dt)
