"""blend_dock.py
----
The expression-blend dock (thesis A ch. 4): a slider per pose of the face's expression library
(``blend:<pose>``, in %), the caricature slider when the library has a mean face, and the
library's files.

* Rows: the shared :class:`app.parameter_row.ParameterRow` of each key; edits go to
  ``rig.set_values`` (undo steps and timeline keys come from the rig's events, as for every layer);
  the rows follow ``rig.parameters_changed`` with their signals blocked.
* "Displacement heat map" is the window's heat map (the FAP dock's box, kept in step): with one pose
  at 100 % it shows that pose's displacement magnitude (thesis A Fig. 4.2).
* "Transfer…": the library moved onto this face (bounding-box scaling or deformation transfer, asked);
  the label names the method.
* "Built-in": the default face's library (``core.layers.blend.builtin``), on the default face or
  its registered canonical face. "Open…" reads a library (.json + .npz); a file that does not fit
  the face shows its message and changes nothing. "Save…" writes the current library.
* The library becomes the rig's ``blend`` layer (``BlendLayer``); the rows are rebuilt for it.

``BlendDock(document, window)`` joins the window's right dock area, tabified with the FAP dock.
"""

from __future__ import annotations

import contextlib

import numpy as np

from PySide6.QtCore import QSignalBlocker, Qt
from PySide6.QtWidgets import (QCheckBox, QDockWidget, QFileDialog, QHBoxLayout, QLabel, QMessageBox, QPushButton, QScrollArea,
                               QVBoxLayout, QWidget)

from app.parameter_row import ParameterRow, align_rows

NO_LIBRARY = "No expression library on this face. Use the built-in one (default face) or open a library file."


class BlendDock(QDockWidget):
    """The blend dock (see the module docstring)."""

    def __init__(self, document=None, window=None):
        super().__init__("Blends", window)
        self.setObjectName("blendDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.document = document
        self.window_ = window
        self.rig = None
        self.rows: dict[str, ParameterRow] = {}
        self._source = None   # the library the current one was transferred from (or itself)
        self.last_import: list = []   # the reports (core.layers.blend.scans.ScanReport) of the last scan import
        body = QWidget(self)
        outer = QVBoxLayout(body)
        self.info_label = QLabel(NO_LIBRARY, body)
        self.info_label.setWordWrap(True)
        outer.addWidget(self.info_label)
        buttons = QHBoxLayout()
        self.builtin_button = QPushButton("Built-in", body)
        self.builtin_button.setToolTip("Use the default face's built-in library (6 expressions, 14 visemes)")
        self.open_button = QPushButton("Open…", body)
        self.save_button = QPushButton("Save…", body)
        self.transfer_button = QPushButton("Transfer…", body)
        self.transfer_button.setToolTip("Move the library's poses onto this face: the thesis's bounding-box scaling "
                                        "or deformation transfer (adapts to the face's local shape)")
        self.add_button = QPushButton("Add pose…", body)
        self.add_button.setToolTip("Add the face as it is now (FAPs, muscles, control points, blends) to the library "
                                   "as a new pose, or replace a pose of the same name")
        self.import_button = QPushButton("Import scans…", body)
        self.import_button.setToolTip("Build a library from one person's scans: one named 'neutral', the others named "
                                      "after their pose (joy.ply, surprise.obj, ...); a scan with a <name>.landmarks.json "
                                      "beside it uses those (corrected) landmarks, the others are detected")
        self.reset_button = QPushButton("Reset", body)
        self.reset_button.setToolTip("Put every blend weight (and the caricature) back to 0 %")
        for b in (self.builtin_button, self.open_button, self.save_button, self.transfer_button):
            buttons.addWidget(b)
        outer.addLayout(buttons)
        more = QHBoxLayout()
        for b in (self.import_button, self.add_button, self.reset_button):
            more.addWidget(b)
        outer.addLayout(more)
        self.heat_check = QCheckBox("Displacement heat map", body)
        self.heat_check.setToolTip("Colour the face by how far each point moved from the neutral face, in mm "
                                   "(a pose at 100 % alone shows that pose's displacement, thesis A Fig. 4.2)")
        outer.addWidget(self.heat_check)
        self.rows_widget = QWidget(body)
        self.rows_layout = QVBoxLayout(self.rows_widget)
        self.rows_layout.setContentsMargins(0, 0, 0, 0)
        scroll = QScrollArea(body)
        scroll.setWidgetResizable(True)
        scroll.setWidget(self.rows_widget)
        outer.addWidget(scroll, 1)
        self.setWidget(body)
        self.builtin_button.clicked.connect(self.use_builtin)
        self.open_button.clicked.connect(lambda: self.open_library())
        self.save_button.clicked.connect(lambda: self.save_library())
        self.reset_button.clicked.connect(self.reset)
        self.add_button.clicked.connect(lambda: self.add_current_pose())
        self.import_button.clicked.connect(lambda: self.import_scans())
        self.transfer_button.clicked.connect(lambda: self.transfer())
        if document is not None:
            document.rig_changed.connect(lambda _rig: self.follow_document())
            document.face_changed.connect(lambda _face: self.follow_document())
        if window is not None:
            window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self)
            fap_dock = getattr(window, "fap_dock", None)
            if fap_dock is not None:
                window.tabifyDockWidget(fap_dock, self)
                fap_dock.raise_()
            fap_heat = getattr(fap_dock, "heat_check", None)
            if fap_heat is not None:   # one heat map (the window's overlay): the two boxes move together
                self.heat_check.setChecked(fap_heat.isChecked())
                self.heat_check.toggled.connect(fap_heat.setChecked)
                fap_heat.toggled.connect(self.heat_check.setChecked)
            if getattr(window, "view_menu", None) is not None:
                self.toggleViewAction().setText("&Blends")
                window.view_menu.addAction(self.toggleViewAction())
        self.follow_document()

    # ------------------------------------------------------------ the rig and its layer
    @property
    def layer(self):
        return None if self.rig is None else self.rig.layer("blend")

    def follow_document(self) -> None:
        rig = None if self.document is None else self.document.rig
        if rig is not self.rig:
            if self.rig is not None:
                with contextlib.suppress(Exception):
                    self.rig.parameters_changed.disconnect(self._on_parameters)
            self.rig = rig
            if rig is not None:
                rig.parameters_changed.connect(self._on_parameters)
            self._source = None
        self._rebuild()

    def set_library(self, library, *, source=None) -> None:
        """Make ``library`` the rig's blend layer (raises LibraryError, changing nothing, if it does
        not fit the face). ``source``: the library it was transferred from (what Transfer starts
        from next time; default ``library`` itself)."""
        from core.layers.blend.layer import BlendLayer

        if self.rig is None:
            raise ValueError("No face is loaded yet: open a face first.")
        layer = BlendLayer(self.rig.face, library, correspondence=self._correspondence(library))
        self.rig.add_layer(layer)
        self._source = source if source is not None else library
        self._rebuild()

    def _correspondence(self, library):
        if self.rig.face.n_vertices == library.n_vertices:
            return None
        from core.layers.blend.builtin import rig_correspondence

        return rig_correspondence(getattr(self.rig, "deformer", None), library.n_vertices)

    def use_builtin(self) -> bool:
        from core.layers.blend.builtin import builtin_library_for

        if self.rig is None:
            return self._message("No face is loaded yet.")
        found = builtin_library_for(self.rig.face, getattr(self.rig, "deformer", None))
        if found is None:
            return self._message("The built-in library belongs to the default face; for another face, register "
                                 "it and transfer a library onto it.")
        self.set_library(found[0])
        return True

    def open_library(self, path: str | None = None) -> bool:
        from core.formats.blend_library import read_library
        from core.layers.blend.library import LibraryError

        if path is None:
            path, _ = QFileDialog.getOpenFileName(self, "Open expression library", "", "Expression library (*.json)")
            if not path:
                return False
        try:
            self.set_library(read_library(path))
        except (LibraryError, ValueError) as exc:
            return self._message(str(exc))
        return True

    def save_library(self, path: str | None = None) -> bool:
        from core.formats.blend_library import write_library

        layer = self.layer
        if layer is None or not layer.library.names:
            return self._message("There is no expression library to save.")
        if path is None:
            path, _ = QFileDialog.getSaveFileName(self, "Save expression library", "", "Expression library (*.json)")
            if not path:
                return False
        try:
            write_library(layer.library, path)
        except (OSError, ValueError) as exc:
            return self._message(str(exc))
        return True

    def transfer(self, method: str | None = None, library=None) -> bool:
        """Transfer ``library`` (default: the current one, else the built-in one) onto this face's
        canonical face (its FAP rig's dense template) by ``method`` ("fap_units", "deformation" or
        "bbox"; asked when None); the dock then says which method made the poses."""
        from core.layers.blend.builtin import builtin_library, transferred_to
        from core.layers.blend.library import LibraryError
        from core.layers.blend.transfer import METHODS

        if self.rig is None:
            return self._message("No face is loaded yet.")
        library = library or self._source or builtin_library()
        if library is None:
            return self._message("There is no expression library to transfer: open one first.")
        if method is None:
            from PySide6.QtWidgets import QInputDialog

            labels = {"deformation": "Deformation transfer (adapts to the face's local shape)",
                      "fap_units": "Scaling by FAP units per region (MPEG-4: mouth by its width, eyes by theirs…)",
                      "bbox": "Bounding-box scaling (thesis A eqs. 4.4–4.6)"}
            text, ok = QInputDialog.getItem(self, "Transfer expressions", "Method:", list(labels.values()), 0, False)
            if not ok:
                return False
            method = next(m for m, t in labels.items() if t == text)
        if method not in METHODS:
            return self._message(f"Unknown transfer method {method!r}.")
        dense = getattr(getattr(self.rig, "deformer", None), "dense", None)
        if dense is None or len(dense.vertices) != library.n_vertices:
            return self._message(f"This face has no canonical face of template {library.template!r} to transfer onto.")
        try:
            weights = getattr(self.rig.deformer, "template_weights", None)
            self.set_library(transferred_to(library, dense.vertices, method, region_weights=weights), source=library)
        except (LibraryError, ValueError) as exc:
            return self._message(str(exc))
        return True

    def add_current_pose(self, name: str | None = None) -> bool:
        """Add the face as shown now to the library as pose ``name`` (asked when None; a pose of that
        name is replaced). The other poses keep their weights; the new one starts at 0 %."""
        from core.layers.blend.library import ExpressionLibrary, LibraryError, check_pose_name

        if self.rig is None:
            return self._message("No face is loaded yet.")
        layer = self.layer
        if name is None:
            from PySide6.QtWidgets import QInputDialog

            name, ok = QInputDialog.getText(self, "Add pose", "Name of the new pose (lower-case letters, digits and _, starting with a letter):")
            if not ok:
                return False
        try:
            name = check_pose_name(name.strip())
            if layer is None:   # no library yet: start one on this face, with the face as its neutral
                from core.layers.blend.layer import BlendLayer

                library = ExpressionLibrary(self.rig.face.vertices, (), np.zeros((0, self.rig.face.n_vertices, 3)),
                                            base=self.rig.face.metadata.name or "")
                layer = BlendLayer(self.rig.face, library)
            pose = layer.pose_from_face(self.rig.vertices())
            weights = {k: self.rig.value(k) for k in layer.parameters() if self.rig.layer("blend") is layer}
            self.set_library(layer.library.with_pose(name, pose), source=self._source)
            kept = {k: v for k, v in weights.items() if k in self.layer.parameters() and v}
            if kept:   # the weights the user had, back on the new layer (not a step of its own)
                edits = getattr(self.document, "rig_edits", None)
                with edits.suspended() if edits is not None else contextlib.nullcontext():
                    self.rig.set_values(kept)
        except (LibraryError, ValueError) as exc:
            return self._message(str(exc))
        self._message_info(f"Added pose {name!r}: its row is at the bottom, at 0 %.")
        return True

    def import_scans(self, paths=None, *, wait: bool = False) -> bool:
        """Build a library from one person's scans (``paths``; asked when None) in the background and
        use it on this face; a summary says which scans' landmarks are worth correcting. ``wait``:
        run here and return when done (scripts, tests)."""
        from pathlib import Path

        from core.layers.blend.library import LibraryError

        if self.rig is None:
            return self._message("No face is loaded yet.")
        if paths is None:
            paths, _ = QFileDialog.getOpenFileNames(self, "Import one person's expression scans", "",
                                                    "Meshes (*.obj *.ply *.stl *.off *.glb *.gltf)")
            if not paths:
                return False
        try:
            plan = scan_import_plan([Path(p) for p in paths])
        except LibraryError as exc:
            return self._message(str(exc))

        def work():
            return import_library(plan)

        if wait or self.window_ is None:
            try:
                self._imported(work())
            except (LibraryError, ValueError) as exc:
                return self._message(str(exc))
            return True
        self.window_.run_job(work, self._imported, "Cannot import the scans",
                             f"Landmarking and registering {len(plan)} scans…")
        return True

    def _imported(self, result) -> None:
        library, reports = result
        self.set_library(library)
        self.last_import = reports
        lines = [r.line() for r in reports]
        needs = [r.pose for r in reports if r.needs_correction]
        heading = (f"Expression library built from {len(reports)} scans. "
                   + (f"Worth correcting in the landmark picker (then save their .landmarks.json beside the scan "
                      f"and import again): {', '.join(needs)}." if needs else "Every scan's landmarks were confident."))
        show = getattr(self.window_, "_show_notes", None)
        if show is not None and self.isVisible():
            show(lines, "the expression scans", heading=heading)
        else:
            self.info_label.setText(heading)

    def _message_info(self, text: str) -> None:
        if self.window_ is not None:
            self.window_.statusBar().showMessage(text, 8000)

    def reset(self) -> None:
        if self.layer is not None and self.layer.parameters():
            self.rig.reset(self.layer.parameters())

    # ------------------------------------------------------------ rows
    def _rebuild(self) -> None:
        while self.rows_layout.count():   # the rows and the stretch below them (else stretches pile up above)
            item = self.rows_layout.takeAt(0)
            if item.widget() is not None:
                item.widget().setParent(None)
                item.widget().deleteLater()
        self.rows = {}
        layer = self.layer
        keys = () if layer is None else layer.parameters()
        if not keys:
            self.info_label.setText(NO_LIBRARY)
        else:
            lib = layer.library
            from core.layers.blend.transfer import METHOD_NAMES

            name = METHOD_NAMES.get(lib.transfer, lib.transfer)
            how = f", transferred by {name}" if lib.transfer and name not in lib.base else ""
            self.info_label.setText(f"{len(lib.names)} poses of {lib.base or 'a person'}{how}; "
                                    f"template {lib.template}, {lib.n_vertices} vertices")
        for key in keys:
            row = ParameterRow(key, self.rows_widget)
            row.edited.connect(self._row_edited)
            row.reset_requested.connect(lambda k: self._apply({k: 0.0}))
            row.show_value(self.rig.value(key))
            self.rows_layout.addWidget(row)
            self.rows[key] = row
        self.rows_layout.addStretch(1)
        if self.rows:
            align_rows(self.rows.values())
        self.save_button.setEnabled(bool(keys))
        self.reset_button.setEnabled(bool(keys))

    def _row_edited(self, key: str, value: float) -> None:
        self._apply({key: value})

    def _apply(self, values) -> None:
        if self.rig is None:
            return
        try:
            self.rig.set_values(values)
        except ValueError as exc:
            self._message(str(exc))
            self._on_parameters(None)

    def _on_parameters(self, change) -> None:
        keys = self.rows if change is None else [k for k in change.values if k in self.rows]
        for key in keys:
            row = self.rows[key]
            with QSignalBlocker(row):
                row.show_value(self.rig.value(key))

    def _message(self, text: str) -> bool:
        if self.window_ is not None and self.isVisible():
            QMessageBox.warning(self, "Expression library", text)
        else:
            self.info_label.setText(text)
        return False


# ------------------------------------------------------------------ importing scans
def scan_import_plan(paths) -> dict[str, tuple]:
    """{pose name: (scan path, its .landmarks.json or None)} for one person's scans: the pose is the
    file name made a pose name (``Joy 2.ply`` -> ``joy_2``); exactly one must be ``neutral``.
    LibraryError saying what to rename otherwise."""
    import re

    from core.layers.blend.library import LibraryError, check_pose_name

    plan: dict[str, tuple] = {}
    for path in paths:
        name = re.sub(r"[^a-z0-9_]+", "_", path.stem.lower()).strip("_")
        name = re.sub(r"^[^a-z]+", "", name)
        if "neutral" in name:
            name = "neutral"
        try:
            if name != "neutral":   # the rest face, not a pose
                check_pose_name(name)
        except LibraryError:
            raise LibraryError(f"{path.name}: its name cannot be a pose name; rename it after its pose "
                               "(e.g. joy.ply)") from None
        if name in plan:
            raise LibraryError(f"{path.name} and {plan[name][0].name} are both pose {name!r}: rename one of them")
        landmarks = path.with_name(path.stem + ".landmarks.json")
        plan[name] = (path, landmarks if landmarks.is_file() else None)
    if "neutral" not in plan:
        raise LibraryError("none of the scans is the neutral face: name it neutral.ply (or .obj, ...)")
    if len(plan) < 2:
        raise LibraryError("only the neutral scan was given: add the scans of the poses (joy.ply, ...)")
    return plan


def import_library(plan):
    """(library, reports) of :func:`core.layers.blend.scans.library_from_scans` for a
    :func:`scan_import_plan` (loads the meshes and the landmark files found beside them)."""
    from core.formats.landmarks_io import load_landmarks
    from core.formats.mesh_io import load_face
    from core.layers.blend.scans import library_from_scans

    faces = {name: load_face(path) for name, (path, _) in plan.items()}
    given = {name: load_landmarks(lm, faces[name]) for name, (_, lm) in plan.items() if lm is not None}
    neutral = faces.pop("neutral")
    return library_from_scans(neutral, faces, landmarks=given, base=plan["neutral"][0].parent.name)
