"""Compiled kernels of the FAP layer's per-tick steps (numba), numpy otherwise.

A FAP slider tick on the 58,907-vertex default face spent ~2 ms of its ~3 ms in its finish steps:
numpy calls on a few thousand vertices each (per-call overhead, temporaries and fancy indexing, not
arithmetic). These loops (in :mod:`core.layers.fap.compiled_steps`) do the same sums in one pass each:

- :func:`add_active_columns`: ``x += F @ v`` in place, reading only the FAT columns of non-zero
  FAPs (scipy's product allocates a (3n,) result and reads every column: 0.55 ms vs 0.40 with all
  68 columns active, a few microseconds with one);
- :func:`lip_overlap`, :func:`lip_sheet_overlap`, :func:`lip_sheet_spread`: the lip contact's overlap
  tests and its sheets' give-way (``lip_contact.LipContact``);
- :func:`close_lids_over_eyeball`: the lid guard (``FapDeformer._close_lids``) of one eye;
- :func:`push_out_of_row` and :func:`spread_pushes`: the teeth guard (``teeth_guard.TeethGuard``);
- :func:`rotate_rows`: an eyeball's gaze rotation;
- :func:`strain_severity`, :func:`guard_smooth`: the surface guard's check of every skin triangle and
  its smoothing where they would break (``surface_guard``);
- :func:`rows_equal`, :func:`put_rows`: the step memos' compare and replay.

Built lazily (:mod:`core.lazy_numba`; ``cache=True`` keeps the machine code under ``__pycache__``,
and the kernels are module-level functions there because numba's cache missed every time for
closures that call one another):
:func:`get` gives them, or None without numba, with ``MIMICA_NO_NUMBA=1`` or while deferred, and
the callers then keep their numpy paths (the tests compare both).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from core.lazy_numba import LazyKernels


def _build(numba) -> SimpleNamespace:
    """The kernels of :mod:`core.layers.fap.compiled_steps` (numba is imported there), warmed."""
    from core.layers.fap import compiled_steps as c

    kernels = SimpleNamespace(**{name: getattr(c, name) for name in _NAMES})
    _warm(kernels)
    return kernels


def _warm(k: SimpleNamespace) -> None:
    """Compile (or load from numba's disk cache) every kernel for the argument types the FAP layer
    passes, on a tiny problem."""
    x = np.zeros((3, 3))
    rows = np.arange(3, dtype=np.int64)
    k.add_active_columns(x.ravel(), np.array([0, 3, 3], np.int64), rows, np.ones(3), np.array([1.0, 0.0]))
    k.lip_overlap(x, rows, rows, 3.0, np.empty(3))
    rest = x.copy()
    rest.setflags(write=False)         # a face's rest vertices (the contact's rest overlap)
    k.lip_overlap(rest, rows, rows, 3.0, np.empty(3))
    k.lip_sheet_overlap(x, rows, rows, 0.0, 0.0, 1.0, 2, 2, np.empty(3), np.empty(3))
    k.lip_sheet_overlap(rest, rows, rows, 0.0, 0.0, 1.0, 2, 2, np.empty(3), np.empty(3))
    k.lip_sheet_spread(np.array([0, 1, 2, 3], np.int64), rows, np.ones(3), np.ones(3), 0.05, np.empty(3))
    k.close_lids_over_eyeball(x, rows, x.copy(), np.zeros(3), np.zeros(3), np.zeros(3), np.ones(3), 0.5, 2.0, 0.1,
                              np.ones((3, 3)), 1.0, 1.0, 1.0, 1.0, 1.5)
    k.push_out_of_row(x, rows, x.copy(), np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3), True, np.zeros(3),
                      -1.0, 2.0, 180, 4, 1.0, 1.0, np.zeros(720), 1.0, True, np.zeros(3, np.int64), np.zeros((3, 3)))
    k.spread_pushes(x, rows, rows, np.zeros((3, 3)), np.arange(4, dtype=np.int64), rows, np.ones(3))
    k.strain_severity(x, rest, rows.reshape(1, 3), np.ones((1, 3)), np.ones((1, 3)), np.ones(1, bool),
                      1.7, 1.95, 0.32, 0.26, 0.3, 0.05, np.zeros((0, 3)), rest[:0, 0], np.empty(1))
    ring = np.array([0, 2, 4, 6], np.int64)                   # a triangle's CSR neighbours
    k.guard_smooth(x, rest, ring, np.array([1, 2, 0, 2, 0, 1], np.int64), np.ones(6), np.zeros(3, bool), np.ones(3),
                   np.array([1.0, 0.0, 0.0]), 1, 1)
    eyeball = rows.copy()
    eyeball.setflags(write=False)      # as a face's parts are: a type of its own to numba
    k.rotate_rows(x, eyeball, np.zeros(3), np.eye(3), np.zeros(3))
    k.rows_equal(x, rows, x.copy())
    k.put_rows(x, rows, x.copy())


_NAMES = ("add_active_columns", "lip_overlap", "lip_sheet_overlap", "lip_sheet_spread", "close_lids_over_eyeball",
          "push_out_of_row", "spread_pushes",
          "rotate_rows", "rows_equal", "put_rows", "strain_severity", "guard_smooth")
_KERNELS = LazyKernels(_build, Path(__file__).with_name("compiled_steps.py"))


def get() -> SimpleNamespace | None:
    """The compiled kernels (attributes named as in ``_NAMES``), or None: take the numpy path."""
    return _KERNELS.get()


def warm_up() -> None:
    """Build the kernels now (e.g. on a background thread), so the first slider tick does not pay."""
    _KERNELS.load()


__all__ = ["get", "warm_up"]
