"""control_point_dock.py
----
Thesis B's interface (§5.4) as a dock: the RBF control points (``core.layers.rbf``) and Waters' vector
muscles (``core.layers.waters``) of the document's rig.

* Layers: the rig gets both layers the first time the dock is shown (or ``ensure_layers()``), about a
  second on the default face; a face without the feature points they need shows why instead.
* RBF: the kernel and its main parameter (δ for the multiquadrics, σ for the Gaussian, mm²), the linear
  polynomial and the regulariser λ (B §5.4: "the RBF type and its main parameter"); a setting the
  system refuses (singular) is a message and the previous one stays. A control point picked in the list
  shows its x/y/z rows (the shared ``ParameterRow``); the reference chart (a 2-D front diagram of the points)
  selects one by a click. Emotion buttons apply the FACS presets (B Tables
  3.2-3.3, EPC files) at the intensity chosen; "Open EPC…" applies an emotion file, "Open PPC…" / "Save
  PPC…" place and save the control points; "Import DPC…" keys a DPC file's frames on the timeline (one
  undo step; the player's start/pause/speed are the timeline's) and "Export DPC…" writes its tracks.
* "Show control points" (on by default) draws them on the face while this tab is shown (yellow points that
  follow the pose). Drag one in the viewport (``app.control_point_drag``): it moves in the view plane or along
  the axis in "Drag along", live, one undo step per drag, Esc cancels; with "Link left/right" its mirror
  partner moves mirrored; hovering one shows its influence region. A drag that starts off the points turns
  the camera as always. "Clicks on the face": move the selected control point to the click (one undo step),
  or the inverse: a first click picks a skin point, a second where it should go, and the Waters muscles move
  to bring it there (``core.inverse``, one undo step).
* Waters: one row per muscle and side, "Link left/right", and how muscles combine (displacement limit,
  strongest of group, plain sum).

House rules of the FAP dock: edits go through ``rig.set_values`` (one undo step each, from the
document's ``UndoableRigEdits``; kernel, combine rule and PPC placement are layer settings, pushed as their
own undo steps), the widgets follow ``rig.parameters_changed`` with their signals
blocked, and the dock never renders.
"""

from __future__ import annotations

from PySide6.QtCore import QPointF, QSignalBlocker, Qt, Signal
from PySide6.QtGui import QColor, QPainter, QPen
from PySide6.QtWidgets import (
    QCheckBox, QComboBox, QDockWidget, QDoubleSpinBox, QFileDialog, QFormLayout, QGridLayout, QGroupBox, QHBoxLayout,
    QLabel, QPushButton, QScrollArea, QVBoxLayout, QWidget)

from app.parameter_row import ParameterRow, align_rows
from core import parameters as P

KERNEL_TITLES = {"multiquadric": "Multiquadric", "inverse_multiquadric": "Inverse multiquadric",
                 "gaussian": "Gaussian", "thin_plate_spline": "Thin plate spline", "linear": "Linear"}
COMBINE_TITLES = {"limit": "Limit per vertex", "strongest": "Strongest of group", "sum": "Sum"}


def mirrored(key: str, value: float, available) -> dict[str, float]:
    """{partner key: value} that "Link left/right" sets with ``key``: the same strength for a Waters muscle's
    other side, the same y/z and the opposite x for a control point's mirror partner (x points to the face's
    left); empty when the partner is not among ``available``."""
    k = P.parse(key)
    if k.kind == "cp":
        partner = P.describe(f"cp:{k.id}:y").mirror
        if partner is None:
            return {}
        out = {f"{partner.rsplit(':', 1)[0]}:{k.side}": -value if k.side == "x" else value}
    else:
        mirror = P.describe(key).mirror
        out = {mirror: value} if mirror else {}
    return {m: v for m, v in out.items() if m in available}


class ReferenceChart(QWidget):
    """Thesis B's reference chart (§5.4): a 2-D front diagram of the control points (the face's left on the
    right, as in the front view). Clicking a point selects it (``point_selected(fp)``); the selected one is
    drawn larger. Positions come from the built-in face's feature points."""

    point_selected = Signal(str)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("referenceChart")
        self.setMinimumSize(160, 200)
        self.setToolTip("Click a control point to select it; with 'Place the point at the click' a click on the "
                        "face puts it there")
        self.points: dict[str, tuple[float, float]] = {}
        self.names: dict[str, str] = {}
        self.selected: str | None = None

    def set_points(self, names, feature_points) -> None:
        from core.default_face import load_default_face

        face = load_default_face()
        xy = {fp: face.landmark_position(fp)[:2] for fp in feature_points if fp in face.landmark_names}
        if xy:
            import numpy as np

            arr = np.array(list(xy.values()))
            lo, hi = arr.min(axis=0), arr.max(axis=0)
            span = max(float((hi - lo).max()), 1e-6)
            self.points = {fp: (float((p[0] - lo[0]) / span), float((p[1] - lo[1]) / span)) for fp, p in xy.items()}
        self.names = dict(zip(feature_points, names))
        self.update()

    def set_selected(self, fp: str | None) -> None:
        self.selected = fp
        self.update()

    def _to_widget(self, u: float, v: float) -> QPointF:
        """Chart coordinates (u right, v up; the points span u in [0, umax], v in [0, 1]) to widget pixels."""
        m = 18.0
        umax = max((p[0] for p in self.points.values()), default=1.0) or 1.0
        scale = max(1.0, min((self.width() - 2 * m) / umax, self.height() - 2 * m))
        x0 = (self.width() - umax * scale) / 2
        y0 = (self.height() - scale) / 2
        return QPointF(x0 + u * scale, y0 + (1.0 - v) * scale)

    def paintEvent(self, _event) -> None:  # noqa: N802 - Qt override
        painter = QPainter(self)
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.fillRect(self.rect(), QColor(40, 42, 48))
        if self.points:
            umax = max(p[0] for p in self.points.values())
            centre = self._to_widget(umax / 2, 0.5)
            corner = self._to_widget(umax * 1.22, 1.12)   # a face outline around the points
            painter.setPen(QPen(QColor(120, 124, 132), 1.5))
            painter.drawEllipse(centre, corner.x() - centre.x(), centre.y() - corner.y())
        for fp, (u, v) in self.points.items():
            chosen = fp == self.selected
            painter.setPen(QPen(QColor(20, 20, 20), 1))
            painter.setBrush(QColor(255, 90, 40) if chosen else QColor(255, 217, 26))
            r = 6.0 if chosen else 3.5
            painter.drawEllipse(self._to_widget(u, v), r, r)
        painter.end()

    def mousePressEvent(self, event) -> None:  # noqa: N802 - Qt override
        pos = event.position()
        best, dist = None, 15.0
        for fp, (u, v) in self.points.items():
            p = self._to_widget(u, v)
            d = ((p.x() - pos.x()) ** 2 + (p.y() - pos.y()) ** 2) ** 0.5
            if d < dist:
                best, dist = fp, d
        if best is not None:
            self.set_selected(best)
            self.point_selected.emit(best)


class ControlPointDock(QDockWidget):
    """The control-point and Waters-muscle dock (see the module docstring)."""

    def __init__(self, document=None, window=None):
        super().__init__("Control points", window)
        self.setObjectName("controlPointDock")
        self.document, self.window_ = document, window
        self.rig = None
        self.rows: dict[str, ParameterRow] = {}
        self._syncing = False
        self.points_actor = None      # the control points in the viewport ("Show control points")
        self._points_mesh = None
        self.drag = None              # dragging them (control_point_drag.ControlPointDrag), with the window
        self.region = None            # the hovered point's influence region (control_point_drag.RegionHighlight)
        self._tab_shown = False       # visibilityChanged's last word: this tab is the one shown
        self.mouse = None             # clicks on the face (picking.ViewportMouse), once a click mode is chosen
        self._picker = (None, None)   # (face actor, its SurfacePicker)
        self.inverse_vertex: int | None = None   # the skin vertex the inverse mode's next click moves
        self._build()
        if window is not None and document is not None:
            window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self)
            if getattr(window, "fap_dock", None) is not None:
                window.tabifyDockWidget(window.fap_dock, self)
                window.fap_dock.raise_()
            toggle = self.toggleViewAction()
            toggle.setText("&Control points")
            toggle.setStatusTip("Show or hide the RBF control points and Waters muscles (thesis B)")
            if getattr(window, "view_menu", None) is not None:
                window.view_menu.addAction(toggle)
            document.rig_changed.connect(lambda _rig: self._follow())
            document.face_changed.connect(lambda _face: self._follow())
            self.visibilityChanged.connect(self._shown)
            plotter = getattr(window, "plotter", None)
            if plotter is not None and getattr(window, "viewport", None) is not None:
                from app.control_point_drag import ControlPointDrag, RegionHighlight

                self.drag = ControlPointDrag(self)
                self.region = RegionHighlight(plotter)
                window.viewport.add_updater(("mesh",), self._update_points)
                self._window_set_draft = window.viewport.set_draft
                window.viewport.set_draft = self._set_draft
        self._follow()

    # ------------------------------------------------------------ widgets
    def _build(self) -> None:
        root = QWidget(self)
        outer = QVBoxLayout(root)
        self.message_label = QLabel(root)
        self.message_label.setWordWrap(True)
        self.message_label.setObjectName("controlPointMessage")
        outer.addWidget(self.message_label)

        rbf = QGroupBox("RBF control points", root)
        form = QFormLayout(rbf)
        self.kernel_combo = QComboBox(rbf)
        self.kernel_combo.setObjectName("rbfKernel")
        for name, title in KERNEL_TITLES.items():
            self.kernel_combo.addItem(title, name)
        self.main_spin = QDoubleSpinBox(rbf)
        self.main_spin.setObjectName("rbfMainParameter")
        self.main_spin.setRange(1.0, 1e6)
        self.main_spin.setDecimals(0)
        self.main_spin.setSuffix(" mm²")
        self.main_spin.setKeyboardTracking(False)
        self.poly_check = QCheckBox("Linear polynomial", rbf)
        self.poly_check.setObjectName("rbfPolynomial")
        self.smoothing_spin = QDoubleSpinBox(rbf)
        self.smoothing_spin.setObjectName("rbfSmoothing")
        self.smoothing_spin.setRange(0.0, 1e3)
        self.smoothing_spin.setDecimals(4)
        self.smoothing_spin.setSingleStep(0.001)
        self.smoothing_spin.setKeyboardTracking(False)
        form.addRow("Kernel", self.kernel_combo)
        self.main_label = QLabel("δ", rbf)
        form.addRow(self.main_label, self.main_spin)
        form.addRow("Regulariser λ", self.smoothing_spin)
        form.addRow(self.poly_check)
        self.show_check = QCheckBox("Show control points", rbf)
        self.show_check.setObjectName("showControlPoints")
        self.show_check.setChecked(True)
        self.show_check.setToolTip("Draw the control points on the face (yellow, following the pose) while this "
                                   "tab is shown. Drag a point to move it (Esc cancels the drag, one undo step "
                                   "per drag); hovering a point shows its influence region; a drag anywhere "
                                   "else turns the view")
        self.show_check.toggled.connect(self.set_points_visible)
        self.axis_combo = QComboBox(rbf)
        self.axis_combo.setObjectName("dragAxis")
        for title, axis in (("View plane", None), ("X (left-right)", "x"), ("Y (up-down)", "y"),
                            ("Z (front-back)", "z")):
            self.axis_combo.addItem(title, axis)
        self.axis_combo.setToolTip("How a dragged control point moves: in the plane through it parallel to the "
                                   "screen, or only along the face's X, Y or Z axis (the other two coordinates "
                                   "stay); the X, Y and Z keys switch it during a drag. With 'Link left/right' "
                                   "its mirror partner moves mirrored")
        show_row = QHBoxLayout()
        show_row.addWidget(self.show_check)
        show_row.addStretch(1)
        show_row.addWidget(QLabel("Drag along", rbf))
        show_row.addWidget(self.axis_combo)
        form.addRow(show_row)
        self.click_combo = QComboBox(rbf)
        self.click_combo.setObjectName("clickMode")
        for title, mode in (("Orbit only", "off"), ("Move the point to the click", "move"),
                            ("Place the point at the click", "place"),
                            ("Inverse: drag or click a skin point", "inverse")):
            self.click_combo.addItem(title, mode)
        self.click_combo.setToolTip("What a click on the face does (a drag orbits the camera, but for a drag on a "
                                    "control point or, in Inverse, on the skin). Move: the selected point is "
                                    "displaced there; Place: its rest position is set there (a new face: pick the "
                                    "point in the chart, click its spot). Inverse: drag a skin point and the Waters "
                                    "muscles follow live to bring it under the pointer as nearly as they can (one "
                                    "undo step, Esc cancels), or click a skin point, then where it should go")
        self.click_combo.currentIndexChanged.connect(lambda _i: self._click_mode_changed())
        form.addRow("Clicks on the face", self.click_combo)
        self.chart = ReferenceChart(rbf)
        form.addRow(self.chart)
        self.point_combo = QComboBox(rbf)
        self.point_combo.setObjectName("rbfPoint")
        form.addRow("Point", self.point_combo)
        self.chart.point_selected.connect(lambda fp: self.point_combo.setCurrentIndex(self.point_combo.findData(fp)))
        self.point_rows = QWidget(rbf)
        self.point_rows.setLayout(QVBoxLayout())
        self.point_rows.layout().setContentsMargins(0, 0, 0, 0)
        form.addRow(self.point_rows)
        emotions = QGridLayout()
        self.intensity_spin = QDoubleSpinBox(rbf)
        self.intensity_spin.setObjectName("emotionIntensity")
        self.intensity_spin.setRange(0.0, 1.0)
        self.intensity_spin.setSingleStep(0.1)
        self.intensity_spin.setValue(1.0)
        self.emotion_buttons: dict[str, QPushButton] = {}
        from core.layers.rbf.emotions import EMOTIONS

        for i, name in enumerate(EMOTIONS + ("neutral",)):
            button = QPushButton(name.capitalize(), rbf)
            button.setObjectName(f"emotion_{name}")
            button.setToolTip("FACS emotion preset (thesis B Tables 3.2-3.3)" if name != "neutral"
                              else "Every control point back to rest")
            button.clicked.connect(lambda _=False, n=name: self.apply_emotion(n))
            self.emotion_buttons[name] = button
            emotions.addWidget(button, i // 3, i % 3)
        form.addRow(emotions)
        form.addRow("Intensity", self.intensity_spin)
        files = QHBoxLayout()
        for text, slot, name in (("Open PPC…", self.open_ppc, "openPpc"), ("Save PPC…", self.save_ppc, "savePpc"),
                                 ("Open EPC…", self.open_epc, "openEpc")):
            button = QPushButton(text, rbf)
            button.setObjectName(name)
            button.clicked.connect(slot)
            files.addWidget(button)
        form.addRow(files)
        dpc = QHBoxLayout()
        for text, slot, name in (("Import DPC…", self.import_dpc, "importDpc"),
                                 ("Export DPC…", self.export_dpc, "exportDpc")):
            button = QPushButton(text, rbf)
            button.setObjectName(name)
            button.setToolTip("Control-point dynamics (thesis B §5.2) as timeline keys, one per frame"
                              if name == "importDpc" else "The timeline's control-point tracks, one frame per "
                                                          "timeline frame")
            button.clicked.connect(slot)
            dpc.addWidget(button)
        form.addRow(dpc)
        outer.addWidget(rbf)

        waters = QGroupBox("Waters muscles", root)
        wl = QVBoxLayout(waters)
        top = QHBoxLayout()
        self.combine_combo = QComboBox(waters)
        self.combine_combo.setObjectName("watersCombine")
        for name, title in COMBINE_TITLES.items():
            self.combine_combo.addItem(title, name)
        self.limit_spin = QDoubleSpinBox(waters)
        self.limit_spin.setObjectName("watersLimit")
        self.limit_spin.setRange(0.5, 100.0)
        self.limit_spin.setSuffix(" mm")
        self.limit_spin.setKeyboardTracking(False)
        self.link_check = QCheckBox("Link left/right", waters)
        self.link_check.setToolTip("Move a muscle's or a control point's mirror partner with it (a control "
                                   "point's x mirrored)")
        self.link_check.setChecked(True)
        top.addWidget(self.combine_combo)
        top.addWidget(self.limit_spin)
        top.addWidget(self.link_check)
        wl.addLayout(top)
        self.waters_rows = QVBoxLayout()
        wl.addLayout(self.waters_rows)
        outer.addWidget(waters)
        outer.addStretch(1)
        self.groups = (rbf, waters)

        scroll = QScrollArea(self)
        scroll.setWidgetResizable(True)
        scroll.setWidget(root)
        self.setWidget(scroll)
        self.kernel_combo.currentIndexChanged.connect(lambda _i: self._kernel_edited(switch=True))
        self.main_spin.valueChanged.connect(lambda _v: self._kernel_edited())
        self.smoothing_spin.valueChanged.connect(lambda _v: self._kernel_edited())
        self.poly_check.toggled.connect(lambda _v: self._kernel_edited())
        self.point_combo.currentIndexChanged.connect(lambda _i: self._show_point_rows())
        self.combine_combo.currentIndexChanged.connect(lambda _i: self._combine_edited())
        self.limit_spin.valueChanged.connect(lambda _v: self._combine_edited())

    # ------------------------------------------------------------ layers
    @property
    def rbf(self):
        return None if self.rig is None else self.rig.layer("control_points")

    @property
    def waters(self):
        return None if self.rig is None else self.rig.layer("waters")

    def _follow(self) -> None:
        rig = None if self.document is None else self.document.rig
        if rig is not self.rig and self.drag is not None and self.drag.drag is not None:
            self.drag.finish(cancel=True)   # before the undo history of the old face goes
        if rig is not self.rig:
            if self.rig is not None:
                try:
                    self.rig.parameters_changed.disconnect(self._on_parameters_changed)
                except (ValueError, RuntimeError):
                    pass
            self.rig = rig
            if rig is not None:
                rig.parameters_changed.connect(self._on_parameters_changed)
            # Built when the dock is really on screen (a tab behind another reports isVisible() but has
            # no visible region): at start-up the build would freeze the window for a second.
            if rig is not None and self.isVisible() and not self.visibleRegion().isEmpty():
                self.ensure_layers()
        self._rebuild()

    def set_rig(self, rig) -> None:
        """Drive ``rig`` without a document (tests, tools)."""
        self.rig = rig
        if rig is not None:
            rig.parameters_changed.connect(self._on_parameters_changed)
        self._rebuild()

    def ensure_layers(self) -> bool:
        """Give the rig its control-point and Waters layers (built here, about a second); False and a
        message when this face cannot have them."""
        if self.rig is None:
            return False
        try:
            self.rig.ensure_layers(["cp:8.3:y", "waters:zygomatic_major:left"])
        except (P.ParameterError, ValueError) as exc:
            self.show_message(str(exc))
            return False
        self._rebuild()
        return True

    def _rebuild(self) -> None:
        for row in list(self.rows.values()):
            row.setParent(None)
            row.deleteLater()
        self.rows.clear()
        rbf, waters = self.rbf, self.waters
        for group in self.groups:
            group.setEnabled(rbf is not None and waters is not None)
        if rbf is None or waters is None:
            self.show_message("No face with control points yet." if self.rig is None else
                              "Show this dock to add the control points and Waters muscles to the face.")
            return
        self.show_message("")
        current = self.point_combo.currentData()
        with QSignalBlocker(self.point_combo):
            self.point_combo.clear()
            for name, fp in zip(rbf.points.names, rbf.points.feature_points):
                self.point_combo.addItem(f"{name} ({fp})", fp)
            if self.point_combo.findData(current) >= 0:
                self.point_combo.setCurrentIndex(self.point_combo.findData(current))
        self.chart.set_points(rbf.points.names, rbf.points.feature_points)
        for key in waters.parameters():
            row = ParameterRow(key, self)
            row.edited.connect(self._row_edited)
            row.reset_requested.connect(lambda k: self._apply({k: 0.0}))
            self.waters_rows.addWidget(row)
            self.rows[key] = row
        self._show_point_rows()
        self._show_settings()
        self._show_values()
        if self.show_check.isChecked():
            self.set_points_visible(True)

    def _show_point_rows(self) -> None:
        for key in [k for k in self.rows if k.startswith("cp:")]:
            row = self.rows.pop(key)
            row.setParent(None)
            row.deleteLater()
        fp = self.point_combo.currentData()
        self.chart.set_selected(fp)
        if fp is None or self.rbf is None:
            return
        for axis in "xyz":
            row = ParameterRow(f"cp:{fp}:{axis}", self.point_rows, text=axis)
            row.edited.connect(self._row_edited)
            row.reset_requested.connect(lambda k: self._apply({k: 0.0}))
            self.point_rows.layout().addWidget(row)
            self.rows[row.key] = row
        align_rows(self.rows.values())
        self._show_values()

    # ------------------------------------------------------------ the viewport
    def set_points_visible(self, visible: bool) -> None:
        """Show or hide the control points on the face (one point actor, moved with the pose; drawn only while
        this dock is on screen)."""
        with QSignalBlocker(self.show_check):
            self.show_check.setChecked(bool(visible))
        plotter = getattr(self.window_, "plotter", None)
        if plotter is None:
            return
        if self.points_actor is not None:
            plotter.remove_actor(self.points_actor, render=False)
            self.points_actor = self._points_mesh = None
        if visible and self.rbf is not None:
            import pyvista as pv

            self._points_mesh = pv.PolyData(self._point_positions())
            self._points_mesh.point_data["rgb"] = self._point_colors()
            self.points_actor = plotter.add_mesh(self._points_mesh, scalars="rgb", rgb=True, point_size=11,
                                                 render_points_as_spheres=True, pickable=False, reset_camera=False,
                                                 show_scalar_bar=False, name="control_points", render=False)
            self.points_actor.SetVisibility(self._on_screen())
        self.show_hover(None)
        self.window_.viewport.request("render")

    def _on_screen(self) -> bool:
        """The dock is shown (not a tab behind another): its markers are drawn and draggable."""
        return self._tab_shown and self.isVisible()

    def _shown(self, shown: bool) -> None:
        self._tab_shown = bool(shown)
        if shown:
            self.ensure_layers()
        if self.points_actor is not None:
            self.points_actor.SetVisibility(bool(shown))
            if not shown:
                self.show_hover(None)
            self.window_.viewport.request("render")

    def markers_shown(self) -> bool:
        """The control points are drawn, so they can be hovered and dragged."""
        return (self.points_actor is not None and bool(self.points_actor.GetVisibility()) and self.rig is not None
                and self.rbf is not None and len(self.rbf.points) == self._points_mesh.n_points)

    def _point_colors(self, hot: int | None = None):
        import numpy as np

        rgb = np.tile(np.array([255, 217, 26], dtype=np.uint8), (len(self.rbf.points), 1))
        if hot is not None and hot < len(rgb):
            rgb[hot] = (255, 90, 40)    # the hovered / dragged point, as in the reference chart
        return rgb

    def show_hover(self, index: int | None) -> None:
        """Mark control point ``index`` (None: none) and show its influence region."""
        if self.region is None:
            return
        if self._points_mesh is not None and self.rbf is not None \
                and len(self.rbf.points) == self._points_mesh.n_points:
            self._points_mesh.point_data["rgb"][:] = self._point_colors(index)
            self._points_mesh.Modified()
        changed = self.region.show(self.rbf, index, self.rig.vertices(), self._preview()) if index is not None \
            else self.region.hide()
        status = getattr(self.window_, "statusBar", None)
        if status is not None and self.rbf is not None and index is not None:
            # the status bar, not the dock's message: a label appearing there would shift the dock under the mouse
            status().showMessage(f"Control point {self.rbf.points.names[index]}: drag to move it (X/Y/Z: along "
                                 "an axis, Esc cancels); the blue area is what it may move", 4000)
        elif status is not None and changed:
            status().clearMessage()
        self.window_.viewport.request("render")

    def _preview(self):
        """The face's draft copy (app.preview.PreviewMesh) when it has one, for the region's draft copy."""
        actor = getattr(self.window_, "face_actor", None)
        return None if actor is None or self.rbf is None or actor.face is not self.rbf.face else actor.preview

    def _set_draft(self, on: bool) -> bool:
        """The viewport's level-of-detail switch, extended: the region follows the face to its draft copy."""
        changed = bool(self._window_set_draft(on)) if self._window_set_draft is not None else False
        actor = getattr(self.window_, "face_actor", None)
        return self.region.use_draft(actor is not None and actor.showing_preview) or changed

    # Link left/right, drag axis and undo stack for control_point_drag.
    def mirrored_values(self, key: str, value: float, available) -> dict[str, float]:
        return mirrored(key, value, available)

    def mirrored_keys(self, key: str, available) -> list[str]:
        return list(mirrored(key, 0.0, available))

    def drag_axis(self) -> str | None:
        return self.axis_combo.currentData()

    def undo_stack(self):
        return getattr(self.document, "undo_stack", None)

    def _click_mode_changed(self) -> None:
        self.inverse_vertex = None
        plotter = getattr(self.window_, "plotter", None)
        if self.click_combo.currentData() != "off" and self.mouse is None and plotter is not None:
            from app.picking import ViewportMouse

            self.mouse = ViewportMouse(plotter, self.on_click)
        if self.click_combo.currentData() == "inverse":
            self.show_message("Inverse: drag a skin point (the Waters muscles follow live), or click it, then "
                              "where it should go. Drag off the face to turn the view.")

    def pick(self, x: float, y: float):
        """The face under display pixel (x, y) (picking.SurfaceHit), or None."""
        actor = getattr(self.window_, "face_actor", None)
        if actor is None or self.rig is None:
            return None
        if self._picker[0] is not actor:
            from app.picking import SurfacePicker

            self._picker = (actor, SurfacePicker(actor.actor, actor.mesh, self.rig.face.triangles))
        return self._picker[1].pick(self.window_.plotter.renderer, x, y)

    def on_click(self, x: float, y: float, _shift: bool = False, _ctrl: bool = False) -> None:
        """A click on the face in the chosen mode: move the selected control point there (one undo step), or
        pick the inverse's skin point, then its target."""
        mode = self.click_combo.currentData()
        if self.drag is not None and self.drag.claimed_press:
            return      # the press grabbed a control point: a drag (or a click selecting it), not a face click
        try:
            if mode == "off" or self.rig is None or (self.rbf is None and not self.ensure_layers()):
                return
            hit = self.pick(x, y)
            if hit is None:
                self.show_message("Missed the face: click on the surface.")
                return
            import numpy as np

            from app.undo import gestures

            target = np.array(hit.position)
            gestures().new()
            if mode == "move":
                rbf, fp = self.rbf, self.point_combo.currentData()
                i = rbf.points.feature_points.index(fp)
                now = self.rig.vertices()[rbf.points.vertices[i]]
                keys = [f"cp:{fp}:{a}" for a in "xyz"]
                values = np.array([self.rig.value(k) for k in keys]) + (target - now)
                self._apply(dict(zip(keys, values.tolist())))
            elif mode == "place":
                rbf, fp = self.rbf, self.point_combo.currentData()
                name = rbf.points.names[rbf.points.feature_points.index(fp)]
                corners = self.rig.face.vertices[self.rig.face.triangles[hit.triangle]]
                positions = rbf.positions()
                positions[name] = np.asarray(hit.barycentric) @ corners      # on the neutral face
                old = rbf.deformer
                rbf.place_points(positions)
                self._push(f"place {name}", lambda d, layer=rbf: (layer.set_deformer(d), self._rebuild()), old,
                           rbf.deformer, None)
                self._rebuild()
                self.point_combo.setCurrentIndex(self.point_combo.findData(fp))
                self.show_message(f"{name} placed.")
            elif self.inverse_vertex is None:
                corners = self.rig.face.triangles[hit.triangle]
                self.inverse_vertex = int(corners[int(np.argmax(hit.barycentric))])
                self.show_message("Now click where that skin point should go.")
            else:
                from core.inverse import LinearResponse, reach

                v, self.inverse_vertex = self.inverse_vertex, None
                waters = self.waters
                reach(self.rig, waters, LinearResponse.of_waters(waters), [v], target[None])
                miss = float(np.linalg.norm(self.rig.vertices()[v] - target))
                self.show_message(f"The Waters muscles reach within {miss:.1f} mm of the target."
                                  + (" It is beyond what they can do." if miss > 1.0 else ""))
        except Exception as exc:  # noqa: BLE001 - a click must never raise into VTK
            self.show_message(f"That click could not be applied: {exc}")

    def _point_positions(self):
        rbf = self.rbf
        v = rbf.points.vertices
        x = self.rig.vertices()
        return x[v] + 0.6 * rbf.face.vertex_normals[v]   # lifted off the skin so the face never hides them

    def _update_points(self, _parts=frozenset()) -> bool:
        """Move the markers and the shown region with the pose (a viewport updater: once per drawn frame)."""
        if self._points_mesh is None or self.rig is None or self.rbf is None:
            return False
        pos = self._point_positions()
        if len(pos) != self._points_mesh.n_points:      # the points were placed anew (a PPC)
            self.set_points_visible(True)
            return True
        self._points_mesh.points = pos
        if self.region is not None and self.region.index is not None:
            self.region.show(self.rbf, self.region.index, self.rig.vertices(), self._preview())
        return True

    # ------------------------------------------------------------ rig -> widgets
    def show_message(self, message: str) -> None:
        self.message_label.setText(message)
        self.message_label.setVisible(bool(message))

    def _show_settings(self) -> None:
        rbf, waters = self.rbf, self.waters
        if rbf is None or waters is None:
            return
        k = rbf.kernel
        blockers = [QSignalBlocker(w) for w in (self.kernel_combo, self.main_spin, self.smoothing_spin,
                                                self.poly_check, self.combine_combo, self.limit_spin)]
        self.kernel_combo.setCurrentIndex(self.kernel_combo.findData(k.name))
        main = k.main_parameter
        self.main_label.setText({"delta": "δ", "sigma": "σ", None: "—"}[main])
        self.main_spin.setEnabled(main is not None)
        if main is not None:
            self.main_spin.setValue(getattr(k, main))
        self.smoothing_spin.setValue(k.smoothing)
        self.poly_check.setChecked(k.polynomial)
        self.combine_combo.setCurrentIndex(self.combine_combo.findData(waters.combine))
        self.limit_spin.setValue(waters.limit_mm)
        self.limit_spin.setEnabled(waters.combine == "limit")
        del blockers

    def _show_values(self) -> None:
        if self.rig is None:
            return
        self._syncing = True
        try:
            for key, row in self.rows.items():
                value = self.rig.value(key)
                if row.value != value:
                    row.show_value(value)
        finally:
            self._syncing = False

    def _on_parameters_changed(self, change) -> None:
        if any(k in self.rows for k in change.values):
            self._show_values()

    # ------------------------------------------------------------ widgets -> rig
    def _apply(self, values: dict) -> bool:
        try:
            self.rig.set_values(values)
        except (P.ParameterError, ValueError) as exc:
            self.show_message(str(exc))
            self._show_values()
            return False
        self.show_message("")
        return True

    def _row_edited(self, key: str, value: float) -> None:
        if self.rig is None or self._syncing:
            return
        values = {key: value}
        if self.link_check.isChecked():
            values.update(mirrored(key, value, self.rig.parameters()))
        self._apply(values)

    def _kernel_edited(self, switch: bool = False) -> None:
        from core.layers.rbf.kernels import Kernel

        rbf = self.rbf
        if rbf is None:
            return
        name = self.kernel_combo.currentData()
        settings = dict(name=name, polynomial=self.poly_check.isChecked() or name == "thin_plate_spline",
                        smoothing=self.smoothing_spin.value(), delta=rbf.kernel.delta, sigma=rbf.kernel.sigma,
                        mu=rbf.kernel.mu if name == rbf.kernel.name else None)
        main = {"multiquadric": "delta", "inverse_multiquadric": "delta", "gaussian": "sigma"}.get(name)
        if main is not None and not switch:
            settings[main] = self.main_spin.value()
        old = rbf.kernel
        try:
            rbf.set_kernel(Kernel(**settings))
        except (P.ParameterError, ValueError) as exc:
            self.show_message(str(exc))
        else:
            self.show_message("")
            self._push("RBF kernel", lambda k, layer=rbf: self._set_setting(layer.set_kernel, k), old, rbf.kernel,
                       "rbf-kernel")
        self._show_settings()

    def _set_setting(self, setter, value) -> None:
        setter(*value) if isinstance(value, tuple) else setter(value)
        self._show_settings()

    def _push(self, text: str, apply_fn, old, new, merge_id) -> None:
        """One undo step for a layer setting already in effect (merged within one gesture)."""
        stack = getattr(self.document, "undo_stack", None)
        if stack is None or old == new:
            return
        from app.undo import SetValueCommand

        stack.push(SetValueCommand(text, apply_fn, old, new, merge_id, applied=True))

    def _combine_edited(self) -> None:
        waters = self.waters
        if waters is None:
            return
        old = (waters.combine, waters.limit_mm)
        waters.set_combine(self.combine_combo.currentData(), self.limit_spin.value())
        self._push("Waters combine rule", lambda c, layer=waters: self._set_setting(layer.set_combine, c), old,
                   (waters.combine, waters.limit_mm), "waters-combine")
        self._show_settings()

    def apply_emotion(self, name: str, emotion=None) -> bool:
        """Set the control points to an emotion preset (or ``emotion``, an EpcEmotion) at the intensity
        box's value: one rig change, one undo step. 'neutral' puts every point back to rest."""
        rbf = self.rbf
        if rbf is None and not self.ensure_layers():
            return False
        rbf = self.rbf
        keys = rbf.parameters()
        if name == "neutral":
            return self._apply({k: 0.0 for k in keys})
        from core.layers.rbf.emotions import emotion_displacements

        try:
            moves = emotion_displacements(emotion if emotion is not None else name)
        except (P.ParameterError, ValueError) as exc:
            self.show_message(str(exc))
            return False
        scale = self.intensity_spin.value()
        values = {k: 0.0 for k in keys}
        for pname, fp in zip(rbf.points.names, rbf.points.feature_points):
            if pname in moves:
                values.update({f"cp:{fp}:{a}": float(moves[pname][i] * scale) for i, a in enumerate("xyz")})
        return self._apply(values)

    # ------------------------------------------------------------ files
    def open_ppc(self, path: str | None = None) -> bool:
        """Place the control points from a PPC file; a bad file is a message and nothing changes."""
        from core.formats.ppc_file import PpcFileError, read_ppc

        path = path or QFileDialog.getOpenFileName(self, "Open control-point positions", "",
                                                   "PPC files (*.ppc);;All files (*)")[0]
        if not path or (self.rbf is None and not self.ensure_layers()):
            return False
        layer, old = self.rbf, self.rbf.deformer
        try:
            layer.place_points(read_ppc(path).as_dict())
        except (PpcFileError, P.ParameterError) as exc:
            self.show_message(str(exc))
            return False
        self._push("place control points", lambda d: (layer.set_deformer(d), self._rebuild()), old, layer.deformer,
                   None)
        self._rebuild()
        return True

    def save_ppc(self, path: str | None = None) -> bool:
        from core.formats.ppc_file import PpcFileError, write_ppc
        from core.layers.rbf.files import ppc_of

        path = path or QFileDialog.getSaveFileName(self, "Save control-point positions", "face.ppc",
                                                   "PPC files (*.ppc)")[0]
        if not path or self.rbf is None:
            return False
        try:
            write_ppc(path, ppc_of(self.rbf))
        except PpcFileError as exc:
            self.show_message(str(exc))
            return False
        return True

    def open_epc(self, path: str | None = None) -> bool:
        """Apply an emotion file (EPC) at the intensity box's value."""
        from core.formats.epc_file import EpcFileError, read_epc

        path = path or QFileDialog.getOpenFileName(self, "Open an emotion", "", "EPC files (*.epc);;All files (*)")[0]
        if not path:
            return False
        try:
            emotion = read_epc(path)
        except EpcFileError as exc:
            self.show_message(str(exc))
            return False
        return self.apply_emotion(emotion.name, emotion)

    def _timeline(self):
        return None if self.document is None else self.document.timeline

    def import_dpc(self, path: str | None = None) -> bool:
        """Key a DPC file's frames on the timeline (its fps, else the timeline's), lengthening the timeline
        when the file is longer; one undo step per timeline edit. A bad file is a message."""
        from core.formats.dpc_file import DpcFileError, read_dpc
        from core.layers.rbf.files import keys_from_dpc

        controller = self._timeline()
        path = path or QFileDialog.getOpenFileName(self, "Import control-point dynamics", "",
                                                   "DPC files (*.dpc);;All files (*)")[0]
        if not path or controller is None or (self.rbf is None and not self.ensure_layers()):
            return False
        timeline = controller.timeline
        try:
            seq = read_dpc(path)
            keys = keys_from_dpc(seq, seq.fps or timeline.fps)
        except (DpcFileError, P.ParameterError) as exc:
            self.show_message(str(exc))
            return False
        end = max(t for rows in keys.values() for t, _, _ in rows)
        if end > timeline.duration:
            controller.push(lambda: timeline.set_settings(duration=end), "lengthen timeline for DPC")
        return controller.push(lambda: timeline.add_keys(keys, "import DPC"), "import DPC") is not None

    def export_dpc(self, path: str | None = None) -> bool:
        """Write the timeline's control-point tracks as a DPC file (one frame per timeline frame)."""
        from core.formats.dpc_file import DpcFileError, write_dpc
        from core.layers.rbf.files import dpc_from_timeline

        controller = self._timeline()
        path = path or QFileDialog.getSaveFileName(self, "Export control-point dynamics", "animation.dpc",
                                                   "DPC files (*.dpc)")[0]
        if not path or controller is None or self.rbf is None:
            return False
        try:
            write_dpc(path, dpc_from_timeline(controller.timeline, self.rbf))
        except (DpcFileError, P.ParameterError) as exc:
            self.show_message(str(exc))
            return False
        return True
