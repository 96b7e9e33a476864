"""scan_tools.py
----
The window's tools for a user's own scan (Tools menu and the landmark dock's buttons): detect the
MPEG-4 landmarks, build the dense correspondence (the canonical face), scale a face stored in other
units, load or flip its texture image, rebuild the rig from corrected landmarks. Slow steps run in
the background (``MainWindow.run_job`` / the window's loader); every failure is a message box.

A mixin of :class:`app.main_window.MainWindow`: it uses the window's document (face, landmark
model), loader and status bar.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from PySide6.QtWidgets import QFileDialog, QMessageBox


EYE_CORNERS_MM = (50.0, 130.0)   # outer eye corner to outer eye corner of a human face (adults ~90 mm)


def _plausible_scale(face, detection) -> bool:
    """True when the detected outer eye corners (3.7, 3.12), scaled by the detection's factor, are
    a human distance apart: a face found at an absurd size is not scaled behind the user's back."""
    points = detection.landmarks
    if "3.7" not in points or "3.12" not in points:
        return False
    probe = face.with_vertices(face.vertices)
    for name in ("3.7", "3.12"):
        probe.set_landmark(name, points[name])
    width = float(np.linalg.norm(probe.landmark_position("3.7") - probe.landmark_position("3.12")))
    return EYE_CORNERS_MM[0] <= width * detection.scale_hint <= EYE_CORNERS_MM[1]


class ScanToolsMixin:
    """Landmark detection, correspondence, scale and texture tools of the main window."""

    def detect_landmarks(self, fixed: dict | None = None) -> None:
        """Detect the MPEG-4 landmarks on the current face (keeping ``fixed`` ones), in the background."""
        if self.face is None:
            return
        face = self.face

        def work():
            from core.registration.pipeline import detect_landmarks

            return detect_landmarks(face, fixed=fixed or None)

        def done(detection):
            if self.face is not face:
                return  # the face changed meanwhile
            if detection.scale_hint and _plausible_scale(face, detection):
                # other units: scale, never stop to ask (Tools > Scale face changes it)
                self._rescale_with_detection(detection)
                return
            self.document.apply_landmark_detection(detection.landmarks, detection.confidence)
            self._report_detection(detection)

        what = "Re-running matching with your edits fixed…" if fixed else "Detecting landmarks…"
        self.run_job(work, done, "Cannot detect landmarks", what)

    def _rescale_with_detection(self, detection) -> None:
        """Scale the face by the detection's factor, then put the detection (with its confidences) on
        the scaled face: surface points do not change with scale."""
        factor = detection.scale_hint
        width = float(np.ptp(self.face.vertices[:, 0]))
        note = (f"This face was {factor:.2f} times {'smaller' if factor > 1 else 'larger'} than a human face "
                f"({width:.0f} mm wide as loaded: its file is probably not in millimetres), so Mimica scaled it by "
                f"{factor:.3g}. Tools ▸ Scale face… changes that.")

        def reapply(ok: bool) -> None:
            self.load_finished.disconnect(reapply)
            if ok:
                self.document.apply_landmark_detection(detection.landmarks, detection.confidence)
                self._report_detection(detection, first=note)

        self.load_finished.connect(reapply)
        self.scale_face(factor)

    def _report_detection(self, detection, first: str = "") -> None:
        """Status bar summary; the detector's notes (and ``first``, e.g. the scaling done) in one box."""
        low = detection.low_confidence()
        note = f"; {len(low)} with low confidence are worth checking" if low else ""
        self.statusBar().showMessage(
            f"Detected {len(detection.landmarks)} landmarks in {detection.timings.get('total_s', 0):.1f} s{note}.",
            15000)
        # The detector's own units line repeats what ``first`` says about scaling.
        lines = [first] if first else []
        lines += [r for r in detection.report if not (first and "probably not millimetres" in r)]
        if lines:
            self._show_notes(lines, "landmark detection", heading="Landmark detection:")

    def build_correspondence(self) -> None:
        """Register the current face to the MPEG-4 template and show the scan itself, animated through
        its canonical face (``scan_animation``); the canonical face when the scan cannot be cut."""
        if self.face is None:
            return
        face = self.face
        landmarks = dict(face.landmarks)
        model = self.document.landmarks
        # The points the user edited or confirmed keep their status on the canonical face (its
        # landmarks are those points), and their confidence.
        status = {n: model.status(n).value for n in model.names} if model is not None else {}
        confidence = {n: c for n in model.names if (c := model.confidence(n)) is not None} if model is not None else {}

        def loader(progress):
            from core.cache import DiskCache
            from core.registration.pipeline import register_scan
            from core.registration.scan_mouth import scan_animation

            progress(0.1, "Building the dense correspondence…")
            registration = register_scan(face, landmarks)
            progress(0.5, "Cutting the lips and fitting a mouth behind them…")
            shown = scan_animation(registration, DiskCache(), lambda f, m: progress(0.6 + 0.4 * f, m))
            kept = set(shown.landmarks)
            shown.metadata = dataclasses.replace(   # a copy: the scan's own metadata stays as it is
                shown.metadata, landmark_status={n: s for n, s in status.items() if n in kept},
                landmark_confidence={n: c for n, c in confidence.items() if n in kept})
            self._canonical_of = (shown, registration.face)   # for Tools ▸ Save canonical face
            return shown

        self._fallback_to_default = False
        self._start_load("", loader, "Building the canonical face from the landmarks…")

    def save_canonical_face_dialog(self) -> None:
        """Save the canonical face behind the shown scan (Build correspondence), for other tools."""
        shown, canonical = getattr(self, "_canonical_of", None) or (None, None)
        if canonical is None or shown is not self.face:
            self.show_error("No canonical face", "A canonical face is made by Landmarks ▸ Build correspondence; "
                            "this face was not built that way, or it was changed since (scaled, retextured). "
                            "Build the correspondence again first.")
            return
        self.ask_and_save_face(canonical, "Save canonical face as", f"{shown.metadata.name or 'face'}.canonical")

    def replace_face(self, face, message: str) -> None:
        """Show an edited copy of the current face; its rig is rebuilt in the background."""
        self._fallback_to_default = False
        self._notes_seen = list(self.face.metadata.notes) if self.face is not None else None
        self._start_load(self.face_path or "", lambda progress: face, message)

    def scale_face(self, factor: float) -> None:
        """Scale the current face by ``factor`` (ValueError with a message for a bad factor)."""
        if self.face is None:
            return
        face = self.face.scaled(factor)
        face.metadata.notes.append(f"Scaled by {factor:.4g} in Mimica.")  # scaled() copied the notes
        self.replace_face(face, f"Scaling the face by {factor:g}…")

    def scale_face_dialog(self) -> None:
        from PySide6.QtWidgets import QInputDialog

        if self.face is None:
            return
        width = float(self.face.bounds[1, 0] - self.face.bounds[0, 0])
        factor, ok = QInputDialog.getDouble(
            self, "Scale face",
            f"The face is {width:.0f} mm wide (an adult face is about 140 mm across the cheeks).\n"
            "Scale factor (10 turns centimetres into millimetres):", 1.0, 0.001, 1000.0, 4)
        if ok and factor != 1.0:
            try:
                self.scale_face(factor)
            except ValueError as exc:
                self.show_error("Cannot scale the face", str(exc))

    def load_texture(self, path) -> None:
        """Map the image at ``path`` onto the current face (errors in a message box)."""
        from core.formats.mesh_io import MeshLoadError, load_texture_image

        if self.face is None:
            return
        from core.face import texture_runs_down

        try:
            face = self.face.with_texture(load_texture_image(path))
        except (MeshLoadError, ValueError) as exc:
            self.show_error("Cannot load the texture", str(exc))
            return
        if texture_runs_down(face):   # decided from the face itself: never upside down, never asked
            face = face.with_flipped_texture()
            note = (f"{Path(path).name} was turned upside down to match this face's texture coordinates "
                    "(they count rows from the top). Tools ▸ Flip texture vertically undoes it.")
            face.metadata = dataclasses.replace(face.metadata, notes=[*face.metadata.notes, note])
        self.replace_face(face, f"Applying the texture {Path(path).name}…")

    def flip_texture(self) -> None:
        """Show the current face with its texture image upside down (an undo is flipping again)."""
        if self.face is None:
            return
        if self.face.texture is None or self.face.uv is None:
            self.show_error("Cannot flip the texture", "This face has no texture image. Load one first with "
                            "Tools > Load texture image…")
            return
        self.replace_face(self.face.with_flipped_texture(), "Flipping the texture…")

    def load_texture_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Load texture image", "",
                                              "Images (*.png *.jpg *.jpeg *.bmp *.tif *.tiff);;All files (*)")
        if path:
            self.load_texture(path)

    def rebuild_animation(self) -> None:
        """Rebuild the animation rig (FAPs, muscles) from the current, corrected landmarks."""
        if self.face is None:
            return
        self.replace_face(self.face, "Rebuilding the animation from the corrected landmarks…")


__all__ = ["ScanToolsMixin"]
