"""
Estimate the wrench from a flight log
=====================================

Estimate the wrench a vehicle felt from its flight log, as you would with a ROS bag exported to CSV.

The "flight" here is the simulator's case B (unmodelled payload, then a fan) flown with PD, so that the
true wrench is known. Its measured velocity, attitude, gyro and commands are written the way a ROS
stack logs them (world ENU, body FLU, quaternion x y z w, angles in degrees, thrust normalised with a
hover-thrust column) and then read back by ``vtol-impedance estimate``, which checks the declared
conventions against physics, converts everything to NED / FRD and runs the paper's estimator. Without the
convention flags, ``--conventions auto`` finds them from the data (the second run below).

Run: ``python examples/estimate_from_a_log.py [--duration 30] [--out results/example-estimate]``
"""

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vtol_impedance.cli import main as cli
from vtol_impedance.logs import frames
from vtol_impedance.model import load_preset
from vtol_impedance.model.kinematics import rotation_zyx
from vtol_impedance.scenarios import get, set_value, simulate

HOVER = 0.55  # what the ESCs would need to hover: thrust_norm = thrust_N * HOVER / (m g)


def write_ros_style_csv(path: Path, duration: float = 30.0) -> dict:
    spec = set_value(get("case-b-fan"), "duration", duration)
    r = simulate(spec, ["pd"])
    t = r.t
    R_enu_flu = frames.rotation_from_ned_frd(rotation_zyx(r["eta_meas"][0]), "enu", "flu")
    q = Rotation.from_matrix(R_enu_flu).as_quat()  # x, y, z, w
    v = frames.world_vector_to_ned(r["v_meas_W"][0], "enu")  # ENU <-> NED is its own inverse
    w = np.degrees(frames.body_vector_to_frd(r["omega_B"][0], "flu"))
    tau = frames.body_vector_to_frd(r["tau_B"][0], "flu")
    mass = load_preset("pelican").mass  # the nominal mass the estimate will use
    u = r["thrust"][0] * HOVER / (mass * 9.81)
    cols = {
        "time": t, "vel_x": v[:, 0], "vel_y": v[:, 1], "vel_z": v[:, 2],
        "q0": q[:, 0], "q1": q[:, 1], "q2": q[:, 2], "q3": q[:, 3],
        "wx": w[:, 0], "wy": w[:, 1], "wz": w[:, 2], "thrust_norm": u, "hover_thrust": np.full(len(t), HOVER),
        "tx": tau[:, 0], "ty": tau[:, 1], "tz": tau[:, 2],
    }  # fmt: skip
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    est = r.config["controllers"][0]["estimator"]  # what ran in flight: its bandwidth and timing
    return {"t": t, "f_lumped_W": r["f_lumped_W"][0], "f_hat_sim": r["f_hat_W"][0]}, est


def run(folder: Path = Path("results/example-estimate"), duration: float = 30.0) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    truth, est = write_ros_style_csv(folder / "flight.csv", duration)
    rc = cli(
        [
            "estimate", str(folder / "flight.csv"), "--vehicle", "pelican",
            "--world", "enu", "--body", "flu", "--quat-order", "xyzw", "--angle-unit", "deg",
            "--column", "t_s=time", "--column", "vx=vel_x", "--column", "vy=vel_y", "--column", "vz=vel_z",
            # the estimator that flew: its bandwidth, the latencies it aligned to, its rotor model
            "--wn", str(est["wn"][0]), "--velocity-delay", str(est["velocity_delay"]),
            "--attitude-delay", str(est["attitude_delay"]), "--rotor-tau", str(est["rotor_tau"]),
            "--zero-phase", "--out", str(folder / "estimate"),
        ]
    )  # fmt: skip
    assert rc == 0
    # the same file without the convention flags: the data decide them
    renames = ["--column", "t_s=time", "--column", "vx=vel_x", "--column", "vy=vel_y", "--column", "vz=vel_z"]
    rc = cli(["estimate", str(folder / "flight.csv"), "--vehicle", "pelican", *renames, "--conventions", "auto",
              "--out", str(folder / "estimate-auto"), "--no-plots", "--quiet"])  # fmt: skip
    assert rc == 0
    chosen = json.loads((folder / "estimate-auto" / "estimate.json").read_text())["info"]["conventions"]["chosen"]
    assert (chosen["world"], chosen["body"], chosen["quat_order"], chosen["rate_unit"]) == ("enu", "flu", "xyzw", "deg")
    print("conventions found by --conventions auto:", {k: chosen[k] for k in ("world", "body", "quat_order")},
          f"rates in {chosen['rate_unit']}")  # fmt: skip
    est = np.genfromtxt(folder / "estimate" / "wrench.csv", delimiter=",", names=True)
    on_log = {k: np.stack([np.interp(est["t_s"], truth["t"], truth[k][:, i]) for i in range(3)], -1) for k in truth
              if k != "t"}  # fmt: skip
    f_est = np.stack([est["fx_W_N"], est["fy_W_N"], est["fz_W_N"]], -1)
    late = est["t_s"] > 1.0
    rms = lambda a, b: float(np.sqrt(np.mean(np.sum((a - b)[late] ** 2, -1))))  # noqa: E731
    print(
        f"RMS |f_hat(log) - f_true|: {rms(f_est, on_log['f_lumped_W']):.3f} N (the fan's turbulence is above G's band)"
    )
    print(f"RMS |f_hat(log) - f_hat(in flight)|: {rms(f_est, on_log['f_hat_sim']):.4f} N")
    return {"t": est["t_s"], "f_est": f_est, "f_true": on_log["f_lumped_W"], "f_flight": on_log["f_hat_sim"]}


def plot(out: dict):
    """The estimate read from the log against the true wrench and the estimate computed in flight."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(7, 6))
    for i, ax in enumerate(axes):
        ax.plot(out["t"], out["f_true"][:, i], color="0.6", lw=0.8, label="true (everything the model misses)")
        ax.plot(out["t"], out["f_flight"][:, i], color="tab:orange", lw=2.5, alpha=0.6, label="estimated in flight")
        ax.plot(out["t"], out["f_est"][:, i], color="tab:blue", lw=1.0, label="estimated from the log")
        ax.set_ylabel(f"$f_{'xyz'[i]}$ [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize="small")
    axes[-1].set_xlabel("time [s]")
    fig.suptitle("Case B: external force, world NED (+z down)")
    fig.tight_layout()
    return fig


# %%
# Write the log, estimate, compare
# --------------------------------
# The payload's weight (+1.08 N along +z, down) appears at take-off, the fan's push along +x once the
# vehicle hovers in its jet. The estimate read from the log is the one computed in flight: the same
# equations on the same numbers, after two frame conversions.

if __name__ == "__main__":
    import matplotlib.pyplot as plt

    parser = argparse.ArgumentParser(description="Estimate the wrench from a ROS-style flight log.")
    parser.add_argument("--duration", type=float, default=30.0, help="flight time, s")
    parser.add_argument("--out", type=Path, default=Path("results/example-estimate"), help="folder for the log")
    args = parser.parse_args()
    plot(run(args.out, args.duration))
    plt.show()
