"""The entry point: the parser with every command registered, exit codes, and no traceback unless asked."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .. import __version__
from . import (
    bench,
    design,
    estimate,
    identify,
    listing,
    live,
    margins,
    paper,
    run,
    sim_autopilot,
    sweep,
    tune,
    tune_page,
)

#: The commands, in the order ``--help`` lists them.
COMMANDS = (
    paper,
    run,
    margins,
    design,
    estimate,
    identify,
    sweep,
    tune,
    tune_page,
    bench,
    live,
    sim_autopilot,
    listing,
)


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``vtol-impedance`` with every command registered (one module each)."""
    p = argparse.ArgumentParser(
        prog="vtol-impedance",
        description="Impedance control of VTOL UAVs with a momentum-based wrench estimator "
        "(Ruggiero et al., ICRA 2014): simulate the paper's case studies and your own.",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
    return p


def _terminate(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt  # unwind: staging folders are removed, workers stopped


def main(argv: list[str] | None = None) -> int:
    """Entry point. Exit codes: 0 done, 1 the run failed (an I/O or internal error), 2 a usage error
    (a bad value, named in the message), 130 interrupted. No traceback is printed unless the environment
    variable ``VTOL_IMPEDANCE_DEBUG`` is set."""
    import os
    import signal

    args = build_parser().parse_args(argv)
    import warnings

    from ..errors import VtolImpedanceError

    previous = signal.getsignal(signal.SIGTERM)
    if threading_main():
        signal.signal(signal.SIGTERM, _terminate)
    try:
        with warnings.catch_warnings():
            seen: set[str] = set()

            def show(message: Any, *rest: Any, **kw: Any) -> None:  # one line, once, no source path
                if str(message) not in seen:
                    seen.add(str(message))
                    print(f"warning: {message}", file=sys.stderr)

            warnings.showwarning = show
            if getattr(args, "out", None) is not None and not str(args.out).strip():
                from ..errors import InputError

                raise InputError("--out is empty: give a folder (or leave --out out for the default)")
            keys = [a.split("=", 1)[0].strip() for a in getattr(args, "set", None) or [] if "=" in str(a)]
            for i, k in enumerate(keys):  # the last would win in silence; a vector and one of its entries too
                for other in keys[:i]:
                    from ..scenarios.spec import keys_overlap

                    if keys_overlap(other, k):
                        from ..errors import InputError

                        both = k if other == k else f"{other} and {k}"
                        raise InputError(f"--set {both} given more than once: set each value once")
            return int(args.func(args))
    except VtolImpedanceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; no results were written", file=sys.stderr)
        return 130
    except OSError as exc:
        import errno

        from ..io import explain_path, user_path

        name = user_path(exc.filename) if exc.filename else None  # the user's path, never a staging one
        path_fault = name and exc.errno in (errno.ENOENT, errno.EACCES, errno.ENOTDIR, errno.ELOOP)
        why = (explain_path(Path(name).parent, "folder") or explain_path(name, "file")) if path_fault else None
        print(f"error: cannot write or read {name or 'a file'}: {why or exc.strerror or exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # the CLI never shows a traceback unless asked
        if _interrupted(exc):  # a library's clean-up failed on the way out of an interrupt (PillowWriter)
            print("interrupted; no results were written", file=sys.stderr)
            return 130
        if os.environ.get("VTOL_IMPEDANCE_DEBUG"):
            raise
        print(
            f"error: internal error ({type(exc).__name__}: {exc}); please report it with the command line "
            "(set VTOL_IMPEDANCE_DEBUG=1 to see the traceback)",
            file=sys.stderr,
        )
        return 1
    finally:
        if threading_main():
            signal.signal(signal.SIGTERM, previous)


def _interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` was raised while an interrupt (Ctrl-C, SIGTERM) was being handled."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__context__
    return False


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
