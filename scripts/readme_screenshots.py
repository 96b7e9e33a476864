"""Regenerate the README's window screenshots (run under Xvfb):

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/readme_screenshots.py

Opens the real main window on the built-in face (fresh settings, nothing of the user's), waits
until its rig is ready, sets each view and grabs the screen (a widget grab of the native VTK view
is empty on software GL) into docs/.
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
    for name, view, landmarks, expression in shots:
        window.set_landmarks_visible(landmarks)
        window.set_camera_view(view)
        window.rig.set_expression(expression, 0.8 if expression else 1.0)
        settle(0.8)
        out = ROOT / "docs" / name
        app.primaryScreen().grabWindow(0).copy(window.frameGeometry()).save(str(out))
        print(f"wrote {out}")
    window.rig.set_expression(None)
    window.close()


if __name__ == "__main__":
    main()
