"""``vtol-impedance bench``: speed of the compiled and NumPy backends, measured in one run.

Timings live here and never in a test assertion. Each batched size runs in a child process so that its
peak memory is its own; compile times are measured in child processes with a fresh numba cache.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from .io import write_text

SIZES = (1, 100, 1000, 10000)


def _child(code: str, env: dict[str, str] | None = None) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **(env or {})}, check=False
    )
    if out.returncode != 0:
        raise RuntimeError(f"benchmark child failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


_COMPILE = """
import json, time
t = time.perf_counter()
from vtol_impedance.scenarios import get, set_value, simulate
simulate(set_value(get("case-a-payload"), "duration", 0.05), ["pdc"])
print(json.dumps({"seconds": time.perf_counter() - t}))
"""

_BATCH = """
import json, resource, time
from vtol_impedance.scenarios import build, get
from vtol_impedance.scenarios.batch import population
from vtol_impedance.sim import run_closed_loop
spec = get("case-a-payload")
b = build(spec)
n, duration = {n}, {duration}
plants, ctrls, seeds = population(spec, n, seed=1)
# compile (or load) both engines before timing: 40 vehicles fly in lanes, fewer one per thread
for m in (2, 40):
    run_closed_loop(plants[:m], ctrls[:m], b.trajectory, 0.05, b.disturbances, b.sensors, seed=seeds[:m],
                    log="metrics")
wall = float("inf")
for _ in range(3 if n * duration < 2000 else 1):  # short runs: best of three
    t = time.perf_counter()
    r = run_closed_loop(plants, ctrls, b.trajectory, duration, b.disturbances, b.sensors, seed=seeds,
                        start_W=b.start_W, log="metrics")
    wall = min(wall, time.perf_counter() - t)
failed = sum(f is not None for f in r.failures)
print(json.dumps({{"n": n, "duration": duration, "wall": wall, "veh_s_per_s": n * duration / wall,
                  "failed": failed, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}}))
"""


_ROTORPY = """
import json, time
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.environments import Environment
from rotorpy.trajectories.hover_traj import HoverTraj
from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.vehicles.multirotor import Multirotor
env = Environment(vehicle=Multirotor(quad_params), controller=SE3Control(quad_params), trajectory=HoverTraj(),
                  sim_rate={rate})
env.run(t_final=0.1)
t = time.perf_counter()
env.run(t_final={duration})
wall = time.perf_counter() - t
print(json.dumps({{"sim_seconds": {duration}, "wall": wall, "real_time_factor": {duration} / wall,
                  "sim_rate_hz": {rate}}}))
"""


def _rotorpy(duration: float) -> dict[str, Any] | str:
    """RotorPy's single-vehicle hover (its default Crazyflie, SE(3) controller, 100 Hz steps), if installed."""
    try:
        import rotorpy  # noqa: F401
    except ImportError:
        return "not installed (pip install 'vtol-impedance[rotorpy]')"
    try:
        return _child(_ROTORPY.format(rate=100, duration=duration))
    except RuntimeError as exc:  # an API change in RotorPy must not sink our own numbers
        return f"failed: {str(exc)[-300:]}"


def _single(
    backend: str, duration: float | None, repeats: int | None = None, vehicles: int = 1, free: bool = False
) -> dict[str, float]:
    """Case C (realistic plant, PD+C) through ``simulate``, all of it timed (building, the flight, the result);
    ``duration=None``: the scenario's own (46 s), as the yardstick's comparison flies it. ``vehicles > 1``:
    that many copies in one batch; the real-time factor is then per vehicle (simulated vehicle-seconds per
    second). ``free``: in free flight (starting in the air, no ground)."""
    from .scenarios import get, set_value, simulate

    spec = get("case-c-circle") if duration is None else set_value(get("case-c-circle"), "duration", duration)
    if free:
        spec = set_value(set_value(spec, "trajectory.start_on_ground", False), "plant.ground", False)
    variants = ["pdc"] * vehicles
    simulate(set_value(spec, "duration", 0.05), variants, backend=backend)  # warm-up / compile
    wall = float("inf")
    for _ in range(repeats or (3 if backend == "compiled" else 1)):  # best of three where it is cheap
        t = time.perf_counter()
        r = simulate(spec, variants, backend=backend)
        wall = min(wall, time.perf_counter() - t)
    sim_s = float(r.t[-1] + (r.t[1] - r.t[0]))
    return {"sim_seconds": sim_s, "wall": wall, "real_time_factor": vehicles * sim_s / wall, "vehicles": vehicles}


def _mujoco(duration: float, vehicles: int = 1, free: bool = False) -> dict[str, float] | str:
    """The same flight on MuJoCo's physics (the compiled controller), if the extra is installed; with more
    vehicles, MuJoCo steps them in threads (one rollout per control period). ``free``: in free flight."""
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return "not installed (pip install 'vtol-impedance[mujoco]')"
    return _single("mujoco", duration, repeats=2, vehicles=vehicles, free=free)


def _latency(calls: int) -> dict[str, float]:
    import warnings

    from .control import ControllerParams, Measurement, Reference
    from .runtime import Controller, ControllerWarning

    ctrl = Controller(ControllerParams.paper("pdc"))
    rng = np.random.default_rng(0)
    y = np.concatenate([[0, 0, -1.0], np.zeros(9)]) + rng.normal(0, 1e-3, 12)
    r = np.array([0, 0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    warnings.simplefilter("ignore", ControllerWarning)  # random inputs saturate; only the time matters
    for _ in range(200):
        ctrl.step_arrays(y, r)
    ns = np.empty(calls)
    clock = time.perf_counter_ns
    for i in range(calls):
        t0 = clock()
        ctrl.step_arrays(y, r)
        ns[i] = clock() - t0
    # the same calls into a kernel that does nothing: what the call itself costs (the checks in Python,
    # the eight arguments handed to compiled code)
    step = ctrl._fast
    ctrl._fast = (ctrl._k.checked_step_entry(probe=True),) + step[1:]
    call = np.empty(calls)
    for i in range(calls):
        t0 = clock()
        ctrl.step_arrays(y, r)
        call[i] = clock() - t0
    ctrl._fast = step
    meas = Measurement(y[0:3], y[3:6], y[6:9], y[9:12])
    ref = Reference(r[0:3], r[3:6], r[6:9], np.array(0.0), np.array(0.0), np.array(0.0))
    slow = np.empty(min(calls, 2000))
    for i in range(len(slow)):
        t0 = clock()
        ctrl.step(meas, ref)
        slow[i] = clock() - t0
    return {
        "step_arrays_median_us": float(np.median(ns) / 1e3),
        "step_arrays_p99_us": float(np.percentile(ns, 99) / 1e3),
        "step_arrays_call_median_us": float(np.median(call) / 1e3),
        "step_median_us": float(np.median(slow) / 1e3),
    }


def _log_estimation(samples: int) -> dict[str, float]:
    """The compiled estimator over a synthetic log of ``samples`` samples at 100 Hz on one core (the loop
    that ``vtol-impedance estimate`` runs), and the NumPy/SciPy path on the same data."""
    from .compiled.estimator import run_log
    from .estimator.momentum import EstimatorParams, design
    from .estimator.series import causal, momentum_residual
    from .model.kinematics import euler_rate_matrix_Q

    rng = np.random.default_rng(0)
    t = np.arange(samples) * 0.01
    eta = np.stack([0.05 * np.sin(1.3 * t), 0.04 * np.sin(0.9 * t), 0.3 * np.sin(0.2 * t)], -1)
    omega = rng.normal(0, 0.05, (samples, 3))
    eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega[..., None])[..., 0]
    v = rng.normal(0, 0.1, (samples, 3))
    thrust = 11.8 + rng.normal(0, 0.1, samples)
    tau = rng.normal(0, 0.01, (samples, 3))
    inertia = np.diag([0.0135, 0.0137, 0.0247])
    restart = np.zeros(samples, bool)
    restart[0] = True
    des = design(EstimatorParams(), 0.01)
    run_log(des, 1.2, inertia, v[:100], eta[:100], eta_dot[:100], thrust[:100], tau[:100], restart[:100])
    wall = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        run_log(des, 1.2, inertia, v, eta, eta_dot, thrust, tau, restart)
        wall = min(wall, time.perf_counter() - t0)
    t0 = time.perf_counter()
    causal(des, momentum_residual(v, eta, eta_dot, thrust, tau, 1.2, inertia, 0.01), restart)
    wall_np = time.perf_counter() - t0
    return {"samples": samples, "wall": wall, "samples_per_s": samples / wall, "numpy_samples_per_s": samples / wall_np}


def _sweep(workers: int | None, quick: bool) -> dict[str, float] | str:
    """Flights per second of a sweep (study (a) cut down), in this process or on a LocalCluster."""
    from .sweeps import from_dict, run_sweep

    spec = {
        "name": "bench", "base": "case-b-fan", "controllers": ["pd", "pdc"], "seeds": 1, "seed": 1, "chunk": 4,
        "set": {"trajectory": {"hover_duration": 5.0 if quick else 15.0}},
        "axes": {"control.rate": [100, 200] if quick else [50, 100, 200, 500],
                 "control.estimator_wn": [5.0, 10.0] if quick else [2.0, 5.0, 10.0, 20.0]},
    }  # fmt: skip
    sweep = from_dict(spec)
    try:
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            run_sweep(sweep, Path(d) / "s", workers=workers, show_progress=False)
            wall = time.perf_counter() - t0
    except Exception as exc:  # a missing or broken Dask must not sink the other numbers
        return f"failed: {type(exc).__name__}: {str(exc)[:200]}"
    return {"flights": sweep.n_flights, "wall_including_startup": wall, "flights_per_s": sweep.n_flights / wall}


def _load_yardstick(path: Path) -> Any:
    """The hand-compiled loop of ``../shared/yardstick/numba_loop.py`` (or any file with its API)."""
    import importlib.util

    from .errors import InputError

    path = Path(path)
    if not path.is_file():
        raise InputError(f"--yardstick: no file {path} (the yardstick is numba_loop.py of the shared yardstick folder)")
    spec = importlib.util.spec_from_file_location("vtol_impedance_yardstick", path)
    try:
        if spec is None or spec.loader is None:
            raise ImportError("not a Python file")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.K, mod.MODE_PDC, mod.initial_state, mod.new_ctrl_state  # noqa: B018
    except Exception as exc:  # a foreign file: say so, do not show its traceback
        raise InputError(
            f"--yardstick {path}: not the yardstick's numba_loop.py ({type(exc).__name__}: {exc})"
        ) from None
    return mod


def _versus(path: Path, n: int, T: float, rounds: int, log=print, ys: Any = None) -> dict[str, Any]:
    """This project against the yardstick, in alternating rounds, best of each (the machine's speed drifts
    between minutes, so only ratios taken this way mean anything): one vehicle of case C (PD+C, this
    project's realistic plant against the yardstick's ideal one), a batch of ``n`` vehicles for ``T`` s
    (metrics only), and the controller + estimator step called from Python."""
    ys = _load_yardstick(path) if ys is None else ys
    K, mode = ys.K, ys.MODE_PDC
    K.sim_single(0.05, 0.11, True, mode, 0.0, 1e300)  # compile
    dms, res_b = np.full(n, 0.11), np.zeros((n, 13))
    K.sim_batch(dms[:16], 0.05, True, mode, 0.0, 1e300, res_b[:16])
    ys_single = ys_batch = our_single = our_batch = 0.0
    ours_b: dict[str, Any] = {}
    for r in range(rounds):
        log(f"yardstick round {r + 1}/{rounds} ...")
        for _ in range(3):
            t = time.perf_counter()
            K.sim_single(40.0, 0.11, True, mode, 0.0, 1e300)
            ys_single = max(ys_single, 40.0 / (time.perf_counter() - t))
        our_single = max(our_single, _single("compiled", None, repeats=3)["real_time_factor"])
        t = time.perf_counter()
        K.sim_batch(dms, T, True, mode, 0.0, 1e300, res_b)
        ys_batch = max(ys_batch, n * T / (time.perf_counter() - t))
        b = _child(_BATCH.format(n=n, duration=T))
        if b["veh_s_per_s"] > our_batch:
            our_batch, ours_b = b["veh_s_per_s"], b
    # the controller step from Python: the yardstick's kernel on its arrays, ours through step_arrays
    # and the same call into a kernel that does nothing (its call's cost: numba's dispatch on five arguments)
    from numba import njit

    x, cs = ys.initial_state(), ys.new_ctrl_state()
    clock = time.perf_counter_ns
    ns, call = np.empty(20000), np.empty(20000)
    for ctrl, times in ((ys.K.ctrl_step, ns), (njit(lambda x, cs, t, mode, circle: None), call)):
        for _ in range(200):
            ctrl(x, cs, 0.0, mode, True)
        for i in range(len(times)):
            t0 = clock()
            ctrl(x, cs, 0.01 * i, mode, True)
            times[i] = clock() - t0
    return {
        "yardstick": str(path), "n": n, "T": T, "rounds": rounds,
        "single_rtf": {"project": our_single, "yardstick": ys_single, "ratio": our_single / ys_single},
        "batch_veh_s_per_s": {"project": our_batch, "yardstick": ys_batch, "ratio": our_batch / ys_batch},
        "batch_peak_rss_mb": ours_b.get("peak_rss_mb", 0.0),
        "ctrl_step_from_python_us": {
            "yardstick_median": float(np.median(ns) / 1e3), "yardstick_call_median": float(np.median(call) / 1e3),
        },
    }  # fmt: skip


#: Where ``bench`` looks for the realistic-plant limit when not told (from the current directory): the
#: project's plant as hand-vectorised C, kept beside the project as a measuring stick (not shipped).
REALISTIC_DIR = Path("../shared/yardstick/realistic")

_LIMIT = """
import ctypes, json, time
import numpy as np
from vtol_impedance.scenarios import get
from vtol_impedance.scenarios.batch import population
from vtol_impedance.sim.plant import compile_plants, pack_plant
n, T, rounds = {n}, {T}, {rounds}
L = ctypes.CDLL({lib!r})
dp = ctypes.POINTER(ctypes.c_double)
L.rk4_soa_nopend.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_double, dp, dp, dp, dp]
plants, _, _ = population(get("case-a-payload"), n, seed=1)
pp = pack_plant(compile_plants(list(plants)))
# plant_soa.c's rows (its P_* enum); its one linear drag coefficient takes lin_drag_B[0] (no quadratic drag)
col = lambda a: np.asarray(a, float).reshape(n, -1)
P = np.ascontiguousarray(np.concatenate([col(pp["inv_mass"]), col(pp["I_com"]), col(pp["I_com_inv"]), col(pp["c_B"]),
    col(pp["r_contact_B"]), col(pp["inv_tau_up"]), col(pp["inv_tau_down"]), col(pp["lin_drag_B"][:, 0]),
    col(pp["ground"]), col(pp["k_ground"]), col(pp["c_ground"]), col(pp["b_ground"]), col(pp["pend_m"]),
    col(pp["pend_L"]), col(pp["E"][:, :, :4]), col(pp["f_min"][:, :4]), col(pp["f_max"][:, :4])], 1).T)
assert P.shape[0] == 58, P.shape
S0 = np.zeros((23, n)); S0[2] = -1.0; S0[6] = 1.0; S0[19:23] = 9.81 * pp["mass"] / 4  # hover at 1 m
FC, D = np.ascontiguousarray(S0[19:23].copy()), np.zeros((6, n))
ptr = lambda a: a.ctypes.data_as(dp)
best = float("inf")
for _ in range(rounds):
    S = S0.copy(); t = time.perf_counter()
    for _ in range(int(round(T / 0.01))):
        L.rk4_soa_nopend(n, 10, 1e-3, ptr(S), ptr(FC), ptr(D), ptr(P))
    best = min(best, time.perf_counter() - t)
print(json.dumps({{"veh_s_per_s": n * T / best, "finite": bool(np.isfinite(S).all())}}))
"""


def _realistic_limit(folder: Path, n: int, T: float, rounds: int, log=print) -> dict[str, Any] | str:
    """The whole closed loop of a batch of ``n`` case-A vehicles (two threads) against the plant alone as
    hand-vectorised C (``plant_soa.c`` of ``folder``, built here with OpenMP on two threads), in alternating
    rounds: ``ratio`` is the best of each, ``ratio_median`` the median of each round's pair (the C plant,
    then the batch, a minute apart: on a machine whose speed drifts between minutes the pairs drift less
    than the bests, which may come from different minutes); or why it was skipped (no folder, no C
    compiler, a failed build)."""
    import shutil

    src = Path(folder) / "plant_soa.c"
    if not src.is_file():
        return f"skipped: no {src} (give its folder with --realistic)"
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        return "skipped: no C compiler (gcc) on this machine"
    with tempfile.TemporaryDirectory() as tmp:
        lib = str(Path(tmp) / "libplant_simd_omp.so")
        cmd = [cc, "-O3", "-march=native", "-fno-math-errno", "-fPIC", "-shared", "-fopenmp", "-o", lib, str(src)]
        built = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if built.returncode != 0:
            return f"skipped: {src} did not build ({built.stderr.strip()[-300:]})"
        two = {"OMP_NUM_THREADS": "2", "NUMBA_NUM_THREADS": "2"}
        pairs = []
        for r in range(rounds):
            log(f"realistic limit round {r + 1}/{rounds}: plant_soa.c, then the batch ...")
            c = _child(_LIMIT.format(n=n, T=T, rounds=2, lib=lib), two)
            if not c["finite"]:
                return "skipped: the C plant diverged (its rows no longer match this project's plant records)"
            pairs.append((c["veh_s_per_s"], _child(_BATCH.format(n=n, duration=T), two)["veh_s_per_s"]))
    limit, ours = max(p[0] for p in pairs), max(p[1] for p in pairs)
    return {"n": n, "T": T, "threads": 2, "limit_veh_s_per_s": limit, "project_veh_s_per_s": ours,
            "ratio": ours / limit, "ratio_median": statistics.median(b / c for c, b in pairs),
            "rounds": [{"limit_veh_s_per_s": c, "project_veh_s_per_s": b} for c, b in pairs],
            "source": str(src)}  # fmt: skip


def _writable_report(out: Path) -> Path:
    """``out`` as a path where the JSON report can be written, or :class:`InputError` saying why not."""
    from .errors import InputError
    from .io import check_output_file

    try:
        return check_output_file(out)
    except InputError as exc:
        raise InputError(f"--out {out}: {exc} (give the path of the JSON report)") from None


def run(
    out: Path,
    quick: bool = False,
    log=print,
    compile_times: bool = True,
    yardstick: Path | None = None,
    realistic: Path | None = None,
) -> dict[str, Any]:
    """Measure everything, print a table, write JSON to ``out``; returns the numbers.

    ``compile_times=False`` skips the two cold/cached compile measurements (the cold one takes up to a minute);
    ``yardstick``: the path of the shared yardstick's ``numba_loop.py``, timed against this project in the same
    run (:func:`_versus`); ``realistic``: the folder of the realistic-plant limit (``plant_soa.c``; default
    :data:`REALISTIC_DIR`), against which a 4,000-vehicle batch is measured (:func:`_realistic_limit`).
    """
    # what can be refused is refused before minutes of measuring: the report's file and the yardstick
    out = _writable_report(out)
    ys = _load_yardstick(yardstick) if yardstick is not None else None
    res: dict[str, Any] = {
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "processor": platform.processor()},
        "quick": quick,
        "compile_first_s": None,
        "compile_cached_s": None,
    }
    if compile_times:
        with tempfile.TemporaryDirectory() as cache:
            env = {"NUMBA_CACHE_DIR": cache}
            log("compile: first use (empty cache) ...")
            res["compile_first_s"] = _child(_COMPILE, env)["seconds"]
            log("compile: second use (cached) ...")
            res["compile_cached_s"] = _child(_COMPILE, env)["seconds"]
    # the batched children first: a child's peak memory (ru_maxrss) starts from this process's at fork
    res["batched"] = []
    sizes = (1, 10) if quick else SIZES
    for n in sizes:
        duration = 0.5 if quick else 40.0
        log(f"batched N = {n} x {duration:g} s (metrics only) ...")
        res["batched"].append(_child(_BATCH.format(n=n, duration=duration)))
    first, last = res["batched"][0], res["batched"][-1]
    # what one more vehicle costs: the largest batch's peak over the smallest's (the interpreter, NumPy and
    # the compiled kernels are in both)
    res["memory_kb_per_vehicle"] = (last["peak_rss_mb"] - first["peak_rss_mb"]) * 1024 / max(last["n"] - first["n"], 1)
    log("single vehicle, case C realistic, PD+C ...")
    res["single_compiled"] = _single("compiled", 5.0 if quick else 46.0)
    res["single_numpy"] = _single("numpy", 1.0 if quick else 5.0)
    res["single_mujoco"] = _mujoco(1.0 if quick else 5.0)
    res["batch_mujoco"] = _mujoco(1.0 if quick else 5.0, vehicles=2 if quick else 8)
    res["free_flight_mujoco"] = _mujoco(1.0 if quick else 5.0, free=True)
    log("controller + estimator step latency ...")
    res["latency"] = _latency(2000 if quick else 50000)
    log("wrench estimation on a flight log ...")
    res["log_estimation"] = _log_estimation(100_000 if quick else 2_000_000)
    log("sweep in this process and on a 2-worker LocalCluster ...")
    res["sweep_in_process"] = _sweep(None, quick)
    res["sweep_local_cluster_2"] = _sweep(2, quick)
    if quick and realistic is None:
        res["realistic_limit"] = "skipped: --quick (give --realistic DIR to measure it)"
    else:
        log("the batch against the realistic-plant limit (hand-vectorised C) ...")
        res["realistic_limit"] = _realistic_limit(
            REALISTIC_DIR if realistic is None else realistic, 400 if quick else 4000, 1.0 if quick else 10.0,
            1 if quick else 2, log,
        )  # fmt: skip
    log("RotorPy single-vehicle hover (if installed) ...")
    res["rotorpy"] = _rotorpy(2.0 if quick else 10.0)
    if yardstick is not None:
        res["versus"] = _versus(yardstick, 1000 if quick else 10000, 2.0 if quick else 20.0, 1 if quick else 3, log, ys)
        res["versus"]["ctrl_step_from_python_us"]["project_step_arrays_median"] = res["latency"][
            "step_arrays_median_us"
        ]
    write_text(out, json.dumps(res, indent=1))
    return res


def table(res: dict[str, Any]) -> str:
    sc, sn = res["single_compiled"], res["single_numpy"]
    lat = res["latency"]
    lines = [
        "what                                             value",
        "-----------------------------------------------  ----------------",
        f"single vehicle, case C realistic, compiled       {sc['real_time_factor']:10.0f} x real time",
        f"single vehicle, case C realistic, NumPy ref.     {sn['real_time_factor']:10.2f} x real time",
    ]
    smj, bmj = res.get("single_mujoco"), res.get("batch_mujoco")
    if isinstance(smj, dict):
        lines.append(f"single vehicle, case C realistic, MuJoCo plant   {smj['real_time_factor']:10.2f} x real time")
    elif smj:
        lines.append(f"MuJoCo plant                                     {smj}")
    if isinstance(bmj, dict):
        what = f"{bmj['vehicles']:d} vehicles on MuJoCo (threads), per vehicle"
        lines.append(f"{what:<49}{bmj['real_time_factor']:10.2f} x real time")
    fmj = res.get("free_flight_mujoco")
    if isinstance(fmj, dict):
        lines.append(f"single vehicle on MuJoCo, free flight (no ground) {fmj['real_time_factor']:9.2f} x real time")
    lines += [
        f"step_arrays latency, median / p99                {lat['step_arrays_median_us']:6.2f} / "
        f"{lat['step_arrays_p99_us']:.2f} us",
    ]
    if "step_arrays_call_median_us" in lat:
        lines.append(
            f"  of which the call (checks, 8 arguments)        {lat['step_arrays_call_median_us']:8.2f} us "
            "(a kernel doing nothing)"
        )
    lines.append(f"step (NamedTuple API) latency, median            {lat['step_median_us']:10.2f} us")
    for key, what in (("sweep_in_process", "in this process"), ("sweep_local_cluster_2", "LocalCluster, 2 workers")):
        sw = res.get(key)
        if isinstance(sw, dict):
            lines.append(f"sweep flights/s, {what:<24}{sw['flights_per_s']:10.1f} (incl. start-up)")
        elif sw:
            lines.append(f"sweep, {what}: {sw}")
    le = res.get("log_estimation")
    if le:
        lines.append(f"log estimation, compiled, one core               {le['samples_per_s'] / 1e6:10.2f} M samples/s")
        lines.append(
            f"log estimation, NumPy/SciPy                      {le['numpy_samples_per_s'] / 1e6:10.2f} M samples/s"
        )
    if res["compile_first_s"] is not None:
        lines.append(
            f"compile, first use / cached                      {res['compile_first_s']:6.1f} / "
            f"{res['compile_cached_s']:.1f} s"
        )
    else:
        lines.append("compile, first use / cached                      not measured (--quick)")
    if "memory_kb_per_vehicle" in res:
        lines.append(f"memory per added vehicle (batched runs)          {res['memory_kb_per_vehicle']:10.1f} kB")
    for b in res["batched"]:
        lines.append(
            f"batched N = {b['n']:<6d} ({b['duration']:g} s each)           {b['veh_s_per_s']:10.0f} veh-s/s, "
            f"peak {b['peak_rss_mb']:.0f} MB"
        )
    vs = res.get("versus")
    if vs:
        a, b = vs["single_rtf"], vs["batch_veh_s_per_s"]
        lines += [
            f"vs yardstick: one vehicle, real-time factor      {a['project']:8.0f} / {a['yardstick']:.0f}  "
            f"ratio {a['ratio']:.2f}",
            f"vs yardstick: batch {vs['n']} x {vs['T']:g} s, veh-s/s   {b['project']:8.0f} / {b['yardstick']:.0f}  "
            f"ratio {b['ratio']:.2f}",
            f"vs yardstick: controller step from Python        {lat['step_arrays_median_us']:8.2f} / "
            f"{vs['ctrl_step_from_python_us']['yardstick_median']:.2f} us",
        ]
        ys_call = vs["ctrl_step_from_python_us"].get("yardstick_call_median")
        if ys_call is not None and "step_arrays_call_median_us" in lat:
            ours = lat["step_arrays_median_us"] - lat["step_arrays_call_median_us"]
            theirs = vs["ctrl_step_from_python_us"]["yardstick_median"] - ys_call
            lines.append(f"vs yardstick: the same, less each one's call     {ours:8.2f} / {theirs:.2f} us")
    rl = res.get("realistic_limit")
    if isinstance(rl, dict):
        what = f"batch {rl['n']} x {rl['T']:g} s, 2 threads / C plant alone"
        speeds = f"{rl['project_veh_s_per_s']:8.0f} / {rl['limit_veh_s_per_s']:.0f} veh-s/s"
        lines.append(f"{what:<49}{speeds}  ratio {rl['ratio']:.2f}")
        if "ratio_median" in rl:
            each = ", ".join(f"{r['project_veh_s_per_s'] / r['limit_veh_s_per_s']:.2f}" for r in rl["rounds"])
            lines.append(f"  the same, each round's pair (median {rl['ratio_median']:.2f}): {each}")
    elif rl:
        lines.append(f"realistic-plant limit                            {rl}")
    rp = res["rotorpy"]
    if isinstance(rp, dict):
        lines.append(f"RotorPy single vehicle, hover, 100 Hz steps       {rp['real_time_factor']:10.2f} x real time")
        lines.append("RotorPy batched                                  needs rotorpy[batched] (torch): not measured")
    else:
        lines.append(f"RotorPy                                          {rp}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- the live path's accuracy

#: The payload of the live accuracy measurement: its weight, N, downward (NED +z) from the start.
LIVE_PAYLOAD_N = 1.0
#: Seconds after the estimator's start left out of the statistics (its settling: 0.5 s at wn = 10 rad/s).
LIVE_SETTLE_S = 2.0
#: Longest set-up (s) of a ``bench --live`` session before its estimate starts: the session ends when the
#: estimate has its seconds, or after this much longer.
LIVE_SETUP_MAX_S = 60.0
#: The estimator's rate in ``bench --live`` (the default of ``live``), Hz.
RATE_HZ = 50.0


def _wrench_stats(t: np.ndarray, f_W: np.ndarray, truth_W: np.ndarray, t_from: float) -> dict[str, Any]:
    """Per world axis: the mean error (signed, N) and the 95th percentile of the absolute error (N) of the
    estimate ``f_W`` (rows at times ``t``, s) against ``truth_W`` over ``t >= t_from``."""
    sel = t >= t_from
    err = f_W[sel] - truth_W
    return {"samples": int(sel.sum()), "seconds": float(t[sel][-1] - t[sel][0]) if sel.any() else 0.0,
            "mean_error_N": err.mean(0).tolist(), "p95_abs_error_N": np.percentile(np.abs(err), 95, axis=0).tolist(),
            "mean_N": f_W[sel].mean(0).tolist()}  # fmt: skip


def _live_case(autopilot: str, seconds: float, log=print) -> dict[str, Any]:
    """One personality of the simulated autopilot (``sim-autopilot case-a-payload --set payload.mass=0
    --inject-force 0,0,1``: case A's vehicle, sensors and rotors, the payload's weight as a constant
    downward force the autopilot did not learn into its hover thrust) flown in a thread for ``seconds`` of
    estimate of ``live`` over UDP loopback (after its set-up); then ``estimate`` on the recorded
    ``flight.tlog``. Returns both statistics."""
    import contextlib
    import socket
    import threading

    from .live import LiveSettings, run_live
    from .live.autopilot import SimAutopilot, SimSettings
    from .scenarios import apply_overrides, get

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    truth = np.array([0.0, 0.0, LIVE_PAYLOAD_N])
    spec = apply_overrides(get("case-a-payload"), ["payload.mass=0"])
    sim = SimAutopilot(spec, SimSettings(f"udpout:127.0.0.1:{port}", autopilot=autopilot, inject_force_W=tuple(truth)))
    ready = threading.Event()
    th = threading.Thread(target=sim.run, kwargs={"ready": ready}, daemon=True)
    th.start()
    ready.wait(10)
    with tempfile.TemporaryDirectory() as d:
        stop = threading.Event()
        rows = int(seconds * RATE_HZ)

        def enough() -> None:
            # the session's set-up (heartbeats, stream requests, the probe) takes a few seconds, more on a loaded
            # machine: stop once the estimate (written as it runs, in the run folder's staging copy) has its rows
            while not stop.wait(0.5):
                for f in Path(d).glob(".run.staging-*/estimate.csv"):
                    with contextlib.suppress(OSError):
                        if f.stat().st_size > 0 and sum(1 for _ in f.open("rb")) > rows:
                            stop.set()

        watcher = threading.Thread(target=enough, daemon=True)
        watcher.start()
        try:
            settings = LiveSettings(f"udpin:127.0.0.1:{port}", duration=seconds + LIVE_SETUP_MAX_S,
                                    out=str(Path(d) / "run"), display="none", connect_timeout_s=20.0)  # fmt: skip
            res = run_live(settings, stop=stop)
        finally:
            stop.set()
            watcher.join(5)
            sim.stop()
            th.join(10)
        est = np.genfromtxt(res.folder / "estimate.csv", delimiter=",", names=True)
        t = est["t_s"]
        f = np.stack([est["fx_W_N"], est["fy_W_N"], est["fz_W_N"]], -1)
        out: dict[str, Any] = {"autopilot": autopilot, "sources": res.summary["estimator"]["sources"],
                               "thrust_map": res.summary["estimator"]["thrust_map"], "end": res.end,
                               "live": _wrench_stats(t, f, truth, t[0] + LIVE_SETTLE_S),
                               "events": [e["text"] for e in res.summary["events"]]}  # fmt: skip
        log(f"  {autopilot}: re-estimating the recorded flight.tlog ...")
        from .errors import InputError
        from .logs import estimate_file
        from .model import load_preset

        try:  # what `vtol-impedance estimate flight.tlog --vehicle pelican` computes
            logged = estimate_file(res.folder / "flight.tlog", vehicle=load_preset("pelican"))
        except InputError as exc:
            out["tlog"] = f"estimate failed: {exc}"
        else:
            out["tlog"] = _wrench_stats(logged.t, logged.f_W, truth, logged.t[0] + LIVE_SETTLE_S)
            # the log reader chooses its own thrust source: say which
            chose = [c for c in logged.info.get("choices", []) if c.startswith("thrust: ") and " at " in c]
            out["tlog"]["thrust_from"] = chose[0][len("thrust: ") :].split(" at ")[0] if chose else "?"
    return out


def live_accuracy(out: Path, seconds: float = 20.0, log=print) -> dict[str, Any]:
    """``bench --live``: the estimate's accuracy along the live path, per autopilot personality of the
    simulated autopilot, for a 1.0 N payload (:func:`_live_case`); written as JSON to ``out``.

    A measurement, not a test: the numbers depend on the scenario's sensor noise and on the link's timing on
    this machine (the estimator runs on the vehicle's clock, so load shows only as lost samples)."""
    from .errors import scalar

    out = _writable_report(out)
    seconds = scalar("--live-seconds", seconds, lo=5.0, hi=3600.0)
    machine = {"python": platform.python_version(), "cpus": os.cpu_count()}
    res: dict[str, Any] = {"payload_N": LIVE_PAYLOAD_N, "seconds": seconds, "settle_s": LIVE_SETTLE_S,
                           "machine": machine, "cases": []}  # fmt: skip
    for autopilot in ("px4", "ardupilot"):
        log(f"live accuracy: simulated {autopilot}, {seconds:g} s with a {LIVE_PAYLOAD_N:g} N payload ...")
        res["cases"].append(_live_case(autopilot, seconds, log))
    write_text(out, json.dumps(res, indent=1))
    return res


def live_table(res: dict[str, Any]) -> str:
    """The table ``bench --live`` prints: per personality and path, mean error and p95 |error| per axis (N)."""
    lines = [
        f"live-path accuracy, {res['payload_N']:g} N payload (truth f_W = [0, 0, +{res['payload_N']:g}] N, NED), "
        f"after {res['settle_s']:g} s of settling",
        "autopilot  path   thrust from                  over    mean error x / y / z (N)    p95 |error| x / y / z (N)",
        "---------  -----  ---------------------------  ------  --------------------------  --------------------------",
    ]
    for c in res["cases"]:
        src = c["sources"]
        for path in ("live", "tlog"):
            s = c.get(path)
            if isinstance(s, dict):
                thrust = src.get("rpm") or src.get("outputs") or src.get("thrust", "?")
                thrust = s.get("thrust_from", thrust)
                if "thrust curve" in thrust:  # the tlog reader names every channel
                    thrust = thrust.split(".")[0] + " (curve)"
                m, p = s["mean_error_N"], s["p95_abs_error_N"]
                head = f"{c['autopilot']:<9}  {path:<5}  {thrust:<27}  {s['seconds']:5.1f}s"
                lines.append(f"{head}  {m[0]:+8.4f} {m[1]:+8.4f} {m[2]:+8.4f}  {p[0]:8.4f} {p[1]:8.4f} {p[2]:8.4f}")
            else:
                lines.append(f"{c['autopilot']:<9}  {path:<5}  {s}")
    return "\n".join(lines)
