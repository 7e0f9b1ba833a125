"""Every public callable refuses bad arguments at its entry, with an error of the package that names the argument.

Generated from the API reference (:func:`test_docs_api.public_names`): each callable has a row in ``TABLE``
(valid baseline arguments and, for the arguments that can be made bad, the kind of value they take) or a
reason in ``EXEMPT``. For every argument of a row, the test substitutes the bad values of its kind (a wrong
type, a wrong shape, NaN, +-inf, a negative or zero value where physics forbids it) into otherwise valid
arguments and expects a :class:`~vtol_impedance.errors.VtolImpedanceError` (``InputError`` and its family)
whose message names the argument: never an ``AttributeError``, ``TypeError``, ``IndexError`` or a NumPy
``ValueError`` from inside, never a silent result. A new public callable with neither fails the test.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_docs_api import PACKAGES, public_names

from vtol_impedance import control, estimator, live, logs, model, robust, scenarios, sim, sweeps, tunepage
from vtol_impedance.control.reference import Trajectory
from vtol_impedance.errors import VtolImpedanceError

NAN, INF = math.nan, math.inf


class Arr:
    """An array argument with trailing shape ``tail`` (batched: leading dimensions free)."""

    def __init__(self, tail: tuple[int, ...], positive: bool = False) -> None:
        self.tail, self.positive = tail, positive


class Obj:
    """An argument that must be an instance of a class."""

    def __init__(self, cls: type) -> None:
        self.cls = cls


def bad_values(kind: Any, good: Any) -> list[Any]:
    """The bad values for an argument of ``kind`` whose valid value is ``good``."""
    if isinstance(kind, Obj):
        return ["abc", 12345]
    if isinstance(kind, Arr):
        g = np.array(good, dtype=float)
        wrong = np.zeros(g.shape[:-1] + (g.shape[-1] + 1,)) if g.ndim else np.zeros(2)
        out: list[Any] = ["abc", wrong]
        for v in (NAN, INF, -INF):
            b = g.copy()
            b.reshape(-1)[0] = v
            out.append(b)
        if kind.positive:
            b = g.copy()
            b.reshape(-1)[0] = -1.0
            out.append(b)
        return out
    common = {
        "real": ["abc", [1.0, 2.0], NAN, INF, -INF],
        "nonneg": ["abc", [1.0, 2.0], NAN, INF, -1.0],
        "pos": ["abc", [1.0, 2.0], NAN, INF, -INF, -1.0, 0.0],
        "batch": ["abc", None],  # real numbers of any batch shape (a mass, a thrust in the batched math)
        "posany": ["abc", NAN, INF, -1.0, 0.0],  # numbers > 0 of any shape
        "count": ["abc", 1.5, NAN, 0, -1],  # a whole number >= 1
        "index": ["abc", 1.5, NAN, -1],  # a whole number >= 0
        "vec3": ["abc", [1.0, 2.0], [NAN, 0.0, 0.0], [INF, 0.0, 0.0]],
        "vec3pos": ["abc", [1.0, 2.0], [NAN, 1.0, 1.0], [INF, 1.0, 1.0], [-1.0, 1.0, 1.0], [0.0, 1.0, 1.0]],
        "gain": ["abc", [16.0, 16.0], NAN, INF, -1.0, 0.0],  # one or three positive numbers
        "gain0": ["abc", [16.0, 16.0], NAN, INF, -1.0],  # one or three numbers >= 0
        "choice": [123, "no-such-choice"],
        "text": [123, 1.5],
        "path": [12345, 1.5],
        "func": ["abc", 12345],
        "mapping": ["abc", 12345],
    }
    return common[kind]


# --- valid objects the rows share (built once, small) ----------------------------------------------------


@functools.cache
def vehicle() -> model.VehicleParams:
    return model.load_preset("pelican")


@functools.cache
def spec() -> scenarios.ScenarioSpec:
    return scenarios.get("case-a-payload-v1")


@functools.cache
def cparams() -> control.ControllerParams:
    return scenarios.controller_params(spec(), "pdc")


@functools.cache
def carrays() -> control.ControllerArrays:
    return control.compile_controllers(cparams())


@functools.cache
def pparams() -> sim.PlantParams:
    return sim.PlantParams(vehicle())


@functools.cache
def parrays():
    return sim.compile_plants(pparams())


@functools.cache
def est_design() -> estimator.EstimatorDesign:
    return estimator.design(estimator.EstimatorParams(), 0.01)


@functools.cache
def lin() -> robust.LinearLoop:
    return robust.linearize(cparams(), pparams())


@functools.cache
def raw() -> logs.RawLog:
    """Two seconds of a level hover at 50 Hz."""
    t = np.arange(0.0, 2.0, 0.02)
    z3 = np.zeros((t.size, 3))
    thrust = np.full((t.size, 1), vehicle().mass * 9.81)
    return logs.RawLog(
        velocity_W=logs.Signal("velocity", "test", t, z3),
        attitude=logs.Signal("attitude", "test", t, z3),
        omega_B=logs.Signal("omega", "test", t, z3),
        thrust=logs.Signal("thrust", "test", t, thrust, hold=True),
        torque_B=logs.Signal("torque", "test", t, z3, hold=True),
    )


@functools.cache
def flight() -> logs.FlightLog:
    return logs.resample(raw(), 50.0)


@functools.cache
def csv_file() -> Path:
    return Path(importlib.import_module("vtol_impedance.logs.samples").__file__).parent / "flight.csv"


@functools.cache
def sweep() -> sweeps.Sweep:
    return sweeps.load("payload-vs-offset")


@functools.cache
def thrust_map() -> live.ThrustMap:
    return live.ThrustMap(mass=vehicle().mass, hover=0.5)


@functools.cache
def plant_x() -> np.ndarray:
    return importlib.import_module("vtol_impedance.sim.plant").initial_state(parrays(), np.array([0.0, 0.0, -1.0]))


@functools.cache
def result() -> sim.Result:
    t = np.arange(0.0, 1.0, 0.1)
    return sim.Result(t=t, labels=["pdc"], data={"e_p": np.zeros((1, t.size, 3))}, config={"window": (0.0, 1.0)})


def z3(*batch: int) -> np.ndarray:
    return np.zeros((*batch, 3))


def eye3() -> np.ndarray:
    return np.diag([0.0034, 0.0034, 0.0047])


# --- the table: name -> (valid keyword arguments, {argument: kind}) --------------------------------------

VP, CP, PP, CA = (
    Obj(model.VehicleParams),
    Obj(control.ControllerParams),
    Obj(sim.PlantParams),
    Obj(control.ControllerArrays),
)
A3, A33 = Arr((3,)), Arr((3, 3))

TABLE: dict[str, tuple[Any, dict[str, Any]]] = {
    # model
    "model.Rotor": (
        lambda: dict(position_B=(0.2, 0.0, 0.0), spin=1),
        {"position_B": "vec3", "f_max": "pos", "spin": "choice"},
    ),
    "model.drag_factor_from_constants": (
        lambda: dict(torque_constant=1e-7, thrust_constant=6e-6),
        {"torque_constant": "pos", "thrust_constant": "pos"},
    ),
    "model.effectiveness": (
        lambda: dict(
            positions_B=model.layout_positions("x", 0.2)[0],
            spins=model.layout_positions("x", 0.2)[1],
            drag_factor=0.016,
        ),
        {"positions_B": Arr((4, 3)), "drag_factor": "pos"},
    ),
    "model.f_max_from_motor": (
        lambda: dict(thrust_constant=6e-6, max_speed=1000.0),
        {"thrust_constant": "pos", "max_speed": "pos"},
    ),
    "model.linear_drag_from_rotor_speed": (
        lambda: dict(coefficient=1.2e-4, hover_speed=470.0, n_rotors=4),
        {"coefficient": "nonneg", "hover_speed": "pos", "n_rotors": "count"},
    ),
    "model.inflow_damping_from_momentum": (
        lambda: dict(hover_thrust=2.9, rotor_radius=0.127, tip_speed=66.0, solidity=0.1),
        {
            "hover_thrust": "pos",
            "rotor_radius": "pos",
            "tip_speed": "pos",
            "solidity": "pos",
            "lift_slope": "pos",
            "n_rotors": "count",
            "air_density": "pos",
        },
    ),
    "model.layout_positions": (lambda: dict(layout="x", arm_length=0.2), {"layout": "choice", "arm_length": "pos"}),
    "model.vehicle_from_dict": (lambda: dict(data={"mass": 1.0, "inertia": [0.01, 0.01, 0.02]}), {"data": "mapping"}),
    "model.VehicleParams": (
        lambda: dict(mass=1.2, inertia=eye3(), arm_length=0.21),
        {
            "mass": "pos",
            "inertia": A33,
            "arm_length": "pos",
            "drag_factor": "pos",
            "inflow_damping": "nonneg",
            "body_drag": "gain0",
        },
    ),
    "model.allocate": (
        lambda: dict(
            thrust=np.array(11.0),
            tau_B=z3(),
            E=vehicle().geometry.E,
            E_pinv=vehicle().geometry.E_pinv,
            f_min=vehicle().geometry.f_min,
            f_max=vehicle().geometry.f_max,
        ),
        {"tau_B": A3, "E": Arr((4, 4)), "thrust_shift_max": "nonneg"},
    ),
    "model.body_moment_from_euler": (lambda: dict(tau_eta=z3(), eta=z3()), {"tau_eta": A3, "eta": A3}),
    "model.coriolis_matrix_C": (
        lambda: dict(eta=z3(), eta_dot=z3(), I_B=eye3()),
        {"eta": A3, "eta_dot": A3, "I_B": A33},
    ),
    "model.euler_moment_from_body": (lambda: dict(tau_B=z3(), eta=z3()), {"tau_B": A3, "eta": A3}),
    "model.euler_rate_matrix_Q": (lambda: dict(eta=z3()), {"eta": A3}),
    "model.euler_rate_matrix_Q_dot": (lambda: dict(eta=z3(), eta_dot=z3()), {"eta": A3, "eta_dot": A3}),
    "model.euler_rate_matrix_T": (lambda: dict(eta=z3()), {"eta": A3}),
    "model.generalized_momentum": (
        lambda: dict(v_W=z3(), eta=z3(), eta_dot=z3(), mass=np.array(1.2), I_B=eye3()),
        {"v_W": A3, "eta": A3, "eta_dot": A3, "mass": "batch", "I_B": A33},
    ),
    "model.inertia_matrix_M": (lambda: dict(eta=z3(), I_B=eye3()), {"eta": A3, "I_B": A33}),
    "model.load_preset": (lambda: dict(name="pelican"), {"name": "choice"}),
    "model.mix": (lambda: dict(f=np.full(4, 3.0), E=vehicle().geometry.E), {"f": Arr((4,)), "E": Arr((4, 4))}),
    "model.momentum_rate_known": (
        lambda: dict(eta=z3(), eta_dot=z3(), thrust=np.array(11.0), tau_B=z3(), mass=np.array(1.2), I_B=eye3()),
        {"eta": A3, "eta_dot": A3, "thrust": "batch", "tau_B": A3, "mass": "batch", "I_B": A33},
    ),
    "model.rotation_zyx": (lambda: dict(eta=z3()), {"eta": A3}),
    "model.skew": (lambda: dict(v=z3()), {"v": A3}),
    "model.unmix": (
        lambda: dict(thrust=np.array(11.0), tau_B=z3(), E_pinv=vehicle().geometry.E_pinv),
        {"tau_B": A3, "E_pinv": Arr((4, 4))},
    ),
    # estimator
    "estimator.EstimatorParams": (
        lambda: dict(),
        {"wn": "gain", "zeta": "gain", "order": "count", "prototype": "choice", "rotor_tau": "nonneg"},
    ),
    "estimator.design": (
        lambda: dict(params=estimator.EstimatorParams(), Ts=0.01),
        {"params": Obj(estimator.EstimatorParams), "Ts": "pos"},
    ),
    "estimator.estimator_step": (
        lambda: dict(
            des=est_design(),
            state=estimator.initial_state(est_design()),
            eta=z3(),
            eta_dot=z3(),
            v_W=z3(),
            thrust_prev=np.array(11.0),
            tau_B_prev=z3(),
            mass=np.array(1.2),
            I_B=eye3(),
        ),
        {
            "des": Obj(estimator.EstimatorDesign),
            "state": Obj(estimator.EstimatorState),
            "eta": A3,
            "v_W": A3,
            "mass": "batch",
        },
    ),
    "estimator.initial_state": (
        lambda: dict(des=est_design()),
        {"des": Obj(estimator.EstimatorDesign), "batch_shape": "mapping"},
    ),
    # control
    "control.ControllerParams": (
        lambda: dict(vehicle=vehicle(), gains=control.ImpedanceGains(16.0, 12.0, 100.0, 20.0)),
        {
            "vehicle": VP,
            "gains": Obj(control.ImpedanceGains),
            "variant": "choice",
            "Ts": "pos",
            "tilt_max": "pos",
            "estimator": Obj(estimator.EstimatorParams),
            "integral_limit": "nonneg",
        },
    ),
    "control.Impedance": (lambda: dict(M=2.0, D=6.0, K=5.0), {"M": "gain", "D": "gain0", "K": "gain0"}),
    "control.ImpedanceGains": (
        lambda: dict(Kp=16.0, Dp=12.0, Ko=100.0, Do=20.0),
        {"Kp": "gain", "Dp": "gain", "Ko": "gain", "Do": "gain", "Ki": "gain0"},
    ),
    "control.Measurement": (lambda: dict(p_W=z3(), v_W=z3(), eta=z3()), {"p_W": A3, "v_W": A3, "eta": A3}),
    "control.Reference": (lambda: dict(p_W=z3()), {"p_W": A3, "v_W": A3, "a_W": A3, "psi": "batch"}),
    "control.acceleration_from_thrust": (
        lambda: dict(thrust=np.array(11.0), eta=z3(), mass=np.array(1.2)),
        {"eta": A3, "mass": "batch", "thrust": "batch"},
    ),
    "control.compile_controllers": (lambda: dict(params=cparams()), {"params": CP}),
    "control.controller_step": (
        lambda: dict(
            P=carrays(),
            S=control.initial_controller_state(carrays()),
            meas=control.Measurement(z3(), z3(), z3(), eta_dot=z3()),
            ref=control.Reference(np.array([0.0, 0.0, -1.0])),
        ),
        {"P": CA, "S": Obj(control.ControllerState), "meas": Obj(control.Measurement), "ref": Obj(control.Reference)},
    ),
    "control.initial_controller_state": (lambda: dict(P=carrays()), {"P": CA}),
    "control.thrust_and_attitude": (
        lambda: dict(mu_bar=np.array([0.0, 0.0, -9.81]), psi_d=np.array(0.0), mass=np.array(1.2)),
        {"mu_bar": A3, "psi_d": "batch", "mass": "batch", "tilt_max": "batch"},
    ),
    # runtime
    "runtime.Controller": (lambda: dict(params=cparams(), backend="numpy"), {"params": CP, "backend": "choice"}),
    "runtime.Estimator": (
        lambda: dict(mass=1.2, inertia_B=eye3(), Ts=0.01, backend="numpy"),
        {"mass": "pos", "inertia_B": A33, "Ts": "pos", "params": Obj(estimator.EstimatorParams), "backend": "choice"},
    ),
    # records
    "records.signal_shape": (lambda: dict(name="p_W", n_rotors=4), {"name": "choice", "n_rotors": "count"}),
    "records.empty_log": (lambda: dict(batch=1, samples=2), {"batch": "count", "samples": "index"}),
    "records.rows_to_data": (
        lambda: dict(rows=importlib.import_module("vtol_impedance.records").empty_log(1, 2), n_rotors=4),
        {"rows": "mapping", "n_rotors": "count"},
    ),
    # sim
    "sim.BandLimitedNoise": (
        lambda: dict(),
        {"force_rms_W": "vec3", "torque_rms_B": "vec3", "f_lo": "pos", "f_hi": "pos"},
    ),
    "sim.ConstantWrench": (lambda: dict(), {"force_W": "vec3", "torque_B": "vec3"}),
    "sim.FanJet": (
        lambda: dict(),
        {"position_W": "vec3", "direction_W": "vec3", "mean_force": "nonneg", "ref_distance": "pos", "width": "pos"},
    ),
    "sim.PlantParams": (
        lambda: dict(vehicle=vehicle()),
        {
            "vehicle": VP,
            "payload_mass": "nonneg",
            "payload_offset_B": "vec3",
            "inertia_scale": "vec3pos",
            "arm_length_scale": "pos",
            "rotor_tau_up": "nonneg",
            "rotor_tau_down": "nonneg",
            "ground_stiffness": "pos",
            "pendulum_length": "pos",
        },
    ),
    "sim.Push": (lambda: dict(), {"force_W": "vec3", "torque_B": "vec3", "t_on": "real", "duration": "pos"}),
    "sim.RampWrench": (lambda: dict(), {"force_W": "vec3", "torque_B": "vec3", "t_start": "real", "t_end": "real"}),
    "sim.Result": (
        lambda: dict(t=np.zeros(2), labels=["a"], data={}),
        {"t": "batch", "labels": "mapping", "data": "mapping"},
    ),
    "sim.SensorParams": (
        lambda: dict(),
        {"pos_noise": "nonneg", "vel_noise": "nonneg", "mocap_delay": "nonneg", "imu_delay": "nonneg"},
    ),
    "sim.SinusoidWrench": (lambda: dict(), {"force_W": "vec3", "torque_B": "vec3", "freq_hz": "pos", "phase": "real"}),
    "sim.StepWrench": (lambda: dict(), {"force_W": "vec3", "torque_B": "vec3", "t_on": "real"}),
    "sim.Wind": (lambda: dict(), {"velocity_W": "vec3", "drag": "nonneg"}),
    "sim.compile_plants": (lambda: dict(params=pparams()), {"params": PP}),
    "sim.plant_derivative": (
        lambda: dict(P=parrays(), x=plant_x(), f_cmd=np.full(4, 3.0)),
        {"P": Obj(type(parrays())), "x": Arr(plant_x().shape), "f_cmd": Arr((4,)), "t": "real"},
    ),
    "sim.rk4_step": (
        lambda: dict(P=parrays(), x=plant_x(), f_cmd=np.full(4, 3.0), t=0.0, dt=0.001),
        {"P": Obj(type(parrays())), "x": Arr(plant_x().shape), "f_cmd": Arr((4,)), "t": "real", "dt": "pos"},
    ),
    "sim.run_closed_loop": (
        lambda: dict(
            plant=pparams(), controllers=[cparams()], trajectory=scenarios.build(spec()).trajectory, duration=0.01
        ),
        {
            "plant": PP,
            "controllers": CP,
            "trajectory": Obj(Trajectory),
            "duration": "pos",
            "plant_rate": "pos",
            "sensors": Obj(sim.SensorParams),
        },
    ),
    # robust
    "robust.Timing": (lambda: dict(), {"velocity_delay": "nonneg", "attitude_delay": "nonneg", "rotor_tau": "nonneg"}),
    "robust.design": (
        lambda: dict(vehicle=vehicle(), Kp=16.0, Dp=12.0),
        {"vehicle": VP, "Kp": "gain", "Dp": "gain", "rate": "pos", "timing": Obj(robust.Timing)},
    ),
    "robust.designed_controller": (
        lambda: dict(vehicle=vehicle(), variant="pdc", Kp=16.0, Dp=12.0),
        {
            "vehicle": VP,
            "variant": "choice",
            "Kp": "gain",
            "Dp": "gain",
            "rate": "pos",
            "timing": Obj(robust.Timing),
            "Ki": "gain0",
        },
    ),
    "robust.Thresholds": (lambda: dict(), {"phase_deg": "nonneg", "gain_db": "nonneg", "damping": "nonneg"}),
    "robust.loop_margins": (
        lambda: dict(name="x", L=lin().loop("thrust")),
        {"name": "text", "L": "mapping", "omega": Arr((2,), positive=True)},
    ),
    "robust.margins": (lambda: dict(loop=lin()), {"loop": Obj(robust.LinearLoop), "label": "text"}),
    "robust.equivalent_rotor_tau": (
        lambda: dict(tau_up=0.0125, tau_down=0.025),
        {"tau_up": "nonneg", "tau_down": "nonneg"},
    ),
    "robust.linearize": (
        lambda: dict(controller=cparams(), plant=pparams()),
        {
            "controller": CP,
            "plant": PP,
            "sensors": Obj(sim.SensorParams),
            "p_W": "vec3",
            "psi": "real",
            "force_W": "vec3",
            "torque_B": "vec3",
            "plant_rate": "pos",
        },
    ),
    "robust.operating_point": (
        lambda: dict(controller=cparams(), plant=pparams()),
        {"controller": CP, "plant": PP, "p_W": "vec3", "psi": "real", "force_W": "vec3", "torque_B": "vec3"},
    ),
    "robust.rotor_lag_describing_function": (
        lambda: dict(tau_up=0.0125, tau_down=0.025, omega=10.0, periods=3),
        {"tau_up": "nonneg", "tau_down": "nonneg", "omega": "pos", "periods": "count"},
    ),
    # scenarios
    "scenarios.ControlSpec": (
        lambda: dict(),
        {
            "rate": "pos",
            "Kp": "gain",
            "Dp": "gain",
            "Ki": "gain0",
            "rotor_tau": "nonneg",
            "tilt_max_deg": "pos",
            "estimator_prototype": "text",
        },
    ),
    "scenarios.PayloadSpec": (lambda: dict(), {"mass": "nonneg", "offset_B": "vec3"}),
    "scenarios.PlantSpec": (
        lambda: dict(),
        {"inertia_scale": "vec3pos", "arm_length_scale": "pos", "rotor_tau_up": "nonneg", "pendulum_length": "pos"},
    ),
    "scenarios.ScenarioSpec": (
        lambda: dict(name="x"),
        {"name": "text", "plant_rate": "pos", "duration": "nonneg", "seed": "index"},
    ),
    "scenarios.TrajectorySpec": (
        lambda: dict(),
        {"kind": "text", "altitude": "real", "takeoff_duration": "pos", "circle_radius": "pos"},
    ),
    "scenarios.apply_overrides": (
        lambda: dict(spec=spec(), assignments=["duration=5"]),
        {"spec": Obj(scenarios.ScenarioSpec), "assignments": "mapping"},
    ),
    "scenarios.build": (lambda: dict(spec=spec()), {"spec": Obj(scenarios.ScenarioSpec)}),
    "scenarios.check": (lambda: dict(spec=spec()), {"spec": Obj(scenarios.ScenarioSpec)}),
    "scenarios.controller_params": (
        lambda: dict(spec=spec(), variant="pdc"),
        {"spec": Obj(scenarios.ScenarioSpec), "variant": "choice"},
    ),
    "scenarios.get": (lambda: dict(name="case-a-payload-v1"), {"name": "choice"}),
    "scenarios.tracking_design": (
        lambda: dict(vehicle="pelican", cases=["gust"]),
        {
            "vehicle": "choice",
            "min_phase_deg": "nonneg",
            "min_gain_db": "nonneg",
            "grid": "mapping",
            "progress": "func",
        },
    ),
    "scenarios.load_toml": (lambda: dict(path=Path("x.toml")), {"path": "path", "base": Obj(scenarios.ScenarioSpec)}),
    "scenarios.register": (lambda: dict(spec=spec()), {"spec": Obj(scenarios.ScenarioSpec)}),
    "scenarios.set_value": (
        lambda: dict(spec=spec(), key="duration", value=5.0),
        {"spec": Obj(scenarios.ScenarioSpec), "key": "choice"},
    ),
    "scenarios.simulate": (
        lambda: dict(scenario=spec()),
        {
            "scenario": Obj(scenarios.ScenarioSpec),
            "variants": "mapping",
            "seed": "index",
            "backend": "choice",
            "progress": "func",
        },
    ),
    # analysis
    "analysis.compute_metrics": (lambda: dict(result=result()), {"result": Obj(sim.Result), "window": "mapping"}),
    "analysis.window_mask": (lambda: dict(result=result()), {"result": Obj(sim.Result), "window": "mapping"}),
    # logs
    "logs.Conventions": (
        lambda: dict(),
        {"world": "choice", "body": "choice", "angle_unit": "choice", "quat_order": "choice", "time_unit": "choice"},
    ),
    "logs.Signal": (
        lambda: dict(name="v", source="x", t=np.arange(3.0), values=np.zeros((3, 3))),
        {"name": "text", "t": Arr((3,)), "values": "batch"},
    ),
    "logs.RawLog": (
        lambda: dict(
            velocity_W=raw().velocity_W, attitude=raw().attitude, omega_B=raw().omega_B, thrust=None, torque_B=None
        ),
        {
            "velocity_W": Obj(logs.Signal),
            "attitude": Obj(logs.Signal),
            "omega_B": Obj(logs.Signal),
            "thrust_unit": "text",
        },
    ),
    "logs.check_conventions": (
        lambda: dict(raw=raw()),
        {"raw": Obj(logs.RawLog), "mode": "choice", "declared": Obj(logs.Conventions)},
    ),
    "logs.check_inertia": (lambda: dict(inertia=[0.01, 0.01, 0.02]), {"inertia": Arr((3,), positive=True)}),
    "logs.commands_in_si": (
        lambda: dict(flight=flight(), mass=1.2),
        {"flight": Obj(logs.FlightLog), "mass": "pos", "hover_thrust": "pos", "thrust_from": "choice"},
    ),
    "logs.default_max_gap": (lambda: dict(sigs=[raw().velocity_W]), {"sigs": "mapping"}),
    "logs.estimate": (
        lambda: dict(flight=flight(), mass=1.2, inertia=[0.0034, 0.0034, 0.0047]),
        {
            "flight": Obj(logs.FlightLog),
            "mass": "pos",
            "params": Obj(estimator.EstimatorParams),
            "backend": "choice",
            "hover_thrust": "pos",
        },
    ),
    "logs.estimate_file": (
        lambda: dict(path=csv_file(), mass=1.2),
        {"path": "path", "mass": "pos", "rate_hz": "pos", "airframe": "text"},
    ),
    "logs.evidence": (lambda: dict(raw=raw()), {"raw": Obj(logs.RawLog)}),
    "logs.identify": (lambda: dict(), {"est": Obj(logs.LogEstimate)}),
    "logs.identify_file": (lambda: dict(path=csv_file(), mass=1.2), {"path": "path", "mass": "pos"}),
    "logs.fit_hover_thrust": (
        lambda: dict(flight=flight(), mass=1.2, segment=(0.1, 1.5)),
        {"flight": Obj(logs.FlightLog), "mass": "pos", "segment": "mapping"},
    ),
    "logs.fit_hover_windows": (
        lambda: dict(flight=flight(), mass=1.2),
        {"flight": Obj(logs.FlightLog), "mass": "pos", "max_tilt_deg": "pos"},
    ),
    "logs.judge": (
        lambda: dict(flight=flight(), thrust_N=np.full(flight().t.shape, 11.77), mass=1.2),
        {"flight": Obj(logs.FlightLog), "thrust_N": Arr(flight().t.shape), "mass": "pos"},
    ),
    "logs.MotorCurve": (
        lambda: dict(),
        {
            "expo": "real",
            "spin_min": "nonneg",
            "spin_max": "nonneg",
            "pwm_min": "nonneg",
            "pwm_max": "nonneg",
            "bat_volt_max": "nonneg",
            "bat_volt_min": "nonneg",
        },
    ),  # fmt: skip
    "logs.log_format": (lambda: dict(path=csv_file()), {"path": "path"}),
    "logs.read_any": (lambda: dict(path=csv_file()), {"path": "path", "conventions": "choice", "world": "choice"}),
    "logs.read_csv": (lambda: dict(path=csv_file()), {"path": "path", "world": "choice", "columns": "mapping"}),
    "logs.read_csv_table": (lambda: dict(path=csv_file()), {"path": "path", "columns": "mapping"}),
    "logs.read_log": (lambda: dict(path=csv_file()), {"path": "path"}),
    "logs.read_ulog": (lambda: dict(path=csv_file().with_name("px4-v1.14.ulg")), {"path": "path"}),
    "logs.resample": (
        lambda: dict(raw=raw()),
        {"raw": Obj(logs.RawLog), "rate_hz": "pos", "max_gap_s": "pos", "t_start": "real"},
    ),
    "logs.table_to_raw": (
        lambda: dict(table=logs.read_csv_table(csv_file()), conv=logs.Conventions()),
        {"table": "mapping", "conv": Obj(logs.Conventions), "rotor_speed_unit": "choice"},
    ),
    "logs.torque_per_unit": (lambda: dict(params={}), {"params": "mapping"}),
    # live
    "live.ControlSettings": (
        lambda: dict(),
        {
            "variant": "choice",
            "comply": "vec3",
            "impedance": "vec3pos",
            "Kp": "pos",
            "Dp": "pos",
            "tilt_max_deg": "pos",
            "watchdog_s": "pos",
            "on_loss": "choice",
        },
    ),
    "live.EstimatorSettings": (
        lambda: dict(),
        {"rate_hz": "pos", "params": Obj(estimator.EstimatorParams), "max_gap_s": "pos", "backend": "choice"},
    ),
    "live.LiveEstimator": (
        lambda: dict(mass=1.2, inertia_B=eye3(), thrust_map=thrust_map(), sources={}, n_rotors=4),
        {
            "mass": "pos",
            "inertia_B": A33,
            "thrust_map": Obj(live.ThrustMap),
            "n_rotors": "count",
            "settings": Obj(live.EstimatorSettings),
        },
    ),
    "live.LiveSettings": (
        lambda: dict(connect="udp:127.0.0.1:14550"),
        {
            "connect": "text",
            "autopilot": "choice",
            "mass": "pos",
            "duration": "pos",
            "connect_timeout_s": "pos",
            "estimator": Obj(live.EstimatorSettings),
            "control": Obj(live.ControlSettings),
        },
    ),
    "live.OffboardController": (
        lambda: dict(
            settings=live.ControlSettings(),
            loop=live.OuterLoop(cparams()),
            profile=importlib.import_module("vtol_impedance.live.streams").PX4,
            thrust_map=thrust_map(),
            mass=1.2,
            rate_hz=50.0,
        ),
        {
            "settings": Obj(live.ControlSettings),
            "loop": Obj(live.OuterLoop),
            "profile": "mapping",
            "thrust_map": Obj(live.ThrustMap),
            "mass": "pos",
            "rate_hz": "pos",
        },
    ),
    "live.OuterLoop": (lambda: dict(params=cparams()), {"params": CP}),
    "live.ThrustMap": (
        lambda: dict(mass=1.2, hover=0.5),
        {"mass": "pos", "hover": "pos", "max_thrust": "pos", "rotor_constant": "pos"},
    ),
    "live.parse_address": (lambda: dict(text="udp:127.0.0.1:14550"), {"text": "text"}),
    "live.replay": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path", "backend": "choice"}),
    "live.run_live": (lambda: dict(settings=None), {"settings": Obj(live.LiveSettings)}),
    # sweeps
    "sweeps.Axis": (lambda: dict(key="duration", values=(1.0, 2.0)), {"key": "text", "n": "count"}),
    "sweeps.SweepFolder": (
        lambda: dict(sweep=sweep(), folder=Path("no-such-folder")),
        {"sweep": Obj(sweeps.Sweep), "folder": "path"},
    ),
    "sweeps.from_dict": (lambda: dict(data={}), {"data": "mapping"}),
    "sweeps.load": (lambda: dict(path_or_name="payload-vs-offset"), {"path_or_name": "path"}),
    "sweeps.read_dataset": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path", "digest": "text"}),
    "sweeps.run_sweep": (
        lambda: dict(sweep=sweep(), out=Path("no-such-folder")),
        {"sweep": Obj(sweeps.Sweep), "out": "path", "workers": "count", "scheduler": "choice", "backend": "choice"},
    ),
    "sweeps.run_units": (
        lambda: dict(sweep=sweep(), units=[]),
        {"sweep": Obj(sweeps.Sweep), "units": "mapping", "backend": "choice"},
    ),
    "sweeps.set_param": (
        lambda: dict(spec=spec(), key="duration", value=5.0),
        {"spec": Obj(scenarios.ScenarioSpec), "key": "choice"},
    ),
    "sweeps.summarise": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path", "metric": "text"}),
    "sweeps.unit_seed": (
        lambda: dict(sweep_seed=1, point=0, repeat=0),
        {"sweep_seed": "index", "point": "index", "repeat": "index"},
    ),
    "tunepage.TunePage": (
        lambda: dict(base="case-a-payload", workers=0),
        {"base": Obj(scenarios.ScenarioSpec), "vehicle": "text", "workers": "index"},
    ),
    "tunepage.make_server": (
        lambda: dict(app=tunepage.TunePage(workers=0), host="127.0.0.1", port=0),
        {"app": Obj(tunepage.TunePage), "host": "text", "port": "index"},
    ),
    "tunepage.is_loopback": (lambda: dict(host="127.0.0.1"), {"host": "text"}),
    "sweeps.write_report": (
        lambda: dict(folder=Path("no-such-folder")),
        {"folder": "path", "metric": "text", "x": "text", "y": "text"},
    ),
    # io
    "io.atomic_path": (lambda: dict(path=Path("no-such-folder/x")), {"path": "path"}),
    "io.source_digest": (lambda: dict(sources=[csv_file()]), {"sources": "mapping"}),
    "io.explain_path": (lambda: dict(path=csv_file(), need="file"), {"path": "path", "need": "choice"}),
    "io.input_file": (lambda: dict(path=csv_file(), what="log file"), {"path": "path", "what": "text"}),
    "io.read_toml": (lambda: dict(path=csv_file(), what="a file"), {"path": "path", "what": "text"}),
    "io.parse_toml": (lambda: dict(text="a = 1", where="a text"), {"text": "text", "where": "text"}),
    "io.user_path": (lambda: dict(filename=Path("results/.x.staging-1")), {"filename": "path"}),
    "io.check_folder_path": (lambda: dict(final=Path("no-such-folder")), {"final": "path"}),
    "io.write_text": (lambda: dict(path=Path("no-such-folder/x"), text="x"), {"path": "path", "text": "text"}),
    "io.write_with": (
        lambda: dict(path=Path("no-such-folder/x"), writer=lambda f: None),
        {"path": "path", "writer": "func"},
    ),
    "io.sha256_of": (lambda: dict(path=csv_file()), {"path": "path"}),
    "io.check_output_file": (lambda: dict(path=Path("no-such-folder/x")), {"path": "path"}),
    "io.is_recording": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path"}),
    "io.check_output_folder": (lambda: dict(final=Path("no-such-folder")), {"final": "path"}),
    "io.FolderLock": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path"}),
    "io.RunFolder": (lambda: dict(final=Path("no-such-folder")), {"final": "path"}),
    "io.verify_run_folder": (lambda: dict(folder=Path("no-such-folder")), {"folder": "path"}),
    # errors: the checks themselves refuse what they check
    "errors.as_finite": (lambda: dict(name="x_W", value=z3(), shape_tail=(3,)), {"value": Arr((3,))}),
    "errors.positive": (lambda: dict(name="x_W", value=1.0), {"value": "posany"}),
    "errors.scalar": (lambda: dict(name="x_W", value=1.0), {"value": "real"}),
    "errors.per_axis": (lambda: dict(name="x_W", value=1.0, lo=0.0, lo_open=True), {"value": "gain"}),
    "errors.instance": (lambda: dict(name="x_W", value=1.0, types=float), {"value": Obj(float)}),
    "errors.choice": (lambda: dict(name="x_W", value="a", options=("a", "b")), {"value": "choice"}),
    "errors.path_like": (lambda: dict(name="x_W", value="a"), {"value": "path"}),
    "errors.batched": (lambda: dict(name="x_W", value=z3(), tail=(3,)), {"value": Arr((3,))}),
    "errors.function": (lambda: dict(name="x_W", value=print), {"value": "func"}),
}

# More arguments of the rows above (kept apart to keep the rows short).
MORE_KINDS: dict[str, dict[str, Any]] = {
    "model.VehicleParams": {"f_max": "pos", "name": "text"},
    "estimator.EstimatorParams": {"velocity_delay": "nonneg", "attitude_delay": "nonneg"},
    "control.ControllerParams": {"attitude_filter_wn": "pos", "attitude_filter_zeta": "pos",
                                 "thrust_shift_max": "nonneg", "min_lift_accel": "pos"},
    "control.Impedance": {"M_o": "gain", "D_o": "gain0", "K_o": "gain0"},
    "control.Measurement": {"eta_dot": A3, "omega_B": A3},
    "sim.FanJet": {"turbulence": "nonneg", "cop_offset_B": "vec3", "t_on": "real"},
    "sim.PlantParams": {"drag_factor_scale": "pos", "rotor_drag": "nonneg", "ground_damping": "nonneg",
                        "ground_friction": "nonneg", "pendulum_mass": "nonneg"},
    "sim.SensorParams": {"att_noise": "nonneg", "gyro_noise": "nonneg"},
    "sim.SinusoidWrench": {"t_on": "real"},
    "sim.run_closed_loop": {"progress": "func", "backend": "choice", "labels": "mapping", "disturbances": "mapping"},
    "robust.linearize": {"comply": "gain0"},
    "scenarios.ControlSpec": {"zeta_o": "pos", "estimator_zeta": "pos", "integral_limit": "nonneg",
                              "thrust_shift_max": "nonneg", "wn_o": "pos", "estimator_wn": "pos",
                              "velocity_delay": "nonneg"},
    "scenarios.PlantSpec": {"drag_factor_scale": "pos", "rotor_tau_down": "nonneg", "rotor_drag": "nonneg",
                            "pendulum_mass": "nonneg"},
    "scenarios.TrajectorySpec": {"takeoff_at": "nonneg", "hover_duration": "nonneg", "land_duration": "pos",
                                 "move_offset": "vec3", "yaw": "real", "move_duration": "pos"},
    "scenarios.ScenarioSpec": {"description": "text", "vehicle": "text", "trajectory": Obj(scenarios.TrajectorySpec),
                               "payload": Obj(scenarios.PayloadSpec), "control": Obj(scenarios.ControlSpec),
                               "sensors": Obj(sim.SensorParams)},
    "logs.Conventions": {"quat_direction": "choice", "velocity_world": "choice", "rate_unit": "choice"},
    "logs.read_csv": {"body": "choice", "angle_unit": "choice", "quat_order": "choice", "time_unit": "choice",
                      "rotor_speed_unit": "choice", "conventions": Obj(logs.Conventions)},
    "logs.resample": {"t_end": "real"},
    "live.ControlSettings": {"thrust_rate_max": "pos", "fence_radius_m": "pos", "fence_height_m": "pos",
                             "max_speed_m_s": "pos", "handshake_timeout_s": "pos", "engage_after_s": "nonneg"},
    "live.EstimatorSettings": {"command_stale_s": "pos"},
    "live.LiveSettings": {"probe_s": "pos", "stream_timeout_s": "pos", "min_stream_hz": "pos", "display": "choice"},
    "sweeps.Axis": {"lo": "real", "hi": "real"},
}  # fmt: skip
for _qual, _kinds in MORE_KINDS.items():
    TABLE[_qual][1].update(_kinds)

# The arguments of the errors helpers are named by their ``name`` argument, not by ``value``.
NAMED_AS = {
    **{f"errors.{n}": "x_W" for n in (
        "as_finite", "positive", "scalar", "per_axis", "instance", "choice", "path_like", "function", "batched")},
    "live.parse_address": "--connect",
    "model.load_preset": "vehicle preset",
}  # fmt: skip

# The batched math called every step lets NaN and infinities through (IEEE arithmetic): the batch engine
# flags a diverged vehicle by them without stopping the others. They refuse wrong types and shapes; the
# entries that take a user's values (the constructors, runtime.Controller, runtime.Estimator) refuse NaN.
NAN_PROPAGATES = {
    "model.allocate", "model.body_moment_from_euler", "model.coriolis_matrix_C", "model.euler_moment_from_body",
    "model.euler_rate_matrix_Q", "model.euler_rate_matrix_Q_dot", "model.euler_rate_matrix_T",
    "model.generalized_momentum", "model.inertia_matrix_M", "model.mix", "model.momentum_rate_known",
    "model.rotation_zyx", "model.skew", "model.unmix", "estimator.estimator_step", "control.acceleration_from_thrust",
    "control.thrust_and_attitude", "control.Measurement", "control.Reference", "sim.plant_derivative", "sim.rk4_step",
    "errors.batched",
    "logs.Signal",  # a reader's raw signal: NaN rows are reported and dropped by the cleaning step
}  # fmt: skip

EXEMPT = {
    **{f"errors.{n}": "an exception class: its argument is the message" for n in
       ("VtolImpedanceError", "InputError", "SingularityError", "ScenarioError")},
    "robust.DesignError": "an exception class", "robust.TrimError": "an exception class",
    "robust.LoopSizeError": "an exception class", "live.LiveError": "an exception class",
    "estimator.EstimatorBandwidthWarning": "a warning class", "runtime.ControllerWarning": "a warning class",
    "sim.LatencyWarning": "a warning class", "robust.DesignWarning": "a warning class",
    "model.VehicleDefaultWarning": "a warning class", "model.HoverWarning": "a warning class", "logs.LogRefused": "an exception class (its verdict)",
    "sweeps.ClusterError": "an exception class", "sweeps.ChunkError": "an exception class",
    "model.aero_force_B": "the plant's inner force law, called at every RK4 stage with the plant's checked arrays",
    "model.preset_names": "no parameters", "sweeps.builtin_names": "no parameters",
    "tunepage.Latest": "no parameters", "tunepage.Superseded": "an exception class",
    "tunepage.Field": "a row of the page's table of controls (tunepage.FIELDS), which the package writes",
    "scenarios.Registry": "no parameters",
    "sim.Disturbance": "an abstract base class without parameters",
    "scenarios.names": "one flag (latest_only), any truth value is meaningful",
    "errors.check_keys": "checks a mapping's keys; the mapping and names come from the package's own readers",
    "errors.flag": "accepts only True or False; every other value is what it refuses",
    "io.quiet_worker": "a process pool's initializer: its one flag (die_with_parent) takes any truth value",
    "io.spawning_quietly": "no parameters",
    # results and records the package builds and hands out; users read them, never construct them
    **{n: "a result record the package builds" for n in (
        "model.Allocation", "model.RotorGeometry", "estimator.EstimatorDesign", "estimator.EstimatorState",
        "control.ControlOutput", "control.ControllerArrays", "control.ControllerState", "runtime.EstimatorOutput",
        "robust.Design", "robust.LoopMargins", "robust.MarginReport", "robust.LinearLoop", "robust.OperatingPoint",
        "logs.ConventionReport", "logs.FlightLog", "logs.LogEstimate", "logs.Verdict", "live.LiveResult", "live.Tick",
        "sweeps.Sweep", "sweeps.Unit", "scenarios.TrackingDesign", "logs.Coefficient", "logs.Identification")},
}  # fmt: skip


def _callables() -> list[str]:
    out = []
    for package in PACKAGES:
        mod = importlib.import_module(f"vtol_impedance.{package}")
        for name in public_names(package):
            obj = getattr(mod, name)
            if callable(obj):
                out.append(f"{package}.{name}")
    return out


def _resolve(qual: str) -> Any:
    package, name = qual.split(".")
    return getattr(importlib.import_module(f"vtol_impedance.{package}"), name)


def test_every_public_callable_is_covered():
    names = _callables()
    missing = [n for n in names if n not in TABLE and n not in EXEMPT]
    assert not missing, f"public callables with neither a row in TABLE nor a reason in EXEMPT: {missing}"
    stale = [n for n in (*TABLE, *EXEMPT) if n not in names]
    assert not stale, f"rows for names that are no longer public callables: {stale}"
    both = [n for n in TABLE if n in EXEMPT]
    assert not both, both


def _cases() -> list[Any]:
    cases = []
    for qual, (_, kinds) in TABLE.items():
        for arg, kind in kinds.items():
            cases.append(pytest.param(qual, arg, kind, id=f"{qual}-{arg}"))
    return cases


def test_rows_name_real_arguments():
    for qual, (_, kinds) in TABLE.items():
        params = inspect.signature(_resolve(qual)).parameters
        wrong = [a for a in kinds if a not in params]
        assert not wrong, f"{qual}: no argument(s) {wrong}"


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    """The rows' relative paths (``no-such-folder``) resolve in a scratch folder: a refusal that came too
    late would leave its traces there, not in the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.mark.parametrize(("qual", "arg", "kind"), _cases())
def test_bad_argument_is_refused_by_name(qual: str, arg: str, kind: Any, tmp_path: Path):
    fn = _resolve(qual)
    base = TABLE[qual][0]()
    good = base.get(arg, inspect.signature(fn).parameters[arg].default)
    if good is inspect.Parameter.empty or good is None:
        good = np.zeros((3,) if not isinstance(kind, Arr) else kind.tail)
    named = NAMED_AS.get(qual, arg)
    bads = bad_values(kind, good)
    if qual in NAN_PROPAGATES:
        bads = [b for b in bads if isinstance(b, str) or b is None or np.isfinite(np.asarray(b, dtype=float)).all()]
    for bad in bads:
        args = {**base, arg: bad}
        try:
            out = fn(**args)
            if hasattr(out, "__enter__") and hasattr(out, "__exit__") and not hasattr(out, "step"):  # a context
                with out:  # manager refuses on entry, before it touches anything
                    pass
        except VtolImpedanceError as exc:
            assert named in str(exc) or named.replace("_", "-") in str(exc), (
                f"{qual}({arg}={bad!r}): the message does not name {named!r}: {exc}"
            )
        except Exception as exc:  # noqa: BLE001  (what the test exists to catch)
            pytest.fail(f"{qual}({arg}={bad!r}) raised {type(exc).__name__}: {exc}")
        else:
            pytest.fail(f"{qual}({arg}={bad!r}) was accepted and returned {type(out).__name__}")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert not left, f"{qual}: refused calls left {left} behind"
