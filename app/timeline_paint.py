"""Painting of the timeline's track view: lanes, value curves, keys, names, values, the ruler and the
cursor, with the static layer cached in a pixmap until something changes."""

from __future__ import annotations

import math

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFontMetrics, QPainter, QPainterPath, QPen, QPixmap, QPolygonF

from core import timeline as tl

from app.timeline_controller import parameter_range

from app.timeline_rows import (
    KEY_COLOR, KEY_SELECTED, KEY_BORDER, CURSOR_COLOR, _format_value)


class TrackPainting:
    """The painting half of :class:`app.timeline_view.TrackView` (a mixin)."""

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
