"""Modules deferred at start-up (pyplot, Agg, numpy.f2py/testing, pooch, qtpy's Qt modules) load on first
use, not when pyvista or scipy is imported, and still work."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def run_fresh(code: str) -> subprocess.CompletedProcess:
    # A fresh interpreter: this test process has imported pyvista (and pyplot) already.
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"),
                          capture_output=True, text=True, timeout=300)


def assert_printed(result: subprocess.CompletedProcess, *lines: str) -> None:
    """The fresh interpreter exited cleanly and printed each of ``lines``."""
    assert result.returncode == 0, result.stderr
    for line in lines:
        assert line in result.stdout, (line, result.stdout)


def test_pyvista_imports_without_pyplot_and_pyplot_works_after():
    result = run_fresh(
        "import sys\n"
        "from app.deferred_imports import defer_pyplot, DeferredModule\n"
        "assert defer_pyplot()\n"
        "import pyvista, pyvista.plotting.charts\n"
        "print('figure loaded at import:', 'matplotlib.figure' in sys.modules)\n"
        "assert isinstance(sys.modules['matplotlib.pyplot'], DeferredModule)\n"
        "assert pyvista.plotting.colors.get_cmap_safe('viridis').N == 256\n"   # colour maps need no pyplot
        "import matplotlib.pyplot as plt\n"
        "fig, ax = plt.subplots()\n"                                         # the first use loads the real module
        "ax.plot([0, 1], [0, 1])\n"
        "print('real pyplot in sys.modules:', type(sys.modules['matplotlib.pyplot']).__name__)\n"
        "print('charts see it:', pyvista.plotting.charts.plt.subplots is plt.subplots)\n"
        "print('cycler:', len(list(pyvista.plotting.colors.get_cycler('matplotlib'))) > 0)\n")
    assert_printed(result, "figure loaded at import: False", "real pyplot in sys.modules: module",
                   "charts see it: True", "cycler: True")


def test_nothing_deferred_once_pyplot_is_imported():
    result = run_fresh(
        "import pyvista.plotting\n"   # imports pyplot
        "from app.deferred_imports import defer_pyplot, defer_module\n"
        "print(defer_pyplot(), defer_module('matplotlib.pyplot'), defer_module('no_such_module_here'))\n")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False", "False"]


def test_startup_deferrals_keep_every_deferred_module_working():
    result = run_fresh(
        "import sys\n"
        "from app.deferred_imports import prepare_startup_imports, DeferredModule\n"
        "prepare_startup_imports()\n"
        "import scipy.sparse, scipy.spatial, pyvista.plotting.charts, pyvistaqt\n"
        "real = [m for m in ('numpy.f2py', 'numpy.testing', 'matplotlib.backends.backend_agg', 'pooch',\n"
        "                    'qtpy.QtCore', 'qtpy.QtGui', 'qtpy.QtWidgets')\n"
        "        if not isinstance(sys.modules[m], DeferredModule)]\n"
        "print('loaded at import:', real)\n"
        "from numpy.testing import assert_allclose\n"                       # first use loads the real module
        "assert_allclose([1.0], [1.0])\n"
        "import matplotlib.pyplot as plt\n"
        "fig = plt.figure()\n"
        "canvas = pyvista.plotting.charts.FigureCanvasAgg(fig)\n"             # the name charts imported
        "from matplotlib.backends.backend_agg import FigureCanvasAgg as Real\n"
        "print('real canvas:', type(canvas) is Real)\n"
        "import PySide6.QtGui, PySide6.QtWidgets, qtpy.QtWidgets\n"
        "print('qtpy names:', qtpy.QtWidgets.QAction is PySide6.QtGui.QAction,\n"        # Qt 6 moved QAction
        "      qtpy.QtWidgets.QFrame is PySide6.QtWidgets.QFrame)\n"
        "print('pooch works:', callable(sys.modules['pooch'].retrieve))\n")
    assert_printed(result, "loaded at import: []", "real canvas: True", "qtpy names: True True", "pooch works: True")
