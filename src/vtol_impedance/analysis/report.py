"""Tables (CSV, Markdown, terminal) and an HTML report, written atomically."""

from __future__ import annotations

import base64
import csv
import html
import io
import json
from collections.abc import Sequence
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
    "_xy": "The horizontal path over the task window: the reference dashed, each controller solid.",
    "_margins_bode": "Loop transfers at the operating point: magnitude and phase of each loop (colour) per "
    "controller (line style); the phase margin is the distance from -180 deg where |L| crosses 0 dB.",
    "_margins_nyquist": "Nyquist plots near -1, one panel per controller: a robust loop keeps its curves away from "
    "-1; the grey circle is the distance the phase-margin threshold allows.",
    "_margins_poles": "Closed-loop poles at the operating point: right of the red line grows; the grey wedge is "
    "damped less than the threshold.",
}


def caption(path: Path) -> str:
    """The caption of a figure: what it shows, then its file name."""
    stem = Path(path).stem
    what = next((v for k, v in CAPTIONS.items() if stem.endswith(k)), "")
    if Path(path).suffix.lower() == ".gif":
        what = "Animation: each vehicle, its reference, the estimated force (thick arrow) and the true one (thin)."
    return f"{what} ({Path(path).name})" if what else Path(path).name


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    mime = "image/gif" if Path(path).suffix.lower() == ".gif" else "image/png"
    name = html.escape(Path(path).stem)
    cap = html.escape(caption(path))
    return f"<figure><img src='data:{mime};base64,{data}' alt='{name}'><figcaption>{cap}</figcaption></figure>"


def html_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows]
    return "\n".join(out) + "</table>"


def write_html(
    folder: Path,
    title: str,
    *,
    tables: Sequence[tuple[str, Sequence[str], Sequence[Sequence[str]]]] = (),
    figures: dict[str, Sequence[Path]] | None = None,
    notes: Sequence[str] = (),
    config: dict[str, Any] | None = None,
    seed: Any = None,
) -> Path:
    """One self-contained ``report.html``: figures embedded (base64), tables, notes, the configuration,
    the tool and library versions and the seed, so that the single file can be mailed."""
    from .. import __version__
    from ..io import _versions

    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}img{max-width:100%}figure{margin:1em 0}figcaption{color:#555;font-size:90%}"
        "pre{background:#f6f6f6;padding:0.5em;overflow:auto;max-height:30em}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    parts += [f"<p class='note'>{html.escape(n)}</p>" for n in notes]
    for caption, head, rows in tables:
        parts.append(f"<h2>{html.escape(caption)}</h2>")
        parts.append(html_table(head, rows))
    for case, figs in (figures or {}).items():
        parts.append(f"<h2>{html.escape(case)}</h2>")
        parts += [_img(p) for p in figs]
    versions = {"vtol-impedance": __version__, **_versions()}
    parts.append("<h2>Versions and seed</h2>")
    parts.append(html_table(["package", "version"], [[k, v] for k, v in versions.items()] + [["seed", str(seed)]]))
    if config is not None:
        text = json.dumps(config, indent=1, default=str)
        parts.append("<h2>Configuration</h2><pre>" + html.escape(text[:500000]) + "</pre>")
    parts.append("</body></html>")
    return write_text(folder / "report.html", "\n".join(parts))
