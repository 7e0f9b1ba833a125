r"""
Reject or comply
================

The same controller either rejects a push (stiff, the paper's PD+C) or yields to it with a programmed
apparent mass, damping and stiffness and comes back when it stops (the ``comply`` variant):

.. math::

   M_d \ddot e + D_d \dot e + K_d e = f_{ext}

The ``operator-push`` scenario: the vehicle hovers, a hand pushes 3 N peak along x for 2.5 s (a
half-sine) and lets go. Comply is switched on along x and y once airborne.
"""

import matplotlib.pyplot as plt
import numpy as np

from vtol_impedance.scenarios import get, simulate

NAMES = {"pd": "PD", "pdc": "PD+C (reject)", "comply": "comply"}

spec = get("operator-push")
print(spec.name, "- interaction:", spec.interaction)
r = simulate(spec, ["pd", "pdc", "comply"], seed=0)

# %%
# Displacement along the push
# ---------------------------
# PD yields by its own stiffness ``K_p`` (16 N/m); PD+C rejects most of the push, up to what the
# estimator's lag lets through; comply yields with the set impedance and returns.

fig, (ax_x, ax_f) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
for b, label in enumerate(r.labels):
    ax_x.plot(r.t, 100 * r.e_p[b, :, 0], label=NAMES[label])
    print(f"{NAMES[label]:>13}: largest displacement along x {100 * np.abs(r.e_p[b, :, 0]).max():.1f} cm")
ax_x.set_ylabel("$x - x_d$ [cm]")
ax_x.legend()
b = r.index("comply")
ax_f.plot(r.t, r["f_ext_W"][b, :, 0], color="0.5", lw=0.8, label="push (true)")
ax_f.plot(r.t, r["f_hat_W"][b, :, 0], color="C2", lw=2.0, label="estimate (comply)")
ax_f.set_ylabel("force along x [N]")
ax_f.set_xlabel("time [s]")
ax_f.legend()
for ax in (ax_x, ax_f):
    ax.grid(alpha=0.3)
fig.tight_layout()
