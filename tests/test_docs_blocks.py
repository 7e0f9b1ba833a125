"""Every code block of README.md and of the documentation pages (docs/**/*.md) runs as written.

The rules (docs/install.md, "Every code block runs", says the same to readers):

- ``python`` blocks run in order, one namespace per page, in one working folder shared by all pages
  (a user following the docs in one place).
- ``bash`` blocks: every ``vtol-impedance ...`` command runs in that folder through the CLI's ``main``
  and must exit with 0. To keep this test short, commands that fly are cut to 2 s (``--duration 2``)
  and, with ``margins`` and ``estimate``, draw no figures or animations (``--no-plots``, ``--animate``
  dropped: the figures are tested by ``test_cli``, ``test_interaction`` and ``test_logs``); plain
  ``paper`` is run by ``test_first_hour`` (with figures, its output and report checked); ``sweep`` flies
  the first and last value of each axis with one seed, 2 s flights and no margin check; ``tune`` two
  trials of two plants over 3 s flights; ``--workers`` is dropped (``tests/test_sweeps.py`` runs the
  cluster). Square brackets mark optional arguments and are left out. A command already run by an
  earlier page is not run again.
- Setup lines (venv, pip, sourcing, the docs build, the test suite, MuJoCo's viewer) are in
  ``NOT_RUN`` with the reason; any other line fails the test, so a new block cannot go untested.
- ``toml`` blocks are loaded as what they are: a scenario file, a sweep, a tuning file, a vehicle, or
  an ``[interaction]`` table on top of a scenario.
- Files a block names are generated first: ``my_scenario.toml``, ``my_quad.toml`` and
  ``my_tuning.toml`` from the docs' own scenario, vehicle and tuning blocks, ``flight.ulg`` (PX4 ULog)
  and ``ros_export.csv`` from flights with a known wrench (``synthflight``, the simulator).
- A documented command that fails today is in ``KNOWN_FAILURES`` with the error it gives and why; the
  test fails when it starts to pass, so that the list stays true.
"""

from __future__ import annotations

import contextlib
import doctest
import importlib
import io
import re
import shlex
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SKIP_DIRS = {"_build", "_gallery_src", "auto_examples", "_templates"}
PAGES = ["README.md"] + sorted(
    str(p.relative_to(ROOT)) for p in DOCS.rglob("*.md") if not SKIP_DIRS & set(p.relative_to(DOCS).parts)
)

#: Lines of bash blocks that the test does not run, and why.
NOT_RUN = {
    r"python3 -m venv \.venv": ".ci/run makes the environment",
    r"(\.venv/bin/)?pip install \S+": ".ci/run installs the package and its extras",
    r"(\.venv/bin/)?python -m pytest.*": "the test suite itself",
    r"(\.venv/bin/)?python -m sphinx .*": ".ci/run builds the docs",
    r"source \.venv/bin/activate|deactivate": "changes the shell only",
    r"python -m mujoco\.viewer --mjcf (?P<file>\S+)": "opens a window (the test checks that the model file exists)",
}
#: Commands run elsewhere (not again here), and where.
RUN_ELSEWHERE = {
    "bench": "tests/test_bench.py runs `bench --quick`",
    "live": "tests/test_live.py runs `live` against `sim-autopilot` over UDP loopback (they run until stopped)",
    "sim-autopilot": "tests/test_live.py runs it with `live` over UDP loopback",
    "tune-page": "tests/test_tune_page.py serves the page and drives it in Chromium (it serves until stopped)",
    "design": "tests/test_tracking_design.py runs `design` on a grid of one and two tunings (the full one takes 40 s)",
}
#: Documented commands that fail today, by the start of their argv: (the error they give, why). The test
#: fails when one starts to pass, so that it is taken off this list.
KNOWN_FAILURES: dict[tuple[str, ...], tuple[str, str]] = {}
FLYING = {"run", "compare", "paper"}
FLIGHT_S = "2"
#: Whole commands (as reduced) run elsewhere with more checked, and where.
RUN_ELSEWHERE_ARGV = {
    ("paper", "--duration", FLIGHT_S, "--no-plots"): "tests/test_first_hour.py runs `paper` (1 s flights, with its "
    "figures) and checks its terminal output and report",
}


@dataclass(frozen=True)
class Block:
    page: str
    line: int
    lang: str
    text: str


def blocks(page: str) -> list[Block]:
    """The fenced code blocks of a Markdown page (MyST directives such as ```{toctree} are not code)."""
    out, lang, start, buf = [], None, 0, []
    for i, line in enumerate((ROOT / page).read_text(encoding="utf-8").splitlines(), 1):
        fence = re.match(r"^```(\S*)\s*$", line)
        if lang is None and fence:
            lang, start, buf = fence.group(1), i, []
        elif lang is not None and line.rstrip() == "```":
            if not lang.startswith("{"):
                out.append(Block(page, start, lang, "\n".join(buf)))
            lang = None
        elif lang is not None:
            buf.append(line)
    return out


def _all_blocks() -> list[Block]:
    return [b for page in PAGES for b in blocks(page)]


# ----------------------------------------------------------------------------------------- TOML


def toml_kind(data: dict) -> str:
    if "axes" in data:
        return "sweep"
    if "search" in data:
        return "tuning"
    if "base" in data:
        return "scenario"
    if "mass" in data:
        return "vehicle"
    if set(data) == {"interaction"}:
        return "interaction"
    return "unknown"


def _toml_block(kind: str, page: str) -> str:
    """The first TOML block of ``kind``: on ``page`` if it has one, else anywhere in the docs."""
    for b in [*blocks(page), *_all_blocks()]:
        if b.lang == "toml" and toml_kind(tomllib.loads(b.text)) == kind:
            return b.text
    raise AssertionError(f"no {kind} TOML block in the docs to write a file from")


def check_toml(block: Block, folder: Path) -> None:
    data = tomllib.loads(block.text)
    kind = toml_kind(data)
    path = folder / f"_block_{Path(block.page).stem}_{block.line}.toml"
    if kind == "sweep":
        from vtol_impedance.sweeps import from_dict

        sweep = from_dict(data, check_points=False)
        assert sweep.points
    elif kind == "tuning":
        from vtol_impedance.errors import InputError
        from vtol_impedance.sweeps.tune import load_tuning

        path.write_text(block.text, encoding="utf-8")
        try:
            load_tuning(path)
        except InputError as exc:  # a tuning file of a command known to fail (KNOWN_FAILURES) may not load
            if not any(k[0] == "tune" and why[0] in str(exc) for k, why in KNOWN_FAILURES.items()):
                raise
    elif kind == "scenario":
        from vtol_impedance.scenarios import load_toml

        path.write_text(block.text, encoding="utf-8")
        load_toml(path)
    elif kind == "vehicle":
        from vtol_impedance.model import vehicle_from_dict

        vehicle_from_dict(data)
    elif kind == "interaction":
        from vtol_impedance.scenarios import load_toml

        path.write_text(f'base = "operator-push"\nname = "docs-interaction-v1"\n{block.text}\n', encoding="utf-8")
        assert load_toml(path).interaction is not None
    else:
        raise AssertionError(f"{block.page}:{block.line}: a TOML block that is none of the known kinds: {list(data)}")


# ------------------------------------------------------------------------------ generated files


def _write_ulog(path: Path) -> None:
    """A 22 s PX4 log (v1.14 topics, normalised commands, control-allocation parameters) of a flight
    with a known wrench, built from Newton-Euler equations (``synthflight``, as in ``test_logs``)."""
    import synthflight
    from test_logs import _ulog

    _ulog(synthflight.flight(duration=22.0, rate=100.0), path, "new", v_every=10)


def _write_ros_csv(path: Path) -> None:
    """The simulator's case B logged the ROS way (``examples/estimate_from_a_log.py``), its velocity
    columns named ``vel_x`` (renamed by the docs' ``--column vx=vel_x``), ``vy``, ``vz``."""
    import runpy

    example = runpy.run_path(str(ROOT / "examples" / "estimate_from_a_log.py"))
    example["write_ros_style_csv"](path, duration=6.0)
    head, _, rest = path.read_text().partition("\n")
    path.write_text(head.replace("vel_y", "vy").replace("vel_z", "vz") + "\n" + rest)


GENERATED = {
    "flight.ulg": lambda path, page: _write_ulog(path),
    "ros_export.csv": lambda path, page: _write_ros_csv(path),
    "my_scenario.toml": lambda path, page: path.write_text(_toml_block("scenario", page), encoding="utf-8"),
    "my_quad.toml": lambda path, page: path.write_text(_toml_block("vehicle", page), encoding="utf-8"),
    "my_tuning.toml": lambda path, page: path.write_text(_toml_block("tuning", page), encoding="utf-8"),
}


def generate_named_files(text: str, page: str, folder: Path) -> None:
    for name, make in GENERATED.items():
        if re.search(rf"(?<![\w/.-]){re.escape(name)}\b", text) and not (folder / name).exists():
            make(folder / name, page)


# ------------------------------------------------------------------------------------------ bash


def commands(text: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments dropped, ``&&`` split."""
    joined = re.sub(r"\\\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        for part in line.split("&&"):
            words = shlex.split(part, comments=True)
            if words:
                out.append(shlex.join(words))
    return out


def cli_argv(command: str) -> list[str] | None:
    """``vtol-impedance ARGS`` (or ``.venv/bin/vtol-impedance``) as an argv without optional ``[...]``."""
    words = shlex.split(command)
    if not words or words[0] not in ("vtol-impedance", ".venv/bin/vtol-impedance"):
        return None
    argv, optional = [], False
    for w in words[1:]:
        if w.startswith("["):
            optional = True
        if not optional:
            argv.append(w)
        if w.endswith("]"):
            optional = False
    return argv


def _drop_option(argv: list[str], option: str) -> list[str]:
    out, skip = [], False
    for w in argv:
        if skip:
            skip = False
        elif w == option:
            skip = True
        elif not w.startswith(option + "="):
            out.append(w)
    return out


def reduced(argv: list[str]) -> list[str]:
    """The command as the test runs it (the reductions of the module docstring)."""
    sub, argv = argv[0], list(argv)
    if sub in FLYING and "--duration" not in argv:
        argv += ["--duration", FLIGHT_S]
    if sub in (*FLYING, "margins", "estimate"):
        argv = [w for w in argv if w != "--animate"]
        if "--no-plots" not in argv:
            argv.append("--no-plots")
    if sub in ("sweep", "tune"):
        argv = _drop_option(argv, "--workers")
    if sub == "tune":
        argv = [*_drop_option(argv, "--trials"), "--trials", "2"]
    return argv


def _shrink_sweep(data: dict) -> dict:
    data = dict(data)
    axes = {}
    for key, axis in data.get("axes", {}).items():
        if isinstance(axis, list):
            axes[key] = [axis[0], axis[-1]] if len(axis) > 1 else axis
        else:
            axes[key] = {**axis, "n": 1 if axis.get("min") == axis.get("max") else 2}
    data["axes"] = axes
    if data.get("mode") == "random":
        data["samples"] = 2
    data.update(seeds=1, margins=False)
    data["set"] = {**data.get("set", {}), "duration": float(FLIGHT_S)}
    return data


@pytest.fixture
def short_studies(monkeypatch, tmp_path):
    """Sweeps and tuning files as the test flies them (module docstring): loaded, shrunk, written to a
    temporary file and loaded from there by the real loaders."""
    import vtol_impedance.sweeps as sweeps
    import vtol_impedance.sweeps.spec as spec
    import vtol_impedance.sweeps.tune as tune

    load_sweep, load_tuning = sweeps.load, tune.load_tuning

    def short_sweep(path_or_name, **kw):  # kw: check_points, on_point
        path = Path(path_or_name)
        if not path.suffix and not path.exists():
            path = spec._BUILTIN / f"{path_or_name}.toml"
        data = _shrink_sweep(tomllib.loads(path.read_text(encoding="utf-8")))
        short = tmp_path / f"{path.stem}.toml"
        short.write_text(_dump_toml(data), encoding="utf-8")
        return load_sweep(short, **kw)

    def short_tuning(path, **kw):  # kw: check_corners
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        data.update(trials=2, population=2)
        data["set"] = {**data.get("set", {}), "duration": 3.0}
        short = tmp_path / f"tuning-{Path(path).name}"
        short.write_text(_dump_toml(data), encoding="utf-8")
        return load_tuning(short, **kw)

    monkeypatch.setattr(sweeps, "load", short_sweep)
    monkeypatch.setattr(tune, "load_tuning", short_tuning)


def _dump_toml(data: dict, prefix: str = "") -> str:
    """Enough TOML for sweep and tuning files: scalars, lists, inline tables for ranges, tables."""
    import json

    def value(v):
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        if isinstance(v, bool):
            return "true" if v else "false"
        return json.dumps(v)

    simple = {k: v for k, v in data.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    lines = [f"{json.dumps(k) if '[' in k or '.' in k else k} = {value(v)}" for k, v in simple.items()]
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{json.dumps(k)} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


_RAN: set[tuple[str, ...]] = set()


def run_command(command: str, block: Block, folder: Path) -> None:
    argv = cli_argv(command)
    if argv is None:
        for pattern in NOT_RUN:
            m = re.fullmatch(pattern, command)
            if m:
                if "file" in m.groupdict():
                    assert (folder / m["file"]).exists(), f"{block.page}:{block.line}: {m['file']} was not written"
                return
        raise AssertionError(
            f"{block.page}:{block.line}: {command!r} is neither a vtol-impedance command nor a setup line the "
            "test knows (NOT_RUN): make it one, or add it to NOT_RUN with the reason"
        )
    if argv and argv[0] in RUN_ELSEWHERE:
        return
    argv = reduced(argv)
    if tuple(argv) in _RAN or tuple(argv) in RUN_ELSEWHERE_ARGV:
        return
    from vtol_impedance.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(argv)
        except SystemExit as exc:  # --version, --help
            rc = exc.code or 0
    known = next((why for k, why in KNOWN_FAILURES.items() if tuple(argv[: len(k)]) == k), None)
    if known and known[0] in err.getvalue():
        assert rc != 0
        _RAN.add(tuple(argv))
        return
    where = f"{block.page}:{block.line}: `vtol-impedance {shlex.join(argv)}`"
    if known:
        assert rc != 0, f"{where} passes now: take it off KNOWN_FAILURES"
    assert rc == 0, f"{where} exited with {rc}:\n{err.getvalue()}"
    _RAN.add(tuple(argv))


# ----------------------------------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """One working folder for every page, with ``examples/`` as in a clone of the repository."""
    where = tmp_path_factory.mktemp("docs-blocks")
    (where / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    return where


@pytest.mark.parametrize("page", PAGES)
def test_code_blocks_run(page, folder, monkeypatch, short_studies):
    monkeypatch.chdir(folder)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace = {"__name__": "__docs__"}
    for block in blocks(page):
        if block.lang in ("python", "bash", "sh", "toml"):
            generate_named_files(block.text, page, folder)
        if block.lang == "python":
            try:
                exec(compile(block.text, f"{page}:{block.line}", "exec"), namespace)
            except Exception as exc:
                raise AssertionError(f"{page}, the python block at line {block.line} fails: {exc!r}") from exc
        elif block.lang in ("bash", "sh"):
            for command in commands(block.text):
                run_command(command, block, folder)
        elif block.lang == "toml":
            check_toml(block, folder)
    import matplotlib.pyplot as plt

    plt.close("all")


def test_every_page_is_checked_and_has_its_kinds_of_blocks():
    """The pages the test runs are the docs' pages, and the blocks it meets are of kinds it runs."""
    assert "README.md" in PAGES and "docs/install.md" in PAGES and len(PAGES) >= 10
    langs = {b.lang for b in _all_blocks()}
    assert langs <= {"python", "bash", "toml", "text", ""}, f"blocks of a language the test does not run: {langs}"


def test_readme_contents_links_resolve():
    """The README's table of contents points at headings that exist (GitHub's anchors)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")

    def slug(title: str) -> str:
        title = re.sub(r"[^\w\- ]", "", title.strip().lower())
        return title.replace(" ", "-")

    anchors = {slug(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}
    links = re.findall(r"\]\(#([^)]+)\)", text)
    assert links, "the README has no table of contents"
    assert not [a for a in links if a not in anchors], f"links to no heading: {[a for a in links if a not in anchors]}"
    for target in re.findall(r"\]\(((?:docs/|CHANGELOG|LICENSE)[^)#]*)\)", text):
        assert (ROOT / target).exists(), f"README links to {target}, which does not exist"


def test_docstring_examples_run():
    """The ``>>>`` examples in the docstrings of the public packages run and print what they show."""
    finder, runner = doctest.DocTestFinder(), doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    tried = 0
    packages = (
        "",
        ".model",
        ".estimator",
        ".control",
        ".sim",
        ".robust",
        ".scenarios",
        ".analysis",
        ".logs",
        ".sweeps",
    )
    for package in packages:
        mod = importlib.import_module(f"vtol_impedance{package}")
        for name in mod.__all__:
            if name.startswith("__"):
                continue
            for test in finder.find(getattr(mod, name), f"vtol_impedance{package}.{name}"):
                tried += len(test.examples)
                out = io.StringIO()
                result = runner.run(test, out=out.write)
                assert not result.failed, out.getvalue()
    assert tried > 0


# The machinery must be able to fail.


def test_the_block_rules_catch_what_they_are_for(tmp_path, monkeypatch):
    assert cli_argv("vtol-impedance paper [--out DIR] [--jobs N]") == ["paper"]
    assert reduced(["run", "case-a-payload"]) == ["run", "case-a-payload", "--duration", "2", "--no-plots"]
    assert reduced(["compare", "x", "--animate"]) == ["compare", "x", "--duration", "2", "--no-plots"]
    assert reduced(["estimate", "f.ulg"]) == ["estimate", "f.ulg", "--no-plots"]
    assert tuple(reduced(["paper"])) in RUN_ELSEWHERE_ARGV and tuple(reduced(["paper", "--tuning", "design"])) not in (
        RUN_ELSEWHERE_ARGV
    )
    assert commands("a \\\n  b  # c\nd && e") == ["a b", "d", "e"]
    with pytest.raises(AssertionError, match="neither a vtol-impedance command"):
        run_command("rm -rf results", Block("x.md", 1, "bash", ""), tmp_path)
    with pytest.raises(AssertionError, match="exited with 2"):
        run_command("vtol-impedance run no-such-scenario", Block("x.md", 1, "bash", ""), tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "_RAN", set())  # what other tests ran runs again here
    monkeypatch.setitem(KNOWN_FAILURES, ("list",), ("an error list never gives", "for this test"))
    with pytest.raises(AssertionError, match="passes now: take it off KNOWN_FAILURES"):
        run_command("vtol-impedance list", Block("x.md", 1, "bash", ""), tmp_path)
    with pytest.raises(AssertionError, match="none of the known kinds"):
        check_toml(Block("x.md", 1, "toml", "colour = 1"), tmp_path)
    page = tmp_path / "page.md"
    page.write_text("```python\nundefined_name\n```\n")
    [block] = blocks(str(page))
    with pytest.raises(NameError):
        exec(block.text, {})
