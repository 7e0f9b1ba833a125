"""The widened robustness study: the figure-eight reference (analytic derivatives, the curve it claims),
its scenario, the shipped studies (trajectories, push, wall) loading within their time budget, and one
cell's rows carrying the margin verdict next to the flight's outcome (checked against closed forms)."""

from __future__ import annotations

import numpy as np
import pytest

from vtol_impedance.control.reference import FigureEight, Hold, Trajectory
from vtol_impedance.errors import InputError
from vtol_impedance.scenarios import get
from vtol_impedance.scenarios.spec import build
from vtol_impedance.sweeps import from_dict, load
from vtol_impedance.sweeps.budget import sweep_seconds

START = (1.0, -0.5, -1.5)


def _eight() -> FigureEight:
    return FigureEight(START, half_length=0.8, speed=0.6, laps=1.5, ramp=1.5)


def test_figure_eight_derivatives_are_those_of_its_position():
    """Velocity and acceleration against central differences of the sampled position (and velocity),
    through the ramps and the plateau; rest at both ends; on Gerono's curve a^2 y^2 = x^2 (a^2 - x^2)."""
    e = _eight()
    h = 1e-4
    tau = np.linspace(0.0, e.duration, 4001)[1:-1]
    p, v, a = e.sample(tau)
    pp, vp, _ = e.sample(tau + h)
    pm, vm, _ = e.sample(tau - h)
    assert np.max(np.abs((pp - pm) / (2 * h) - v)) < 1e-6
    assert np.max(np.abs((vp - vm) / (2 * h) - a)) < 1e-5
    assert np.max(np.abs(a)) > 0.1  # the test sees a real acceleration
    d = p - np.asarray(START)
    A = e.half_length
    assert np.max(np.abs(A**2 * d[:, 1] ** 2 - d[:, 0] ** 2 * (A**2 - d[:, 0] ** 2))) < 1e-12
    assert np.all(d[:, 2] == 0.0)
    for t in (0.0, e.duration):
        p0, v0, a0 = e.sample(np.array([t]))
        assert np.allclose(p0[0], START, atol=1e-12) and np.allclose(v0, 0.0) and np.allclose(a0, 0.0, atol=1e-12)


def test_figure_eight_runs_at_its_speed_through_the_crossing():
    """On the plateau the parameter runs at w = speed / (a sqrt 2) (each ramp covers half the angle it
    would at full speed): at tau = pi / w + ramp / 2 the vehicle is at the crossing at ``speed``."""
    e = _eight()
    w = e.speed / (e.half_length * np.sqrt(2.0))
    assert e.duration == pytest.approx(2 * np.pi * e.laps / w + e.ramp)
    p, v, _ = e.sample(np.array([np.pi / w + e.ramp / 2]))
    assert np.allclose(p[0], START, atol=1e-12)
    assert np.linalg.norm(v[0]) == pytest.approx(e.speed, rel=1e-12)
    with pytest.raises(InputError, match="half length"):
        FigureEight(START, half_length=0.0)
    Trajectory((Hold(START, 1.0), e, Hold(START, 1.0)))  # joins its neighbours


def test_figure_eight_scenario_is_registered_and_flies_the_eight():
    spec = get("figure-eight")
    assert spec.name == "figure-eight-v1" and spec.trajectory.kind == "figure-eight"
    b = build(spec)
    t0, t1 = b.window
    w = 0.7 / np.sqrt(2.0)  # 1 m half length, 0.7 m/s at the crossing
    assert t1 - t0 == pytest.approx(2 * 2 * np.pi / w + 2.0)
    rows = b.trajectory.sample_many(np.linspace(t0, t1, 500))
    d = rows[:, 0:3] - np.array([0.0, 0.0, -1.0])
    assert np.max(np.abs(d[:, 1] ** 2 - d[:, 0] ** 2 * (1 - d[:, 0] ** 2))) < 1e-12
    assert d[:, 0].max() == pytest.approx(1.0, abs=1e-4) and d[:, 1].max() == pytest.approx(0.5, abs=1e-4)


@pytest.mark.parametrize(
    ("name", "controllers", "flights"),
    [("robustness-trajectories", ["pd", "pdc"], 108), ("robustness-push", ["pd", "pdc", "comply"], 81),
     ("robustness-wall", ["comply"], 27)],
)  # fmt: skip
def test_the_widened_studies_load_within_a_few_minutes(name, controllers, flights):
    s = load(name, check_points=False)
    assert s.controllers == controllers and s.n_flights == flights and s.measures and s.margins
    assert "payload.mass" in [a.key for a in s.axes]
    assert max(p["payload.mass"] for p in s.points) == pytest.approx(0.3 * 1.2, rel=0.05)  # 30 % of the mass
    assert sweep_seconds(s, "compiled", 2) < 180.0


def test_bad_margins_at_is_refused():
    with pytest.raises(InputError, match="margins_at"):
        from_dict({"base": "operator-push-v3", "margins_at": "later", "axes": {"payload.mass": [0.0]}})


def _cell(base: str, controllers: list[str]) -> dict:
    from vtol_impedance.sweeps.run import run_units

    sweep = from_dict({"name": "cell", "base": base, "controllers": controllers, "measures": True,
                       "margins_at": "engaged", "axes": {"payload.mass": [0.0]}}, check_points=False)  # fmt: skip
    return run_units(sweep, sweep.units)[0]


def _half_sine_peak(F: float, T: float, M: float, D: float, K: float) -> float:
    """Largest displacement of M x'' + D x' + K x = F sin(pi t / T) on [0, T], 0 after, from rest (RK4)."""
    dt, x, v, peak = 1e-3, 0.0, 0.0, 0.0
    f = lambda t, x, v: ((F * np.sin(np.pi * t / T) if t <= T else 0.0) - D * v - K * x) / M  # noqa: E731
    for i in range(int((T + 2.0) / dt)):
        t = i * dt
        k1 = (v, f(t, x, v))
        k2 = (v + dt / 2 * k1[1], f(t + dt / 2, x + dt / 2 * k1[0], v + dt / 2 * k1[1]))
        k3 = (v + dt / 2 * k2[1], f(t + dt / 2, x + dt / 2 * k2[0], v + dt / 2 * k2[1]))
        k4 = (v + dt * k3[1], f(t + dt, x + dt * k3[0], v + dt * k3[1]))
        x += dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v += dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        peak = max(peak, abs(x))
    return peak


def test_a_cell_carries_the_verdict_next_to_the_outcome():
    """One push cell (reject and comply) and one wall cell: each row has the margin verdict, where it was
    taken (comply engaged: its 5 s switch plus the 0.5 s blend), what it leaves out (the wall's contact),
    and the flight's outcome: comply yields to the 3 N half-sine as its impedance (M 2, D 6, K 5) does,
    within 5 % (measured 0.3 %), reject barely moves; at the wall comply
    holds K_d (0.8 - 0.5) = 1.5 N."""
    rows = _cell("operator-push-v3", ["pdc", "comply"])
    assert rows["controller"] == ["pdc", "comply"]
    assert all(v in (0.0, 1.0) for v in rows["margin_stable"] + rows["margin_ok"])
    assert rows["margin_at_s"] == [pytest.approx(5.5, abs=0.011)] * 2
    assert rows["margin_scope"] == ["", ""]
    assert all(np.isfinite(rows["pm_min_deg"]))
    assert rows["pm_min_deg"][0] != rows["pm_min_deg"][1]  # comply was checked engaged, not as reject
    expected = 100 * _half_sine_peak(3.0, 2.5, 2.0, 6.0, 5.0)
    assert rows["push_peak_cm"][1] == pytest.approx(expected, rel=0.05)
    assert rows["push_peak_cm"][0] < 0.2 * rows["push_peak_cm"][1]
    assert all(0.0 < s < 0.9 for s in rows["settle_ev_cms"])  # settled (the docs' threshold: 0.9 cm/s)
    assert np.isnan(rows["wall_force_N"]).all()

    rows = _cell("wall-contact-v2", ["comply"])
    assert "wall contact" in rows["margin_scope"][0]
    assert rows["wall_force_N"][0] == pytest.approx(1.5, rel=0.05)
    assert abs(rows["wall_force_err_pct"][0]) < 5.0
    assert np.isnan(rows["push_peak_cm"][0])
