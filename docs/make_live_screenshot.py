"""Draw docs/img/live-display.png: the live display of a session against the simulated autopilot flying case
B (the fan), as a terminal would show it. Run from the repository root: ``python docs/make_live_screenshot.py``
(about 15 s)."""

from __future__ import annotations

import io
import re
import socket
import threading
from pathlib import Path

from vtol_impedance.live import LiveSettings, run_live
from vtol_impedance.live.autopilot import SimAutopilot, SimSettings
from vtol_impedance.live.display import to_png
from vtol_impedance.scenarios import get


class Capture(io.StringIO):
    def isatty(self) -> bool:
        return True


def main() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sim = SimAutopilot(get("case-b-fan"), SimSettings(f"udpout:127.0.0.1:{port}"))
    th = threading.Thread(target=sim.run, daemon=True)
    th.start()
    screen = Capture()
    out = Path("results/live-screenshot")
    run_live(LiveSettings(f"udpin:127.0.0.1:{port}", duration=12.0, display="tty", out=str(out)), stream=screen)
    sim.stop()
    th.join()
    frame = screen.getvalue().split("\x1b[H")[-1]
    lines = [re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", ln) for ln in frame.split("\n")]
    lines = [ln for ln in lines if ln.strip() or ln == ""][:-1]
    lines = [
        ln.replace(str(out.absolute()), "results/live-20250101-120000").replace(f":{port}", ":14550") for ln in lines
    ]
    Path("docs/img").mkdir(parents=True, exist_ok=True)
    to_png(lines, "docs/img/live-display.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
