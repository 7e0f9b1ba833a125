"""The tuning page's web server: the standard library's threading HTTP server, one HTML page with plain
JavaScript and inline SVG (nothing loaded from the network: it works offline), and a small JSON API.

Routes: ``GET /`` the page; ``GET /api/fields`` the controls and the defaults; ``POST /api/evaluate``
``{"tab", "seq", "values", "compensating"}`` the margins, verdict and flights of a tuning;
``POST /api/design`` the designed bandwidths; ``POST /api/toml`` the tuning as a scenario file.
A bad value answers ``400 {"error", "key"}`` with the scenario's message.

The latest state wins: each tab numbers its requests; one evaluation runs at a time, and a request
waiting for it is answered ``409 {"superseded": true}`` as soon as a newer one of its tab arrives, so a
dragged slider never queues stale work. The server binds to the loopback interface unless told
otherwise, and then answers only requests addressed to a loopback name (no DNS rebinding).
"""

from __future__ import annotations

import ipaddress
import json
import threading
from collections import OrderedDict
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from ..errors import InputError, VtolImpedanceError, flag, instance, scalar
from .app import BUDGET_MS, FIELDS, TunePage

#: The largest request body accepted, bytes.
MAX_BODY = 65536
#: Tabs whose newest request number is remembered (the oldest forgotten first).
MAX_TABS = 64
_LOOPBACK_NAMES = ("localhost", "localhost.localdomain")


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is this machine's loopback interface."""
    instance("host", host, str)
    if host.lower() in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class Superseded(Exception):
    """A request overtaken by a newer one of its tab before it ran."""


class Latest:
    """One computation at a time; a waiting request is dropped when a newer one of its tab arrives."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._newest: OrderedDict[str, int] = OrderedDict()
        self._busy = False
        self.dropped = 0

    def run(self, tab: str, seq: int, fn: Callable[[], Any]) -> Any:
        """``fn()`` once no other computation runs, unless a request of ``tab`` numbered above ``seq``
        arrives first (then :class:`Superseded`)."""
        with self._cond:
            if seq <= self._newest.get(tab, -1):
                self.dropped += 1
                raise Superseded
            self._newest[tab] = seq
            self._newest.move_to_end(tab)
            while len(self._newest) > MAX_TABS:
                self._newest.popitem(last=False)
            self._cond.notify_all()  # an older request of this tab, waiting, gives up now
            while self._busy:
                self._cond.wait()
                if self._newest.get(tab) != seq:
                    self.dropped += 1
                    self._cond.notify_all()
                    raise Superseded
            self._busy = True
        try:
            return fn()
        finally:
            with self._cond:
                self._busy = False
                self._cond.notify_all()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    app: TunePage
    latest: Latest
    allow_remote: bool


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002  (quiet: the terminal shows the URL)
        pass

    def _send(self, status: int, body: bytes, kind: str = "application/json") -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):  # the tab was closed: nobody to answer
            self.close_connection = True

    def _json(self, status: int, data: Any) -> None:
        self._send(status, json.dumps(data, allow_nan=False).encode())

    def _allowed(self) -> bool:
        host = urlsplit("//" + (self.headers.get("Host") or "")).hostname or ""
        if self.server.allow_remote or is_loopback(host):
            return True
        self._json(HTTPStatus.FORBIDDEN, {"error": f"this server answers requests to 127.0.0.1, not to {host!r}"})
        return False

    def do_GET(self) -> None:  # noqa: N802  (http.server's name)
        if not self._allowed():
            return
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            page = resources.files("vtol_impedance.tunepage").joinpath("page.html").read_bytes()
            self._send(HTTPStatus.OK, page, "text/html; charset=utf-8")
        elif path == "/api/fields":
            app = self.server.app
            self._json(HTTPStatus.OK, {
                "fields": [f.__dict__ for f in FIELDS], "defaults": app.defaults, "scenario": app.base_name,
                "vehicle": app.base.vehicle, "budget_ms": BUDGET_MS,
            })  # fmt: skip
        else:
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no page {path!r}"})

    def do_POST(self) -> None:  # noqa: N802
        if not self._allowed():
            return
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            n = -1
        if not 0 <= n <= MAX_BODY:
            self.close_connection = True
            return self._json(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, {"error": f"a request body is 0-{MAX_BODY} bytes"})
        try:
            body = json.loads(self.rfile.read(n) or b"{}")
            if not isinstance(body, dict):
                raise InputError("the request body must be a JSON object")
            status, out = self._route(self.path, body)
        except json.JSONDecodeError as exc:
            status, out = HTTPStatus.BAD_REQUEST, {"error": f"the request body is not JSON: {exc}"}
        except VtolImpedanceError as exc:
            status, out = HTTPStatus.BAD_REQUEST, {"error": str(exc), "key": _key_of(str(exc))}
        except Exception as exc:  # noqa: BLE001  (the page shows it; the server keeps serving)
            status, out = HTTPStatus.INTERNAL_SERVER_ERROR, {"error": f"internal error ({type(exc).__name__}: {exc})"}
        self._json(status, out)

    def _route(self, path: str, body: dict[str, Any]) -> tuple[int, Any]:
        app = self.server.app
        values = body.get("values", {})
        if path == "/api/evaluate":
            tab = instance("tab", body.get("tab", ""), str)[:64]
            seq = int(scalar("seq", body.get("seq", 0), lo=0, integer=True))
            comp = body.get("compensating", "pdc")
            app.spec_of(values)  # a bad value is answered at once, not after the evaluation running now
            try:
                out = self.server.latest.run(tab, seq, lambda: app.evaluate(values, comp, body.get("loop") or None))
            except Superseded:
                return HTTPStatus.CONFLICT, {"seq": seq, "superseded": True}
            return HTTPStatus.OK, {"seq": seq, **out}
        if path == "/api/design":
            return HTTPStatus.OK, app.designed(values)
        if path == "/api/toml":
            return HTTPStatus.OK, {"toml": app.toml(values), "filename": f"{app.base.name}.toml"}
        return HTTPStatus.NOT_FOUND, {"error": f"no API {path!r}"}


def _key_of(message: str) -> str | None:
    """The page's key an error names (its box is marked), if any."""
    keys = sorted({f.key for f in FIELDS} | {f.key.partition("[")[0] for f in FIELDS}, key=len, reverse=True)
    return next((k for k in keys if k in message), None)


def make_server(app: TunePage, host: str = "127.0.0.1", port: int = 0, allow_remote: bool = False) -> _Server:
    """A threading HTTP server of ``app`` bound to ``host``:``port`` (0: a free port), not yet serving
    (call ``serve_forever``; ``server_address`` holds the port). A host other than the loopback interface
    is refused unless ``allow_remote``: the page runs simulations for whoever reaches it."""
    instance("app", app, TunePage)
    instance("host", host, str)
    port = int(scalar("port", port, lo=0, hi=65535, integer=True))
    flag("allow_remote", allow_remote)
    if not allow_remote and not is_loopback(host):
        raise InputError(
            f"host {host!r} is not the loopback interface: the tuning page runs simulations for whoever reaches "
            "it; bind 127.0.0.1, or pass --allow-remote (allow_remote=True) to serve the network"
        )
    family_v6 = ":" in host
    cls = type("_Server6", (_Server,), {"address_family": __import__("socket").AF_INET6}) if family_v6 else _Server
    try:
        server = cls((host.strip("[]"), port), _Handler)
    except OSError as exc:
        raise InputError(f"cannot serve on {host}:{port}: {exc.strerror or exc}") from None
    server.app, server.latest, server.allow_remote = app, Latest(), allow_remote
    return server


__all__ = ["Latest", "Superseded", "is_loopback", "make_server"]
