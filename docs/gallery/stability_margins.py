"""
Stability margins of the paper's loop
=====================================

Linearise the sampled closed loop that the simulator flies (controller, estimator, sensor latency, rotor
lag; :mod:`vtol_impedance.robust`) and read its margins, for the hover *without* payload, where the
paper's controller has least margin:

* the paper's controller as printed (attitude 8 rad/s, estimator 10 rad/s, no timing alignment);
* this package's designed defaults (:func:`vtol_impedance.robust.design`), with the same position
  impedance ``K_p = 16``, ``D_p = 12``.

The command line does the same with ``vtol-impedance margins case-a-payload --set payload.mass=0``.
"""

import matplotlib.pyplot as plt
import numpy as np

from vtol_impedance.robust import linearize, margins
from vtol_impedance.scenarios import build, controller_params, get, set_value
from vtol_impedance.scenarios.spec import PAPER_CONTROL

designed = set_value(get("case-a-payload"), "payload.mass", 0.0)
paper = designed
for key, value in PAPER_CONTROL.items():
    paper = set_value(paper, key, value)

reports = {}
for tuning, spec in (("paper", paper), ("designed", designed)):
    b = build(spec)
    for variant in ("pd", "pdc"):
        loop = linearize(controller_params(spec, variant), b.plant, b.sensors, p_W=(0.0, 0.0, -1.0))
        reports[tuning, variant] = report = margins(loop)
        s = report.summary()
        verdict = "stable" if report.stable else "UNSTABLE"
        print(
            f"{tuning:>8} {variant:>4}: {verdict:<8} least phase margin {s['pm_min_deg']:6.1f} deg, "
            f"rightmost pole {report.rightmost:.3f} rad/s"
        )

# %%
# The roll torque loop on the Nyquist plane
# -----------------------------------------
# Each curve is ``L(e^{jωTs})`` of the loop broken at the roll torque command, the others closed. The
# paper's PD+C encircles −1: its closed loop has a pole in the right half-plane (a slowly growing
# 2 Hz oscillation); the designed defaults keep about 30° from it for both controllers.

fig, ax = plt.subplots(figsize=(5.5, 5.5))
for (tuning, variant), report in reports.items():
    L = report.loops["roll torque"].response
    style = "-" if tuning == "designed" else "--"
    (line,) = ax.plot(L.real, L.imag, ls=style, label=f"{tuning}, {variant.upper().replace('C', '+C')}")
    ax.plot(L.real, -L.imag, ls=style, color=line.get_color(), lw=0.5, alpha=0.5)
theta = np.linspace(0.0, 2.0 * np.pi, 200)
ax.plot(np.cos(theta), np.sin(theta), color="0.7", lw=0.8, ls=":")
ax.plot([-1], [0], "r+", ms=12)
ax.set_xlim(-2.5, 1.0)
ax.set_ylim(-1.75, 1.75)
ax.set_aspect("equal")
ax.set_xlabel("Re L")
ax.set_ylabel("Im L")
ax.set_title("roll torque loop, hover without payload")
ax.legend(loc="lower left")
ax.grid(alpha=0.3)
fig.tight_layout()
