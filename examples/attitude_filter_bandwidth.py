"""
Bandwidth of the attitude filter
================================

Measure what the bandwidth of the filter on the desired roll and pitch trades.

The paper smooths ``eta_d`` of eq. (20) with a second-order low-pass filter that also gives its rates. A
slow filter smooths ``eta_d`` (smaller torque peaks) but lags, so the compensated loop reacts late to the
estimate; a fast one passes the estimate's jitter into the torque and can saturate the rotors. This flies
PD+C through the paper's gusty fan case (B) and the circle (C) with every effect on, for several
bandwidths and three seeds, and plots the position error against the peak roll/pitch torque.

Run: ``python examples/attitude_filter_bandwidth.py``
"""

import numpy as np

from vtol_impedance.scenarios import get, set_value, simulate
from vtol_impedance.sim.result import window_mask_of

BANDWIDTHS = (15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0)


def measure(bandwidths=BANDWIDTHS, cases=("case-b-fan", "case-c-circle"), seeds=(0, 1, 2)) -> list[dict]:
    rows = []
    for case in cases:
        for wn in bandwidths:
            rms, peak, limited, failed = [], [], [], 0
            for seed in seeds:
                spec = set_value(get(case), "control.attitude_filter_wn", wn)
                r = simulate(spec, ["pdc"], seed=seed)
                failed += r.failures[0] is not None
                m = window_mask_of(r.t, r.config["window"])
                e = np.linalg.norm(r.e_p[0, m], axis=-1)
                rms.append(np.sqrt(np.mean(e**2)))
                peak.append(np.abs(r["tau_B_request"][0, m, :2]).max())
                limited.append(np.mean(np.fmax(r["saturated"][0], r["tilt_limited"][0])))
            rows.append(
                {
                    "case": case,
                    "filter_wn": wn,
                    "rms_ep_cm": 100 * float(np.mean(rms)),
                    "peak_roll_pitch_torque_mNm": 1000 * float(np.mean(peak)),
                    "limited_pct": 100 * float(np.mean(limited)),
                    "diverged": f"{failed}/{len(seeds)}",
                }
            )
    return rows


def main() -> list[dict]:
    rows = measure()
    head = f"{'case':<16} {'wn [rad/s]':>10} {'RMS |e_p| [cm]':>15} {'peak |tau_xy| [mN m]':>21} {'limited [%]':>12}"
    print(head + f" {'diverged':>9}")
    for r in rows:
        print(
            f"{r['case']:<16} {r['filter_wn']:>10.0f} {r['rms_ep_cm']:>15.3f} "
            f"{r['peak_roll_pitch_torque_mNm']:>21.1f} {r['limited_pct']:>12.2f} {r['diverged']:>9}"
        )
    return rows


def plot(rows: list[dict]):
    """Error and torque peak against the filter bandwidth, one line per case."""
    import matplotlib.pyplot as plt

    fig, (ax_e, ax_t) = plt.subplots(1, 2, figsize=(9, 3.6))
    for case in dict.fromkeys(r["case"] for r in rows):
        mine = [r for r in rows if r["case"] == case]
        wn = [r["filter_wn"] for r in mine]
        ax_e.plot(wn, [r["rms_ep_cm"] for r in mine], "o-", label=case)
        ax_t.plot(wn, [r["peak_roll_pitch_torque_mNm"] for r in mine], "o-", label=case)
    ax_e.set_ylabel("RMS $\\|e_p\\|$ over the task [cm]")
    ax_t.set_ylabel("peak roll/pitch torque [mN m]")
    for ax in (ax_e, ax_t):
        ax.set_xlabel("attitude filter bandwidth [rad/s]")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("PD+C, realistic plant, mean of three seeds")
    fig.tight_layout()
    return fig


# %%
# Measure and plot
# ----------------
# The default (``control.attitude_filter_wn``) is designed with the attitude loop for each vehicle
# (:func:`vtol_impedance.robust.design`); with other latencies or vehicles, measure again.

if __name__ == "__main__":
    import matplotlib.pyplot as plt

    plot(main())
    plt.show()
