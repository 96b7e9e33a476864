"""Layering: ``core`` is GUI/graphics-free.

``core`` holds data and solvers and must import without Qt or VTK, so it can
run in scripts, tests and workers. Checked two ways: statically (every import
statement in every core/*.py, including ones nested in functions) and
dynamically (importing every core module in a fresh interpreter).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "core"
FORBIDDEN = ("PySide6", "PyQt5", "PyQt6", "qtpy", "pyvista", "pyvistaqt", "vtk", "vtkmodules")


def _core_files() -> list[Path]:
    return sorted(p for p in CORE.rglob("*.py") if "__pycache__" not in p.parts)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _forbidden(name: str) -> bool:
    top = name.split(".")[0]
    return top in FORBIDDEN


def test_core_exists():
    assert _core_files(), "no core/*.py found"


def test_core_sources_import_no_gui_or_vtk():
    offenders = []
    for path in _core_files():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", ""))
                  in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant)
                  and isinstance(node.args[0].value, str)):
                names = [node.args[0].value]
            offenders += [f"{path.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names if _forbidden(n)]
    assert not offenders, "core must not use Qt/VTK:\n" + "\n".join(offenders)


def test_importing_core_loads_no_gui_or_vtk():
    modules = [_module_name(p) for p in _core_files()]
    modules = [m for m in modules if not m.endswith("__main__")]  # scripts run on import
    code = (
        "import importlib, json, sys\n"
        f"mods = {modules!r}\n"
        "errors = {}\n"
        "for m in mods:\n"
        "    try:\n"
        "        importlib.import_module(m)\n"
        "    except Exception as exc:\n"
        "        errors[m] = f'{type(exc).__name__}: {exc}'\n"
        f"bad = sorted(n for n in sys.modules if n.split('.')[0] in {FORBIDDEN!r})\n"
        "print(json.dumps({'bad': bad, 'errors': errors}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not result["errors"], f"core modules failed to import: {result['errors']}"
    assert not result["bad"], f"importing core pulled in: {result['bad']}"


# ---------------------------------------------------------------- architecture contracts
def _lint_imports(root: Path, config: Path) -> subprocess.CompletedProcess:
    """Run import-linter's contracts from ``config`` on the packages found under ``root``."""
    import os

    env = {**os.environ, "PYTHONPATH": str(root)}
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run([sys.executable, "-c", code, "--config", str(config), "--no-cache"], cwd=root, env=env,
                          capture_output=True, text=True, timeout=300)


def test_architecture_contracts_hold():
    """pyproject.toml's [tool.importlinter] contracts: core display-free and independent of app;
    core.layers.muscles, core.registration and core.lipsync independent; app's layers only import downwards."""
    proc = _lint_imports(ROOT, ROOT / "pyproject.toml")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "BROKEN" not in proc.stdout and proc.stdout.count("KEPT") >= 4


def test_architecture_contracts_catch_bad_modules(tmp_path):
    """The same contracts on a copy of the code with three deliberate violations: each is named."""
    import shutil

    for package in ("core", "app"):
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / "core" / "bad_display.py").write_text("import PySide6.QtWidgets\n")
    (tmp_path / "core" / "layers" / "muscles" / "bad_link.py").write_text("from core.registration import icp\n")
    with open(tmp_path / "app" / "viewport.py", "a", encoding="utf-8") as fh:
        fh.write("\nfrom app import main_window  # an upward import\n")
    proc = _lint_imports(tmp_path, tmp_path / "pyproject.toml")
    out = proc.stdout
    assert proc.returncode != 0, out
    assert "core.bad_display -> PySide6" in out.replace("PySide6.QtWidgets", "PySide6")
    assert "core.layers.muscles.bad_link -> core.registration" in out.replace("core.registration.icp", "core.registration")
    assert "app.viewport is not allowed to import app.main_window" in out
