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
    if not only or "control_point_tour.png" in only:
        control_point_tour(window, app, settle)
    window.close()


def control_points_in_front(window, settle):
    """Raise the Control points dock, wait until its markers are drawn, front view without landmarks."""
    dock = window.control_point_dock
    dock.raise_()
    deadline = time.monotonic() + 60
    while not dock.markers_shown() and time.monotonic() < deadline:
        settle(0.2)
    window.set_landmarks_visible(False)
    window.set_camera_view("front")
    return dock


def control_point_drag_shot(window, app, settle) -> None:
    """docs/control_point_drag.png: the left mouth corner in the middle of a drag (real mouse events on the
    viewport, as a user's), its influence region highlighted and the mirror partner following."""
    from PySide6.QtCore import QPoint, Qt
    from PySide6.QtTest import QTest

    from app.picking import display_to_qt
    from app.projection import world_to_display

    dock = control_points_in_front(window, settle)
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


def control_point_tour(window, app, settle) -> None:
    """docs/control_point_tour.png: thesis B in the window, one state per panel: a point placed from the
    reference chart, a kernel switched, an EPC emotion, a DPC file playing on the timeline, Waters
    muscle sliders, and an inverse drag (each by the dock's own actions or real mouse events)."""
    import numpy as np
    from PIL import Image, ImageDraw, ImageFont
    from PySide6.QtCore import QPoint, Qt
    from PySide6.QtTest import QTest

    from app.picking import display_to_qt
    from app.projection import world_to_display
    from core.formats.dpc_file import DpcSequence, write_dpc
    from core.layers.rbf.emotions import emotion_displacements

    dock = control_points_in_front(window, settle)
    window.rig.reset([k for k in window.rig.parameters() if k.startswith("cp:")])   # e.g. the drag shot's pose
    window.plotter.camera.zoom(1.3)
    widget, panels = window.plotter, []

    def grab(caption: str) -> None:
        settle(0.8)
        image = app.primaryScreen().grabWindow(0).copy(window.frameGeometry()).toImage()
        path = Path(tempfile.mkdtemp()) / "panel.png"
        image.save(str(path))
        panels.append((caption, Image.open(path).convert("RGB")))

    def screen_point(world) -> QPoint:
        x, y, _ = world_to_display(window.plotter.renderer, np.asarray(world, float))[0]
        return QPoint(*(round(c) for c in display_to_qt(widget, x, y)))

    def drag(start: QPoint, offset: QPoint) -> None:
        QTest.mouseMove(widget, start)
        QTest.mousePress(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
        for i in range(1, 11):
            QTest.mouseMove(widget, start + offset * i / 10)
            settle(0.05)
        QTest.mouseRelease(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start + offset)

    # 1. Place a point from the chart: pick it there, then click its new spot on the skin.
    rbf = dock.rbf
    names = list(rbf.points.names)
    corner = names.index("mouth_corner_l")
    dock.point_combo.setCurrentIndex(dock.point_combo.findData(rbf.points.feature_points[corner]))
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("place"))
    target = np.asarray(dock._point_positions()[corner]) + [4.0, 6.0, 0.0]
    spot = screen_point(target)
    QTest.mouseClick(widget, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, spot)
    grab("1  Reference chart: mouth_corner_l picked in the chart, then clicked on the face")
    # 2. A control-point move under another kernel.
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("off"))
    fp = rbf.points.feature_points[corner]
    window.rig.set_values({f"cp:{fp}:x": 6.0, f"cp:{fp}:y": 8.0})
    dock.kernel_combo.setCurrentIndex(dock.kernel_combo.findData("gaussian"))
    grab("2  mouth_corner_l moved (6, 8) mm with the Gaussian kernel")
    dock.kernel_combo.setCurrentIndex(dock.kernel_combo.findData("multiquadric"))
    window.rig.reset([f"cp:{fp}:x", f"cp:{fp}:y"])
    # 3. An EPC emotion (thesis B's joy, FACS action units).
    dock.apply_emotion("joy")
    grab("3  EPC emotion: joy (thesis B Tables 3.2-3.3)")
    dock.apply_emotion("neutral")
    # 4. A DPC file on the timeline: neutral to surprise in one second, shown at its last frame.
    moves = emotion_displacements("surprise")
    rest = np.zeros((len(names), 3))
    peak = np.array([moves.get(n, np.zeros(3)) for n in names], float)
    frames = np.stack([rest + peak * k / 29 for k in range(30)])
    path = Path(tempfile.mkdtemp()) / "surprise.dpc"
    write_dpc(path, DpcSequence(frames, tuple(names), tuple(rbf.points.feature_points), 30.0))
    dock.import_dpc(str(path))
    controller = dock._timeline()
    controller.seek(29 / 30)
    grab("4  DPC file imported and played: neutral -> surprise, frame 29 of 30")
    controller.undo_stack.undo()   # the DPC keys go again (one undo step), so later panels start clean
    controller.seek(0.0)
    window.rig.reset([k for k in window.rig.parameters() if k.startswith("cp:")])
    # 5. Waters muscles: the zygomatic majors pulled.
    window.rig.set_values({"waters:zygomatic_major:left": 1.0, "waters:zygomatic_major:right": 1.0})
    grab("5  Waters vector muscles: zygomatic major L/R at full contraction")
    window.rig.reset([k for k in window.rig.parameters() if k.startswith("waters:")])
    # 6. Inverse: drag a skin point on the cheek; the Waters muscles follow.
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("inverse"))
    # Start on skin well away from every control point (a press on a point would drag the point).
    points = np.asarray(dock._point_positions())
    face = window.rig.face
    near_mouth = face.vertices[np.linalg.norm(face.vertices - face.landmark_position("8.3"), axis=1) < 25]
    gap = np.linalg.norm(near_mouth[:, None, :2] - points[None, :, :2], axis=2).min(axis=1)
    front = near_mouth[:, 2] > face.landmark_position("8.3")[2] - 5
    start = near_mouth[np.argmax(np.where(front, gap, -1))]
    drag(screen_point(start), QPoint(14, -16))
    grab("6  Inverse: a skin point dragged up and out; the Waters sliders moved to reach it")
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("off"))

    width = 800
    tiles = [(c, im.resize((width, round(im.height * width / im.width)))) for c, im in panels]
    band, height = 34, tiles[0][1].height
    sheet = Image.new("RGB", (2 * width, 3 * (height + band)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=20)
    for k, (caption, im) in enumerate(tiles):
        x, y = (k % 2) * width, (k // 2) * (height + band)
        draw.text((x + 8, y + 6), caption, fill=(20, 20, 20), font=font)
        sheet.paste(im, (x, y + band))
    out = ROOT / "docs" / "control_point_tour.png"
    sheet.save(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
