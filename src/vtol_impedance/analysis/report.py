"""Tables (CSV, Markdown, terminal) and an HTML report, written atomically."""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..control.impedance import DISPLAY_NAMES
from ..io import write_text
from .metrics import METRIC_COLUMNS

NAMES = DISPLAY_NAMES


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 0.01 and v != 0 else f"{v:.2f}"
    return "" if v is None else str(v)


def table_rows(metrics: dict[str, list[dict[str, Any]]]) -> tuple[list[str], list[list[str]]]:
    head = ["case", "controller", *METRIC_COLUMNS.values(), "failure"]
    rows = []
    for case, rs in metrics.items():
        for r in rs:
            rows.append(
                [case, NAMES.get(r["controller"], r["controller"])]
                + [_fmt(r[k]) for k in METRIC_COLUMNS]
                + [_fmt(r.get("failure"))]
            )
    return head, rows


def markdown_rows(caption: str, head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A captioned Markdown table."""
    out = [f"**{caption}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def text_rows(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An aligned text table."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True))  # noqa: E731
    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(r) for r in rows]) + "\n"


def markdown_table(metrics: dict[str, list[dict[str, Any]]]) -> str:
    head, rows = table_rows(metrics)
    drop_fail = all(not r[-1] for r in rows)
    if drop_fail:
        head, rows = head[:-1], [r[:-1] for r in rows]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def text_table(metrics: dict[str, list[dict[str, Any]]]) -> str:
    head, rows = table_rows(metrics)
    if all(not r[-1] for r in rows):
        head, rows = head[:-1], [r[:-1] for r in rows]
    return text_rows(head, rows)


def write_tables(metrics: dict[str, list[dict[str, Any]]], folder: Path, stem: str = "metrics") -> list[Path]:
    head, rows = table_rows(metrics)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["case", "controller", *METRIC_COLUMNS.keys(), "failure"])
    for case, rs in metrics.items():
        for r in rs:
            w.writerow([case, r["controller"], *(r[k] for k in METRIC_COLUMNS), r.get("failure") or ""])
    return [
        write_text(folder / f"{stem}.csv", buf.getvalue()),
        write_text(folder / f"{stem}.md", markdown_table(metrics)),
    ]


#: What each figure shows, by the end of its file name (the report's captions).
CAPTIONS = {
    "_errors": "Position and velocity error norms over the task window, one line per controller.",
    "_inputs": "Thrust and body torques the rotors were asked for (after the allocation), one column per controller.",
    "_wrench": "The estimated external force (world NED) and moment (Euler coordinates), thick, against what the "
    "nominal model really misses, computed from the true motion, thin; the scale is the task window's.",
    "_xy": "The horizontal path over the task window, one panel per controller: the reference dashed, the "
    "controller's path solid, its RMS distance from the reference in the panel's title.",
    "_margins_bode": "Loop transfers at the operating point: magnitude and phase of each loop (colour) per "
    "controller (line style); the phase margin is the distance from -180 deg where |L| crosses 0 dB.",
    "_margins_nyquist": "Nyquist plots near -1, one panel per controller: a robust loop keeps its curves away from "
    "-1; the grey circle is the distance the phase-margin threshold allows.",
    "_margins_poles": "Closed-loop poles at the operating point: right of the red line grows; the grey wedge is "
    "damped less than the threshold.",
}

#: The figure of Ruggiero et al. (ICRA 2014, Sec. VI.B) each figure mirrors, by scenario (its name without
#: the version) and the end of the figure's file name, in the paper's order.
PAPER_FIGURES: dict[str, dict[str, str]] = {
    "case-a-payload": {"_errors": "Fig. 4(a)-(b)", "_inputs": "Fig. 4(d)", "_wrench": "Fig. 5"},
    "case-b-fan": {"_errors": "Fig. 6", "_wrench": "Fig. 7"},
    "case-c-circle": {"_xy": "Fig. 8(a)", "_errors": "Fig. 8(b)", "_wrench": "Fig. 9"},
}

#: What each column of the reports' tables means, by its header (the legend under each table).
COLUMNS = {
    "case": "the scenario flown, with its version",
    "controller": "PD: the impedance of eq. (18), no compensation; PID: PD plus an integral of the position "
    "error; PD+C: PD with the estimated external force and moment fed forward, eqs. (14) and (20) (the "
    "paper's method); comply: PD+C yielding along the axes its scenario names",
    METRIC_COLUMNS["rms_ep_cm"]: "root mean square of the position error norm over the task window",
    METRIC_COLUMNS["max_ep_cm"]: "largest position error norm over the task window",
    METRIC_COLUMNS["ss_ep_cm"]: "mean position error norm over the last second of the task window",
    METRIC_COLUMNS["rms_ev_cms"]: "root mean square of the velocity error norm over the task window",
    METRIC_COLUMNS["rms_f_err_N"]: "root mean square of the estimated external force (world frame) minus the "
    "force the nominal model misses, computed from the true motion",
    METRIC_COLUMNS["rms_tau_err_mNm"]: "the same for the moment (Euler coordinates)",
    METRIC_COLUMNS["sat_pct"]: "share of the task window in which the rotor allocation or the tilt limit of "
    "eq. (16) gave something up",
    "failure": "why a vehicle stopped before the end (non-finite state, tilt, distance, crash); empty when it "
    "flew to the end",
    "closed loop": "stable when every closed-loop pole of the linearised loop decays",
    "rightmost pole [1/s]": "the closed-loop pole with the largest real part (its growth rate when positive), "
    "continuous equivalent",
    "least damped pole": "the closed-loop pole with the smallest damping ratio",
    "damping": "that pole's damping ratio -Re(s)/|s|",
    "verdict": "ok, or every threshold the controller falls short of",
    "loop": "the loop broken (the others closed): a force or torque input, or a position or attitude reference",
    "phase margin [deg]": "distance from -180 deg of the loop's phase where its gain crosses 1",
    "gain margin up [dB]": "how much the loop's gain may rise before the closed loop goes unstable (none: no "
    "rise does)",
    "gain margin down [dB]": "how much it may fall (a loop around a double integrator also destabilises when "
    "its gain falls; none: no fall does)",
    "delay margin [ms]": "the extra delay the loop tolerates: phase margin over crossover frequency",
    "crossover [rad/s]": "where the loop's gain crosses 1",
    "sensitivity peak": "the largest |1/(1 + L)|: how much the loop amplifies a disturbance at its worst frequency",
    "package": "the tool and the libraries it ran with",
    "version": "their versions; 'seed' is the random seed of the flights",
}


def caption(path: Path) -> str:
    """The caption of a figure: the paper's figure it mirrors (:data:`PAPER_FIGURES`), what it shows, then
    its file name."""
    stem = Path(path).stem
    what = next((v for k, v in CAPTIONS.items() if stem.endswith(k)), "")
    if Path(path).suffix.lower() == ".gif":
        what = "Animation: each vehicle, its reference, the estimated force (thick arrow) and the true one (thin)."
    fig = paper_figure(path)
    if fig and what:
        what = f"{fig}: {what}"
    return f"{what} ({Path(path).name})" if what else Path(path).name


def _paper_kind(path: Path) -> tuple[str, str] | None:
    """``(case, end of the file name)`` of a figure of a paper case (:data:`PAPER_FIGURES`), else ``None``."""
    stem = Path(path).stem
    for case in PAPER_FIGURES:
        m = re.fullmatch(rf"{re.escape(case)}(?:-v\d+)?(_\w+)", stem)
        if m is not None:
            return case, m[1]
    return None


def paper_figure(path: Path) -> str:
    """``"The paper's Fig. 5"``-like words for a figure with a counterpart in :data:`PAPER_FIGURES`, a
    pointer to case A's for another case's inputs (the paper shows only those), ``""`` otherwise."""
    kind = _paper_kind(path)
    if kind is None:
        return ""
    case, end = kind
    if end in PAPER_FIGURES[case]:
        return f"The paper's {PAPER_FIGURES[case][end]}"
    if end == "_inputs":
        return f"Not in the paper (case A's are its {PAPER_FIGURES['case-a-payload']['_inputs']})"
    return ""


def _paper_order(path: Path) -> int:
    """Figures in the paper's order within a case (:data:`PAPER_FIGURES`), the others after them (a stable
    sort keeps their order)."""
    kind = _paper_kind(path)
    order = list(PAPER_FIGURES[kind[0]]) if kind else []
    return order.index(kind[1]) if kind and kind[1] in order else len(order)


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    mime = "image/gif" if Path(path).suffix.lower() == ".gif" else "image/png"
    name = html.escape(Path(path).stem)
    cap = html.escape(caption(path))
    return f"<figure><img src='data:{mime};base64,{data}' alt='{name}'><figcaption>{cap}</figcaption></figure>"


def _cell(text: str) -> str:
    """A table cell: numbers right-aligned, prose (a verdict, a reason) left."""
    return f"<td class='text'>{text}</td>" if len(text) > 24 else f"<td>{text}</td>"


def html_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(_cell(html.escape(str(c))) for c in r) + "</tr>" for r in rows]
    return "\n".join(out) + "</table>"


def legend(head: Sequence[str], extra: dict[str, str] | None = None) -> str:
    """The legend under a table: what each of its columns means (:data:`COLUMNS`, then ``extra``), as
    HTML; ``""`` when no column is known."""
    known = {**COLUMNS, **(extra or {})}
    items = [f"<b>{html.escape(h)}</b>: {html.escape(known[h])}" for h in head if h in known]
    return f"<p class='legend'>{'; '.join(items)}.</p>" if items else ""


def _drop_empty(head: Sequence[str], rows: Sequence[Sequence[str]], names: Sequence[str] = ("failure",)):
    """The table without the columns of ``names`` that are empty in every row."""
    keep = [i for i, h in enumerate(head) if h not in names or any(r[i] for r in rows)]
    return [head[i] for i in keep], [[r[i] for i in keep] for r in rows]


@dataclass(frozen=True)
class Section:
    """A section of :func:`write_html`: a heading, then its tables (each with the legend of its columns,
    from :data:`COLUMNS` and ``legend``), paragraphs (``notes``), a bulleted list (``items``), figures
    (captioned by :func:`caption`), preformatted text and subsections, one heading level down.
    ``anchor``: its id in the page, the table of contents' link (default: made from the title)."""

    title: str
    notes: Sequence[str] = ()
    tables: Sequence[tuple[str, Sequence[str], Sequence[Sequence[str]]]] = ()
    figures: Sequence[Path] = ()
    subsections: Sequence[Section] = ()
    anchor: str = ""
    legend: dict[str, str] = field(default_factory=dict)
    preformatted: str = ""
    items: Sequence[str] = ()


def _anchors(sections: Sequence[Section], taken: set[str]) -> list[str]:
    out = []
    for s in sections:
        base = re.sub(r"[^A-Za-z0-9._-]+", "-", s.anchor or s.title.lower()).strip("-")[:48] or "section"
        a, k = base, 2
        while a in taken:
            a, k = f"{base}-{k}", k + 1
        taken.add(a)
        out.append(a)
    return out


def _render(sections: Sequence[Section], level: int, taken: set[str]) -> tuple[list[str], list[str]]:
    """The HTML of ``sections`` and their table of contents (nested lists of links)."""
    body, toc = [], []
    for s, a in zip(sections, _anchors(sections, taken), strict=True):
        body.append(f"<h{level} id='{a}'>{html.escape(s.title)}</h{level}>")
        for cap, head, rows in s.tables:
            head, rows = _drop_empty(head, rows)
            if cap and cap != s.title:
                body.append(f"<p class='caption'><b>{html.escape(cap)}</b></p>")
            body += [html_table(head, rows), legend(head, s.legend)]
        body += [f"<p class='note'>{html.escape(n)}</p>" for n in s.notes]
        body += ["<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in s.items) + "</ul>"] if s.items else []
        body += [_img(p) for p in s.figures]
        body += [f"<pre>{html.escape(s.preformatted)}</pre>"] if s.preformatted else []
        sub_body, sub_toc = _render(s.subsections, level + 1, taken)
        body += sub_body
        toc.append(f"<li><a href='#{a}'>{html.escape(s.title)}</a>" + (f"<ul>{''.join(sub_toc)}</ul>" if sub_toc
                   else "") + "</li>")  # fmt: skip
    return body, toc


def write_html(
    folder: Path,
    title: str,
    *,
    tables: Sequence[tuple[str, Sequence[str], Sequence[Sequence[str]]]] = (),
    figures: dict[str, Sequence[Path]] | None = None,
    notes: Sequence[str] = (),
    config: dict[str, Any] | None = None,
    seed: Any = None,
    sections: Sequence[Section] = (),
) -> Path:
    """One self-contained ``report.html``: a table of contents, then ``tables`` (a section each), the
    ``figures`` (a section per key), ``sections``, the tool and library versions and the seed, and the
    configuration; figures embedded (base64), so that the single file can be mailed. ``notes`` go under
    the title."""
    from .. import __version__
    from ..io import _versions

    versions = {"vtol-impedance": __version__, **_versions()}
    every = [
        *(Section(cap, tables=[(cap, head, rows)]) for cap, head, rows in tables),
        *(Section(case, figures=figs) for case, figs in (figures or {}).items()),
        *sections,
        Section(
            "Versions and seed",
            tables=[("", ["package", "version"], [[k, v] for k, v in versions.items()] + [["seed", str(seed)]])],
            anchor="versions",
        ),
    ]
    if config is not None:
        text = json.dumps(config, indent=1, default=str)[:500000]
        every.append(Section("Configuration", anchor="configuration", preformatted=text))
    body, toc = _render(every, 2, {"contents"})
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}td:first-child,th:first-child{text-align:left;white-space:nowrap}td.text{text-align:left}"
        "img{max-width:100%}figure{margin:1em 0}figcaption{color:#555;font-size:90%}"
        ".legend{color:#555;font-size:85%;margin-top:0}nav ul{margin:0.2em 0}"
        "pre{background:#f6f6f6;padding:0.5em;overflow:auto;max-height:30em}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        *(f"<p class='note'>{html.escape(n)}</p>" for n in notes),
        f"<nav id='contents'><b>Contents</b><ul>{''.join(toc)}</ul></nav>",
        *body,
        "</body></html>",
    ]
    return write_text(folder / "report.html", "\n".join(parts))


def flight_sections(
    tables: Sequence[tuple[str, Sequence[str], Sequence[Sequence[str]]]],
    figures: dict[str, Sequence[Path]],
    *,
    notes: Sequence[str] = (),
    descriptions: dict[str, str] | None = None,
    margin_tables: Sequence[tuple[str, Sequence[str], Sequence[Sequence[str]]]] = (),
    margin_notes: Sequence[str] = (),
    margin_findings: Sequence[str] = (),
) -> list[Section]:
    """The sections of a flight's report (``paper``, ``run``, ``compare``), ordered for a reader: the
    ``tables`` with their ``notes``; each case's figures (``figures``, by case) in the paper's order,
    captions citing the paper's figure (:data:`PAPER_FIGURES`); then the stability margins:
    ``margin_notes`` (paragraphs), ``margin_findings`` (a list), and per case its tables (those whose
    caption starts with ``"<case>:"``) and margin figures (``*_margins_*``). ``descriptions``: a heading
    per case (default: the case's name)."""
    desc = descriptions or {}
    heading = {c: f"{desc[c].rstrip('.')}; scenario {c}" if desc.get(c) else c for c in figures}
    flights = {
        c: sorted((p for p in f if "_margins_" not in Path(p).stem), key=_paper_order) for c, f in figures.items()
    }
    out = [Section("Results", tables=tables, notes=notes, anchor="results")]
    if any(flights.values()):
        subs = [Section(heading[c], figures=f, anchor=f"figures-{c}") for c, f in flights.items() if f]
        out.append(Section("Figures", subsections=subs, anchor="figures"))
    cases = {c: ([t for t in margin_tables if t[0].startswith(f"{c}:")],
                 [p for p in figures[c] if "_margins_" in Path(p).stem]) for c in figures}  # fmt: skip
    rest = [t for t in margin_tables if not any(t in ts for ts, _ in cases.values())]
    if margin_notes or margin_findings or margin_tables:
        from ..robust import Thresholds

        t = Thresholds()
        subs = [Section(f"Margins: {c}", tables=ts, figures=fs, anchor=f"margins-{c}")
                for c, (ts, fs) in cases.items() if ts or fs]  # fmt: skip
        notes = [
            "Each controller's closed loop linearised at the operating point (hover at the reference where the "
            "task window starts, on the true plant, under the disturbances' mean wrench) and broken at one loop "
            f"at a time, the others closed; thresholds: {t.phase_deg:g} deg phase, {t.gain_db:g} dB gain up and "
            f"down, damping {t.damping:g} ('vtol-impedance margins' for one scenario; the guide's 'Stability "
            "margins' for why).",
            *margin_notes,
        ]
        out.append(Section("Stability margins", notes=notes, items=margin_findings, tables=rest, subsections=subs,
                           anchor="margins"))  # fmt: skip
    return out
