"""Batches of scans for ``mimica landmarks|register FOLDER``: local worker processes or a Dask
cluster, a progress bar, a per-scan summary CSV, resume, and failures that never stop the batch.

A batch command describes one scan's work as a module-level function ``work(path, options) ->
ScanResult`` (so it can run in another process or on another machine: ``options`` is a plain,
picklable namespace) and the file it writes per scan (``output``). :func:`run_batch` then

- skips scans whose output exists when ``--resume`` is given (a batch stopped half way goes on),
- runs the rest here (``--workers 1``), in ``--workers N`` local processes, or on the Dask
  distributed scheduler at ``--scheduler ADDRESS`` (``tcp://host:8786``; needs ``dask[distributed]``,
  the ``cluster`` extra), in every case reporting each scan as it finishes,
- turns any failure of one scan (a bad file, an exception, a worker that died) into a "failed" row
  with its message, and goes on,
- writes ``summary.csv`` in the output folder: scan, status (ok / failed / skipped), seconds,
  scan confidence, low-confidence points, message — rewritten after every scan, so it is
  complete up to the moment a batch is interrupted.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import io
import multiprocessing
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from app.cli.common import CliError

__all__ = ["ScanResult", "BatchRow", "run_batch", "add_batch_options", "SUMMARY_NAME"]

SUMMARY_NAME = "summary.csv"
SUMMARY_FIELDS = ("scan", "status", "seconds", "scan_confidence", "low_confidence", "message")


@dataclass(frozen=True)
class ScanResult:
    """What one scan's work reports: a one-line ``summary`` for the terminal, and for the summary CSV
    its scan confidence (0..1, None when it has none) and number of low-confidence points."""

    summary: str
    scan_confidence: float | None = None
    low_confidence: int | None = None


@dataclass
class BatchRow:
    """One line of the summary CSV."""

    scan: str
    status: str                     # "ok", "failed" or "skipped"
    seconds: float = 0.0
    scan_confidence: float | None = None
    low_confidence: int | None = None
    message: str = ""
    notes: tuple[str, ...] = ()     # what the scan's work printed (a worker's output, shown after its line)

    def as_csv(self) -> dict:
        conf = "" if self.scan_confidence is None else f"{self.scan_confidence:.3f}"
        low = "" if self.low_confidence is None else str(self.low_confidence)
        return {"scan": self.scan, "status": self.status, "seconds": f"{self.seconds:.2f}",
                "scan_confidence": conf, "low_confidence": low, "message": self.message}


def add_batch_options(p: argparse.ArgumentParser) -> None:
    """``--workers``, ``--scheduler`` and ``--resume`` (they matter for a folder of scans)."""
    p.add_argument("--workers", type=_worker_count, default=1, metavar="N",
                   help="scans processed at once in local processes (default 1; 0 = one per CPU core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the scans on the Dask distributed cluster at ADDRESS (e.g. tcp://host:8786); "
                        "needs 'pip install dask[distributed]'")
    p.add_argument("--resume", action="store_true",
                   help="skip scans whose output already exists (go on with a batch that was stopped)")


def _worker_count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of workers, got {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"the number of workers cannot be negative, got {n}")
    return n or (os.cpu_count() or 1)


# ------------------------------------------------------------------ one scan, wherever it runs
def run_one(work: Callable, path: Path, options) -> BatchRow:
    """``work(path, options)`` as a summary row: never raises (a failure is a "failed" row)."""
    start = time.perf_counter()
    try:
        result = work(path, options)
    except CliError as exc:
        return BatchRow(path.name, "failed", time.perf_counter() - start, message=str(exc))
    except MemoryError:
        return BatchRow(path.name, "failed", time.perf_counter() - start, message="not enough memory for this scan")
    except Exception as exc:   # noqa: BLE001 - one broken scan must not stop the batch; say what it was
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return BatchRow(path.name, "failed", time.perf_counter() - start,
                        message=f"unexpected {type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})")
    return BatchRow(path.name, "ok", time.perf_counter() - start, result.scan_confidence, result.low_confidence,
                    result.summary)


def _run_in_worker(work: Callable, path: Path, options) -> BatchRow:
    # Worker output (per-scan notes) would interleave with the progress bar: keep it in the row.
    out, err = io.StringIO(), io.StringIO()
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = out, err
    try:
        row = run_one(work, path, options)
    finally:
        sys.stdout, sys.stderr = stdout, stderr
    row.notes = tuple(line.rstrip() for line in (out.getvalue() + err.getvalue()).splitlines() if line.strip())
    return row


# ------------------------------------------------------------------ executors
def _serial(work, paths, options) -> Iterator[BatchRow]:
    for path in paths:
        yield run_one(work, path, options)


def _local_pool(work, paths, options, workers: int) -> Iterator[BatchRow]:
    # spawn: a forked child would inherit Qt/VTK state of a parent that has any.
    context = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=min(workers, len(paths)), mp_context=context) as pool:
        futures = {pool.submit(_run_in_worker, work, path, options): path for path in paths}
        for future in cf.as_completed(futures):
            yield _row_of(future, futures[future])


def _dask(work, paths, options, address: str) -> Iterator[BatchRow]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise CliError("--scheduler needs Dask: pip install 'dask[distributed]' (the 'cluster' extra)") from None
    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise CliError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    try:
        futures = {client.submit(_run_in_worker, work, path, options, key=f"mimica-{path.name}-{time.time_ns()}",
                                 pure=False): path for path in paths}
        for future in as_completed(futures):
            yield _row_of(future, futures[future])
    finally:
        client.close()


def _row_of(future, path: Path) -> BatchRow:
    try:
        return future.result()
    except Exception as exc:   # noqa: BLE001 - the worker process died (killed, out of memory)
        return BatchRow(path.name, "failed", message=f"its worker stopped: {type(exc).__name__}: {exc}")


# ------------------------------------------------------------------ the batch
def run_batch(files: list[Path], work: Callable, options, what: str, *, output: Callable[[Path], Path],
              summary_dir: Path | None = None) -> int:
    """Run ``work(path, options) -> ScanResult`` over ``files`` (see the module docstring); returns
    1 if any scan failed, else 0. ``output(path)``: the file a scan writes (for ``--resume``);
    ``summary_dir``: where ``summary.csv`` goes (None: no summary, e.g. a single scan)."""
    workers = getattr(options, "workers", 1) or 1
    scheduler = getattr(options, "scheduler", None)
    rows: dict[str, BatchRow] = {}
    todo = []
    for path in files:
        if getattr(options, "resume", False) and output(path).exists():
            rows[path.name] = BatchRow(path.name, "skipped", message=f"{output(path).name} exists (--resume)")
        else:
            todo.append(path)
    progress = _Progress(len(files), len(files) - len(todo))
    if rows:
        print(f"{len(rows)} of {len(files)} scan(s) already done, skipped (--resume)", file=sys.stderr)
    if scheduler:
        results = _dask(work, todo, options, scheduler)
    elif workers > 1 and len(todo) > 1:
        results = _local_pool(work, todo, options, workers)
    else:
        results = _serial(work, todo, options)
    try:
        for row in results:
            rows[row.scan] = row
            progress.report(row, single=len(files) == 1)
            if summary_dir is not None:
                _write_summary(summary_dir, files, rows)
    finally:
        progress.finish()
    failed = [r for r in rows.values() if r.status == "failed"]
    if failed and len(files) > 1:
        print(f"{len(failed)} of {len(files)} scan(s) could not be {what}", file=sys.stderr)
    if summary_dir is not None and len(files) > 1:
        print(f"summary: {summary_dir / SUMMARY_NAME}", file=sys.stderr)
    return 1 if failed else 0


def _write_summary(folder: Path, files: list[Path], rows: dict[str, BatchRow]) -> None:
    from core.formats.atomic_files import write_atomic

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_FIELDS, lineterminator="\n")
    writer.writeheader()
    for path in files:   # in the folder's order, whatever order they finished in
        if path.name in rows:
            writer.writerow(rows[path.name].as_csv())
    try:
        write_atomic(folder / SUMMARY_NAME, buffer.getvalue().encode("utf-8"))
    except OSError as exc:
        raise CliError(f"cannot write {folder / SUMMARY_NAME}: {exc.strerror or exc}") from None


@dataclass
class _Progress:
    """Per-scan lines on stdout, and on a terminal a progress bar with the time left on stderr."""

    total: int
    done: int = 0
    started: float = field(default_factory=time.perf_counter)
    _bar_shown: bool = False

    def report(self, row: BatchRow, *, single: bool) -> None:
        self.done += 1
        self._clear_bar()
        prefix = row.scan if single else f"[{self.done}/{self.total}] {row.scan}"
        if row.status == "failed":
            print(f"{prefix}: failed: {row.message}", file=sys.stderr, flush=True)
        else:
            print(f"{prefix}: {row.message} ({row.seconds:.1f} s)", flush=True)
        for note in row.notes:
            print(note, file=sys.stderr, flush=True)
        if not single and sys.stderr.isatty() and self.done < self.total:
            elapsed = time.perf_counter() - self.started
            left = elapsed / self.done * (self.total - self.done)
            filled = round(30 * self.done / self.total)
            sys.stderr.write(f"\r[{'#' * filled}{'-' * (30 - filled)}] {self.done}/{self.total} · ~{left:.0f} s left")
            sys.stderr.flush()
            self._bar_shown = True

    def _clear_bar(self) -> None:
        if self._bar_shown:
            sys.stderr.write("\r\033[K")
            self._bar_shown = False

    def finish(self) -> None:
        self._clear_bar()
