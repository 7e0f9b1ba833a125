"""The live display: one steady screen redrawn in place, or a plain line now and then when not a terminal.

:func:`render` is pure (a :class:`View` in, lines out), so the same text is what the terminal shows, what
the tests read and what the README's screenshot is drawn from (:func:`to_png`).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np

#: Refreshes per second of the terminal display, and seconds between lines of the plain output.
TTY_HZ = 10.0
PLAIN_EVERY_S = 2.0
#: Full scale of the bars: force (N) and moment (N m).
FORCE_SCALE_N = 2.0
MOMENT_SCALE_NM = 0.1
BAR = 24


@dataclass
class StreamRow:
    message: str
    role: str
    requested_hz: float | None
    measured_hz: float
    used: bool


@dataclass
class View:
    """What one screen shows (every field named with its unit and frame in the text)."""

    address: str
    vehicle: str = "waiting for a heartbeat"
    mode: str = ""
    elapsed_s: float = 0.0
    t_vehicle_s: float | None = None
    f_hat_W: np.ndarray | None = None
    tau_hat_B: np.ndarray | None = None
    tick_age_s: float | None = None
    segment: int = 0
    streams: list[StreamRow] = field(default_factory=list)
    latency_ms: float | None = None
    telemetry_age_ms: float | None = None
    counts: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)  # by MESSAGE.field
    missing: list[str] = field(default_factory=list)  # "role: why"
    others: list[str] = field(default_factory=list)
    estimator: str = ""
    commands: str = ""
    control: list[str] = field(default_factory=list)
    recording: str = ""
    events: list[str] = field(default_factory=list)


def _bar(value: float, scale: float) -> str:
    if not np.isfinite(value):
        return " " * (2 * BAR + 1)
    n = int(round(min(abs(value) / scale, 1.0) * BAR))
    left = " " * BAR if value >= 0 else " " * (BAR - n) + "#" * n
    right = "#" * n + " " * (BAR - n) if value >= 0 else " " * BAR
    return left + "|" + right


def _scale_line(scale: float, unit: str) -> str:
    """The bars' scale, aligned with the bars below it (which start after a 20-character label)."""
    left, right = f"-{scale:g} {unit}", f"+{scale:g} {unit}"
    return " " * 20 + left + "0".rjust(BAR + 1 - len(left)) + right.rjust(BAR)


def _num(v: float, fmt: str = "+7.3f") -> str:
    return format(v, fmt) if np.isfinite(v) else "    n/a"


def render(v: View, width: int = 100) -> list[str]:
    """The screen as lines (no colour, no control codes)."""
    lines = [
        f"vtol-impedance live  {v.address}  {v.vehicle}  {v.mode}".rstrip(),
        f"session {v.elapsed_s:7.1f} s   vehicle clock "
        + (f"{v.t_vehicle_s:9.2f} s" if v.t_vehicle_s is not None else "      --")
        + (f"   estimate {v.tick_age_s * 1e3:5.0f} ms old" if v.tick_age_s is not None else "")
        + (f"   segment {v.segment}" if v.segment else ""),
        "",
        "external force f_hat_W (N, world NED)",
        _scale_line(FORCE_SCALE_N, "N"),
    ]
    f = v.f_hat_W if v.f_hat_W is not None else np.full(3, np.nan)
    for name, val in zip(("north x", "east  y", "down  z"), f, strict=True):
        lines.append(f"  {name} {_num(val)}   {_bar(val, FORCE_SCALE_N)}".rstrip())
    fn = float(np.linalg.norm(f)) if np.all(np.isfinite(f)) else float("nan")
    lines.append(f"  |f|     {_num(fn, '7.3f')}")
    lines.append("moment tau_hat_B (N m, body FRD)")
    lines.append(_scale_line(MOMENT_SCALE_NM, "N m"))
    t = v.tau_hat_B if v.tau_hat_B is not None else np.full(3, np.nan)
    for name, val in zip(("roll  x", "pitch y", "yaw   z"), t, strict=True):
        lines.append(f"  {name} {_num(val, '+7.4f')}   {_bar(val, MOMENT_SCALE_NM)}".rstrip())
    if not np.any(np.isfinite(t)):
        lines.append("  (no moment: the vehicle streams no per-rotor commands or speeds; see the stream table)")
    lines += ["", f"{'stream':<24}{'role':<10}{'requested':>10}{'measured':>10}  used"]
    for s in v.streams:
        req = f"{s.requested_hz:g} Hz" if s.requested_hz else "-"
        lines.append(f"  {s.message:<22}{s.role:<10}{req:>10}{s.measured_hz:>7.1f} Hz  {'yes' if s.used else ''}")
    c = v.counts
    link = (
        f"link: latency {v.latency_ms:.1f} ms (TIMESYNC round trip / 2)"
        if v.latency_ms is not None
        else "link: latency --"
    )
    if v.telemetry_age_ms is not None:
        link += f", telemetry {v.telemetry_age_ms:.0f} ms old on arrival"
    lines.append(link)
    lines.append(
        f"  lost {c.get('lost', 0)}, repeated {c.get('repeated', 0) + c.get('duplicates', 0)}, late {c.get('late', 0)}"
        f", restarts {c.get('restarts', 0)}, clock jumps {c.get('clock_jumps', 0)}, damaged {c.get('bad_data', 0)}"
    )
    if v.rejected:
        lines.append("  rejected (out of range): " + ", ".join(f"{k} {n}" for k, n in sorted(v.rejected.items())))
    for m in v.missing:
        lines.append(f"  MISSING {m}")
    lines.append("  other systems: " + (", ".join(v.others) if v.others else "none"))
    lines.append(f"estimator: {v.estimator}")
    lines.append(f"commands:  {v.commands}")
    lines += v.control
    if v.recording:
        lines.append(f"recording: {v.recording}")
    for e in v.events[-4:]:
        lines.append(f"  ! {e}")
    return [ln[:width] for ln in lines]


class Screen:
    """Draws views: ``"tty"`` redraws one screen in place (cursor home, clear to end of line, no scrolling),
    ``"plain"`` prints one summary line every :data:`PLAIN_EVERY_S` seconds (a log file, a pipe), ``"none"``
    draws nothing; ``"auto"`` picks ``tty`` on a terminal and ``plain`` otherwise."""

    def __init__(self, mode: str = "auto", stream: IO[str] | None = None) -> None:
        self.stream = stream or sys.stdout
        if mode == "auto":
            mode = "tty" if getattr(self.stream, "isatty", lambda: False)() else "plain"
        if mode not in ("tty", "plain", "none"):
            raise ValueError(f"display mode must be auto, tty, plain or none, got {mode!r}")
        self.mode = mode
        self._last = -1e9
        self._started = False
        self._height = 0

    def due(self, now: float) -> bool:
        period = 1.0 / TTY_HZ if self.mode == "tty" else PLAIN_EVERY_S
        return self.mode != "none" and now - self._last >= period

    def draw(self, view: View, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        self._last = now
        if self.mode == "none":
            return
        if self.mode == "plain":
            f = view.f_hat_W
            ftxt = "--" if f is None else " ".join(f"{x:+.3f}" for x in f)
            t = view.tau_hat_B
            ttxt = "--" if t is None or not np.any(np.isfinite(t)) else " ".join(f"{x:+.4f}" for x in t)
            extra = "".join(f"  MISSING {m}" for m in view.missing)
            if view.rejected:
                extra += f"  rejected {sum(view.rejected.values())} (" + ", ".join(sorted(view.rejected)) + ")"
            self.stream.write(
                f"[{view.elapsed_s:6.1f} s] f_hat_W N: {ftxt}  tau_hat_B N m: {ttxt}  {view.mode}{extra}\n"
            )
            self.stream.flush()
            return
        lines = render(view)
        out = []
        if not self._started:
            out.append("\x1b[?25l\x1b[2J")  # hide the cursor, clear once
            self._started = True
        out.append("\x1b[H")
        out.extend(ln + "\x1b[K\n" for ln in lines)
        out.append("\x1b[J")  # clear whatever an earlier, longer screen left below
        self._height = len(lines)
        self.stream.write("".join(out))
        self.stream.flush()

    def close(self) -> None:
        if self.mode == "tty" and self._started:
            self.stream.write("\x1b[?25h\n")  # show the cursor again
            self.stream.flush()


def to_png(lines: list[str], path: Any, title: str | None = None) -> Any:
    """The display's text drawn as a terminal screenshot (monospace, light on dark) with matplotlib."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = max(len(ln) for ln in lines)
    fig_w, fig_h = 0.085 * cols + 0.4, 0.166 * len(lines) + 0.25
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=110)
    fig.patch.set_facecolor("#1e1f22")
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_facecolor("#1e1f22")
    ax.text(0.02, 0.98, "\n".join(lines), family="monospace", fontsize=9.5, color="#d8dee9", va="top", ha="left",
            transform=ax.transAxes, linespacing=1.25)  # fmt: skip
    if title:
        fig.suptitle(title, color="#d8dee9")
    fig.savefig(path, facecolor=fig.get_facecolor())
    plt.close(fig)
    return path
