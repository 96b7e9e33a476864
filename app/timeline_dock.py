"""timeline_dock.py
----
The timeline dock (bottom of the window): transport bar and a custom-painted track view over a
:class:`app.timeline_controller.TimelineController`. Built by the main window with the document and
the window (``TimelineDock(document, window)``), it creates the controller over the document
(``dock.controller``, registered as ``document.timeline``) and the project actions
(:class:`app.project_actions.ProjectActions`, ``document.project``), and adds the File / Edit /
View / Tools menu items to the window.

Track view (:class:`TrackView`)
    Rows are grouped like the docks: the FAP dock's groups (``core.layers.fap.tables.DOCK_GROUPS``), then
    expressions, visemes and muscles. A group header shows a summary of its tracks' keys and folds
    with a click. By default only parameters with a track are listed; "Show all" lists every
    parameter the face can animate (select such a row and press K to start its track).
    Ruler on top in seconds and frames; the red cursor is scrubbed by clicking/dragging in the ruler
    (the viewport follows live). Keys: click selects, Shift+click adds/removes, dragging on empty
    lane space draws a selection box, dragging selected keys moves them in whole frames, the right
    button offers interpolation (step / linear / smooth), copy, paste, delete. Keys are drawn by
    interpolation: ● smooth, ◆ linear, ■ step; selected keys are orange. Each lane also shows the
    track's curve scaled to the parameter's range. Ctrl+wheel zooms time, Shift+wheel pans,
    double-click in the ruler fits the whole duration.

The view holds no timeline state of its own beyond folding, zoom and scroll; the key and track
selections live in the controller (the Edit menu acts on them).
"""

from __future__ import annotations

import traceback

from PySide6.QtCore import QSignalBlocker, Qt
from PySide6.QtGui import QAction, QFontMetrics, QKeySequence
from PySide6.QtWidgets import (
    QCheckBox, QComboBox, QDockWidget, QDoubleSpinBox, QHBoxLayout, QLabel, QMenu,
    QScrollBar, QStyle, QToolButton, QVBoxLayout, QWidget)

from core import timeline as tl

from app.timeline_controller import SPEEDS, TimelineController
from app.widgets import FlowLayout

from app.timeline_rows import (  # noqa: F401 - re-exported
    group_of, Row, build_rows)
from app.timeline_view import (  # noqa: F401 - re-exported
    TrackView)


# ------------------------------------------------------------------ the dock
class TimelineDock(QDockWidget):
    """Transport bar + :class:`TrackView` for the document's :class:`TimelineController`.

    Parameters
    ----------
    document : app.document.Document
    window : app.main_window.MainWindow
        Gets the dock (bottom), the menu items and the window shortcuts; parent of the dialogs.
    state_dir : where untitled projects autosave (default: ``autosave/`` beside the window's settings file).
    check_recovery : offer to recover an autosave left by a Mimica that did not close (after the face loads).
    autosave_ms : autosave interval (default :data:`app.project_actions.AUTOSAVE_MS`).
    """

    def __init__(self, document, window, *, state_dir=None, check_recovery: bool = True,
                 autosave_ms: int | None = None):
        super().__init__("Timeline", window)
        self.setObjectName("timelineDock")
        self.document = document
        self.main_window = window
        self.lipsync_dialog = None
        controller = TimelineController(document)
        controller.dock = self
        self.c = self.controller = controller
        self.setAllowedAreas(Qt.DockWidgetArea.BottomDockWidgetArea | Qt.DockWidgetArea.TopDockWidgetArea)
        body = QWidget(self)
        outer = QVBoxLayout(body)
        outer.setContentsMargins(4, 2, 4, 4)
        outer.setSpacing(3)
        # Three groups (transport, keys, timeline settings) that wrap onto a second row when the
        # dock is narrow, so every control stays in sight.
        groups = [QHBoxLayout() for _ in range(3)]
        bar = groups[0]
        style = self.style()

        def tool(name: str, icon, tip: str, checkable=False) -> QToolButton:
            b = QToolButton(body)
            b.setObjectName(name)
            if isinstance(icon, str):
                b.setText(icon)
            else:
                b.setIcon(style.standardIcon(icon))
            b.setToolTip(tip)
            b.setCheckable(checkable)
            b.setAutoRaise(True)
            bar.addWidget(b)
            return b

        SP = QStyle.StandardPixmap
        self.start_button = tool("timelineStart", SP.SP_MediaSkipBackward, "Go to the start (Home)")
        self.play_button = tool("timelinePlay", SP.SP_MediaPlay, "Play / pause (Space)", checkable=True)
        self.stop_button = tool("timelineStop", SP.SP_MediaStop, "Stop: pause and go back to the start")
        self.loop_check = QCheckBox("Loop", body)
        self.loop_check.setObjectName("timelineLoop")
        self.loop_check.setToolTip("Start again from the beginning at the end")
        bar.addWidget(self.loop_check)
        self.speed_combo = QComboBox(body)
        self.speed_combo.setObjectName("timelineSpeed")
        for s in SPEEDS:
            self.speed_combo.addItem(f"{s:g}×", s)
        self.speed_combo.setCurrentIndex(SPEEDS.index(1.0))
        self.speed_combo.setToolTip("Playback speed (time runs this many times faster than real time)")
        bar.addWidget(self.speed_combo)
        self.time_label = QLabel(body)
        self.time_label.setObjectName("timelineTime")
        self.time_label.setMinimumWidth(QFontMetrics(self.time_label.font()).horizontalAdvance(
            "000.00 s · frame 00000 / 00000") + 8)
        bar.addWidget(self.time_label)
        self.fps_label = QLabel(body)
        self.fps_label.setObjectName("timelineAchievedFps")
        self.fps_label.setToolTip("Frames actually shown per second during playback (late frames are dropped)")
        self.fps_label.setMinimumWidth(QFontMetrics(self.fps_label.font()).horizontalAdvance("shown 00.0 fps") + 6)
        bar.addWidget(self.fps_label)
        bar = groups[1]
        self.key_button = tool("timelineSetKey", "◆ Set key", "Key the selected tracks — or every animated or "
                               "non-neutral control — at the cursor (K)")
        self.key_button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
        self.auto_key_button = tool("timelineAutoKey", "● Auto-key", "While on, every slider change is keyed "
                                    "at the cursor", checkable=True)
        self.auto_key_button.setStyleSheet("QToolButton:checked { color: white; background: #c8352a; "
                                           "border-radius: 3px; }")
        self.show_all_check = QCheckBox("Show all", body)
        self.show_all_check.setObjectName("timelineShowAll")
        self.show_all_check.setToolTip("List every parameter, not only the animated ones")
        bar.addWidget(self.show_all_check)
        self.lipsync_button = tool("timelineLipSync", "Lip-sync…", "Make viseme tracks from text (Tools ▸ Lip-sync)")
        bar = groups[2]
        bar.addWidget(QLabel("fps", body))
        self.fps_combo = QComboBox(body)
        self.fps_combo.setObjectName("timelineFps")
        for f in tl.FPS_CHOICES:
            self.fps_combo.addItem(str(f), f)
        self.fps_combo.setToolTip("Frame rate of the timeline (keys stay at their times)")
        bar.addWidget(self.fps_combo)
        bar.addWidget(QLabel("length", body))
        self.duration_spin = QDoubleSpinBox(body)
        self.duration_spin.setObjectName("timelineDuration")
        self.duration_spin.setRange(0.1, tl.MAX_DURATION_S)
        self.duration_spin.setDecimals(2)
        self.duration_spin.setSuffix(" s")
        self.duration_spin.setKeyboardTracking(False)
        self.duration_spin.setToolTip("Length of the timeline in seconds")
        bar.addWidget(self.duration_spin)
        flow = FlowLayout(spacing=14)
        for group in groups:
            group.setSpacing(4)
            group.setContentsMargins(0, 0, 0, 0)
            holder = QWidget(body)
            holder.setLayout(group)
            flow.addWidget(holder)
        strip = QWidget(body)
        strip.setObjectName("timelineBar")
        strip.setLayout(flow)
        outer.addWidget(strip)

        area = QHBoxLayout()
        area.setSpacing(0)
        self.view = TrackView(controller, body)
        self.scrollbar = QScrollBar(Qt.Orientation.Vertical, body)
        self.view.scrollbar = self.scrollbar
        self.scrollbar.valueChanged.connect(self.view.set_scroll)
        area.addWidget(self.view, 1)
        area.addWidget(self.scrollbar)
        outer.addLayout(area, 1)
        self.empty_label = QLabel("No animated tracks yet: pose the face with the sliders and press K "
                                  "(or ◆ Set key), or turn on Show all.", self.view)
        self.empty_label.setObjectName("timelineEmpty")
        self.empty_label.setStyleSheet("color: palette(mid);")
        self.setWidget(body)

        # widgets -> controller
        self.start_button.clicked.connect(lambda: controller.seek(0.0))
        self.play_button.clicked.connect(lambda _c: controller.toggle_play())
        self.stop_button.clicked.connect(lambda: controller.stop())
        self.loop_check.toggled.connect(lambda on: setattr(controller, "loop", bool(on)))
        self.speed_combo.currentIndexChanged.connect(lambda _i: controller.set_speed(self.speed_combo.currentData()))
        self.key_button.clicked.connect(lambda: controller.set_key())
        self.auto_key_button.toggled.connect(controller.set_auto_key)
        self.show_all_check.toggled.connect(self.view.set_show_all)
        self.fps_combo.activated.connect(self._fps_chosen)
        self.duration_spin.valueChanged.connect(self._duration_chosen)
        # controller -> widgets
        controller.time_changed.connect(lambda _t: self._sync_time())
        controller.playing_changed.connect(self._on_playing)
        controller.edited.connect(lambda _e: self.sync())
        controller.timeline_replaced.connect(self.sync)
        controller.auto_key_changed.connect(self._on_auto_key)
        controller.fps_measured.connect(lambda f: self.fps_label.setText(f"shown {f:.1f} fps"))
        self.view.rows_changed.connect(self._place_empty_label)
        self.sync()
        self._install(window, state_dir=state_dir, check_recovery=check_recovery, autosave_ms=autosave_ms)

    # ------------------------------------------------------------ sync
    def sync(self) -> None:
        """Every widget to the controller's state, emitting nothing."""
        c = self.c
        with QSignalBlocker(self.fps_combo), QSignalBlocker(self.duration_spin), QSignalBlocker(self.loop_check), \
                QSignalBlocker(self.speed_combo), QSignalBlocker(self.auto_key_button):
            self.fps_combo.setCurrentIndex(tl.FPS_CHOICES.index(c.timeline.fps))
            self.duration_spin.setValue(c.timeline.duration)
            self.loop_check.setChecked(c.loop)
            if c.speed in SPEEDS:
                self.speed_combo.setCurrentIndex(SPEEDS.index(c.speed))
            self.auto_key_button.setChecked(c.auto_key)
        self._on_playing(c.playing)
        self._sync_time()
        self._place_empty_label()

    def _sync_time(self) -> None:
        c = self.c
        frame = c.timeline.frame_of(c.current_time)
        self.time_label.setText(f"{c.current_time:.2f} s · frame {frame} / {c.timeline.n_frames - 1}")

    def _on_playing(self, playing: bool) -> None:
        with QSignalBlocker(self.play_button):
            self.play_button.setChecked(playing)
        icon = QStyle.StandardPixmap.SP_MediaPause if playing else QStyle.StandardPixmap.SP_MediaPlay
        self.play_button.setIcon(self.style().standardIcon(icon))
        if not playing and self.c.frames_shown:
            self.fps_label.setText(f"shown {self.c.achieved_fps:.1f} fps")
        elif playing:
            self.fps_label.setText("")

    def _on_auto_key(self, on: bool) -> None:
        with QSignalBlocker(self.auto_key_button):
            self.auto_key_button.setChecked(on)

    def _place_empty_label(self) -> None:
        empty = not any(not r.is_group for r in self.view.rows)
        self.empty_label.setVisible(empty)
        if empty:
            self.empty_label.adjustSize()
            self.empty_label.move(TrackView.NAME_W + 16, TrackView.RULER_H + 12)

    def _fps_chosen(self, _index: int) -> None:
        fps = int(self.fps_combo.currentData())
        if fps != self.c.timeline.fps:
            self.c.set_settings(fps=fps)
        self.sync()

    def _duration_chosen(self, value: float) -> None:
        if abs(value - self.c.timeline.duration) > 1e-9:
            self.c.set_settings(duration=float(value))
            self.view.fit()
        self.sync()

    # ------------------------------------------------------------ place in the window
    def _install(self, window, *, state_dir, check_recovery: bool, autosave_ms: int | None) -> None:
        """The dock at the bottom, File ▸ project / import / export actions, Edit ▸ key actions,
        View ▸ Timeline / playback, Tools ▸ Lip-sync; the project actions; ``controller.actions``."""
        from app.project_actions import AUTOSAVE_MS, ProjectActions

        c = self.controller
        window.addDockWidget(Qt.DockWidgetArea.BottomDockWidgetArea, self)
        self.show()
        self.raise_()
        window.resizeDocks([self], [300], Qt.Orientation.Vertical)
        c.message.connect(lambda text: window.statusBar().showMessage(text, 8000))

        acts = {}
        acts["set_key"] = _action(window, "Set &key", c.set_key, "K",
                                  "Key the selected tracks (or every animated / non-neutral control) at the cursor")
        acts["auto_key"] = _action(window, "&Auto-key", c.set_auto_key, None,
                                   "Key every slider change at the cursor", checkable=True)
        acts["copy_keys"] = _action(window, "&Copy keys", c.copy_selected, QKeySequence.StandardKey.Copy,
                                    "Copy the selected keys")
        acts["paste_keys"] = _action(window, "&Paste keys", c.paste, QKeySequence.StandardKey.Paste,
                                     "Paste the copied keys at the cursor")
        acts["delete_keys"] = _action(window, "&Delete keys", c.delete_selected, QKeySequence.StandardKey.Delete,
                                      "Delete the selected keys")
        acts["select_all_keys"] = _action(window, "Select all &keys", c.select_all_keys, None,
                                          "Select every key of every track")
        acts["play"] = _action(window, "&Play / pause", c.toggle_play, "Space", "Play or pause the timeline")
        acts["stop"] = _action(window, "&Stop", c.stop, None, "Pause and go back to the start")
        acts["loop"] = _action(window, "&Loop playback", lambda on: (setattr(c, "loop", bool(on)), self.sync()),
                               None, "Start again at the end", checkable=True)
        c.auto_key_changed.connect(lambda on: (acts["auto_key"].blockSignals(True), acts["auto_key"].setChecked(on),
                                               acts["auto_key"].blockSignals(False)))
        self.loop_check.toggled.connect(lambda on: (acts["loop"].blockSignals(True), acts["loop"].setChecked(on),
                                                    acts["loop"].blockSignals(False)))
        c.playing_changed.connect(lambda playing: acts["play"].setText("&Pause" if playing else "&Play"))

        edit = _menu(window, "&Edit", before="View")
        if edit.actions() and not edit.actions()[-1].isSeparator():
            edit.addSeparator()
        for name in ("set_key", "auto_key", "copy_keys", "paste_keys", "delete_keys", "select_all_keys"):
            edit.addAction(acts[name])

        view = window.view_menu
        toggle = self.toggleViewAction()
        toggle.setText("&Timeline")
        toggle.setShortcut(QKeySequence("Ctrl+Shift+T"))
        toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        toggle.setStatusTip("Show or hide the timeline")
        window.addAction(toggle)
        view.addAction(toggle)
        playback = view.addMenu("Play&back")
        for name in ("play", "stop", "loop"):
            playback.addAction(acts[name])
        acts["timeline"] = toggle

        tools = _menu(window, "&Tools", before="Help")
        acts["lipsync"] = _action(window, "&Lip-sync from text…", self.open_lipsync_dialog, None,
                                  "Make viseme (and blink) tracks from typed text, spoken by eSpeak NG")
        tools.addAction(acts["lipsync"])
        file_menu = _menu(window, "&File")
        acts["import_animation"] = _action(window, "&Import animation (.fap, .dpc)…", self.import_dialog,
                                           "Ctrl+Shift+O", "Add a .fap or DPC control-point animation as tracks at the cursor")
        acts["export_fap"] = _action(window, "Export .&fap…", self.export_fap_dialog, "Ctrl+Shift+E",
                                     "Write the timeline (or the current pose) as an MPEG-4 .fap animation")
        acts["export_video"] = _action(window, "Export &video…", self.export_video, "Ctrl+E",
                                       "Render the timeline to MP4 (with speech), GIF, AVI or PNG images")
        acts["export_still"] = _action(window, "Export s&till…", lambda: self.export_video(still=True), None,
                                       "Render the face at the timeline's current time to PNG or JPEG")
        anchor = window.screenshot_action
        for name in ("import_animation", "export_fap", "export_video", "export_still"):
            if anchor in file_menu.actions():
                file_menu.insertAction(anchor, acts[name])
            else:
                file_menu.addAction(acts[name])
        self.lipsync_button.clicked.connect(self.open_lipsync_dialog)
        c.actions = acts

        project = ProjectActions(self.document, window, c, state_dir=state_dir,
                                 autosave_ms=AUTOSAVE_MS if autosave_ms is None else autosave_ms)
        c.project = project
        self.document.timeline, self.document.project = c, project
        if check_recovery:
            project.check_startup_recovery_when_ready()

    # ------------------------------------------------------------ dialogs
    def import_dialog(self) -> None:
        from PySide6.QtWidgets import QFileDialog

        path, _ = QFileDialog.getOpenFileName(self.main_window, "Import animation", "",
                                              "Animations (*.fap *.dpc *.txt);;All files (*)")
        if path:
            self.import_file(path)

    def import_file(self, path):
        """Import an animation file onto the timeline; a refusal is shown in a message box."""
        from PySide6.QtWidgets import QMessageBox

        return self.controller.import_animation(
            path, warn=lambda title, text: QMessageBox.warning(self.main_window, title, text))

    def export_video(self, *, still: bool = False):
        """File ▸ Export video… / still: the export dialog for the timeline, rendered from a copy of the
        rig (``controller.animation()``), with the speech track. Returns the export job, or None."""
        from app.export_dialog import run_export_dialog

        controller = self.controller
        if controller.rig is None:
            controller.message.emit("This face has no rig: nothing to export.")
            return None
        controller.pause()
        try:
            audio = controller.audio_path()
        except Exception as exc:  # noqa: BLE001 - export without sound rather than not at all
            traceback.print_exc()
            controller.message.emit(f"The speech audio could not be prepared ({exc}); exporting without sound.")
            audio = None
        animation = controller.animation()
        return run_export_dialog(self.main_window, self.document.face, animation.vertices,
                                 controller.timeline.duration, controller.timeline.fps, audio, still=still,
                                 current_time_s=controller.current_time, content_end_s=controller.content_end(audio))

    def export_fap_dialog(self) -> None:
        from PySide6.QtWidgets import QFileDialog

        path, _ = QFileDialog.getSaveFileName(self.main_window, "Export .fap animation", "animation.fap",
                                              "MPEG-4 FAP animation (*.fap)")
        if path:
            self.controller.export_fap(path if path.lower().endswith(".fap") else path + ".fap")

    def open_lipsync_dialog(self):
        """Show (or raise) the lip-sync dialog."""
        from app.lipsync_dialog import LipSyncDialog

        if self.lipsync_dialog is None:
            self.lipsync_dialog = LipSyncDialog(self.controller, self.main_window)
        dialog = self.lipsync_dialog
        dialog.set_start_time(self.controller.current_time)
        dialog.show()
        dialog.raise_()
        dialog.activateWindow()
        return dialog


# ------------------------------------------------------------------ menus
def _menu(window, title: str, before: str | None = None) -> QMenu:
    """The window's top-level menu called ``title`` ("&Edit"), created (before ``before``) if missing."""
    bar = window.menuBar()
    plain = title.replace("&", "")
    for act in bar.actions():
        if act.menu() is not None and act.text().replace("&", "") == plain:
            return act.menu()
    menu = QMenu(title, window)
    anchor = None
    if before is not None:
        for act in bar.actions():
            if act.text().replace("&", "") == before.replace("&", ""):
                anchor = act
                break
    if anchor is not None:
        bar.insertMenu(anchor, menu)
    else:
        bar.addMenu(menu)
    return menu


def _action(window, text: str, slot, shortcut=None, tip: str = "", checkable: bool = False) -> QAction:
    act = QAction(text, window)
    if shortcut is not None:
        act.setShortcut(QKeySequence(shortcut))
        act.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
    if tip:
        act.setStatusTip(tip)
    act.setCheckable(checkable)
    if checkable:
        act.toggled.connect(slot)
    else:
        act.triggered.connect(lambda _c=False: slot())
    window.addAction(act)
    return act


__all__ = ["TimelineDock", "TrackView", "Row", "build_rows", "group_of"]
