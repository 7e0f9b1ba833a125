"""Measure what the bandwidth of the filter on the desired roll/pitch trades (README, "Python API").

A slow filter smooths eta_d (smaller torque peaks) but lags, so the compensated loop reacts late to the
estimate; a fast one passes the estimate's jitter into the torque and can saturate the rotors. Flies PD+C
through the paper's gusty fan case (B) and the circle (C) with every effect on, for several bandwidths.
Run: python examples/attitude_filter_bandwidth.py
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


if __name__ == "__main__":
    main()
