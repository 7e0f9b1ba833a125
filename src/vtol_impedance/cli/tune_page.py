"""``vtol-impedance tune-page``: the tuning page, served on this machine (docs/guide/tuning-page.md)."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any


def cmd_tune_page(args: argparse.Namespace) -> int:
    """Serve the tuning page until interrupted (Ctrl-C)."""
    import threading

    from ..errors import scalar
    from ..scenarios import get
    from ..tunepage import TunePage, make_server

    t0 = time.perf_counter()
    scalar("--port", args.port, lo=0, hi=65535, integer=True)  # named as the command line names them
    scalar("--workers", args.workers, lo=0, hi=8, integer=True)
    app = TunePage(get(args.scenario), args.vehicle, workers=args.workers)
    server = make_server(app, args.host, args.port, args.allow_remote)  # refuses a remote bind before any work

    def warm() -> None:  # the first change is then as fast as the next; a request meanwhile waits for it
        try:
            app.start()
        except Exception as exc:  # noqa: BLE001 - a thread's error would print as a traceback
            if app._pool is None and args.workers:  # stopped meanwhile (Ctrl-C): the pool shut down under it
                return
            print(f"warning: the warm-up failed ({type(exc).__name__}: {exc}); the first change will be slower",
                  file=sys.stderr, flush=True)  # fmt: skip
            return
        if not args.quiet:
            print(f"warmed up in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    app.open_pool()  # here, not in the warm-up: an interrupt then always finds the pool to stop
    warming = threading.Thread(target=warm, daemon=True)
    try:
        warming.start()
        host, port = server.server_address[:2]
        url = f"http://{'[' + host + ']' if ':' in host else host}:{port}/"
        print(f"tuning page at {url} (Ctrl-C stops it)", flush=True)
        if not args.no_browser:
            import webbrowser

            webbrowser.open(url)
        server.serve_forever()
    except KeyboardInterrupt:
        if warming.is_alive():
            # Stopped while the warm-up still runs compiled code: the interpreter's shutdown would tear the
            # native thread pools down under it and abort the process (seen in CI as a -6 exit). Nothing is
            # written by this command, so the process ends here, with the CLI's message and code.
            import gc
            import multiprocessing.util
            import os

            server.server_close()
            app.close(wait=False)
            gc.collect()  # the pool's queues, and with them their locks
            # what the interpreter's exit would do for multiprocessing (its finalizers: the locks a queue of
            # the warm-up still holds), without the native thread pools' teardown
            getattr(multiprocessing.util, "_exit_function", lambda: None)()
            print("interrupted; no results were written", file=sys.stderr, flush=True)
            sys.stdout.flush()
            os._exit(130)
        raise
    finally:
        server.server_close()
        app.close()
    return 0


def register(sub: Any) -> None:
    """Add the 'tune-page' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "tune-page",
        help="a page in the browser: move the gains, see the margins, the verdict and three flights at once",
        description="Serves a page on this machine where sliders set the position and interaction impedance, the "
        "estimator, the attitude bandwidths and the vehicle's rotor lag, latencies, inertia and payload, and "
        "show within about 0.2 s the stability margins (Bode, Nyquist), the pre-flight verdict and a step, a "
        "push and a gust flown by PD and PD+C; the tuning is written as a scenario file that 'run' and "
        "'compare' fly. See docs/guide/tuning-page.md.",
    )
    sp.add_argument("vehicle", nargs="?", default=None,
                    help="a vehicle preset name or a vehicle .toml file (default: the scenario's)")  # fmt: skip
    sp.add_argument("--scenario", default="case-a-payload",
                    help="registered scenario whose operating point is tuned (default: case-a-payload)")  # fmt: skip
    sp.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1, this machine only)")
    sp.add_argument("--port", type=int, default=8765, help="port (default: 8765; 0: any free port)")
    sp.add_argument("--allow-remote", action="store_true",
                    help="allow a --host off this machine (whoever reaches it runs simulations)")  # fmt: skip
    sp.add_argument("--workers", type=int, default=2, help="processes for the margins (default: 2; 0: none)")
    sp.add_argument("--no-browser", action="store_true", help="do not open a browser")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    sp.set_defaults(func=cmd_tune_page)
