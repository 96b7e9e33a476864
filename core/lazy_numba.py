"""Numba kernels compiled (or loaded from numba's disk cache) on first use, or in the background.

Importing numba and loading cached machine code costs ~0.3 s + ~0.5 s of mostly Python work the
first time in a process; a window that did it before showing the face, or before handing over the
rig, kept the user waiting for code the first frames do not need. :class:`LazyKernels` builds a
module's kernels on first use; after :func:`defer_until_warm` (the window calls it) they are built
only by an explicit ``load()`` (a background job once the face is animatable) and callers take their
numpy paths until then. ``MIMICA_NO_NUMBA=1`` or a missing numba: never built (numpy paths).
"""

from __future__ import annotations

import os
import threading
from types import SimpleNamespace
from typing import Callable

_deferred = False


def defer_until_warm() -> None:
    """From now on kernels are built only by ``LazyKernels.load()``, never on a caller's first use."""
    global _deferred
    _deferred = True


class LazyKernels:
    """The kernels ``build(numba) -> SimpleNamespace`` makes, built once per process (thread-safe)."""

    def __init__(self, build: Callable[[object], SimpleNamespace]):
        self._build = build
        self._lock = threading.Lock()
        self._kernels: SimpleNamespace | None = None
        self._tried = False

    def get(self) -> SimpleNamespace | None:
        """The kernels, or None: use numpy (no numba, disabled, deferred, or being built elsewhere)."""
        if self._tried:
            return self._kernels
        return None if _deferred else self.load()

    def load(self) -> SimpleNamespace | None:
        """Build the kernels now (once; later calls return them), or None without numba."""
        with self._lock:
            if not self._tried:
                try:
                    if not os.environ.get("MIMICA_NO_NUMBA"):
                        import numba

                        self._kernels = self._build(numba)
                except ImportError:  # pragma: no cover - numba is a dependency; the numpy paths still work
                    self._kernels = None
                finally:
                    self._tried = True
            return self._kernels


__all__ = ["LazyKernels", "defer_until_warm"]
