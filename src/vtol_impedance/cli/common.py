"""What every command shares: loading a scenario with the command line's overrides, the default results folder,
progress lines, the shared option group of the flying commands, and number parsing that names the option."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

DEFAULT_OUT = "results"


def _bound_flags(sp: argparse.ArgumentParser) -> None:
    """``--max-minutes`` and ``--yes``: the bound on the estimated duration (docs: sweeps, 'Bounded work')."""
    sp.add_argument("--max-minutes", type=float, default=None, metavar="M",
                    help="refuse when the estimated duration exceeds M minutes (default 10)")  # fmt: skip
    sp.add_argument("--yes", action="store_true", help="run whatever the estimated duration")


class _Progress:
    """Progress on stderr with the time left: an updating line on a terminal, otherwise a line every 25 % or
    every 5 s, whichever comes first."""

    def __init__(self, name: str, enabled: bool = True) -> None:
        self.name = name
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self.last = -1
        self.last_t = self.t0

    def __call__(self, frac: float) -> None:
        if not self.enabled:
            return
        pct = int(frac * 100)
        now = time.perf_counter()
        el = now - self.t0
        if self.tty:
            bar = "#" * (pct // 4) + "." * (25 - pct // 4)
            sys.stderr.write(f"\r  {self.name:<20} [{bar}] {pct:3d}%  {el:5.1f} s")
            if frac >= 1.0:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif pct // 25 > self.last // 25 or frac >= 1.0 or now - self.last_t >= 5.0:
            left = f", {el * (1.0 - frac) / frac:.0f} s left" if 0.0 < frac < 1.0 else ""
            sys.stderr.write(f"  {self.name}: {pct}% ({el:.1f} s{left})\n")
            sys.stderr.flush()
            self.last_t = now
        self.last = pct


def _load_spec(name: str, sets: list[str], duration: float | None, ideal: bool):
    """The scenario ``name`` (registered, or a ``.toml`` file) with the command line's overrides, and the
    folder tag of a file (:func:`_file_tag`)."""
    from ..errors import InputError
    from ..scenarios import apply_overrides, get, load_toml, set_value

    base = load_toml(name) if name.endswith(".toml") else get(name)
    tag = _file_tag(base) if name.endswith(".toml") else ()
    spec = apply_overrides(base, sets or [])
    if duration is not None:
        if not duration > 0 or duration != duration or duration == float("inf"):
            raise InputError(f"--duration must be a positive number of seconds, got {duration}")
        spec = set_value(spec, "duration", float(duration))
    if ideal:
        spec = set_value(spec, "ideal", True)
    return spec, tag


def _run_folder(args: argparse.Namespace, name: str, extra: tuple[str, ...] = ()) -> Path:
    """``--out``, or ``results/<name>`` for the scenario as registered and ``results/<name>+<what changed>``
    when anything was overridden (``--set``, ``--duration``, ``--seed``, ``--ideal``, ``--plant mujoco``,
    ``--tuning``), so that a run never replaces another configuration's folder; a long list is cut and
    ended by a hash of the whole. The manifest and ``*.config.json`` hold the full configuration."""
    if args.out:
        return Path(args.out)
    import hashlib
    import re

    parts = [*extra, *args.set]
    if getattr(args, "duration", None) is not None:
        parts.append(f"duration={args.duration:g}")
    if getattr(args, "seed", None) is not None:
        parts.append(f"seed={args.seed}")
    if args.ideal:
        parts.append("ideal")
    if getattr(args, "plant", None) == "mujoco":
        parts.append("plant=mujoco")
    if not parts:
        return Path(DEFAULT_OUT) / name
    slug = "+".join(re.sub(r"[^A-Za-z0-9._=,-]+", "_", p.strip()) for p in parts)
    if len(slug) > 80:
        slug = slug[:60] + "-" + hashlib.sha256(slug.encode()).hexdigest()[:8]
    return Path(DEFAULT_OUT) / f"{name}+{slug}"


def _file_tag(spec: Any) -> tuple[str, ...]:
    """``("file=<hash>",)`` for a scenario read from a file whose content is not the registered scenario of
    its name (a file without ``name`` takes its base's, and two files may share one): its folder must not
    be the registered scenario's or another file's. The hash is of the file's whole scenario."""
    import hashlib

    from ..errors import ScenarioError
    from ..scenarios import get

    plain = json.dumps(spec.to_dict(), sort_keys=True, default=str)
    try:
        if json.dumps(get(spec.name).to_dict(), sort_keys=True, default=str) == plain:
            return ()
    except ScenarioError:
        pass
    return (f"file={hashlib.sha256(plain.encode()).hexdigest()[:8]}",)


def _backend(args: argparse.Namespace) -> str:
    """``--plant mujoco`` puts MuJoCo's physics under the controller of ``--backend`` (compiled or NumPy)."""
    if args.plant == "mujoco":
        from ..sim.mjplant import require_mujoco

        require_mujoco()
        return "mujoco" if args.backend == "compiled" else "mujoco-numpy"
    return args.backend


def _announce_compile(backend: str, quiet: bool) -> None:
    """Compile the simulation kernels now when they are not cached (the first run after an install or an
    upgrade), with a line when it starts and one with its time when it ends, on a terminal or not: the
    compile is timed as such, not as the first case's flight."""
    if backend != "compiled":
        return
    from ..compiled import kernels_cached

    if kernels_cached():
        return
    from ..scenarios import get, set_value, simulate

    if not quiet:
        print("compiling the simulation kernels (first run only; cached afterwards) ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    simulate(set_value(get("case-a-payload"), "duration", 0.05), ["pdc"])  # one short flight compiles them all
    if not quiet:
        print(f"compiled the kernels in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def _seed(args: argparse.Namespace) -> int | None:
    from ..errors import InputError

    if args.seed is not None and not 0 <= args.seed < 2**63:
        raise InputError(f"--seed must be a whole number in [0, 2^63), got {args.seed}")
    return args.seed


def _floats(name: str, text: str | None, n: int | tuple[int, ...]) -> list[float] | None:
    from ..errors import InputError

    if text is None:
        return None
    try:
        vals = [float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise InputError(f"{name} must be comma-separated numbers, got {text!r}") from None
    counts = (n,) if isinstance(n, int) else n
    if len(vals) not in counts or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(f"{name} must be {' or '.join(map(str, counts))} finite numbers, got {text!r}")
    return vals


def _numbers(text: str | None, name: str, n: int) -> tuple[float, ...] | None:
    """``"a,b,c"`` as ``n`` finite numbers, or a clear error naming the option."""
    from ..errors import InputError

    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(f"{name} must be {n} comma-separated finite numbers, got {text!r}")
    return vals


def _default_out(kind: str, name: str) -> Path:
    """``results/<kind>-<name>``, without doubling the kind when the name already starts with it."""
    return Path(DEFAULT_OUT) / (name if name.startswith(f"{kind}-") else f"{kind}-{name}")


def add_flight_options(sp: argparse.ArgumentParser) -> None:
    """The options of the flying commands (paper, run, compare): results folder, overrides, seed, duration,
    ideal plant, figures, progress, execution and physics."""
    sp.add_argument(
        "--out",
        default=None,
        help=f"results folder, replaced as a whole by each run (default: {DEFAULT_OUT}/paper for 'paper', "
        f"{DEFAULT_OUT}/<scenario name> otherwise, with '+<what was overridden>' appended when --set, "
        "--duration, --seed, --ideal or --plant change it, and '+file=<hash>' for a scenario file that is not "
        "the registered scenario of its name)",
    )
    sp.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario value, e.g. --set payload.mass=0.2 (repeatable)",
    )
    sp.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    sp.add_argument("--duration", type=float, default=None, help="cut the run to this many seconds")
    sp.add_argument(
        "--ideal",
        action="store_true",
        help="turn off every unmodelled effect except the payload mass and listed disturbances",
    )
    sp.add_argument("--no-plots", action="store_true", help="skip figures")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    sp.add_argument(
        "--backend",
        choices=["compiled", "numpy"],
        default="compiled",
        help="compiled (numba) or the NumPy reference",
    )
    sp.add_argument(
        "--plant",
        choices=["builtin", "mujoco"],
        default="builtin",
        help="the physics: this package's plant, or MuJoCo's (an independent engine, flown by the controller "
        "of --backend; needs: pip install 'vtol-impedance[mujoco]')",
    )
