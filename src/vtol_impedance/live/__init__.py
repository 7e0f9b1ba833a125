"""Live: the estimator and the outer impedance loop on a flying vehicle over MAVLink.

* :mod:`.streams`: what PX4 and ArduPilot stream, which message gives which input, in which units;
* :mod:`.link`: addresses, the connection, the ``.tlog`` recording, heartbeats and commands;
* :mod:`.estimator`: :class:`LiveEstimator`, eqs. (6)-(13) on asynchronous telemetry (the same class replays
  a recording, :func:`replay`);
* :mod:`.display`: the steady one-screen display;
* :mod:`.control`: the outer loop offboard (eqs. (16)-(20), ``SET_ATTITUDE_TARGET``) and its safety;
* :mod:`.autopilot`: a simulated autopilot behind a MAVLink endpoint (the project's simulator);
* :mod:`.session`: :func:`run_live`, one session from connection to run folder.

This package sits above the library (it imports :mod:`vtol_impedance.runtime`, ``control``, ``sim`` and
``scenarios``); nothing below imports it.
"""

from .control import ControlSettings, OffboardController, OuterLoop
from .estimator import EstimatorSettings, LiveEstimator, Tick, replay
from .link import LiveError, parse_address
from .session import LiveResult, LiveSettings, run_live
from .streams import ARDUPILOT, PROFILES, PX4, ThrustMap

__all__ = [
    "ARDUPILOT",
    "PROFILES",
    "PX4",
    "ControlSettings",
    "EstimatorSettings",
    "LiveError",
    "LiveEstimator",
    "LiveResult",
    "LiveSettings",
    "OffboardController",
    "OuterLoop",
    "ThrustMap",
    "Tick",
    "parse_address",
    "replay",
    "run_live",
]
