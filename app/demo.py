"""demo.py
----
The built-in showcase (``mimica demo``): the six expressions of thesis A's Table B.1, one after the
other, a spoken sentence with lip-sync and blinks, then a muscle-driven kiss and smile (thesis C's
presets, simulated with the muscle layer's dynamic integrator so they ramp and settle). About 24 s.
"""

from __future__ import annotations

SENTENCE = "Hello! I am Mimica. I can talk, smile, and blow you a kiss."
EXPRESSIONS = ("joy", "surprise", "sadness", "anger", "fear", "disgust")
EXPRESSION_STEP_S = 1.9      # one expression: 0.6 s in, 0.7 s held, 0.6 s out
SPEECH_START_S = 0.6 + EXPRESSION_STEP_S * len(EXPRESSIONS) + 0.4
MUSCLE_GAP_S = 0.8


def demo_timeline(speech_end_s: float):
    """(Timeline, speech start s) of the showcase; ``speech_end_s`` is when the lip-sync clip ends."""
    from core.layers.muscles import preset
    from core.timeline import Timeline

    tracks: dict[str, list[tuple[float, float, str]]] = {}
    t = 0.6
    for name in EXPRESSIONS:
        tracks[f"expression:{name}"] = [(t, 0.0, "smooth"), (t + 0.6, 1.0, "smooth"),
                                        (t + 1.3, 1.0, "smooth"), (t + 1.9, 0.0, "smooth")]
        t += EXPRESSION_STEP_S
    kiss_start = speech_end_s + MUSCLE_GAP_S
    smile_start = kiss_start + 3.2
    end = smile_start + 4.0
    for start, name in ((kiss_start, "kiss"), (smile_start, "discreet_smile")):
        for (muscle, side), force in preset(name).forces.items():
            key = f"muscle:{muscle}:{side}" if side else f"muscle:{muscle}"
            hold = 1.6 if name == "kiss" else 2.2
            tracks.setdefault(key, []).extend(
                [(start, 0.0, "step"), (start + 0.05, force, "step"), (start + hold, 0.0, "step")])
    timeline = Timeline(duration=round(end + 0.5, 1), fps=30)
    timeline.add_keys(tracks, label="demo")
    return timeline


def demo_project():
    """(default Face, Project) of the showcase, lip-sync included."""
    from core.default_face import load_default_face
    from core.lipsync import lipsync_tracks
    from core.formats.project import FaceRef, Project, SpeechClip

    speech = lipsync_tracks(SENTENCE, "en", start_s=SPEECH_START_S, blinks=True, seed=7)
    timeline = demo_timeline(speech.end_s)
    timeline.add_keys({key: track.keys for key, track in speech.tracks.items()}, label="lip-sync")
    face = load_default_face()
    project = Project.from_state(face, FaceRef.default_face(), timeline=timeline,
                                 speech=[SpeechClip(SENTENCE, "en", SPEECH_START_S)])
    return face, project

