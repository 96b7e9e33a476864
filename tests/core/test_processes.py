"""core.processes: is the owner of a pid-named file still running?"""

from __future__ import annotations


def test_process_alive_tells_running_from_gone_processes():
    import os
    import subprocess
    import sys

    from core.processes import process_alive

    assert process_alive(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    assert not process_alive(child.pid), "a reaped child is gone"
    assert not process_alive(0) and not process_alive(-1), "never a process group"
