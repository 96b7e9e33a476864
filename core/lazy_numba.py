"""Numba kernels compiled (or loaded from numba's disk cache) on first use, or in the background.

Importing numba and loading cached machine code costs ~0.3 s + ~0.5 s of mostly Python work the
first time in a process; a window that did it before showing the face, or before handing over the
rig, kept the user waiting for code the first frames do not need. :class:`LazyKernels` builds a
module's kernels on first use; after :func:`defer_until_warm` (the window calls it) they are built
only by an explicit ``load()`` (a background job once the face is animatable) and callers take their
numpy paths until then. ``MIMICA_NO_NUMBA=1`` or a missing numba: never built (numpy paths).

Numba's disk cache is a file like any other: a corrupt or foreign index made numba raise on load.
Then the module's cache files are deleted and the kernels built afresh, with a note on stderr;
should that fail too, the numpy paths are used.
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

_deferred = False


def defer_until_warm() -> None:
    """From now on kernels are built only by ``LazyKernels.load()``, never on a caller's first use."""
    global _deferred
    _deferred = True


def numba_cache_files(source: str | os.PathLike) -> list[Path]:
    """Numba's cache files (index ``.nbi`` and code ``.nbc``) of the kernels defined in ``source``:
    next to it in ``__pycache__``, and under ``NUMBA_CACHE_DIR`` when that is set."""
    source = Path(source)
    pattern = f"{source.stem}.*.nb[ic]"
    found = list((source.parent / "__pycache__").glob(pattern))
    if os.environ.get("NUMBA_CACHE_DIR"):
        found += Path(os.environ["NUMBA_CACHE_DIR"]).glob(f"**/{pattern}")
    return found


class LazyKernels:
    """The kernels ``build(numba) -> SimpleNamespace`` makes, built once per process (thread-safe);
    ``source`` is the file that defines them (its numba cache is cleared if unreadable)."""

    def __init__(self, build: Callable[[object], SimpleNamespace], source: str | os.PathLike):
        self._build = build
        self._source = source
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

                        self._kernels = self._build_or_repair(numba)
                except ImportError:  # pragma: no cover - numba is a dependency; the numpy paths still work
                    self._kernels = None
                finally:
                    self._tried = True
            return self._kernels

    def _build_or_repair(self, numba) -> SimpleNamespace | None:
        try:
            return self._build(numba)
        except Exception as exc:  # noqa: BLE001 - a damaged cache must not cost the feature
            name = Path(self._source).name
            removed = 0
            for path in numba_cache_files(self._source):
                try:
                    path.unlink()
                    removed += 1
                except OSError:
                    pass
            print(f"Mimica: numba's cache of {name} was unreadable ({type(exc).__name__}: {exc}); "
                  f"{removed} cache files removed, compiling afresh.", file=sys.stderr)
        try:
            return self._build(numba)
        except Exception as exc:  # noqa: BLE001
            print(f"Mimica: the compiled kernels of {name} are not available ({type(exc).__name__}: {exc}); "
                  "using the slower numpy code.", file=sys.stderr)
            return None


__all__ = ["LazyKernels", "defer_until_warm"]
