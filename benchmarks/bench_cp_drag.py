"""Control-point drag latency as a user feels it: each mouse move of a drag to the first picture that shows it.

Starts the real main window on the default face (under ``xvfb-run`` when there is no display: the script
re-runs itself), brings the Control points tab forward, presses on the left mouth corner's marker with
QTest and moves the mouse ``--moves`` times in a small circle; each move is timed from the event to the
first render whose pixels differ from the picture before it (read back from the render window). The
viewport draws its draft copy while things move, so this is the draft frame; ``compute``/``draw`` split
it (the viewport's own timings):

    renderer=<OpenGL renderer string>
    cp_drag_to_pixels_ms median=<x> n=<moves> max=<x>
    cp_drag_compute_ms median=<x> cp_drag_draw_ms median=<x>
    inverse_drag_to_pixels_ms median=<x> ...   the same for a live inverse drag of a cheek point (Waters)

Usage: python benchmarks/bench_cp_drag.py [--moves 20]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from virtual_display import pump_events, rerun_under_xvfb_without_display  # noqa: E402

rerun_under_xvfb_without_display()

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--moves", type=int, default=20, help="mouse moves timed")
args = parser.parse_args()

_home = tempfile.mkdtemp(prefix="mimica-bench-")
for var in ("XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME"):
    os.environ[var] = _home

from PySide6.QtCore import QPoint, QSettings, Qt  # noqa: E402
from PySide6.QtTest import QTest  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

app = QApplication(sys.argv)

from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402
from vtkmodules.vtkCommonCore import vtkUnsignedCharArray  # noqa: E402

from app.main_window import MainWindow  # noqa: E402
from app.picking import display_to_qt  # noqa: E402
from app.projection import world_to_display  # noqa: E402


def pump(seconds: float, until=None) -> bool:
    return pump_events(app, seconds, until)


def pixels(win) -> np.ndarray:
    rw = win.plotter.render_window
    w, h = rw.GetSize()
    data = vtkUnsignedCharArray()
    rw.GetPixelData(0, 0, w - 1, h - 1, 0, data, 0)
    return vtk_to_numpy(data).copy()


def main() -> None:
    from core.default_face import load_default_face

    settings = QSettings(os.path.join(_home, "bench.ini"), QSettings.Format.IniFormat)
    win = MainWindow(load_default_face(), settings=settings, load_default=False)
    win.resize(1600, 1000)
    win.show()
    pump(120, lambda: win.rig is not None)
    pump(0.5)
    dock = win.control_point_dock
    dock.raise_()
    pump(60, dock.markers_shown)
    pump(15, lambda: win.face_actor.preview is not None)
    win.set_camera_view("front")
    pump(0.5)
    win.flush_updates()
    print(f"renderer={win.renderer_name or 'unknown'}")
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}, window {win.plotter.window_size}, "
          f"{win.face.n_vertices} vertices")

    changed: list[float] = []
    watch = {"ref": None}

    def rendered(*_args) -> None:
        if watch["ref"] is not None and not np.array_equal(pixels(win), watch["ref"]):
            changed.append(time.perf_counter())

    win.plotter.render_window.AddObserver("EndEvent", rendered)
    ticks: list[tuple[float, float]] = []
    win.viewport.timed.connect(lambda c, d: ticks.append((c, d)))

    def drag(world_point, radius_px: float, name: str, undo_text: str) -> None:
        x, y, _ = world_to_display(win.plotter.renderer, world_point)[0]
        start = QPoint(*(round(c) for c in display_to_qt(win.plotter, x, y)))
        widget = win.plotter
        ticks.clear()
        QTest.mousePress(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
        QTest.mouseMove(widget, start + QPoint(round(radius_px), 0))      # past the click slop: the drag is on
        pump(0.5)
        times = []
        for i in range(args.moves):
            pump(0.3, lambda: not win.viewport.timer.isActive())
            watch["ref"], changed[:] = pixels(win), []
            angle = 2 * np.pi * (i + 1) / args.moves
            target = start + QPoint(round(radius_px * np.cos(angle)), round(-radius_px * np.sin(angle)))
            t0 = time.perf_counter()
            QTest.mouseMove(widget, target)
            pump(10, lambda: bool(changed))
            watch["ref"] = None
            times.append((changed[0] - t0) * 1e3 if changed else float("nan"))
        QTest.mouseRelease(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
        pump(0.5)
        assert win.undo_stack.undoText() == undo_text, win.undo_stack.undoText()
        print(f"{name}_to_pixels_ms median={np.nanmedian(times):.1f} n={len(times)} max={np.nanmax(times):.1f}")
        if ticks:
            c, d = np.array(ticks).T
            print(f"{name}_compute_ms median={np.median(c):.1f} {name}_draw_ms median={np.median(d):.1f}")

    index = dock.rbf.points.names.index("mouth_corner_l")
    drag(dock._point_positions()[index], 12, "cp_drag", "Move control point mouth_corner_l")
    win.undo_stack.undo()
    # The inverse, live: a cheek point under the left zygomatic major pulled around by the Waters muscles.
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("inverse"))
    dock.show_check.setChecked(False)
    waters = win.rig.layer("waters")
    muscle = waters.model.muscles[waters.model.keys.index("waters:zygomatic_major:left")]
    skin = win.rig.face.vertices[np.argmin(np.linalg.norm(win.rig.face.vertices - (
        0.7 * muscle.insertion + 0.3 * muscle.attachment), axis=1))]
    drag(skin, 8, "inverse_drag", "Inverse drag of a skin point")
    win.close()


if __name__ == "__main__":
    main()
