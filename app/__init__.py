"""Mimica desktop application (PySide6 + pyvistaqt) over the ``core`` package."""

__version__ = "0.1.0"
