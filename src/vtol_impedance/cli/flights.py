"""What the flying commands (paper, run, compare) share: the pre-flight margin check, flying a case (in worker
processes for several), and writing a case's files, tables and report."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .common import _Progress


def _run_case(spec: Any, variants: list[str], seed: int | None, quiet: bool, backend: str = "compiled") -> Any:
    from ..scenarios import simulate

    return simulate(spec, variants, seed=seed, progress=_Progress(spec.name, not quiet), backend=backend)


def _run_case_job(args: tuple[Any, list[str], int | None, bool, str]) -> Any:
    return _run_case(*args)


def _run_parallel(jobs_args: list[tuple[Any, ...]], jobs: int) -> list[Any]:
    from concurrent.futures import ProcessPoolExecutor

    from ..io import quiet_worker, spawning_quietly

    ex = ProcessPoolExecutor(max_workers=jobs, initializer=quiet_worker)
    try:
        with spawning_quietly():
            futures = [ex.submit(_run_case_job, a) for a in jobs_args]
        results = [f.result() for f in futures]
    except BaseException:
        for proc in list(getattr(ex, "_processes", {}).values()):
            proc.terminate()
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown()
    return results


def _write_case(result: Any, folder: Any, stem: str, plots: bool, animate: bool = False) -> list[Path]:
    from ..io import write_text

    files = [result.save(folder.path(f"{stem}.npz"))]
    files.append(write_text(folder.path(f"{stem}.config.json"), json.dumps(result.config, indent=1)))
    if plots:
        from ..analysis.plots import plot_case

        files += plot_case(result, folder.staging, stem)
    if animate:
        from ..analysis.animate import write_gif

        files.append(write_gif(result, folder.path(f"{stem}.gif")))
    return files


def _write_mjcf(spec: Any, folder: Any) -> Path:
    """The MuJoCo model that was flown, for MuJoCo's own viewer (``python -m mujoco.viewer --mjcf ...``)."""
    from ..io import write_text
    from ..scenarios.spec import build
    from ..sim.mjplant import scene_mjcf

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
    from ..analysis.measures import purpose_tables
    from ..analysis.metrics import compute_metrics
    from ..analysis.report import (
        flight_sections,
        markdown_rows,
        table_rows,
        text_rows,
        text_table,
        write_html,
        write_tables,
    )
    from ..io import write_text

    metrics = {name: compute_metrics(r) for name, r in results.items()}
    write_tables(metrics, folder.staging)
    notes = [
        "Errors are over each case's task window (hover after take-off for A and B, the two circle laps for C).",
        _gains_note(results),
        "Estimation error compares the estimate with everything the nominal model misses (payload, mismatch, "
        "rotor lag, drag, disturbances), computed from the true motion.",
    ]
    if any(str(r.config.get("backend")).startswith("mujoco") for r in results.values()):
        from ..io import _versions

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
    from ..scenarios.spec import PAPER_CONTROL, ControlSpec

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


def _preflight(
    specs: list[Any], variants: list[str], quiet: bool, verbose: bool = False, paper_gains: bool = False
) -> dict[str, Any]:
    """The margin check before a flight: margins of every controller at each scenario's operating point,
    and a warning (on stderr) naming what falls short of the thresholds, one line per scenario
    (:func:`~vtol_impedance.scenarios.margins.summary_of`; every finding with ``verbose``). ``paper_gains``:
    the controller is the paper's as printed, whose shortfalls are expected on a realistic plant; the
    warning says so and points at the designed tuning. Returns the reports per scenario, for the run
    folder's figures and report."""
    from ..robust import LoopSizeError, Thresholds, TrimError
    from ..scenarios.margins import below_header, scenario_margins, summary_of, warnings_of

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
        print(f"warning: {below_header(t)}\n" + "\n".join(lines), file=sys.stderr)
    return out


def _write_margins(reports: dict[str, Any], folder: Any, stem: str, plots: bool) -> tuple[list[Path], list[Any]]:
    """Figures, ``<stem>.margins.json`` and the report tables of one scenario's margins."""
    from ..analysis.margin_plots import margin_rows, margins_json, plot_margins, pole_rows
    from ..io import write_text

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
