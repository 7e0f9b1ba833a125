"""The house: imports flow one way through the layers (docs/api/index.rst), the command line is a package with
one module per command, the loop and the controller read as named stages, and ``--help`` loads no heavy
library."""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "vtol_impedance"

#: The layers, lowest first: a module may import its own layer and the ones below it, never one above (a
#: function-level import counts: it is still a dependency).
LAYERS = [
    {"__version__", "conventions", "errors", "io"},
    {"model", "records"},
    {"estimator"},
    {"control"},
    {"compiled", "runtime"},
    {"sim"},
    {"robust"},
    {"scenarios"},
    {"logs"},
    {"analysis"},
    {"sweeps", "live", "bench", "tunepage"},
    {"cli", "__main__", "__init__"},
]
LAYER = {name: i for i, names in enumerate(LAYERS) for name in names}


def _top(path: Path) -> str:
    parts = path.relative_to(PKG).with_suffix("").parts
    return "__init__" if parts == ("__init__",) else parts[0]


def _imports(path: Path) -> set[str]:
    """The package's top-level modules that ``path`` imports, anywhere in it."""
    parts = list(path.relative_to(PKG).with_suffix("").parts)
    pkg = parts if parts[-1] == "__init__" else parts[:-1]
    pkg = [p for p in pkg if p != "__init__"]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = pkg[: len(pkg) - (node.level - 1)]
            target = base + (node.module.split(".") if node.module else [])
            out |= {target[0]} if target else {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("vtol_impedance."):
            out.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            out |= {a.name.split(".")[1] for a in node.names if a.name.startswith("vtol_impedance.")}
    return out


def test_every_module_has_a_layer():
    tops = {_top(p) for p in PKG.rglob("*.py")}
    assert tops <= set(LAYER), f"modules with no layer in LAYERS: {sorted(tops - set(LAYER))}"


def test_imports_flow_one_way():
    upward = []
    for path in sorted(PKG.rglob("*.py")):
        me = _top(path)
        for other in _imports(path) - {me}:
            if LAYER.get(other, -1) > LAYER[me]:
                upward.append(f"{path.relative_to(PKG)} imports {other}")
    assert not upward, "imports against the layers: " + "; ".join(upward)


def test_the_checker_sees_an_upward_import(tmp_path):
    """The check above can fail: a lower layer importing a higher one inside a function is found."""
    fake = PKG / "model" / "_probe_upward.py"
    fake.write_text("def f():\n    from ..analysis import metrics\n", encoding="utf-8")
    try:
        assert "analysis" in _imports(fake)
        with pytest.raises(AssertionError, match="_probe_upward.py imports analysis"):
            test_imports_flow_one_way()
    finally:
        fake.unlink()


def test_the_command_line_is_a_package_with_one_module_per_command():
    from vtol_impedance.cli.main import COMMANDS, build_parser

    assert not (PKG / "cli.py").exists()
    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    commands = set(sub.choices)
    owned = {}
    for module in COMMANDS:
        s = argparse.ArgumentParser().add_subparsers()
        module.register(s)
        owned[module.__name__] = set(s.choices)
    assert set().union(*owned.values()) == commands  # every command is registered by exactly one module
    assert sum(len(v) for v in owned.values()) == len(commands)
    for name, cmds in owned.items():
        assert len(cmds) <= 2, f"{name} registers {cmds}"


def test_help_loads_no_heavy_library():
    code = (
        "import sys\nfrom vtol_impedance.cli import build_parser\nbuild_parser()\n"
        "print(sorted(m for m in ('numba', 'matplotlib', 'scipy', 'pyarrow', 'pymavlink', 'mujoco', 'dask') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def _long_functions(path: Path, limit: int) -> list[str]:
    """Functions whose code (without the docstring) is longer than ``limit`` lines."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                body = body[1:]
            if node.end_lineno - body[0].lineno + 1 > limit:
                out.append(f"{path.name}:{node.name}")
    return out


def test_the_loop_and_the_controller_read_as_stages():
    """No function of the simulator or the runtime is longer than 60 lines of code; the NumPy tick and the
    controller's step call their stages by name."""
    long = [f for p in sorted((PKG / "sim").glob("*.py")) + [PKG / "runtime.py"] for f in _long_functions(p, 60)]
    assert not long, long
    loop = (PKG / "sim" / "loop.py").read_text(encoding="utf-8")
    for stage in ("sens.measure(", "controller_step(", "_log_tick(", "plant.advance(", "_stop_failed("):
        assert stage in loop
    runtime = (PKG / "runtime.py").read_text(encoding="utf-8")
    for stage in ("self._measurement(", "self._reference(", "self._warn_once("):
        assert stage in runtime
