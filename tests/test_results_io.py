"""Results: save/load round trip, corrupt files, atomic writes, failure flagging."""

from dataclasses import replace

import numpy as np
import pytest

from vtol_impedance.control import ControllerParams
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.errors import InputError
from vtol_impedance.io import write_text
from vtol_impedance.model import load_preset
from vtol_impedance.scenarios import get, set_value, simulate
from vtol_impedance.sim import PlantParams, Result, SensorParams, run_closed_loop


@pytest.fixture(scope="module")
def short_result():
    return simulate(set_value(get("case-b-fan"), "duration", 0.5), ["pd", "pdc"])


def test_save_load_round_trip(short_result, tmp_path):
    p = short_result.save(tmp_path / "r.npz")
    r = Result.load(p)
    assert r.labels == short_result.labels
    assert r.config["scenario"]["name"] == "case-b-fan-v1"
    for k, v in short_result.data.items():
        np.testing.assert_array_equal(r[k], v)
    assert not list(tmp_path.glob(".*tmp"))


def test_metrics_and_failures_survive_the_round_trip(tmp_path):
    """A ``log="metrics"`` result keeps its metrics and a result with a stopped vehicle keeps the time and
    reason (hand-made values, compared field by field); a signal whose sample count is not ``len(t)`` is
    refused on load."""
    metrics = [{"controller": "pd", "rms_ep_cm": 1.25, "failure": None},
               {"controller": "pdc", "rms_ep_cm": 0.5, "failure": {"time": 1.5, "reason": "tilt"}}]  # fmt: skip
    failures = [None, {"time": 1.5, "reason": "tilt"}]
    r = Result(np.arange(0.0, 0.3, 0.1), ["pd", "pdc"], {}, {"seed": 3}, failures, metrics)
    back = Result.load(r.save(tmp_path / "m.npz"))
    assert back.metrics == metrics and back.failures == failures and back.data == {}
    bad = Result(np.arange(3.0), ["a"], {"p_W": np.zeros((1, 4, 3))}, {}, [None])
    with pytest.raises(InputError, match=r"signal p_W has shape \(1, 4, 3\), expected \(1, 3, ...\)"):
        Result.load(bad.save(tmp_path / "bad.npz"))


def test_corrupt_and_foreign_files_are_refused(short_result, tmp_path):
    p = short_result.save(tmp_path / "r.npz")
    data = p.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="not a readable"):
        Result.load(tmp_path / "cut.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(InputError):
        Result.load(tmp_path / "other.npz")


def test_atomic_write_leaves_old_file_on_failure(tmp_path):
    target = tmp_path / "table.md"
    write_text(target, "old")

    class Boom(Exception):
        pass

    from vtol_impedance.io import atomic_path

    with pytest.raises(Boom), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise Boom
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]


def test_a_diverging_vehicle_is_flagged_and_the_others_go_on():
    veh = load_preset()
    good = PlantParams(veh, ground=False)
    # 50x less inertia than the controller believes and no rotor limit: the attitude loop blows up
    bad = PlantParams(replace(veh, f_max=1e3), inertia_scale=(0.02, 0.02, 0.02), ground=False)
    ctrls = [ControllerParams.paper("pdc")] * 2
    r = run_closed_loop(
        [good, bad],
        ctrls,
        Trajectory((Hold((0, 0, -1.0), 3.0),)),
        3.0,
        sensors=SensorParams(),
        labels=["good", "bad"],
        seed=1,
    )
    assert r.failures[0] is None
    assert r.failures[1] is not None and r.failures[1]["time"] < 3.0
    assert "tilt" in r.failures[1]["reason"] or "non-finite" in r.failures[1]["reason"]
    assert np.all(np.isfinite(r["p_W"][0]))
    assert np.isnan(r["p_W"][1, -1]).all()
    assert np.linalg.norm(r.e_p[0, -1]) < 5e-3


def test_run_arguments_are_checked():
    veh = load_preset()
    traj = Trajectory((Hold((0, 0, -1.0), 1.0),))
    with pytest.raises(InputError, match="whole number"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, plant_rate=333.0)
    with pytest.raises(InputError, match="labels"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, labels=["a", "b"])
    with pytest.raises(InputError, match="duration"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, -1.0)


def test_written_files_get_ordinary_permissions(tmp_path):
    import os

    p = write_text(tmp_path / "a.md", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert (p.stat().st_mode & 0o777) == (0o666 & ~mask)


def test_a_reference_below_the_ground_is_refused_before_the_flight():
    """With the ground on, a reference 0.5 m under it (NED z = +0.5) is refused naming the depth and the
    time (it was flown and recorded as a crash); without a ground the same reference flies."""
    from vtol_impedance.control.reference import MinJerk

    traj = Trajectory((Hold((0.0, 0.0, -1.0), 0.5), MinJerk((0.0, 0.0, -1.0), (0.0, 0.0, 0.5), 0.5),
                       Hold((0.0, 0.0, 0.5), 1.0)))  # fmt: skip
    ctrl = [ControllerParams.paper("pd")]
    with pytest.raises(InputError, match=r"goes 0.5 m below the ground \(NED z > 0\) at t = 1 s"):
        run_closed_loop(PlantParams(load_preset(), ground=True), ctrl, traj, 2.0, start_W=np.array([0, 0, -1.0]))
    r = run_closed_loop(PlantParams(load_preset(), ground=False), ctrl, traj, 1.5, start_W=np.array([0, 0, -1.0]))
    assert r.failures == [None]


@pytest.mark.parametrize(
    "window, message",
    [((0.4, 0.1), "t0 <= t1"), ((5.0, 6.0), "fewer than two samples"), ((0.1, 0.4, 99.0), "window must be"),
     ("0.1,0.4", "window must be")],
)  # fmt: skip
def test_a_window_given_for_the_metrics_is_checked_not_widened(short_result, window, message):
    """A caller's window reversed, outside the run or of three numbers is refused by name: the metrics of
    the whole run under another window's name would be a wrong number. A proper one narrows the metrics
    to its samples (their count is checked against the log)."""
    from vtol_impedance.analysis import compute_metrics

    with pytest.raises(InputError, match=message):
        compute_metrics(short_result, window)
    inside = compute_metrics(short_result, (0.1, 0.4))
    whole = compute_metrics(short_result, (0.0, 0.5))
    e = np.linalg.norm(short_result.e_p[0], axis=-1)
    sel = (short_result.t >= 0.1) & (short_result.t <= 0.4)
    assert inside[0]["rms_ep_cm"] == pytest.approx(100 * np.sqrt(np.mean(e[sel] ** 2)))
    assert whole[0]["rms_ep_cm"] == pytest.approx(100 * np.sqrt(np.mean(e**2)))


def test_foreign_headers_and_unkeepable_values_are_refused_by_name(short_result, tmp_path):
    """Every way a file can be a result's look-alike gives an InputError (never a TypeError, KeyError or
    AttributeError), and a save that cannot be kept writes nothing; a NumPy scalar in the config is kept."""
    import json

    from vtol_impedance.analysis import compute_metrics

    p = short_result.save(tmp_path / "r.npz")
    np.save(tmp_path / "a.npy", np.zeros(3))
    with pytest.raises(InputError, match="not a readable"):
        Result.load(tmp_path / "a.npy")
    with pytest.raises(InputError, match="path"):
        Result.load(5)
    good = json.loads(str(np.load(p)["header"]))
    for name, header in [("list", [1, 2]), ("nolabels", {k: v for k, v in good.items() if k != "labels"}),
                         ("labels5", good | {"labels": 5}), ("badfail", good | {"failures": [{"time": 1.0}, None]}),
                         ("badmetrics", good | {"metrics": 3}), ("shortfail", good | {"failures": [None]}),
                         ("longmetrics", good | {"metrics": [{}, {}, {}]})]:  # fmt: skip
        with np.load(p) as z:
            arrays = {k: z[k] for k in z.files if k != "header"}
        np.savez(tmp_path / f"{name}.npz", header=np.array(json.dumps(header)), **arrays)
        with pytest.raises(InputError):
            Result.load(tmp_path / f"{name}.npz")
    lacking = Result(short_result.t, short_result.labels, {k: v for k, v in short_result.data.items() if k != "p_ref_W"},
                     short_result.config, short_result.failures)  # fmt: skip
    with pytest.raises(InputError, match="p_ref_W"):
        compute_metrics(lacking)
    kept = Result(short_result.t, short_result.labels, short_result.data, {"note": np.float32(1.5)},
                  short_result.failures)  # fmt: skip
    assert Result.load(kept.save(tmp_path / "f32.npz")).config["note"] == 1.5
    odd = Result(short_result.t, short_result.labels, short_result.data, {"note": object()}, short_result.failures)
    with pytest.raises(InputError, match="object"):
        odd.save(tmp_path / "odd.npz")
    assert not (tmp_path / "odd.npz").exists()
    with pytest.raises(InputError, match="folder"):
        short_result.save(tmp_path)
    metrics_only = Result(short_result.t[:0], short_result.labels, {}, {"window": [0.0, 0.5]},
                          short_result.failures, compute_metrics(short_result))  # fmt: skip
    with pytest.raises(InputError, match="no traces"):  # its metrics are its own window's, not (0, 0.3)'s
        compute_metrics(metrics_only, (0.0, 0.3))


def test_a_numpy_integer_decimation_is_taken_as_the_whole_number():
    """``log=np.int64(5)`` (a count computed with NumPy) is ``log=5``, not refused."""
    spec = set_value(get("case-b-fan"), "duration", 0.2)
    a = simulate(spec, ["pd"], log=np.int64(5))
    b = simulate(spec, ["pd"], log=5)
    assert a.t.tolist() == b.t.tolist() and len(a.t) == 4
