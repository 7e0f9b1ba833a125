"""Command-line interface: ``vtol-impedance {paper,run,compare,margins,estimate,live,sim-autopilot,sweep,sweep-report,
tune,bench,list}``.

Heavy modules are imported inside the commands so that ``--help`` answers at once.

One module per command, each owning its parser (``register``) and handler; :mod:`.main` registers them.
"""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
