"""vtol-impedance: impedance control of multirotor UAVs with a momentum-based external wrench estimator.

Implements Ruggiero, Cacace, Sadeghian, Lippiello, "Impedance Control of VTOL UAVs with a
Momentum-based External Generalized Forces Estimator", ICRA 2014.

Subpackages: :mod:`.model` (eqs. 1-5), :mod:`.estimator` (eqs. 6-13), :mod:`.control` (eqs. 14-20),
:mod:`.sim` (true plant, disturbances, sensors, closed loop), :mod:`.scenarios` (the paper's case
studies), :mod:`.analysis` (metrics, figures, reports).
"""

__version__ = "0.1.0"
