"""The reference aligned to the measurement's latency (``control.reference_timing``,
``ControllerParams.reference_delay``): a trajectory tracked on time, against the closed form of tracking
it a latency late, with the feedback (and so every margin) unchanged, in both executions."""

from __future__ import annotations

import numpy as np
import pytest

from vtol_impedance.errors import InputError
from vtol_impedance.scenarios import apply_overrides, build, controller_params, get, set_value, simulate
from vtol_impedance.scenarios.margins import scenario_margins
from vtol_impedance.sim import run_closed_loop
from vtol_impedance.sim.result import window_mask

SPEED = 0.5  # m/s, case C's circle (paper Sec. V): 1 m radius flown at 0.5 m/s


def _circle(delay: float, aligned: bool):
    """Case C without what the estimator has to catch (no payload, no noise, no drag): what is left of
    the error is the timing."""
    quiet = ["payload.mass=0", "plant.rotor_drag=0", *(f"sensors.{n}=0" for n in ("pos_noise", "vel_noise",
             "att_noise", "gyro_noise"))]  # fmt: skip
    return apply_overrides(
        get("case-c-circle"),
        [*quiet, f"sensors.mocap_delay={delay}", f"control.reference_timing={str(aligned).lower()}"],
    )


def _rms_true_error(spec) -> float:
    """RMS of |p - p_d(t)| over the circle, p_d the trajectory itself (not what the controller was given)."""
    r = simulate(spec, ["pdc"])
    m = window_mask(r)
    p_d = build(spec).trajectory.sample_many(r.t[m])[:, 0:3]
    return float(np.sqrt(np.mean(np.sum((r["p_W"][0][m] - p_d) ** 2, axis=-1))))


@pytest.mark.parametrize("delay", [0.02, 0.04])
def test_a_circle_is_flown_a_latency_late_unless_the_reference_is_aligned(delay):
    late = _rms_true_error(_circle(delay, aligned=False))
    on_time = _rms_true_error(_circle(delay, aligned=True))
    # closed form: tracking what was measured `delay` ago puts the vehicle v * delay ahead along the path
    assert late == pytest.approx(SPEED * delay, rel=0.2)
    assert on_time < 0.2 * SPEED * delay


def test_the_alignment_leaves_the_feedback_and_its_margins_unchanged():
    a = scenario_margins(_circle(0.02, aligned=False), ("pdc",))["pdc"].summary()
    b = scenario_margins(_circle(0.02, aligned=True), ("pdc",))["pdc"].summary()
    assert a == b


def test_both_executions_fly_the_aligned_reference_alike():
    spec = set_value(set_value(get("case-a-payload"), "duration", 3.0), "control.reference_timing", True)
    rn, rc = simulate(spec, ["pdc"], backend="numpy"), simulate(spec, ["pdc"], backend="compiled")
    for k in ("p_W", "f_hat_W", "p_ref_W", "thrust"):
        scale = max(float(np.max(np.abs(rn[k]))), 1e-9)
        assert float(np.max(np.abs(rn[k] - rc[k]))) / scale <= 1e-9, k
    # the take-off moves the reference: the alignment changed the flight, and the log keeps the true one
    plain = simulate(set_value(spec, "control.reference_timing", False), ["pdc"], backend="compiled")
    assert np.max(np.abs(plain["p_W"] - rc["p_W"])) > 1e-4
    np.testing.assert_array_equal(plain["p_ref_W"], rc["p_ref_W"])


def test_one_batch_shares_one_alignment():
    spec = _circle(0.02, aligned=True)
    b = build(spec)
    on, off = (
        controller_params(spec, "pdc"),
        controller_params(set_value(spec, "control.reference_timing", False), "pd"),
    )
    assert on.reference_delay == pytest.approx(0.02) and off.reference_delay == 0.0
    with pytest.raises(InputError, match=r"different delays \(\[0.0, 0.02\] s\)"):
        run_closed_loop(b.plant, [on, off], b.trajectory, 1.0, sensors=b.sensors)
    with pytest.raises(InputError, match="reference_delay"):
        controller_params(spec, "pdc").__class__(vehicle=on.vehicle, gains=on.gains, reference_delay=-0.01)
