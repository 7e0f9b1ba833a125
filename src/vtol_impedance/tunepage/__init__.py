"""The tuning page: sliders for the gains, the estimator and the vehicle's timing, and at once the stability
margins, the pre-flight verdict and three short flights (``vtol-impedance tune-page``; docs/guide/tuning-page.md).

:class:`TunePage` computes (the package's margin check and compiled engine, no copy of either);
:func:`make_server` serves it on the loopback interface with the standard library's HTTP server.
"""

from .app import BUDGET_MS, COMPENSATING, FIELDS, Field, TunePage
from .server import Latest, Superseded, is_loopback, make_server

__all__ = ["BUDGET_MS", "COMPENSATING", "FIELDS", "Field", "Latest", "Superseded", "TunePage", "is_loopback",
           "make_server"]  # fmt: skip
