"""Fixtures for the GUI/render tests.

These tests need an X display (the pyvistaqt viewport cannot render under
Qt's ``offscreen`` platform). Run them as ``xvfb-run -a pytest``; without a
display every test here fails with that instruction instead of being skipped.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # for app_helpers

NO_DISPLAY_MESSAGE = (
    "tests/app need an X display for the Qt/VTK viewport. "
    "Run them under Xvfb: xvfb-run -a -s '-screen 0 1600x1000x24' pytest tests/app"
)


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY"))


# Qt must use the X display we are given (an inherited QT_QPA_PLATFORM=offscreen
# would make the VTK widget fail with "Render window is not current").
if _has_display() and os.environ.get("QT_QPA_PLATFORM") == "offscreen":
    os.environ.pop("QT_QPA_PLATFORM")

import pyvista as pv  # noqa: E402

# The Qt viewport renders on the (virtual) screen; app.render always asks
# for its own off-screen plotter explicitly.
pv.OFF_SCREEN = False


@pytest.fixture(autouse=True)
def _require_display():
    if not _has_display():
        pytest.fail(NO_DISPLAY_MESSAGE, pytrace=False)


@pytest.fixture(autouse=True, scope="session")
def _isolated_qsettings(tmp_path_factory):
    """Point every QSettings scope/format at a temp folder: tests never touch the user's settings."""
    from PySide6.QtCore import QSettings

    root = tmp_path_factory.mktemp("qsettings")
    for fmt in (QSettings.Format.NativeFormat, QSettings.Format.IniFormat):
        for scope in (QSettings.Scope.UserScope, QSettings.Scope.SystemScope):
            QSettings.setPath(fmt, scope, str(root))
    yield root


@pytest.fixture
def settings(tmp_path):
    from PySide6.QtCore import QSettings

    return QSettings(str(tmp_path / "mimica-test.ini"), QSettings.Format.IniFormat)


@pytest.fixture
def synthetic_face():
    from app_helpers import make_synthetic_face

    return make_synthetic_face()


@pytest.fixture
def error_boxes(monkeypatch):
    """Capture QMessageBox.warning calls (title, text) instead of blocking on them."""
    from PySide6.QtWidgets import QMessageBox

    calls: list[tuple[str, str]] = []

    def fake_warning(parent, title, text, *args, **kwargs):
        calls.append((title, text))
        return QMessageBox.StandardButton.Ok

    monkeypatch.setattr(QMessageBox, "warning", fake_warning)
    return calls


@pytest.fixture
def window(qtbot, synthetic_face, settings, error_boxes):
    """A shown MainWindow on the synthetic face (no default face load)."""
    from app.main_window import MainWindow

    win = MainWindow(synthetic_face, settings=settings, load_default=False)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    qtbot.wait(50)
    yield win
    win.close()


# The default face and its FAP deformer (~4 s) for the modules that animate it; one per module,
# since tests may edit the face's landmarks in place.
@pytest.fixture(scope="module")
def default_face():
    from core.default_face import load_default_face

    return load_default_face()


@pytest.fixture(scope="module")
def deformer(default_face):
    from core.layers.fap.fat import FapDeformer

    return FapDeformer(default_face)


@pytest.fixture
def default_face_window(qtbot, settings, error_boxes, default_face, deformer):
    """A shown MainWindow on the default face with its rig (the module's prebuilt FAP deformer)."""
    from app.main_window import MainWindow
    from core.rig import FaceRig

    w = MainWindow(settings=settings, load_default=False)
    qtbot.addWidget(w)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()
