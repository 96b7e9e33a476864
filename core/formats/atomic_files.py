"""Files written whole or not at all, and the leftovers of writers that were killed.

Every write goes to a staging file beside its target, named ``.<target name>.<pid>.<random>.tmp``,
and is renamed over the target when complete; a set of files (a mesh with its ``.mtl`` and texture)
is committed together, the previous files kept as ``.<name>.<pid>.<random>.bak`` hard links until
all are in place. A process killed mid-write (kill -9, power loss) leaves such files behind but
never a half-written target; :func:`sweep_stale_staging` removes those whose writer is gone (the
pid in the name), so a successor cleans up after a crash without touching a live writer's files.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path
from typing import Mapping

from core.processes import process_alive

__all__ = ["write_atomic", "write_set_atomic", "write_reporting_errors", "sweep_stale_staging"]

_STAGING = re.compile(r"^\..+\.(\d+)\.[0-9a-f]{8}\.(tmp|bak)$")


def _side_name(path: Path, kind: str) -> Path:
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.{kind}"


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a staging file beside ``path``, then rename it over ``path``
    (the one-file case of :func:`write_set_atomic`)."""
    write_set_atomic({Path(path): data})


def write_set_atomic(files: Mapping[Path, bytes]) -> None:
    """Write several files as one set (a mesh and its ``.mtl`` and texture): all or nothing.

    Every file is staged beside its target first; only when all are staged are they moved into
    place, companions first and the first file given (the mesh, which names them) last. If a move
    fails, the files already replaced get their previous contents back and no staging file stays.
    Staging files of dead writers in the target folders are swept first (:func:`sweep_stale_staging`).
    Through a symbolic link the link's target is written (the link stays a link).
    """
    for folder in {Path(p).parent for p in files}:
        sweep_stale_staging(folder)   # what a killed writer left here before
    staged: list[tuple[Path, Path]] = []
    moved: list[tuple[Path, Path | None]] = []      # (target, its backup or None when it was new)
    try:
        for path, data in files.items():
            path = Path(os.path.realpath(path)) if Path(path).is_symlink() else Path(path)
            mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
            tmp = _side_name(path, "tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            staged.append((path, tmp))
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.chmod(tmp, mode)
        for path, tmp in [*staged[1:], *staged[:1]]:
            backup = None
            if len(staged) > 1 and path.exists():
                backup = _side_name(path, "bak")
                os.link(path, backup)   # the previous contents, kept until the whole set is in place
            moved.append((path, backup))
            os.replace(tmp, path)
    except BaseException:
        for path, backup in reversed(moved):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, path)
                    if backup.exists():
                        backup.unlink()   # rename() does nothing when both names are one file (never replaced)
                elif len(staged) > 1:
                    path.unlink()   # it did not exist before this save
        for _, tmp in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise
    for _, backup in moved:
        if backup is not None:
            with contextlib.suppress(OSError):
                backup.unlink()


def sweep_stale_staging(folder) -> list[Path]:
    """Remove the staging and backup files in ``folder`` left by writers that are no longer running;
    returns what was removed. A live process's files (its pid in the name) are kept."""
    removed = []
    with contextlib.suppress(OSError):
        for entry in Path(folder).iterdir():
            match = _STAGING.match(entry.name)
            if match and entry.is_file() and not process_alive(int(match.group(1))):
                with contextlib.suppress(OSError):
                    entry.unlink()
                    removed.append(entry)
    return removed


def write_reporting_errors(path: Path, write, error_type: type[Exception]) -> None:
    """Run ``write()`` for ``path``, turning file-system failures into ``error_type`` with a user-facing message."""
    if not path.parent.is_dir():
        raise error_type(f"Cannot save '{path.name}': the folder '{path.parent}' does not exist.")
    try:
        write()
    except PermissionError:
        raise error_type(
            f"Mimica is not allowed to write in '{path.parent}'. Choose another folder or check its permissions."
        ) from None
    except OSError as exc:
        raise error_type(f"Could not save '{path}': {exc.strerror or exc}.") from None
