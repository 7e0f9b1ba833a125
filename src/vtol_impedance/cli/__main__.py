"""``python -m vtol_impedance.cli``."""

import sys

from .main import main

sys.exit(main())
