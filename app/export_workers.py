"""export_workers.py
----
Frames rendered by several processes at once, for :mod:`app.export`.

Software OpenGL (Mesa llvmpipe) costs about 92 ms of CPU for a 1280x720 frame of the default
face (the strip around it, :class:`app.export._FaceRenderer`). One process spreads part of that
over the cores (llvmpipe's rasterizer threads), but not its vertex processing, set-up and VTK's
own work; so an export with ``workers = N > 1`` starts N
render processes (``python -m app.export_workers SPEC.json``), each with its own off-screen
renderer (:class:`app.export._FaceRenderer`, the code the serial path uses, so the pixels are the
same), and the exporting process only computes the vertices, hands them out and passes the images
to the encoder in order.

Frames go to whichever worker is free (a shared queue, in frame order) and come back into a small
reordering window: a worker slowed by other programs on the machine does not hold the others up,
and no worker runs more than the window (about two frames per worker) ahead of the encoder, which
bounds the memory.

Protocol of a worker
    stdin: its frames' vertices, (n, 3) little-endian float64, one after the other; end of file
    means no more frames (and is how a worker learns that its exporter died).
    stdout: per frame one message, a 4-byte kind, a 4-byte little-endian length and the payload:
    ``IMG `` with (h, w, 3) uint8 RGB (top row first) or ``ERR `` with a message for the user (then
    the worker exits). Anything a library prints goes to stderr, a log file of the pool's.

In the exporter :class:`RenderPool` runs one thread per worker (take a frame, write its vertices,
read its image); the calling thread takes images in frame order (:meth:`RenderPool.take`),
polling its cancel flag. A worker that fails or dies becomes one :class:`ExportError` naming what
it said; :meth:`RenderPool.close` kills the workers (they hold no files), so cancelling is as
quick as with one renderer.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path
from typing import Callable

import numpy as np

from app.export_plan import ExportCancelled, ExportError, ExportSettings
from app.export_sinks import _tail

_HEADER = struct.Struct("<4sI")
_IMAGE, _ERROR = b"IMG ", b"ERR "
_END = object()           # "no more frames" in a worker's inbox
_POLL_S = 0.05
_EXIT_WAIT_S = 5.0


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _project_root() -> Path:
    return Path(__file__).resolve().parent.parent


def _read_exact(stream, size: int) -> bytearray | None:
    """``size`` bytes from ``stream``; None at end of file (also after a partial read)."""
    buffer = bytearray(size)
    view = memoryview(buffer)
    got = 0
    while got < size:
        n = stream.readinto(view[got:])
        if not n:
            return None
        got += n
    return buffer


class RenderPool:
    """``workers`` render processes for one export.

    Feed frames in order with :meth:`submit` (from one thread) and :meth:`end_of_frames`; take the
    images in order with :meth:`take` (from another); always :meth:`close`.
    """

    #: Images waiting for the encoder, at most (beyond one per worker), in bytes.
    WINDOW_BYTES = 512 * 2**20

    def __init__(self, face_file: Path, settings: ExportSettings, size: tuple[int, int], n_vertices: int,
                 workers: int, work: Path, *, python: str | None = None):
        self.workers = int(workers)
        self.size = (int(size[0]), int(size[1]))
        self.n_vertices = int(n_vertices)
        self._frame_bytes = self.size[0] * self.size[1] * 3
        self.window = self.workers + max(1, min(self.workers + 2, self.WINDOW_BYTES // self._frame_bytes))
        self._stop = threading.Event()
        self._jobs: queue.Queue = queue.Queue(maxsize=self.workers)
        self._done = threading.Condition()
        self._images: dict[int, np.ndarray] = {}   # rendered, not yet taken (guarded by _done)
        self._next = 0                               # the frame the encoder takes next
        self._failure: tuple[str, object] | None = None
        self._logs: list[Path] = []
        self._procs: list[subprocess.Popen] = []
        self._threads: list[threading.Thread] = []
        spec = Path(work) / "render-worker.json"
        spec.write_text(json.dumps({"settings": settings.to_json(), "face": str(face_file),
                                    "size": list(self.size), "n_vertices": self.n_vertices}), encoding="utf-8")
        env = dict(os.environ)
        root = str(_project_root())
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        # llvmpipe draws one frame with as many threads as there are cores; with one process per core
        # those threads only fight each other (measured: 130 instead of 134 ms of CPU a frame at 1280x720).
        env.setdefault("LP_NUM_THREADS", str(max(1, _cores() // self.workers)))
        try:
            for i in range(self.workers):
                log = Path(work) / f"render-worker-{i}.log"
                self._logs.append(log)
                with open(log, "wb") as err:
                    self._procs.append(subprocess.Popen(
                        [python or sys.executable, "-m", "app.export_workers", str(spec)],
                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, env=env, cwd=root))
        except OSError as exc:
            self.close()
            raise ExportError(f"Could not start the export's render processes: {exc.strerror or exc}.") from None
        for i in range(self.workers):
            thread = threading.Thread(target=self._serve, args=(i,), name=f"mimica-render-{i}", daemon=True)
            thread.start()
            self._threads.append(thread)

    # ------------------------------------------------------------ feeding (one thread, in frame order)
    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._jobs.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def submit(self, k: int, vertices: np.ndarray) -> bool:
        """Queue frame ``k``'s (n, 3) vertices for the next free worker; blocks while all are busy or
        the encoder is a window behind. False when the pool is closing."""
        with self._done:
            while k >= self._next + self.window and not self._stop.is_set():
                self._done.wait(_POLL_S)
        return self._put((k, np.ascontiguousarray(vertices, dtype="<f8")))

    def end_of_frames(self) -> None:
        """No more frames: each worker exits after its last one."""
        for _ in range(self.workers):
            if not self._put(_END):
                return

    # ------------------------------------------------------------ one thread per worker
    def _fail(self, kind: str, value) -> None:
        with self._done:
            if self._failure is None:
                self._failure = (kind, value)
            self._done.notify_all()

    def _serve(self, i: int) -> None:
        proc = self._procs[i]
        try:
            while not self._stop.is_set():
                try:
                    item = self._jobs.get(timeout=_POLL_S)
                except queue.Empty:
                    continue
                if item is _END:
                    proc.stdin.close()
                    return
                k, vertices = item
                try:
                    proc.stdin.write(memoryview(vertices).cast("B"))
                    proc.stdin.flush()
                except OSError:
                    pass  # it stopped reading: what it said before exiting (if anything) is on its stdout
                header = _read_exact(proc.stdout, _HEADER.size)
                if header is None:
                    raise EOFError
                kind, length = _HEADER.unpack(header)
                payload = _read_exact(proc.stdout, length)
                if payload is None:
                    raise EOFError
                if kind == _IMAGE and length == self._frame_bytes:
                    image = np.frombuffer(payload, dtype=np.uint8).reshape(self.size[1], self.size[0], 3)
                    with self._done:
                        self._images[k] = image
                        self._done.notify_all()
                elif kind == _ERROR:
                    self._fail("error", payload.decode("utf-8", "replace"))
                    return
                else:
                    self._fail("error", f"A render process sent an unexpected message ({kind!r}, {length} bytes).")
                    return
        except (EOFError, OSError, ValueError):
            if not self._stop.is_set():
                self._fail("died", i)

    def _died(self, i: int) -> str:
        proc = self._procs[i]
        try:
            status = proc.wait(timeout=_EXIT_WAIT_S)
        except subprocess.TimeoutExpired:
            status = None
        tail = _tail(self._logs[i], 12)
        how = f"exit status {status}" if status is not None and status >= 0 else (
            f"killed by signal {-status}" if status is not None else "it stopped answering")
        return (f"A render process of the export stopped unexpectedly ({how})."
                + (f"\nIts last messages:\n{tail}" if tail else ""))

    # ------------------------------------------------------------ taking images (in frame order)
    def take(self, k: int, cancelled: Callable[[], bool], check: Callable[[], None] = lambda: None) -> np.ndarray:
        """Frame ``k``'s (h, w, 3) uint8 image once rendered (take them in order). Polls ``cancelled``
        (raises :class:`ExportCancelled`) and ``check`` (which may raise the feeder's problem); a
        worker's failure is an :class:`ExportError`."""
        while True:
            if cancelled():
                raise ExportCancelled()
            check()
            with self._done:
                if k in self._images:
                    self._next = k + 1
                    self._done.notify_all()
                    return self._images.pop(k)
                failure = self._failure
                if failure is None:
                    self._done.wait(_POLL_S)
                    continue
            kind, value = failure
            raise ExportError(value if kind == "error" else self._died(value))

    def close(self, *, wait: bool = False) -> None:
        """Stop the workers (killed at once unless ``wait``: then given a few seconds to exit after
        their last frame) and the threads."""
        self._stop.set()
        for proc in self._procs:
            if wait and proc.poll() is None:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=_EXIT_WAIT_S)
            if proc.poll() is None:
                with contextlib.suppress(OSError):
                    proc.kill()
        for proc in self._procs:
            for stream in (proc.stdin, proc.stdout):
                with contextlib.suppress(OSError, ValueError):
                    stream.close()
            proc.wait()
        for thread in self._threads:
            thread.join(timeout=_EXIT_WAIT_S)


# ------------------------------------------------------------------ the worker process
def _worker_main(spec_path: str) -> int:
    """Entry of ``python -m app.export_workers SPEC.json`` (see the module docstring)."""
    # The exporter decides when to stop: a terminal's Ctrl-C reaches the whole process group.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The protocol owns the real stdout; whatever a library prints goes to the log.
    out = open(os.dup(1), "wb")
    os.dup2(2, 1)
    stdin = sys.stdin.buffer

    def send(kind: bytes, payload) -> None:
        payload = memoryview(payload).cast("B")
        out.write(_HEADER.pack(kind, len(payload)))
        out.write(payload)
        out.flush()

    try:
        from app.export import _FaceRenderer, _load_face_npz

        spec = json.loads(Path(spec_path).read_text(encoding="utf-8"))
        settings = ExportSettings.from_json(spec["settings"])
        size = tuple(int(v) for v in spec["size"])
        n = int(spec["n_vertices"])
        renderer = _FaceRenderer(_load_face_npz(Path(spec["face"])), settings, size)
        try:
            while True:
                data = _read_exact(stdin, n * 3 * 8)
                if data is None:
                    return 0  # no more frames (or the exporter went away)
                vertices = np.frombuffer(data, dtype="<f8").reshape(n, 3)
                send(_IMAGE, np.ascontiguousarray(renderer.render(vertices), dtype=np.uint8))
        finally:
            renderer.close()
    except (BrokenPipeError, ConnectionResetError):
        return 0  # the exporter went away: nobody to tell
    except ExportError as exc:
        with contextlib.suppress(OSError):
            send(_ERROR, str(exc).encode("utf-8"))
        return 2
    except Exception as exc:  # noqa: BLE001 - the exporter shows the sentence, the log keeps the traceback
        import traceback

        traceback.print_exc()
        with contextlib.suppress(OSError):
            send(_ERROR, f"The export renderer failed: {type(exc).__name__}: {exc}".encode("utf-8"))
        return 1


if __name__ == "__main__":
    if len(sys.argv) == 2:
        sys.exit(_worker_main(sys.argv[1]))
    print("usage: python -m app.export_workers SPEC.json  (internal: a render process of app.export)",
          file=sys.stderr)
    sys.exit(2)
