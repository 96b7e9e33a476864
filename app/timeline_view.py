"""The timeline's track view: a ruler and one lane per parameter with its keys and curve, drawn in
app/timeline_paint.py; here the geometry (time <-> x, rows), hit tests, selection, dragging keys,
scrubbing, zoom and pan, and the keyboard."""

from __future__ import annotations


import numpy as np
from PySide6.QtCore import QRectF, QSignalBlocker, QSize, Qt, Signal
from PySide6.QtGui import QFont, QKeySequence, QPixmap
from PySide6.QtWidgets import QMenu, QScrollBar, QSizePolicy, QWidget

from core import timeline as tl

from app.timeline_controller import TimelineController

from app.timeline_rows import (
    Row, build_rows)
from app.timeline_paint import TrackPainting


# ------------------------------------------------------------------ track view
class TrackView(TrackPainting, QWidget):
    """Custom-painted ruler, track names and key lanes (see the module docstring)."""

    NAME_W = 236
    RULER_H = 34
    ROW_H = 20
    KEY_R = 5.0
    VALUE_W = 48  # px of the names column for the value at the cursor
    PAD = 8.0  # px before time 0 and after the duration

    rows_changed = Signal()

    def __init__(self, controller: TimelineController, parent: QWidget | None = None):
        super().__init__(parent)
        self.c = controller
        self.setObjectName("timelineTrackView")
        self.show_all = False
        self.collapsed: set[str] = set()
        self.rows: list[Row] = []
        self.scroll = 0
        self.scrollbar: QScrollBar | None = None
        self._pps: float | None = None  # pixels per second; None = fit the duration
        self._t0 = 0.0
        self._drag: dict | None = None
        self._anchor_row: int | None = None
        self._layer: QPixmap | None = None  # everything but the cursor and the values at the cursor
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.setMouseTracking(True)
        self.setMinimumHeight(self.RULER_H + 3 * self.ROW_H)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self._small = QFont(self.font())
        self._small.setPointSizeF(max(7.0, self.font().pointSizeF() * 0.85))
        self._bold = QFont(self.font())
        self._bold.setBold(True)
        controller.time_changed.connect(self._on_time)
        controller.edited.connect(lambda _e: self.rebuild_rows())
        controller.timeline_replaced.connect(self.rebuild_rows)
        controller.selection_changed.connect(self._on_selection)
        controller.rig_values_changed.connect(self.update)  # values of rows without a track
        self.rebuild_rows()

    def sizeHint(self) -> QSize:  # noqa: N802 - Qt override
        return QSize(900, 220)

    # ------------------------------------------------------------ rows
    def rebuild_rows(self) -> None:
        self.rows = build_rows(self.c, self.show_all, self.collapsed)
        self._update_scrollbar()
        self.rows_changed.emit()
        self.invalidate()

    def set_show_all(self, on: bool) -> None:
        self.show_all = bool(on)
        self.rebuild_rows()

    def toggle_group(self, group: str) -> None:
        self.collapsed.symmetric_difference_update({group})
        self.rebuild_rows()

    def _on_selection(self) -> None:
        keys = {r.key for r in self.rows if not r.is_group}
        if not self.c.selected_tracks <= keys:
            self.rebuild_rows()
        else:
            self.invalidate()

    def _update_scrollbar(self) -> None:
        visible = max(0, self.height() - self.RULER_H)
        total = len(self.rows) * self.ROW_H
        top = max(0, total - visible)
        self.scroll = min(self.scroll, top)
        if self.scrollbar is not None:
            with QSignalBlocker(self.scrollbar):
                self.scrollbar.setRange(0, top)
                self.scrollbar.setPageStep(max(visible, 1))
                self.scrollbar.setSingleStep(self.ROW_H)
                self.scrollbar.setValue(self.scroll)
            self.scrollbar.setVisible(top > 0)

    def set_scroll(self, value: int) -> None:
        self.scroll = int(value)
        self.invalidate()

    def resizeEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().resizeEvent(event)
        self._update_scrollbar()
        self.invalidate()

    def changeEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().changeEvent(event)
        self.invalidate()

    def invalidate(self) -> None:
        """Repaint the cached layer (rows, keys, curves, ruler) on the next paint."""
        self._layer = None
        self.update()

    def row_at(self, y: float) -> int | None:
        if y < self.RULER_H:
            return None
        i = int((y - self.RULER_H + self.scroll) // self.ROW_H)
        return i if 0 <= i < len(self.rows) else None

    def row_top(self, i: int) -> float:
        return self.RULER_H + i * self.ROW_H - self.scroll

    def row_index(self, key: str) -> int | None:
        for i, r in enumerate(self.rows):
            if r.key == key:
                return i
        return None

    # ------------------------------------------------------------ time <-> x
    @property
    def lane_width(self) -> float:
        return max(10.0, self.width() - self.NAME_W - 2 * self.PAD)

    @property
    def pps(self) -> float:
        if self._pps is None:
            return self.lane_width / self.c.timeline.duration
        return self._pps

    @property
    def t0(self) -> float:
        return 0.0 if self._pps is None else self._t0

    def x_of(self, t):
        return self.NAME_W + self.PAD + (np.asarray(t, float) - self.t0) * self.pps

    def t_of(self, x: float) -> float:
        return self.t0 + (float(x) - self.NAME_W - self.PAD) / self.pps

    def fit(self) -> None:
        self._pps = None
        self.invalidate()

    def zoom(self, factor: float, around_x: float | None = None) -> None:
        around_x = self.NAME_W + self.PAD + self.lane_width / 2 if around_x is None else around_x
        t = self.t_of(around_x)
        fit_pps = self.lane_width / self.c.timeline.duration
        pps = min(max(self.pps * factor, fit_pps), 4000.0)
        if pps <= fit_pps * 1.0001:
            self._pps = None
        else:
            self._pps = pps
            self._t0 = t - (around_x - self.NAME_W - self.PAD) / pps
            self._clamp_t0()
        self.invalidate()

    def pan(self, seconds: float) -> None:
        if self._pps is None:
            return
        self._t0 += seconds
        self._clamp_t0()
        self.invalidate()

    def _clamp_t0(self) -> None:
        span = self.lane_width / self.pps
        self._t0 = min(max(self._t0, 0.0), max(0.0, self.c.timeline.duration - span))

    def _on_time(self, t: float) -> None:
        if self._pps is not None:  # zoomed in: keep the cursor in view
            span = self.lane_width / self.pps
            if not self._t0 <= t <= self._t0 + span:
                self._t0 = t - 0.1 * span
                self._clamp_t0()
                self.invalidate()
                return
        self.update()  # only the cursor and the values moved: the cached layer stays

    # ------------------------------------------------------------ hit tests
    def _row_keys(self, row: Row) -> tuple[tuple[str, ...], np.ndarray]:
        """(parameter keys, times) of a row: a track's keys, or the union of a group's."""
        tracks = self.c.timeline.tracks
        if not row.is_group:
            tr = tracks.get(row.key)
            return (row.key,), (tr.times if tr is not None else np.zeros(0))
        members = tuple(m for m in row.members if m in tracks)
        times = [tracks[m].times for m in members]
        return members, (np.unique(np.concatenate(times)) if times else np.zeros(0))

    def keys_at(self, x: float, y: float) -> dict[str, list[float]]:
        """The key(s) under a point: {parameter key: [time]} (a group summary key selects all at that time)."""
        i = self.row_at(y)
        if i is None or x < self.NAME_W:
            return {}
        members, times = self._row_keys(self.rows[i])
        if not len(times):
            return {}
        xs = self.x_of(times)
        j = int(np.argmin(np.abs(xs - x)))
        if abs(xs[j] - x) > self.KEY_R + 2:
            return {}
        t = float(times[j])
        tracks = self.c.timeline.tracks
        out = {}
        for m in members:
            k = tracks[m].index_at(t)
            if k is not None:
                out[m] = [float(tracks[m].times[k])]
        return out

    def keys_in_rect(self, rect: QRectF) -> dict[str, list[float]]:
        out: dict[str, set[float]] = {}
        t_lo, t_hi = self.t_of(rect.left()), self.t_of(rect.right())
        tracks = self.c.timeline.tracks
        for i, row in enumerate(self.rows):
            cy = self.row_top(i) + self.ROW_H / 2
            if not rect.top() <= cy <= rect.bottom():
                continue
            members = (row.key,) if not row.is_group else row.members
            for m in members:
                tr = tracks.get(m)
                if tr is None:
                    continue
                inside = tr.times[(tr.times >= t_lo) & (tr.times <= t_hi)]
                if len(inside):
                    out.setdefault(m, set()).update(inside.tolist())
        return {k: sorted(v) for k, v in out.items()}











    # ------------------------------------------------------------ mouse
    def _snap(self, t: float) -> float:
        fps = self.c.timeline.fps
        return round(t * fps) / fps

    def mousePressEvent(self, event) -> None:  # noqa: N802 - Qt override
        self.setFocus(Qt.FocusReason.MouseFocusReason)
        pos = event.position()
        x, y = pos.x(), pos.y()
        mods = event.modifiers()
        shift = bool(mods & Qt.KeyboardModifier.ShiftModifier)
        ctrl = bool(mods & Qt.KeyboardModifier.ControlModifier)
        button = event.button()
        if y < self.RULER_H:
            if x >= self.NAME_W and button == Qt.MouseButton.LeftButton:
                self._drag = {"mode": "scrub"}
                self.c.seek(self.t_of(x))
            return
        i = self.row_at(y)
        if x < self.NAME_W:
            if i is None:
                if button == Qt.MouseButton.LeftButton:
                    self.c.set_selected_tracks(set())
                return
            row = self.rows[i]
            if row.is_group:
                if button == Qt.MouseButton.LeftButton:
                    if ctrl or shift:
                        self.c.set_selected_tracks(set(self.c.selected_tracks) | set(row.members))
                    else:
                        self.toggle_group(row.group)
                return
            self._select_track_row(i, ctrl=ctrl, shift=shift, keep=button == Qt.MouseButton.RightButton)
            return
        hits = self.keys_at(x, y)
        if button == Qt.MouseButton.RightButton:
            if hits and not self._all_selected(hits):
                self.c.set_selection(hits)
            return
        if button != Qt.MouseButton.LeftButton:
            return
        if hits:
            if shift or ctrl:
                sel = {k: set(v) for k, v in self.c.selected_keys.items()}
                if self._all_selected(hits):
                    for k, ts in hits.items():
                        sel[k] = sel.get(k, set()) - set(ts)
                else:
                    for k, ts in hits.items():
                        sel.setdefault(k, set()).update(ts)
                self.c.set_selection(sel)
            elif not self._all_selected(hits):
                self.c.set_selection(hits)
            self._drag = {"mode": "keys", "x0": x, "dt": 0.0, "moved": False}
        else:
            self._drag = {"mode": "band", "p0": pos, "p1": pos, "add": shift or ctrl}
        self.invalidate()

    def _all_selected(self, hits) -> bool:
        sel = self.c.selected_keys
        return all(set(ts) <= sel.get(k, set()) for k, ts in hits.items())

    def _select_track_row(self, i: int, *, ctrl: bool, shift: bool, keep: bool = False) -> None:
        key = self.rows[i].key
        current = set(self.c.selected_tracks)
        if keep and key in current:
            return
        if shift and self._anchor_row is not None and self._anchor_row < len(self.rows):
            lo, hi = sorted((self._anchor_row, i))
            new = current | {r.key for r in self.rows[lo:hi + 1] if not r.is_group}
        elif ctrl:
            new = current ^ {key}
            self._anchor_row = i
        else:
            new = {key}
            self._anchor_row = i
        self.c.set_selected_tracks(new)

    def mouseMoveEvent(self, event) -> None:  # noqa: N802 - Qt override
        drag = self._drag
        if drag is None:
            return
        pos = event.position()
        if drag["mode"] == "scrub":
            self.c.seek(self.t_of(pos.x()))
        elif drag["mode"] == "keys":
            if abs(pos.x() - drag["x0"]) >= 3:
                drag["moved"] = True
            if drag["moved"]:
                dt = self._snap((pos.x() - drag["x0"]) / self.pps)
                sel = self.c.selection()
                if sel:
                    lo = min(min(v) for v in sel.values())
                    hi = max(max(v) for v in sel.values())
                    dt = min(max(dt, -lo), self.c.timeline.duration - hi)
                    dt = self._snap(dt) if abs(self._snap(dt) - dt) < 1e-9 else dt
                drag["dt"] = dt
                self.invalidate()
        elif drag["mode"] == "band":
            drag["p1"] = pos
            self.update()

    def mouseReleaseEvent(self, event) -> None:  # noqa: N802 - Qt override
        drag, self._drag = self._drag, None
        if drag is None:
            return
        if drag["mode"] == "keys" and drag["moved"] and drag["dt"] != 0:
            self.c.move_selected(drag["dt"])
        elif drag["mode"] == "band":
            rect = QRectF(drag["p0"], drag["p1"]).normalized()
            if rect.width() < 3 and rect.height() < 3:
                if not drag["add"]:
                    self.c.set_selection({})
            else:
                found = self.keys_in_rect(rect)
                if drag["add"]:
                    sel = {k: set(v) for k, v in self.c.selected_keys.items()}
                    for k, ts in found.items():
                        sel.setdefault(k, set()).update(ts)
                    found = sel
                self.c.set_selection(found)
        self.invalidate()

    def mouseDoubleClickEvent(self, event) -> None:  # noqa: N802 - Qt override
        pos = event.position()
        if pos.y() < self.RULER_H and pos.x() >= self.NAME_W:
            self.fit()
        elif pos.x() >= self.NAME_W and not self.keys_at(pos.x(), pos.y()):
            self.c.seek(self.t_of(pos.x()))

    def wheelEvent(self, event) -> None:  # noqa: N802 - Qt override
        delta = event.angleDelta().y() or event.angleDelta().x()
        mods = event.modifiers()
        if mods & Qt.KeyboardModifier.ControlModifier:
            self.zoom(1.25 ** (delta / 120.0), event.position().x())
        elif mods & Qt.KeyboardModifier.ShiftModifier:
            self.pan(-delta / 120.0 * 40.0 / self.pps)
        elif self.scrollbar is not None and self.scrollbar.maximum() > 0:
            self.scrollbar.setValue(self.scrollbar.value() - int(delta / 120.0 * 3 * self.ROW_H))
        else:
            event.ignore()
            return
        event.accept()

    def keyPressEvent(self, event) -> None:  # noqa: N802 - Qt override
        key = event.key()
        if key == Qt.Key.Key_Left:
            self.c.step(-1)
        elif key == Qt.Key.Key_Right:
            self.c.step(1)
        elif key == Qt.Key.Key_Home:
            self.c.seek(0.0)
        elif key == Qt.Key.Key_End:
            self.c.seek(self.c.timeline.duration)
        elif key in (Qt.Key.Key_Delete, Qt.Key.Key_Backspace):
            self.c.delete_selected()
        # The window's shortcuts normally take these first; here for a floating / inactive dock.
        elif key == Qt.Key.Key_K and not event.modifiers():
            self.c.set_key()
        elif key == Qt.Key.Key_Space and not event.modifiers():
            self.c.toggle_play()
        elif event.matches(QKeySequence.StandardKey.Copy):
            self.c.copy_selected()
        elif event.matches(QKeySequence.StandardKey.Paste):
            self.c.paste()
        else:
            super().keyPressEvent(event)
            return
        event.accept()

    def contextMenuEvent(self, event) -> None:  # noqa: N802 - Qt override
        pos = event.pos()
        x, y = float(pos.x()), float(pos.y())
        menu = QMenu(self)
        c = self.c
        if x < self.NAME_W:
            i = self.row_at(y)
            if i is None or self.rows[i].is_group:
                return
            key = self.rows[i].key
            keys = sorted(c.selected_tracks) if key in c.selected_tracks else [key]
            menu.addAction(f"Set key on {len(keys)} track{'s' if len(keys) != 1 else ''} (K)",
                           lambda: c.set_key(keys))
            if any(k in c.timeline.tracks for k in keys):
                menu.addAction("Select all keys of the track" + ("s" if len(keys) > 1 else ""),
                               lambda: c.set_selection({k: c.timeline.tracks[k].times.tolist()
                                                        for k in keys if k in c.timeline.tracks}))
                menu.addAction("Delete track" + ("s" if len(keys) > 1 else ""),
                               lambda: c.push(lambda: c.timeline.replace_tracks(
                                   {k: None for k in keys if k in c.timeline.tracks}, "delete track"),
                                   "delete track" + ("s" if len(keys) > 1 else "")))
            menu.exec(event.globalPos())
            return
        sel = c.selection()
        interp = menu.addMenu("&Interpolation")
        codes = {int(c.timeline.tracks[k].codes[c.timeline.tracks[k].index_at(t)]) for k, ts in sel.items()
                 for t in ts if k in c.timeline.tracks and c.timeline.tracks[k].index_at(t) is not None}
        for name, label in (("step", "&Step (hold)"), ("linear", "&Linear"), ("smooth", "S&mooth")):
            act = interp.addAction(label, lambda n=name: c.set_interpolation(n))
            act.setCheckable(True)
            act.setChecked(codes == {tl.INTERPOLATIONS.index(name)})
        interp.setEnabled(bool(sel))
        menu.addSeparator()
        act = menu.addAction("&Copy keys", c.copy_selected)
        act.setEnabled(bool(sel))
        t_here = self._snap(min(max(self.t_of(x), 0.0), c.timeline.duration))
        act = menu.addAction(f"&Paste keys at {t_here:.2f} s", lambda: c.paste(t_here))
        act.setEnabled(c.clipboard is not None)
        act = menu.addAction("&Delete keys", c.delete_selected)
        act.setEnabled(bool(sel))
        menu.addSeparator()
        menu.addAction(f"Set &key at {t_here:.2f} s", lambda: (c.seek(t_here), c.set_key()))
        menu.addAction("Select &all keys", c.select_all_keys)
        menu.exec(event.globalPos())
