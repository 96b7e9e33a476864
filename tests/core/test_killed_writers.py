"""kill -9 at any moment of an autosave: the autosave on disk is always a whole project (the one
before or the one being written), and the staging files the killed writer left are swept by the
next writer (or at start-up), never a live writer's."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from core.formats import project as P
from core.formats.atomic_files import sweep_stale_staging, write_atomic

ROOT = Path(__file__).resolve().parents[2]

# A child that autosaves a ~1 MB project (15,000 keys) in a loop, each one with a new duration; it
# says "ready" once the first is on disk, and "staged" whenever a staging file is complete and about
# to be renamed (it then waits 0.2 s there, so a kill can land between staging and rename).
WRITER = textwrap.dedent("""
    import sys, time
    from core.formats import atomic_files
    real_replace = atomic_files.os.replace
    def slow_replace(src, dst):
        print("staged", flush=True)
        time.sleep(0.2)
        real_replace(src, dst)
    atomic_files.os.replace = slow_replace
    from core.formats import project as P
    from core.timeline import Timeline, Track
    state = sys.argv[1]
    times = [i * 0.01 for i in range(5000)]
    for n in range(1, 10**6):
        tl = Timeline(200.0 + n, 30)
        tl.replace_tracks({f"fap:{k}": Track(f"fap:{k}", [(t, float(i % 100)) for i, t in enumerate(times)])
                           for k in (3, 4, 5)})
        P.write_autosave(P.Project(timeline=tl), state_dir=state)
        if n == 1:
            print("ready", flush=True)
""")


def test_an_autosave_killed_at_any_moment_leaves_a_whole_project_and_nothing_else(tmp_path):
    state = tmp_path / "state"
    rng = np.random.default_rng(7)
    durations, left = set(), 0
    for i, delay in enumerate(rng.uniform(0.0, 0.5, size=4)):
        child = subprocess.Popen([sys.executable, "-c", WRITER, str(state)], cwd=ROOT,
                                 stdout=subprocess.PIPE, text=True)
        try:
            while child.stdout.readline().strip() != "ready":
                pass
            if i == 0:   # once for sure: between a complete staging file and its rename
                assert child.stdout.readline().strip() == "staged"
            else:        # then at random moments
                time.sleep(float(delay))
        finally:
            os.kill(child.pid, signal.SIGKILL)
            child.wait(10)
        autosave = P.autosave_path(state_dir=state)
        durations.add(P.load_project(autosave).timeline.duration)   # loads: never half written
        leftovers = [p for p in state.iterdir() if p != autosave]
        left += bool(leftovers)
        assert set(sweep_stale_staging(state)) == set(leftovers), "only the dead writer's staging files"
        assert list(state.iterdir()) == [autosave]
    assert durations and all(d > 200.0 for d in durations)
    assert left >= 1, "a kill between staging and rename left its staging file for the sweep"


def test_a_live_writers_staging_files_are_kept(tmp_path):
    mine = tmp_path / f".take.mimica.{os.getpid()}.0123abcd.tmp"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    theirs = tmp_path / f".take.mimica.{dead.pid}.89abcdef.tmp"
    unrelated = tmp_path / ".take.mimica.notes.tmp"
    for p in (mine, theirs, unrelated):
        p.write_bytes(b"partial")
    write_atomic(tmp_path / "take.mimica", b"{}")   # a writer sweeps its folder first
    assert mine.exists() and unrelated.exists() and not theirs.exists()
    assert (tmp_path / "take.mimica").read_bytes() == b"{}"
