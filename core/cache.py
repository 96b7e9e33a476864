"""A disk cache for what Mimica derives from a face and that does not change between runs.

Building the FAP table of the 54k-vertex default face takes seconds (densifying the template and
binding every skin vertex by closest-point queries); the same face gives the same table, so it is
stored once under the user's cache folder and read back in milliseconds on the next start.

An entry's key is a fingerprint of everything it was derived from (the face's arrays, its
landmarks, the template file) *and* of the source files of the code that derived it, so editing
that code makes old entries unreachable instead of wrong. The folder is safe to delete at any time.
A damaged or unreadable entry is deleted and rebuilt with a note (``DiskCache.notes``), never an
error; a folder that cannot be written only costs the speed-up.

Entries are Python pickles: the cache folder is the user's own (like ``~/.cache`` of any program),
never a file a user opens or shares.

Folder: ``$MIMICA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mimica``, else ``~/.cache/mimica``.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import tempfile
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

CACHE_ENV = "MIMICA_CACHE_DIR"
FORMAT_VERSION = 1  # bump when the layout of the cache folder itself changes

T = TypeVar("T")


#: How the notes name each kind of entry (other kinds: "<kind> data").
_PLAIN_KINDS = {"fap": "face's FAP table", "preview": "face's preview mesh",
                "closed_eye_raster": "closed-eye reference", "export-lod": "export's level of detail"}


def cache_dir() -> Path:
    """The user's Mimica cache folder (not created here)."""
    explicit = os.environ.get(CACHE_ENV)
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mimica"


def fingerprint(*parts) -> str:
    """A hex SHA-256 over arrays (dtype, shape and bytes), strings, bytes, numbers, and nested
    tuples/lists/dicts of them (dicts in key order). Equal inputs give equal fingerprints."""
    h = hashlib.sha256()
    _feed(h, parts)
    return h.hexdigest()


def _feed(h, part) -> None:
    if isinstance(part, np.ndarray):
        a = np.ascontiguousarray(part)
        h.update(f"a{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(part, (bytes, bytearray)):
        h.update(b"b%d:" % len(part))
        h.update(part)
    elif isinstance(part, str):
        _feed(h, part.encode())
    elif isinstance(part, dict):
        h.update(b"d%d" % len(part))
        for key in sorted(part, key=str):
            _feed(h, str(key))
            _feed(h, part[key])
    elif isinstance(part, (tuple, list)):
        h.update(b"t%d" % len(part))
        for item in part:
            _feed(h, item)
    elif part is None or isinstance(part, (bool, int, float)):
        _feed(h, repr(part))
    else:
        raise TypeError(f"cannot fingerprint a {type(part).__name__}")


def source_version(*modules) -> str:
    """Fingerprint of the source files of ``modules`` (module objects): the code's data version."""
    return fingerprint(FORMAT_VERSION, *[Path(m.__file__).read_bytes() for m in modules])


class DiskCache:
    """Pickled objects under ``root/<kind>/<key>.pkl``.

    ``root=None`` uses :func:`cache_dir`; ``enabled=False`` stores and finds nothing (every
    ``get_or_build`` builds). ``notes`` collects what the user should be told (damaged entries
    removed, a folder that cannot be written).
    """

    def __init__(self, root: str | os.PathLike | None = None, *, enabled: bool = True):
        self.root = Path(root) if root is not None else cache_dir()
        self.enabled = enabled
        self.notes: list[str] = []

    def path(self, kind: str, key: str) -> Path:
        return self.root / kind / f"{key}.pkl"

    def get(self, kind: str, key: str):
        """The stored object, or None if missing, disabled, or damaged (then deleted, with a note)."""
        if not self.enabled:
            return None
        path = self.path(kind, key)
        try:
            with open(path, "rb") as f:
                return pickle.load(f)
        except (FileNotFoundError, NotADirectoryError):
            return None
        except Exception as exc:  # noqa: BLE001 - any damage means "rebuild", never a crash
            # (The window shows notes that name the cache in its status bar: app/face_files.py.)
            self.notes.append(f"Mimica's cache of the {_PLAIN_KINDS.get(kind, kind + ' data')} could not be "
                              f"read (damaged or cut short); it was deleted and is being rebuilt — nothing "
                              f"of yours is lost ({type(exc).__name__}).")
            try:
                path.unlink()
            except OSError:
                pass
            return None

    def put(self, kind: str, key: str, obj) -> bool:
        """Store ``obj`` atomically (a reader never sees half a file); False (with a note) if the
        folder cannot be written."""
        if not self.enabled:
            return False
        path = self.path(kind, key)
        tmp = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{key[:12]}.", suffix=".tmp")
            with os.fdopen(fd, "wb") as f:
                pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
            return True
        except Exception as exc:  # noqa: BLE001 - a cache that cannot be written only costs speed
            self.notes.append(f"Could not write Mimica's cache in {path.parent} ({exc}); start-up will "
                              f"not be faster next time. Set {CACHE_ENV} to a writable folder.")
            if tmp is not None:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
            return False

    def get_or_build(self, kind: str, key: str, build: Callable[[], T]) -> T:
        """The cached object for ``key``, else ``build()`` stored under it."""
        found = self.get(kind, key)
        if found is not None:
            return found
        obj = build()
        self.put(kind, key, obj)
        return obj


__all__ = ["CACHE_ENV", "DiskCache", "cache_dir", "fingerprint", "source_version"]
