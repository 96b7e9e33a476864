"""Modules imported by our dependencies at start-up but used only later, loaded on first use.

pyvista imports ``matplotlib.pyplot`` and ``matplotlib.backends.backend_agg`` (``pyvista.plotting.
colors`` and ``charts``) but uses them only for matplotlib charts and the colour cycler, which
Mimica's window never needs to show a face, and ``pooch`` only to download files; scipy imports
``numpy.f2py`` and ``numpy.testing`` (its array-API layer reads every attribute of numpy);
pyvistaqt imports ``qtpy.QtCore``/``QtGui``/``QtWidgets``, whose ``from PySide6.QtX import *``
makes PySide create every class of the module (PySide creates them on first use otherwise).
Together ~0.8 s of the window's start-up on a 2-core machine. :func:`defer_module` puts a stand-in
in ``sys.modules`` that imports the real module the first time one of its attributes is read, so
everything that uses it still works, only later. :func:`prepare_startup_imports` does all of it.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
import threading
import types

_LOCK = threading.RLock()   # re-entrant: loading one deferred module may load another


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
        return getattr(self.load(), attr)

    def load(self) -> types.ModuleType:
        """Import the real module (once) and take over its namespace; returns the real module."""
        with _LOCK:
            if sys.modules.get(self.__name__) is self:
                del sys.modules[self.__name__]
            real = importlib.import_module(self.__name__)
            self.__dict__.update({k: v for k, v in vars(real).items() if k not in ("__spec__", "__loader__")})
        return real


def _class_loaded_on_call(stand_in: DeferredModule, name: str) -> type:
    """A stand-in for class ``name`` of a deferred module, for a ``from module import name`` at
    import time: calling it loads the module and returns an instance of the real class."""

    def new(_cls, *args, **kwargs):
        return getattr(stand_in.load(), name)(*args, **kwargs)

    return type(name, (), {"__new__": new, "__module__": stand_in.__name__,
                           "__doc__": f"Loads {stand_in.__name__} and makes a real {name} when called."})


def defer_module(name: str, classes: tuple[str, ...] = ()) -> bool:
    """Load module ``name`` on first use instead of when it is imported; False when it is already
    imported (nothing to defer) or cannot be found. ``classes``: classes that importers take with
    ``from name import cls`` but only call later (see :func:`_class_loaded_on_call`)."""
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
        for cls in classes:
            setattr(stand_in, cls, _class_loaded_on_call(stand_in, cls))
        sys.modules[name] = stand_in
        if parent and parent in sys.modules:   # `import a.b as c` reads c from the parent package
            setattr(sys.modules[parent], name.rpartition(".")[2], stand_in)
        return True


class QtpyFromPySide(DeferredModule):
    """Stands in for ``qtpy.<module>`` when qtpy wraps PySide6: a name is read from the PySide6
    modules in ``sources`` (the first that has it); only a name none of them has (a qtpy addition)
    loads the real qtpy module. The objects are the same ones qtpy would give: on PySide6, qtpy's
    modules re-export PySide6's classes (patching a few methods Mimica and pyvistaqt do not call)."""

    sources: tuple[str, ...] = ()

    def __getattr__(self, attr: str):
        if attr.startswith("__") and attr.endswith("__"):
            raise AttributeError(attr)
        for source in self.sources:
            module = importlib.import_module(source)
            if hasattr(module, attr):
                value = getattr(module, attr)
                setattr(self, attr, value)
                return value
        return getattr(self.load(), attr)


# qtpy module -> the PySide6 modules its names come from (Qt 6 moved QAction and friends to QtGui).
_QTPY_SOURCES = {
    "qtpy.QtCore": ("PySide6.QtCore",),
    "qtpy.QtGui": ("PySide6.QtGui",),
    "qtpy.QtWidgets": ("PySide6.QtWidgets", "PySide6.QtGui"),
    "qtpy.QtOpenGLWidgets": ("PySide6.QtOpenGLWidgets",),
}


def shortcut_qtpy() -> bool:
    """Put :class:`QtpyFromPySide` stand-ins for qtpy's Qt modules in ``sys.modules`` (False when
    qtpy is missing, wraps another binding, or its modules are imported already)."""
    with _LOCK:
        try:
            import qtpy
        except ImportError:
            return False
        if getattr(qtpy, "API_NAME", "") != "PySide6" or any(name in sys.modules for name in _QTPY_SOURCES):
            return False
        for name, sources in _QTPY_SOURCES.items():
            stand_in = QtpyFromPySide(name)
            stand_in.sources = sources
            stand_in.__spec__ = importlib.machinery.ModuleSpec(name, None)
            sys.modules[name] = stand_in
            setattr(qtpy, name.rpartition(".")[2], stand_in)
        return True


def defer_pyplot() -> bool:
    """Defer ``matplotlib.pyplot`` (see the module docstring); call before ``pyvista.plotting`` is
    imported (False when pyplot is imported already)."""
    return defer_module("matplotlib.pyplot")


def prepare_startup_imports() -> None:
    """Defer every module of the module docstring, then import what the window does need that does
    not need Qt (:func:`import_before_qt`); call before scipy, pyvista and PySide6 are imported."""
    defer_module("numpy.f2py")
    defer_module("numpy.testing")
    defer_pyplot()
    # pyvista.plotting.charts: ``from matplotlib.backends.backend_agg import FigureCanvasAgg``,
    # called only when a matplotlib chart is made.
    defer_module("matplotlib.backends.backend_agg", classes=("FigureCanvasAgg",))
    defer_module("pooch")   # pyvista's reader registry: downloads of URLs only
    import_before_qt()
    shortcut_qtpy()   # imports PySide6.QtCore


def import_before_qt() -> None:
    """Import numpy, scipy.sparse and pyvista (without its Qt part) now, before PySide6.QtCore if it
    is not imported yet: from then on every import runs PySide's ``__feature__`` hook, which reads
    the new module's source to see whether it uses PySide (~0.2 ms a module, ~0.15 s for these)."""
    import numpy  # noqa: F401
    import pyvista.plotting  # noqa: F401
    import scipy.sparse  # noqa: F401
