"""Window benchmarks need a display: without one, run the calling script again under Xvfb."""

import os
import shutil
import subprocess
import sys


def rerun_under_xvfb_without_display() -> None:
    """Exit with the result of this script run under ``xvfb-run`` when there is no display (returns
    when there is one, or in that child)."""
    if os.environ.get("DISPLAY") or os.environ.get("MIMICA_BENCH_CHILD"):
        return
    if shutil.which("xvfb-run") is None:
        sys.exit("No display and no xvfb-run: run ./scripts/test.sh once (it installs Xvfb), or set DISPLAY.")
    env = dict(os.environ, MIMICA_BENCH_CHILD="1")
    sys.exit(subprocess.call(["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24", sys.executable, *sys.argv], env=env))


def pump_events(app, seconds: float, until=None) -> bool:
    """Process Qt events for ``seconds`` or until ``until()`` is true; returns whether it came true
    (True when there is no condition)."""
    import time

    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        app.processEvents()
        if until is not None and until():
            return True
        time.sleep(0.001)
    return until() if until is not None else True
