"""fap_player.py
----
Play MPEG-4 ``.fap`` animations (:class:`core.fap_file.FapSequence`) on a
:class:`core.rig.FaceRig`, and export the rig's current state as a one-frame
``.fap`` file.

* :class:`FapPlayer` (a ``QObject``, no widgets): load / play / pause / stop /
  seek. Playback keeps wall-clock time: a ``QTimer`` ticks about once per frame
  and the frame shown is computed from a ``QElapsedTimer``, so slow rendering
  drops frames instead of slowing the animation down.
* :func:`sequence_from_rig`: the rig's current state as a one-frame sequence
  ("Export .fap").
* :class:`FapPlayerBar`: a compact bar (Open .fap…, Play/Pause, Stop, frame
  slider, frame label, Loop, Export .fap…) over a :class:`FapPlayer`.

Frame semantics (as in the MPEG-4 players): a FAP masked in at a frame takes
that frame's value; a FAP masked out holds the value it was last given. Any
frame ``k`` can be shown directly (seeking, dropped frames): each FAP then has
the value of the last frame ``<= k`` that masked it in, or the value it had
before playback started if no such frame exists. FAP 1 (viseme) and FAP 2
(expression) are applied through ``FaceRig.set_fap1`` / ``set_fap2`` the same
way. FAPs the player never drives are left alone, so the user can still move
other sliders during playback.

Nothing is clamped silently: FAPs the rig cannot animate (tongue, ears, gaze
without eyeballs, ...) are skipped and collected in ``FapPlayer.skipped``;
values beyond the slider range are recorded in ``FapPlayer.clipped`` and then
limited to it. :meth:`FapPlayer.report` turns both into one line for the window.

All changes of one frame reach the rig with the rig's ``changed`` signal
blocked and are announced by a single ``rig.touch()`` afterwards, so the view
redraws once per frame (one ``set_faps`` call plus the FAP 1 / FAP 2 preset
calls of that frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import QElapsedTimer, QObject, QSignalBlocker, Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QMessageBox,
    QSlider,
    QToolButton,
    QWidget,
)

from core.fap import tables
from core.fap_file import N_FAPS, FapFileError, FapSequence, read_fap, write_fap

if TYPE_CHECKING:  # pragma: no cover
    from core.rig import FaceRig

__all__ = ["FapPlayer", "FapPlayerBar", "sequence_from_rig", "FAP_FILTER"]

FAP_FILTER = "MPEG-4 FAP animation (*.fap);;All files (*)"
MIN_TICK_MS = 10

#: FAPs Mimica may not animate, by part of the face (for the "ignored FAPs" notice).
_PARTS = (
    (range(23, 27), "gaze"),
    (range(27, 29), "eyeball thrust"),
    (range(29, 31), "pupils"),
    (range(43, 48), "tongue"),
    (range(48, 51), "head"),
    (range(65, 69), "ears"),
)


def _part(fap: int) -> str:
    for numbers, name in _PARTS:
        if fap in numbers:
            return name
    return tables.fap_spec(fap).name


def _number_text(value: float) -> str:
    """1800 -> '1800', 12.5 -> '12.5' (for user messages)."""
    if float(value).is_integer():
        return str(int(value))
    return f"{value:.2f}".rstrip("0").rstrip(".")


def _intensity63(fraction: float) -> int:
    """A 0..1 intensity as the 0..63 integer of FAP 1/2, rounded half up."""
    return int(min(63, max(0, math.floor(float(fraction) * 63 + 0.5))))


@dataclass
class _RigState:
    """What the player may change on a rig: low-level values and the two preset mixes."""

    values: np.ndarray
    expressions: tuple
    visemes: tuple

    @classmethod
    def capture(cls, rig: "FaceRig") -> "_RigState":
        return cls(rig.fap_values(), tuple(rig.expressions), tuple(rig.visemes))


def _restore_expressions(rig: "FaceRig", mix: tuple) -> None:
    if len(mix) == 1:
        rig.set_expression(mix[0][0], mix[0][1])
    else:
        (s1, w1), (s2, w2) = mix[:2]
        rig.set_fap2(s1, _intensity63(w1), s2, _intensity63(w2))


def _restore_visemes(rig: "FaceRig", mix: tuple) -> None:
    if len(mix) == 1:
        rig.set_viseme(mix[0][0], mix[0][1])
    else:
        (s1, w1), (s2, _w2) = mix[:2]
        rig.set_fap1(s1, s2, _intensity63(w1))


# ------------------------------------------------------------------ export
def sequence_from_rig(rig: "FaceRig", *, fps: float = 25.0, name: str = "mimica") -> FapSequence:
    """A one-frame :class:`FapSequence` of the rig's current state.

    The user's non-zero low-level FAP values (3..68) are masked in; FAP 2 holds the active
    expression preset(s) and FAP 1 the active viseme preset(s), intensities mapped to 0..63
    (rounded half up). A neutral expression / no viseme leaves FAP 2 / FAP 1 masked out.
    """
    values = np.full((1, N_FAPS), np.nan)
    user = rig.fap_values()
    nonzero = np.flatnonzero(user[2:]) + 2
    values[0, nonzero] = user[nonzero]

    expression = np.full((1, 6), -1, np.int64)
    active = [(int(e), w) for e, w in rig.expressions if e != 0 and w > 0]
    if active:
        row = [0, 0, 0, 0, 0, 0]
        for slot, (eid, weight) in enumerate(active[:2]):
            row[2 * slot] = eid
            row[2 * slot + 1] = _intensity63(weight)
        expression[0] = row

    viseme = np.full((1, 4), -1, np.int64)
    mix = list(rig.visemes)
    if any(v != 0 and w > 0 for v, w in mix):
        (s1, w1), (s2, _w2) = (mix + [(0, 0.0)])[:2]
        viseme[0] = [int(s1), int(s2), _intensity63(w1), 0]

    return FapSequence.from_values(values, fps, name=name, viseme=viseme, expression=expression)


# ------------------------------------------------------------------ the player
class FapPlayer(QObject):
    """Plays a :class:`FapSequence` on a :class:`FaceRig` in wall-clock time.

    Signals
    -------
    frame_changed(int)
        The frame shown (0-based) changed.
    finished()
        Playback reached the last frame without ``loop`` (emitted after ``state_changed(False)``).
    state_changed(bool)
        Playing (True) or not (False).
    sequence_changed()
        A sequence was loaded (or the rig replaced); ``n_frames`` / ``fps`` may have changed.

    Attributes
    ----------
    skipped : set of int
        FAPs masked in by the frames played so far that the rig cannot animate (not applied).
    clipped : dict int -> float
        FAP -> largest |value| seen beyond its slider range in the frames played so far (the
        value applied was limited to the range).
    """

    frame_changed = Signal(int)
    finished = Signal()
    state_changed = Signal(bool)
    sequence_changed = Signal()

    def __init__(self, rig: "FaceRig | None", parent: QObject | None = None):
        super().__init__(parent)
        self._rig = rig
        self._seq: FapSequence | None = None
        self._frame = 0
        self._loop = False
        self._playing = False
        self._timer = QTimer(self)
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.timeout.connect(self._tick)
        self._clock = QElapsedTimer()
        self._start_frame = 0  # frame shown when the clock was (re)started
        self._position = 0  # frames advanced since then (not wrapped)
        self._baseline: _RigState | None = None  # the rig before playback; None = nothing applied
        self._driven: set[int] = set()  # low-level FAPs the player has set on the rig
        self._expression_driven = False
        self._viseme_driven = False
        self.skipped: set[int] = set()
        self.clipped: dict[int, float] = {}
        self._extreme: dict[int, float] = {}  # fap -> signed value of largest |value| beyond range
        self._n_clipped = 0
        self._analyse()

    # ----------------------------------------------------------- properties
    @property
    def rig(self) -> "FaceRig | None":
        return self._rig

    @property
    def sequence(self) -> FapSequence | None:
        return self._seq

    @property
    def frame(self) -> int:
        """The current frame, 0-based."""
        return self._frame

    @property
    def n_frames(self) -> int:
        return 0 if self._seq is None else self._seq.n_frames

    @property
    def fps(self) -> float:
        return 0.0 if self._seq is None else self._seq.fps

    @property
    def is_playing(self) -> bool:
        return self._playing

    @property
    def loop(self) -> bool:
        return self._loop

    @loop.setter
    def loop(self, value: bool) -> None:
        self._loop = bool(value)

    @property
    def frames_played(self) -> int:
        """How many distinct frames playback or seeking has gone through since the last load."""
        return int(self._covered.sum())

    # ----------------------------------------------------------- loading
    def set_rig(self, rig: "FaceRig | None") -> None:
        """Play on another rig (e.g. a new face): stops (restoring the old rig) first."""
        self.stop()
        self._rig = rig
        self._analyse()
        self.sequence_changed.emit()

    def load(self, seq: FapSequence | None) -> None:
        """Replace the sequence: stops the current one (restoring the rig), frame 0, counters cleared.

        The rig is not touched until :meth:`play` or :meth:`seek`.
        """
        self.stop()
        self._seq = seq
        self._analyse()
        self.sequence_changed.emit()
        self.frame_changed.emit(self._frame)

    def _analyse(self) -> None:
        """Per-frame tables of the sequence on the rig: held frames, unanimated FAPs, values out of range."""
        self.skipped = set()
        self.clipped = {}
        self._extreme = {}
        self._n_clipped = 0
        seq = self._seq
        n = 0 if seq is None else seq.n_frames
        self._covered = np.zeros(n, bool)
        self._animated = np.zeros(N_FAPS, bool)
        self._lo = self._hi = np.full(N_FAPS, np.nan)
        if seq is None or self._rig is None:
            self._held = np.full((n, N_FAPS), -1, np.int64)
            self._unanimated = np.zeros((n, N_FAPS), bool)
            self._beyond = np.zeros((n, N_FAPS), bool)
            return
        frames = np.arange(n)[:, None]
        # held[k, c]: the last frame <= k that masks column c in (-1: none yet)
        self._held = np.maximum.accumulate(np.where(seq.mask, frames, -1), axis=0)
        animated = np.zeros(N_FAPS, bool)
        animated[[f - 1 for f in self._rig.animated_faps]] = True
        self._animated = animated
        low = np.zeros(N_FAPS, bool)
        low[2:] = True
        specs = tables.fap_specs()
        self._lo = np.array([s.minimum for s in specs])
        self._hi = np.array([s.maximum for s in specs])
        finite = np.isfinite(seq.values)
        self._unanimated = seq.mask & low & ~animated
        with np.errstate(invalid="ignore"):
            self._beyond = seq.mask & low & animated & finite & ((seq.values < self._lo) | (seq.values > self._hi))

    # ----------------------------------------------------------- transport
    def play(self) -> None:
        """Start or resume playback from the current frame (from frame 0 when at the end without loop)."""
        if self._playing or self._rig is None or self.n_frames == 0:
            return
        start = 0 if self._frame >= self.n_frames - 1 and not self._loop else self._frame
        self._show(start)
        self._restart_clock()
        self._timer.setInterval(max(MIN_TICK_MS, int(round(1000.0 / self.fps))))
        self._timer.start()
        self._playing = True
        self.state_changed.emit(True)

    def pause(self) -> None:
        """Stop advancing; the rig keeps the current frame."""
        if not self._playing:
            return
        self._timer.stop()
        self._playing = False
        self.state_changed.emit(False)

    def stop(self) -> None:
        """Pause, go back to frame 0 and give the rig back the values/presets it had before playback."""
        self.pause()
        self._restore()
        if self._frame != 0:
            self._frame = 0
            self.frame_changed.emit(0)

    def toggle(self) -> None:
        """Play if paused, pause if playing."""
        if self._playing:
            self.pause()
        else:
            self.play()

    def seek(self, frame: int) -> None:
        """Show ``frame`` (clamped to the sequence); playback, if running, continues from there."""
        if self._rig is None or self.n_frames == 0:
            return
        frame = int(min(max(int(frame), 0), self.n_frames - 1))
        self._show(frame)
        if self._playing:
            self._restart_clock()

    def _restart_clock(self) -> None:
        self._start_frame = self._frame
        self._position = 0
        self._clock.start()

    def _tick(self) -> None:
        if not self._playing or self._seq is None:
            return
        n = self.n_frames
        position = int(self._clock.elapsed() * self.fps / 1000.0)
        if position <= self._position:
            return
        passed = np.arange(self._start_frame + self._position + 1, self._start_frame + position + 1)
        self._position = position
        end = self._start_frame + position
        if self._loop:
            self._cover(passed[-n:] % n)
            self._show(end % n)
        elif end >= n - 1:
            self._cover(passed[passed < n])
            self._show(n - 1)
            self.pause()
            self.finished.emit()
        else:
            self._cover(passed)
            self._show(end)

    # ----------------------------------------------------------- applying
    def _show(self, k: int) -> None:
        self._cover(np.array([k]))
        self._apply(k)
        if k != self._frame:
            self._frame = k
            self.frame_changed.emit(k)

    def _cover(self, frames: np.ndarray) -> None:
        """Record what frames ``frames`` (shown or dropped) skip and clip, once per frame."""
        frames = np.asarray(frames, np.int64)
        if not len(frames):
            return
        new = np.unique(frames[~self._covered[frames]])
        if not len(new):
            return
        self._covered[new] = True
        cols = np.flatnonzero(self._unanimated[new].any(axis=0))
        self.skipped.update(int(c) + 1 for c in cols)
        rows, cols = np.nonzero(self._beyond[new])
        self._n_clipped += len(rows)
        for k, c in zip(new[rows].tolist(), cols.tolist()):
            value = float(self._seq.values[k, c])
            fap = c + 1
            if abs(value) > self.clipped.get(fap, -1.0):
                self.clipped[fap] = abs(value)
                self._extreme[fap] = value

    def _apply(self, k: int) -> None:
        """Put the rig in the state of frame ``k`` (held values), announcing it once."""
        rig, seq = self._rig, self._seq
        if self._baseline is None:
            self._baseline = _RigState.capture(rig)
        held = self._held[k]
        cols = np.flatnonzero((held >= 0) & self._animated)
        cols = cols[cols >= 2]
        values = seq.values[held[cols], cols]
        ok = np.isfinite(values)
        cols, values = cols[ok], np.clip(values[ok], self._lo[cols[ok]], self._hi[cols[ok]])
        updates = {int(c) + 1: float(v) for c, v in zip(cols, values)}
        driven = set(updates)
        for fap in self._driven - driven:  # seeking back before a FAP's first key
            updates[fap] = float(self._baseline.values[fap - 1])
        self._driven = driven

        before = _RigState.capture(rig)
        updates = {fap: v for fap, v in updates.items() if before.values[fap - 1] != v}
        with rig.changed.blocked():
            if held[0] >= 0:
                s1, s2, blend, _def = seq.viseme[held[0]].tolist()
                rig.set_fap1(s1, s2, blend)
                self._viseme_driven = True
            elif self._viseme_driven:
                _restore_visemes(rig, self._baseline.visemes)
                self._viseme_driven = False
            if held[1] >= 0:
                s1, i1, s2, i2, _init, _def = seq.expression[held[1]].tolist()
                rig.set_fap2(s1, i1, s2, i2)
                self._expression_driven = True
            elif self._expression_driven:
                _restore_expressions(rig, self._baseline.expressions)
                self._expression_driven = False
            if updates:
                rig.set_faps(updates)
        self._announce(before)

    def _restore(self) -> None:
        """Give the rig back what the player changed (the values before playback), once."""
        rig, base = self._rig, self._baseline
        self._baseline = None
        if rig is None or base is None:
            self._driven = set()
            self._expression_driven = self._viseme_driven = False
            return
        before = _RigState.capture(rig)
        with rig.changed.blocked():
            if self._driven:
                rig.set_faps({fap: float(base.values[fap - 1]) for fap in self._driven})
            if self._expression_driven:
                _restore_expressions(rig, base.expressions)
            if self._viseme_driven:
                _restore_visemes(rig, base.visemes)
        self._driven = set()
        self._expression_driven = self._viseme_driven = False
        self._announce(before)

    def _announce(self, before: _RigState) -> None:
        rig = self._rig
        if (not np.array_equal(before.values, rig.fap_values()) or before.expressions != tuple(rig.expressions)
                or before.visemes != tuple(rig.visemes)):
            rig.touch()

    # ----------------------------------------------------------- report
    def report(self) -> str:
        """One line for the window: frames played, FAPs ignored (and why), values limited to the range.

        e.g. "Played 3 frames; ignored FAPs 43, 47 (tongue: not animated); 2 values beyond the
        slider range were limited: open_jaw 1800 > 1400".
        """
        n = self.frames_played
        parts = [f"Played {n} frame{'' if n == 1 else 's'}"]
        if self.skipped:
            by_part: dict[str, list[int]] = {}
            for fap in sorted(self.skipped):
                by_part.setdefault(self._skip_reason(fap), []).append(fap)
            groups = [f"{', '.join(map(str, faps))} ({reason})" for reason, faps in by_part.items()]
            word = "FAP" if len(self.skipped) == 1 else "FAPs"
            parts.append(f"ignored {word} " + ", ".join(groups))
        if self._n_clipped:
            items = []
            for fap in sorted(self._extreme):
                spec = tables.fap_spec(fap)
                v = self._extreme[fap]
                bound = f"> {_number_text(spec.maximum)}" if v > spec.maximum else f"< {_number_text(spec.minimum)}"
                items.append(f"{spec.name} {_number_text(v)} {bound}")
            m = self._n_clipped
            parts.append(f"{m} value{'s' if m != 1 else ''} beyond the slider range "
                         f"{'were' if m != 1 else 'was'} limited: " + ", ".join(items))
        return "; ".join(parts)

    def _skip_reason(self, fap: int) -> str:
        part = _part(fap)
        if fap in range(23, 27):
            return f"{part}: this face has no separate eyeballs"
        return f"{part}: not animated"


# ------------------------------------------------------------------ the bar
class FapPlayerBar(QWidget):
    """Open .fap…, Play/Pause, Stop, frame slider, "frame 12 / 108 · 25 fps", Loop, Export .fap….

    The frame label counts from 1 (frame 0 of the file is "frame 1 / n").

    Signals
    -------
    message(str)
        A one-line notice for the status bar: the reader's notes after opening a file, the player's
        :meth:`FapPlayer.report` when playback finishes or stops, where an export went.
    """

    message = Signal(str)

    def __init__(self, player: FapPlayer, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("fapPlayerBar")
        self.player = player
        self.path: Path | None = None
        self._dir = ""

        layout = QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        layout.setSpacing(4)

        def button(text: str, name: str, tip: str) -> QToolButton:
            b = QToolButton(self)
            b.setText(text)
            b.setObjectName(name)
            b.setToolTip(tip)
            b.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
            layout.addWidget(b)
            return b

        self.open_button = button("Open .fap…", "fapOpen", "Open an MPEG-4 .fap animation")
        self.play_button = button("Play", "fapPlay", "Play / pause the animation (wall-clock time)")
        self.play_button.setCheckable(True)
        self.stop_button = button("Stop", "fapStop", "Stop: back to frame 1 and the face as it was before playing")
        self.slider = QSlider(Qt.Orientation.Horizontal, self)
        self.slider.setObjectName("fapSlider")
        self.slider.setTracking(True)
        self.slider.setMinimumWidth(120)
        self.slider.setToolTip("Drag to scrub through the animation")
        layout.addWidget(self.slider, 1)
        self.frame_label = QLabel(self)
        self.frame_label.setObjectName("fapFrameLabel")
        layout.addWidget(self.frame_label)
        self.loop_check = QCheckBox("Loop", self)
        self.loop_check.setObjectName("fapLoop")
        layout.addWidget(self.loop_check)
        self.export_button = button("Export .fap…", "fapExport",
                                    "Save the face's current FAP state as a one-frame .fap file")

        self.open_button.clicked.connect(self.open_dialog)
        self.export_button.clicked.connect(self.export_dialog)
        self.play_button.clicked.connect(self._play_clicked)
        self.stop_button.clicked.connect(self._stop_clicked)
        self.slider.valueChanged.connect(self.player.seek)
        self.loop_check.toggled.connect(self._loop_toggled)
        player.frame_changed.connect(self._sync)
        player.state_changed.connect(self._on_state)
        player.sequence_changed.connect(self._sync)
        player.finished.connect(lambda: self.message.emit(player.report()))
        self._sync()

    # ----------------------------------------------------------- work (no dialogs)
    def open_file(self, path) -> bool:
        """Read ``path`` and load it; on error a message box, the previous sequence stays. True if loaded."""
        path = Path(path)
        try:
            seq = read_fap(path)
        except (FapFileError, ValueError, OSError) as exc:
            QMessageBox.warning(self, "Cannot open .fap file", str(exc))
            return False
        if seq.n_frames == 0:
            QMessageBox.warning(self, "Cannot open .fap file",
                                f"'{path.name}' has no frames; there is nothing to play.")
            return False
        self.path = path
        self._dir = str(path.parent)
        self.player.load(seq)
        notice = f"Loaded '{path.name}': {seq.n_frames} frames at {_number_text(seq.fps)} fps."
        self.message.emit(" ".join([notice, *seq.notes]))
        return True

    def export_file(self, path) -> bool:
        """Write the rig's current state to ``path`` as a one-frame .fap; errors in a message box."""
        path = Path(path)
        rig = self.player.rig
        if rig is None:
            QMessageBox.warning(self, "Cannot export .fap file",
                                "This face has no FAP rig; there is nothing to export.")
            return False
        try:
            fps = self.player.fps or 25.0
            write_fap(path, sequence_from_rig(rig, fps=fps, name=path.stem or "mimica"))
        except (FapFileError, ValueError, OSError) as exc:
            QMessageBox.warning(self, "Cannot export .fap file", str(exc))
            return False
        self._dir = str(path.parent)
        self.message.emit(f"Exported the current FAP state to '{path.name}'.")
        return True

    # ----------------------------------------------------------- dialogs
    def open_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open .fap animation", self._dir, FAP_FILTER)
        if path:
            self.open_file(path)

    def export_dialog(self) -> None:
        start = str(Path(self._dir) / "mimica.fap") if self._dir else "mimica.fap"
        path, _ = QFileDialog.getSaveFileName(self, "Export .fap", start, FAP_FILTER)
        if path:
            if not Path(path).suffix:
                path += ".fap"
            self.export_file(path)

    # ----------------------------------------------------------- state
    def _play_clicked(self) -> None:
        self.player.toggle()
        self._on_state(self.player.is_playing)

    def _stop_clicked(self) -> None:
        played = self.player.frames_played
        self.player.stop()
        if played:
            self.message.emit(self.player.report())

    def _loop_toggled(self, on: bool) -> None:
        self.player.loop = on

    def _on_state(self, playing: bool) -> None:
        with QSignalBlocker(self.play_button):
            self.play_button.setChecked(playing)
        self.play_button.setText("Pause" if playing else "Play")

    def _sync(self, *_args) -> None:
        p = self.player
        n = p.n_frames
        has = n > 0 and p.rig is not None
        for w in (self.play_button, self.stop_button, self.slider):
            w.setEnabled(has)
        self.export_button.setEnabled(p.rig is not None)
        with QSignalBlocker(self.slider):
            self.slider.setRange(0, max(n - 1, 0))
            self.slider.setValue(p.frame)
        with QSignalBlocker(self.loop_check):
            self.loop_check.setChecked(p.loop)
        if n:
            self.frame_label.setText(f"frame {p.frame + 1} / {n} · {_number_text(p.fps)} fps")
        else:
            self.frame_label.setText("no .fap loaded")
        self._on_state(p.is_playing)
