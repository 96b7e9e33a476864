"""Regenerate the README's window screenshots (run under Xvfb):

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/readme_screenshots.py

Opens the real main window on the built-in face, sets each view and grabs the
whole window (menus, viewport and status bar) into docs/.
"""

import sys
import tempfile
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    from app.main_window import MainWindow
    from core.default_face import load_default_face

    app = QApplication.instance() or QApplication(sys.argv[:1])
    settings = QSettings(str(Path(tempfile.mkdtemp()) / "mimica.ini"), QSettings.IniFormat)
    window = MainWindow(load_default_face(), settings=settings, load_default=False)
    window.resize(1400, 900)
    window.show()
    shots = [("window_front.png", "front", False), ("window_three_quarter.png", "three-quarter", True)]
    for name, view, landmarks in shots:
        window.set_landmarks_visible(landmarks)
        window.set_camera_view(view)
        for _ in range(20):
            app.processEvents()
        window.plotter.render()
        app.processEvents()
        out = ROOT / "docs" / name
        window.grab().save(str(out))
        print(f"wrote {out}")
    window.close()


if __name__ == "__main__":
    main()
