"""Regenerate the README's window screenshots (run under Xvfb):

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/readme_screenshots.py [name.png ...]

Opens the real main window on the built-in face (fresh settings, nothing of the user's), waits
until its rig is ready, sets each view and grabs the screen (a widget grab of the native VTK view
is empty on software GL) into docs/. Names on the command line: only those shots.
"""

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
for variable in ("XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME"):
    os.environ[variable] = tempfile.mkdtemp(prefix="mimica-shots-")

from PySide6.QtCore import QSettings  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402


def main() -> None:
    from app.main_window import MainWindow
    from core.default_face import load_default_face

    app = QApplication.instance() or QApplication(sys.argv[:1])
    settings = QSettings(str(Path(tempfile.mkdtemp()) / "mimica.ini"), QSettings.IniFormat)
    window = MainWindow(load_default_face(), settings=settings, load_default=False)
    window.resize(1600, 1000)
    window.move(0, 0)
    window.show()

    def settle(seconds: float = 0.5) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            app.processEvents()
            time.sleep(0.02)
        window.flush_updates()
        window.plotter.render()
        app.processEvents()

    deadline = time.monotonic() + 120
    while window.rig is None and time.monotonic() < deadline:
        settle(0.2)
    settle(1.0)
    shots = [("window_front.png", "front", False, None), ("window_three_quarter.png", "three-quarter", True, None),
             ("window_timeline.png", "three-quarter", False, "joy")]
    only = set(sys.argv[1:])
    for name, view, landmarks, expression in shots:
        if only and name not in only:
            continue
        window.set_landmarks_visible(landmarks)
        window.set_camera_view(view)
        window.rig.set_expression(expression, 0.8 if expression else 1.0)
        settle(0.8)
        out = ROOT / "docs" / name
        app.primaryScreen().grabWindow(0).copy(window.frameGeometry()).save(str(out))
        print(f"wrote {out}")
    window.rig.set_expression(None)
    if not only or "control_point_drag.png" in only:
        control_point_drag_shot(window, app, settle)
    window.close()


def control_point_drag_shot(window, app, settle) -> None:
    """docs/control_point_drag.png: the left mouth corner in the middle of a drag (real mouse events on the
    viewport, as a user's), its influence region highlighted and the mirror partner following."""
    from PySide6.QtCore import QPoint, Qt
    from PySide6.QtTest import QTest

    from app.picking import display_to_qt
    from app.projection import world_to_display

    dock = window.control_point_dock
    dock.raise_()
    deadline = time.monotonic() + 60
    while not dock.markers_shown() and time.monotonic() < deadline:
        settle(0.2)
    window.set_landmarks_visible(False)
    window.set_camera_view("front")
    index = dock.rbf.points.names.index("mouth_corner_l")
    camera = window.plotter.camera          # closer, centred a little above the mouth
    shift = [0.0, dock._point_positions()[index][1] + 15.0 - camera.focal_point[1], 0.0]
    camera.focal_point = tuple(a + b for a, b in zip(camera.focal_point, shift))
    camera.position = tuple(a + b for a, b in zip(camera.position, shift))
    camera.zoom(1.6)
    window.plotter.renderer.ResetCameraClippingRange()
    settle(0.5)
    x, y, _ = world_to_display(window.plotter.renderer, dock._point_positions()[index])[0]
    start = QPoint(*(round(c) for c in display_to_qt(window.plotter, x, y)))
    widget = window.plotter
    QTest.mouseMove(widget, start)
    QTest.mousePress(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
    for i in range(1, 11):
        QTest.mouseMove(widget, start + QPoint(3 * i, -3 * i))
        settle(0.05)
    settle(0.8)            # the full-quality frame after the pause, still mid-drag
    out = ROOT / "docs" / "control_point_drag.png"
    app.primaryScreen().grabWindow(0).copy(window.frameGeometry()).save(str(out))
    print(f"wrote {out}")
    QTest.mouseRelease(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start + QPoint(30, -30))
    settle(0.2)


if __name__ == "__main__":
    main()
