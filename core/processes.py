"""Whether a process still runs: for files named after their owner's pid (export staging files and
work folders, untitled autosaves), which only a dead owner's successor may clean up or take over."""

from __future__ import annotations

import os
from pathlib import Path


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (another user's process counts as alive)."""
    if pid <= 0:
        return False  # kill(0 or -n, 0) would ask about a whole process group
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists, but not ours to signal
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")  # a killed process its parent has not waited for yet


__all__ = ["process_alive"]
