"""timeline_dock.py
----
The timeline dock (bottom of the window): transport bar and a custom-painted track view over a
:class:`app.timeline_controller.TimelineController`, plus :func:`attach_timeline`, which wires the
dock, the project actions, the Edit / View / Tools menu items and the face changes into a
:class:`app.main_window.MainWindow`.

Track view (:class:`TrackView`)
    Rows are grouped like the docks: the FAP dock's groups (``core.fap.tables.DOCK_GROUPS``), then
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

import math
import traceback
from dataclasses import dataclass, field

import numpy as np
from PySide6.QtCore import QPointF, QRectF, QSignalBlocker, QSize, Qt, Signal
from PySide6.QtGui import (QAction, QColor, QFont, QFontMetrics, QKeySequence, QPainter, QPainterPath, QPen, QPixmap,
                           QPolygonF)
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDockWidget,
    QDoubleSpinBox,
    QFrame,
    QHBoxLayout,
    QLabel,
    QMenu,
    QScrollArea,
    QScrollBar,
    QSizePolicy,
    QStyle,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from core import timeline as tl
from core.fap import tables

from .timeline_controller import SPEEDS, TimelineController, muscle_keys, parameter_label, parameter_range

GROUP_TITLES = {"jaw & chin": "Jaw & chin", "other": "Other FAPs", "expressions": "Expressions",
                "visemes": "Visemes", "muscles": "Muscles"}
KEY_COLOR = QColor(222, 222, 222)
KEY_SELECTED = QColor(255, 150, 30)
KEY_BORDER = QColor(40, 40, 40)
CURSOR_COLOR = QColor(224, 64, 42)


def group_of(key: str) -> str:
    kind, _, rest = key.partition(":")
    if kind == "fap":
        dock = tables.fap_spec(int(rest)).dock
        return dock if dock in tables.DOCK_GROUPS else "other"
    if kind == "expression":
        return "expressions"
    if kind == "viseme":
        return "visemes"
    return "muscles"


def group_order() -> tuple[str, ...]:
    return (*tables.DOCK_GROUPS, "other", "expressions", "visemes", "muscles")


def all_parameters(controller: TimelineController) -> list[str]:
    """Every parameter the face can animate now (the rows of "Show all")."""
    keys = []
    rig = controller.rig
    if rig is not None:
        animated = set(rig.animated_faps)
        for spec in tables.fap_specs():
            if spec.number in animated and spec.dock and math.isfinite(spec.minimum) and spec.number > 2:
                keys.append(f"fap:{spec.number}")
        keys += [f"expression:{n}" for n in tables.expression_names()[1:]]
        keys += [f"viseme:{i}" for i in range(1, len(tables.viseme_names()))]
    if getattr(controller.window, "muscle_layer", None) is not None:
        keys += list(muscle_keys())
    return keys


@dataclass
class Row:
    """One line of the track view: a group header (key None) or a parameter."""

    group: str
    key: str | None = None
    label: str = ""
    members: tuple[str, ...] = field(default=())  # group rows: the parameter keys listed under it

    @property
    def is_group(self) -> bool:
        return self.key is None


def build_rows(controller: TimelineController, show_all: bool, collapsed: set[str]) -> list[Row]:
    tracked = [k for k, tr in controller.timeline.tracks.items() if len(tr)]
    keys = list(dict.fromkeys((all_parameters(controller) if show_all else []) + tracked
                              + sorted(controller.selected_tracks)))
    by_group: dict[str, list[str]] = {}
    for k in keys:
        by_group.setdefault(group_of(k), []).append(k)
    rows: list[Row] = []
    for g in group_order():
        members = by_group.get(g)
        if not members:
            continue
        members.sort(key=_param_order)
        n_tracked = sum(1 for m in members if m in controller.timeline.tracks)
        title = GROUP_TITLES.get(g, g.capitalize())
        label = f"{title}  ({n_tracked}/{len(members)})" if show_all else f"{title}  ({len(members)})"
        rows.append(Row(g, None, label, tuple(members)))
        if g not in collapsed:
            rows += [Row(g, m, parameter_label(m)) for m in members]
    return rows


def _param_order(key: str):
    kind, _, rest = key.partition(":")
    if kind in ("fap", "viseme"):
        return (0, int(rest), "")
    if kind == "expression":
        return (0, tables.expression_id(rest), "")
    return (1, 0, key)


def _format_value(key: str, v: float) -> str:
    kind = key.split(":")[0]
    if kind in ("expression", "viseme"):
        return f"{v * 100:.0f} %"
    if kind == "fap":
        spec = tables.fap_spec(int(key[4:]))
        if spec.is_rotation:
            return f"{math.degrees(v * tables.ANGLE_UNIT):.1f}°"
        return f"{v:.0f}"
    if kind == "jaw":
        return f"{v:.1f}°"
    return f"{v:.3g}"


# ------------------------------------------------------------------ track view
class TrackView(QWidget):
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

    # ------------------------------------------------------------ painting
    def paintEvent(self, event) -> None:  # noqa: N802 - Qt override
        # Rows, keys, curves and the ruler change only on edits, scrolling and zooming: they are
        # drawn once into a pixmap. A playback frame draws the pixmap, the values at the cursor and
        # the cursor: a handful of painter calls instead of several per key.
        if self._layer is None or self._layer.size() != self.size() * self.devicePixelRatioF():
            self._layer = self._render_layer()
        p = QPainter(self)
        p.drawPixmap(0, 0, self._layer)
        p.setRenderHint(QPainter.RenderHint.Antialiasing, True)
        self._paint_cursor(p)
        if self._drag is not None and self._drag["mode"] == "band":
            r = QRectF(self._drag["p0"], self._drag["p1"]).normalized()
            c = QColor(self.palette().highlight().color())
            c.setAlpha(50)
            p.setBrush(c)
            c.setAlpha(200)
            p.setPen(QPen(c, 1))
            p.drawRect(r)
        self._paint_values(p)  # last: it clips to the names column
        p.end()

    def _render_layer(self) -> QPixmap:
        ratio = self.devicePixelRatioF()
        pixmap = QPixmap(self.size() * ratio)
        pixmap.setDevicePixelRatio(ratio)
        pixmap.fill(self.palette().window().color())
        p = QPainter(pixmap)
        p.setRenderHint(QPainter.RenderHint.Antialiasing, True)
        w, h = self.width(), self.height()
        ticks = self._ticks()
        p.save()
        p.setClipRect(QRectF(self.NAME_W, self.RULER_H, w - self.NAME_W, h - self.RULER_H))
        self._paint_lanes(p, ticks)
        p.restore()
        p.save()
        p.setClipRect(QRectF(0, self.RULER_H, self.NAME_W, h - self.RULER_H))
        self._paint_names(p)
        p.restore()
        self._paint_ruler(p, ticks)
        p.end()
        return pixmap

    def _ticks(self) -> tuple[float, float, list[float]]:
        """(major step s, minor step s, major tick times in view)."""
        fps = self.c.timeline.fps
        pps = self.pps
        candidates = sorted({k / fps for k in (1, 2, 5, 10, 15)} | {0.5, 1, 2, 5, 10, 15, 30, 60, 120, 300, 600,
                                                                      1800, 3600})
        metrics = QFontMetrics(self._small)
        need = metrics.horizontalAdvance("00.00 s") + 14
        major = next((s for s in candidates if s * pps >= need), candidates[-1])
        minor = 1.0 / fps if pps / fps >= 6 else major / 5 if major * pps / 5 >= 6 else major
        t_start = max(0.0, self.t_of(self.NAME_W))
        t_end = min(self.c.timeline.duration, self.t_of(self.width()))
        first = math.ceil(t_start / major - 1e-9)
        times = [k * major for k in range(first, int(math.floor(t_end / major + 1e-9)) + 1)]
        return major, minor, times

    def _paint_lanes(self, p: QPainter, ticks) -> None:
        pal = self.palette()
        w, h = self.width(), self.height()
        tracks = self.c.timeline.tracks
        base, alt = pal.base().color(), pal.alternateBase().color()
        header = pal.button().color().darker(104)
        sel_tracks = self.c.selected_tracks
        highlight = QColor(pal.highlight().color())
        highlight.setAlpha(45)
        first = max(0, self.scroll // self.ROW_H)
        last = min(len(self.rows), first + (h - self.RULER_H) // self.ROW_H + 2)
        x_end = float(self.x_of(self.c.timeline.duration))
        for i in range(first, last):
            row = self.rows[i]
            y = self.row_top(i)
            color = header if row.is_group else (base if i % 2 else alt)
            p.fillRect(QRectF(self.NAME_W, y, w - self.NAME_W, self.ROW_H), color)
            if not row.is_group and row.key in sel_tracks:
                p.fillRect(QRectF(self.NAME_W, y, w - self.NAME_W, self.ROW_H), highlight)
        # beyond the end of the timeline
        if x_end < w:
            p.fillRect(QRectF(x_end, self.RULER_H, w - x_end, h - self.RULER_H), QColor(0, 0, 0, 28))
        # grid
        major, minor, times = ticks
        grid = QColor(pal.mid().color())
        grid.setAlpha(70)
        p.setPen(QPen(grid, 1))
        for t in times:
            x = float(self.x_of(t))
            p.drawLine(QPointF(x, self.RULER_H), QPointF(x, h))
        # curves and keys
        drag_dt = self._drag["dt"] if self._drag is not None and self._drag["mode"] == "keys" else 0.0
        selected = self.c.selected_keys
        curve_color = QColor(pal.highlight().color())
        curve_color.setAlpha(150)
        for i in range(first, last):
            row = self.rows[i]
            y = self.row_top(i)
            if not row.is_group:
                tr = tracks.get(row.key)
                if tr is not None and len(tr):
                    self._paint_curve(p, row.key, tr, y, curve_color)
            members, times = self._row_keys(row)
            if not len(times):
                continue
            cy = y + self.ROW_H / 2
            if row.is_group:
                sel_times = set()
                for m in members:
                    sel_times |= selected.get(m, set())
                codes = None
                radius = self.KEY_R - 1
            else:
                sel_times = selected.get(row.key, set())
                codes = tracks[row.key].codes
                radius = self.KEY_R
            if len(times) > 1:  # dense keys (lip-sync) get smaller so they do not melt into a blob
                gap = float(np.diff(times).min()) * self.pps
                radius = max(2.0, min(radius, 0.45 * gap))
            for j, t in enumerate(times.tolist()):
                is_sel = t in sel_times
                tx = t + drag_dt if is_sel else t
                x = float(self.x_of(tx))
                if x < self.NAME_W - radius or x > w + radius:
                    continue
                self._paint_key(p, x, cy, radius, None if codes is None else int(codes[j]), is_sel)

    def _paint_curve(self, p: QPainter, key: str, tr, y: float, color: QColor) -> None:
        lo, hi = parameter_range(key, tr)
        if key.split(":")[0] in ("fap", "muscle", "jaw"):
            # Scaled to the track's own span (with 0): a 300-unit jaw move must be visible in a 1400 range.
            lo, hi = min(float(tr.values.min()), 0.0), max(float(tr.values.max()), 0.0)
        if not hi > lo:
            lo, hi = lo - 1.0, hi + 1.0
        x0 = max(float(self.x_of(0.0)), self.NAME_W)
        x1 = min(float(self.x_of(self.c.timeline.duration)), self.width())
        if x1 <= x0:
            return
        xs = np.arange(x0, x1 + 3, 3.0)
        xs[-1] = min(xs[-1], x1)
        vals = tr.evaluate(self.t0 + (xs - self.NAME_W - self.PAD) / self.pps)
        top, bottom = y + 3, y + self.ROW_H - 3
        ys = bottom - (np.clip(vals, lo, hi) - lo) / (hi - lo) * (bottom - top)
        if lo < 0 < hi:  # bidirectional: a faint zero line
            zero = bottom - (0 - lo) / (hi - lo) * (bottom - top)
            faint = QColor(color)
            faint.setAlpha(50)
            p.setPen(QPen(faint, 1, Qt.PenStyle.DotLine))
            p.drawLine(QPointF(x0, zero), QPointF(x1, zero))
        p.setPen(QPen(color, 1.3))
        p.drawPolyline(QPolygonF([QPointF(a, b) for a, b in zip(xs.tolist(), ys.tolist())]))

    @staticmethod
    def _paint_key(p: QPainter, x: float, y: float, r: float, code: int | None, selected: bool) -> None:
        p.setPen(QPen(KEY_BORDER, 1))
        p.setBrush(KEY_SELECTED if selected else KEY_COLOR)
        if code == tl.STEP:
            p.drawRect(QRectF(x - r * 0.85, y - r * 0.85, 1.7 * r, 1.7 * r))
        elif code == tl.SMOOTH:
            p.drawEllipse(QPointF(x, y), r * 0.95, r * 0.95)
        else:  # linear, and group summaries
            p.drawPolygon(QPolygonF([QPointF(x, y - r), QPointF(x + r, y), QPointF(x, y + r), QPointF(x - r, y)]))

    def _paint_names(self, p: QPainter) -> None:
        pal = self.palette()
        h = self.height()
        tracks = self.c.timeline.tracks
        first = max(0, self.scroll // self.ROW_H)
        last = min(len(self.rows), first + (h - self.RULER_H) // self.ROW_H + 2)
        header = pal.button().color().darker(104)
        highlight = pal.highlight().color()
        metrics = QFontMetrics(self.font())
        for i in range(first, last):
            row = self.rows[i]
            y = self.row_top(i)
            rect = QRectF(0, y, self.NAME_W, self.ROW_H)
            if row.is_group:
                p.fillRect(rect, header)
                collapsed = row.group in self.collapsed
                cx, cy = 9.0, y + self.ROW_H / 2
                tri = ([QPointF(cx - 3, cy - 4), QPointF(cx + 3, cy), QPointF(cx - 3, cy + 4)] if collapsed else
                       [QPointF(cx - 4, cy - 2.5), QPointF(cx + 4, cy - 2.5), QPointF(cx, cy + 3)])
                p.setPen(Qt.PenStyle.NoPen)
                p.setBrush(pal.windowText())
                p.drawPolygon(QPolygonF(tri))
                p.setFont(self._bold)
                p.setPen(pal.windowText().color())
                p.drawText(rect.adjusted(18, 0, -4, 0), Qt.AlignmentFlag.AlignVCenter | Qt.AlignmentFlag.AlignLeft,
                           row.label)
                continue
            selected = row.key in self.c.selected_tracks
            if selected:
                p.fillRect(rect, highlight)
            text_color = QColor(pal.highlightedText().color() if selected else pal.windowText().color())
            if row.key not in tracks:
                text_color.setAlpha(150)  # no track yet
            p.setFont(self.font())
            p.setPen(text_color)
            label = metrics.elidedText(row.label, Qt.TextElideMode.ElideRight, int(self.NAME_W - 24 - self.VALUE_W))
            p.drawText(rect.adjusted(22, 0, 0, 0), Qt.AlignmentFlag.AlignVCenter | Qt.AlignmentFlag.AlignLeft, label)
        p.setPen(QPen(pal.mid().color(), 1))
        p.drawLine(QPointF(self.NAME_W - 0.5, self.RULER_H), QPointF(self.NAME_W - 0.5, h))

    def _paint_values(self, p: QPainter) -> None:
        """Each track's value at the cursor, right-aligned in the names column (changes every frame)."""
        pal = self.palette()
        tracks = self.c.timeline.tracks
        t = self.c.current_time
        first = max(0, self.scroll // self.ROW_H)
        last = min(len(self.rows), first + (self.height() - self.RULER_H) // self.ROW_H + 2)
        rows = [(i, r) for i, r in enumerate(self.rows[first:last], first) if not r.is_group]
        if not rows:
            return
        keys = [r.key for _, r in rows if r.key in tracks and len(tracks[r.key])]
        values = dict(zip(*self.c.timeline.evaluate_array(t, keys))) if keys else {}
        normal = pal.windowText().color()
        pen = None
        p.setClipRect(QRectF(0, self.RULER_H, self.NAME_W, self.height() - self.RULER_H))
        p.setFont(self._small)
        for i, row in rows:
            v = values.get(row.key)
            color = normal
            if row.key in self.c.selected_tracks:
                color = pal.highlightedText().color()
            if v is None:
                v = self.c.rig_value(row.key)
                if v is None:
                    continue
                color = QColor(color)
                color.setAlpha(150)
            if pen != color.rgba():  # one setPen per colour change, not per row
                p.setPen(color)
                pen = color.rgba()
            y = self.row_top(i)
            p.drawText(QRectF(self.NAME_W - self.VALUE_W - 6, y, self.VALUE_W, self.ROW_H),
                       Qt.AlignmentFlag.AlignVCenter | Qt.AlignmentFlag.AlignRight, _format_value(row.key, float(v)))

    def _paint_ruler(self, p: QPainter, ticks) -> None:
        pal = self.palette()
        w = self.width()
        fps = self.c.timeline.fps
        p.fillRect(QRectF(0, 0, w, self.RULER_H), pal.button().color())
        p.setPen(QPen(pal.mid().color(), 1))
        p.drawLine(QPointF(0, self.RULER_H - 0.5), QPointF(w, self.RULER_H - 0.5))
        # left: what the two label rows are
        dim = QColor(pal.buttonText().color())
        dim.setAlpha(140)
        p.setFont(self._small)
        p.setPen(pal.buttonText().color())
        right = Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter
        p.drawText(QRectF(4, 2, self.NAME_W - 10, 14), right, "seconds")
        p.setPen(dim)
        p.drawText(QRectF(4, 15, self.NAME_W - 10, 14), right, f"frames @ {fps} fps")
        p.save()
        p.setClipRect(QRectF(self.NAME_W, 0, w - self.NAME_W, self.RULER_H))
        major, minor, times = ticks
        t_start = max(0.0, self.t_of(self.NAME_W))
        t_end = min(self.c.timeline.duration, self.t_of(w))
        if minor < major:
            p.setPen(QPen(pal.mid().color(), 1))
            k0, k1 = math.ceil(t_start / minor - 1e-9), math.floor(t_end / minor + 1e-9)
            if k1 - k0 < 4000:
                for k in range(k0, k1 + 1):
                    x = float(self.x_of(k * minor))
                    p.drawLine(QPointF(x, self.RULER_H - 5), QPointF(x, self.RULER_H - 1))
        p.setFont(self._small)
        metrics = QFontMetrics(self._small)
        for tm in times:
            x = float(self.x_of(tm))
            p.setPen(QPen(pal.buttonText().color(), 1))
            p.drawLine(QPointF(x, self.RULER_H - 10), QPointF(x, self.RULER_H - 1))
            label = f"{tm:.2f}".rstrip("0").rstrip(".") + " s"
            frame_label = f"{int(round(tm * fps))}"
            width = max(metrics.horizontalAdvance(label), metrics.horizontalAdvance(frame_label))
            tx = x + 3 if x + 3 + width <= w - 2 else x - 3 - width  # the last label stays inside
            p.drawText(QPointF(tx, 13), label)
            p.setPen(dim)
            p.drawText(QPointF(tx, 25), frame_label)
        x_end = float(self.x_of(self.c.timeline.duration))
        p.setPen(QPen(pal.dark().color(), 2))
        p.drawLine(QPointF(x_end, 0), QPointF(x_end, self.RULER_H))
        p.restore()

    def _paint_cursor(self, p: QPainter) -> None:
        x = float(self.x_of(self.c.current_time))
        if x < self.NAME_W - 1 or x > self.width() + 1:
            return
        p.setPen(QPen(CURSOR_COLOR, 1.5))
        p.drawLine(QPointF(x, self.RULER_H - 8), QPointF(x, self.height()))
        p.setPen(Qt.PenStyle.NoPen)
        p.setBrush(CURSOR_COLOR)
        path = QPainterPath()
        path.moveTo(x - 5, self.RULER_H - 12)
        path.lineTo(x + 5, self.RULER_H - 12)
        path.lineTo(x + 5, self.RULER_H - 6)
        path.lineTo(x, self.RULER_H - 1)
        path.lineTo(x - 5, self.RULER_H - 6)
        path.closeSubpath()
        p.drawPath(path)

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


# ------------------------------------------------------------------ the dock
class TimelineDock(QDockWidget):
    """Transport bar + :class:`TrackView` for a :class:`TimelineController`."""

    def __init__(self, controller: TimelineController, parent: QWidget | None = None):
        super().__init__("Timeline", parent)
        self.setObjectName("timelineDock")
        self.c = controller
        self.setAllowedAreas(Qt.DockWidgetArea.BottomDockWidgetArea | Qt.DockWidgetArea.TopDockWidgetArea)
        body = QWidget(self)
        outer = QVBoxLayout(body)
        outer.setContentsMargins(4, 2, 4, 4)
        outer.setSpacing(3)
        bar = QHBoxLayout()
        bar.setSpacing(4)
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
        bar.addStretch(1)
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
        bar.addSpacing(8)
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
        # The transport bar scrolls sideways when the window is narrow, so the dock never forces a wide
        # window (its buttons alone are ~1000 px).
        strip = QWidget(body)
        strip.setLayout(bar)
        bar.setContentsMargins(0, 0, 0, 0)
        scroller = QScrollArea(body)
        scroller.setWidget(strip)
        scroller.setWidgetResizable(True)
        scroller.setFrameShape(QFrame.Shape.NoFrame)
        scroller.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAsNeeded)
        scroller.setVerticalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroller.setFixedHeight(strip.sizeHint().height() + scroller.horizontalScrollBar().sizeHint().height() + 2)
        outer.addWidget(scroller)

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


# ------------------------------------------------------------------ wiring into the window
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


def attach_timeline(window, *, state_dir=None, check_recovery: bool = True, autosave_ms: int | None = None
                    ) -> TimelineController:
    """Add the timeline to a MainWindow: the dock (bottom; the .fap player dock is tabified behind it and
    hidden), File ▸ project actions, Edit ▸ key actions, View ▸ Timeline / playback, Tools ▸ Lip-sync.

    state_dir : where untitled projects autosave (default: ``autosave/`` beside the window's settings file).
    check_recovery : offer to recover an autosave left by a Mimica that did not close (after the face loads).
    Returns the controller; ``controller.dock``, ``controller.project`` and ``window.timeline`` give the rest.
    """
    from app.project_actions import AUTOSAVE_MS, ProjectActions

    stack = window.document.undo_stack
    controller = TimelineController(window, stack)
    dock = TimelineDock(controller, window)
    controller.dock = dock
    window.addDockWidget(Qt.DockWidgetArea.BottomDockWidgetArea, dock)
    dock.show()
    dock.raise_()
    window.resizeDocks([dock], [300], Qt.Orientation.Vertical)

    status = getattr(window, "statusBar", None)
    if status is not None:
        controller.message.connect(lambda text: window.statusBar().showMessage(text, 8000))

    c = controller
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
    acts["loop"] = _action(window, "&Loop playback", lambda on: (setattr(c, "loop", bool(on)), dock.sync()),
                           None, "Start again at the end", checkable=True)
    c.auto_key_changed.connect(lambda on: (acts["auto_key"].blockSignals(True), acts["auto_key"].setChecked(on),
                                           acts["auto_key"].blockSignals(False)))
    dock.loop_check.toggled.connect(lambda on: (acts["loop"].blockSignals(True), acts["loop"].setChecked(on),
                                                acts["loop"].blockSignals(False)))
    c.playing_changed.connect(lambda playing: acts["play"].setText("&Pause" if playing else "&Play"))

    edit = _menu(window, "&Edit", before="View")
    if edit.actions() and not edit.actions()[-1].isSeparator():
        edit.addSeparator()
    for name in ("set_key", "auto_key", "copy_keys", "paste_keys", "delete_keys", "select_all_keys"):
        edit.addAction(acts[name])

    view = getattr(window, "view_menu", None) or _menu(window, "&View")
    toggle = dock.toggleViewAction()
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
    acts["lipsync"] = _action(window, "&Lip-sync from text…", lambda: open_lipsync_dialog(c), None,
                              "Make viseme (and blink) tracks from typed text, spoken by eSpeak NG")
    tools.addAction(acts["lipsync"])
    file_menu = _menu(window, "&File")
    acts["import_animation"] = _action(window, "&Import animation (.fap, .dpc)…", lambda: _import_dialog(c),
                                       "Ctrl+Shift+O", "Add a .fap or DPC control-point animation as tracks at the cursor")
    acts["export_fap"] = _action(window, "Export .&fap…", lambda: _export_fap_dialog(c), "Ctrl+Shift+E",
                                 "Write the timeline (or the current pose) as an MPEG-4 .fap animation")
    acts["export_video"] = _action(window, "Export &video…", lambda: export_video(c), "Ctrl+E",
                                   "Render the timeline to MP4 (with speech), GIF, AVI or PNG images")
    acts["export_still"] = _action(window, "Export s&till…", lambda: export_video(c, still=True), None,
                                   "Render the face at the timeline's current time to PNG or JPEG")
    anchor = getattr(window, "screenshot_action", None)
    for name in ("import_animation", "export_fap", "export_video", "export_still"):
        if anchor is not None and anchor in file_menu.actions():
            file_menu.insertAction(anchor, acts[name])
        else:
            file_menu.addAction(acts[name])
    dock.lipsync_button.clicked.connect(lambda: open_lipsync_dialog(c))
    c.actions = acts

    project = ProjectActions(window, controller, state_dir=state_dir,
                             autosave_ms=AUTOSAVE_MS if autosave_ms is None else autosave_ms)
    c.project = project
    window.timeline = controller
    if check_recovery:
        project.check_startup_recovery_when_ready()
    return controller


def _import_dialog(controller: TimelineController) -> None:
    from PySide6.QtWidgets import QFileDialog

    path, _ = QFileDialog.getOpenFileName(controller.window, "Import animation", "",
                                          "Animations (*.fap *.dpc *.txt);;All files (*)")
    if path:
        controller.import_animation(path)


def export_video(controller: TimelineController, *, still: bool = False):
    """File ▸ Export video… / still: the export dialog for the timeline, rendered from a copy of the rig
    (``controller.animation()``), with the speech track. Returns the export job, or None."""
    from app.export_dialog import run_export_dialog

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
    return run_export_dialog(controller.window, controller.window.face, animation.vertices,
                             controller.timeline.duration, controller.timeline.fps, audio, still=still,
                             current_time_s=controller.current_time)


def _export_fap_dialog(controller: TimelineController) -> None:
    from PySide6.QtWidgets import QFileDialog

    path, _ = QFileDialog.getSaveFileName(controller.window, "Export .fap animation", "animation.fap",
                                          "MPEG-4 FAP animation (*.fap)")
    if path:
        controller.export_fap(path if path.lower().endswith(".fap") else path + ".fap")


def open_lipsync_dialog(controller: TimelineController):
    """Show (or raise) the lip-sync dialog for ``controller``."""
    from app.lipsync_dialog import LipSyncDialog

    dialog = getattr(controller, "lipsync_dialog", None)
    if dialog is None:
        dialog = LipSyncDialog(controller, controller.window)
        controller.lipsync_dialog = dialog
    dialog.set_start_time(controller.current_time)
    dialog.show()
    dialog.raise_()
    dialog.activateWindow()
    return dialog


__all__ = ["TimelineDock", "TrackView", "Row", "build_rows", "attach_timeline", "open_lipsync_dialog",
           "group_of"]
