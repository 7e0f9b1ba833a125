"""vtol-impedance: impedance control of multirotor UAVs with a momentum-based external wrench estimator.

Implements Ruggiero, Cacace, Sadeghian, Lippiello, "Impedance Control of VTOL UAVs with a
Momentum-based External Generalized Forces Estimator", ICRA 2014.

Subpackages: :mod:`.model` (eqs. 1-5), :mod:`.estimator` (eqs. 6-13), :mod:`.control` (eqs. 14-20),
:mod:`.sim` (true plant, disturbances, sensors, closed loop), :mod:`.scenarios` (the paper's case
studies), :mod:`.analysis` (metrics, figures, reports). :class:`Controller` (in :mod:`.runtime`) is the
controller for a flight loop, :class:`Estimator` the estimator alone fed one sample at a time (telemetry),
both on either backend.
"""

__version__ = "0.1.0"

_RUNTIME = ("Controller", "ControllerWarning", "Estimator", "EstimatorOutput")
__all__ = [*_RUNTIME, "__version__"]


def __getattr__(name: str):  # the controller on demand: importing the package stays light (no numba)
    if name in _RUNTIME:
        from . import runtime

        return getattr(runtime, name)
    raise AttributeError(f"module 'vtol_impedance' has no attribute {name!r}")
