"""muscle_view.py
----
The muscles of a :class:`core.layers.muscles.MuscleLayer` drawn in the viewport: every linear muscle as
a thick line from its mobile end P (at the lips) to its fixed end R, and the orbicularis oris as
its ring, coloured by activation (grey at 0 → red at the muscle's maximum force).

One ``pv.PolyData`` holds every muscle (a polyline of ``samples`` points per segment) and one
actor draws it; updates write the points and the per-line activation into the existing arrays
(no new actor, mesh or array per tick). Showing/hiding adds/removes that one actor.

Choices:

* Draped on the skin, not straight. P and R lie on the skin, so the straight chord between them
  runs *under* a curved cheek (a 50 mm muscle on a cheek of 80 mm radius sinks about 4 mm) and
  the face would hide it. When the mesh is built, every chord sample is moved to the closest
  point of the layer's simulated skin (``MuscleLayer.tissue_skin()``, the dense MPEG-4 template:
  its mouth is an open boundary, so nothing snaps to the inside of the lips, teeth or cavity),
  kept as (triangle, barycentric); each update evaluates those points on the current simulated
  skin and lifts them by ``lift_mm`` along its normal. The lines therefore move with the tissue
  (the P end with the lip corner) and stay on top of the face.
* The layer's own skin is used: FAP deformations of the face are not added to the lines (a
  known limit: with an expression from the FAP dock the lines sit on the muscle-only skin).
* Colour is the muscle's current (ramped) activation as a fraction of its maximum force, as
  ``MuscleLayer.muscle_segments`` / ``muscle_ring`` give it (0..1), with a 0.6 gamma so that
  small forces already read as "on".
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np
import pyvista as pv

#: Colour at zero and at full activation (RGB 0..1).
REST_COLOR = (0.66, 0.70, 0.78)
ACTIVE_COLOR = (0.93, 0.10, 0.08)
ACTIVATION_ARRAY = "activation"


def activation_lookup_table(n: int = 256) -> pv.LookupTable:
    """Grey → red lookup table over [0, 1]."""
    lut = pv.LookupTable()
    t = np.linspace(0.0, 1.0, n)[:, None] ** 0.6
    rgb = (1 - t) * np.array(REST_COLOR) + t * np.array(ACTIVE_COLOR)
    values = np.concatenate([rgb, np.ones((n, 1))], axis=1)
    lut.values = (values * 255).round().astype(np.uint8)
    lut.scalar_range = (0.0, 1.0)
    return lut


def _triangle_normals(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(k, 3) unit normals of triangles ``tris`` (k, 3) on positions ``x``."""
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


class MuscleView:
    """Muscles as draped lines on ``plotter`` (see the module docstring).

    Parameters
    ----------
    plotter : pyvista plotter (the window's ``QtInteractor``)
    skin_triangles : (m, 3) int
        Triangles of the skin the lines are draped on (``layer.model.triangles``).
    samples : int
        Points per segment (>= 2).
    lift_mm : float
        How far above the skin the lines run.
    line_width : float
        Screen pixels.
    name : str
        The actor's name on the plotter.
    """

    def __init__(self, plotter, skin_triangles: np.ndarray, *, samples: int = 12, lift_mm: float = 1.2,
                 line_width: float = 4.0, name: str = "muscles"):
        if samples < 2:
            raise ValueError(f"samples must be at least 2, got {samples}")
        self.plotter = plotter
        self.name = name
        self.samples = int(samples)
        self.lift_mm = float(lift_mm)
        self.triangles = np.asarray(skin_triangles, np.int64)
        self._t = np.linspace(0.0, 1.0, self.samples)[None, :, None]  # (1, s, 1)
        self._tri: np.ndarray | None = None  # (k*s,) skin triangle of every line point
        self._bary: np.ndarray | None = None  # (k*s, 3)
        self._sign: np.ndarray | None = None  # (k*s,) +1/-1: makes the skin normal point outward
        self._normals = None  # VertexNormals of the skin triangulation
        self._keys: list[tuple] = []
        self.mesh: pv.PolyData | None = None
        self.actor = None
        self._visible = False
        self._line_width = float(line_width)

    # ------------------------------------------------------------ queries
    @property
    def visible(self) -> bool:
        return self._visible

    @property
    def n_segments(self) -> int:
        return len(self._keys)

    @property
    def keys(self) -> list[tuple]:
        """(name, side) of every drawn segment (the orbicularis has several)."""
        return list(self._keys)

    @property
    def activations(self) -> np.ndarray | None:
        """(k,) the colour values shown (activation as a fraction of the maximum, 0..1)."""
        if self.mesh is None:
            return None
        return np.asarray(self.mesh.cell_data[ACTIVATION_ARRAY])

    @property
    def in_scene(self) -> bool:
        """True when the actor is in the plotter's renderer."""
        if self.actor is None:
            return False
        try:
            return self.name in self.plotter.renderer.actors
        except AttributeError:
            return False

    # ------------------------------------------------------------ geometry
    def _drape(self, P: np.ndarray, R: np.ndarray, skin: np.ndarray) -> None:
        """Fix every chord sample to a point of ``skin`` (triangle + barycentric).

        Each muscle's samples are projected along one direction, the mean skin normal at its two
        ends: a parallel projection of a straight chord onto a smooth surface is a smooth curve
        (the closest point jumps across folds such as the nasolabial one). Samples whose ray
        misses (the mouth opening) take the closest point."""
        from core.surface_query import TriangleSet

        k, s = len(P), self.samples
        chord = (P[:, None, :] + self._t * (R - P)[:, None, :]).reshape(-1, 3)
        surface = TriangleSet(skin, self.triangles)
        # Outward = away from a point well behind the face (the template's winding is not assumed).
        centre = skin.mean(axis=0) - np.array([0.0, 0.0, 0.8 * float(np.ptp(skin[:, 1]))])

        def outward(tri, pos):
            n = _triangle_normals(skin, self.triangles[tri])
            return n * np.where(np.einsum("ij,ij->i", n, pos - centre) < 0, -1.0, 1.0)[:, None]

        end_pos, end_tri, _ = surface.closest(np.concatenate([P, R]))
        end_n = outward(end_tri, end_pos)
        direction = end_n[:k] + end_n[k:]
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        dirs = np.repeat(direction, s, axis=0)
        length = float(np.max(np.linalg.norm(R - P, axis=1))) if k else 1.0
        pos, tri, bary, hit = surface.ray_nearest(chord, dirs, max_distance=0.5 * length, same_facing=False)
        if not hit.all():
            c_pos, c_tri, c_bary = surface.closest(chord[~hit])
            pos[~hit], tri[~hit], bary[~hit] = c_pos, c_tri, c_bary
        self._tri, self._bary = tri, bary
        from core.face import VertexNormals

        self._normals = VertexNormals(self.triangles, len(skin))
        n = np.einsum("pj,pjd->pd", bary, self._normals(skin)[self.triangles[tri]])
        self._sign = np.where(np.einsum("ij,ij->i", n, pos - centre) < 0, -1.0, 1.0)

    def _points(self, skin: np.ndarray) -> np.ndarray:
        corners = self.triangles[self._tri]  # (p, 3)
        pos = np.einsum("pj,pjd->pd", self._bary, skin[corners])
        if self._normals is None or self._normals.n_vertices != len(skin):
            from core.face import VertexNormals

            self._normals = VertexNormals(self.triangles, len(skin))
        vn = self._normals(skin)
        n = np.einsum("pj,pjd->pd", self._bary, vn[corners]) * self._sign[:, None]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        pts = (pos + self.lift_mm * n).reshape(-1, self.samples, 3)
        # One 1-2-1 pass along each line (ends kept): irons out the kinks of a crumpled skin.
        pts[:, 1:-1] = 0.25 * pts[:, :-2] + 0.5 * pts[:, 1:-1] + 0.25 * pts[:, 2:]
        return pts.reshape(-1, 3)

    def _build(self, keys: list[tuple], P: np.ndarray, R: np.ndarray, skin: np.ndarray) -> None:
        k, s = len(keys), self.samples
        self._keys = list(keys)
        self._drape(P, R, skin)
        lines = np.hstack([np.full((k, 1), s), np.arange(k * s).reshape(k, s)]).ravel()
        mesh = pv.PolyData(self._points(skin), lines=lines)
        mesh.cell_data[ACTIVATION_ARRAY] = np.zeros(k, dtype=np.float32)
        mapper = pv.DataSetMapper(mesh)
        mapper.lookup_table = activation_lookup_table()
        mapper.SetScalarModeToUseCellFieldData()
        mapper.SelectColorArray(ACTIVATION_ARRAY)
        mapper.color_mode = "map"
        mapper.SetUseLookupTableScalarRange(False)
        mapper.scalar_range = (0.0, 1.0)
        mapper.scalar_visibility = True
        actor = pv.Actor(mapper=mapper)
        prop = actor.prop
        prop.line_width = self._line_width
        prop.render_lines_as_tubes = True
        prop.ambient = 0.35
        prop.diffuse = 0.75
        prop.specular = 0.25
        prop.specular_power = 20.0
        was_visible = self._visible
        if self.actor is not None and was_visible:
            self._remove_actor()
        self.mesh, self.actor = mesh, actor
        if was_visible:
            self._add_actor()

    # ------------------------------------------------------------ updates
    def update(self, segments: Iterable[Sequence], skin: np.ndarray) -> None:
        """Show ``segments`` [(name, side, P (3,) mm, R (3,) mm, activation 0..1)] on ``skin``, in place.

        ``skin`` (N, 3) mm: the current simulated skin (vertices of ``skin_triangles``). The
        first call, or one with different muscles, builds the mesh and drapes it.
        """
        segments = list(segments)
        skin = np.asarray(skin, float)
        keys = [(s[0], s[1]) for s in segments]
        act = np.clip(np.array([float(s[4]) for s in segments]), 0.0, 1.0).astype(np.float32)
        if self.mesh is None or keys != self._keys:
            if not keys:
                self.remove()
                return
            P = np.array([s[2] for s in segments], dtype=float).reshape(-1, 3)
            R = np.array([s[3] for s in segments], dtype=float).reshape(-1, 3)
            self._build(keys, P, R, skin)
        else:
            self.mesh.points[:] = self._points(skin)
        self.mesh.cell_data[ACTIVATION_ARRAY][:] = act
        self.mesh.Modified()

    # ------------------------------------------------------------ visibility
    def _add_actor(self) -> None:
        self.plotter.add_actor(self.actor, reset_camera=False, name=self.name, render=False)

    def _remove_actor(self) -> None:
        try:
            self.plotter.remove_actor(self.actor, reset_camera=False, render=False)
        except (AttributeError, KeyError, ValueError):  # the plotter is already closed
            pass

    def set_visible(self, visible: bool) -> None:
        """Add (True) or remove (False) the muscles' actor; does not render."""
        visible = bool(visible)
        if visible == self._visible:
            return
        self._visible = visible
        if self.actor is None:
            return
        if visible:
            self._add_actor()
        else:
            self._remove_actor()

    def remove(self) -> None:
        """Take the muscles off the plotter and forget the geometry."""
        if self.actor is not None and self._visible:
            self._remove_actor()
        self.actor = None
        self.mesh = None
        self._keys = []
        self._tri = self._bary = self._sign = None


def layer_segments(layer) -> list[tuple]:
    """Every drawable segment of a ``MuscleLayer``: its linear muscles (``muscle_segments``) and
    the orbicularis ring (``muscle_ring``) cut into its consecutive chords (closed)."""
    segments = list(layer.muscle_segments())
    ring_fn = getattr(layer, "muscle_ring", None)
    if callable(ring_fn):
        from core.layers.muscles import control_keys

        ring, act = ring_fn()
        ring = np.asarray(ring, float)
        name, side = next(k for k in control_keys() if k[1] is None)
        for a, b in zip(ring, np.roll(ring, -1, axis=0)):
            segments.append((name, side, a, b, act))
    return segments


def draw_muscles(view: MuscleView, layer) -> None:
    """Update ``view`` from ``layer`` (segments, ring and the simulated skin)."""
    view.update(layer_segments(layer), layer.tissue_skin())


__all__ = ["MuscleView", "activation_lookup_table", "draw_muscles", "layer_segments", "ACTIVE_COLOR",
           "REST_COLOR"]
