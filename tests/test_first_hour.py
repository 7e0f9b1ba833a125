"""The first command as a newcomer meets it: ``vtol-impedance paper``'s terminal output (one margin line per
case, the compile timed as such, the report named last) and its report, ordered for a reviewer (the
table, then the figures citing the paper's figure numbers, then the margins; a table of contents whose
links land; every column explained). One short paper run is shared by every check."""

from __future__ import annotations

import contextlib
import csv
import io
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from vtol_impedance.cli import main
from vtol_impedance.robust.margins import LoopMargins, MarginReport
from vtol_impedance.scenarios import PAPER_CASES, get
from vtol_impedance.scenarios.margins import RISK, scenario_margins, summary_of
from vtol_impedance.sim import Result

CASES = ("case-a-payload-v1", "case-b-fan-v1", "case-c-circle-v1")


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    """``paper --duration 1 --jobs 1`` with its stderr as a pipe sees it, the kernels treated as not yet
    compiled (as on a first run: the compile is announced and timed; here it loads from the cache)."""
    out = tmp_path_factory.mktemp("first-hour") / "paper"
    err, printed = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stderr(err), contextlib.redirect_stdout(printed):
        mp.setattr("vtol_impedance.compiled.kernels_cached", lambda: False)
        rc = main(["paper", "--out", str(out), "--duration", "1.0", "--jobs", "1"])
    assert rc == 0
    return {"out": out, "err": err.getvalue(), "printed": printed.getvalue()}


class _Page(HTMLParser):
    """The report's structure: headings (level, id, text), every id, the contents' links, and the events
    in page order: ``h2``, ``h3``, ``table``, ``th``, ``legend``, ``term`` (a column a legend explains),
    ``caption`` (a figure's), each with its text."""

    TRACKED = ("h2", "h3", "th", "figcaption")

    def __init__(self) -> None:
        super().__init__()
        self.headings: list[tuple[int, str, str]] = []
        self.ids: list[str] = []
        self.toc: list[str] = []
        self.events: list[tuple[str, str]] = []
        self._open: list[list[str]] = []  # [kind, id, text] of the tracked elements now open
        self._nav = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        self._nav = self._nav or tag == "nav"
        if tag == "a" and self._nav and a.get("href", "").startswith("#"):
            self.toc.append(a["href"][1:])
        if tag == "table":
            self.events.append(("table", ""))
        in_legend = bool(self._open) and self._open[-1][0] == "legend"
        if tag in self.TRACKED or (tag == "p" and a.get("class") == "legend") or (tag == "b" and in_legend):
            kind = {"p": "legend", "b": "term", "figcaption": "caption"}.get(tag, tag)
            self._open.append([kind, a.get("id", ""), ""])

    def handle_endtag(self, tag):
        self._nav = self._nav and tag != "nav"
        kind = {"p": "legend", "b": "term", "figcaption": "caption"}.get(tag, tag)
        if self._open and self._open[-1][0] == kind:
            _, hid, text = self._open.pop()
            if kind in ("h2", "h3"):
                self.headings.append((int(kind[1]), hid, text))
            self.events.append((kind, text))

    def handle_data(self, data):
        for entry in self._open:
            entry[2] += data


@pytest.fixture(scope="module")
def page(paper) -> _Page:
    p = _Page()
    p.feed((paper["out"] / "report.html").read_text(encoding="utf-8"))
    return p


def _case_lines(err: str, case: str) -> list[str]:
    """Lines of the margin warning about ``case`` (the progress lines name the case too, never a margin)."""
    return [ln for ln in err.splitlines() if case in ln and re.search(r"deg|dB|damping|unstable|margins", ln)]


# ----------------------------------------------------------------------------- the terminal


def test_one_margin_line_per_case_and_the_risk_still_said_before_the_flight(paper):
    err = paper["err"]
    for case in CASES:
        lines = _case_lines(err, case)
        # the paper's gains fall short on this plant (the guide's "Stability margins"): said, once per case
        assert len(lines) == 1, lines
    assert err.count(RISK) == len(CASES)  # PD+C may fly worse than PD: still said before it flies
    assert "expected for the paper's printed gains" in err and "--tuning design" in err and "--verbose" in err
    assert err.index("warning: stability margins") < err.index("flying 3 cases")
    assert len(err.splitlines()[0]) < 200 and max(len(ln) for ln in _case_lines(err, CASES[0])) < 200


def test_compile_is_announced_and_timed_as_compile_not_as_the_first_case(paper):
    err = paper["err"]
    start = err.index("compiling the simulation kernels")
    end = re.search(r"compiled the kernels in \d+\.\d s", err)
    assert end is not None and start < end.start() < err.index("flying 3 cases")
    first_case = re.search(rf"^  {CASES[0]}: \d+% \(", err, re.M)  # not a terminal: a line per 25 %
    assert first_case is not None and first_case.start() > end.end()


def test_the_last_line_names_the_report(paper):
    last = paper["err"].rstrip().splitlines()[-1]
    assert "report.html" in last
    path = Path(re.search(r"(\S+report\.html)", last)[1])
    assert path.resolve() == (paper["out"] / "report.html").resolve() and path.is_file()


def test_files_table_and_data(paper):
    """What ``paper`` writes: per case the figures, the signals and the configuration; the table."""
    out = paper["out"]
    assert "PD+C" in paper["printed"] and "case-c-circle-v1" in paper["printed"]
    for case in CASES:
        for suffix in ("_errors.png", "_inputs.png", "_wrench.png", ".npz", ".config.json"):
            assert (out / f"{case}{suffix}").stat().st_size > 0
        assert Result.load(out / f"{case}.npz").labels == ["pd", "pid", "pdc"]
    assert (out / "case-c-circle-v1_xy.png").stat().st_size > 0
    rows = list(csv.DictReader((out / "metrics.csv").open(encoding="utf-8")))
    assert len(rows) == 9 and {r["controller"] for r in rows} == {"pd", "pid", "pdc"}
    assert (out / "metrics.md").read_text(encoding="utf-8").startswith("| case")
    assert not list(out.glob(".*.tmp"))


# ----------------------------------------------------------------------------- the report


def test_report_opens_with_the_table_then_figures_then_margins(page):
    h2 = [hid for level, hid, _ in page.headings if level == 2]
    assert h2 == ["results", "figures", "margins", "versions", "configuration"]
    first = [kind for kind, _ in page.events if kind not in ("th", "term")][:3]
    assert first == ["h2", "table", "legend"]  # the table (and its legend) before anything else
    fig = [t for k, t in page.events if k == "caption"]
    margins_at = page.events.index(("h2", "Stability margins"))
    flight = [t for k, t in page.events[:margins_at] if k == "caption"]
    assert flight and all("Fig." in c for c in flight)
    assert all("_margins_" not in c for c in flight)  # the margins' figures come after the flights'
    assert any("_margins_bode" in c for c in fig[len(flight) :])


def test_the_report_holds_every_margin_finding_in_full(paper):
    text = (paper["out"] / "report.html").read_text(encoding="utf-8")
    margins = text[text.index("<h2 id='margins'>") :]
    assert "As expected, the paper&#x27;s printed gains" in margins and "--tuning design" in margins
    for case in CASES:
        # the terminal's one line per case, in full here: each controller, its loop and its margins
        for who in ("PD", "PID", "PD+C"):
            assert f"<li>{case}, {who}: " in margins, (case, who)
    assert margins.count(RISK) >= len(CASES) and "delay margin" in margins


def test_captions_cite_the_paper_figure_each_figure_mirrors(page):
    """Ruggiero et al. 2014, Sec. VI.B: Fig. 4 (a) position and (b) velocity error norms and (d) inputs of
    case A, Fig. 5 its estimated wrench; Figs. 6 and 7 case B's errors and wrench; Fig. 8 (a) the x-y
    circle and (b) the error norm of case C, Fig. 9 its wrench."""
    caps = {re.search(r"\(([\w.-]+\.png)\)$", t)[1]: t for k, t in page.events if k == "caption"}
    expected = {
        "case-a-payload-v1_errors.png": "Fig. 4(a)-(b)",
        "case-a-payload-v1_inputs.png": "Fig. 4(d)",
        "case-a-payload-v1_wrench.png": "Fig. 5",
        "case-b-fan-v1_errors.png": "Fig. 6",
        "case-b-fan-v1_wrench.png": "Fig. 7",
        "case-c-circle-v1_xy.png": "Fig. 8(a)",
        "case-c-circle-v1_errors.png": "Fig. 8(b)",
        "case-c-circle-v1_wrench.png": "Fig. 9",
    }
    for name, fig in expected.items():
        assert caps[name].startswith(f"The paper's {fig}:"), caps[name]
    assert caps["case-b-fan-v1_inputs.png"].startswith("Not in the paper")


def test_contents_links_land_on_ids_of_the_page(page):
    assert len(page.ids) == len(set(page.ids))
    assert page.toc and set(page.toc) <= set(page.ids)
    assert {"results", "figures", "margins"} <= set(page.toc)
    assert {f"figures-{c}" for c in CASES} | {f"margins-{c}" for c in CASES} <= set(page.toc)


def test_every_column_is_explained_and_an_empty_failure_column_dropped(page):
    tables: list[list[str]] = []
    explained: list[set[str]] = []
    for kind, text in page.events:
        if kind == "table":
            tables.append([])
            explained.append(set())
        elif kind == "th":
            tables[-1].append(text)
        elif kind == "term":
            explained[-1].add(text)
    assert len(tables) >= 2 + 2 * len(CASES)  # the metrics, per case the poles and the loops, the versions
    for head, terms in zip(tables, explained, strict=True):
        assert head and set(head) <= terms, set(head) - terms
    assert "failure" not in tables[0]  # every vehicle flew to the end (metrics.csv's column is empty)


def test_case_c_draws_one_panel_per_controller(paper, monkeypatch, tmp_path):
    """Three circles in one panel hide each other: the x-y figure has a panel per controller, each with
    the reference and that controller's path alone."""
    from vtol_impedance.analysis import plots

    drawn = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or path)
    r = Result.load(paper["out"] / "case-c-circle-v1.npz")
    plots.plot_xy(r, tmp_path / "xy.png")
    panels = drawn[0].axes
    assert [a.get_title().split(":")[0] for a in panels] == ["PD", "PID", "PD+C"]
    assert all(len(a.get_lines()) == 2 for a in panels)  # the reference and one path
    plots.plt.close(drawn[0])


# ----------------------------------------------------------------------------- the one-line summary


def _report(phase: float, gain: float, poles: list[complex]) -> MarginReport:
    z = np.zeros(1)
    loop = LoopMargins("pitch torque", gain, gain + 5.0, phase, 12.0, phase / 1e3, 2.0, z, z.astype(complex))
    return MarginReport({"pitch torque": loop}, np.array(poles), label="")


def test_summary_names_who_falls_short_the_worst_and_the_risk():
    ok = _report(45.0, 10.0, [-5.0, -3 + 1j, -3 - 1j])
    pid = _report(15.0, 10.0, [-5.0])  # phase only
    pdc = _report(12.0, 2.0, [-0.5 + 10j, -0.5 - 10j])  # damping 0.5 / sqrt(100.25) = 0.050
    line = summary_of({"pd": ok, "pid": pid, "pdc": pdc})
    assert line.startswith("PID, PD+C below (worst PD+C: phase 12.0 deg, gain 2.0 dB, damping 0.05)")
    assert line.endswith(RISK)
    assert summary_of({"pd": ok, "pid": pid}) == "PID below (worst PID: phase 15.0 deg)"  # no compensation, no risk
    assert summary_of({"pd": ok, "pdc": ok}) == ""
    grows = _report(40.0, 10.0, [0.3 + 5j, 0.3 - 5j])
    assert "PD+C: unstable, a closed-loop pole grows at 0.3 1/s" in summary_of({"pid": pid, "pdc": grows})


def test_the_designed_tuning_the_warning_points_at_meets_the_thresholds():
    for name in PAPER_CASES:
        assert summary_of(scenario_margins(get(name), ["pd", "pid", "pdc"])) == "", name


def test_verbose_prints_every_finding(capsys):
    from vtol_impedance.cli.flights import _preflight
    from vtol_impedance.scenarios import set_value
    from vtol_impedance.scenarios.spec import PAPER_CONTROL

    spec = get("case-a-payload")
    for k, v in PAPER_CONTROL.items():
        spec = set_value(spec, k, v)
    _preflight([spec], ["pd", "pdc"], quiet=False, verbose=True, paper_gains=True)
    err = capsys.readouterr().err
    assert len(_case_lines(err, spec.name)) == 2  # PD and PD+C, each in full
    assert "delay margin" in err and "--verbose" not in err
