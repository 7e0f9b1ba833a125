"""Use the estimator + impedance controller outside the simulator, as in a flight loop at 100 Hz.

Here the "vehicle" is the library's true plant with an unmodelled payload; in a real system the
measurements come from motion capture and the IMU (``omega_B`` is the gyro's body rate, FRD), and
``out.f_rotor`` goes to the motors. Quaternions crossing this API are ``[w, x, y, z]``, body to world.
Run: python examples/controller_in_your_loop.py
"""

import numpy as np

from vtol_impedance import Controller
from vtol_impedance.control import ControllerParams, Measurement, Reference
from vtol_impedance.model import load_preset
from vtol_impedance.model.kinematics import euler_from_rotation, quat_to_rotation
from vtol_impedance.sim import PlantParams, compile_plants, rk4_step
from vtol_impedance.sim.plant import OMEGA, QUAT, initial_state, origin_kinematics


def main(seconds: float = 8.0) -> np.ndarray:
    nominal = load_preset("pelican")
    ctrl = Controller(ControllerParams.paper("pdc", vehicle=nominal))  # the paper's PD+C, 100 Hz
    plant = compile_plants(PlantParams(nominal, payload_mass=0.110, ground=False))  # 110 g it does not know about
    x = initial_state(plant, np.array([0.0, 0.0, -1.0]))
    hold = Reference(np.array([0.0, 0.0, -1.0]))  # hold 1 m up (NED), nose north; the rest defaults to 0

    ctrl.reset()  # a new flight starts with no estimate
    for k in range(int(seconds / 0.01)):
        p_W, v_W = origin_kinematics(plant, x)
        eta = euler_from_rotation(quat_to_rotation(x[QUAT]))
        out = ctrl.step(Measurement(p_W, v_W, eta, omega_B=x[OMEGA]), hold)
        for j in range(10):  # 1 kHz plant, command held for 10 ms
            x = rk4_step(plant, x, out.f_rotor, k * 0.01 + j * 1e-3, 1e-3)

    print(f"estimated external force f_hat_W = {np.round(out.f_hat_W, 3)} N (payload weight 1.079 N, +z is down)")
    print(f"position error = {1000 * (p_W - hold.p_W)} mm, thrust {out.thrust:.3f} N")
    return out.f_hat_W


if __name__ == "__main__":
    main()
