"""The MAVLink link: addresses, the connection, the recording, heartbeats and commands.

Addresses use pymavlink's notation: ``udpin:HOST:PORT`` (listen: the vehicle or its simulator sends to this
port, as PX4's simulators send to 14550), ``udpout:HOST:PORT`` (send to), ``udp:HOST:PORT`` (= ``udpin``),
``tcp:HOST:PORT`` (connect), ``tcpin:HOST:PORT`` (accept), or a serial device ``/dev/ttyUSB0`` or ``COM3``
with an optional ``,BAUD`` (default 57600, the telemetry radios' rate).

Everything received is written to a MAVLink telemetry log (``.tlog``: each packet as it arrived, preceded by
the receive time in microseconds since 1970 as 8 big-endian bytes, the format ground stations and
``pymavlink`` write), with the packets this tool sent, so a flight can be re-read exactly.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import select
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from ..errors import InputError

#: This tool on the link: a ground-station system id (MAVLink reserves 255 for ground stations) and the
#: onboard-computer component, the role it plays.
SOURCE_SYSTEM = 255
SOURCE_COMPONENT = 191
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS = 6
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT = {0: "accepted", 1: "temporarily rejected", 2: "denied", 3: "unsupported", 4: "failed",
              5: "in progress", 6: "cancelled"}  # fmt: skip
ADDRESS_FORMS = (
    "udpin:HOST:PORT (listen), udpout:HOST:PORT (send to), udp:HOST:PORT (listen), tcp:HOST:PORT, "
    "tcpin:HOST:PORT, or a serial device such as /dev/ttyUSB0,57600 or COM3,57600"
)
DEFAULT_BAUD = 57600


class LiveError(InputError):
    """The link, the vehicle or its streams are not what a live session needs (the message says why)."""


def mavutil() -> Any:
    """``pymavlink.mavutil`` speaking MAVLink 2 (``ESC_STATUS``, ``ODOMETRY`` and ``ACTUATOR_OUTPUT_STATUS``
    have ids above 255, which MAVLink 1 cannot carry)."""
    os.environ.setdefault("MAVLINK20", "1")
    try:
        from pymavlink import mavutil as mu
    except ImportError:  # pragma: no cover - a core dependency
        raise LiveError("the live commands need pymavlink: pip install 'pymavlink>=2.4.41'") from None
    if not getattr(mu.mavlink, "WIRE_PROTOCOL_VERSION", "1.0") == "2.0":
        mu.set_dialect(mu.current_dialect)
    return mu


@dataclass(frozen=True)
class Address:
    """A parsed link address: ``kind`` (udpin, udpout, tcp, tcpin, serial), and ``text`` for pymavlink."""

    kind: str
    text: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = DEFAULT_BAUD

    @property
    def listens(self) -> bool:
        return self.kind in ("udpin", "tcpin")


_NET = re.compile(r"^(?P<kind>udpin|udpout|udp|tcp|tcpin):(?P<host>[^:\s]+):(?P<port>\d+)$")


def parse_address(text: Any) -> Address:
    """Check an address before opening anything; a clear :class:`LiveError` naming the accepted forms."""
    if not isinstance(text, str) or not text.strip():
        raise LiveError(f"--connect needs an address: {ADDRESS_FORMS}")
    text = text.strip()
    m = _NET.match(text)
    if m:
        port = int(m["port"])
        if not 1 <= port <= 65535:
            raise LiveError(f"port {port} in {text!r} is not in 1..65535")
        kind = "udpin" if m["kind"] == "udp" else m["kind"]
        return Address(kind, f"{kind}:{m['host']}:{port}", m["host"], port)
    head = text.split(":", 1)[0]
    if head in ("udpin", "udpout", "udp", "tcp", "tcpin"):
        raise LiveError(f"address {text!r} does not parse: {head} needs HOST:PORT, e.g. {head}:127.0.0.1:14550")
    dev, _, baud = text.partition(",")
    if dev.startswith("/dev/") or re.match(r"^COM\d+$", dev, re.I):
        try:
            b = int(baud) if baud else DEFAULT_BAUD
        except ValueError:
            raise LiveError(f"serial baud rate {baud!r} in {text!r} is not a whole number") from None
        if b <= 0:
            raise LiveError(f"serial baud rate must be positive, got {b}")
        if dev.startswith("/dev/") and not Path(dev).exists():
            raise LiveError(f"serial device {dev} does not exist (is the radio or the vehicle plugged in?)")
        return Address("serial", dev, device=dev, baud=b)
    raise LiveError(f"address {text!r} does not parse; use one of: {ADDRESS_FORMS}")


class TlogWriter:
    """Writes packets as a ``.tlog``: 8-byte big-endian receive time (us since 1970), then the packet.

    Times are made strictly increasing, so a frame is identified by its time (the estimate's first frame is
    recorded in ``live.json`` that way). Flushed about once a second: a crash loses at most that much.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._fh: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self.frames = 0
        self.bytes = 0
        self.last_us = 0
        self._flushed = time.monotonic()

    def write(self, packet: bytes, t_us: int | None = None) -> int:
        if self._fh is None:
            return self.last_us
        t = int(time.time() * 1e6) if t_us is None else int(t_us)
        t = max(t, self.last_us + 1)
        self._fh.write(struct.pack(">Q", t) + packet)
        self.last_us = t
        self.frames += 1
        self.bytes += 8 + len(packet)
        now = time.monotonic()
        if now - self._flushed > 1.0:
            self._fh.flush()
            self._flushed = now
        return t

    def close(self) -> None:
        if self._fh is not None:
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()
            self._fh = None


@dataclass
class Peer:
    """A system/component heard on the link, from its heartbeats."""

    system: int
    component: int
    autopilot: int
    mav_type: int
    base_mode: int = 0
    custom_mode: int = 0
    last_heartbeat: float = 0.0  # monotonic s
    heartbeats: int = 0

    @property
    def is_vehicle(self) -> bool:
        return self.autopilot != MAV_AUTOPILOT_INVALID and self.mav_type != MAV_TYPE_GCS

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)


@dataclass
class LinkStats:
    received: int = 0
    sent: int = 0
    bad_data: int = 0
    lost: int = 0  # sequence gaps of the target
    duplicates: int = 0  # repeated sequence numbers of the target
    by_type: dict[str, int] = field(default_factory=dict)
    by_source: dict[tuple[int, int], int] = field(default_factory=dict)
    arrivals: dict[str, deque] = field(default_factory=dict)  # message -> recent arrival times (monotonic)

    def rate(self, message: str, now: float, window: float = 2.0) -> float:
        d = self.arrivals.get(message)
        if not d:
            return 0.0
        n = sum(1 for t in d if t > now - window)
        return n / window

    def rate_since(self, message: str, since: float, now: float, min_count: int = 5) -> float:
        """Rate (Hz) of ``message`` from its first arrival after ``since`` to ``now``: a stream that started
        late in the window (a request on a slow link) is measured at its own rate, not diluted by the wait;
        0 with fewer than ``min_count`` arrivals (too few to rank). Bounded by the :data:`ARRIVALS_KEPT` kept."""
        ts = [t for t in self.arrivals.get(message, ()) if t > since]
        if len(ts) < min_count or now <= ts[0]:
            return 0.0
        return len(ts) / (now - ts[0] + 1e-9)


#: Receive buffer asked of the operating system for a network link (the default, about 200 kB, holds only a
#: few hundred small datagrams: a second of busy work would drop packets).
RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024
#: Arrival times kept per message type for the measured rates (bounded memory).
ARRIVALS_KEPT = 512


class Link:
    """A pymavlink connection with recording, heartbeat bookkeeping, stream requests and commands.

    :meth:`poll` waits up to ``timeout`` for data, reads what arrived (at most ``max_messages``), records
    every packet, updates the peers from their heartbeats and hands each message to ``on_message``.
    """

    #: The clock of arrivals and heartbeats (monotonic seconds); scripted links in tests replace it.
    now = staticmethod(time.monotonic)

    def __init__(self, address: Address, connect_timeout: float = 10.0) -> None:
        self.address = address
        self.mu = mavutil()
        self.recorder: TlogWriter | None = None
        self.peers: dict[tuple[int, int], Peer] = {}
        self.stats = LinkStats()
        self.target: tuple[int, int] | None = None
        self._last_seq: int | None = None
        out, err = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                if address.kind == "serial":
                    conn = self.mu.mavlink_connection(
                        address.device, baud=address.baud, source_system=SOURCE_SYSTEM,
                        source_component=SOURCE_COMPONENT,
                    )  # fmt: skip
                else:
                    conn = self.mu.mavlink_connection(
                        address.text, source_system=SOURCE_SYSTEM, source_component=SOURCE_COMPONENT,
                        retries=max(int(connect_timeout), 1),
                    )  # fmt: skip
        except OSError as exc:
            raise LiveError(f"cannot open {address.text}: {exc.strerror or exc}") from None
        except Exception as exc:  # pymavlink raises plain Exceptions for refused TCP, bad serial ports
            raise LiveError(f"cannot open {address.text}: {exc}") from None
        self.conn = conn
        sock = getattr(conn, "port", None)
        if hasattr(sock, "setsockopt"):  # room for a few seconds of telemetry while the tool is busy
            import socket

            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)

    # ------------------------------------------------------------------ receiving

    def fileno(self) -> int | None:
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def poll(self, timeout: float, on_message: Callable[[Any], None] | None = None, max_messages: int = 2000) -> int:
        fd = self.fileno()
        if timeout > 0:
            if fd is not None:
                with contextlib.suppress(OSError, ValueError):
                    select.select([fd], [], [], timeout)
            else:
                time.sleep(timeout)
        n = 0
        while n < max_messages:
            try:
                msg = self.conn.recv_msg()
            except (OSError, ConnectionError):
                break
            except Exception:  # a malformed packet pymavlink chokes on: count it, go on
                self.stats.bad_data += 1
                continue
            if msg is None:
                break
            n += 1
            self._received(msg)
            if on_message is not None and msg.get_type() != "BAD_DATA":
                on_message(msg)
        return n

    def _received(self, msg: Any) -> None:
        typ = msg.get_type()
        if typ == "BAD_DATA":
            self.stats.bad_data += 1
            return
        if self.recorder is not None:
            buf = msg.get_msgbuf()
            if buf:
                msg._tlog_us = self.recorder.write(bytes(buf))
        self.stats.received += 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if len(self.stats.by_source) < 64 or src in self.stats.by_source:  # bounded: a flood of ids is not kept
            self.stats.by_source[src] = self.stats.by_source.get(src, 0) + 1
        if src == self.target:
            seq = msg.get_seq()
            if self._last_seq is not None:
                gap = (seq - self._last_seq - 1) % 256
                if gap == 255:
                    self.stats.duplicates += 1
                elif gap < 128:
                    self.stats.lost += gap
            self._last_seq = seq
            self.stats.by_type[typ] = self.stats.by_type.get(typ, 0) + 1
            d = self.stats.arrivals.get(typ)
            if d is None:
                d = self.stats.arrivals[typ] = deque(maxlen=ARRIVALS_KEPT)
            d.append(self.now())
        if typ == "HEARTBEAT":
            p = self.peers.get(src)
            if p is None:
                p = self.peers[src] = Peer(src[0], src[1], int(msg.autopilot), int(msg.type))
            p.autopilot, p.mav_type = int(msg.autopilot), int(msg.type)
            p.base_mode, p.custom_mode = int(msg.base_mode), int(msg.custom_mode)
            p.last_heartbeat = self.now()
            p.heartbeats += 1

    # ------------------------------------------------------------------ sending

    def send(self, msg: Any) -> None:
        """Pack, send and record one message (never raises on a dead link: the watchdog decides)."""
        mav = self.conn.mav
        try:
            buf = msg.pack(mav)
        except Exception as exc:  # a value out of the field's range is a bug here, say so
            raise LiveError(f"cannot pack {msg.get_type()}: {exc}") from None
        mav.seq = (mav.seq + 1) % 256
        with contextlib.suppress(OSError, ConnectionError):
            self.conn.write(buf)
        self.stats.sent += 1
        if self.recorder is not None:
            self.recorder.write(bytes(buf))

    @property
    def mavlink(self) -> Any:
        return self.mu.mavlink

    def command_long(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        sys_id, comp = self.target or (1, 1)
        self.send(self.mavlink.MAVLink_command_long_message(sys_id, comp, command, 0, *p[:7]))

    def ack_is_ours(self, msg: Any) -> bool:
        """Whether a ``COMMAND_ACK`` is meant for this tool: MAVLink 2 carries the target of an ACK
        (``target_system``, ``target_component``); 0 there (MAVLink 1, or an autopilot that leaves them unset)
        means any, so only a target naming another station makes it someone else's."""
        ts = int(getattr(msg, "target_system", 0) or 0)
        tc = int(getattr(msg, "target_component", 0) or 0)
        return ts in (0, SOURCE_SYSTEM) and tc in (0, SOURCE_COMPONENT)

    def message_id(self, name: str) -> int | None:
        return getattr(self.mavlink, f"MAVLINK_MSG_ID_{name}", None)

    def vehicles(self) -> list[Peer]:
        return [p for p in self.peers.values() if p.is_vehicle]

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.conn.close()
