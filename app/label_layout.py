"""Name labels that do not pile up: each render shows only the labels that fit.

A face carries 64–84 feature points, a dozen of them within a few millimetres around the mouth;
drawn all at once their names cover each other and the lips. :class:`LabelLayout` keeps one
label per point in a label mesh (the string array VTK's point-label mapper draws) and, just
before every render (the renderer's ``StartEvent``), blanks

- labels of points on the far side of the face (their surface normal turned away from the camera),
- labels whose box would overlap a label already placed, placing the most frontal points first,
- labels of ``reserved`` points, which have a box of their own (the selected and hovered landmark),
  and labels that would overlap those boxes.

A point whose label is hidden keeps its marker; hovering it shows its name. Cost: one 4x4
projection of the k points and a greedy pass over k boxes (k < 100), well under a millisecond.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from app.projection import world_to_display

__all__ = ["LabelLayout", "place_labels", "label_box_sizes"]

#: Pixels per character and per line of VTK's default font at size 1 (measured on the point-label
#: mapper's boxes: ~0.62 em per digit or dot, ~1.45 em per line with the frame's margin).
_CHAR_EM = 0.62
_LINE_EM = 1.45
#: Space kept clear around another actor's label box (its frame is drawn outside the text).
_BOX_CLEARANCE_PX = 5.0


def label_box_sizes(texts: Sequence[str], font_size: float, margin_px: float = 2.0) -> np.ndarray:
    """(k, 2) width and height in pixels of the boxes of ``texts`` drawn at ``font_size``."""
    chars = np.array([len(t) for t in texts], dtype=float)
    width = chars * _CHAR_EM * font_size + 2.0 * margin_px + 4.0
    height = np.full(len(texts), _LINE_EM * font_size + 2.0 * margin_px)
    return np.c_[width, height]


def place_labels(centres: np.ndarray, sizes: np.ndarray, order: Iterable[int],
                 reserved: Iterable[int] = (), blocked: np.ndarray | None = None) -> np.ndarray:
    """(k,) bool: which labels to show so that no two shown boxes overlap.

    ``centres`` (k, 2) box centres and ``sizes`` (k, 2) their width and height, in pixels;
    ``order``: the candidate indices, first placed first (others are hidden); ``reserved``
    indices are never shown (they have a box of their own); ``blocked`` (m, 4) centre x, y,
    width, height of boxes drawn by others (those own boxes), which no shown label may overlap.
    """
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    half = np.asarray(sizes, dtype=float).reshape(-1, 2) / 2.0
    blocked = np.zeros((0, 4)) if blocked is None else np.asarray(blocked, dtype=float).reshape(-1, 4)
    taken_centres = [tuple(b) for b in blocked[:, :2]]
    taken_half = [tuple(b) for b in blocked[:, 2:] / 2.0]
    shown = np.zeros(len(centres), dtype=bool)
    reserved = {int(i) for i in reserved}
    for i in (int(i) for i in order if int(i) not in reserved):
        if taken_centres:
            gap = np.abs(np.array(taken_centres) - centres[i]) - (np.array(taken_half) + half[i])
            if np.any((gap[:, 0] < 0.0) & (gap[:, 1] < 0.0)):
                continue
        taken_centres.append(tuple(centres[i]))
        taken_half.append(tuple(half[i]))
        shown[i] = True
    return shown


class LabelLayout:
    """Shows the labels of ``label_mesh``'s string array ``array`` that fit (see the module docstring).

    Call :meth:`set_points` after moving the anchors (with the surface normals at the points) and
    :meth:`set_reserved` when the selected/hovered points change; the layout itself runs before
    every render of ``renderer``. :meth:`detach` before dropping the labels.
    """

    def __init__(self, renderer, label_mesh, array: str, names: Sequence[str], *, font_size: float,
                 offset_px: tuple[float, float] = (0.0, 0.0)):
        self.renderer = renderer
        self.label_mesh = label_mesh
        self.array = array
        self.names = list(names)
        self.sizes = label_box_sizes(self.names, font_size)
        self.offset_px = np.asarray(offset_px, dtype=float)
        self.normals = np.zeros((len(self.names), 3))
        self.reserved: frozenset[int] = frozenset()
        self.boxes: tuple = ()
        self.shown = np.ones(len(self.names), dtype=bool)
        self.enabled = True
        self.active = True      # False while the labels are hidden: nothing to lay out
        self._observer = renderer.AddObserver("StartEvent", lambda *_: self.update())

    def set_points(self, normals: np.ndarray) -> None:
        """The unit surface normals (k, 3) at the labelled points (the anchors are the mesh's points)."""
        self.normals = np.asarray(normals, dtype=float).reshape(-1, 3)

    def set_reserved(self, indices: Iterable[int], boxes: Sequence[tuple] = ()) -> None:
        """Hide the labels of ``indices`` (they have a box of their own) and keep the others off
        ``boxes``: (world point (3,), text, font size, pixel offset (dx, dy) of the box's left
        edge and vertical centre from the point's projection), e.g. the selected landmark's box."""
        self.reserved = frozenset(int(i) for i in indices if i is not None)
        self.boxes = tuple(boxes)

    def visible_names(self) -> list[str]:
        """Names whose label the last layout showed."""
        return [n for n, s in zip(self.names, self.shown) if s]

    def update(self) -> None:
        """Lay the labels out for the renderer's current camera (called before every render)."""
        if not self.names or self.label_mesh is None or not self.active:
            return
        anchors = np.asarray(self.label_mesh.points, dtype=float)
        if not self.enabled:
            shown = np.array([i not in self.reserved for i in range(len(self.names))])
        else:
            shown = self._fitting(anchors)
        if np.array_equal(shown, self.shown):
            return
        self.shown = shown
        labels = self.label_mesh.GetPointData().GetAbstractArray(self.array)
        for i, (name, show) in enumerate(zip(self.names, shown)):
            labels.SetValue(i, name if show else "")
        labels.Modified()
        self.label_mesh.Modified()

    def _fitting(self, anchors: np.ndarray) -> np.ndarray:
        camera = self.renderer.GetActiveCamera()
        if camera.GetParallelProjection():
            towards_camera = -np.asarray(camera.GetDirectionOfProjection(), float)[None, :]
        else:
            towards_camera = np.asarray(camera.GetPosition(), float)[None, :] - anchors
            towards_camera /= np.maximum(np.linalg.norm(towards_camera, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("kd,kd->k", self.normals, towards_camera)
        screen = world_to_display(self.renderer, anchors)
        width, height = self.renderer.GetSize()
        inside = ((screen[:, 0] >= 0) & (screen[:, 0] <= width) & (screen[:, 1] >= 0) & (screen[:, 1] <= height)
                  & (screen[:, 2] > 0) & (screen[:, 2] < 1))
        candidates = np.flatnonzero((facing > 0.05) & inside)
        order = candidates[np.argsort(-facing[candidates], kind="stable")]
        return place_labels(screen[:, :2] + self.offset_px, self.sizes, order, self.reserved, self._blocked())

    def _blocked(self) -> np.ndarray:
        """(m, 4) display boxes (centre x, y, width, height) of the reserved label boxes."""
        if not self.boxes:
            return np.zeros((0, 4))
        where = world_to_display(self.renderer, np.array([b[0] for b in self.boxes], dtype=float))[:, :2]
        sizes = np.concatenate([label_box_sizes([text], size, margin_px=4.0) for _, text, size, _ in self.boxes])
        offsets = np.array([b[3] for b in self.boxes], dtype=float)
        centres = where + offsets + np.c_[sizes[:, 0] / 2.0, np.zeros(len(sizes))]
        return np.c_[centres, sizes + 2.0 * _BOX_CLEARANCE_PX]

    def detach(self) -> None:
        if self._observer is not None:
            self.renderer.RemoveObserver(self._observer)
            self._observer = None
        self.label_mesh = None
