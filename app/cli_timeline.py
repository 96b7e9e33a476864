"""cli_timeline.py
----
Commands that work on animations (projects, lip-sync, the demo):

    mimica export PROJECT --out FILE.mp4|.gif|.avi|.png|.fap [--size WxH] [--fps N]
    mimica lipsync "TEXT" --lang en|pt-br --out PROJECT.mimica [--no-blinks]
    mimica demo [--out demo.mp4] [--size WxH] [--fps N]

A project is evaluated exactly as the window plays it: the timeline is applied to a FaceRig at
each frame time, and muscle tracks are simulated forward with the muscle layer's dynamic
integrator (:class:`core.timeline.MuscleSimulationCache`). Speech clips are re-synthesised and
mixed into one sound track (each clip at its start time), so an MP4/AVI carries the voice in sync.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import wave
from pathlib import Path

import numpy as np

from app.cli import CliError, _parse_size

VIDEO_SUFFIXES = (".mp4", ".gif", ".avi", ".png", ".jpg")


# ------------------------------------------------------------------ evaluating a project
class ProjectAnimation:
    """A project's face, rig and (optional) muscle simulation, posed at any time."""

    def __init__(self, face, timeline, *, rig_settings=None, log=print):
        from core import timeline as tl
        from core.rig import FaceRig

        self.face, self.timeline = face, timeline
        try:
            self.rig = FaceRig(face)
        except ValueError as exc:
            raise CliError(f"cannot animate this face: {exc}") from None
        self.muscles = None
        self.simulation = None
        if rig_settings is not None:
            rig_settings.apply(self.rig)
        if any(tl.is_simulated(key) for key in timeline.tracks):
            from core.muscles import MuscleLayer

            log("building the muscle model…")
            self.muscles = MuscleLayer(face)
            self.muscles.attach(self.rig)
            self.simulation = tl.MuscleSimulationCache(timeline, self.muscles)

    def vertices(self, t: float) -> np.ndarray:
        """(n, 3) mm: the face at time ``t`` s."""
        from core.timeline import apply_at

        apply_at(self.timeline, t, self.rig, self.simulation)
        return np.array(self.rig.vertices())

    def fap_values(self, t: float) -> np.ndarray:
        """(68,) the effective FAP values at ``t`` (presets folded into low-level FAPs)."""
        from core.timeline import apply_at

        apply_at(self.timeline, t, self.rig, None)
        return self.rig.effective_fap_values()


def speech_track(clips, out_dir: Path) -> Path | None:
    """One WAV with every speech clip at its start time (None without clips)."""
    from core.lipsync import speech_audio, write_wav

    if not clips:
        return None
    pieces, rate = [], None
    for clip in clips:
        path, sample_rate = speech_audio(clip.text, clip.lang, rate_wpm=clip.rate_wpm)
        with wave.open(str(path), "rb") as w:
            samples = np.frombuffer(w.readframes(w.getnframes()), dtype=np.int16).astype(np.float32)
        if rate is not None and sample_rate != rate:
            raise CliError("speech clips with different sample rates cannot be mixed")
        rate = sample_rate
        pieces.append((int(round(clip.start_s * sample_rate)), samples))
    total = max(start + len(s) for start, s in pieces)
    mix = np.zeros(total, np.float32)
    for start, samples in pieces:
        mix[start:start + len(samples)] += samples
    out = out_dir / "speech.wav"
    write_wav(out, np.clip(mix, -32768, 32767).astype(np.int16), rate)
    return out


def _load_project(path: str):
    from core.project import ProjectError, load_project, open_face

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


def _export_video(face, animation: ProjectAnimation, out: Path, *, size, fps: float, duration: float,
                  audio: Path | None) -> None:
    from app.export import ExportError, ExportSettings, export

    settings = ExportSettings(path=out, end_s=duration, size=size, fps=fps, audio_path=audio)
    total = [0]

    def progress(done: int, n: int) -> None:
        total[0] = n
        if done == n or done % max(1, n // 20) == 0:
            print(f"\rrendering frame {done}/{n}", end="", file=sys.stderr, flush=True)

    try:
        result = export(face, animation.vertices, settings, progress=progress)
    except ExportError as exc:
        raise CliError(str(exc)) from None
    finally:
        if total[0]:
            print(file=sys.stderr)
    print(result.describe() + f" in {result.seconds:.0f} s")


def _export_fap(animation: ProjectAnimation, out: Path, *, fps: float, duration: float) -> None:
    from core.fap_file import FapFileError, FapSequence, write_fap

    times = np.arange(int(round(duration * fps))) / fps
    values = np.array([animation.fap_values(t) for t in times])
    driven = np.abs(values).max(axis=0) > 0
    values[:, ~driven] = np.nan   # FAPs the animation never moves stay masked out
    try:
        write_fap(out, FapSequence.from_values(values, fps, name=out.stem))
    except (FapFileError, ValueError, OSError) as exc:
        raise CliError(f"cannot write {out}: {exc}") from None
    print(f"wrote {out} ({len(times)} frames at {fps:g} fps, {int(driven.sum())} FAPs)")


def cmd_export(args: argparse.Namespace) -> int:
    """Render or write a project's animation."""
    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in VIDEO_SUFFIXES + (".fap",):
        raise CliError(f"--out must end in {', '.join(VIDEO_SUFFIXES + ('.fap',))}, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    project, face = _load_project(args.project)
    timeline = project.timeline
    fps = float(args.fps or timeline.fps)
    animation = ProjectAnimation(face, timeline, rig_settings=project.rig)
    if suffix == ".fap":
        _export_fap(animation, out, fps=fps, duration=timeline.duration)
        return 0
    with tempfile.TemporaryDirectory(prefix="mimica-export-") as tmp:
        audio = speech_track(project.speech, Path(tmp)) if suffix in (".mp4", ".avi") else None
        _export_video(face, animation, out, size=args.size, fps=fps, duration=timeline.duration, audio=audio)
    return 0


def cmd_lipsync(args: argparse.Namespace) -> int:
    """Text -> visemes (+ blinks) on a new project for the default face."""
    from core.default_face import load_default_face
    from core.lipsync import lipsync_tracks
    from core.project import FaceRef, Project, ProjectError, SpeechClip, save_project
    from core.timeline import Timeline

    out = Path(args.out)
    if out.suffix.lower() != ".mimica":
        raise CliError(f"--out must end in .mimica, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    if not args.text.strip():
        raise CliError("give some text to speak")
    try:
        result = lipsync_tracks(args.text, args.lang, blinks=not args.no_blinks)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    duration = float(np.ceil((result.end_s + 0.5) * 10) / 10)
    timeline = Timeline(duration=duration, fps=args.fps, tracks=result.tracks.values())
    project = Project.from_state(load_default_face(), FaceRef.default_face(), timeline=timeline,
                                 speech=[SpeechClip(args.text, args.lang, 0.0)])
    try:
        save_project(out, project)
    except (ProjectError, OSError) as exc:
        raise CliError(f"cannot write {out}: {exc}") from None
    n_keys = sum(len(t) for t in result.tracks.values())
    print(f"wrote {out}: {len(result.phonemes)} phonemes, {len(result.tracks)} tracks, {n_keys} keys, "
          f"{duration:.1f} s")
    if result.unmapped:
        print(f"note: phonemes without a viseme (their time went to the neighbours): "
              f"{', '.join(sorted(set(result.unmapped)))}", file=sys.stderr)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """The built-in showcase: export it (--out) or play it in the window."""
    from app.demo import demo_project

    if args.out is None:
        from app.main_window import run_gui

        return run_gui(None, demo=True)
    out = Path(args.out)
    if out.suffix.lower() not in (".mp4", ".gif", ".avi"):
        raise CliError(f"--out must end in .mp4, .gif or .avi, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    face, project = demo_project()
    animation = ProjectAnimation(face, project.timeline)
    with tempfile.TemporaryDirectory(prefix="mimica-demo-") as tmp:
        audio = speech_track(project.speech, Path(tmp)) if out.suffix.lower() != ".gif" else None
        _export_video(face, animation, out, size=args.size, fps=float(args.fps),
                      duration=project.timeline.duration, audio=audio)
    return 0


# ------------------------------------------------------------------ parsers
def add_export(sub) -> None:
    p = sub.add_parser("export", help="render a project to video/stills or write its .fap",
                       description="Render PROJECT's animation off screen (MP4 H.264, GIF, AVI, PNG/JPG "
                                   "still) with its speech as sound, or write its FAP values as a .fap file.")
    p.add_argument("project", metavar="PROJECT.mimica")
    p.add_argument("--out", "-o", required=True, metavar="FILE")
    p.add_argument("--size", type=_parse_size, default=(1280, 720), metavar="WxH", help="default 1280x720")
    p.add_argument("--fps", type=float, help="frames per second (default: the project's)")
    p.set_defaults(func=cmd_export)


def add_lipsync(sub) -> None:
    p = sub.add_parser("lipsync", help="make a talking-face project from text",
                       description="Speak TEXT with espeak-ng, map its phonemes to MPEG-4 visemes with "
                                   "coarticulation (and blinks) and save a project with the speech attached.")
    p.add_argument("text", metavar="TEXT")
    p.add_argument("--lang", choices=("en", "en-gb", "pt-br"), default="en")
    p.add_argument("--out", "-o", required=True, metavar="PROJECT.mimica")
    p.add_argument("--fps", type=int, choices=(24, 25, 30, 60), default=30)
    p.add_argument("--no-blinks", action="store_true", help="do not add eye blinks")
    p.set_defaults(func=cmd_lipsync)


def add_demo(sub) -> None:
    p = sub.add_parser("demo", help="play (or export) the built-in showcase",
                       description="The six expressions, a spoken sentence, and muscle-driven kiss and "
                                   "smile. Without --out it plays in the window.")
    p.add_argument("--out", "-o", metavar="demo.mp4")
    p.add_argument("--size", type=_parse_size, default=(1280, 720), metavar="WxH")
    p.add_argument("--fps", type=int, choices=(24, 25, 30, 60), default=30)
    p.set_defaults(func=cmd_demo)
