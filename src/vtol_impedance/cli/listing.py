"""``vtol-impedance list``: the registered scenarios and controllers."""

from __future__ import annotations

import argparse
from typing import Any


def cmd_list(args: argparse.Namespace) -> int:
    from ..control.impedance import VARIANTS
    from ..scenarios import get, names

    print("scenarios (a name without -vN means its latest version):")
    for n in names(latest_only=False):
        print(f"  {n:<22} {get(n).description}")
    print("controllers:")
    for k, v in VARIANTS.items():
        print(f"  {k:<22} {v}")
    return 0


def register(sub: Any) -> None:
    """Add the 'list' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("list", help="registered scenarios and controllers")
    sp.set_defaults(func=cmd_list)
