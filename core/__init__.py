"""Mimica core: face data, I/O and every solver. Never imports Qt, PyVista or VTK."""
