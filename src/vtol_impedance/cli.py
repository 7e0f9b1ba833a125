"""Command-line interface: ``vtol-impedance {paper,run,compare,margins,estimate,live,sim-autopilot,sweep,sweep-report,
tune,bench,list}``.

Heavy modules are imported inside the commands so that ``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from . import __version__

DEFAULT_OUT = "results"


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
    from .errors import InputError
    from .scenarios import apply_overrides, get, load_toml, set_value

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

    from .errors import ScenarioError
    from .scenarios import get

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
        from .sim.mjplant import require_mujoco

        require_mujoco()
        return "mujoco" if args.backend == "compiled" else "mujoco-numpy"
    return args.backend


def _announce_compile(backend: str, quiet: bool) -> None:
    """Compile the simulation kernels now when they are not cached (the first run after an install or an
    upgrade), with a line when it starts and one with its time when it ends, on a terminal or not: the
    compile is timed as such, not as the first case's flight."""
    if backend != "compiled":
        return
    from .compiled import kernels_cached

    if kernels_cached():
        return
    from .scenarios import get, set_value, simulate

    if not quiet:
        print("compiling the simulation kernels (first run only; cached afterwards) ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    simulate(set_value(get("case-a-payload"), "duration", 0.05), ["pdc"])  # one short flight compiles them all
    if not quiet:
        print(f"compiled the kernels in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def _run_case(spec: Any, variants: list[str], seed: int | None, quiet: bool, backend: str = "compiled") -> Any:
    from .scenarios import simulate

    return simulate(spec, variants, seed=seed, progress=_Progress(spec.name, not quiet), backend=backend)


def _run_case_job(args: tuple[Any, list[str], int | None, bool, str]) -> Any:
    return _run_case(*args)


def _die_with_parent() -> None:
    """In a worker process: be killed when the parent dies, however it dies (Linux ``PR_SET_PDEATHSIG``)."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass


def _run_parallel(jobs_args: list[tuple[Any, ...]], jobs: int) -> list[Any]:
    from concurrent.futures import ProcessPoolExecutor

    ex = ProcessPoolExecutor(max_workers=jobs, initializer=_die_with_parent)
    try:
        results = list(ex.map(_run_case_job, jobs_args))
    except BaseException:
        for proc in list(getattr(ex, "_processes", {}).values()):
            proc.terminate()
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown()
    return results


def _write_case(result: Any, folder: Any, stem: str, plots: bool, animate: bool = False) -> list[Path]:
    from .io import write_text

    files = [result.save(folder.path(f"{stem}.npz"))]
    files.append(write_text(folder.path(f"{stem}.config.json"), json.dumps(result.config, indent=1)))
    if plots:
        from .analysis.plots import plot_case

        files += plot_case(result, folder.staging, stem)
    if animate:
        from .analysis.animate import write_gif

        files.append(write_gif(result, folder.path(f"{stem}.gif")))
    return files


def _write_mjcf(spec: Any, folder: Any) -> Path:
    """The MuJoCo model that was flown, for MuJoCo's own viewer (``python -m mujoco.viewer --mjcf ...``)."""
    from .io import write_text
    from .scenarios.spec import build
    from .sim.mjplant import scene_mjcf

    b = build(spec)
    return write_text(folder.path(f"{spec.name}.mjcf.xml"), scene_mjcf(b.plant, b.disturbances, 1.0 / spec.plant_rate))


def _finish(
    folder: Any,
    title: str,
    results: dict[str, Any],
    figures: dict[str, list[Path]],
    quiet: bool,
    extra_tables: list[Any] = (),  # type: ignore[assignment]
    margin_notes: list[str] = (),  # type: ignore[assignment]
    margin_findings: list[str] = (),  # type: ignore[assignment]
) -> Path:
    """Metrics, tables and ``report.html`` (:func:`~vtol_impedance.analysis.report.flight_sections`; the
    ``extra_tables`` are the margins' tables) into the folder, committed; the tables printed. Returns the
    committed folder."""
    from .analysis.measures import purpose_tables
    from .analysis.metrics import compute_metrics
    from .analysis.report import (
        flight_sections,
        markdown_rows,
        table_rows,
        text_rows,
        text_table,
        write_html,
        write_tables,
    )
    from .io import write_text

    metrics = {name: compute_metrics(r) for name, r in results.items()}
    write_tables(metrics, folder.staging)
    notes = [
        "Errors are over each case's task window (hover after take-off for A and B, the two circle laps for C).",
        _gains_note(results),
        "Estimation error compares the estimate with everything the nominal model misses (payload, mismatch, "
        "rotor lag, drag, disturbances), computed from the true motion.",
    ]
    if any(str(r.config.get("backend")).startswith("mujoco") for r in results.values()):
        from .io import _versions

        notes.append(
            f"Plant: MuJoCo {_versions()['mujoco']} (an independent physics engine; the model flown is "
            "<scenario>.mjcf.xml). The true external force includes MuJoCo's contact and link forces."
        )
    configs = {k: r.config for k, r in results.items()}
    seeds = [r.config.get("seed") for r in results.values()]
    head, rows = table_rows(metrics)
    table = ("Errors, estimation and limits over each case's task window", head, rows)
    purpose = [t for name, r in results.items() for t in purpose_tables(r, name)]  # what each scenario is for
    if purpose:
        write_text(folder.path("measures.md"), "\n".join(markdown_rows(*t) for t in purpose))
    descriptions = {k: r.config.get("scenario", {}).get("description", "") for k, r in results.items()}
    sections = flight_sections([*purpose, table], figures, notes=notes, descriptions=descriptions,
                               margin_tables=extra_tables, margin_notes=margin_notes,
                               margin_findings=margin_findings)  # fmt: skip
    write_html(folder.staging, title, sections=sections, config=configs, seed=seeds)
    final = folder.commit(configs, seed=seeds)
    for caption, h, r in purpose:
        print(f"{caption}\n{text_rows(h, r)}")
    print(text_table(metrics))
    failed = [f"{c}/{r['controller']}" for c, rs in metrics.items() for r in rs if r["failure"]]
    if failed:
        print(f"warning: vehicles stopped early: {', '.join(failed)} (see the failure column)", file=sys.stderr)
    if not quiet:
        print(f"results written to {final}", file=sys.stderr)
    return final


def _gains_note(results: dict[str, Any]) -> str:
    """The report's note on the gains flown: the paper's as printed when every case flew them."""
    from .scenarios.spec import PAPER_CONTROL, ControlSpec

    paper = {k.split(".", 1)[1]: v for k, v in PAPER_CONTROL.items()}
    paper |= {k: getattr(ControlSpec(), k) for k in ("rate", "Kp", "Dp", "Ki")}
    controls = [r.config.get("scenario", {}).get("control", {}) for r in results.values()]
    if all(c.get(k) == v for c in controls for k, v in paper.items()):
        return (
            "Gains as printed in the paper: Kp = 16, Dp = 12 (they do not follow from the stated wn = 4 rad/s, "
            "zeta = 1 with m = 1.2 kg), attitude wn = 8 rad/s, zeta = 1, estimator wn = 10 rad/s, zeta = 1, "
            "PID Ki = 0.5, control at 100 Hz."
        )
    return (
        "Gains: the position impedance and PID Ki of each case's configuration (the paper's Kp = 16, Dp = 12, "
        "Ki = 0.5 unless set otherwise); the attitude and estimator bandwidths designed by this tool to meet the "
        "stability margins unless set (the configuration below holds every value flown)."
    )


def _seed(args: argparse.Namespace) -> int | None:
    from .errors import InputError

    if args.seed is not None and not 0 <= args.seed < 2**63:
        raise InputError(f"--seed must be a whole number in [0, 2^63), got {args.seed}")
    return args.seed


def _preflight(
    specs: list[Any], variants: list[str], quiet: bool, verbose: bool = False, paper_gains: bool = False
) -> dict[str, Any]:
    """The margin check before a flight: margins of every controller at each scenario's operating point,
    and a warning (on stderr) naming what falls short of the thresholds, one line per scenario
    (:func:`~vtol_impedance.scenarios.margins.summary_of`; every finding with ``verbose``). ``paper_gains``:
    the controller is the paper's as printed, whose shortfalls are expected on a realistic plant; the
    warning says so and points at the designed tuning. Returns the reports per scenario, for the run
    folder's figures and report."""
    from .robust import LoopSizeError, Thresholds, TrimError
    from .scenarios.margins import scenario_margins, summary_of, warnings_of

    out, lines = {}, []
    for spec in specs:
        try:
            reports = scenario_margins(spec, variants)
        except (TrimError, LoopSizeError) as exc:  # the flight may still show what happens; say why not
            lines.append(f"  {spec.name}: no margins, {exc}")
            out[spec.name] = {}
            continue
        out[spec.name] = reports
        if verbose:
            lines += [f"  {spec.name}, {w}" for w in warnings_of(reports)]
        elif summary := summary_of(reports):
            lines.append(f"  {spec.name}: {summary}")
    if lines:
        t = Thresholds()
        if paper_gains:
            lines.append("  expected for the paper's printed gains: '--tuning design' flies gains designed to meet "
                         "the thresholds; every finding: report.html, section 'Stability margins'"
                         + ("" if verbose else ", or --verbose"))  # fmt: skip
        else:
            lines.append("  every finding: the margins in the results folder, or 'vtol-impedance margins'")
        print(
            f"warning: stability margins below the thresholds ({t.phase_deg:g} deg phase, {t.gain_db:g} dB gain, "
            f"damping {t.damping:g}) at the operating point:\n" + "\n".join(lines),
            file=sys.stderr,
        )
    return out


def _write_margins(reports: dict[str, Any], folder: Any, stem: str, plots: bool) -> tuple[list[Path], list[Any]]:
    """Figures, ``<stem>.margins.json`` and the report tables of one scenario's margins."""
    from .analysis.margin_plots import margin_rows, margins_json, plot_margins, pole_rows
    from .io import write_text

    if not reports:
        return [], []
    files = [write_text(folder.path(f"{stem}.margins.json"), json.dumps(margins_json(reports), indent=1))]
    if plots:
        files += plot_margins(reports, folder.staging, f"{stem}_margins")
    tables = [
        (f"{stem}: stability at the operating point", *pole_rows(reports)),
        (f"{stem}: margins per loop", *margin_rows(reports)),
    ]
    return files, tables


def cmd_margins(args: argparse.Namespace) -> int:
    """Stability margins of a scenario's controllers at its operating point: table, figures, report."""
    from .analysis.margin_plots import text_margins
    from .analysis.report import write_html
    from .io import RunFolder
    from .scenarios import check
    from .scenarios.margins import scenario_margins, warnings_of
    from .scenarios.spec import check_variants

    spec, tag = _load_spec(args.scenario, args.set, None, args.ideal)
    variants = check_variants([c.strip() for c in args.controllers.split(",") if c.strip()], unique=True)
    check(spec, variants)
    out = _run_folder(args, f"margins-{spec.name}", tag)
    with RunFolder(out) as folder:
        if not args.quiet:
            print(f"linearising {spec.name} for {', '.join(variants)} ...", file=sys.stderr)
        reports = scenario_margins(spec, variants)
        files, tables = _write_margins(reports, folder, spec.name, not args.no_plots)
        warn = warnings_of(reports)
        notes = [
            "Each loop is broken with the others closed; L is closed by 1 + L. Gain margins up and down: a loop "
            "around a double integrator also destabilises when its gain falls. An unstable closed loop shows no "
            "margins.",
            "Operating point: hover at the reference where the task window starts, on the true plant, under the "
            "disturbances' mean wrench there (module vtol_impedance.scenarios.margins).",
        ] + ([f"Below the thresholds: {w}" for w in warn] or ["Every controller meets the thresholds."])
        write_html(folder.staging, f"Stability margins: {spec.name}", tables=tables,
                   figures={spec.name: [p for p in files if p.suffix == ".png"]}, notes=notes,
                   config={"scenario": spec.to_dict()}, seed=spec.seed)  # fmt: skip
        final = folder.commit({"scenario": spec.to_dict()}, seed=spec.seed)
    print(text_margins(reports))
    for w in warn:
        print(f"below the thresholds: {w}")
    if not warn:
        print("every controller meets the thresholds")
    if not args.quiet:
        print(f"results written to {final}", file=sys.stderr)
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    from .control.impedance import VARIANTS
    from .scenarios import get, names

    print("scenarios (a name without -vN means its latest version):")
    for n in names(latest_only=False):
        print(f"  {n:<22} {get(n).description}")
    print("controllers:")
    for k, v in VARIANTS.items():
        print(f"  {k:<22} {v}")
    return 0


def cmd_run(args: argparse.Namespace, variants: list[str]) -> int:
    from .io import RunFolder
    from .scenarios import check
    from .scenarios.spec import check_variants

    spec, tag = _load_spec(args.scenario, args.set, args.duration, args.ideal)
    variants = check_variants(variants, unique=True)
    seed = _seed(args)
    check(spec, variants)
    backend = _backend(args)
    t0 = time.perf_counter()
    with RunFolder(_run_folder(args, spec.name, tag)) as folder:
        margins = _preflight([spec], variants, args.quiet)
        _announce_compile(backend, args.quiet)
        result = _run_case(spec, variants, seed, args.quiet, backend)
        if args.animate and not args.quiet:
            print("drawing the animation ...", file=sys.stderr)
        figs = _write_case(result, folder, spec.name, not args.no_plots, args.animate)
        mfiles, mtables = _write_margins(margins[spec.name], folder, spec.name, not args.no_plots)
        if backend.startswith("mujoco"):
            figs.append(_write_mjcf(spec, folder))
        _finish(
            folder,
            f"vtol-impedance: {spec.name}",
            {spec.name: result},
            {spec.name: [p for p in figs + mfiles if p.suffix in (".png", ".gif")]},
            args.quiet,
            mtables,
        )
    if not args.quiet:
        print(f"wall time {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def cmd_paper(args: argparse.Namespace) -> int:
    from .errors import InputError
    from .io import RunFolder
    from .scenarios import PAPER_CASES, check
    from .scenarios.spec import PAPER_CONTROL

    if args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    tuning = [] if args.tuning == "design" else [f"{k}={json.dumps(v)}" for k, v in PAPER_CONTROL.items()]
    specs = [_load_spec(n, tuning + args.set, args.duration, args.ideal)[0] for n in PAPER_CASES]
    variants = ["pd", "pid", "pdc"]
    seed = _seed(args)
    for spec in specs:
        check(spec, variants)
    backend = _backend(args)
    t0 = time.perf_counter()
    tag = () if args.tuning == "paper" else (f"tuning={args.tuning}",)
    with RunFolder(_run_folder(args, "paper", tag)) as folder:
        margins = _preflight(specs, variants, args.quiet, args.verbose, paper_gains=args.tuning == "paper")
        _announce_compile(backend, args.quiet)
        if not args.quiet:
            print(f"flying {len(specs)} cases x {len(variants)} controllers ...", file=sys.stderr)
        jobs = min(args.jobs, len(specs))
        jobs_args = [(s, variants, seed, args.quiet, backend) for s in specs]
        results_list = _run_parallel(jobs_args, jobs) if jobs > 1 else [_run_case_job(a) for a in jobs_args]
        results: dict[str, Any] = {}
        figures: dict[str, list[Path]] = {}
        mtables: list[Any] = []
        for spec, res in zip(specs, results_list, strict=True):
            results[spec.name] = res
            figs = _write_case(res, folder, spec.name, not args.no_plots)
            mfiles, tabs = _write_margins(margins[spec.name], folder, spec.name, not args.no_plots)
            mtables += tabs
            if backend.startswith("mujoco"):
                _write_mjcf(spec, folder)
            figures[spec.name] = [p for p in figs + mfiles if p.suffix == ".png"]
        title = "Ruggiero et al. (ICRA 2014) case studies, simulated" + (
            " (the paper's controller)" if args.tuning == "paper" else " (this tool's robust defaults)"
        )
        found = _margin_findings(margins)
        why = [_PAPER_GAINS_NOTE] if found and args.tuning == "paper" else []
        final = _finish(folder, title, results, figures, args.quiet, mtables, why, found)
    if not args.quiet:
        print(f"wall time {time.perf_counter() - t0:.1f} s; the report: {final / 'report.html'}", file=sys.stderr)
    return 0


#: Why the paper's printed gains fall short of the margins, and what flies without them (its report).
_PAPER_GAINS_NOTE = (
    "As expected, the paper's printed gains (attitude 8 rad/s, estimator 10 rad/s, the estimate read at face "
    "value) fall short on a plant with sensor latency and rotor lag; 'vtol-impedance paper --tuning design' flies "
    "gains designed to meet the thresholds, with the same position impedance. Every finding:"
)


def _margin_findings(margins: dict[str, Any]) -> list[str]:
    """Every margin finding in full, one per case and controller that falls short (the report's list)."""
    from .scenarios.margins import warnings_of

    return [f"{case}, {w}" for case, reports in margins.items() for w in warnings_of(reports)]


def _floats(name: str, text: str | None, n: int | tuple[int, ...]) -> list[float] | None:
    from .errors import InputError

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


def _estimate_tables(est: Any, s: dict[str, Any]) -> list[tuple[str, list[str], list[list[str]]]]:
    tables = []
    for name, st in s["stats"].items():
        rows = [[k] + [f"{v:.4g}" for v in vals] for k, vals in st.items()]
        tables.append((f"Estimate {name} over the log", [name, "x", "y", "z"], rows))
    if est.bias is not None:
        rows = [[k] + [f"{v:.4g}" for v in est.bias[k]] for k in ("f_W_N", "tau_B_Nm") if k in est.bias]
        a, b = est.bias["segment_s"]
        tables.append((f"Bias: mean estimate over the quiet segment {a:g}-{b:g} s", ["", "x", "y", "z"], rows))
    choices = est.info.get("choices", [])
    if choices:
        tables.append(("What was chosen from the log", ["choice"], [[c] for c in choices]))
    conv = est.info.get("conventions")
    if conv and conv.get("evidence_chosen"):
        ev = conv["evidence_chosen"]
        rows = [[k, str(v)] for k, v in ev.items()] + [["mode", conv["mode"]], ["readings tried", str(conv["tried"])]]
        if conv.get("chosen"):
            rows.append(["conventions", ", ".join(f"{k} {v}" for k, v in conv["chosen"].items())])
        tables.append(("Conventions checked against physics", ["item", "value"], rows))
    gaps = est.info.get("gaps") or []
    if gaps:
        rows = []
        for g in gaps[:200]:
            bound = (
                f"{g['bound_f_N']:.3g} N (+{g['bound_f_per_N_change']:.2g} per N of change)" if "bound_f_N" in g else ""
            )
            rows.append(
                [g["signal"], f"{g['t0_s']:.3f}", f"{g['t1_s']:.3f}", f"{g['length_s']:.3f}", g["action"], bound]
            )
        caption = "Gaps: bridged (estimator state carried) or restart (the data stop)"
        if len(gaps) > 200:
            caption += f"; the first 200 of {len(gaps)}"
        tables.append((caption, ["signal", "from s", "to s", "length s", "action", "bound after it"], rows))
    skip = ("estimator", "inertia_kg_m2", "choices", "conventions", "gaps")
    info_rows = [[k, str(v)] for k, v in est.info.items() if k not in skip]
    tables.append(("How the log was read", ["item", "value"], info_rows))
    return tables


def cmd_estimate(args: argparse.Namespace) -> int:
    """Estimate the external wrench along a flight log (CSV, PX4 ULog, ArduPilot DataFlash, MAVLink tlog)."""
    from .errors import InputError
    from .estimator import EstimatorParams
    from .io import RunFolder
    from .logs import estimate_file, log_format
    from .logs import samples as sample_logs

    if args.example is not None:
        if args.example == "list":
            print(sample_logs.listing())
            print(f"\ne.g. vtol-impedance estimate --example px4 --mass {sample_logs.MASS_KG}")
            return 0
        if args.log is not None:
            raise InputError("give a log file or --example NAME, not both")
        log = sample_logs.path(args.example)
        stem = args.example
    else:
        if args.log is None:
            raise InputError("give a log file (CSV, .ulg, .bin, .tlog) or --example NAME (--example list)")
        log = Path(args.log)
        if not log.is_file():
            from .io import explain_path

            raise InputError(f"cannot read log file {log}: {explain_path(log) or 'not a regular file'}")
        stem = log.stem
    inertia: Any = _floats("--inertia", args.inertia, (3, 9))
    if inertia is not None and len(inertia) == 9:
        inertia = [inertia[0:3], inertia[3:6], inertia[6:9]]
    vehicle = None
    if args.vehicle:
        from .model import load_preset

        vehicle = load_preset(args.vehicle)
    columns = {}
    for item in args.column:
        role, sep, name = item.partition("=")
        if not sep or not role or not name:
            raise InputError(f"--column takes ROLE=NAME, got {item!r}")
        columns[role.strip()] = name.strip()
    csv_flags = {
        "world": args.world, "body": args.body, "angle_unit": args.angle_unit, "quat_order": args.quat_order,
        "quat_direction": args.quat_direction, "time_unit": args.time_unit, "rate_unit": args.rate_unit,
        "velocity_world": args.velocity_world,
    }  # fmt: skip
    given = {k: v for k, v in csv_flags.items() if v is not None}
    read_options: dict[str, Any] = {"conventions": args.conventions}
    read_options.update({k: v for k, v in (("sysid", args.sysid), ("compid", args.compid)) if v is not None})
    if log_format(log) == "csv":
        read_options.update(given, columns=columns, rotor_speed_unit=args.rotor_speed_unit or "rpm")
    elif given or columns or args.rotor_speed_unit:
        flags = ", ".join(["--" + k.replace("_", "-") for k in given] + (["--column"] if columns else []))
        raise InputError(f"{flags or '--rotor-speed-unit'} appl{'y' if ',' in flags else 'ies'} to CSV logs; "
                         f"a {log_format(log)} log states its own frames and units")  # fmt: skip
    params = EstimatorParams(
        wn=args.wn, zeta=args.zeta, order=args.order, prototype=args.prototype, velocity_delay=args.velocity_delay,
        attitude_delay=args.attitude_delay, rotor_tau=args.rotor_tau,
    )  # fmt: skip
    est = estimate_file(
        log, args.mass, inertia, params,
        vehicle=vehicle,
        rate_hz=args.rate,
        max_gap_s=args.max_gap,
        t_start=args.start,
        t_end=args.end,
        read_options=read_options,
        zero_phase_too=args.zero_phase,
        quiet_segment=_floats("--quiet-segment", args.quiet_segment, 2),
        remove_bias=args.remove_bias,
        hover_thrust=args.hover_thrust,
        hover_segment=_floats("--hover-segment", args.hover_segment, 2),
        torque_scale=_floats("--torque-scale", args.torque_scale, (1, 3)),
        backend=args.backend,
        thrust_from=args.thrust_from,
        thrust_coefficient=args.thrust_coefficient,
        airframe=args.airframe,
        on_ground=args.on_ground,
        force=args.force,
    )  # fmt: skip
    out = Path(args.out) if args.out else _estimate_folder(stem, log)
    flight = est.flight
    with RunFolder(out) as folder:
        from .analysis.report import write_html
        from .logs.output import summary, write_estimate

        s = summary(est)
        write_estimate(est, folder.staging, s)
        figs = []
        if not args.no_plots:
            from .analysis.log_plots import plot_log_inputs, plot_log_wrench

            figs = [
                plot_log_wrench(est, folder.path("wrench.png"), f"{log.name}: estimated external wrench"),
                plot_log_inputs(est, folder.path("inputs.png"), f"{log.name}: inputs at {flight.rate_hz:g} Hz"),
            ]
        notes = [f"WARNING: {w}" for w in est.warnings] + [
            "Force in world NED, moment in body FRD. The estimate contains everything the nominal model misses: "
            "a thrust-map or mass error appears as a constant force along the thrust axis (see the bias).",
            *est.notes,
        ]
        write_html(folder.staging, f"Wrench estimate: {log.name}", tables=_estimate_tables(est, s),
                   figures={"Figures": figs}, notes=notes, config=s["info"])  # fmt: skip
        final = folder.commit(s["info"])
    for w in est.warnings:
        print(f"WARNING: {w}", file=sys.stderr)
    if not args.quiet:
        for c in est.info.get("choices", []):
            print(f"chose: {c}", file=sys.stderr)
        for n in est.notes:
            print(f"note: {n}", file=sys.stderr)
        st = s["stats"]["f_W_N"]
        restarts = int(flight.restart.sum()) - 1
        bridged = sum(1 for g in flight.gaps if g["action"] == "bridged")
        print(f"{len(est.t)} samples at {flight.rate_hz:g} Hz, {est.info['segments']} segment(s) "
              f"({restarts} restart(s), {bridged} bridged dropout(s))")  # fmt: skip
        what = "ground reaction + external force" if est.info.get("on_ground") else "force"
        print(f"{what}, world NED [N]  mean " + " ".join(f"{v:+.3f}" for v in st["mean"]) + "   max |.| "
              + " ".join(f"{v:.3f}" for v in st["max_abs"]))  # fmt: skip
        sd = (est.info.get("hover_thrust") or {}).get("fz_sd_at_hover_N")
        if sd is not None:
            print(f"vertical force uncertainty from the fitted hover thrust: {sd:.3f} N (1 sd at hover; per sample "
                  "in the column fz_W_N_hover_sd)")  # fmt: skip
        if est.bias is not None:
            print("bias over the quiet segment [N]: " + " ".join(f"{v:+.4f}" for v in est.bias["f_W_N"]))
        verdict = est.info.get("verdict")
        if verdict is not None:
            print(f"verdict: {verdict['outcome']}" + (" (overridden with --force)" if verdict["forced"] else ""))
        print(f"results written to {final}", file=sys.stderr)
    return 0


def _estimate_folder(stem: str, log: Path) -> Path:
    """``results/estimate-<log name>``, or, when that folder holds the estimate of another file of the same
    name, ``results/estimate-<log name>+<hash of this file's path>``: a log never replaces another's."""
    import hashlib

    base = Path(DEFAULT_OUT) / f"estimate-{stem}"
    try:
        other = json.loads((base / "estimate.json").read_text())["info"]["file"]
    except (OSError, ValueError, KeyError, TypeError):
        return base  # no estimate there (or not ours: RunFolder refuses a foreign folder)
    here = Path(log).resolve()
    if Path(other).resolve() == here:
        return base
    return base.with_name(f"{base.name}+{hashlib.sha256(str(here).encode()).hexdigest()[:8]}")


def _default_out(kind: str, name: str) -> Path:
    """``results/<kind>-<name>``, without doubling the kind when the name already starts with it."""
    return Path(DEFAULT_OUT) / (name if name.startswith(f"{kind}-") else f"{kind}-{name}")


def _sweep_out(args: argparse.Namespace, name: str) -> Path:
    return Path(args.out) if args.out else _default_out("sweep", name)


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run or resume a sweep, then write its summary."""
    from .io import check_folder_path
    from .sweeps import load, run_sweep, write_report
    from .sweeps.budget import Progress, check_budget, sweep_seconds
    from .sweeps.run import METRICS

    if args.metric not in METRICS:  # checked before the flights, not after them in the report
        from .errors import InputError

        raise InputError(f"--metric must be one of {', '.join(METRICS)}, got {args.metric!r}")
    sweep = load(args.spec, check_points=False)
    check_folder_path(_sweep_out(args, sweep.name))  # before any work
    check_budget(sweep_seconds(sweep, args.backend, args.workers), f"sweep {sweep.name}", args.max_minutes, args.yes)
    checked = Progress(len(sweep.points), "points checked", not args.quiet)
    sweep = load(args.spec, on_point=checked)  # every point checked (its controller designed)
    where = Path(args.spec) if Path(args.spec).suffix else None
    if sweep.fast_estimator_points and not args.quiet:
        print(
            f"note: {len(sweep.fast_estimator_points)} of {len(sweep.points)} points put the estimator bandwidth "
            "near the sampling rate (|p| Ts > 0.5): measurement noise is barely filtered there",
            file=sys.stderr,
        )
    _preflight([sweep.base], sweep.controllers, args.quiet)  # the base point; every point's margins are in its rows
    t0 = time.perf_counter()
    folder, computed = run_sweep(
        sweep, _sweep_out(args, sweep.name), args.workers, args.scheduler, args.backend, args.restart, where,
        show_progress=not args.quiet,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    if not args.no_report:
        write_report(folder, args.metric)
    if not args.quiet:
        flights = computed * sweep.chunk * len(sweep.controllers)
        print(f"{computed} chunk(s) computed in {wall:.1f} s (about {flights / max(wall, 1e-9):.1f} flights/s); "
              f"results in {folder}", file=sys.stderr)  # fmt: skip
    return 0


def cmd_sweep_report(args: argparse.Namespace) -> int:
    from .sweeps import write_report

    files = write_report(Path(args.folder), args.metric, args.x, args.y)
    if not args.quiet:
        print(f"wrote {len(files)} files to {args.folder}", file=sys.stderr)
    return 0


def cmd_tune(args: argparse.Namespace) -> int:
    """Search gains with optuna over a population of plants; write the best as a scenario file."""
    from .analysis.plots import _save, plt
    from .analysis.report import write_html
    from .io import RunFolder, check_folder_path, write_text
    from .sweeps.budget import check_budget, tuning_seconds
    from .sweeps.tune import _optuna, best_scenario_toml, bound_notes, load_tuning, trials_csv, tune

    _optuna()  # a missing extra is said at once, before anything compiles
    t = load_tuning(args.spec, check_corners=False)
    out = check_folder_path(Path(args.out) if args.out else _default_out("tune", t.name))
    seconds = tuning_seconds(t, t.trials if args.trials is None else args.trials, args.backend, args.workers)
    check_budget(seconds, f"tuning {t.name}", args.max_minutes, args.yes)
    t = load_tuning(args.spec)  # the search box's corners checked (their controllers designed)
    _preflight([t.base_spec()], [t.controller], args.quiet)
    with RunFolder(out) as folder:
        log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
        res = tune(t, args.workers, args.scheduler, args.trials, args.backend, log)
        write_text(folder.path("trials.csv"), trials_csv(res["trials"]))
        best_row = min(res["trials"], key=lambda r: r["cost"])
        if best_row["failed"] or best_row.get("below_margin", 0):
            from .errors import VtolImpedanceError

            margin = " and within the phase margin" if best_row.get("below_margin") else ""
            raise VtolImpedanceError(
                f"no trial flew every member of the population without failing{margin} (the best had "
                f"{best_row['failed']} failed flights): no best.toml is written; widen or move the search ranges, "
                "or soften the population"
            )
        toml_text = best_scenario_toml(t, res["best"])
        write_text(folder.path("best.toml"), toml_text)
        notes = bound_notes(t, res["best"])
        costs = [r["cost"] for r in res["trials"]]
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.plot(range(1, len(costs) + 1), costs, "o", ms=3, color="gray", label="trial")
        ax.plot(range(1, len(costs) + 1), [min(costs[: i + 1]) for i in range(len(costs))], color="tab:blue",
                label="best so far")  # fmt: skip
        ax.set_yscale("log")
        ax.set_xlabel("trial")
        ax.set_ylabel(f"cost ({t.metric} + penalties)")
        ax.grid(alpha=0.3)
        ax.legend()
        fig_path = _save(fig, folder.path("history.png"))
        keys = list(res["best"])
        fmt = lambda v: f"{v:.4g}" if isinstance(v, int | float) else str(v)  # noqa: E731
        rows = [[str(i + 1)] + [fmt(r[k]) for k in keys] + [fmt(r["cost"]), str(r["failed"])]
                for i, r in enumerate(res["trials"])]  # fmt: skip
        write_html(folder.staging, f"Tuning {t.name}", tables=[("Trials", ["trial", *keys, "cost", "failed"], rows)],
                   figures={"Search": [fig_path]},
                   notes=[f"Best cost {res['cost']:.4g}; best.toml:", toml_text, *notes],
                   config=t.data, seed=t.seed)  # fmt: skip
        final = folder.commit(t.data, seed=t.seed)
    print(toml_text, end="")
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    if not args.quiet:
        print(f"best cost {res['cost']:.4g}; results written to {final}", file=sys.stderr)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run, table

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    res = run(Path(args.out), quick=args.quick, log=log, compile_times=not args.quick, yardstick=args.yardstick)
    print(table(res))  # the table always, on stdout; --quiet silences the progress only
    return 0


def _numbers(text: str | None, name: str, n: int) -> tuple[float, ...] | None:
    """``"a,b,c"`` as ``n`` finite numbers, or a clear error naming the option."""
    from .errors import InputError

    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(f"{name} must be {n} comma-separated finite numbers, got {text!r}")
    return vals


def cmd_live(args: argparse.Namespace) -> int:
    """The estimator (and with --control the outer loop) on a vehicle over MAVLink; see the README, "Live over
    MAVLink"."""
    import json as _json

    from .errors import InputError
    from .estimator.momentum import EstimatorParams
    from .live import ControlSettings, EstimatorSettings, LiveSettings, run_live

    control = None
    only_with_control = {
        "--comply": args.comply, "--impedance": args.impedance, "--kp": args.kp, "--dp": args.dp,
        "--fence": args.fence, "--max-speed": args.max_speed, "--tilt-max": args.tilt_max,
        "--tilt-rate": args.tilt_rate, "--watchdog": args.watchdog, "--on-loss": args.on_loss,
        "--handshake-timeout": args.handshake_timeout, "--arm": args.arm or None,
    }  # fmt: skip
    if args.control is None:
        given = [k for k, v in only_with_control.items() if v is not None]
        if given:
            raise InputError(f"{', '.join(given)} appl{'y' if len(given) > 1 else 'ies'} with --control only")
    else:
        fence = _numbers(args.fence, "--fence", 2)
        comply = _numbers(args.comply, "--comply", 3)
        if comply is None:
            comply = (1.0, 1.0, 0.0) if args.control == "comply" else (0.0, 0.0, 0.0)
        kw = {
            "impedance": _numbers(args.impedance, "--impedance", 3),
            "Kp": args.kp,
            "Dp": args.dp,
            "tilt_max_deg": args.tilt_max,
            "tilt_rate_max_deg_s": args.tilt_rate,
            "max_speed_m_s": args.max_speed,
            "watchdog_s": args.watchdog,
            "on_loss": args.on_loss,
            "handshake_timeout_s": args.handshake_timeout,
        }
        if fence is not None:
            kw["fence_radius_m"], kw["fence_height_m"] = fence
        control = ControlSettings(  # what is not given keeps ControlSettings' default (one place for them)
            variant=args.control, comply=comply, arm=args.arm, **{k: v for k, v in kw.items() if v is not None}
        )  # fmt: skip
    est = EstimatorSettings(
        rate_hz=args.rate, max_gap_s=args.max_gap, backend=args.backend,
        params=EstimatorParams(wn=args.wn, zeta=args.zeta, rotor_tau=args.rotor_tau),
    )  # fmt: skip
    inertia = None
    if args.inertia is not None:
        inertia = _numbers(args.inertia, "--inertia", 3)
    settings = LiveSettings(
        connect=args.connect, autopilot=args.autopilot, system=args.system, vehicle=args.vehicle, mass=args.mass,
        inertia=inertia, hover_thrust=args.hover_thrust, max_thrust=args.max_thrust,
        rotor_constant=args.rotor_constant, estimator=est, duration=args.duration, out=args.out,
        send_back=args.send_back, display=args.display, connect_timeout_s=args.connect_timeout,
        stream_timeout_s=args.stream_timeout, control=control,
    )  # fmt: skip
    if args.backend == "compiled":  # compile (first use) or load the kernels now, not while the link runs
        _warm_live_kernels(quiet=args.display == "none")
    res = run_live(settings, warn=lambda text: print(f"warning: {text}", file=sys.stderr))
    s = res.summary
    print(f"live session ended: {res.end}; {res.ticks} estimates", file=sys.stderr)
    if s.get("control"):
        c = s["control"]
        hb = c.get("handback") or {}
        extra = f", handed back to {hb['mode']}" if hb else ""
        print(f"control: {c['state']} ({c['reason'] or 'ok'}){extra}", file=sys.stderr)
    if res.folder is not None:
        print(f"recorded to {res.folder} (flight.tlog, estimate.csv, live.json)", file=sys.stderr)
    if args.json:
        print(_json.dumps(s, indent=1, default=str))
    return res.exit_code


def _warm_live_kernels(quiet: bool) -> None:
    """One estimator sample on the compiled kernels: the first use after an install or an upgrade compiles
    them (tens of seconds), which must happen before the session's clocks (connect timeout, duration) run."""
    import numpy as np

    from .compiled import kernels_cached
    from .runtime import Estimator

    if not quiet and not kernels_cached():
        print("compiling the estimator's kernels (first use only, cached on disk) ...", file=sys.stderr)
    z = np.zeros(3)
    Estimator(1.0, [0.01, 0.01, 0.02], 0.02).step(z, z, 9.81, z, omega_B=z)


def _sim_event(text: str) -> tuple[float, str, str]:
    from .errors import InputError

    parts = str(text).split(",")
    try:
        if len(parts) != 3:
            raise ValueError
        return float(parts[0]), parts[1].strip(), parts[2].strip()
    except ValueError:
        raise InputError(
            f"--event is T,KIND,ARG (T simulated s; KIND mode, stop or clock), e.g. 8,mode,POSCTL; got {text!r}"
        ) from None


def cmd_sim_autopilot(args: argparse.Namespace) -> int:
    """A simulated autopilot (the project's simulator) behind a MAVLink endpoint."""
    import threading

    from .live.autopilot import Impairments, SimAutopilot, SimSettings

    spec, _ = _load_spec(args.scenario, args.set, None, args.ideal)
    inject_at = _numbers(args.inject_at, "--inject-at", len(str(args.inject_at).split(","))) if args.inject_at else None
    if inject_at is not None and len(inject_at) not in (1, 2):
        from .errors import InputError

        raise InputError(f"--inject-at is T_ON or T_ON,T_OFF in simulated seconds, got {args.inject_at!r}")
    on, off = (inject_at[0], inject_at[1] if len(inject_at) > 1 else float("inf")) if inject_at else (0.0, float("inf"))
    settings = SimSettings(
        connect=args.connect, autopilot=args.autopilot, speed=args.speed, duration=args.duration,
        inject_force_W=_numbers(args.inject_force, "--inject-force", 3) or (0.0, 0.0, 0.0),
        inject_torque_B=_numbers(args.inject_torque, "--inject-torque", 3) or (0.0, 0.0, 0.0),
        inject_on=on, inject_off=off,
        impairments=Impairments(args.loss, args.duplicate, args.reorder, args.latency, args.seed or 0),
        no_streams=tuple(args.no_stream), events=tuple(_sim_event(e) for e in args.event), system=args.system,
        control_rate=args.control_rate,
        plant_rate=args.plant_rate,
    )  # fmt: skip
    sim = SimAutopilot(spec, settings)
    if not args.quiet:
        print(
            f"simulated {sim.profile.name} autopilot flying {spec.name} (system {settings.system}) on "
            f"{sim.address.text}, hovering at {sim.hold_W.tolist()} m NED in {sim.mode}; Ctrl-C to stop",
            file=sys.stderr,
        )
    if settings.duration is None and sim.dist.items and sim.series_end_s < 3600.0:
        print(
            f"note: the disturbances' random series are drawn for the first {sim.series_end_s:.0f} simulated s "
            f"at {settings.plant_rate:g} Hz and hold their last value after that (give --duration to size them)",
            file=sys.stderr,
        )
    done = threading.Event()
    out: dict[str, Any] = {}

    def fly() -> None:
        try:
            out["summary"] = sim.run()
        except BaseException as exc:  # reported by the main thread
            out["error"] = exc
        finally:
            done.set()

    th = threading.Thread(target=fly, name="sim-autopilot", daemon=True)
    th.start()
    try:
        while not done.wait(2.0):
            if not args.quiet:
                p = sim.history[-1][1] if sim.history else sim.hold_W
                print(f"  t {sim.t:7.1f} s  {sim.mode:<12} p_W [{p[0]:+.3f} {p[1]:+.3f} {p[2]:+.3f}] m  "
                      f"set-points {sim.stats['setpoints']}", file=sys.stderr)  # fmt: skip
    except KeyboardInterrupt:
        sim.stop()
        th.join(5.0)
    if "error" in out:
        raise out["error"]
    s = out.get("summary") or sim.summary()
    lat = s.get("setpoint_latency_ms")
    print(f"simulated {s['simulated_s']:.1f} s; final mode {s['mode']}; set-points received {s['setpoints']}"
          + (f", their age on arrival {lat['mean']:.1f} ms mean, {lat['max']:.1f} ms max" if lat else ""),
          file=sys.stderr)  # fmt: skip
    if s["behind_real_time_s"] > 0:
        print(
            f"warning: the computer fell {s['behind_real_time_s']:.1f} s behind --speed {args.speed:g}", file=sys.stderr
        )
    if s["failure"] is not None:
        f = s["failure"]
        print(f"error: the simulated vehicle failed at {f['time']:.2f} s ({f['reason']}); the run stopped there",
              file=sys.stderr)  # fmt: skip
        return 1
    return 0


def _bound_flags(sp: argparse.ArgumentParser) -> None:
    """``--max-minutes`` and ``--yes``: the bound on the estimated duration (docs: sweeps, 'Bounded work')."""
    sp.add_argument("--max-minutes", type=float, default=None, metavar="M",
                    help="refuse when the estimated duration exceeds M minutes (default 10)")  # fmt: skip
    sp.add_argument("--yes", action="store_true", help="run whatever the estimated duration")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vtol-impedance",
        description="Impedance control of VTOL UAVs with a momentum-based wrench estimator "
        "(Ruggiero et al., ICRA 2014): simulate the paper's case studies and your own.",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
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

    sp = sub.add_parser("paper", help="all three case studies with PD, PID and PD+C: figures, table, report")
    common(sp)
    sp.add_argument(
        "--tuning",
        choices=["paper", "design"],
        default="paper",
        help="the paper's controller as printed (default: attitude 8 rad/s, estimator 10 rad/s, no timing "
        "alignment), or this tool's robust design (README, 'Stability margins')",
    )
    sp.add_argument(
        "--jobs", type=int, default=1, help="parallel processes (the compiled backend is fast; plotting dominates)"
    )
    sp.add_argument(
        "--verbose",
        action="store_true",
        help="every margin finding before the flights (default: one line per case; all of them are in the report)",
    )
    sp.set_defaults(func=cmd_paper)

    sp = sub.add_parser("run", help="one scenario with one controller")
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controller", default="pdc", choices=["pd", "pid", "pdc", "comply"])
    common(sp)
    sp.add_argument("--animate", action="store_true", help="also write <scenario>.gif (3D, with the force arrows)")
    sp.set_defaults(func=lambda a: cmd_run(a, [a.controller]))

    sp = sub.add_parser("compare", help="one scenario with several controllers on the same disturbances")
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controllers", default="pd,pid,pdc", help="comma-separated (default: pd,pid,pdc)")
    common(sp)
    sp.add_argument("--animate", action="store_true", help="also write <scenario>.gif (3D, with the force arrows)")
    sp.set_defaults(func=lambda a: cmd_run(a, [c.strip() for c in a.controllers.split(",") if c.strip()]))

    sp = sub.add_parser(
        "margins",
        help="stability margins of a scenario's controllers (the sampled loop linearised): table, Bode, "
        "Nyquist, poles, report",
        description="Linearises the closed loop the simulator flies at the scenario's operating point (hover at the "
        "task's reference, true plant, sensor latencies, rotor lag) and reports per loop the phase, gain and delay "
        "margins and the sensitivity peak, and the closed-loop poles; see the README, 'Stability margins'.",
    )
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controllers", default="pd,pid,pdc", help="comma-separated (default: pd,pid,pdc)")
    sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario value")
    sp.add_argument("--ideal", action="store_true", help="the ideal plant and sensors (no lag, no latency)")
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/margins-<scenario>)")
    sp.add_argument("--no-plots", action="store_true", help="skip figures")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    sp.set_defaults(func=cmd_margins)

    sp = sub.add_parser(
        "estimate",
        help="estimate the external wrench along a flight log (CSV, PX4 .ulg, ArduPilot .bin, MAVLink .tlog): "
        "series, figures, report",
        description="Runs the momentum-based estimator (eqs. (6)-(13)) on a flight log, after checking its "
        "conventions against physics. CSV columns: t_s, vx, vy, vz, roll, pitch, yaw (or q0..q3), wx, wy, wz, "
        "thrust_n (or thrust_norm), optional tx, ty, tz and rpm1..rpm8; see the README, section 'Estimating "
        "from flight logs'. --example list shows the sample logs that ship with the package.",
    )
    sp.add_argument("log", nargs="?", default=None, help="a .ulg (PX4), .bin (ArduPilot), .tlog (MAVLink) or .csv file")
    sp.add_argument("--example", default=None, metavar="NAME", help="a sample log that ships with the package "
                    "(--example list)")  # fmt: skip
    sp.add_argument(
        "--vehicle", default=None, help="preset name or vehicle .toml: nominal mass, inertia, rotor geometry"
    )
    sp.add_argument("--mass", type=float, default=None, help="nominal mass, kg (overrides --vehicle and the log)")
    sp.add_argument("--inertia", default=None, help="nominal inertia Ixx,Iyy,Izz or 9 values, kg m^2 (for the moment)")
    g = sp.add_argument_group("conventions (CSV; checked against physics for every format)")
    g.add_argument("--conventions", default="check", choices=["check", "auto", "unchecked"],
                   help="check the declared conventions against physics (default), choose them from the data "
                   "(auto), or skip that check (only that one: a thrust that does not carry the weight is still "
                   "refused; --on-ground for a log on the ground)")  # fmt: skip
    g.add_argument("--world", default=None, choices=["ned", "enu"], help="world frame of the attitude (and velocity)")
    g.add_argument("--velocity-world", default=None, choices=["ned", "enu"], help="world frame of the velocity")
    g.add_argument("--body", default=None, choices=["frd", "flu"], help="body frame of attitude, rates, torques")
    g.add_argument("--angle-unit", default=None, choices=["rad", "deg"], help="Euler angles (and rates)")
    g.add_argument("--rate-unit", default=None, choices=["rad", "deg"], help="body rates (default: --angle-unit)")
    g.add_argument("--quat-order", default=None, choices=["wxyz", "xyzw"], help="order of q0..q3")
    g.add_argument("--quat-direction", default=None, choices=["body-to-world", "world-to-body"])
    g.add_argument("--time-unit", default=None, choices=["s", "ms", "us", "ns"],
                   help="unit of the time column (default: s for t_s, us for timestamp_us)")  # fmt: skip
    g.add_argument("--rotor-speed-unit", default=None, choices=["rpm", "rad/s"], help="CSV rpm1..rpmN (default rpm)")
    g.add_argument("--column", action="append", default=[], metavar="ROLE=NAME",
                   help="read role ROLE (e.g. vx) from column NAME (repeatable); common other names (time, vel_x, "
                   "p/q/r...) are accepted without it (docs: 'CSV columns')")  # fmt: skip
    g = sp.add_argument_group("vehicle of a telemetry log (.tlog)")
    g.add_argument("--sysid", type=int, default=None, metavar="N",
                   help="MAVLink system id of the vehicle to estimate (needed when a tlog holds several)")  # fmt: skip
    g.add_argument("--compid", type=int, default=None, metavar="C",
                   help="its component id (default: the one that sent the most attitude messages)")  # fmt: skip
    g = sp.add_argument_group("time base")
    g.add_argument("--rate", type=float, default=100.0, help="resampling rate, Hz (default 100)")
    g.add_argument("--max-gap", type=float, default=None, metavar="S",
                   help="dropouts up to this long are bridged, longer ones restart the estimator (default: ten "
                   "periods of the log's slowest signal, within 0.5-5 s)")  # fmt: skip
    g.add_argument("--start", type=float, default=None, help="estimate from this time on, s")
    g.add_argument("--end", type=float, default=None, help="estimate up to this time, s")
    g = sp.add_argument_group("thrust and torque")
    g.add_argument("--airframe", default="auto", choices=["auto", "multirotor"],
                   help="auto: a log of a vehicle that is not a multirotor (fixed wing, helicopter, rover, boat, "
                   "submarine) is refused, a VTOL hybrid warned about; multirotor: take it as one anyway")  # fmt: skip
    g.add_argument("--thrust-from", default="auto", choices=["auto", "commands", "rotors"],
                   help="commands, or measured rotor speeds (no rotor lag); auto: rotor speeds when the log has "
                   "them at 20 Hz or more")  # fmt: skip
    g.add_argument("--thrust-coefficient", type=float, default=None, metavar="KT",
                   help="rotor thrust per speed squared, N/(rad/s)^2 (default: calibrated on the log)")  # fmt: skip
    g.add_argument("--hover-thrust", type=float, default=None,
                   help="normalised hover thrust (0..1); default: the log's estimate or its parameter (not at "
                   "the firmware default), else fitted on the hover windows found in the log (their spread "
                   "becomes the column fz_W_N_hover_sd), else refused (docs: 'The hover thrust')")  # fmt: skip
    g.add_argument("--hover-segment", default=None, metavar="T0,T1", help="fit the hover thrust on this hover")
    g.add_argument("--on-ground", action="store_true",
                   help="the vehicle stands on the ground (a bench test): the thrust is not checked against the "
                   "weight and the force is the ground reaction plus the external force")  # fmt: skip
    g.add_argument("--torque-scale", default=None, metavar="KX,KY,KZ",
                   help="N m per unit normalised torque (else from the log's rotor geometry)")  # fmt: skip
    g = sp.add_argument_group("estimator")
    g.add_argument("--wn", type=float, default=10.0, help="bandwidth, rad/s (paper: 10)")
    g.add_argument("--zeta", type=float, default=1.0, help="damping of eq. (10) (paper: 1)")
    g.add_argument("--order", type=int, default=2, help="filter order (2: eq. (10))")
    g.add_argument("--prototype", default="zeta", choices=["zeta", "binomial", "butterworth"])
    g.add_argument(
        "--velocity-delay",
        type=float,
        default=0.0,
        metavar="S",
        help="latency of the logged velocity against the commands, s (the estimator aligns to it; a PX4 log's "
        "timestamp_sample already does)",
    )
    g.add_argument(
        "--attitude-delay",
        type=float,
        default=0.0,
        metavar="S",
        help="latency of the logged attitude and rates against the commands, s",
    )
    g.add_argument(
        "--rotor-tau",
        type=float,
        default=0.0,
        metavar="S",
        help="rotor time constant: the commands pass through a first-order rotor model, s",
    )
    g.add_argument("--zero-phase", action="store_true", help="also the offline forward-backward estimate")
    g.add_argument("--quiet-segment", default=None, metavar="T0,T1", help="report the mean estimate here (bias)")
    g.add_argument("--remove-bias", action="store_true", help="subtract the quiet-segment bias")
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--force", action="store_true",
                    help="estimate even when the log's columns contradict physics (the verdict is refused); the "
                    "override is recorded in the results and printed")  # fmt: skip
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/estimate-<log name>)")
    sp.add_argument("--no-plots", action="store_true", help="skip figures")
    sp.add_argument("--quiet", action="store_true", help="no notes or progress (warnings are still printed)")
    sp.set_defaults(func=cmd_estimate)

    sp = sub.add_parser(
        "sweep",
        help="a parameter study or Monte-Carlo over any scenario value (resumable; optional Dask)",
        description="Runs a sweep file (or a built-in study: rate-vs-bandwidth, payload-vs-offset) on the "
        "compiled batch engine, writes one Parquet file per chunk and a summary. Running the same command "
        "again after an interruption computes only the missing chunks.",
    )
    sp.add_argument("spec", help="a sweep .toml file or the name of a built-in study")
    sp.add_argument("--out", default=None, help=f"sweep folder (default: {DEFAULT_OUT}/sweep-<name>)")
    sp.add_argument("--workers", type=int, default=None, help="start a local Dask cluster with N worker processes")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS", help="use an existing Dask cluster")
    sp.add_argument("--restart", action="store_true", help="discard a different sweep found in the folder")
    sp.add_argument("--metric", default="rms_ep_cm", help="metric of the summary figures (default rms_ep_cm)")
    sp.add_argument("--no-report", action="store_true", help="only the data, no summary")
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    _bound_flags(sp)
    sp.set_defaults(func=cmd_sweep)

    sp = sub.add_parser("sweep-report", help="summary figures, table and HTML report of a finished sweep folder")
    sp.add_argument("folder", help="a sweep folder")
    sp.add_argument("--metric", default="rms_ep_cm", help="metric (default rms_ep_cm)")
    sp.add_argument("--x", default=None, help="axis along x of the heat maps (default: the first axis)")
    sp.add_argument("--y", default=None, help="axis along y of the heat maps (default: the second axis)")
    sp.add_argument("--quiet", action="store_true")
    sp.set_defaults(func=cmd_sweep_report)

    sp = sub.add_parser("tune", help="search gains with optuna over a population of plants; best as a scenario file")
    sp.add_argument("spec", help="a tuning .toml file")
    sp.add_argument("--trials", type=int, default=None, help="number of trials (default: the file's)")
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/tune-<name>)")
    sp.add_argument("--workers", type=int, default=None, help="start a local Dask cluster with N worker processes")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS", help="use an existing Dask cluster")
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--quiet", action="store_true")
    _bound_flags(sp)
    sp.set_defaults(func=cmd_tune)

    sp = sub.add_parser("bench", help="speed of the compiled and NumPy backends; prints a table, writes JSON")
    sp.add_argument("--out", default=f"{DEFAULT_OUT}/bench.json", help=f"JSON file (default: {DEFAULT_OUT}/bench.json)")
    sp.add_argument(
        "--quick", action="store_true", help="small sizes and short runs, no cold-compile measurement (a smoke test)"
    )
    sp.add_argument("--quiet", action="store_true", help="only the table (no progress)")
    sp.add_argument(
        "--yardstick", type=Path, default=None, metavar="NUMBA_LOOP_PY",
        help="also time the shared yardstick (its numba_loop.py) against this project, alternating rounds: "
        "one vehicle, a 10,000-vehicle batch, the controller step, and their ratios",
    )  # fmt: skip
    sp.set_defaults(func=cmd_bench)

    sp = sub.add_parser(
        "live",
        help="the wrench estimate live from a vehicle over MAVLink (and with --control the outer impedance loop)",
        description="Connects over MAVLink (pymavlink addresses), asks for the streams the estimator needs, shows the "
        "estimated external force and moment on one steady screen, and records the flight (flight.tlog, "
        "estimate.csv, live.json) in a run folder. With --control it flies the outer loop offboard "
        "(SET_ATTITUDE_TARGET) with a handshake, fence, limits and a watchdog. See the README, 'Live over MAVLink'.",
    )
    sp.add_argument("--connect", required=True, metavar="ADDRESS",
                    help="udpin:HOST:PORT (listen, e.g. udpin:127.0.0.1:14550), udpout:HOST:PORT, tcp:HOST:PORT, "
                    "or a serial device /dev/ttyUSB0,57600")  # fmt: skip
    sp.add_argument("--system", type=int, default=None, help="the vehicle's system id (default: the first heard)")
    sp.add_argument("--autopilot", default="auto", choices=["auto", "px4", "ardupilot"],
                    help="its message set (default: from its heartbeat)")  # fmt: skip
    sp.add_argument("--vehicle", default="pelican", help="preset or vehicle .toml: nominal mass, inertia, rotors")
    sp.add_argument("--mass", type=float, default=None, help="nominal mass, kg (overrides --vehicle)")
    sp.add_argument("--inertia", default=None, metavar="IXX,IYY,IZZ", help="nominal inertia, kg m^2")
    g = sp.add_argument_group("thrust in newtons")
    g.add_argument("--hover-thrust", type=float, default=None,
                   help="normalised hover thrust (default: the vehicle's MPC_THR_HOVER / MOT_THST_HOVER)")  # fmt: skip
    g.add_argument("--max-thrust", type=float, default=None, help="total thrust at full throttle, N")
    g.add_argument("--rotor-constant", type=float, default=None, metavar="KF",
                   help="N s^2/rad^2: use the ESCs' rotor speeds (f = KF omega^2)")  # fmt: skip
    g = sp.add_argument_group("estimator")
    g.add_argument("--rate", type=float, default=50.0, help="estimator rate and requested stream rate, Hz (50)")
    g.add_argument("--wn", type=float, default=10.0, help="bandwidth of eq. (10), rad/s (paper: 10)")
    g.add_argument("--zeta", type=float, default=1.0, help="damping of eq. (10) (paper: 1)")
    g.add_argument("--rotor-tau", type=float, default=0.0, help="rotor time constant the commands pass through, s")
    g.add_argument("--max-gap", type=float, default=0.25, help="a longer gap in a stream restarts the estimator, s")
    g.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    g = sp.add_argument_group("offboard control")
    g.add_argument("--control", nargs="?", const="pdc", default=None, choices=["pdc", "comply"],
                   help="fly the outer loop: pdc (reject: PD + estimate) or comply (yield on --comply)")  # fmt: skip
    g.add_argument("--comply", default=None, metavar="X,Y,Z", help="comply fraction per world axis (comply: 1,1,0)")
    # these take effect with --control only (None: not given, the ControlSettings default)
    g.add_argument("--impedance", default=None, metavar="M,D,K", help="comply's M_d kg, D_d N s/m, K_d N/m (2,6,5)")
    g.add_argument("--kp", type=float, default=None, help="position stiffness Kp, N/m (4; the paper's 16 is too "
                   "fast for an autopilot's attitude interface, README)")  # fmt: skip
    g.add_argument("--dp", type=float, default=None, help="position damping Dp, N s/m (5; paper: 12)")
    g.add_argument("--fence", default=None, metavar="R,H", help="fence around the hold point: radius, height (1,0.5) m")
    g.add_argument("--max-speed", type=float, default=None, help="speed fence, m/s (1.5)")
    g.add_argument("--tilt-max", type=float, default=None, help="largest roll/pitch set-point, deg (20)")
    g.add_argument("--tilt-rate", type=float, default=None, help="largest roll/pitch set-point rate, deg/s (180)")
    g.add_argument("--watchdog", type=float, default=None, help="no telemetry tick for this long hands back, s (0.25)")
    g.add_argument("--on-loss", default=None, choices=["hold", "land"], help="what the watchdog hands back to (hold)")
    g.add_argument("--handshake-timeout", type=float, default=None, help="each handshake step's time limit, s (3)")
    g.add_argument("--arm", action="store_true", help="arm a disarmed vehicle (else it must be armed and flying)")
    sp.add_argument("--duration", type=float, default=None, help="end after this many seconds (default: Ctrl-C)")
    sp.add_argument("--out", default=None, help=f"run folder (default: {DEFAULT_OUT}/live-<date>-<time>)")
    sp.add_argument("--send-back", action="store_true",
                    help="send the estimate as NAMED_VALUE_FLOAT fx..tz and DEBUG_VECT f_hat_W (10 Hz)")  # fmt: skip
    sp.add_argument("--display", default="auto", choices=["auto", "tty", "plain", "none"],
                    help="steady screen (tty), a line every 2 s (plain) or none; auto: tty on a terminal")  # fmt: skip
    sp.add_argument("--connect-timeout", type=float, default=10.0, help="wait this long for a heartbeat, s")
    sp.add_argument("--stream-timeout", type=float, default=3.0, help="wait this long for the streams, s")
    sp.add_argument("--json", action="store_true", help="print the session summary (live.json) on stdout")
    sp.set_defaults(func=cmd_live)

    sp = sub.add_parser(
        "sim-autopilot",
        help="a simulated autopilot (this simulator, PX4 or ArduPilot messages) behind a MAVLink endpoint",
        description="Flies a scenario's true vehicle and disturbances with its own position hold, streams what PX4 "
        "(or ArduPilot) would, honours SET_ATTITUDE_TARGET in OFFBOARD (GUIDED_NOGPS) with its own attitude loop, "
        "and can inject a known wrench, packet loss, repeats, reordering and latency. Try 'live' against it.",
    )
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file, e.g. case-b-fan")
    sp.add_argument("--connect", required=True, metavar="ADDRESS",
                    help="where to send, e.g. udpout:127.0.0.1:14550 (where 'live' listens)")  # fmt: skip
    sp.add_argument("--autopilot", default="px4", choices=["px4", "ardupilot"], help="whose messages and modes")
    sp.add_argument("--speed", type=float, default=1.0, help="simulated seconds per second (faster than real time)")
    sp.add_argument("--duration", type=float, default=None, help="simulated seconds (default: until Ctrl-C)")
    sp.add_argument("--inject-force", default=None, metavar="FX,FY,FZ", help="a known force, N, world NED")
    sp.add_argument("--inject-torque", default=None, metavar="TX,TY,TZ", help="a known moment, N m, body FRD")
    sp.add_argument("--inject-at", default=None, metavar="T_ON[,T_OFF]", help="when the injection acts, simulated s")
    sp.add_argument("--loss", type=float, default=0.0, help="probability a packet is lost (each way)")
    sp.add_argument("--duplicate", type=float, default=0.0, help="probability a packet is sent twice")
    sp.add_argument("--reorder", type=float, default=0.0, help="probability a packet swaps with the next")
    sp.add_argument("--latency", type=float, default=0.0, help="delay of every packet, s (each way)")
    sp.add_argument("--no-stream", action="append", default=[], metavar="MESSAGE",
                    help="a message this autopilot never sends (repeatable), e.g. LOCAL_POSITION_NED")  # fmt: skip
    sp.add_argument("--event", action="append", default=[], metavar="T,KIND,ARG",
                    help="at simulated time T: mode (a pilot switches to mode ARG, e.g. 8,mode,POSCTL), stop "
                    "(stream ARG stops, e.g. 6,stop,LOCAL_POSITION_NED) or clock (the clock jumps ARG s, "
                    "e.g. 5,clock,-100)")  # fmt: skip
    sp.add_argument("--system", type=int, default=1, help="its MAVLink system id")
    sp.add_argument("--control-rate", type=float, default=50.0, help="its own controller's rate, Hz")
    sp.add_argument("--plant-rate", type=float, default=100.0, help="the plant's RK4 rate, Hz")
    sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario value")
    sp.add_argument("--ideal", action="store_true", help="the ideal plant and sensors (no lag, no noise)")
    sp.add_argument("--seed", type=int, default=None, help="seed of the link's impairments")
    sp.add_argument("--quiet", action="store_true", help="no status lines")
    sp.set_defaults(func=cmd_sim_autopilot)

    sp = sub.add_parser("list", help="registered scenarios and controllers")
    sp.set_defaults(func=cmd_list)
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

    from .errors import VtolImpedanceError

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
                from .errors import InputError

                raise InputError("--out is empty: give a folder (or leave --out out for the default)")
            return int(args.func(args))
    except VtolImpedanceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; no results were written", file=sys.stderr)
        return 130
    except OSError as exc:
        import errno

        from .io import explain_path, user_path

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


if __name__ == "__main__":
    sys.exit(main())
