"""
The controller in your own loop
===============================

Use the estimator and the impedance controller outside the simulator, as in a flight loop at 100 Hz.

Here the "vehicle" is the library's true plant carrying a 110 g payload the controller does not know
about; in a real system the measurements come from motion capture and the IMU (``omega_B`` is the
gyro's body rate, FRD), and ``out.f_rotor`` goes to the motors. Quaternions crossing this API are
``[w, x, y, z]``, body to world.

Run: ``python examples/controller_in_your_loop.py [--seconds 8]``
"""

import argparse

import numpy as np

from vtol_impedance import Controller
from vtol_impedance.control import ControllerParams, Measurement, Reference
from vtol_impedance.model import load_preset
from vtol_impedance.model.kinematics import euler_from_rotation, quat_to_rotation
from vtol_impedance.sim import PlantParams, compile_plants, rk4_step
from vtol_impedance.sim.plant import OMEGA, QUAT, initial_state, origin_kinematics


def fly(seconds: float = 8.0) -> dict[str, np.ndarray]:
    """Hold 1 m up for ``seconds``; return the time, position and estimated force at every control tick."""
    nominal = load_preset("pelican")
    ctrl = Controller(ControllerParams.paper("pdc", vehicle=nominal))  # the paper's PD+C, 100 Hz
    plant = compile_plants(PlantParams(nominal, payload_mass=0.110, ground=False))  # 110 g it does not know about
    x = initial_state(plant, np.array([0.0, 0.0, -1.0]))
    hold = Reference(np.array([0.0, 0.0, -1.0]))  # hold 1 m up (NED), nose north; the rest defaults to 0

    ctrl.reset()  # a new flight starts with no estimate
    log = {"t": [], "p_W": [], "f_hat_W": [], "thrust": []}
    for k in range(int(round(seconds / 0.01))):
        p_W, v_W = origin_kinematics(plant, x)
        eta = euler_from_rotation(quat_to_rotation(x[QUAT]))
        out = ctrl.step(Measurement(p_W, v_W, eta, omega_B=x[OMEGA]), hold)
        for j in range(10):  # 1 kHz plant, command held for 10 ms
            x = rk4_step(plant, x, out.f_rotor, k * 0.01 + j * 1e-3, 1e-3)
        for key, value in (("t", k * 0.01), ("p_W", p_W), ("f_hat_W", out.f_hat_W), ("thrust", out.thrust)):
            log[key].append(value)
    return {key: np.asarray(value) for key, value in log.items()}


def report(log: dict[str, np.ndarray]) -> np.ndarray:
    """Print the final estimate and position error; return the final ``f_hat_W`` (N, world NED)."""
    f_hat, p_W = log["f_hat_W"][-1], log["p_W"][-1]
    print(f"estimated external force f_hat_W = {np.round(f_hat, 3)} N (payload weight 1.079 N, +z is down)")
    print(f"position error = {np.round(1000 * (p_W - [0.0, 0.0, -1.0]), 3)} mm, thrust {log['thrust'][-1]:.3f} N")
    return f_hat


def main(seconds: float = 8.0) -> np.ndarray:
    """Fly and report; return the final ``f_hat_W``."""
    return report(fly(seconds))


# %%
# Fly and look
# ------------
# The estimate finds the payload's weight, +1.079 N along +z (down, NED), within half a second
# (the estimator's ``G(s)`` with 10 rad/s, ζ = 1), and the compensated controller holds the height.

if __name__ == "__main__":
    import matplotlib.pyplot as plt

    parser = argparse.ArgumentParser(description="The estimator and the controller in your own loop.")
    parser.add_argument("--seconds", type=float, default=8.0, help="flight time, s")
    seconds = parser.parse_args().seconds

    log = fly(seconds)
    report(log)

    fig, (ax_f, ax_z) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    for i, axis in enumerate("xyz"):
        ax_f.plot(log["t"], log["f_hat_W"][:, i], label=f"$\\hat f_{axis}$")
    ax_f.axhline(0.110 * 9.81, color="k", lw=0.8, ls="--", label="payload weight")
    ax_f.set_ylabel("estimated force [N]\n(world NED)")
    ax_f.legend(loc="right")
    ax_z.plot(log["t"], 1000 * (log["p_W"][:, 2] + 1.0))
    ax_z.set_ylabel("height error $z + 1$ [mm]\n(+ is below)")
    ax_z.set_xlabel("time [s]")
    for ax in (ax_f, ax_z):
        ax.grid(alpha=0.3)
    fig.suptitle("PD+C holding 1 m with an unmodelled 110 g payload")
    fig.tight_layout()
    plt.show()
