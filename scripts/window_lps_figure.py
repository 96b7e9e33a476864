"""Remake docs/window_lps_scan.png: LeePerrySmith imported in the real window with the README's steps
(run under Xvfb; reads ../shared/data/leeperrysmith, never copies it):

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/window_lps_figure.py

Open the GLB, load color.jpg, Detect landmarks, Build correspondence, then the FAP dock's open jaw
slider clicked to 600 MNS (front, three-quarter) and the Joy preset at 80 % (front, three-quarter):
the viewport of each, side by side. Prints how long each step took and the window's notes.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
for variable in ("XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME"):
    os.environ[variable] = tempfile.mkdtemp(prefix="mimica-lps-")
DATA = ROOT.parent / "shared" / "data" / "leeperrysmith"

from PySide6.QtCore import QPoint, QSettings, Qt  # noqa: E402
from PySide6.QtGui import QImage, QPainter  # noqa: E402
from PySide6.QtTest import QTest  # noqa: E402
from PySide6.QtWidgets import QApplication, QMessageBox  # noqa: E402

app = QApplication(sys.argv[:1])


def pump(seconds: float, until=lambda: False) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.02)
        if until():
            return True
    return until()


def close_boxes(window) -> None:
    for box in app.topLevelWidgets():
        if isinstance(box, QMessageBox) and box.isVisible():
            print(f"  (closed the box “{box.windowTitle()}”: {box.text()[:120]})")
            box.close()


def viewport_shot(window) -> QImage:
    """The 3-D view as the screen shows it (a widget grab of the native VTK view is empty on software GL)."""
    pump(0.8)
    window.viewport.flush()
    app.processEvents()
    top_left = window.plotter.mapTo(window, QPoint(0, 0)) + window.geometry().topLeft()
    size = window.plotter.size()
    return app.primaryScreen().grabWindow(0, top_left.x(), top_left.y(), size.width(), size.height()).toImage()


def main() -> None:
    from app.main_window import MainWindow

    if not (DATA / "LeePerrySmith.glb").is_file():
        raise SystemExit(f"LeePerrySmith is not at {DATA}")
    settings = QSettings(str(Path(tempfile.mkdtemp()) / "mimica.ini"), QSettings.IniFormat)
    w = MainWindow(settings=settings)
    w.resize(1600, 1000)
    w.move(0, 0)
    w.show()
    pump(180, lambda: w.rig is not None)
    start = time.monotonic()
    w.load_face_file(str(DATA / "LeePerrySmith.glb"))
    pump(180, lambda: w.face is not None and "Perry" in (w.face.metadata.name or "") and not w.is_loading)
    print(f"opened: {w.face.n_vertices} vertices ({time.monotonic() - start:.1f} s)")
    w.load_texture(str(DATA / "color.jpg"))
    pump(180, lambda: not w.is_loading and w.face.texture is not None)
    pump(1.0)
    close_boxes(w)
    start = time.monotonic()
    w.detect_landmarks()
    pump(300, lambda: w.statusBar().currentMessage().startswith("Detected") and not w.is_loading)
    print(f"detected: {w.statusBar().currentMessage()} ({time.monotonic() - start:.1f} s)")
    pump(2.0)
    close_boxes(w)
    start = time.monotonic()
    w.build_correspondence()
    pump(5.0)
    pump(300, lambda: not w.is_loading and w.rig is not None and w.rig.face is w.face)
    print(f"built: {w.face.n_vertices} vertices, parts {sorted(w.face.parts)} ({time.monotonic() - start:.1f} s)")
    for note in w.face.metadata.notes[-4:]:
        print("  note:", note)
    close_boxes(w)
    w.set_landmarks_visible(False)
    w.fap_dock.raise_()
    slider = w.fap_dock.row(3).slider
    while w.rig.value("fap:3") < 600.0:      # page clicks to the right of the handle, as a user would
        QTest.mouseClick(slider, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier,
                         QPoint(int(slider.width() * 0.9), slider.height() // 2))
        pump(0.3)
    print(f"open jaw: {w.rig.value('fap:3'):.0f} MNS")
    shots = []
    for view in ("front", "three-quarter"):
        w.set_camera_view(view)
        shots.append(viewport_shot(w))
    w.rig.set_values({"fap:3": 0.0})
    w.rig.set_expression("joy", 0.8)
    for view in ("front", "three-quarter"):
        w.set_camera_view(view)
        shots.append(viewport_shot(w))
    w.close()
    width, height = shots[0].width(), shots[0].height()
    strip = QImage(width * len(shots), height, QImage.Format.Format_RGB32)
    painter = QPainter(strip)
    for k, shot in enumerate(shots):
        painter.drawImage(k * width, 0, shot)
    painter.end()
    out = ROOT / "docs" / "window_lps_scan.png"
    strip.scaledToWidth(min(strip.width(), 2400), Qt.TransformationMode.SmoothTransformation).save(str(out))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
