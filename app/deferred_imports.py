"""Modules imported by our dependencies at start-up but used only later, loaded on first use.

pyvista imports ``matplotlib.pyplot`` when it is imported (``pyvista.plotting.colors`` and
``charts``) but calls it only for matplotlib charts and the colour cycler, which Mimica's window
never needs to show a face. Loading pyplot (and with it ``matplotlib.figure``) costs ~0.4 s of the
window's start-up on a 2-core machine; :func:`defer_module` puts a stand-in in ``sys.modules``
that imports the real module the first time one of its attributes is read, so everything that uses
it still works, only later.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
import threading
import types

_LOCK = threading.Lock()


class DeferredModule(types.ModuleType):
    """Stands in for a module in ``sys.modules`` until an attribute of it is read.

    ``import name`` finds the stand-in (its spec says it is not initialising, so the import system
    does not look inside it); the first missing attribute imports the real module, copies its
    namespace into this one (so names bound to the stand-in keep working, directly after that) and
    leaves the real module in ``sys.modules``.
    """

    def __getattr__(self, attr: str):
        if attr.startswith("__") and attr.endswith("__"):
            raise AttributeError(attr)   # introspection (copy, pickle, pydoc) does not load the module
        with _LOCK:
            if sys.modules.get(self.__name__) is self:
                del sys.modules[self.__name__]
            real = importlib.import_module(self.__name__)
            self.__dict__.update({k: v for k, v in vars(real).items() if k not in ("__spec__", "__loader__")})
        return getattr(real, attr)


def defer_module(name: str) -> bool:
    """Load module ``name`` on first use instead of when it is imported; False when it is already
    imported (nothing to defer) or cannot be found."""
    with _LOCK:
        if name in sys.modules:
            return False
        parent, _, _ = name.rpartition(".")
        try:
            found = importlib.util.find_spec(name) is not None   # imports the parent package only
        except (ImportError, ValueError):
            found = False
        if not found or name in sys.modules:
            return False
        stand_in = DeferredModule(name)
        stand_in.__spec__ = importlib.machinery.ModuleSpec(name, None)
        sys.modules[name] = stand_in
        if parent and parent in sys.modules:   # `import a.b as c` reads c from the parent package
            setattr(sys.modules[parent], name.rpartition(".")[2], stand_in)
        return True


def defer_pyplot() -> bool:
    """Defer ``matplotlib.pyplot`` (see the module docstring); call before ``pyvista.plotting`` is
    imported (False when pyplot is imported already)."""
    return defer_module("matplotlib.pyplot")
