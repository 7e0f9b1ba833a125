"""Frames, constants and sign conventions used everywhere in the package.

World frame W is North-East-Down (z points down), body frame B is Forward-Right-Down.
Attitude is the ZYX Euler triple ``eta = [phi, theta, psi]`` with ``R_WB = Rz(psi) Ry(theta) Rx(phi)``.
Thrust acts along ``-z_B``, so eq. (5a) of Ruggiero et al. (2014) reads
``m p_ddot = m g_W - u R_WB e3 + f_ext_W``.

Every other module imports these names rather than redefining them.
"""

from __future__ import annotations

import numpy as np

#: Standard gravity used in the paper, m/s^2.
G: float = 9.81
#: Gravity vector in the NED world frame (down is +z).
GRAVITY_W: np.ndarray = np.array([0.0, 0.0, G])
GRAVITY_W.setflags(write=False)
#: Third axis unit vector.
E3: np.ndarray = np.array([0.0, 0.0, 1.0])
E3.setflags(write=False)
#: ``v_NED = T_NED_ENU v_ENU`` (swap x and y, flip z) and ``v_FRD = T_FRD_FLU v_FLU`` (flip y and z): the
#: z-up conventions of ROS logs and of MuJoCo. Each matrix is its own inverse.
T_NED_ENU: np.ndarray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
T_NED_ENU.setflags(write=False)
#: ``v_FRD = T_FRD_FLU v_FLU``: body Forward-Right-Down from Forward-Left-Up (flip y and z); its own inverse.
T_FRD_FLU: np.ndarray = np.diag([1.0, -1.0, -1.0])
T_FRD_FLU.setflags(write=False)
#: Distance of ``|cos(theta)|`` from zero under which the Euler parametrisation is declared singular.
SINGULARITY_COS_EPS: float = 1e-3
#: Largest magnitude of the pitch a ZYX Euler triple has (pi/2, with rounding's margin): a measured pitch
#: beyond it is in degrees or of another convention, and is refused.
MAX_PITCH_RAD: float = 0.5 * np.pi + 1e-9
