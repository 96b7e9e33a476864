"""Shared by the ``mimica`` subcommands: the user-facing error, argument parsers, loading a face or a
project, and parsing rig parameters (``--fap``, ``--expression``, ``--viseme``, ``--muscles``, ``--jaw``)
into canonical parameter keys (``core.parameters``), so every subcommand spells them one way."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np

PROG = "mimica"
VIEWS = ("front", "side", "three-quarter", "back")
MODES = ("textured", "shaded", "wireframe", "points")


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 1 (or ``status``)."""

    def __init__(self, message: str, status: int = 1):
        super().__init__(message)
        self.status = status


def format_errors() -> tuple[type[Exception], ...]:
    """The error classes of Mimica's file formats: their messages are written for the user."""
    from core.formats.dpc_file import DpcFileError
    from core.formats.fap_file import FapFileError
    from core.formats.landmarks_io import LandmarkFileError
    from core.formats.mesh_io import MeshLoadError, MeshSaveError
    from core.formats.project import ProjectError
    from core.layers.muscles.force_file import ForceFileError

    return (ProjectError, FapFileError, DpcFileError, LandmarkFileError, ForceFileError, MeshLoadError, MeshSaveError)


def unexpected_error_message(exc: BaseException, command: str | None = None) -> str:
    """One line for an exception no subcommand turned into a CliError: a format error's own message
    (it names the file and the field), else what failed and what to do — never just a type name."""
    try:
        known = isinstance(exc, format_errors())
    except Exception:  # noqa: BLE001 - the message must not fail
        known = False
    if known:
        return str(exc)
    if isinstance(exc, MemoryError):
        return (f"'{command or PROG}' ran out of memory; try a smaller file, size or duration")
    if isinstance(exc, OSError):
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        return f"a file could not be read or written{where}: {exc.strerror or exc}"
    detail = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
    return (f"'{command or PROG}' failed unexpectedly ({detail}). This is a bug in Mimica: please report it "
            "with the command you ran.")


def parse_size(text: str) -> tuple[int, int]:
    """``"1200x900"`` -> (1200, 900)."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 1200x900, got {text!r}") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"size {width}x{height} out of range (16..8192 per side)")
    return width, height


def load_face_or_default(path: str | None):
    """The face at ``path`` (via ``core.formats.mesh_io``) or the default face; raises :class:`CliError`."""
    if path is None:
        try:
            from core.default_face import load_default_face
        except ImportError as exc:
            raise CliError(f"the default face is not available ({exc}); give a face file") from None
        return load_default_face()
    p = Path(path)
    if not p.exists():
        raise CliError(f"no such file: {path}")
    if p.is_dir():
        raise CliError(f"{path} is a directory, not a face file")
    try:
        from core.formats.mesh_io import MeshLoadError
    except ImportError as exc:
        raise CliError(f"mesh loading is not available ({exc})") from None
    from core.registration.correspondence import load_face_or_canonical

    try:
        return load_face_or_canonical(p)   # a saved canonical face is kept whole and animates again
    except MeshLoadError as exc:
        raise CliError(f"cannot load {path}: {exc}") from None


def _named_value(text: str, what: str) -> tuple[str, str | None]:
    name, sep, value = text.partition("=" if what == "fap" else ":")
    if not name.strip() or (sep and not value.strip()):
        example = "open_jaw=400" if what == "fap" else f"{'joy:60' if what == 'expression' else '10:80'}"
        raise CliError(f"--{what} {text!r}: expected e.g. --{what} {example}")
    return name.strip(), value.strip() if sep else None


def _number(text: str, what: str) -> float:
    try:
        value = float(text.rstrip("%"))
    except ValueError:
        raise CliError(f"{what}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise CliError(f"{what}: {text!r} is not a finite number")
    return value


def _intensity(text: str | None, what: str) -> float:
    """Percent (0-100) -> fraction; absent means 100 %."""
    if text is None:
        return 1.0
    value = _number(text, what)
    if not 0 <= value <= 100:
        raise CliError(f"{what}: intensity must be 0-100 (%), got {text}")
    return value / 100.0


def rig_values(args) -> dict[str, float]:
    """{canonical key: value} of --fap / --expression / --viseme / --muscles / --jaw (FAP units,
    percent intensities, muscle forces, degrees); CliError naming the option for anything wrong."""
    from core import parameters as P

    values: dict[str, float] = {}
    for item in getattr(args, "fap", None) or []:
        name, value = _named_value(item, "fap")
        if value is None:
            raise CliError(f"--fap {item!r}: give a value, e.g. --fap {name}=200")
        try:
            key = P.key_of(name if ":" in name else f"fap:{name}")
            # Within the widest range any face allows (a closed eye's upper lid opens further than
            # the table says); the rig checks the face's own once the face is loaded.
            values[key] = P.check_value(key, _number(value, f"--fap {name}"))
        except P.ParameterError as exc:
            raise CliError(f"--fap {item!r}: {exc}") from None
    for what in ("expression", "viseme"):
        text = getattr(args, what, None)
        if text:
            name, value = _named_value(text, what)
            try:
                values[P.key_of(f"{what}:{name}")] = _intensity(value, f"--{what} {name}")
            except P.ParameterError as exc:
                raise CliError(f"--{what} {text!r}: {exc}") from None
    if getattr(args, "muscles", None):
        for (name, side), force in parse_muscle_forces(args.muscles).forces.items():
            try:
                key = P.key_of((name, side))
                values[key] = P.check_value(key, force)
            except P.ParameterError as exc:
                raise CliError(f"--muscles: {exc}") from None
    if getattr(args, "jaw", None) is not None:
        values["jaw"] = checked_value("--jaw", "jaw", args.jaw)
    return values


def checked_value(option: str, key: str, value) -> float:
    """``value`` of parameter ``key`` checked through the registry; CliError naming ``option`` if not."""
    from core import parameters as P

    try:
        return P.check_value(key, value)
    except P.ParameterError as exc:
        raise CliError(f"{option}: {exc}") from None


def parse_muscle_forces(text: str):
    """``"kiss"`` (a preset) or ``"zygomatic_major=9,risorius:left=6,orbicularis_oris=8"`` -> ForceSet.

    A paired muscle without a side gets the force on both sides.
    """
    from core.layers.muscles import ForceSet, control_keys, preset, preset_id, preset_names

    text = text.strip()
    named = preset_id(text)              # an id or the name the window shows, any case
    if named is not None:
        return preset(named)
    if "=" not in text:
        raise CliError(f"--muscles {text!r}: not a preset ({', '.join(preset_names())}) "
                       "and not name=force pairs, e.g. --muscles risorius=40,zygomatic_major:left=9")
    keys = control_keys()
    names = sorted({name for name, _side in keys})
    forces = {}
    for item in text.split(","):
        target, sep, value = item.partition("=")
        name, _, side = target.strip().partition(":")
        side = side.strip() or None
        if not sep or not name or not value.strip():
            raise CliError(f"--muscles {item!r}: expected name=force, e.g. risorius=40")
        if name not in names:
            raise CliError(f"--muscles: unknown muscle {name!r}; muscles are {', '.join(names)}")
        sides = [s for n, s in keys if n == name]
        if side is not None and side not in sides:
            raise CliError(f"--muscles {item!r}: side must be one of {', '.join(str(s) for s in sides)}")
        force = _number(value, f"--muscles {name}")
        for s in ([side] if side is not None else sides):
            forces[(name, s)] = force
    return ForceSet(forces=forces)


def open_project(path: str):
    """(Project, its face) of a .mimica file; load notes go to stderr; CliError otherwise."""
    from core.formats.project import ProjectError, load_project, open_face

    p = Path(path)
    if not p.is_file():
        raise CliError(f"no such project: {path}")
    notes: list[str] = []
    try:
        project = load_project(p)
        face = open_face(project, notes)
    except (ProjectError, ValueError, OSError) as exc:
        raise CliError(str(exc)) from None
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    return project, face




# ---------------------------------------------------------------- scans, one file or a folder
SCAN_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
TEMPLATES = ("mpeg4_80", "a48")


def scan_files(path: str) -> list[Path]:
    p = Path(path)
    if not p.exists():
        raise CliError(f"no such file or folder: {path}")
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in SCAN_SUFFIXES)
        if not files:
            raise CliError(f"{path} holds no scans ({', '.join(SCAN_SUFFIXES)})")
        return files
    return [p]


def output_for(scan: Path, out: Path, batch: bool, suffix: str) -> Path:
    """Output path of one scan: ``out`` itself, or ``out/<scan name><suffix>`` for a folder."""
    if not batch:
        if not out.parent.exists():
            raise CliError(f"output folder does not exist: {out.parent}")
        return out
    out.mkdir(parents=True, exist_ok=True)
    return out / (scan.stem + suffix)


def with_texture(scan, args: argparse.Namespace):
    """``scan`` with the image of ``--texture``, if given: turned upright when the scan's texture
    coordinates count rows from the top (``core.face.texture_runs_down``, as the window does, with a
    note on stderr); ``--flip-texture`` turns the result over once more."""
    from core.face import texture_runs_down
    from core.formats.mesh_io import MeshLoadError, load_texture_image

    try:
        if args.texture:
            scan = scan.with_texture(load_texture_image(args.texture))
            if texture_runs_down(scan):
                scan = scan.with_flipped_texture()
                print(f"note: {Path(args.texture).name} was turned upside down to match the scan's texture "
                      "coordinates (they count rows from the top); --flip-texture turns it back", file=sys.stderr)
        return scan.with_flipped_texture() if args.flip_texture and scan.texture is not None else scan
    except (MeshLoadError, ValueError) as exc:
        raise CliError(f"--texture {args.texture}: {exc}") from None


def add_texture_options(p) -> None:
    p.add_argument("--texture", metavar="IMAGE",
                   help="map IMAGE onto the scan through its texture coordinates (a scan whose texture is a "
                        "separate file)")
    p.add_argument("--flip-texture", action="store_true",
                   help="turn the texture upside down (after Mimica's own choice from the texture coordinates)")


def positive_factor(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number such as 10 or 0.001, got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"the scale factor must be a positive number, got {text!r}")
    return value



# ---------------------------------------------------------------- video out
class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP during an export: handled like Ctrl-C (everything temporary is removed)."""


@contextlib.contextmanager
def stop_on_signals():
    """While inside, SIGTERM and SIGHUP raise :class:`Stopped` (a KeyboardInterrupt) in the main thread,
    like SIGINT does, so ``finally`` blocks and ``with`` exits remove temporary files; a second signal
    during that clean-up is ignored. Restores the previous handlers on exit."""
    import signal

    names = [name for name in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, name)]
    numbers = [getattr(signal, name) for name in names]

    def stop(signum, _frame):
        for number in numbers:
            signal.signal(number, signal.SIG_IGN)  # let the clean-up finish
        raise Stopped(signal.Signals(signum).name)

    try:
        previous = {number: signal.signal(number, stop) for number in numbers}
    except ValueError:  # not the main thread: nothing to install
        previous = {}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def export_video(face, frame_vertices, out: Path, *, size, fps: float, duration: float, audio: Path | None,
                 workers: int | None = None, full_detail: bool = False) -> None:
    """Render ``frame_vertices(t)`` for 0..duration to ``out`` (MP4/GIF/AVI/PNG/JPG) with progress on stderr.

    ``workers`` render processes work in parallel (default: one per core, fewer for short
    animations); ``full_detail`` turns the export's level of detail off. Prints what was written and, last, ``exported N frames in S s (F fps, W workers)``.
    Call it inside :func:`stop_on_signals` so SIGTERM/SIGHUP stop it cleanly.
    """
    from app.export import ExportError, ExportSettings, export

    settings = ExportSettings(path=out, end_s=duration, size=size, fps=fps, audio_path=audio, workers=workers,
                              full_detail=full_detail)
    total = [0]

    def progress(done: int, n: int) -> None:
        total[0] = n
        if done == n or done % max(1, n // 20) == 0:
            print(f"\rrendering frame {done}/{n}", end="", file=sys.stderr, flush=True)

    try:
        result = export(face, frame_vertices, settings, progress=progress)
    except ExportError as exc:
        raise CliError(str(exc)) from None
    finally:
        if total[0]:
            print(file=sys.stderr)
    print(result.describe())
    print(f"exported {result.speed()}", flush=True)
