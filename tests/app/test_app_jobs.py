"""The window's one background-job class (app.jobs): results, user-facing errors, progress, the
generation counter (a newer job supersedes), cancellation and the ``cancelled`` notice."""

from __future__ import annotations

import threading

import pytest


@pytest.fixture
def runner(qapp):
    from app.jobs import JobRunner

    r = JobRunner()
    yield r
    r.cancel()
    assert r.wait(5000)
    r.deleteLater()


def test_result_progress_and_generation(qtbot, runner):
    got, progress = [], []

    def work(job):
        job.progress(0.5, "half")
        job.progress(None, "a message alone")
        return 42

    first = runner.start(work, got.append, progress=lambda f, m: progress.append((f, m)))
    qtbot.waitUntil(lambda: got == [42], timeout=5000)
    assert progress == [(0.5, "half"), (None, "a message alone")]
    assert runner.generation == first and not runner.busy
    assert runner.start(work, got.append) == first + 1


def test_errors_become_messages(qtbot, runner, capsys):
    class LoaderError(Exception):
        pass

    from app.jobs import JobRunner

    failures = []
    runner.start(lambda job: (_ for _ in ()).throw(ValueError("the scan has no faces")), None, failures.append)
    qtbot.waitUntil(lambda: len(failures) == 1, timeout=5000)
    assert failures[0] == "the scan has no faces"
    runner.start(lambda job: 1 / 0, None, failures.append)
    qtbot.waitUntil(lambda: len(failures) == 2, timeout=5000)
    assert failures[1].startswith("Unexpected error: ZeroDivisionError")
    assert "Traceback" in capsys.readouterr().err   # a bug keeps its traceback for the log
    loads = JobRunner(user_errors=(LoaderError,))
    loads.start(lambda job: (_ for _ in ()).throw(LoaderError("missing texture")), None, failures.append)
    qtbot.waitUntil(lambda: len(failures) == 3, timeout=5000)
    assert failures[2] == "missing texture"
    loads.wait(5000)


def test_a_newer_job_supersedes_the_older_one(qtbot, qapp):
    from app.jobs import JobRunner

    loads = JobRunner(supersede=True, threads=2)
    release = threading.Event()
    got = []

    def slow(job):
        release.wait(5)
        return "old"

    old = loads.start(slow, got.append)
    new = loads.start(lambda job: "new", got.append)
    assert new == old + 1 and not loads.is_current(old) and loads.is_current(new)
    qtbot.waitUntil(lambda: got == ["new"], timeout=5000)
    release.set()
    assert loads.wait(5000)
    qtbot.wait(50)
    assert got == ["new"]   # the superseded load's result never arrives


def test_cancel_stops_the_work_and_says_when_it_has_stopped(qtbot, runner, capsys):
    started, stopped, delivered = threading.Event(), [], []

    def work(job):
        started.set()
        while not job.cancelled():
            job.progress(0.1, "working")
            threading.Event().wait(0.01)
        raise RuntimeError("broken off")   # cancelling may break the work: no message, no traceback

    runner.start(work, delivered.append, delivered.append, cancelled=stopped.append)
    assert started.wait(5) and runner.busy
    runner.cancel()
    assert not runner.busy
    qtbot.waitUntil(lambda: stopped == [None], timeout=5000)
    assert delivered == [] and "Traceback" not in capsys.readouterr().err


def test_a_cancel_that_comes_too_late_hands_over_the_result(qtbot, runner):
    """The work ran to its end although it was cancelled (an export's file is written): ``cancelled``
    gets the result, ``done`` is not called."""
    started, proceed, stopped, delivered = threading.Event(), threading.Event(), [], []

    def work(job):
        started.set()
        proceed.wait(5)
        return "written"

    runner.start(work, delivered.append, cancelled=stopped.append)
    assert started.wait(5)
    runner.cancel()
    proceed.set()
    qtbot.waitUntil(lambda: stopped == ["written"], timeout=5000)
    assert delivered == []


def test_a_job_cancelled_before_it_starts_never_runs(qtbot, runner):
    release, ran, stopped = threading.Event(), [], []
    runner.start(lambda job: release.wait(5), lambda _r: None)        # occupies the only thread
    runner.start(lambda job: ran.append(True), lambda _r: None, cancelled=stopped.append)
    runner.cancel()
    release.set()
    qtbot.waitUntil(lambda: stopped == [None], timeout=5000)
    assert ran == []
